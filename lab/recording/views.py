"""What the Rerun logger draws: the arm's poses, the network, the static scene, the blueprint.

Pure functions from lab objects to Rerun archetypes; lab/recording/writer.py decides when to log
them. What differs per method comes from its registry entry, as a `MethodView` (plain data, so
that the writer process needs no method's code). Goals of a planar arm are drawn at z = 0.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass
from importlib import metadata

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import robots
from lab.problem.controllers import network_layout
from robots.visual import joint_poses, visual_geometry

GREEN, BLUE, RED, GREY, ORANGE = [40, 170, 60], [60, 110, 220], [220, 60, 50], [150, 150, 150], [240, 150, 30]
LAYER_DX, NODE_DY = 160.0, 70.0  # network layout, in the graph view's units


@dataclass(frozen=True)
class MethodView:
    """What a recording shows of its method: the fields of its lab.methods.Method of these names."""

    name: str
    label: str
    controller: str  # "mlp" or "graph"
    search_title: str
    search_series: str


@dataclass(frozen=True)
class Geometry:
    """The arm and its training goals in 3D, with line widths scaled to the workspace."""

    arm: robots.Arm
    goals: np.ndarray  # (n, len(task_axes)) as the problem has them
    goals3: np.ndarray  # (n, 3); a tree's (n E, 3), the effectors of each goal one after the other
    radius: float  # a thin line, in the arm's length unit

    def __init__(self, arm: robots.Arm, goals: np.ndarray):
        goals = np.asarray(goals, dtype=np.float64)
        lo, hi = arm.workspace_bounds
        object.__setattr__(self, "arm", arm)
        object.__setattr__(self, "goals", goals)
        # pose goals (n, 4, 4): their positions are drawn
        points = goals[:, :3, 3] if goals.ndim == 3 and goals.shape[1:] == (4, 4) else goals
        object.__setattr__(self, "goals3", arm.to_3d(points).reshape(-1, 3))
        object.__setattr__(self, "radius", 0.003 * float(np.max(hi - lo)))


def pose(geo: Geometry, controller) -> dict:
    """The arm at controller(goal) for every training goal, the points reached, and the errors."""
    q = controller(geo.goals)  # (n, nq)
    strips = geo.arm.joint_positions(q).astype(np.float32)  # (n, nq + 2, 3); float32 converts 2x faster
    if geo.arm.is_tree:  # no polyline: a segment from each point to the one it hangs from
        parents = geo.arm.point_parents
        child = np.flatnonzero(parents >= 0)
        strips = np.stack([strips[:, parents[child]], strips[:, child]], axis=2).reshape(-1, 2, 3)
    reached = geo.arm.to_3d(geo.arm.reach(q)).reshape(-1, 3)
    r = geo.radius
    return {
        **robot_pose(geo.arm, q[0]),
        "world/arm": rr.LineStrips3D(strips, radii=0.6 * r, colors=[*GREY, 110]),
        "world/reached": rr.Points3D(reached, radii=2.5 * r, colors=BLUE),
        "world/errors": rr.Arrows3D(origins=geo.goals3, vectors=reached - geo.goals3, radii=0.7 * r, colors=RED),
    }


def _quaternion(wxyz: np.ndarray) -> rr.Quaternion:
    return rr.Quaternion(xyzw=[wxyz[1], wxyz[2], wxyz[3], wxyz[0]])


def robot_meshes(arm: robots.Arm) -> list:
    """Logged once (static): the arm's visual geometry (robots.visual), one entity per object
    under world/robot/j<joint>, placed in its joint's frame; robot_pose moves the joints."""
    out = []
    for i, g in enumerate(visual_geometry(arm)):
        entity = f"world/robot/j{g.joint}/g{i}"
        color = (255 * g.rgba).astype(np.uint8)
        if g.kind == "Mesh":
            shape = rr.Mesh3D(vertex_positions=g.params[0], triangle_indices=g.params[1], albedo_factor=color)
        elif g.kind == "Box":
            shape = rr.Boxes3D(half_sizes=[0.5 * np.asarray(g.params[0])], colors=color, fill_mode="solid")
        elif g.kind == "Cylinder":
            shape = rr.Cylinders3D(lengths=[g.params[1]], radii=[g.params[0]], colors=color, fill_mode="solid")
        else:
            shape = rr.Ellipsoids3D(half_sizes=[[g.params[0]] * 3], colors=color, fill_mode="solid")
        out += [(entity, rr.Transform3D(translation=g.position, quaternion=_quaternion(g.wxyz))), (entity, shape)]
    return out


def robot_pose(arm: robots.Arm, q: np.ndarray) -> dict:
    """The arm's meshes at joint values q (nq,): one Transform3D per joint (world/robot/j<joint>)."""
    return {f"world/robot/j{j}": rr.Transform3D(translation=p, quaternion=_quaternion(wxyz))
            for j, (p, wxyz) in joint_poses(arm, q).items()}


