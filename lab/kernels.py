"""Compiled fitness kernels: network forward pass + forward kinematics + squared error, fused.

One call evaluates a whole population on all goals, without intermediate arrays:

    mse[p] = mean_g || goal_g - fk(joints(net_p(x_g)))[task_axes] ||^2

joints() is lab.encoding.Encoding.joints; its arrays travel as qmap = (offset, scale, lo, hi).

A controller whose output or error is NaN or infinite gets +inf.
tanh is computed as (e - 1) / (e + 1), e = exp(2 z) with |z| clipped at 20 (where tanh is 1 to
double precision): it agrees with math.tanh to a few ulp and costs less than half.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from robots.kinematics import chain_point

_JIT = dict(cache=True, nogil=True, fastmath=False)


@numba.njit(inline="always", **_JIT)
def tanh(z):
    if not (z > -20.0):  # also NaN, which must stay NaN
        return -1.0 if z <= -20.0 else z
    z = min(z, 20.0)
    e = math.exp(2.0 * z)
    return (e - 1.0) / (e + 1.0)


@numba.njit(inline="always", **_JIT)
def to_joint(a, o, qmap):
    """Output a of joint o -> joint value: offset + (a + 1) scale, clipped (NaN stays NaN)."""
    q_off, q_scale, q_lo, q_hi = qmap
    q = q_off[o] + (a + 1.0) * q_scale[o]
    if q < q_lo[o]:
        return q_lo[o]
    if q > q_hi[o]:
        return q_hi[o]
    return q


@numba.njit(inline="always", **_JIT)
def _sq_error(q, i, goal, axes, chain):
    rot, pos, kind, identity, ee_pos, joints = chain
    x, y, z = chain_point(q, i, rot, pos, kind, identity, ee_pos, joints)
    p = (x, y, z)
    err = 0.0
    for a in range(axes.shape[0]):
        d = goal[a] - p[axes[a]]
        err += d * d
    return err


@numba.njit(**_JIT)
def mlp_mse(X, goals, axes, W, nh, qmap, chain, out):
    """The paper's MLP for every row of W (P, D) on inputs X (n, ni): out (P,) <- MSE.

    Genome layout (paper, section 4.3): w_i = W[:(ni+1)*nh] as (ni+1, nh), bias the last input
    row; w_o = W[(ni+1)*nh:] as (nh, no). a_o = tanh(tanh([x, 1] w_i) w_o).
    """
    n, ni = X.shape
    no = qmap[0].shape[0]
    off = (ni + 1) * nh
    h = np.empty(nh)
    q = np.empty((1, no))
    for p in range(W.shape[0]):
        w = W[p]
        total = 0.0
        for g in range(n):
            for j in range(nh):
                s = w[ni * nh + j]
                for i in range(ni):
                    s += X[g, i] * w[i * nh + j]
                h[j] = tanh(s)
            for o in range(no):
                s = 0.0
                for j in range(nh):
                    s += h[j] * w[off + j * no + o]
                q[0, o] = to_joint(tanh(s), o, qmap)
            total += _sq_error(q, 0, goals[g], axes, chain)
        mse = total / n
        out[p] = mse if math.isfinite(mse) else np.inf


@numba.njit(**_JIT)
def mlp_forward(X, w, nh, no, out):
    """One MLP (weights w) on inputs X (n, ni): out (n, no) <- outputs in [-1, 1]."""
    n, ni = X.shape
    off = (ni + 1) * nh
    h = np.empty(nh)
    for g in range(n):
        for j in range(nh):
            s = w[ni * nh + j]
            for i in range(ni):
                s += X[g, i] * w[i * nh + j]
            h[j] = tanh(s)
        for o in range(no):
            s = 0.0
            for j in range(nh):
                s += h[j] * w[off + j * no + o]
            out[g, o] = tanh(s)


@numba.njit(**_JIT)
def graph_forward(X, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, no, out, p0, p1):
    """Feed-forward graphs (NEAT phenotypes) of programs p0..p1-1 on inputs X: out (P, n, no).

    Program p evaluates nodes starts[p] .. starts[p] + n_nodes[p] - 1 in order; node m computes
    tanh(bias[m] + response[m] * sum_l link_w[l] * v[link_src[l]]) over l in link_start[m] ..
    link_start[m + 1] - 1. Slots: 0 .. ni-1 hold the inputs, ni + k the k-th node of the
    program, and slot -1 a constant 0 (an output with no path from the inputs).
    out_slot (P, no) names the slot of each output.
    """
    n, ni = X.shape
    maxm = 0
    for p in range(p0, p1):
        maxm = max(maxm, n_nodes[p])
    v = np.zeros(ni + maxm)
    for p in range(p0, p1):
        s0 = starts[p]
        for g in range(n):
            for i in range(ni):
                v[i] = X[g, i]
            for k in range(n_nodes[p]):
                m = s0 + k
                s = 0.0
                for l in range(link_start[m], link_start[m + 1]):
                    s += link_w[l] * v[link_src[l]]
                v[ni + k] = tanh(bias[m] + response[m] * s)
            for o in range(no):
                slot = out_slot[p, o]
                out[p - p0, g, o] = 0.0 if slot < 0 else v[slot]


@numba.njit(**_JIT)
def joints_mse(A, goals, axes, qmap, chain, out):
    """Network outputs A (P, n, nq) in [-1, 1] -> out (P,) <- MSE over the goals."""
    P, n, no = A.shape
    q = np.empty((1, no))
    for p in range(P):
        total = 0.0
        for g in range(n):
            for o in range(no):
                q[0, o] = to_joint(A[p, g, o], o, qmap)
            total += _sq_error(q, 0, goals[g], axes, chain)
        mse = total / n
        out[p] = mse if math.isfinite(mse) else np.inf
