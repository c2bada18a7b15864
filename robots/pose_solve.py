"""A compiled pose solver: Levenberg-Marquardt steps in SE(3) from given starts, then random
restarts, within a time budget (TRAC-IK's way of meeting a success rate: restarts in 5 ms).

    from robots import pose, pose_solve
    arm = robots.load("ur5")
    goal = pose.sample_poses(arm, 1, seed=3)[0]                       # (4, 4)
    r = pose_solve.solve_pose(arm, goal, seconds=0.005)               # from the rest pose, then restarts
    r = pose_solve.solve_pose(arm, goal, starts=q_net, seconds=0.005) # from a network's answers first
    r.q, r.error, r.angle, r.converged, r.restarts                    # robots.ik.IKResult

robots.ik.refine_pose takes a few steps from each of many seeds through Pinocchio, one Python call
a step; this module runs whole descents in one compiled call (the batched kinematics' own
`tree_points`, the frame Jacobian as robots.pose's kernel builds it), so that a few thousand steps
fit in TRAC-IK's 5 ms budget. Each descent:

    e  = (p_g - p, L log3(R_g R^T))          (an approach-axis arm: L (g - a), robots.pose.residual)
    Je = (J_v, L Jr^-1(log3(R_g R^T)) J_w)   Jr^-1: SO(3)'s inverse right Jacobian (Pinocchio's Jlog3)
    dq = Je^T (Je Je^T + (|e|^2 + b^2) I)^-1 e   Sugihara's damping (|e|^2: strong far from the goal,
                                                   vanishing near it, where the steps converge quadratically)
    q  <- clip(q + t dq),  t the first of 1, 1/2, ..., 1/16 that lowers |e|; a joint held at a limit
                           the step pushes past is left out of the step (its column zeroed)

L = tol / angle_tol weighs an error at tolerance the same in angle as in position. A descent stops
within tolerance (position below tol and angle below angle_tol), after `iterations` steps, or when
no step length lowers |e|. The starts: the given ones in order (a network's proposals), then joint
vectors drawn uniformly within the limits (a generator of `seed`) while `seconds` of wall time
last (checked between batches of descents) or up to `restarts`. The best iterate of all is kept.

Nothing here knows about networks.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from robots import pose
from robots.arm import Arm
from robots.ik import IKResult, pose_tolerances, workspace_size
from robots.kinematics import tree_points
from robots.pose import jacobian_columns, tool_rotation_of

WRAP = True  # a revolute joint of a whole turn or more passes a limit by a whole turn (docs/results/pose.md)
BATCH = 8  # random starts a compiled call takes between two looks at the clock
STALL = 0.9  # a descent gives up when a step leaves more than this share of |e| (after its second step)
STEPS_FROM_START = 40  # steps a descent may take (measured: benchmarks/bench_pose.py, docs/results/pose.md)


@numba.njit(cache=True, nogil=True)
def _log3(E, w):
    """w (3,) <- log3(E) of a rotation E (3, 3); returns its angle in [0, pi]."""
    c = 0.5 * (E[0, 0] + E[1, 1] + E[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    vx, vy, vz = E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]  # 2 sin(theta) times the axis
    theta = math.atan2(0.5 * math.sqrt(vx * vx + vy * vy + vz * vz), c)  # exact near 0, unlike acos(c)
    if theta < 1e-6:  # sin(theta) / theta -> 1
        w[0], w[1], w[2] = 0.5 * vx, 0.5 * vy, 0.5 * vz
    elif theta > math.pi - 1e-4:  # near a half turn: the axis from the diagonal, its signs from v
        for k in range(3):
            w[k] = theta * math.sqrt(max(0.0, (E[k, k] - c) / (1.0 - c)))
        if vx < 0.0:
            w[0] = -w[0]
        if vy < 0.0:
            w[1] = -w[1]
        if vz < 0.0:
            w[2] = -w[2]
    else:
        f = theta / (2.0 * math.sin(theta))
        w[0], w[1], w[2] = f * vx, f * vy, f * vz
    return theta


@numba.njit(cache=True, nogil=True)
def _jr_inv(w, theta, M):
    """M (3, 3) <- SO(3)'s inverse right Jacobian at w: I + [w]x / 2 + (1 / theta^2 - (1 + cos theta) /
    (2 theta sin theta)) [w]x^2 (Pinocchio's Jlog3)."""
    if theta < 1e-6:
        k = 1.0 / 12.0
    elif theta > math.pi - 1e-6:
        k = 1.0 / (theta * theta)
    else:
        k = 1.0 / (theta * theta) - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    wx, wy, wz = w[0], w[1], w[2]
    W = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    W2 = W @ W
    for r in range(3):
        for c in range(3):
            M[r, c] = (1.0 if r == c else 0.0) + 0.5 * W[r, c] + k * W2[r, c]


@numba.njit(cache=True, nogil=True)
def _residual(q, gR, gp, chain, tool, axis, length, e, Je, want_j, scratch):
    """e (6,) and, when want_j, Je (6, n) at q (1, n); returns (|e|, position error, angle error).
    Callers pass want_j as np.bool_(...): a literal True or False would compile it twice."""
    rot, pos, kind, identity, parent, ee_joint, effector_pos = chain
    F, p, origins, axes, R, E, w, M = scratch
    tree_points(q, 0, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, p, 0, origins, axes)
    tool_rotation_of(F, ee_joint[0], tool, R)
    e[0], e[1], e[2] = gp[0] - p[0, 0, 0], gp[1] - p[0, 0, 1], gp[2] - p[0, 0, 2]
    err_p = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    n = q.shape[1]
    if want_j:
        jacobian_columns(p[0, 0], origins[0], axes, kind, Je)
    if axis[0] == 0.0 and axis[1] == 0.0 and axis[2] == 0.0:  # full pose
        for r in range(3):
            for c in range(3):
                E[r, c] = gR[r, 0] * R[c, 0] + gR[r, 1] * R[c, 1] + gR[r, 2] * R[c, 2]  # R_g R^T
        err_a = _log3(E, w)
        e[3], e[4], e[5] = length * w[0], length * w[1], length * w[2]
        if want_j:
            _jr_inv(w, err_a, M)
            for k in range(n):
                j0, j1, j2 = Je[3, k], Je[4, k], Je[5, k]
                Je[3, k] = length * (M[0, 0] * j0 + M[0, 1] * j1 + M[0, 2] * j2)
                Je[4, k] = length * (M[1, 0] * j0 + M[1, 1] * j1 + M[1, 2] * j2)
                Je[5, k] = length * (M[2, 0] * j0 + M[2, 1] * j1 + M[2, 2] * j2)
    else:  # the approach axis u: a = R u, g = R_g u
        a0 = R[0, 0] * axis[0] + R[0, 1] * axis[1] + R[0, 2] * axis[2]
        a1 = R[1, 0] * axis[0] + R[1, 1] * axis[1] + R[1, 2] * axis[2]
        a2 = R[2, 0] * axis[0] + R[2, 1] * axis[1] + R[2, 2] * axis[2]
        g0 = gR[0, 0] * axis[0] + gR[0, 1] * axis[1] + gR[0, 2] * axis[2]
        g1 = gR[1, 0] * axis[0] + gR[1, 1] * axis[1] + gR[1, 2] * axis[2]
        g2 = gR[2, 0] * axis[0] + gR[2, 1] * axis[1] + gR[2, 2] * axis[2]
        cx, cy, cz = a1 * g2 - a2 * g1, a2 * g0 - a0 * g2, a0 * g1 - a1 * g0
        err_a = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), a0 * g0 + a1 * g1 + a2 * g2)
        e[3], e[4], e[5] = length * (g0 - a0), length * (g1 - a1), length * (g2 - a2)
        if want_j:
            for k in range(n):
                j0, j1, j2 = Je[3, k], Je[4, k], Je[5, k]
                Je[3, k] = -length * (a1 * j2 - a2 * j1)
                Je[4, k] = -length * (a2 * j0 - a0 * j2)
                Je[5, k] = -length * (a0 * j1 - a1 * j0)
    norm = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2] + e[3] * e[3] + e[4] * e[4] + e[5] * e[5])
    return norm, err_p, err_a


