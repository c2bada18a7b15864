"""Arms and the shared scene, drawn in viser from the arm's Pinocchio model.

An `ArmView` is one drawn arm: a frame node per joint, placed at the joint's world pose
data.oMi[j], and under it one node per visual geometry at its placement in that joint
(meshes as triangle meshes taken from the geometry's BVH, so .dae files need no extra
loader; boxes, cylinders and spheres as viser primitives). Moving the arm to q sends nq
poses, whatever the number of meshes.

The joint frames keep their names ({name}/j{j}: what the tests and the probe follow); each
geometry's name carries a number of its own view ({name}/j{j}/g{i}-{view}), so that an arm drawn
where another was (another robot, a goal removed and added again) never re-creates a mesh under a
name the browser still holds: viser folds a removal and a creation of one name that meet in a
tab's queue into the creation alone, and its client, given a mesh again under a frame that is
itself given again, drew the mesh away from its arm (after the planar arm, the g1's pelvis on the
floor below its feet).

`frame_workspace` gives the camera, floor grid and marker limits of an arm; `shown_goals` the
training goals the scene draws (a run trains on all of them).
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pinocchio as pin

import robots
from app.viser_private import set_pose
from robots.visual import se3_pose, visual_geometry

_VIEWS = itertools.count()  # each ArmView's number, in its geometries' names
# red dots the scene draws of the training goals at most (a tree's goal is a dot per effector): a
# humanoid's 600 goals x 4 effectors crowd the robot out of view; the eye reads a cloud's extent
# from a few hundred. More goals: an even sample of them, every effector's dot of each kept goal
MAX_GOAL_DOTS = 400


def shown_goals(points: np.ndarray, effectors: int = 1, limit: int = MAX_GOAL_DOTS) -> np.ndarray:
    """The dots drawn of the training goals (points: (goals x effectors, 3), goal by goal, each
    goal's effectors together): all of them up to `limit`, else evenly spaced goals whose dots
    number at most `limit` (at least one goal)."""
    points = np.asarray(points).reshape(-1, effectors, 3)
    n = len(points)
    keep = max(1, limit // effectors)
    if n > keep:
        points = points[np.unique(np.linspace(0, n - 1, keep).round().astype(int))]
    return points.reshape(-1, 3)


class ArmView:
    """One arm drawn under `name` in a viser scene (server.scene or client.scene); scale and offset: drawn
    at offset + scale x its own coordinates (a robot drawn beside another of another size; viser's
    frames do not scale their children, so each joint's place and each geometry are scaled here)."""

    def __init__(self, scene, arm: robots.Arm, name: str, *, opacity: float | None = None,
                 tint: tuple[int, int, int] | None = None, scale: float = 1.0, offset=(0.0, 0.0, 0.0)):
        self.arm, self.name, self.scene = arm, name, scene
        self.scale, self.offset = float(scale), np.asarray(offset, dtype=np.float64)
        self.data = arm.model.createData()
        joints = sorted({j for j, *_ in visual_geometry(arm)} | set(range(1, arm.model.njoints)))
        self.frames = {j: scene.add_frame(f"{name}/j{j}", show_axes=False, position=self.offset) for j in joints}
        view = next(_VIEWS)
        for i, (j, pos, wxyz, kind, params, rgba) in enumerate(visual_geometry(arm)):
            color = tuple(int(255 * c) for c in rgba[:3]) if tint is None else tint
            kw = dict(position=self.scale * np.asarray(pos, np.float64), wxyz=wxyz, opacity=opacity,
                      cast_shadow=opacity is None)
            if self.scale != 1.0:
                kw["scale"] = self.scale
            node = f"{name}/j{j}/g{i}-{view}"
            if kind == "Box":
                scene.add_box(node, color=color, dimensions=params[0], **kw)
            elif kind == "Cylinder":
                scene.add_cylinder(node, radius=params[0], height=params[1], color=color, **kw)
            elif kind == "Sphere":
                scene.add_icosphere(node, radius=params[0], color=color, subdivisions=2, **kw)
            else:
                scene.add_mesh_simple(node, params[0], params[1], color=color, **kw)
        self._add_capsules(scene, name, view, opacity, tint)
        self.moving = {j: f for j, f in self.frames.items() if j > 0}  # joint 0 is the fixed base
        self.q = None

    def _add_capsules(self, scene, name: str, view: int, opacity, tint) -> None:
        """A capsule per chain link with nothing to draw (no visual, or a mesh that does not resolve: a URDF
        of your own), from its joint to the next (app/any_robot.py capsules), named {name}/j{j}/c{k}-{view}."""
        from app.any_robot import capsule_note, capsule_radius, capsules

        segments = capsules(self.arm)
        if not segments:
            return
        capsule_note(self.arm)  # the log says which, once
        r = self.scale * capsule_radius(self.arm)
        color = (150, 155, 165) if tint is None else tint
        kw = dict(color=color, opacity=opacity, cast_shadow=opacity is None)
        for k, (j, p0, p1) in enumerate(segments):
            a, b = self.scale * p0, self.scale * p1
            length = float(np.linalg.norm(b - a))
            node = f"{name}/j{j}/c{k}-{view}"
            scene.add_icosphere(f"{node}a", radius=r, subdivisions=2, position=a, **kw)
            if length > 1e-9:  # a cylinder along z, turned onto the segment, and its far end's cap
                z = (b - a) / length
                wxyz = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), z).coeffs()  # xyzw
                scene.add_cylinder(f"{node}s", radius=r, height=length, position=0.5 * (a + b),
                                   wxyz=(wxyz[3], wxyz[0], wxyz[1], wxyz[2]), **kw)
                scene.add_icosphere(f"{node}b", radius=r, subdivisions=2, position=b, **kw)

    def set_q(self, q) -> None:
        """Move the drawn arm to joint values q (nq,): one pose message per joint."""
        q = np.asarray(q, dtype=np.float64)
        pin.forwardKinematics(self.arm.model, self.data, self.arm.to_pinocchio(q))
        scaled = self.scale != 1.0 or self.offset.any()
        for j, frame in self.moving.items():
            position, wxyz = se3_pose(self.data.oMi[j])
            set_pose(frame, self.offset + self.scale * position if scaled else position, wxyz)
        self.q = q

    @property
    def visible(self) -> bool:
        return next(iter(self.frames.values())).visible

    @visible.setter
    def visible(self, value: bool) -> None:
        for frame in self.frames.values():
            frame.visible = bool(value)

    def remove(self) -> None:
        for frame in self.frames.values():
            frame.remove()


