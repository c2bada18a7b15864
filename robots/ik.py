"""Damped least-squares inverse kinematics on an arm's Pinocchio model: the classical baseline.

One query iterates, from the rest pose q_0 = arm.rest,

    e_k  = g - p(q_k)[task_axes]                        task-space error, (m,)
    J_k  = J_p(q_k)[task_axes]                          translational frame Jacobian rows, (m, nq)
    J#   = J_k^T (J_k J_k^T + lambda^2 I)^-1            damped pseudo-inverse (Wampler 1986; Buss 2004)
    dq_k = J# e_k + (I - J# J_k) b_k                    b_k: a posture term toward mid-range
    q_{k+1} = q_k + dq_k                                within the limits (arm.within_limits)

J_p comes from `pinocchio.computeFrameJacobian` (LOCAL_WORLD_ALIGNED, end-effector frame). A tree of E
end effectors (Arm.effectors) is the same iteration on stacked vectors: e_k the E effectors' errors one
after the other (3E rows with three task axes), J_k their Jacobians stacked (3E x nq; a joint that does
not move an effector has zeros in its rows), ||e|| the norm of the whole stack.
The arm's chain has one velocity per coordinate (nv == nq), so dq is a step in the arm's own
coordinates. Safeguards a textbook DLS needs here: no coordinate moves more than max_step per
iteration; a joint the step would take past a limit stops at it and the others solve for the
rest of the error (an active set); b_k = posture * min(1, ||e|| / (0.05 size)) * 0.85^k (mid - q)
takes the planar arm off its stretched, singular rest pose and then fades away. The damping
lambda [length] is a fraction of the workspace size, so one setting serves arms in metres and
the paper's units alike. It stops when ||e|| < tol, when the step stalls or the error has not
improved for 10 iterations (a goal out of reach), or after max_iter, and returns the best iterate.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from robots import pose
from robots.arm import Arm
from robots.limbs import hips
from robots.limbs import solve as solve_limbs
from robots.registry import in_metres

_local = threading.local()  # one pin.Data per thread and arm (pink's rule: Data is not shared)


@dataclass(frozen=True)
class IKResult:
    """q (nq,) within the limits; error = ||g - reach(q)|| [length]; iterations; seconds of
    wall time; converged: error < tol (a pose goal: and angle < angle_tol). A pose goal's
    (dls_pose_ik) also: angle, the tool's angle error [rad] (robots.pose.pose_errors), and the
    random restarts it took."""

    q: np.ndarray
    error: float
    iterations: int
    seconds: float
    converged: bool
    angle: float | None = None
    restarts: int = 0


def _step(J, e, bias, lam2) -> np.ndarray:
    """DLS step J# e plus the null-space posture term (I - J# J) bias, J# = J^T (J J^T + lam2 I)^-1."""
    J_pinv = J.T @ np.linalg.inv(J @ J.T + lam2 * np.eye(len(e)))  # (nq, m)
    return J_pinv @ e + bias - J_pinv @ (J @ bias)


def _limited(dq: np.ndarray, max_step: float) -> np.ndarray:
    """dq scaled down so that no coordinate moves more than max_step."""
    return dq * min(1.0, max_step / max(float(np.max(np.abs(dq))), 1e-300))


def _task_error(arm: Arm, data: pin.Data, goal: np.ndarray, axes: list) -> np.ndarray:
    """goal - the effectors' task coordinates, stacked (E len(axes),), after forwardKinematics."""
    model, fids = arm.model, arm.effector_ids
    if len(fids) == 1:
        pin.updateFramePlacement(model, data, fids[0])
        return goal - data.oMf[fids[0]].translation[axes]
    for fid in fids:
        pin.updateFramePlacement(model, data, fid)
    return goal - np.concatenate([data.oMf[fid].translation[axes] for fid in fids])


def _task_jacobian(arm: Arm, data: pin.Data, q_pin: np.ndarray, axes: list) -> np.ndarray:
    """The effectors' positional frame Jacobians on the task axes, stacked: (E len(axes), nq)."""
    model, fids = arm.model, arm.effector_ids
    if len(fids) == 1:
        return pin.computeFrameJacobian(model, data, q_pin, fids[0], pin.LOCAL_WORLD_ALIGNED)[:3][axes]
    return np.concatenate([pin.computeFrameJacobian(model, data, q_pin, fid, pin.LOCAL_WORLD_ALIGNED)[:3][axes]
                           for fid in fids])


def _task_jacobian_axes(arm: Arm, data: pin.Data, q_pin: np.ndarray, axes: list) -> tuple[np.ndarray, list]:
    """_task_jacobian's stacked (E len(axes), nq) rows, and each effector's positional and angular
    rows (3, nq) each: an angular column is the joint's unit axis (zero for a prismatic joint or a
    joint that does not move that effector)."""
    full = [pin.computeFrameJacobian(arm.model, data, q_pin, fid, pin.LOCAL_WORLD_ALIGNED) for fid in arm.effector_ids]
    J = full[0][:3][axes] if len(full) == 1 else np.concatenate([f[:3][axes] for f in full])
    return J, [(f[:3], f[3:]) for f in full]