@numba.njit(cache=True, nogil=True)
def _spd_solve(A, b, y):
    """y <- A^-1 b for a symmetric positive definite A (m, m) (J J^T + lambda^2 I), by Cholesky; A is
    overwritten by its factor. Written out rather than np.linalg.solve, whose LAPACK binding took
    a quarter of the pose solver's compile (docs/results/app-speed.md). A pivot that is not positive
    (NaN in, or a rounding that made A indefinite) gives a step the line search then rejects."""
    m = A.shape[0]
    for j in range(m):
        d = A[j, j]
        for k in range(j):
            d -= A[j, k] * A[j, k]
        d = math.sqrt(d) if d > 0.0 else 1e-300
        A[j, j] = d
        for i in range(j + 1, m):
            v = A[i, j]
            for k in range(j):
                v -= A[i, k] * A[j, k]
            A[i, j] = v / d
    for i in range(m):  # L z = b
        v = b[i]
        for k in range(i):
            v -= A[i, k] * y[k]
        y[i] = v / A[i, i]
    for i in range(m - 1, -1, -1):  # L^T y = z
        v = y[i]
        for k in range(i + 1, m):
            v -= A[k, i] * y[k]
        y[i] = v / A[i, i]


@numba.njit(cache=True, nogil=True, inline="always")
def _within(x, lo, hi, wrap):
    """x within [lo, hi]: a joint of a whole turn or more (wrap) by whole turns where that brings it
    inside (the same rotation), else clipped."""
    if wrap:
        if x > hi and x - 2.0 * math.pi >= lo:
            x -= 2.0 * math.pi
        elif x < lo and x + 2.0 * math.pi <= hi:
            x += 2.0 * math.pi
    return min(hi, max(lo, x))


