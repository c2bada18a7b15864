"""Pose goals: where the tool is and how it is turned, as (n, 4, 4) homogeneous transforms.

A pose is the arm's tool frame (`arm.ee_frame`) in the base frame, Pinocchio's `SE3.homogeneous`:

    T = [[R, p],        R (3, 3) a rotation (orthonormal, det +1), p (3,) the frame's origin
         [0, 1]]

    import robots
    from robots import pose
    arm = robots.load("ur5")
    T = pose.sample_poses(arm, 100, seed=0)       # (100, 4, 4) of uniformly random joint vectors
    T = pose.fk_pose(arm, q)                      # (..., nq) -> (..., 4, 4)
    J = pose.pose_jacobian(arm, q)                # (..., nq) -> (..., 6, nq): linear rows, then angular
    pose.check_poses(T)                           # ValueError naming a bad pose (shape, NaN, not a rotation)
    pose.rotation_angle(Ra, Rb)                   # geodesic angle between rotations [rad]
    pose.rotation_6d(R)                           # (..., 3, 3) -> (..., 6): first two columns (Zhou et al. 2019)
    pose.pose_errors(arm, T, q)                   # (position error [length], angle error [rad]) per goal

The Jacobian's convention is Pinocchio's LOCAL_WORLD_ALIGNED at the tool frame: rows 0-2 are the
velocity of the tool frame's origin, rows 3-5 its angular velocity, both in the base frame's axes
(`pinocchio.computeFrameJacobian(model, data, q, arm.ee_frame_id, LOCAL_WORLD_ALIGNED)`; the arm's
chain has one velocity per coordinate, so its columns are d/dq of the arm's own coordinates).

Which constraints a pose makes (`approach_axis`): an arm of 6 or more joints is held to all six
(position and full orientation). A 5-joint arm cannot turn its tool every way; for the SO-100 and
SO-101 a pose is the position and the direction of the gripper's approach axis (5 constraints), the
roll about that axis left free: APPROACH_AXES names that axis in the tool frame, read off the
URDFs' gripper geometry (docs/pose.md). The angle error is then the angle between the tool's
approach axis and the goal's.

Nothing here knows about networks.
"""

from __future__ import annotations

import math
import weakref

import numba
import numpy as np
import pinocchio as pin

from robots import registry
from robots.arm import Arm
from robots.kinematics import tree_points

# The approach axis, in the tool frame, of each 5-joint arm whose pose leaves the roll free: the
# direction from the wrist toward the fingertips, which is the wrist-roll joint's axis.
#   so100: its tool frame "gripper" is the gripper link's frame, at the wrist-roll joint; the roll
#          turns about its y axis, and the fixed jaw (Fixed_Jaw.stl) reaches from y = 0 to y = -106 mm,
#          the moving jaw's hinge sits at y = -24 mm: the fingers point along -y.
#   so101: its tool frame "gripper_frame_link" sits 98 mm past the wrist-roll joint, between the
#          fingertips, turned half a turn about y from the gripper link, whose z the roll turns about
#          and along whose -z the jaw (wrist_roll_follower_so101_v1.stl) reaches 105 mm: +z of the tool frame.
# approach_axis returns the roll joint's own axis in the tool frame, with the sign given here: so101's
# URDF turns its tool frame by 3.14159 rad, not pi, which leaves its +z 2.7e-6 rad off the roll axis.
APPROACH_AXES: dict[str, tuple[float, float, float]] = {
    "so100": (0.0, -1.0, 0.0),
    "so101": (0.0, 0.0, 1.0),
}
FULL_POSE_JOINTS = 6  # an arm of at least this many joints is held to a full pose
APPROACH_JOINTS = 5  # an arm of this many joints is held to its approach axis (the last joint's), roll free
DEFAULT_ANGLE_TOL = math.radians(0.1)  # a pose's angle tolerance [rad]: 0.1 degree
ORTHONORMAL_ATOL = 1e-6  # how far R^T R may be from I (largest entry) and the last row from (0, 0, 0, 1)
AXIS_AGREEMENT = 1e-3  # rad: how far APPROACH_AXES may be from the last joint's axis