def _curvature(parts: list, v: np.ndarray, axes: list) -> np.ndarray:
    """d^2/dt^2 of the effectors' task coordinates at t = 0 along q + t v, stacked: for each effector,
    sum_j (2 Omega_j + v_j w_j) x (J_j v_j), J_j its positional column of joint j, w_j the joint's
    axis (its angular column) and Omega_j = sum_{i < j} v_i w_i (the joints' order is parents first,
    and a joint off the effector's path has zero columns). Exact for revolute and prismatic joints:
    along v, a column J_j = w_j x (p - c_j) (revolute) or d_j (prismatic) turns with the joints
    before it, and a revolute joint's own turn moves p too. The sum of the cross products a_j x b_j
    is the axial vector of A B^T - B A^T (A, B: the columns side by side)."""
    out = []
    for lin, ang in parts:
        wv = ang * v  # (3, nq): v_j w_j
        M = (2.0 * np.cumsum(wv, axis=1) - wv) @ (lin * v).T
        out.append(np.array([M[1, 2] - M[2, 1], M[2, 0] - M[0, 2], M[0, 1] - M[1, 0]])[axes])
    return out[0] if len(out) == 1 else np.concatenate(out)


def _data(arm: Arm) -> pin.Data:
    """This thread's pin.Data of the arm's model; dropped with the arm (an id could be reused)."""
    cache = getattr(_local, "data", None)
    if cache is None:
        cache = _local.data = weakref.WeakKeyDictionary()
    d = cache.get(arm)
    if d is None:
        d = cache[arm] = arm.model.createData()
    return d


def workspace_size(arm: Arm) -> float:
    """The largest extent of the task coordinates' bounding box [length]."""
    lo, hi = arm.workspace_bounds
    return float(np.max(hi - lo))


def default_tolerance(arm: Arm) -> float:
    """refine's tolerance when none is given [length]: 1e-4 m (0.1 mm) on a robot in metres
    (robots.in_metres: the real arms, the trees, an arm from a URDF of another name; on a tree it
    bounds all its effectors' errors stacked, so each is within it); 1e-4 x workspace_size otherwise
    (the paper's arms and the snakes, in the paper's units)."""
    if in_metres(arm.name):
        return 1e-4
    return 1e-4 * workspace_size(arm)


def dls_ik(arm: Arm, goal, q0=None, *, damping: float = 0.02, tol: float | None = None,
           max_iter: int = 100, max_step: float = 0.5, posture: float = 0.1) -> IKResult:
    """Solve reach(q) = goal by damped least squares, from q0 (arm.rest by default; moved into the limits).

    goal: (len(task_axes),) task coordinates, (E, len(task_axes)) for a tree of E effectors;
    damping: lambda as a fraction of workspace_size; tol: error threshold [length] (default
    1e-4 * workspace_size) on ||e||, all effectors' errors stacked.
    """
    t0 = time.perf_counter()
    goal = np.asarray(goal, dtype=np.float64)
    shape = goal.shape
    goal = goal.reshape(-1)
    axes = list(arm.task_axes)
    if arm.is_tree and shape != (arm.n_effectors, len(axes)):
        raise ValueError(f"{arm.name}: goal must have shape ({arm.n_effectors}, {len(axes)}) (one position per "
                         f"effector: {', '.join(arm.effectors)}), got shape {shape}")
    if goal.shape != (len(axes) * arm.n_effectors,):
        raise ValueError(f"{arm.name}: goal must have {len(axes)} coordinates, got shape {goal.shape}")
    size = workspace_size(arm)
    lam2 = (damping * size) ** 2
    tol = 1e-4 * size if tol is None else float(tol)
    model, data = arm.model, _data(arm)
    q = arm.rest.copy() if q0 is None else arm.within_limits(np.asarray(q0, dtype=np.float64).reshape(-1))
    cont = arm.chain.continuous.astype(bool)
    lower, upper = arm.lower, arm.upper
    mid = 0.5 * (lower + upper)
    direct = model.nq == arm.nq  # no continuous joint: Pinocchio's q is the arm's q
    err = np.inf
    it = 0
    best, since_best, patience = (q, np.inf), 0, 10
    for it in range(max_iter + 1):
        q_pin = q if direct else arm.to_pinocchio(q)
        pin.forwardKinematics(model, data, q_pin)
        e = _task_error(arm, data, goal, axes)
        err = float(np.sqrt(e @ e))  # np.linalg.norm, bit for bit, without its overhead (IK per drag)
        if err < best[1]:
            best, since_best = (q, err), 0
        else:
            since_best += 1
        if err < tol or it == max_iter or since_best >= patience:
            break
        J = _task_jacobian(arm, data, q_pin, axes)  # (m, nq), m = E len(axes)
        # toward mid-range, fading with the error and the iterations: it takes the arm off the rest
        # pose's singularity, then vanishes (also for a goal out of reach)
        bias = np.where(cont, 0.0, posture * min(1.0, err / (0.05 * size)) * 0.85**it * (mid - q))
        dq = _limited(_step(J, e, bias, lam2), max_step)
        held = np.zeros(len(q), bool)
        for _ in range(len(q)):  # an active set: a joint the step would take past a limit stops at it
            over = ~cont & ~held & ((q + dq < lower) | (q + dq > upper))
            if not over.any():
                break
            held |= over
            dq_held = np.where(held, np.clip(q + dq, lower, upper) - q, 0.0)
            free = _step(np.where(held, 0.0, J), e - J @ dq_held, np.where(held, 0.0, bias), lam2)
            dq = dq_held + _limited(np.where(held, 0.0, free), max_step)
        q_new = arm.within_limits(q + dq)  # continuous joints turn by whole turns into their range
        if np.max(np.abs(q_new - q)) < 1e-10:  # stalled: held at limits
            break
        q = q_new
    q, err = best
    return IKResult(q=q, error=err, iterations=it, seconds=time.perf_counter() - t0, converged=err < tol)