@numba.njit(cache=True, nogil=True)
def descend_many(starts, gR, gp, chain, tool, axis, length, lower, upper, wrap, bias2, tol, atol, iterations, stall,
                 best):
    """Descents from each row of starts (S, n) in turn, until one ends within tolerance; best (n,) <-
    the best iterate of all. Returns (|e|, position error, angle error, steps taken, descents run)
    of best."""
    S, n = starts.shape
    q, trial = np.empty((1, n)), np.empty((1, n))
    e, e_try, Je, dq = np.empty(6), np.empty(6), np.empty((6, n)), np.empty(n)
    A, held, y = np.empty((6, 6)), np.zeros(n, np.bool_), np.empty(6)
    scratch = (np.empty((n, 12)), np.empty((1, 1, 3)), np.empty((1, n + 1, 3)), np.empty((n, 3)), np.empty((3, 3)),
               np.empty((3, 3)), np.empty(3), np.empty((3, 3)))
    best_norm, best_p, best_a, steps = np.inf, np.inf, np.inf, 0
    for s in range(S):
        for k in range(n):
            q[0, k] = _within(starts[s, k], lower[k], upper[k], wrap[k])
        norm, err_p, err_a = _residual(q, gR, gp, chain, tool, axis, length, e, Je, np.bool_(True), scratch)
        for it in range(iterations + 1):
            if norm < best_norm:
                best_norm, best_p, best_a = norm, err_p, err_a
                for k in range(n):  # loops, not slices: numba's shape-mismatch message costs compile time
                    best[k] = q[0, k]
            if (err_p < tol and err_a < atol) or it == iterations:
                break
            steps += 1
            lam2 = norm * norm + bias2
            for k in range(n):  # a joint at a limit the gradient pushes past is held
                g = Je[0, k] * e[0] + Je[1, k] * e[1] + Je[2, k] * e[2] + Je[3, k] * e[3] + Je[4, k] * e[4] + \
                    Je[5, k] * e[5]
                held[k] = not wrap[k] and ((q[0, k] <= lower[k] and g < 0.0) or (q[0, k] >= upper[k] and g > 0.0))
                if held[k]:
                    for r in range(6):
                        Je[r, k] = 0.0
            for r in range(6):
                for c in range(6):
                    acc = 0.0
                    for k in range(n):
                        acc += Je[r, k] * Je[c, k]
                    A[r, c] = acc + (lam2 if r == c else 0.0)
            _spd_solve(A, e, y)
            for k in range(n):
                dq[k] = Je[0, k] * y[0] + Je[1, k] * y[1] + Je[2, k] * y[2] + Je[3, k] * y[3] + Je[4, k] * y[4] + \
                    Je[5, k] * y[5]
            t, moved = 1.0, False
            for h in range(5):
                for k in range(n):
                    trial[0, k] = _within(q[0, k] + t * dq[k], lower[k], upper[k], wrap[k])
                n_try, p_try, a_try = _residual(trial, gR, gp, chain, tool, axis, length, e_try, Je, np.bool_(False), scratch)
                if n_try < norm:
                    moved = True
                    break
                t *= 0.5
            if not moved or (it >= 2 and n_try > stall * norm):  # stuck, or a slow crawl: the next start
                if moved and n_try < best_norm:
                    best_norm, best_p, best_a = n_try, p_try, a_try
                    for k in range(n):
                        best[k] = trial[0, k]
                break
            for k in range(n):
                q[0, k] = trial[0, k]
            norm, err_p, err_a = _residual(q, gR, gp, chain, tool, axis, length, e, Je, np.bool_(True), scratch)
        if best_p < tol and best_a < atol:
            return best_norm, best_p, best_a, steps, s + 1
    return best_norm, best_p, best_a, steps, S


def _setup(arm: Arm):
    """The compiled call's arm arguments: (chain, tool rotation, approach axis or zeros)."""
    axis = pose.approach_axis(arm)
    return (arm.chain.tree_arrays, pose._tool_rotation(arm),
            np.zeros(3) if axis is None else np.asarray(axis, dtype=np.float64))