# ---------------------------------------------------------------- what a pose constrains
def _check_pose_arm(arm: Arm) -> None:
    """ValueError, naming why, for an arm that takes no pose goals: a tree (several end effectors),
    an arm whose goals are not 3-D (the planar arms), one of fewer than 6 joints with no approach axis."""
    if arm.is_tree:
        raise ValueError(f"{arm.name} has {arm.n_effectors} end effectors ({', '.join(arm.effectors)}): "
                         "pose goals are for a serial arm's one tool frame")
    if tuple(arm.task_axes) != (0, 1, 2):
        raise ValueError(f"{arm.name}: its goals are on task axes {tuple(arm.task_axes)}; a pose is a 3-D "
                         "position and orientation (task axes (0, 1, 2))")
    if arm.nq < APPROACH_JOINTS:
        raise ValueError(f"{arm.name} has {arm.nq} joints: a full pose needs {FULL_POSE_JOINTS}, and a pose held "
                         f"to an approach axis (the last joint's, its roll left free) {APPROACH_JOINTS}")


_approach_axes = weakref.WeakKeyDictionary()


def approach_axis(arm: Arm) -> np.ndarray | None:
    """The unit tool-frame axis whose direction a pose of this arm holds, the roll about it free:
    for a 5-joint arm, the last joint's (the wrist roll's) axis in the tool frame, pointing toward the
    fingers (the SO arms: the sign APPROACH_AXES gives; any other: from the last joint's origin toward
    the tool's, where they are apart along it); None for an arm held to a full pose (6 joints or more).
    ValueError, naming why, for an arm that takes no pose goals (_check_pose_arm), a last joint that
    does not turn (prismatic), or when the last joint's axis is not the one APPROACH_AXES names."""
    _check_pose_arm(arm)
    if arm.nq >= FULL_POSE_JOINTS:
        return None
    axis = _approach_axes.get(arm)
    if axis is None:
        data = arm.model.createData()
        q = arm.to_pinocchio(arm.rest)
        J = pin.computeFrameJacobian(arm.model, data, q, arm.ee_frame_id, pin.LOCAL)
        turn = np.linalg.norm(J[3:, -1])
        if turn < 1e-9:
            raise ValueError(f"{arm.name}: its last joint does not turn the tool (a prismatic joint?), so it has no "
                             "approach axis to hold a 5-joint pose to; use position goals, or a tool frame of a "
                             "chain that ends in a revolute joint")
        roll = J[3:, -1] / turn  # the last joint's axis in the tool frame
        registered = _registered_axis(arm)
        if registered is not None:
            nominal = np.asarray(registered, dtype=np.float64)
        else:  # toward the tool: the tool's origin seen from the last joint's, in the tool frame
            pin.framesForwardKinematics(arm.model, data, q)
            tool = data.oMf[arm.ee_frame_id]
            ahead = tool.rotation.T @ (tool.translation - data.oMi[arm.model.njoints - 1].translation)
            nominal = roll if abs(ahead @ roll) < 1e-9 else ahead
        nominal = nominal / np.linalg.norm(nominal)
        roll = roll if roll @ nominal >= 0 else -roll
        if registered is not None and math.atan2(np.linalg.norm(np.cross(roll, nominal)), roll @ nominal) > AXIS_AGREEMENT:
            raise ValueError(f"{arm.name}: the approach axis {nominal.tolist()} of robots.pose.APPROACH_AXES is not "
                             f"its last joint's axis {np.round(roll, 6).tolist()} (in the tool frame)")
        axis = _approach_axes[arm] = roll
        axis.flags.writeable = False
    return axis


def _registered_axis(arm: Arm) -> tuple[float, float, float] | None:
    """APPROACH_AXES' sign for a registered SO arm, also when loaded by its example-robot-data name
    with the registry's tool frame ("erd:so100")."""
    if arm.name in APPROACH_AXES:
        return APPROACH_AXES[arm.name]
    source = (arm.source or "").partition("#")[0]
    if source.startswith("erd:"):
        for name, axis in APPROACH_AXES.items():
            spec = registry.SPECS[name]
            if spec.erd == source[len("erd:"):] and arm.effectors == (spec.ee_frame,):
                return axis
    return None


def pose_dims(arm: Arm) -> int:
    """How many constraints a pose of this arm makes: 6 (a full pose), 5 (position and approach axis)."""
    return 6 if approach_axis(arm) is None else 5


