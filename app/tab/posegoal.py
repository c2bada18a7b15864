"""Pose goals in the app: which arms take them, a gizmo's pose as a 4 x 4 goal, its errors in words.

In pose mode (the Train panel's *Goal*, `python -m app --goal pose`) a goal is the arm's tool frame:
each goal gizmo turns as well as moves, and the goal is the 4 x 4 transform of the gizmo's position
and orientation (robots.pose: position and full orientation on a 6- or 7-joint arm, position and the
gripper's approach direction on the 5-joint SO arms). The arm shows a pose controller's answer
(a controller that declares `goal = "pose"` and answers (n, 4, 4) poses with (n, nq) joints): the
arm's shipped one, app/pretrained/<robot>-pose-<method>.json, when there is one, else the run's.
Until one exists the arm shows `PositionSeed`, the arm's position network on the goal's position
(it ignores the turn, and says so), and the refined ghost makes either exact.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pinocchio as pin

import robots
from robots import pose

GOALS = ("position", "pose")
GOAL_LABELS = {"Position": "position", "Pose": "pose"}  # the panel's Goal menu


def goal_label(kind: str) -> str:
    return next(label for label, k in GOAL_LABELS.items() if k == kind)


@functools.lru_cache(maxsize=None)
def takes_poses(robot: str) -> bool:
    """Whether `robot` takes pose goals (the Train panel shows its Goal menu only then)."""
    return pose_refusal(robot) is None


def pose_refusal(robot: str) -> str | None:
    """Why `robot` takes no pose goals (a line naming it), or None for one that does: the real arms
    (robots.kind "real") and a robot of your own with a serial chain of 5-7 joints (kind "custom"), whose
    tool frame robots.pose holds (robots.pose.approach_axis)."""
    try:
        kind = robots.kind(robot)
    except Exception as e:  # noqa: BLE001 - an unknown robot: its own message
        return f"pose goals: {e}"
    if kind == "custom":  # a robot of your own (erd:NAME, a URDF): a serial chain of 5-7 joints, as TRAC-IK's
        arm = robots.load(robot)
        if arm.is_tree or not 5 <= arm.nq <= 7:
            return (f"pose goals are for serial chains of 5 to 7 joints; the {arm.name} has "
                    f"{f'{arm.n_effectors} end effectors' if arm.is_tree else f'{arm.nq} joints'}: positions only")
    elif kind != "real":
        real = ", ".join(n for n in robots.names() if robots.kind(n) == "real")
        return (f"pose goals are for the real arms ({real}); the {robot} is a {kind} robot, whose goals "
                "are positions only")
    try:
        pose.approach_axis(robots.load(robot))
    except ValueError as e:
        return f"pose goals: {e}"
    return None


def goal_kind(controller) -> str:
    """"pose" for a controller that declares `goal = "pose"`, else "position" (as lab.solve)."""
    return "pose" if getattr(controller, "goal", "position") == "pose" else "position"


def wxyz_to_matrix(wxyz) -> np.ndarray:
    """(3, 3) rotation of a quaternion (w, x, y, z), normalized first (a gizmo's float32 quaternion)."""
    q = np.asarray(wxyz, dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"a goal's orientation must be a nonzero quaternion (w, x, y, z), got {q.tolist()}")
    w, x, y, z = q / n
    return pin.Quaternion(w, x, y, z).toRotationMatrix()


def matrix_to_wxyz(R) -> np.ndarray:
    """(4,) quaternion (w, x, y, z) of a rotation matrix."""
    c = pin.Quaternion(np.asarray(R, dtype=np.float64)).coeffs()  # (x, y, z, w)
    return np.array([c[3], c[0], c[1], c[2]])


def gizmo_pose(position, wxyz) -> np.ndarray:
    """(4, 4) the goal of a gizmo at `position` turned by `wxyz`."""
    T = np.eye(4)
    T[:3, :3] = wxyz_to_matrix(wxyz)
    T[:3, 3] = np.asarray(position, dtype=np.float64)
    return T


def fmt_angle(angle: float) -> str:
    """An angle [rad] in degrees (below 0.1 degree with two digits, so a refined answer does not read as 0;
    below 1e-6 degree, rounding's noise: 0, as a closed-form wrist's answer reads)."""
    if not np.isfinite(angle):
        return "∞"
    d = math.degrees(angle)
    if d < 1e-6:
        return "0°"
    return f"{d:.1f}°" if d >= 0.1 else f"{d:.2g}°"


def default_pose(arm: robots.Arm, k: int, seed: int) -> np.ndarray:
    """Goal k's starting pose: the tool frame of the joint vector that arm.sample_goals(k + 1, seed)[k]
    came from (robots.pose.sample_poses), so its position is that goal."""
    return pose.sample_poses(arm, k + 1, seed=seed)[k]


def errors(arm: robots.Arm, T, q) -> tuple[float, float]:
    """(position error [m], angle error [rad]) of joints q (nq,) for the pose goal T (4, 4)."""
    p, a = pose.pose_errors(arm, np.asarray(T)[None], np.asarray(q)[None])
    return float(p[0]), float(a[0])


class PositionSeed:
    """Stands in for a pose controller where none is trained yet: the arm's position controller on the
    pose goal's position (it ignores the turn; refinement then makes the answer exact)."""

    goal = "pose"

    def __init__(self, position_controller):
        self.position = position_controller
        self.encoding = getattr(position_controller, "encoding", None)
        self.chain = getattr(position_controller, "chain", None)

    def __call__(self, poses) -> np.ndarray:
        T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        return self.position(T[:, :3, 3])

    def proposals(self, poses) -> np.ndarray:
        from lab.problem.controllers import proposals

        T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        return proposals(self.position, T[:, :3, 3])