def solve_pose(arm: Arm, goal, starts=None, *, seconds: float | None = 0.005, restarts: int | None = None,
               tol: float | None = None, angle_tol: float | None = None, iterations: int = STEPS_FROM_START,
               damping: float = 1e-4, stall: float = STALL, seed: int | None = 0, clock=time.perf_counter) -> IKResult:
    """One pose goal (4, 4) of arm's tool frame: descents from `starts` ((n,) or (k, n) joint vectors,
    tried in order; none: arm.rest), then from uniformly random joint vectors while `seconds` last
    on `clock` (checked every BATCH descents; None: no limit) and at most `restarts` of them (None:
    no limit; seconds and restarts both None: no restarts). tol [length] and angle_tol [rad]:
    robots.ik.pose_tolerances (default 0.1 mm and 0.1 degree); iterations: steps a descent may take;
    damping: b in the damping |e|^2 + b^2, as a fraction of robots.ik.workspace_size. Returns an
    IKResult (q, error, iterations: steps in all, seconds, converged, angle, restarts) of the best
    iterate. ValueError, naming the problem, for a goal that is not one pose or starts of another shape.
    Many goals of one arm: PoseSolver, which prepares the arm's arrays once."""
    t0 = clock()
    solver = PoseSolver(arm, tol=tol, angle_tol=angle_tol, iterations=iterations, damping=damping, stall=stall)
    return solver.solve(goal, starts, seconds=seconds, restarts=restarts, seed=seed, clock=clock, t0=t0)


class PoseSolver:
    """solve_pose for many goals of one arm: the arm's arrays, tolerances and settings prepared once
    (half the time of a pose solved from its first start was that preparation, redone each goal)."""

    def __init__(self, arm: Arm, *, tol: float | None = None, angle_tol: float | None = None,
                 iterations: int = STEPS_FROM_START, damping: float = 1e-4, stall: float = STALL):
        self.arm = arm
        self.tol, self.angle_tol = pose_tolerances(arm, tol, angle_tol)
        if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
            raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
        self.nq = arm.nq
        self.lower, self.upper = np.asarray(arm.lower, np.float64), np.asarray(arm.upper, np.float64)
        self.span = self.upper - self.lower
        # a writeable copy: one compiled signature for every caller (a readonly array would be another)
        self.rest = np.array(arm.rest, dtype=np.float64, order="C", ndmin=2)
        chain, tool, axis = _setup(arm)
        wrap = (~np.asarray(arm.is_prismatic, bool)) & (self.span >= 2 * np.pi - 1e-9) & bool(WRAP)
        self._args = (chain, tool, axis, self.tol / self.angle_tol, self.lower, self.upper, np.asarray(wrap, np.bool_),
                      (damping * workspace_size(arm)) ** 2, self.tol, self.angle_tol, int(iterations), float(stall))

    def solve(self, goal, starts=None, *, seconds: float | None = 0.005, restarts: int | None = None,
              seed: int | None = 0, clock=time.perf_counter, t0: float | None = None) -> IKResult:
        """solve_pose's answer for one goal (4, 4) with this solver's arm and settings."""
        t0 = clock() if t0 is None else t0
        arm, tol, angle_tol = self.arm, self.tol, self.angle_tol
        goals = pose.check_poses(goal, what=f"{arm.name}: pose goal")
        if len(goals) != 1:
            raise ValueError(f"{arm.name}: solve_pose solves one pose (4, 4), got {len(goals)}")
        if starts is None:
            starts = self.rest
        else:
            starts = np.array(starts, dtype=np.float64, order="C", ndmin=2)
            if starts.ndim != 2 or starts.shape[1] != self.nq or not len(starts) or not np.isfinite(starts).all():
                raise ValueError(f"{arm.name}: starts must be finite joint vectors ({self.nq},) or (k, {self.nq}), "
                                 f"got shape {np.shape(starts)}")
        g = goals[0]
        gR, gp = np.ascontiguousarray(g[:3, :3]), np.ascontiguousarray(g[:3, 3])
        chain, tool, axis, *rest = self._args
        best = np.empty(self.nq)
        norm, err_p, err_a, steps, _ = descend_many(starts, gR, gp, chain, tool, axis, *rest, best)
        q = best.copy()
        rng = None  # made when the first restart needs it (the same draws as made up front)
        done = 0
        more = seconds is not None or restarts is not None
        while more and not (err_p < tol and err_a < angle_tol):
            if (seconds is not None and clock() - t0 >= seconds) or (restarts is not None and done >= restarts):
                break
            rng = np.random.default_rng(seed) if rng is None else rng
            k = BATCH if restarts is None else min(BATCH, restarts - done)
            draws = self.lower + self.span * rng.random((k, self.nq))
            n2, p2, a2, s2, ran = descend_many(draws, gR, gp, chain, tool, axis, *rest, best)
            steps += s2
            done += ran
            if n2 < norm:
                norm, err_p, err_a, q = n2, p2, a2, best.copy()
        return IKResult(q=q, error=float(err_p), iterations=int(steps), seconds=clock() - t0,
                        converged=bool(err_p < tol and err_a < angle_tol), angle=float(err_a), restarts=done)