# ---------------------------------------------------------------- batched forward kinematics
_tool_rotations = weakref.WeakKeyDictionary()


def _tool_rotation(arm: Arm) -> np.ndarray:
    """(3, 3) the tool frame's rotation in the frame of its joint as the batched kinematics fold it
    (joint axes turned to z): read once by comparing the kernel's joint frame with Pinocchio's
    tool frame at q = 0, then re-orthonormalised."""
    rot = _tool_rotations.get(arm)
    if rot is None:
        _check_pose_arm(arm)  # a serial arm with 3-D goals, or a clear error
        chain = arm.chain
        q = np.zeros((1, arm.nq))
        F = np.empty((arm.nq, 12))
        p = np.empty((1, 1, 3))
        tree_points(q, 0, *chain.tree_arrays, F, p, 0, np.empty((0, 0, 3)))
        j = int(chain.ee_joint[0])
        R_joint = F[j, :9].reshape(3, 3) if j >= 0 else np.eye(3)
        data = arm.model.createData()
        pin.framesForwardKinematics(arm.model, data, arm.to_pinocchio(q[0]))
        u, _, vt = np.linalg.svd(R_joint.T @ data.oMf[arm.ee_frame_id].rotation)
        rot = _tool_rotations[arm] = np.ascontiguousarray(u @ vt)
    return rot


@numba.njit(cache=True, nogil=True, inline="always")
def tool_rotation_of(F, j, tool_rot, R):
    """R (3, 3) <- the tool frame's rotation from joint j's frame F[j] (tree_points' scratch; j < 0:
    the tool on the root) and the tool's fixed rotation in it."""
    for r in range(3):
        for c in range(3):
            if j >= 0:
                R[r, c] = F[j, 3 * r] * tool_rot[0, c] + F[j, 3 * r + 1] * tool_rot[1, c] + \
                    F[j, 3 * r + 2] * tool_rot[2, c]
            else:
                R[r, c] = tool_rot[r, c]


@numba.njit(cache=True, nogil=True, inline="always")
def jacobian_columns(p, origins, axes, kind, J):
    """J (6, n) <- the LOCAL_WORLD_ALIGNED Jacobian of the point p (3,): column k is (a_k x (p - o_k);
    a_k) for a revolute joint, (a_k; 0) for a prismatic one (origins (n + 1, 3), axes (n, 3) as
    tree_points writes them)."""
    ex, ey, ez = p[0], p[1], p[2]
    for k in range(axes.shape[0]):
        ax, ay, az = axes[k, 0], axes[k, 1], axes[k, 2]
        if kind[k] == 0:
            dx, dy, dz = ex - origins[k + 1, 0], ey - origins[k + 1, 1], ez - origins[k + 1, 2]
            J[0, k] = ay * dz - az * dy
            J[1, k] = az * dx - ax * dz
            J[2, k] = ax * dy - ay * dx
            J[3, k], J[4, k], J[5, k] = ax, ay, az
        else:
            J[0, k], J[1, k], J[2, k] = ax, ay, az
            J[3, k], J[4, k], J[5, k] = 0.0, 0.0, 0.0


@numba.njit(cache=True, nogil=True)
def _pose_kernel(q, rot, pos, kind, identity, parent, ee_joint, effector_pos, tool_rot, T, J, want_j):
    """T (N, 4, 4) <- the tool frame at every row of q (N, n); when want_j, J (N, 6, n) <- its
    LOCAL_WORLD_ALIGNED Jacobian (jacobian_columns)."""
    n = rot.shape[0]
    F = np.empty((n, 12))
    p = np.empty((1, 1, 3))
    origins = np.empty((1, n + 1, 3)) if want_j else np.empty((0, 0, 3))
    axes = np.empty((n, 3))
    R = np.empty((3, 3))
    for i in range(q.shape[0]):
        if want_j:
            tree_points(q, i, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, p, 0, origins, axes)
        else:
            tree_points(q, i, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, p, 0, origins)
        tool_rotation_of(F, ee_joint[0], tool_rot, R)
        for r in range(3):
            for c in range(3):
                T[i, r, c] = R[r, c]
            T[i, r, 3] = p[0, 0, r]
            T[i, 3, r] = 0.0
        T[i, 3, 3] = 1.0
        if want_j:
            jacobian_columns(p[0, 0], origins[0], axes, kind, J[i])