def static_scene(geo: Geometry) -> list:
    """Logged once: axes convention, goals, series styles."""
    out = [("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP),
           ("world/goals", rr.Points3D(geo.goals3, radii=3.0 * geo.radius, colors=GREEN)),
           ("world/base", rr.Points3D([[0.0, 0.0, 0.0]], radii=5.0 * geo.radius, colors=[40, 40, 40]))]
    for entity, unit in (("mse", "MSE"), ("log10_mse", "log10 MSE")):
        names = [f"best so far ({unit})", f"generation median ({unit})", f"generation worst ({unit})"]
        out.append((entity, rr.SeriesLines(colors=[GREEN, BLUE, RED], names=names, widths=2)))
    return out


def network(controller) -> tuple:
    """GraphNodes and GraphEdges of a controller's network (lab.problem.controllers.network_layout:
    inputs in the first column, hidden nodes by depth, joints in the last; enabled links only)."""
    nodes, links = network_layout(controller)
    columns: dict[int, list] = {}
    for node in nodes:
        columns.setdefault(node.layer, []).append(node)
    pos = {n.key: (d * LAYER_DX, (k - (len(col) - 1) / 2) * NODE_DY) for d, col in columns.items()
           for k, n in enumerate(col)}
    color = {"input": GREEN, "hidden": ORANGE, "output": BLUE}
    ids = [str(n.key) for n in nodes]
    graph = rr.GraphNodes(ids, positions=[pos[n.key] for n in nodes], labels=[n.label for n in nodes],
                          colors=[color[n.kind] for n in nodes], show_labels=True)
    return graph, rr.GraphEdges([(str(a), str(b)) for a, b, _w in links if a in pos and b in pos], graph_type="directed")


def palette(n: int) -> list:
    """n distinct series colours."""
    base = [ORANGE, [150, 70, 200], [30, 160, 170], [200, 60, 120], [110, 110, 40], [90, 90, 90]]
    return [base[k % len(base)] for k in range(n)]


def blueprint(method: MethodView, geo: Geometry | None = None) -> rrb.Blueprint:
    """Arm on the left; error curves (log10 first, linear in a tab), search state and the network
    (a graph method) or the controller's JSON (an MLP method) on the right; the time panel on `generation`.
    With the geometry, the 3D camera frames the workspace (from above for a planar arm)."""
    mse = rrb.Tabs(rrb.TimeSeriesView(origin="/log10_mse", name="log10 training MSE"),
                   rrb.TimeSeriesView(origin="/mse", name="training MSE (linear)"), name="Training error")
    search = rrb.TimeSeriesView(origin="/search", name=method.search_title)
    if method.controller == "graph":
        detail = rrb.GraphView(origin="/network", name="Best network (inputs left, joints right)",
                               force_link=rrb.archetypes.ForceLink(enabled=False),
                               force_many_body=rrb.archetypes.ForceManyBody(enabled=False),
                               force_center=rrb.archetypes.ForceCenter(enabled=False))
    else:
        detail = rrb.TextDocumentView(origin="/controller", name="Best controller (JSON)")
    arm = rrb.Spatial3DView(origin="/world", name="Arm at the best controller, every training goal",
                            eye_controls=_eye(geo) if geo is not None else None)
    left = rrb.Vertical(arm,
                        rrb.TextDocumentView(origin="/about", name="About this recording"), row_shares=[3, 1])
    right = rrb.Vertical(mse, search, detail, row_shares=[2, 1, 2])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[3, 2]),
                         rrb.TimePanel(timeline="generation", expanded=True), collapse_panels=False)


def _eye(geo: Geometry) -> rrb.EyeControls3D:
    lo, hi = (geo.arm.to_3d(b).reshape(-1, 3) for b in geo.arm.workspace_bounds)  # a tree: a box per effector
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    center, size = (lo + hi) / 2, float(np.max(hi - lo))
    planar = len(geo.arm.task_axes) == 2
    offset = np.array([0.0, -0.35, 1.3]) if planar else np.array([0.7, -0.7, 0.55])
    return rrb.EyeControls3D(position=center + size * offset, look_target=center, eye_up=[0.0, 0.0, 1.0])


def about(config: dict, method: MethodView) -> str:
    """The recording's /about text; config: TrainConfig.to_dict()."""
    graph = method.controller == "graph"
    if config.get("seconds") is None:
        budget = f"{config['generations']} generations of {config['population']}"
    else:  # a time budget (lab.running.config: generations UNBOUNDED, 10^9, unless given)
        budget = (f"a time budget of {config['seconds']:g} s of optimizer time, at most {config['generations']:,} "
                  f"generations of {config['population']}")
    return f"""# {config["robot"]} arm, {method.label}, seed {config["seed"]}

Evolution of a neural inverse-kinematics controller ({budget}).

- **3D view**: the arm's meshes at the best controller's joint values for the first training goal,
  the arm as lines for every training goal (grey), the goals (green), the points reached (blue)
  and the errors goal -> reached (red).
  Updated on improvement, at most every few generations. **Population**: every candidate of the
  generation at its reach for the display goal (white), coloured by its training MSE on a log scale
  from the generation's best (dark purple) to its worst (yellow) (`world/population`; by species in
  `world/population_species` for a method with species); every generation up to 100, then every
  10th (the one at or before the time cursor is shown).
- **Training error**: best so far, median and worst (when finite) of each generation, as log10(MSE)
  (Rerun 0.41 has no log axis) and in a second tab on a linear scale.
- **Search**: {method.search_series}.
- **{"Network" if graph else "Controller"}**: {"the best network; inputs left, joint outputs right"
    if graph else "the best controller as JSON (rebuild it with lab.load_controller)"}.

Drag the time cursor (timeline `generation`) to see any generation. The full protocol is in `/protocol`.
"""


def versions() -> dict:
    out = {"python": platform.python_version()}
    for dist in ("neuro-ik-lab", "numpy", "numba", "rerun-sdk", "cma", "neat-python", "pin"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out
