"""What the Rerun logger draws: the arm's poses, the NEAT network, the static scene, the blueprint.

Pure functions from lab objects to Rerun archetypes; lab/recording.py decides when to log them.
Goals of a planar arm (task_axes (0, 1)) are drawn at z = 0.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass
from importlib import metadata

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import robots

GREEN, BLUE, RED, GREY, ORANGE = [40, 170, 60], [60, 110, 220], [220, 60, 50], [150, 150, 150], [240, 150, 30]
LAYER_DX, NODE_DY = 160.0, 70.0  # network layout, in the graph view's units


@dataclass(frozen=True)
class Geometry:
    """The arm and its training goals in 3D, with line widths scaled to the workspace."""

    arm: robots.Arm
    goals: np.ndarray  # (n, len(task_axes)) as the problem has them
    goals3: np.ndarray  # (n, 3)
    radius: float  # a thin line, in the arm's length unit

    def __init__(self, arm: robots.Arm, goals: np.ndarray):
        goals = np.asarray(goals, dtype=np.float64)
        lo, hi = arm.workspace_bounds
        object.__setattr__(self, "arm", arm)
        object.__setattr__(self, "goals", goals)
        object.__setattr__(self, "goals3", to_3d(goals, arm.task_axes))
        object.__setattr__(self, "radius", 0.003 * float(np.max(hi - lo)))


def to_3d(points: np.ndarray, task_axes) -> np.ndarray:
    """Task coordinates (n, len(task_axes)) -> (n, 3), zeros on the other axes."""
    out = np.zeros((len(points), 3))
    out[:, list(task_axes)] = points
    return out


def pose(geo: Geometry, controller) -> dict:
    """The arm at controller(goal) for every training goal, the points reached, and the errors."""
    q = controller(geo.goals)  # (n, nq)
    strips = geo.arm.joint_positions(q).astype(np.float32)  # (n, nq + 2, 3); float32 converts 2x faster
    reached = to_3d(geo.arm.reach(q), geo.arm.task_axes)
    r = geo.radius
    return {
        "world/arm": rr.LineStrips3D(strips, radii=0.6 * r, colors=[*GREY, 110]),
        "world/reached": rr.Points3D(reached, radii=2.5 * r, colors=BLUE),
        "world/errors": rr.Arrows3D(origins=geo.goals3, vectors=reached - geo.goals3, radii=0.7 * r, colors=RED),
    }


def static_scene(geo: Geometry, method: str) -> list:
    """Logged once: axes convention, goals, series styles."""
    out = [("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP),
           ("world/goals", rr.Points3D(geo.goals3, radii=3.0 * geo.radius, colors=GREEN)),
           ("world/base", rr.Points3D([[0.0, 0.0, 0.0]], radii=5.0 * geo.radius, colors=[40, 40, 40]))]
    for entity, unit in (("mse", "MSE"), ("log10_mse", "log10 MSE")):
        names = [f"best so far ({unit})", f"generation median ({unit})", f"generation worst ({unit})"]
        out.append((entity, rr.SeriesLines(colors=[GREEN, BLUE, RED], names=names, widths=2)))
    return out


def network(controller) -> tuple:
    """GraphNodes and GraphEdges of a NEAT genome (enabled connections), laid out in layers:
    inputs at x = 0, hidden nodes at their longest-path depth, outputs in the last column."""
    g = controller.genome
    inputs, outputs = list(controller.input_keys), list(controller.output_keys)
    hidden = [k for k, _ in g["nodes"] if k not in outputs]
    edges = [(i, o) for i, o, _, enabled in g["connections"] if enabled]
    depth = {k: 0 for k in inputs}
    for _ in range(len(hidden) + 1):  # longest path, relaxed (the genome is feed-forward)
        for i, o in edges:
            if o in hidden and i in depth:
                depth[o] = max(depth.get(o, 1), depth[i] + 1)
    for k in hidden:
        depth.setdefault(k, 1)
    last = max([depth[k] for k in hidden], default=0) + 1
    depth.update({k: last for k in outputs})
    names = controller.encoding.input_names
    label = {k: names[n] for n, k in enumerate(inputs)} | {k: f"q{n}" for n, k in enumerate(outputs)}
    keys = inputs + hidden + outputs
    columns: dict[int, list] = {}
    for k in keys:
        columns.setdefault(depth[k], []).append(k)
    pos = {k: (d * LAYER_DX, (n - (len(col) - 1) / 2) * NODE_DY) for d, col in columns.items() for n, k in enumerate(col)}
    color = {k: GREEN for k in inputs} | {k: ORANGE for k in hidden} | {k: BLUE for k in outputs}
    ids = [str(k) for k in keys]
    nodes = rr.GraphNodes(ids, positions=[pos[k] for k in keys], labels=[label.get(k, f"h{k}") for k in keys],
                          colors=[color[k] for k in keys], show_labels=True)
    return nodes, rr.GraphEdges([(str(i), str(o)) for i, o in edges if i in pos and o in pos], graph_type="directed")


def palette(n: int) -> list:
    """n distinct series colours."""
    base = [ORANGE, [150, 70, 200], [30, 160, 170], [200, 60, 120], [110, 110, 40], [90, 90, 90]]
    return [base[k % len(base)] for k in range(n)]


def blueprint(method: str, geo: Geometry | None = None) -> rrb.Blueprint:
    """Arm on the left; error curves (log10 first, linear in a tab), search state and the network
    (NEAT) or the controller's JSON (CMA-ES) on the right; the time panel on `generation`.
    With the geometry, the 3D camera frames the workspace (from above for a planar arm)."""
    mse = rrb.Tabs(rrb.TimeSeriesView(origin="/log10_mse", name="log10 training MSE"),
                   rrb.TimeSeriesView(origin="/mse", name="training MSE (linear)"), name="Training error")
    search = rrb.TimeSeriesView(origin="/search", name="CMA-ES step size and restarts" if method == "cmaes"
                                else "NEAT species and best network size")
    if method == "neat":
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
    lo, hi = (to_3d(b[None, :], geo.arm.task_axes)[0] for b in geo.arm.workspace_bounds)
    center, size = (lo + hi) / 2, float(np.max(hi - lo))
    planar = len(geo.arm.task_axes) == 2
    offset = np.array([0.0, -0.35, 1.3]) if planar else np.array([0.7, -0.7, 0.55])
    return rrb.EyeControls3D(position=center + size * offset, look_target=center, eye_up=[0.0, 0.0, 1.0])


def about(config) -> str:
    return f"""# {config.robot} arm, {config.method}, seed {config.seed}

Evolution of a neural inverse-kinematics controller ({config.generations} generations of {config.population}).

- **3D view**: the arm at the best controller's joint values for every training goal (grey),
  the goals (green), the points reached (blue) and the errors goal -> reached (red).
  Updated on improvement, at most every few generations.
- **Training error**: best so far, median and worst (when finite) of each generation, as log10(MSE)
  (Rerun 0.41 has no log axis) and in a second tab on a linear scale.
- **Search**: {"CMA-ES step size sigma and the number of restarts" if config.method == "cmaes"
               else "number of species, nodes and enabled connections of the best genome"}.
- **{"Network" if config.method == "neat" else "Controller"}**: {"the best genome; inputs left, joint outputs right"
    if config.method == "neat" else "the best controller as JSON (rebuild it with lab.load_controller)"}.

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