def fk_pose_and_jacobian(arm: Arm, q) -> tuple[np.ndarray, np.ndarray]:
    """(T, J): the tool frame (..., 4, 4) and its 6-row frame Jacobian (..., 6, nq) at q (..., nq),
    in one pass of the batched kinematics (LOCAL_WORLD_ALIGNED: the module's docstring)."""
    tool = _tool_rotation(arm)
    flat, batch = arm._as_batch(q)
    T = np.empty((len(flat), 4, 4))
    J = np.empty((len(flat), 6, arm.nq))
    _pose_kernel(flat, *arm.chain.tree_arrays, tool, T, J, True)
    return T.reshape(*batch, 4, 4), J.reshape(*batch, 6, arm.nq)


def fk_pose(arm: Arm, q) -> np.ndarray:
    """The tool frame in the base frame: q (..., nq) -> (..., 4, 4) homogeneous transforms
    (Pinocchio's data.oMf[arm.ee_frame_id].homogeneous)."""
    tool = _tool_rotation(arm)
    flat, batch = arm._as_batch(q)
    T = np.empty((len(flat), 4, 4))
    _pose_kernel(flat, *arm.chain.tree_arrays, tool, T, np.empty((0, 6, arm.nq)), False)
    return T.reshape(*batch, 4, 4)


def pose_jacobian(arm: Arm, q) -> np.ndarray:
    """The tool frame's 6-row Jacobian: q (..., nq) -> (..., 6, nq), rows (v; omega) in the base
    frame's axes (Pinocchio's computeFrameJacobian(..., LOCAL_WORLD_ALIGNED))."""
    return fk_pose_and_jacobian(arm, q)[1]


def sample_poses(arm: Arm, n: int, seed: int | None = None) -> np.ndarray:
    """(n, 4, 4) reachable poses: the tool frames of n uniformly drawn joint vectors (arm.sample_q;
    the same joint vectors as arm.sample_goals(n, seed), so their positions are those goals)."""
    poses = fk_pose(arm, arm.sample_q(n, seed))
    if not np.isfinite(poses).all():
        bad = int((~np.isfinite(poses)).reshape(len(poses), -1).any(axis=-1).sum())
        raise ValueError(f"{arm.name}: {bad} of {len(poses)} sampled poses are not finite numbers")
    return poses


# ---------------------------------------------------------------- validation
@numba.njit(cache=True, nogil=True)
def _pose_measures(arr, atol, finite, bottom, off, det):
    """Per pose of arr (n, 4, 4): whether all 16 entries are finite, the largest deviation of the last
    row from (0, 0, 0, 1), the largest entry of |R^T R - I| and det R (R the rotation block). Returns
    whether every pose passes (finite, both deviations within atol, det >= 0)."""
    good = True
    for i in range(arr.shape[0]):
        ok = True
        for a in range(4):
            for b in range(4):
                if not math.isfinite(arr[i, a, b]):
                    ok = False
        finite[i] = ok
        bottom[i] = max(abs(arr[i, 3, 0]), abs(arr[i, 3, 1]), abs(arr[i, 3, 2]), abs(arr[i, 3, 3] - 1.0))
        worst = 0.0
        for a in range(3):
            for b in range(3):
                d = abs(arr[i, 0, a] * arr[i, 0, b] + arr[i, 1, a] * arr[i, 1, b] + arr[i, 2, a] * arr[i, 2, b]
                        - (1.0 if a == b else 0.0))
                if d > worst:
                    worst = d
        off[i] = worst
        det[i] = (arr[i, 0, 0] * (arr[i, 1, 1] * arr[i, 2, 2] - arr[i, 1, 2] * arr[i, 2, 1])
                  - arr[i, 0, 1] * (arr[i, 1, 0] * arr[i, 2, 2] - arr[i, 1, 2] * arr[i, 2, 0])
                  + arr[i, 0, 2] * (arr[i, 1, 0] * arr[i, 2, 1] - arr[i, 1, 1] * arr[i, 2, 0]))
        if not (ok and bottom[i] <= atol and off[i] <= atol and det[i] >= 0.0):
            good = False
    return good


