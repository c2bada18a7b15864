"""How pose goals enter a network, and how far an answer is from its pose.

A pose goal is the tool frame as a 4 x 4 transform (robots.pose). A pose network sees its
position through a position `Encoding` (the same features, scaled the same way, as a position
network of the arm: "sphere" on a real arm) followed by its orientation in a continuous form
(robots.pose.pose_features): the 6-D rotation (the first two columns of R, Zhou et al. 2019) on an
arm held to a full pose, the approach axis's direction on the SO arms (whose roll is free). Those
are already in [-1, 1]. The outputs map onto joint values as the position encoding maps them
(margin, clip, continuous joints), and the first joint may be turned in closed form toward the
position's bearing (Encoding.turn): any exact answer has that bearing, and the turn moves the
orientation with it, rigidly about the first joint's axis.

Error of an answer on a pose goal (the pose fitness, lab.problem.pose_fitness):

    e = ||p - p_g||^2 + (L theta)^2

theta the geodesic angle between the tool's rotation and the goal's (an SO arm: the angle between
the approach axes), L = `weight` metres per radian (POSE_WEIGHT x the arm's reach: docs/pose.md,
"Training").

The wrist (`wrist=True`, an arm held to a full pose whose last three joints are revolute): the
network's answers for those three joints are not used; after the turn they are solved in closed
form for the goal's orientation on the frame the other joints leave (pose_kernels' wrist, two
solutions, the nearer kept), so the network places the arm and the wrist turns the tool.

The reach (`reach=k` passes, with the turn; on a full-pose arm with the wrist): after the wrist, the
elbow is solved for the goal's distance from the shoulder, the shoulder for the goal's bearing about
its axis, then the turn and the wrist again; on an arm held to an approach axis whose roll follows
the flex (the SO arms, no wrist) a pass solves every joint: the first joint, the flex, the roll, then
the elbow and the shoulder on the flex's origin, and the flex again; where the wrist's last two axes
meet and its first joint is parallel to the shoulder (the UR arms, the Z1), a pass is exact too (the
first joint from the goal's wrist point, the wrist, the elbow and the shoulder on the first wrist
joint's origin, the wrist again). Each goal keeps the joint values of its best pass. The network's
outputs for those joints only pick the branch (pose_kernels' reach).

`PoseEncoding` carries everything the compiled error needs: the arm's kinematic chain, the tool
frame's rotation in the chain's last joint frame (robots.pose's tool rotation) and the approach
axis. `to_dict()` stores it all, so a pose controller reloads without the arm.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

import robots
from lab.problem import pose_kernels
from lab.problem.encoding import Encoding
from lab.problem.kernels import check_chain

POSE_WEIGHT = 0.1  # L / reach: an angle of 1 rad weighs as an error of a tenth of the arm's reach
# the arms whose pose networks solve the last three joints in closed form: every arm held to a full
# pose (240 s of CMA-ES: the median angle from 57-91 to 0 degrees, refined in 3 steps from 10-21 to
# 58-81 %; docs/pose.md)
WRIST_ARMS: frozenset[str] = frozenset({"ur5", "ur10", "panda", "xarm7", "kinova", "z1"})
# the turn and the wrist twice: the second turn on the solved wrist's tool point (UR5 120 s: 72.8 mm
# against 89.8 with one pass)
WRIST_PASSES = 2
# passes of the closed-form reach (the elbow and the shoulder solved for the goal's position after the
# wrist, then the turn and the wrist again; the SO arms' flex first) on every real arm (240 s of CMA-ES,
# 2,000 held-out poses, passes 3 / 5 / 8: UR5 1.2 / 0.1 / 0.0 mm median, Panda 7.6 / 2.1 / 0.3 mm; SO-100
# with 8: 12.2 mm and 16 degrees -> 0.0 mm and 0.01 degrees; docs/pose.md)
REACH_PASSES: dict[str, int] = {name: 8 for name in (*WRIST_ARMS, "so100", "so101")}
GOALS = ("position", "pose")


def can_reach(arm: robots.Arm) -> bool:
    """Whether a pose network of this arm may have the closed-form reach: an arm held to a full pose with
    the closed-form wrist (WRIST_ARMS), or one held to an approach axis (the SO arms)."""
    from robots import pose

    return arm.name in WRIST_ARMS or pose.approach_axis(arm) is not None


def default_reach(arm: robots.Arm) -> int:
    """The passes of the closed-form reach a pose network of this arm has by default (REACH_PASSES; 0
    where none was measured)."""
    return REACH_PASSES.get(arm.name, 0)


def check_goal(goal) -> str:
    """goal as given when it is one of GOALS; ValueError naming it otherwise."""
    if not isinstance(goal, str) or goal not in GOALS:
        raise ValueError(f"goal must be one of {', '.join(GOALS)}, got {goal!r}")
    return goal


def check_pose_robot(robot) -> None:
    """ValueError, naming the robot and why, unless pose goals can train a network on it (a name or an
    Arm): a real arm (lab.problem.robot.arm_kind "real": a registered real arm, or a serial arm of a
    URDF) whose tool frame robots.pose knows (a full pose, or the SO arms' approach axis)."""
    from lab.problem.robot import arm_kind, load_arm

    arm = load_arm(robot)
    kind = arm_kind(arm)
    if kind != "real":
        what = {"paper": "one of the paper's arms", "snake": "a planar snake", "tree": "a tree of several end effectors"}
        real = ", ".join(n for n in robots.names() if robots.kind(n) == "real")
        raise ValueError(f"goal='pose' is for a real arm ({real}, or a serial arm of a URDF); {arm.name} is "
                         f"{what.get(kind, kind)}")
    from robots import pose

    pose.approach_axis(arm)  # ValueError naming why for an arm without a pose


@dataclass(frozen=True, eq=False)
class PoseEncoding:
    """A pose network's inputs and output mapping, and the compiled pose error (see the module).

    position: the position encoding (inputs of the goal's position, the output mapping, the turn);
    chain: the arm's kinematic arrays (kernels' chain); tool: (3, 3) the tool frame's rotation in
    the chain's last joint frame; axis: (3,) the approach axis in the tool frame (None: a full pose);
    weight: L, metres of error per radian of angle in the fitness."""

    position: Encoding
    chain: tuple
    tool: np.ndarray
    axis: np.ndarray | None
    weight: float
    wrist: bool = False
    wrist_passes: int = 1
    reach: int = 0
    goal = "pose"

    def __post_init__(self):
        if not isinstance(self.position, Encoding) or tuple(self.position.task_axes) != (0, 1, 2):
            raise ValueError("a pose encoding's position part must be a serial arm's Encoding on the axes x, y, z")
        nq = len(self.position.q_lo)
        object.__setattr__(self, "chain", check_chain(self.chain, nq))
        tool = np.ascontiguousarray(np.asarray(self.tool, dtype=np.float64))
        if tool.shape != (3, 3) or not np.all(np.isfinite(tool)) or np.abs(tool.T @ tool - np.eye(3)).max() > 1e-6:
            raise ValueError(f"tool must be a 3 x 3 rotation, got {np.asarray(self.tool).tolist()}")
        object.__setattr__(self, "tool", tool)
        if self.axis is not None:
            axis = np.asarray(self.axis, dtype=np.float64).reshape(-1)
            if axis.shape != (3,) or not np.all(np.isfinite(axis)) or abs(np.linalg.norm(axis) - 1) > 1e-6:
                raise ValueError(f"axis must be a unit 3-vector or None, got {self.axis!r}")
            object.__setattr__(self, "axis", np.ascontiguousarray(axis))
        if not (isinstance(self.weight, (int, float)) and np.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"weight must be a positive number of metres per radian, got {self.weight!r}")
        object.__setattr__(self, "weight", float(self.weight))
        object.__setattr__(self, "wrist", bool(self.wrist))
        if self.wrist_passes not in (1, 2):
            raise ValueError(f"wrist_passes must be 1 or 2, got {self.wrist_passes!r}")
        if isinstance(self.reach, bool) or not isinstance(self.reach, (int, np.integer)) or not 0 <= self.reach <= 16:
            raise ValueError(f"reach must be a number of passes from 0 to 16, got {self.reach!r}")
        if self.reach and not ((self.wrist or self.axis is not None) and self.position.turns):
            raise ValueError("the closed-form reach (shoulder and elbow) needs the turn of the first joint and, on an "
                             "arm held to a full pose, the closed-form wrist: turn=True, wrist=True")
        object.__setattr__(self, "reach", int(self.reach))
        if self.wrist or self.reach:
            object.__setattr__(self, "_closed", self.closed_form_arrays())

    @classmethod
    def for_arm(cls, arm: robots.Arm, features: str = "sphere", margin: float = 0.0, turn: bool = False,
                weight: float | None = None, wrist: bool | None = None, reach: int | None = None) -> "PoseEncoding":
        """The pose encoding of a real arm; weight None: POSE_WEIGHT x the arm's reach; wrist None: the
        closed-form wrist on the arms of WRIST_ARMS; reach None: REACH_PASSES's passes of the closed-form
        shoulder and elbow (0 without the wrist or the turn)."""
        from robots import pose

        axis = pose.approach_axis(arm)  # ValueError for an arm without a pose
        wrist = arm.name in WRIST_ARMS if wrist is None else wrist
        reach = (default_reach(arm) if (wrist or axis is not None) and turn else 0) if reach is None else reach
        return cls(Encoding.for_arm(arm, features, margin, turn), arm.chain.arrays, pose._tool_rotation(arm),
                   None if axis is None else np.array(axis), POSE_WEIGHT * arm.reach_radius if weight is None
                   else weight, wrist, WRIST_PASSES, reach)

    def wrist_arrays(self) -> np.ndarray:
        """The closed-form wrist's constants as pose_kernels' wrist takes them (a flat array): with w
        the first of the last three joints, a2, a3 the second and third joints' axes in joint w's
        frame (C = rot[w + 1] rot[w + 2]: Rz(t1) rot[w + 1] Rz(t2) rot[w + 2] Rz(t3) = Rz(t1) Rot(a2, t2)
        Rot(a3, t3) C), t2 from z . Rot(a2, t2) a3 = A cos t2 + B sin t2 + Cc (phi = atan2(B, A), the
        radius of (A, B)); xv a unit vector across a3; the three joints' limits and whether each
        wraps. ValueError for an arm whose wrist has no such solution."""
        rot, _pos, kind = self.chain[0], self.chain[1], self.chain[2]
        nq = len(rot)
        if self.axis is not None or nq < 6 or np.any(np.asarray(kind)[nq - 3:] != 0):
            raise ValueError("a closed-form wrist needs an arm held to a full pose whose last three joints are "
                             f"revolute (6 or more joints), got {nq} joints"
                             + (" with an approach axis" if self.axis is not None else ""))
        w = nq - 3
        z = np.array([0.0, 0.0, 1.0])
        a2 = rot[w + 1] @ z
        C = rot[w + 1] @ rot[w + 2]
        a3 = C @ z
        A = z @ a3 - (z @ a2) * (a2 @ a3)
        B = z @ np.cross(a2, a3)
        radius = float(np.hypot(A, B))
        if radius < 1e-6:
            raise ValueError("a closed-form wrist needs its second joint's axis across the first's and the third's")
        xv = np.cross(a3, [1.0, 0.0, 0.0])
        if np.linalg.norm(xv) < 1e-6:
            xv = np.cross(a3, [0.0, 1.0, 0.0])
        xv /= np.linalg.norm(xv)
        lo, hi = self.position.q_lo[w:], self.position.q_hi[w:]
        wrap = np.asarray(self.position.wrap, bool)[w:]
        return np.concatenate([[w, np.arctan2(B, A), radius, (z @ a2) * (a2 @ a3)], a2, a3, xv, C.ravel(), lo, hi,
                               wrap.astype(float), [self.wrist_passes]])

    def closed_form_arrays(self) -> np.ndarray:
        """The closed-form joints' constants as pose_kernels take them (spec[4], a flat array): the wrist's
        (wrist_arrays; without the wrist, its first entry -1 and zeros), then the reach's: S, E, F (-1:
        none), the passes, and the three joints' limits and whether each wraps."""
        head = self.wrist_arrays() if self.wrist else np.concatenate([[-1.0], np.zeros(pose_kernels._S - 1)])
        S, E, F = self.reach_joints() if self.reach else (0, 0, -1)
        three = [S, E, max(F, 0)]
        point = self.wrist_point() if self.reach and self.wrist else None
        kind = 0.0 if point is None else 1.0 if point[1] else 3.0 if self._wrist_parallel() else 2.0
        tail = [0.0] * 7 if point is None else \
            [kind, *point[0], *(self.tool.T @ (point[0] - np.asarray(self.chain[4], float)))]
        ends = [0, len(self.position.q_lo) - 1]  # the first joint and the last (an SO arm's exact pass)
        return np.ascontiguousarray(np.concatenate([head, [S, E, F, self.reach], self.position.q_lo[three],
                                                    self.position.q_hi[three],
                                                    np.asarray(self.position.wrap, bool)[three].astype(float),
                                                    tail, self.position.q_lo[ends], self.position.q_hi[ends],
                                                    np.asarray(self.position.wrap, bool)[ends].astype(float)]),
                                    dtype=np.float64)

    def wrist_point(self) -> tuple[np.ndarray, bool] | None:
        """(the point where the wrist's axes meet, in the last joint's frame; whether all three meet
        there) or None: a spherical wrist's centre, which no wrist joint moves (the Kinova's), else the
        point where the last two axes meet, which only the first wrist joint moves (the UR arms' and
        Z1's), else None (the Panda's and xArm7's are 7.6-8.8 cm apart). Within a micrometre, at a
        configuration of general position."""
        lines, frame, point = self._axes(0.3 + 0.4 * np.arange(len(self.chain[0])))  # general position
        lines = lines[-3:]
        for meet, spherical in ((lines, True), (lines[1:], False)):
            A = sum(np.eye(3) - np.outer(w, w) for _, w in meet)
            x = np.linalg.solve(A, sum((np.eye(3) - np.outer(w, w)) @ c for c, w in meet))
            if max(np.linalg.norm((np.eye(3) - np.outer(w, w)) @ (x - c)) for c, w in meet) < 1e-6:
                return frame.T @ (x - point), spherical
        return None

    @property
    def exact_pass(self) -> bool:
        """Whether a pass of the reach solves every joint in closed form (the SO arms: the roll after
        the flex; the UR arms and the Z1: the wrist point's plane), so that the network only picks the
        branch."""
        closed = self.__dict__.get("_closed", np.zeros(0))
        if not self.reach or len(closed) <= pose_kernels._WC:
            return False
        return closed[pose_kernels._WC] == 3.0 or closed[pose_kernels._F] == len(self.position.q_lo) - 2

    def _wrist_parallel(self) -> bool:
        """Whether the first wrist joint's axis is parallel to the shoulder's (the UR arms', the Z1's):
        then the wrist point moves in one plane across them, and a pass of the reach is exact
        (pose_kernels._wrist_point_pass)."""
        lines = self._axes(0.3 + 0.4 * np.arange(len(self.chain[0])))[0]
        return abs(lines[self.reach_joints()[0]][1] @ lines[len(lines) - 3][1]) > 1.0 - 1e-9

    def reach_joints(self) -> tuple[int, int, int]:
        """(S, E, F) of the closed-form reach: the shoulder S, the second joint; the elbow E, the first
        joint after it whose axis is parallel to S's at the zero pose (its turn changes the tool's
        distance from S's axis), before the wrist (a full pose: the last three joints) or the roll (an
        approach axis: the last joint); on an approach-axis arm the flex F, the next such joint (it
        turns the approach axis), else -1. ValueError when the arm has none."""
        kind = np.asarray(self.chain[2])
        end = len(kind) - (3 if self.axis is None else 1)
        axes = [w for _, w in self._axes()[0][:end]]
        parallel = [e for e in range(2, end) if kind[e] == 0 and abs(axes[e] @ axes[1]) > 0.99]
        if end >= 3 and kind[1] == 0 and abs(axes[1] @ axes[0]) < 0.99 and parallel:
            if self.axis is None:
                return 1, parallel[0], -1
            if len(parallel) > 1:
                return 1, parallel[0], parallel[1]
        raise ValueError("a closed-form reach needs a revolute shoulder (the second joint, across the first) and a "
                         "revolute elbow parallel to it before the wrist"
                         + ("" if self.axis is None else ", then a wrist flex parallel to them before the roll"))

    @property
    def turns(self) -> bool:
        """Whether joints() needs the poses: a turned first joint, or the closed-form wrist."""
        return bool(self.position.turns or self.wrist)  # the reach needs the turn

    @property
    def turned_joints(self) -> np.ndarray:
        """The joints solved in closed form, whose network outputs are unused: the turned first joint,
        the wrist's three."""
        joints = list(self.position.turned_joints)
        if self.wrist:
            joints += list(range(len(self.position.q_lo) - 3, len(self.position.q_lo)))
        if self.reach:
            joints += [j for j in self.reach_joints() if j >= 0]
        return np.asarray(sorted(set(joints)), dtype=np.int64)

    @functools.cached_property
    def swept_joints(self) -> tuple[int, ...]:
        """The joints whose values swept() spreads over their ranges, one at a time: the one joint the
        turn, the reach and the wrist leave to the network, where its turn moves the tool point (a
        7-joint arm's redundant joint, the third on the Panda and xArm7; the SO-101's roll, its tool
        point 7.9 mm off the roll's axis), then the shoulder (the reach's S), whose value at the start
        picks the solution the reach's passes settle on. () without the reach."""
        if not self.reach:
            return ()
        free = sorted(set(range(len(self.position.q_lo))) - set(self.turned_joints.tolist()))
        lead = (free[0],) if len(free) == 1 and self._tool_offset(free[0]) > 1e-6 else ()
        return lead + (self.reach_joints()[0],)

    def _tool_offset(self, j: int) -> float:
        """The tool point's distance from joint j's axis at the zero pose [m]."""
        lines, frame, point = self._axes()
        centre, axis = lines[j]
        d = point + frame @ np.asarray(self.chain[4]) - centre
        return float(np.linalg.norm(d - (d @ axis) * axis))

    def _axes(self, q=None) -> tuple[list, np.ndarray, np.ndarray]:
        """(each joint's axis as (a point, its unit direction) in the base frame, the last joint's
        frame's rotation and origin) at joint values q (None: the zero pose), walking the chain as
        pose_kernels do."""
        rot, pos, identity = self.chain[0], self.chain[1], self.chain[3]
        frame, point, lines = np.eye(3), np.zeros(3), []
        for k in range(len(rot)):
            point = point + frame @ np.asarray(pos[k])
            frame = frame if identity[k] else frame @ np.asarray(rot[k])
            lines.append((point.copy(), frame[:, 2].copy()))
            if q is not None:
                c, s_ = np.cos(q[k]), np.sin(q[k])
                frame = frame @ np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
        return lines, frame, point

    def swept(self, q: np.ndarray, poses: np.ndarray, count: int) -> np.ndarray:
        """(joints count k, n, nq): answers q (k, n, nq) with each of the swept joints in turn set to
        count values spread evenly over its range (the middles of count equal parts; at most one turn),
        the closed form then solving the others for each pose (finished). (0, n, nq) without any."""
        q = np.asarray(q, dtype=np.float64)
        if not self.swept_joints or count < 1:
            return np.empty((0, *q.shape[-2:]))
        out = np.repeat(q[None, None], len(self.swept_joints), axis=0).repeat(count, axis=1)  # (J, count, k, n, nq)
        for i, j in enumerate(self.swept_joints):
            lo, hi = self.position.q_lo[j], self.position.q_hi[j]
            if self.position.wrap[j] or hi - lo >= 2 * np.pi:  # a turn holds every direction once
                lo, hi = -np.pi, np.pi
            out[i, ..., j] = (lo + (hi - lo) * (np.arange(count) + 0.5) / count)[:, None, None]
        return self.finished(out.reshape(-1, *q.shape[-2:]), poses)

    # ------------------------------------------------------------ what the position part decides
    def __getattr__(self, name: str):
        """The output mapping's arrays and the turn (q_lo, q_offset, clip_lo, turns, ...) are the
        position encoding's."""
        if name.startswith("__") or name == "position":
            raise AttributeError(name)
        return getattr(self.__dict__["position"] if "position" in self.__dict__ else None, name)

    @property
    def features(self) -> str:
        return self.position.features

    @property
    def task_axes(self) -> tuple[int, ...]:
        return (0, 1, 2)

    @property
    def n_rotation(self) -> int:
        """Inputs of the orientation: 6 (the 6-D rotation) or 3 (the approach axis's direction)."""
        return 6 if self.axis is None else 3

    @property
    def n_inputs(self) -> int:
        return self.position.n_inputs + self.n_rotation

    @property
    def n_outputs(self) -> int:
        return self.position.n_outputs

    @property
    def input_names(self) -> list[str]:
        rot = ["r11", "r21", "r31", "r12", "r22", "r32"] if self.axis is None else ["ax", "ay", "az"]
        return self.position.input_names + rot

    # ------------------------------------------------------------ goals in, joints out
    def check(self, poses) -> np.ndarray:
        """poses (n, 4, 4) as float64, ValueError naming what is wrong (robots.pose.check_poses)."""
        from robots import pose

        return pose.check_poses(poses, what="pose goals")

    def rotation_features(self, poses: np.ndarray) -> np.ndarray:
        """(n, n_rotation): the 6-D rotation (columns 1 and 2 of R, robots.pose.rotation_6d) or R axis."""
        R = poses[:, :3, :3]
        if self.axis is None:
            return np.concatenate([R[:, :, 0], R[:, :, 1]], axis=1)
        return R @ self.axis

    def inputs(self, poses) -> np.ndarray:
        """Poses (n, 4, 4) -> network inputs (n, n_inputs) in about [-1, 1]."""
        poses = self.check(poses)
        position = self.position.compiled_inputs(poses[:, :3, 3])
        return np.concatenate([position, self.rotation_features(poses)], axis=1)

    def joints(self, a: np.ndarray, poses=None) -> np.ndarray:
        """Outputs (..., n, nq) -> joint values (..., n, nq), turned toward each pose's position when the
        encoding turns (then poses are needed)."""
        if not self.turns:
            return self.position.mapped(a)
        if poses is None:
            raise ValueError("this encoding turns the first joint toward each goal's bearing or solves the wrist: "
                             "joints() needs the poses")
        poses = np.asarray(poses, dtype=np.float64)
        if not (self.wrist or self.reach):
            return self.position.joints(a, poses[:, :3, 3])
        return self.finished(self.position.mapped(a), poses)

    def finished(self, q: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Mapped joint values q (..., n, nq) as the fitness answers with them: the first joint turned
        (when the encoding turns), then the wrist solved (when it has one)."""
        q = np.asarray(q, dtype=np.float64)
        QT, GP, GR = self._side_by_side(q, poses)
        pose_kernels.finish_joints(QT, GP, GR, self.chain, self.position.turn_spec, self.spec())
        return QT.T.reshape(q.shape)

    def answers(self, a: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(joints(a, poses), sq_errors of them): outputs (..., n, nq) -> joint values (..., n, nq) and
        their errors (..., n), in one pass of the kernels where the encoding solves the wrist or the
        reach (a controller's proposals on one pose: the chain walked once, not twice)."""
        if not (self.wrist or self.reach):
            q = self.joints(a, poses)
            return q, self.sq_errors(q, poses)
        q = self.position.mapped(a)
        QT, GP, GR = self._side_by_side(q, self.check(poses))
        D, A = np.empty(QT.shape[1]), np.empty(QT.shape[1])
        pose_kernels.finish_joints_errors(QT, GP, GR, self.chain, self.position.turn_spec, self.spec(), D, A)
        e = (D + (self.weight * A) ** 2).reshape(q.shape[:-1])
        return QT.T.reshape(q.shape), np.where(np.isfinite(e), e, np.inf)

    def _side_by_side(self, q: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint values q (..., n, nq) as the kernels take them, (nq, N), with the goals' arrays tiled to
        match (N = every leading row's n goals side by side)."""
        n, nq = q.shape[-2], q.shape[-1]
        QT = np.ascontiguousarray(q.reshape(-1, nq).T)
        GP, GR = self.goal_arrays(poses)
        reps = QT.shape[1] // max(n, 1)
        if reps == 1:
            return QT, GP, GR
        return QT, np.ascontiguousarray(np.tile(GP, (1, reps))), np.ascontiguousarray(np.tile(GR, (1, reps)))

    def mapped(self, a: np.ndarray) -> np.ndarray:
        return self.position.mapped(a)

    # ------------------------------------------------------------ errors
    def spec(self) -> tuple:
        """The pose error's arrays as the pose kernels take them: (tool, axis in the last joint frame,
        mode (0 full pose, 1 approach axis), L^2)."""
        axis_j = np.zeros(3) if self.axis is None else np.ascontiguousarray(self.tool @ self.axis)
        return (self.tool, axis_j, 0 if self.axis is None else 1, self.weight ** 2,
                self.__dict__.get("_closed", np.zeros(0)))

    def goal_arrays(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (3, n), orientations (9, n) row-major R or (3, n) approach directions) as the
        kernels take the goals."""
        poses = np.asarray(poses, dtype=np.float64)
        GP = np.ascontiguousarray(poses[:, :3, 3].T)
        if self.axis is None:
            GR = np.ascontiguousarray(poses[:, :3, :3].reshape(-1, 9).T)
        else:
            GR = np.ascontiguousarray((poses[:, :3, :3] @ self.axis).T)
        return GP, GR

    def errors(self, q: np.ndarray, poses) -> tuple[np.ndarray, np.ndarray]:
        """(position error [m], angle [rad]) of joint values q (..., n, nq) on poses (n, 4, 4), each
        (..., n), by the compiled kinematics the fitness uses (no turn: q as given)."""
        poses = self.check(poses)
        q = np.asarray(q, dtype=np.float64)
        lead, n = q.shape[:-2], q.shape[-2]
        QT, GP, GR = self._side_by_side(q, poses)
        D, A = np.empty(QT.shape[1]), np.empty(QT.shape[1])
        pose_kernels.pose_parts(QT, GP, GR, self.chain, self.spec(), D, A)
        return np.sqrt(D).reshape(*lead, n), A.reshape(*lead, n)

    def sq_errors(self, q: np.ndarray, poses) -> np.ndarray:
        """(..., n) the fitness's error of each answer: ||p - p_g||^2 + (L angle)^2 (inf where not finite)."""
        d, a = self.errors(q, poses)
        e = d * d + (self.weight * a) ** 2
        return np.where(np.isfinite(e), e, np.inf)

    # ------------------------------------------------------------ storage
    def to_dict(self) -> dict:
        return {"goal": "pose", "position": self.position.to_dict(),
                "chain": dict(zip(("rot", "pos", "kind", "identity", "ee_pos"),
                                  (np.asarray(x).tolist() for x in self.chain))),
                "tool": self.tool.tolist(), "axis": None if self.axis is None else self.axis.tolist(),
                "weight": self.weight, **({"wrist": True, "wrist_passes": self.wrist_passes} if self.wrist else {}),
                **({"reach": self.reach} if self.reach else {})}

    @classmethod
    def from_dict(cls, d: dict) -> "PoseEncoding":
        if d.get("goal") != "pose":
            raise ValueError(f"not a pose encoding: its goal is {d.get('goal')!r}")
        return cls(Encoding.from_dict(d["position"]), d["chain"], np.asarray(d["tool"], dtype=np.float64),
                   d.get("axis"), d["weight"], bool(d.get("wrist", False)), int(d.get("wrist_passes", 1)),
                   int(d.get("reach", 0)))