@dataclass(frozen=True)
class RefineResult:
    """q (n, nq) within the limits; error (n,) = ||g - reach(q)|| [length] (a tree: the worst
    effector's, so error < tol means every effector within tol; a pose goal: the distance of the
    tool frame's origin from the goal's); steps (n,) taken; seconds of wall time for the whole
    batch. Pose goals also: angle (n,), the angle error [rad] (robots.pose.pose_errors: geodesic, or
    between approach axes). tol and angle_tol: the tolerances refine held the goals to;
    converged (n,): each goal within them."""

    q: np.ndarray
    error: np.ndarray
    steps: np.ndarray
    seconds: float
    # (n,) the proposal kept for each goal, when refine had several (refine; a tree's mix: its largest group's)
    choice: np.ndarray | None = None
    angle: np.ndarray | None = None  # (n,) [rad], pose goals only
    tol: float | None = None
    angle_tol: float | None = None

    @property
    def converged(self) -> np.ndarray:
        """(n,) bool: error < tol, and angle < angle_tol for pose goals."""
        tol = np.inf if self.tol is None else self.tol
        ok = self.error < tol
        if self.angle is not None:
            ok &= self.angle < (np.inf if self.angle_tol is None else self.angle_tol)
        return ok


def _held_step(J, e, q, lower, upper, free_limits, lam2_eye) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A damped Gauss-Newton step J^T (J J^T + lambda^2 I)^-1 e whose joints stay within their limits:
    a joint the step would take past a limit stops at it, and the free joints solve for the rest of
    the error (an active set, at most one pass per joint). free_limits: False for continuous joints.
    Returns the step, and the free joints' Jacobian Jf (held columns zero) and (Jf Jf^T + lambda^2 I)^-1
    of its last solve (the same solve for another right-hand side: Jf^T K r)."""
    K = np.linalg.inv(J @ J.T + lam2_eye)
    dq = J.T @ (K @ e)
    held = np.zeros(len(q), bool)
    Jf = J
    for _ in range(len(q)):
        over = free_limits & ~held & ((q + dq < lower) | (q + dq > upper))
        if not over.any():
            break
        held |= over
        dq_held = np.where(held, np.clip(q + dq, lower, upper) - q, 0.0)
        Jf = np.where(held, 0.0, J)
        K = np.linalg.inv(Jf @ Jf.T + lam2_eye)
        dq = dq_held + Jf.T @ (K @ (e - J @ dq_held))
    return dq, Jf, K


def _bearing(arm: Arm) -> tuple[np.ndarray, np.ndarray] | None:
    """The first joint's axis (point, unit direction) in task coordinates, when a turn of that joint
    can be solved for in closed form: a revolute first joint, and 3 task axes (or the x-y plane of
    an arm whose first joint turns about z). None otherwise."""
    if arm.is_prismatic[0]:
        return None
    c, w = arm.base_axis
    axes = list(arm.task_axes)
    if len(axes) == 3:
        return c, w
    if axes == [0, 1] and arm.base_upright:
        return c[:2], None
    return None


def _turned(q, p, goal, bearing, lower, upper, continuous) -> np.ndarray:
    """q with its first joint turned so that the end effector p's bearing about the first joint's
    axis is the goal's: turning that joint alone moves p on a circle about the axis, and the point
    of the circle nearest the goal lies at the goal's bearing (when that bearing is beyond the
    joint's limits: the turn within them nearest to it). Scalar math on Python floats: it runs
    once per goal and step."""
    c, w = bearing
    ux, uy, *uz = (a - b for a, b in zip(p.tolist(), c))
    vx, vy, *vz = (a - b for a, b in zip(goal.tolist(), c))
    if w is None:  # the x-y plane, turned about z
        turn = math.atan2(ux * vy - uy * vx, ux * vx + uy * vy)
    else:
        wx, wy, wz = w
        uz, vz = uz[0], vz[0]
        du, dv = ux * wx + uy * wy + uz * wz, vx * wx + vy * wy + vz * wz
        ux, uy, uz = ux - du * wx, uy - du * wy, uz - du * wz
        vx, vy, vz = vx - dv * wx, vy - dv * wy, vz - dv * wz
        cross = (uy * vz - uz * vy) * wx + (uz * vx - ux * vz) * wy + (ux * vy - uy * vx) * wz
        turn = math.atan2(cross, ux * vx + uy * vy + uz * vz)
    q = q.copy()
    q0, lo, hi = float(q[0]), float(lower[0]), float(upper[0])
    if continuous:  # whole turns into its range
        q[0] = lo + (q0 + turn - lo) % (2 * math.pi)
        return q
    # |p' - g|^2 = const - 2 |u| |v| cos(turn still to go): the larger that cosine, the nearer
    best, score = q0, math.cos(turn)
    for cand in (q0 + turn - 2 * math.pi, q0 + turn, q0 + turn + 2 * math.pi, lo, hi):
        cos = math.cos(turn - (cand - q0))
        if lo - 1e-12 <= cand <= hi + 1e-12 and cos > score + 1e-15:
            best, score = min(max(cand, lo), hi), cos
    q[0] = best
    return q


def _vector_tools(arm: Arm):
    """(within, to_pin, limited): arm.within_limits and arm.to_pinocchio of one joint vector, without
    their checks and batching (refine's own, for a goal's inner loop; within changes x in place), and
    the mask of the joints with limits (not continuous)."""
    lower, upper = arm.lower, arm.upper
    limited = ~arm.chain.continuous.astype(bool)
    wrapped = [(int(j), float(lower[j])) for j in np.flatnonzero(arm.chain.continuous)]
    cos_at, sin_at = arm.chain.idx_q[~limited], arm.chain.idx_q[~limited] + 1
    plain_at, q_ref = arm.chain.idx_q[limited], arm.q_ref
    direct = arm.model.nq == arm.nq

    def within(x):
        for j, lo in wrapped:  # whole turns into [lo, lo + 2 pi)
            v = float(x[j])
            if not lo <= v < lo + 2 * np.pi:
                x[j] = lo + (v - lo) % (2 * np.pi)
        return np.minimum(np.maximum(x, lower), upper)

    def to_pin(x):
        if direct:
            return x
        out = q_ref.copy()
        out[plain_at], out[cos_at], out[sin_at] = x[limited], np.cos(x[~limited]), np.sin(x[~limited])
        return out

    return within, to_pin, limited


def refine(arm: Arm, goals, q0, *, steps: int = 3, tol: float | None = None, damping: float = 1e-3,
           halvings: int = 4, turn: bool = True, curved: bool = True, flips: bool = True,
           angle_tol: float | None = None, limbs: bool = True) -> RefineResult:
    """A learned seed made exact: at most `steps` damped Gauss-Newton steps from q0 toward each goal,
    each after a closed-form turn of the first joint (turn=True), each bent along the arc the
    joints' turns trace (curved=True).

        q_0 = q0 with its first joint turned to the goal's bearing about that joint's axis (_turned)
        dq_k = J^T (J J^T + lambda^2 I)^-1 (g - p(q_k))       with joints at a limit held (an active set)
        a_k: J a_k = -d2p/dt2 along dq_k (_curvature); none when |a_k| >= 1.5 |dq_k|
        q_{k+1} = turned(q_k + t dq_k + t^2 a_k / 2),  t the first of 1, 1/2, 1/4, ... (halvings) that lowers the error

    J the translational rows of Pinocchio's frame Jacobian (LOCAL_WORLD_ALIGNED, end-effector
    frame) on the task axes (a tree of E effectors: their errors and Jacobians stacked, goals
    (n, E, len(task_axes)), and no turn: no one joint turns every effector); lambda = damping x
    workspace_size (a small damping: near the solution a Gauss-Newton step converges
    quadratically, the damping only guards singular poses). Two safeguards make a step count
    from a seed tens of millimetres off: a joint the step would push past its limit stops there
    and the others take up the rest of the error
    (clipping it instead left many more goals unsolved: docs/log.md), and the step length
    is halved while the full step does not lower the error (each halving costs one forward
    kinematics, not a Jacobian). A goal stops once its error is below tol (default:
    default_tolerance, 0.1 mm on a real arm); each goal keeps its best iterate. goals (n, len(task_axes)), q0 (n, nq)
    (a network's output), or (k, n, nq): k proposals for each goal (a multi-head network's, one
    per head). Then each proposal in turn takes the turn and the first step, until one is within
    tolerance; otherwise the one nearest its goal after them takes the rest (RefineResult.choice):
    the answer kept has had at most `steps` steps, and the proposals cost at most k - 1 steps more
    than one seed. Picking the proposal after its first step rather than by its seed error matters
    where a seed a few millimetres off sits on a branch that no step leaves (a multi-head SO
    network: docs/results/real-arms.md).

    The turn first (one forward kinematics, no Jacobian): the first joint alone moves the end
    effector on a circle about its axis (Arm.base_axis), whose point nearest the goal lies at the
    goal's bearing, so that joint's best value is known in closed form (the nearest one within its
    limits when the bearing is out of them); it is kept when it lowers the error. Near the base
    axis a seed a few millimetres off can be tens of degrees off in that joint, where a
    Gauss-Newton step, linear in the angle, overshoots. The turn again after every step: a step
    that moves the end effector toward or away from the axis leaves its bearing off again (more
    goals within tolerance for a little more time; the figures: docs/results/real-arms.md,
    docs/log.md). turn=False: Gauss-Newton steps only.

    The bend (geodesic acceleration, Transtrum and Sethna 2012): a Gauss-Newton step is a straight
    line in joint space, but each joint's turn moves the effector on a circle, so the step lands off
    the point its linear model aims at, worst near a fold of the workspace (an elbow nearly
    straight, a goal near full reach). The second derivative of the effector's position along the
    step is known in closed form from the Jacobian's columns and the joints' axes, so the same
    factored solve corrects the step to second order: no more Jacobians, no more forward
    kinematics. curved=False: straight steps.

    The half turns (flips=True): when the best proposal's first step took less than 90 % of its
    error off (a step that stalls on the wrong side of a fold: a wrist turning its offset away from
    a goal near full reach), that proposal with one joint turned by half a turn (pi, or -pi to stay
    within its limits), for each joint after the first that is not prismatic, takes the turn (one
    forward kinematics each), and the two of them then nearest the goal are two more proposals,
    tried as the others (the first step, one at a time until one is within tolerance);
    RefineResult.choice is then k + j - 1 for the one of joint j. Goals whose first step goes well
    never try them: the answer kept has still had at most `steps` steps.

    A tree with several proposals (a multi-head network's, one head per limb group): when no
    proposal is within tolerance after its first step, each limb group (effectors that share joints,
    robots.kinematics.limb_groups) takes the joints of the proposal that put its own effectors
    nearest, and that mix is kept when it is nearer than the best proposal (RefineResult.choice: the
    proposal its largest group took). Groups share no joint, so a leg solved in one proposal and an
    arm in another make one answer that solves both.

    A tree's limbs in closed form (limbs=True), a tree's turn: before its first step, each proposal
    has every limb with a hip (a free first joint, two joints whose axes meet, a knee: g1's legs and
    arms, talos-legs' legs) solved for its effector's goal, the solution nearest the proposal's own
    joints, and a shared prefix (g1's waist) moved where an arm cannot reach its goal under it
    (robots.limbs, which keeps a limb group's proposed joints where they are nearer). limbs=False:
    the proposals as given.

    Pose goals, (n, 4, 4) homogeneous transforms of the tool frame (robots.pose): the same damped
    Gauss-Newton steps in SE(3), each goal held to tol and to angle_tol [rad] (default 0.1 degree):
    refine_pose, where the turn, the bend, the half turns and the limbs do not apply."""
    if pose.is_pose_array(goals):
        return refine_pose(arm, goals, q0, steps=steps, tol=tol, angle_tol=angle_tol, damping=damping,
                           halvings=halvings)
    if angle_tol is not None:
        raise ValueError(f"{arm.name}: angle_tol applies to pose goals (n, 4, 4); these goals have shape "
                         f"{np.shape(goals)}")
    t0 = time.perf_counter()
    goals = np.asarray(goals, dtype=np.float64)
    goals = goals[None] if goals.ndim == (2 if arm.is_tree else 1) else goals
    q = np.asarray(q0, dtype=np.float64)
    q = arm.within_limits(q if q.ndim == 3 else np.atleast_2d(q)[None])  # (k, n, nq)
    axes = list(arm.task_axes)
    goal_shape = (*arm._effector_shape, len(axes))
    if goals.shape[1:] != goal_shape or q.shape[1:] != (len(goals), arm.nq) or not len(q):
        raise ValueError(f"{arm.name}: goals must be (n, {', '.join(map(str, goal_shape))}) and q0 (n, {arm.nq}) "
                         f"or (k, n, {arm.nq}), got {goals.shape} and {np.shape(q0)}")
    if limbs and arm.is_tree and len(axes) == 3 and hips(arm):
        q = np.stack([solve_limbs(arm, goals, qj)[0] for qj in q])
    goals = goals.reshape(len(goals), int(np.prod(goal_shape)))  # a tree's: its effectors' coordinates in turn
    size = workspace_size(arm)
    lam2_eye = (damping * size) ** 2 * np.eye(goals.shape[1])
    tol = default_tolerance(arm) if tol is None else float(tol)
    model, data = arm.model, _data(arm)
    lower, upper = arm.lower, arm.upper
    within, to_pin, limited = _vector_tools(arm)

    def error(qi, goal):
        pin.forwardKinematics(model, data, to_pin(qi))
        e = _task_error(arm, data, goal, axes)
        return e, float(np.sqrt(e @ e))

    m = len(axes)

    def worst(e):
        """The error reported and held to tol: the distance of the effector farthest from its goal
        (a serial arm's one), not the stacked norm, so within tol means every effector within it."""
        return float(np.sqrt(max(e[k:k + m] @ e[k:k + m] for k in range(0, len(e), m))))

    def close(e, err):
        """Within tolerance: err (the stacked norm) is the one effector's distance on a serial arm."""
        return err < tol if m == len(e) else worst(e) < tol

    bearing = _bearing(arm) if turn and not arm.is_tree else None
    if bearing is not None:  # Python floats for _turned's scalar math
        bearing = (tuple(bearing[0].tolist()), None if bearing[1] is None else tuple(bearing[1].tolist()))
    continuous0 = bool(arm.chain.continuous[0])

    def start(qi, goal, e=None, err=None):
        """qi and its error (e, err when known), after the turn when that lowers it."""
        if e is None:
            e, err = error(qi, goal)
        if bearing is not None and err >= tol:
            q_try = _turned(qi, goal - e, goal, bearing, lower, upper, continuous0)
            e_try, err_try = error(q_try, goal)
            if err_try < err:
                return q_try, e_try, err_try
        return qi, e, err

    def descend(qi, e, err, goal, most):
        """At most `most` steps; stuck: no step length lowered the error (a local minimum, or a goal
        out of reach)."""
        k = 0
        while not close(e, err) and k < most:
            if curved:
                J, parts = _task_jacobian_axes(arm, data, to_pin(qi), axes)  # (m, nq)
            else:
                J = _task_jacobian(arm, data, to_pin(qi), axes)
            dq, Jf, K = _held_step(J, e, qi, lower, upper, limited, lam2_eye)
            bend = 0.0
            if curved:  # the arc's correction a / 2: J a = -d2p/dt2 along dq, with the held joints held
                bend = -0.5 * (Jf.T @ (K @ _curvature(parts, dq, axes)))
                if bend @ bend >= 0.5625 * (dq @ dq):  # |a| >= 1.5 |dq|: the second-order model is off
                    bend = 0.0
            k += 1
            for h in range(halvings + 1):
                t = 0.5**h
                q_try = within(qi + t * dq + (t * t) * bend)
                e_try, err_try = error(q_try, goal)
                if err_try < err:
                    break
            if err_try >= err:
                return qi, e, err, k, True
            qi, e, err = start(q_try, goal, e_try, err_try)  # and the turn again
        return qi, e, err, k, False

    first = min(steps, 1)  # the proposals' first steps; then the nearest takes the rest
    flippable = [j for j in range(1, arm.nq) if flips and not arm.is_prismatic[j]]
    # a tree with several proposals: each limb group (no joint shared) may keep another proposal's joints
    groups = [(np.concatenate([np.arange(e * m, (e + 1) * m) for e in g]),
               np.unique(np.concatenate([arm.chain.path(e) for e in g])), len(g))
              for g in arm.chain.limb_groups] if arm.is_tree and len(q) > 1 else []
    if len(groups) < 2:
        groups = []
    out_q, out_err = np.empty((len(goals), arm.nq)), np.zeros(len(goals))
    taken, choice = np.zeros(len(goals), np.int64), np.zeros(len(goals), np.int64)
    for i, goal in enumerate(goals):
        best, states = None, []
        for j in range(len(q)):
            seed = start(q[j, i], goal)
            state = descend(*seed, goal, first)
            states.append(state)
            if best is None or state[2] < best[2]:
                best, choice[i], before = state, j, seed[2]
            if close(best[1], best[2]):  # done: the later proposals cannot do better than within tolerance
                break
        if groups and len(states) > 1 and not close(best[1], best[2]):
            best, choice[i] = _limbwise(states, groups, error, goal, best, choice[i])
        if first and flippable and not close(best[1], best[2]) and best[2] > 0.1 * before:
            # the best first step took less than 90 % of the error off: the seed may sit on the wrong
            # side of a fold (a wrist turning its offset away from a goal near full reach); the best
            # proposal with one joint turned by half a turn (within its limits) is another proposal
            kept, tried = q[choice[i], i], []
            for j in flippable:
                qf = kept.copy()
                half = math.pi if qf[j] + math.pi <= upper[j] or not limited[j] else -math.pi
                qf[j] += half
                if limited[j] and not lower[j] <= qf[j] <= upper[j]:
                    continue
                tried.append((*start(within(qf), goal), j))
            tried.sort(key=lambda x: x[2])  # the two nearest the goal after the turn take the first step
            for qs, es, errs, j in tried[:2]:
                state = descend(qs, es, errs, goal, first)
                if state[2] < best[2]:
                    best, choice[i] = state, len(q) + j - 1
                if close(best[1], best[2]):
                    break
        qi, e, err, k, stuck = best
        if not stuck and k < steps:
            qi, e, err, more, _ = descend(qi, e, err, goal, steps - k)
            k += more
        out_q[i], out_err[i], taken[i] = qi, err if m == len(e) else worst(e), k
    several = len(q) > 1 or bool(first and flippable)
    return RefineResult(out_q, out_err, taken, time.perf_counter() - t0, choice if several else None, tol=tol)


def _limbwise(states: list, limbs: list, error, goal, best: tuple, chosen: int) -> tuple[tuple, int]:
    """A tree's proposals after their first steps, mixed limb group by limb group: each group keeps
    the joints of the proposal that put its own effectors nearest their goals (groups share no joint,
    so a group's effectors depend on its joints alone). (state, choice): the mix when it is nearer the
    goal than `best`, its choice the proposal its largest group kept; else best and chosen unchanged."""
    q_mix = states[0][0].copy()
    picks = []
    for rows, joints, _ in limbs:
        j = int(np.argmin([st[1][rows] @ st[1][rows] for st in states]))
        q_mix[joints] = states[j][0][joints]
        picks.append(j)
    if len(set(picks)) == 1:  # every group kept the same proposal: no mix
        return best, chosen
    e, err = error(q_mix, goal)
    if err >= best[2]:
        return best, chosen
    largest = int(np.argmax([size for *_, size in limbs]))
    return (q_mix, e, err, max(st[3] for st in states), False), picks[largest]


# ---------------------------------------------------------------- pose goals (robots.pose)
class _PoseProblem:
    """One arm's pose goals: the tool frame's residual (robots.pose.residual) at a joint vector, and
    damped Gauss-Newton steps on it within the joint limits, each goal's best iterate kept."""

    def __init__(self, arm: Arm, tol: float, angle_tol: float, damping: float, halvings: int):
        self.arm, self.axis = arm, pose.approach_axis(arm)
        self.tol, self.angle_tol, self.halvings = tol, angle_tol, halvings
        self.length = tol / angle_tol  # an error at tolerance weighs as much in angle as in position
        self.lam2_eye = (damping * workspace_size(arm)) ** 2 * np.eye(6)
        self.within, self.to_pin, self.limited = _vector_tools(arm)
        self.model, self.data, self.fid = arm.model, _data(arm), arm.ee_frame_id

    def state(self, q, goal, jacobian: bool):
        """(q, e, |e|, position error, angle error, Je or None) at q."""
        model, data, fid = self.model, self.data, self.fid
        q_pin = self.to_pin(q)
        if jacobian:
            J6 = pin.computeFrameJacobian(model, data, q_pin, fid, pin.LOCAL_WORLD_ALIGNED)  # and data.oMf[fid]
        else:
            pin.forwardKinematics(model, data, q_pin)
            pin.updateFramePlacement(model, data, fid)
            J6 = None
        e, Je, err_p, err_a = pose.residual(goal, data.oMf[fid], J6, self.axis, self.length)
        return q, e, math.sqrt(e @ e), err_p, err_a, Je

    def close(self, s) -> bool:
        return s[3] < self.tol and s[4] < self.angle_tol

    def descend(self, s, goal, most: int):
        """At most `most` steps from state s (Je may be None); (state, steps taken, stuck): stuck when
        no step length lowered |e| (a local minimum, a singular pose, a goal out of reach)."""
        arm = self.arm
        k = 0
        while not self.close(s) and k < most:
            if s[5] is None:
                s = self.state(s[0], goal, True)
            q, e, norm = s[0], s[1], s[2]
            dq, _, _ = _held_step(s[5], e, q, arm.lower, arm.upper, self.limited, self.lam2_eye)
            k += 1
            for h in range(self.halvings + 1):
                t = 0.5**h
                trial = self.state(self.within(q + t * dq), goal, False)
                if trial[2] < norm:
                    break
            if trial[2] >= norm:
                return s, k, True
            s = trial
        return s, k, False


def pose_tolerances(arm: Arm, tol=None, angle_tol=None) -> tuple[float, float]:
    """(tol [length], angle_tol [rad]) of pose goals: default_tolerance(arm) and 0.1 degree where
    None; ValueError unless both are finite and > 0."""
    tol = default_tolerance(arm) if tol is None else float(tol)
    angle_tol = pose.DEFAULT_ANGLE_TOL if angle_tol is None else float(angle_tol)
    if not (tol > 0 and angle_tol > 0 and math.isfinite(tol) and math.isfinite(angle_tol)):
        raise ValueError(f"{arm.name}: tol and angle_tol must be finite and > 0, got {tol!r} and {angle_tol!r}")
    return tol, angle_tol


def refine_pose(arm: Arm, poses, q0, *, steps: int = 3, tol: float | None = None, angle_tol: float | None = None,
                damping: float = 1e-3, halvings: int = 4) -> RefineResult:
    """Pose goals made exact: at most `steps` damped Gauss-Newton steps in SE(3) from q0 toward each
    pose (robots.refine takes (n, 4, 4) goals here).

        e_k  = (p_g - p(q_k), L log3(R_g R(q_k)^T))      (robots.pose.residual; an approach axis: L (g - a))
        Je_k = (J_v, L Jlog3(R_g R^T) J_w)              J: Pinocchio's 6-row frame Jacobian, LOCAL_WORLD_ALIGNED
        dq_k = Je^T (Je Je^T + lambda^2 I)^-1 e_k         with joints at a limit held (an active set)
        q_{k+1} = q_k + t dq_k,  t the first of 1, 1/2, 1/4, ... (halvings) that lowers |e|

    L = tol / angle_tol [length / rad] (6 cm at the defaults) weighs a turn against a move so that
    an error at tolerance weighs the same in both; lambda = damping x workspace_size guards singular
    poses. A 5-joint SO arm is held to its position and its approach axis (robots.pose.approach_axis),
    its roll left free. A goal stops once its position error is below tol (default:
    default_tolerance, 0.1 mm on a real arm) and its angle error below angle_tol [rad] (default 0.1
    degree); each goal keeps its best iterate. poses (n, 4, 4) (or one (4, 4)), checked by
    robots.pose.check_poses; q0 (n, nq), or (k, n, nq): k proposals for each goal, each taking the
    first step in turn until one is within tolerance, the nearest after it taking the rest
    (RefineResult.choice), as refine does with positions."""
    t0 = time.perf_counter()
    goals = pose.check_poses(poses, what=f"{arm.name}: pose goals")
    tol, angle_tol = pose_tolerances(arm, tol, angle_tol)
    q = np.asarray(q0, dtype=np.float64)
    if q.ndim not in (1, 2, 3) or q.shape[-1] != arm.nq or (q.ndim == 1 and len(goals) != 1) or \
            (q.ndim > 1 and q.shape[-2] != len(goals)) or (q.ndim == 3 and not len(q)):
        raise ValueError(f"{arm.name}: q0 must be ({len(goals)}, {arm.nq}) or (k, {len(goals)}, {arm.nq}) for "
                         f"{len(goals)} pose goals, got shape {np.shape(q0)}")
    q = arm.within_limits(q if q.ndim == 3 else np.atleast_2d(q)[None])  # (k, n, nq)
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ValueError(f"steps must be an integer >= 0, got {steps!r}")
    problem = _PoseProblem(arm, tol, angle_tol, damping, halvings)
    first = min(steps, 1)
    n = len(goals)
    out_q, out_err, out_angle = np.empty((n, arm.nq)), np.empty(n), np.empty(n)
    taken, choice = np.zeros(n, np.int64), np.zeros(n, np.int64)
    for i, goal in enumerate(goals):
        best = None
        for j in range(len(q)):
            state = problem.descend(problem.state(q[j, i].copy(), goal, False), goal, first)
            if best is None or state[0][2] < best[0][2]:
                best, choice[i] = state, j
            if problem.close(best[0]):
                break
        s, k, stuck = best
        if not stuck and k < steps:
            s, more, _ = problem.descend(s, goal, steps - k)
            k += more
        out_q[i], out_err[i], out_angle[i], taken[i] = s[0], s[3], s[4], k
    return RefineResult(out_q, out_err, taken, time.perf_counter() - t0, choice if len(q) > 1 else None,
                        angle=out_angle, tol=tol, angle_tol=angle_tol)


def dls_pose_ik(arm: Arm, goal, q0=None, *, restarts: int = 20, seconds: float | None = None, max_iter: int = 100,
                damping: float = 0.005, tol: float | None = None, angle_tol: float | None = None,
                seed: int | None = 0) -> IKResult:
    """One pose goal (4, 4) by damped least squares with random restarts, the KDL-like baseline:
    the damped Gauss-Newton steps of refine_pose from q0 (arm.rest by default), at most max_iter of
    them; when they stall short of tolerance, again from a joint vector drawn uniformly within the
    limits (a generator of `seed`), at most `restarts` times and, when `seconds` is given, only while
    that wall time lasts. damping: lambda as a fraction of workspace_size (larger than refine's: a
    start far from the goal passes near singular poses; 0.02, dls_ik's, converged on fewer poses of
    UR5 and Panda in more time: docs/pose.md). Returns the best iterate of all starts."""
    t0 = time.perf_counter()
    goals = pose.check_poses(goal, what=f"{arm.name}: pose goal")
    if len(goals) != 1:
        raise ValueError(f"{arm.name}: dls_pose_ik solves one pose (4, 4), got {len(goals)}: use refine_pose for many")
    tol, angle_tol = pose_tolerances(arm, tol, angle_tol)
    problem = _PoseProblem(arm, tol, angle_tol, damping, halvings=4)
    g = goals[0]
    rng = np.random.default_rng(seed)
    start = arm.rest.copy() if q0 is None else arm.within_limits(np.asarray(q0, dtype=np.float64).reshape(-1))
    best, iterations, r = None, 0, 0
    for r in range(int(restarts) + 1):
        if r:
            if seconds is not None and time.perf_counter() - t0 >= seconds:
                r -= 1
                break
            start = arm.lower + (arm.upper - arm.lower) * rng.random(arm.nq)
        s, k, _ = problem.descend(problem.state(start, g, False), g, max_iter)
        iterations += k
        if best is None or s[2] < best[2]:
            best = s
        if problem.close(best):
            break
    return IKResult(q=best[0], error=best[3], iterations=iterations, seconds=time.perf_counter() - t0,
                    converged=problem.close(best), angle=best[4], restarts=r)