def check_poses(poses, *, atol: float = ORTHONORMAL_ATOL, what: str = "poses") -> np.ndarray:
    """poses as a float (n, 4, 4) array (one (4, 4) pose becomes (1, 4, 4)), or ValueError naming the
    problem and the first pose that has it: not an array of 4 x 4 real numbers, NaN or infinity, a
    last row other than (0, 0, 0, 1), a rotation block that is not orthonormal (the largest entry of
    R^T R - I above atol) or is a reflection (det -1)."""
    try:
        arr = np.asarray(poses)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be an (n, 4, 4) array of homogeneous transforms: {e}") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{what} must hold real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    if arr.shape == (4, 4):
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"{what} must have shape (n, 4, 4) (homogeneous transforms, Pinocchio's "
                         f"SE3.homogeneous), got shape {arr.shape}")
    n = len(arr)
    finite, bottom, off, det = np.empty(n, np.bool_), np.empty(n), np.empty(n), np.empty(n)
    if _pose_measures(np.ascontiguousarray(arr), float(atol), finite, bottom, off, det):  # compiled: microseconds
        return arr
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"{what}: {int((~finite).sum())} of {len(arr)} poses hold NaN or infinity "
                         f"(the first: pose {i})")
    if (bottom > atol).any():
        i = int(np.argmax(bottom > atol))
        raise ValueError(f"{what}: {int((bottom > atol).sum())} of {len(arr)} poses have a last row other than "
                         f"(0, 0, 0, 1) (the first: pose {i}, last row {arr[i, 3].tolist()})")
    if (off > atol).any():
        i = int(np.argmax(off > atol))
        raise ValueError(f"{what}: {int((off > atol).sum())} of {len(arr)} poses have a rotation block that is "
                         f"not orthonormal (the first: pose {i}, |R^T R - I| up to {off[i]:.3g} > {atol:g})")
    if (det < 0).any():
        i = int(np.argmax(det < 0))
        raise ValueError(f"{what}: {int((det < 0).sum())} of {len(arr)} poses have a rotation block with "
                         f"det {det[i]:.3g}: a reflection, not a rotation (the first: pose {i})")
    return arr


def is_pose_array(goals) -> bool:
    """Whether goals are shaped as poses, (4, 4) or (n, 4, 4), rather than positions (n, 3)."""
    shape = np.shape(goals)
    return len(shape) in (2, 3) and shape[-2:] == (4, 4)


# ---------------------------------------------------------------- angles and features
def rotation_angle(Ra, Rb) -> np.ndarray:
    """The geodesic angle [rad, in [0, pi]] between rotations Ra and Rb (..., 3, 3): the angle of
    Ra^T Rb, |log3(Ra^T Rb)|. atan2(sin, cos), with sin from the skew part and cos = (trace - 1) / 2,
    is exact to rounding everywhere; arccos((trace - 1) / 2) alone loses half the digits near 0 and pi."""
    M = np.swapaxes(np.asarray(Ra, dtype=np.float64), -1, -2) @ np.asarray(Rb, dtype=np.float64)
    s = 0.5 * np.sqrt((M[..., 2, 1] - M[..., 1, 2]) ** 2 + (M[..., 0, 2] - M[..., 2, 0]) ** 2
                      + (M[..., 1, 0] - M[..., 0, 1]) ** 2)
    c = 0.5 * (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0)
    return np.arctan2(s, c)


