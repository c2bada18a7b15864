"""Damped least-squares inverse kinematics on an arm's Pinocchio model: the classical baseline.

One query iterates, from the rest pose q_0 = arm.rest,

    e_k  = g - p(q_k)[task_axes]                          task-space error, (m,)
    J_k  = J_p(q_k)[task_axes]                            translational frame Jacobian rows, (m, nq)
    dq_k = J_k^T (J_k J_k^T + lambda^2 I)^-1 e_k          (Wampler 1986; Buss 2004, eq. 11)
    q_{k+1} = clamp(q_k + dq_k)                           joint limits; continuous joints wrap

joints held at a limit that the step would push further are dropped from J for that step
(an active set), with J_p from `pinocchio.computeFrameJacobian` in the LOCAL_WORLD_ALIGNED frame of the
end-effector frame. The arm's chain has one velocity per joint coordinate (nv == nq), so dq is
a step in the arm's own coordinates. The damping lambda [length] is a fraction of the
workspace size, so one setting serves arms in metres and the paper's units alike.
It stops when ||e|| < tol, when the step stalls (an unreachable goal: the closest pose it
finds), or after max_iter iterations.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .arm import Arm

_local = threading.local()  # one pin.Data per thread and arm (pink's rule: Data is not shared)


@dataclass(frozen=True)
class IKResult:
    """q (nq,) within the limits; error = ||g - reach(q)|| [length]; iterations; seconds of
    wall time; converged: error < tol."""

    q: np.ndarray
    error: float
    iterations: int
    seconds: float
    converged: bool


def _step(J, e, bias, lam2) -> np.ndarray:
    """DLS step J# e plus the null-space posture term (I - J# J) bias, J# = J^T (J J^T + lam2 I)^-1."""
    J_pinv = J.T @ np.linalg.inv(J @ J.T + lam2 * np.eye(len(e)))  # (nq, m)
    return J_pinv @ e + bias - J_pinv @ (J @ bias)


def _data(arm: Arm) -> pin.Data:
    cache = getattr(_local, "data", None)
    if cache is None:
        cache = _local.data = {}
    d = cache.get(id(arm.model))
    if d is None:
        d = cache[id(arm.model)] = arm.model.createData()
    return d


def workspace_size(arm: Arm) -> float:
    """The largest extent of the task coordinates' bounding box [length]."""
    lo, hi = arm.workspace_bounds
    return float(np.max(hi - lo))


def dls_ik(arm: Arm, goal, q0=None, *, damping: float = 0.02, tol: float | None = None,
           max_iter: int = 100, max_step: float = 0.5, posture: float = 0.1) -> IKResult:
    """Solve reach(q) = goal by damped least squares, from q0 (arm.rest by default).

    goal: (len(task_axes),) task coordinates; damping: lambda as a fraction of workspace_size;
    tol: error threshold [length] (default 1e-4 * workspace_size).
    """
    t0 = time.perf_counter()
    goal = np.asarray(goal, dtype=np.float64).reshape(-1)
    axes = list(arm.task_axes)
    if goal.shape != (len(axes),):
        raise ValueError(f"{arm.name}: goal must have {len(axes)} coordinates, got shape {goal.shape}")
    size = workspace_size(arm)
    lam2 = (damping * size) ** 2
    tol = 1e-4 * size if tol is None else float(tol)
    model, data, fid = arm.model, _data(arm), arm.ee_frame_id
    q = np.array(arm.rest if q0 is None else q0, dtype=np.float64)
    cont = arm.chain.continuous.astype(bool)
    lower, upper = arm.lower, arm.upper
    mid = 0.5 * (lower + upper)
    direct = model.nq == arm.nq  # no continuous joint: Pinocchio's q is the arm's q
    err = np.inf
    it = 0
    for it in range(max_iter + 1):
        q_pin = q if direct else arm.to_pinocchio(q)
        pin.forwardKinematics(model, data, q_pin)
        pin.updateFramePlacement(model, data, fid)
        e = goal - data.oMf[fid].translation[axes]
        err = float(np.linalg.norm(e))
        if err < tol or it == max_iter:
            break
        J = pin.computeFrameJacobian(model, data, q_pin, fid, pin.LOCAL_WORLD_ALIGNED)[:3][axes]  # (m, nq)
        # toward mid-range, fading as the error does: leaves the rest pose's singularity, then vanishes
        bias = np.where(cont, 0.0, posture * min(1.0, err / (0.05 * size)) * (mid - q))
        dq = _step(J, e, bias, lam2)
        blocked = ((q <= lower) & (dq < 0) | (q >= upper) & (dq > 0)) & ~cont
        if blocked.any():  # a joint held at a limit: solve again without it (an active set)
            J[:, blocked] = 0.0
            dq = _step(J, e, bias, lam2)
            dq[blocked] = 0.0
        dq *= min(1.0, max_step / max(float(np.max(np.abs(dq))), 1e-300))
        q_new = q + dq
        q_new[cont] = (q_new[cont] + np.pi) % (2 * np.pi) - np.pi
        q_new = np.clip(q_new, lower, upper)
        if np.max(np.abs(q_new - q)) < 1e-10:  # stalled: a limit or an unreachable goal
            break
        q = q_new
    return IKResult(q=q, error=err, iterations=it, seconds=time.perf_counter() - t0, converged=err < tol)