def to_world(arm: robots.Arm, goal) -> np.ndarray:
    """Task coordinates (len(task_axes),) -> a 3D point (other coordinates 0); a tree's goal
    (E, len(task_axes)) -> (E, 3)."""
    return arm.to_3d(goal)


@functools.lru_cache(maxsize=16)
def body_bounds(arm: robots.Arm) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) of the arm's visual geometry at rest: its meshes' vertices, its primitives'
    centres (a tree's body: a humanoid's torso and head stand far above its feet's workspace)."""
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, arm.to_pinocchio(arm.rest))
    points = [np.zeros((1, 3))]
    for j, pos, wxyz, kind, params, _rgba in visual_geometry(arm):
        M = data.oMi[j]
        local = params[0].astype(np.float64) if kind == "Mesh" else np.zeros((1, 3))
        R = pin.Quaternion(float(wxyz[0]), float(wxyz[1]), float(wxyz[2]), float(wxyz[3])).toRotationMatrix()
        points.append((local @ R.T + pos) @ M.rotation.T + M.translation)
    points = np.concatenate(points)
    return points.min(axis=0), points.max(axis=0)


def frame_workspace(arm: robots.Arm) -> dict:
    """Camera, floor and goal-marker limits for an arm, from its workspace bounds (a tree's: the box
    around all its effectors' boxes and its body at rest for the camera and floor, each effector's
    own box for its marker).

    limits: one (x, y, z) range triple per end effector; gizmo: the markers' size (on a tree at most
    0.8 x the smallest distance between two effectors at rest, so a hand's fingertips keep apart);
    point: the population's point size; label_offset: from a goal's marker to its label's bottom right
    corner, up and to the left (screen right is about +x in every camera view here), so that the
    label's text runs away from the panel on the right of the page."""
    lo3, hi3 = (arm.to_3d(b).reshape(-1, 3) for b in arm.workspace_bounds)  # (E, 3) each
    box_lo, box_hi = lo3.min(axis=0), hi3.max(axis=0)
    if arm.is_tree:  # the camera and floor take in the whole robot, not only where its effectors go
        body_lo, body_hi = body_bounds(arm)
        box_lo, box_hi = np.minimum(box_lo, body_lo), np.maximum(box_hi, body_hi)
    size = float(np.max((box_hi - box_lo)[list(arm.task_axes)]))
    center = 0.5 * (box_lo + box_hi)
    margin = 0.25 * (hi3 - lo3)  # markers may leave the workspace: unreachable goals are allowed
    limits = [tuple((float(a - m), float(b + m)) if k in arm.task_axes else (0.0, 0.0)
                    for k, (a, b, m) in enumerate(zip(lo, hi, mg))) for lo, hi, mg in zip(lo3, hi3, margin)]
    floor_z = float(box_lo[2] - 0.08 * size) if 2 in arm.task_axes else -0.12 * size
    if arm.is_tree:  # the floor under its body at rest: a humanoid's, a biped's, a quadruped's soles on it
        floor_z = float(body_bounds(arm)[0][2])
    gizmo, point, view = 0.2 * size, 0.015 * size, np.array([-0.15, -0.75, 0.65])
    if arm.is_tree:
        rest = arm.fk(arm.rest)  # (E, 3)
        apart = np.linalg.norm(rest[:, None] - rest[None], axis=-1)[np.triu_indices(len(rest), 1)]
        gizmo = min(gizmo, 0.8 * float(apart.min()))
        point = 0.4 * point  # E points per candidate: smaller, so that the feet and fingers still show
        view = np.array([0.35, -0.8, 0.4])  # lower and more from the front: a standing robot, a hand
    return dict(
        center=center, size=size, limits=limits, floor_z=floor_z, label_offset=np.array([-0.03, 0.03, 0.03]) * size,
        camera=center + size * view, cell=10 ** np.floor(np.log10(size / 4)), gizmo=gizmo, point=point,
    )