def axis_angle_between(a, b) -> np.ndarray:
    """The angle [rad, in [0, pi]] between directions a and b (..., 3): atan2(|a x b|, a . b)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def rotation_6d(R) -> np.ndarray:
    """The continuous 6-D form of rotations (Zhou et al. 2019): (..., 3, 3) -> (..., 6), the first
    column of R then its second. Unlike Euler angles or a quaternion (whose sign is a choice) it has
    no jump: near rotations give near features."""
    R = np.asarray(R, dtype=np.float64)
    return np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


def rotation_from_6d(x) -> np.ndarray:
    """rotation_6d's inverse, for any 6-vector whose halves are not parallel (a network's output):
    Gram-Schmidt on the two columns, the third their cross product. (..., 6) -> (..., 3, 3)."""
    x = np.asarray(x, dtype=np.float64)
    a, b = x[..., :3], x[..., 3:]
    c0 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b - np.sum(c0 * b, axis=-1, keepdims=True) * c0
    c1 = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.stack([c0, c1, np.cross(c0, c1)], axis=-1)


def pose_features(arm: Arm, poses) -> np.ndarray:
    """A network's continuous view of pose goals: (n, 4, 4) -> (n, 9), the position then
    rotation_6d (a full pose); (n, 6), the position then the approach axis's direction in the base
    frame (an arm with an approach axis, whose roll is free)."""
    T = check_poses(poses)
    axis = approach_axis(arm)
    turn = rotation_6d(T[:, :3, :3]) if axis is None else T[:, :3, :3] @ axis
    return np.concatenate([T[:, :3, 3], turn], axis=-1)


def pose_errors(arm: Arm, poses, q) -> tuple[np.ndarray, np.ndarray]:
    """(position error [length], angle error [rad]), each (n,), of joint vectors q (n, nq) on pose
    goals (n, 4, 4): the distance between the tool frame's origin and the goal's, and the geodesic
    angle between their rotations (a full pose) or between their approach axes (an arm whose roll
    is free)."""
    goals = check_poses(poses)
    T = fk_pose(arm, q)
    if T.shape != goals.shape:
        raise ValueError(f"{arm.name}: q must be ({len(goals)}, {arm.nq}) for {len(goals)} poses, got {np.shape(q)}")
    position = np.linalg.norm(T[:, :3, 3] - goals[:, :3, 3], axis=-1)
    axis = approach_axis(arm)
    if axis is None:
        return position, rotation_angle(T[:, :3, :3], goals[:, :3, :3])
    return position, axis_angle_between(T[:, :3, :3] @ axis, goals[:, :3, :3] @ axis)


# ---------------------------------------------------------------- one goal's residual (refinement)
def residual(goal: np.ndarray, M: pin.SE3, J6: np.ndarray | None, axis: np.ndarray | None,
             length: float) -> tuple[np.ndarray, np.ndarray | None, float, float]:
    """(e, Je, position error, angle error) of one pose goal (4, 4) at the tool frame M with its
    LOCAL_WORLD_ALIGNED Jacobian J6 (6, nq): e(q + dq) = e(q) - Je dq to first order, so the
    Gauss-Newton step toward the goal solves Je dq = e (J6 None: no Je, the error alone).

    Full pose: e = (p_g - p, length * log3(R_g R^T)), Je = (J_v, length * Jlog3(R_g R^T) J_w). A turn
    w of the tool (R -> exp(w) R) takes log3(R_g R^T) to log3(R_g R^T exp(-w)), to first order
    log3(R_g R^T) - Jlog3(R_g R^T) w (Jlog3: Pinocchio's inverse right Jacobian of SO(3)).
    Approach axis u (tool frame), a = R u, g = R_g u: e = (p_g - p, length * (g - a)), whose last
    three rows, the chord between the two directions (|g - a| = 2 sin(angle / 2), zero only when they
    agree), have rank 2: a turn w moves a by w x a, so Je = (J_v, length * [a]x^T J_w), and the roll
    about a changes nothing. length [length / rad] weighs an angle against a distance."""
    p, R = M.translation, M.rotation
    e = np.empty(6)
    e[:3] = goal[:3, 3] - p
    err_p = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    Je = None
    if axis is None:
        E = goal[:3, :3] @ R.T
        w = pin.log3(E)
        e[3:] = length * w
        if J6 is not None:
            Je = J6.copy()
            Je[3:] = length * (pin.Jlog3(E) @ J6[3:])
        return e, Je, err_p, math.sqrt(w @ w)
    a, g = R @ axis, goal[:3, :3] @ axis
    cx, cy, cz = a[1] * g[2] - a[2] * g[1], a[2] * g[0] - a[0] * g[2], a[0] * g[1] - a[1] * g[0]
    angle = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), float(a @ g))
    e[3:] = length * (g - a)
    if J6 is not None:
        Jw = J6[3:]
        Je = J6.copy()  # the last rows: -length [a]x J_w, column by column
        Je[3] = -length * (a[1] * Jw[2] - a[2] * Jw[1])
        Je[4] = -length * (a[2] * Jw[0] - a[0] * Jw[2])
        Je[5] = -length * (a[0] * Jw[1] - a[1] * Jw[0])
    return e, Je, err_p, angle
