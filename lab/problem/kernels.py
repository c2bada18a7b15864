"""Compiled fitness kernels: network forward pass + forward kinematics + squared error, fused.

One call evaluates a whole population on all goals:

    mse[p] = mean_g || goal_g - fk(joints(net_p(x_g)))[task_axes] ||^2

joints() is lab.problem.encoding.Encoding.joints; its arrays travel as qmap = (offset, scale, lo, hi,
turn): turn (NO_TURN when off) turns the first joint toward each goal's bearing in closed form
(Encoding.turn) before the error is taken.
A controller whose output or error is NaN or infinite gets +inf.
A tree of several end effectors has its own kernels (tree_mlp_mse, tree_graph_mse, tree_joints_mse):
the squared error of a goal is the sum over the effectors of each one's, every effector's own serial
chain composed by fk_sq_errors (see pack_tree).

Layout: goals run along the innermost, contiguous axis ("structure of arrays": inputs (ni, n),
hidden activations (nh, n), joint values (nq, n), the chain's rotation (3, 3, n)), so every
loop over goals is a straight run of arithmetic that LLVM turns into SIMD code. The
transcendental functions are written for that too, from a table and a short polynomial, to
about 1 ulp (tested against numpy):
    tanh(z) = sign(z) (1 - e) / (1 + e),  e = exp(-2|z|) = E[j] exp(-r),  2|z| = j/16 + r;
    sin/cos(x) from S[j], C[j] at x_j = -8 + j/16 and the Taylor series of the rest r < 1/16
    (outside [-8, 8], and for NaN, the library functions).
The only fast-math flag is nsz: no reassociation or contraction, so every compiled variant gives
the same bits, and NaN and infinity keep their meaning.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# No reassoc/contract/arcp: results must not depend on which compiled specialization runs
# (numba may pick an existing one for another array layout), so same seed = same run, bit for bit.
FASTMATH = {"nsz"}
_JIT = dict(cache=True, nogil=True, fastmath=FASTMATH, error_model="numpy")  # numpy: no ZeroDivisionError checks, which block SIMD

_EXP_STEP = 16.0
EXP_TABLE = np.exp(-np.arange(0, 641 + 1) / _EXP_STEP)  # exp(-j/16), 2|z| up to 40
_SC_LO, _SC_STEP = -8.0, 16.0
SIN_TABLE = np.sin(_SC_LO + np.arange(257) / _SC_STEP)
COS_TABLE = np.cos(_SC_LO + np.arange(257) / _SC_STEP)


@numba.njit(**_JIT)
def tanh_row(x):
    """x <- tanh(x), in place, for a 1-D contiguous array."""
    T = EXP_TABLE
    for i in range(x.shape[0]):
        v = x[i]
        a = min(abs(v), 20.0) * 2.0  # tanh(20) is 1 to double precision
        j = min(max(int(a * _EXP_STEP), 0), 640)  # clamped: NaN gives a garbage but safe index
        r = j * (1.0 / _EXP_STEP) - a  # in (-1/16, 0]
        p = 1.0 + r * (1.0 + r * (1 / 2 + r * (1 / 6 + r * (1 / 24 + r * (1 / 120 + r * (
            1 / 720 + r * (1 / 5040 + r * (1 / 40320 + r * (1 / 362880)))))))))
        e = T[j] * p
        t = (1.0 - e) / (1.0 + e)
        t = t if v >= 0.0 else -t
        x[i] = t if v == v else v


@numba.njit(**_JIT)
def sincos_row(x, s, c):
    """s, c <- sin(x), cos(x) for 1-D contiguous arrays."""
    S, C = SIN_TABLE, COS_TABLE
    n = x.shape[0]
    for i in range(n):
        v = x[i]
        j = min(max(int((v - _SC_LO) * _SC_STEP), 0), 255)
        r = v - (_SC_LO + j * (1.0 / _SC_STEP))  # in [0, 1/16) inside the table
        r2 = r * r
        sr = r * (1.0 - r2 * (1 / 6 - r2 * (1 / 120 - r2 * (1 / 5040 - r2 * (1 / 362880)))))
        cr = 1.0 - r2 * (1 / 2 - r2 * (1 / 24 - r2 * (1 / 720 - r2 * (1 / 40320 - r2 * (1 / 3628800)))))
        s[i] = S[j] * cr + C[j] * sr
        c[i] = C[j] * cr - S[j] * sr
    for i in range(n):
        v = x[i]
        if not (v >= -7.99 and v <= 7.99):  # outside the table, or NaN
            s[i] = math.sin(v)
            c[i] = math.cos(v)


@numba.njit(**_JIT)
def _to_joints_row(a, o, qmap):
    """a <- joint values of output row o: offset + (a + 1) scale, clipped (NaN stays NaN)."""
    q_off, q_scale, q_lo, q_hi = qmap[0], qmap[1], qmap[2], qmap[3]
    off, scale, lo, hi = q_off[o], q_scale[o], q_lo[o], q_hi[o]
    for g in range(a.shape[0]):
        q = off + (a[g] + 1.0) * scale
        q = lo if q < lo else q
        a[g] = hi if q > hi else q


# the polar inputs polar_inputs computes (lab.problem.encoding's features of the same names)
POLAR_MODES = {"reach": 0, "sphere": 1, "bearings": 2}


@numba.njit(**_JIT)
def polar_inputs(goals, mode, r_max, z_c, rho_max, ax, ay, facing, in_lo, in_hi, out):
    """out (n, ni) <- network inputs in about [-1, 1] of goals (n, k): the polar features of POLAR_MODES
    (encoding._raw_features's, its numpy the reference) scaled by in_lo, in_hi. Per goal: the goal,
    then r, phi (bearings: from `facing`) and sqrt(1 - r / r_max) about the base axis through (ax, ay);
    sphere and bearings then rho, atan2(h, r), sqrt(1 - rho / rho_max) about (0, 0, z_c); bearings
    then phi - pi. The slacks are clipped to [0, 1], the angles wrapped into [-pi, pi)."""
    two_pi = 2.0 * math.pi
    k = goals.shape[1]
    for g in range(goals.shape[0]):
        x, y = goals[g, 0] - ax, goals[g, 1] - ay
        r = math.hypot(x, y)
        phi = math.atan2(y, x)
        if mode == 2:
            phi = (phi - facing + math.pi) % two_pi - math.pi
        for a in range(k):
            out[g, a] = goals[g, a]
        c = k
        out[g, c], out[g, c + 1] = r, phi
        out[g, c + 2] = math.sqrt(min(1.0, max(0.0, 1.0 - r / r_max)))
        c += 3
        if mode >= 1:
            h = goals[g, 2] - z_c
            rho = math.hypot(r, h)
            out[g, c], out[g, c + 1] = rho, math.atan2(h, r)
            out[g, c + 2] = math.sqrt(min(1.0, max(0.0, 1.0 - rho / rho_max)))
            c += 3
            if mode == 2:
                out[g, c] = (phi - math.pi + math.pi) % two_pi - math.pi
                c += 1
        for j in range(c):
            out[g, j] = 2.0 * (out[g, j] - in_lo[j]) / (in_hi[j] - in_lo[j]) - 1.0


# The turn of a controller that turns its first joint in closed form (lab.problem.encoding.Encoding.turn):
# [on, c (3), w (3), lower, upper, continuous] of the first joint's axis (point c, unit direction w)
NO_TURN = np.zeros(10)


@numba.njit(**_JIT)
def _chain_frames(Q, chain, R, P):
    """R (3, 3, N), P (3, N) <- the last joint's frame of joint values Q (nq, N) (chain as fk_sq_errors)."""
    rot, pos, kind, identity, ee_pos = chain
    n = Q.shape[1]
    T, S, C = np.empty((3, 3, n)), np.empty(n), np.empty(n)
    for a in range(3):
        for b in range(3):
            v = 1.0 if a == b else 0.0
            for g in range(n):
                R[a, b, g] = v
        for g in range(n):
            P[a, g] = 0.0
    for k in range(rot.shape[0]):
        for a in range(3):
            p0, p1, p2 = pos[k, 0], pos[k, 1], pos[k, 2]
            for g in range(n):
                P[a, g] += R[a, 0, g] * p0 + R[a, 1, g] * p1 + R[a, 2, g] * p2
        if not identity[k]:
            m = rot[k]
            for a in range(3):
                for b in range(3):
                    m0, m1, m2 = m[0, b], m[1, b], m[2, b]
                    for g in range(n):
                        T[a, b, g] = R[a, 0, g] * m0 + R[a, 1, g] * m1 + R[a, 2, g] * m2
            for a in range(3):
                for b in range(3):
                    for g in range(n):
                        R[a, b, g] = T[a, b, g]
        if kind[k] == 0:
            sincos_row(Q[k], S, C)
            for a in range(3):
                for g in range(n):
                    r0 = R[a, 0, g]
                    r1 = R[a, 1, g]
                    R[a, 0, g] = C[g] * r0 + S[g] * r1
                    R[a, 1, g] = C[g] * r1 - S[g] * r0
        else:
            for a in range(3):
                for g in range(n):
                    P[a, g] += Q[k, g] * R[a, 2, g]


@numba.njit(**_JIT)
def fk_sq_errors(Q, goalsT, axes, chain, E):
    """E (N,) <- squared task-space error of joint values Q (nq, N) against goals (k, N).

    chain = (rot, pos, kind, identity, ee_pos) as robots.kinematics.ChainKinematics.arrays.
    Mirrors robots.kinematics.chain_point:
    per joint k, p += R pos[k]; R = R rot[k]; revolute: mix columns 0 and 1 by (cos, sin);
    prismatic: p += q R[:, 2].
    """
    fk_turned_sq_errors(Q, goalsT, axes, chain, NO_TURN, E)


@numba.njit(**_JIT)
def _turn_of(q0, theta, turn):
    """The first joint's value after its turn by theta in [-pi, pi] toward the goal's bearing, and
    the angle still to go: q0 + theta, or that a whole turn away, within the limits (a continuous
    joint: turned by whole turns into its range); when none is, the limit nearer in angle (the
    largest cos of the angle still to go, as robots.ik's closed-form turn chooses)."""
    lo, hi = turn[7], turn[8]
    t = q0 + theta
    if turn[9] != 0.0:  # continuous: whole turns into its range, the bearing met exactly
        return lo + (t - lo) % (2 * math.pi), 0.0
    for k in range(3):
        c = t + (0.0 if k == 0 else (-2 * math.pi if k == 1 else 2 * math.pi))
        if lo <= c <= hi:
            return c, 0.0
    best = lo if math.cos(t - lo) >= math.cos(t - hi) else hi
    return best, t - best


@numba.njit(**_JIT)
def _turn_row(P, R, ee_pos, Q, goalsT, turn, E, write):
    """Per goal g, the end effector p = P + R ee_pos turned about the first joint's axis toward goal g:
    E[g] <- its squared error after the turn (write: Q[0, g] <- the turned joint value).
    With u = p - c, v = goal - c split into heights h along w and radial parts of lengths r, a turn by
    the angle theta between the radial parts leaves |p' - goal|^2 = (r_u - r_v)^2 + (h_u - h_v)^2,
    plus 4 r_u r_v sin^2(d / 2) when the limits stop it d short."""
    cx, cy, cz, wx, wy, wz = turn[1], turn[2], turn[3], turn[4], turn[5], turn[6]
    e0, e1, e2 = ee_pos[0], ee_pos[1], ee_pos[2]
    for g in range(Q.shape[1]):
        ux = P[0, g] + R[0, 0, g] * e0 + R[0, 1, g] * e1 + R[0, 2, g] * e2 - cx
        uy = P[1, g] + R[1, 0, g] * e0 + R[1, 1, g] * e1 + R[1, 2, g] * e2 - cy
        uz = P[2, g] + R[2, 0, g] * e0 + R[2, 1, g] * e1 + R[2, 2, g] * e2 - cz
        vx, vy, vz = goalsT[0, g] - cx, goalsT[1, g] - cy, goalsT[2, g] - cz
        hu = ux * wx + uy * wy + uz * wz
        hv = vx * wx + vy * wy + vz * wz
        ux, uy, uz = ux - hu * wx, uy - hu * wy, uz - hu * wz
        vx, vy, vz = vx - hv * wx, vy - hv * wy, vz - hv * wz
        ru = math.sqrt(ux * ux + uy * uy + uz * uz)
        rv = math.sqrt(vx * vx + vy * vy + vz * vz)
        sin_part = (uy * vz - uz * vy) * wx + (uz * vx - ux * vz) * wy + (ux * vy - uy * vx) * wz
        theta = math.atan2(sin_part, ux * vx + uy * vy + uz * vz)
        q0, short = _turn_of(Q[0, g], theta, turn)
        dr, dh, s = ru - rv, hu - hv, math.sin(0.5 * short)
        E[g] = dr * dr + dh * dh + 4.0 * ru * rv * s * s
        if write:
            Q[0, g] = q0


@numba.njit(**_JIT)
def fk_turned_sq_errors(Q, goalsT, axes, chain, turn, E):
    """fk_sq_errors, the first joint turned toward each goal's bearing first when turn[0] is set
    (3 task axes, in the order x, y, z)."""
    rot, pos, kind, identity, ee_pos = chain
    n = Q.shape[1]
    R, P = np.empty((3, 3, n)), np.empty((3, n))
    _chain_frames(Q, chain, R, P)
    if turn[0] != 0.0:
        _turn_row(P, R, ee_pos, Q, goalsT, turn, E, np.bool_(False))
        return
    e0, e1, e2 = ee_pos[0], ee_pos[1], ee_pos[2]
    for g in range(n):
        E[g] = 0.0
    for t in range(axes.shape[0]):
        a = axes[t]
        for g in range(n):
            d = goalsT[t, g] - (P[a, g] + R[a, 0, g] * e0 + R[a, 1, g] * e1 + R[a, 2, g] * e2)
            E[g] += d * d


@numba.njit(**_JIT)
def turn_first_joint(Q, goalsT, chain, turn):
    """Q[0] <- the first joint of joint values Q (nq, N) turned toward each goal's bearing (goalsT (3, N))."""
    n = Q.shape[1]
    R, P, E = np.empty((3, 3, n)), np.empty((3, n)), np.empty(n)
    _chain_frames(Q, chain, R, P)
    _turn_row(P, R, chain[4], Q, goalsT, turn, E, np.bool_(True))


@numba.njit(**_JIT)
def _segment_means(E, n, out):
    """out[p] <- mean of E[p n : (p + 1) n], +inf where it is not finite."""
    for p in range(out.shape[0]):
        total = 0.0
        for g in range(p * n, (p + 1) * n):
            total += E[g]
        mse = total / n
        out[p] = mse if math.isfinite(mse) else np.inf


@numba.njit(**_JIT)
def _population_mse(A, goalsT, axes, qmap, chain, out):
    """A (nq, P n): outputs of P controllers side by side -> out (P,) <- MSE of each."""
    for o in range(A.shape[0]):
        _to_joints_row(A[o], o, qmap)
    _joints_side_by_side_mse(A, goalsT, axes, chain, qmap[4], out)


@numba.njit(**_JIT)
def _joints_side_by_side_mse(Q, goalsT, axes, chain, turn, out):
    """Q (nq, P n): joint values of P controllers side by side -> out (P,) <- MSE of each."""
    n = goalsT.shape[1]
    P = out.shape[0]
    tiled = _tiled(goalsT, P)
    E = np.empty(P * n)
    fk_turned_sq_errors(Q, tiled, axes, chain, turn, E)
    _segment_means(E, n, out)


@numba.njit(**_JIT)
def mlp_outputs(XT, W, nh, A):
    """The paper's MLP (section 4.3) of every row of W (P, D) on inputs XT (ni, n):
    A (no, P n) <- outputs, controller p in columns p n .. (p + 1) n - 1.

    Genome layout: w_i = w[:(ni+1)*nh] as (ni+1, nh), bias the last input row; w_o = w[(ni+1)*nh:]
    as (nh, no). a_o = tanh(tanh([x, 1] w_i) w_o).
    """
    mlp_offset_outputs(XT, W, nh, np.zeros(A.shape[0]), A)


@numba.njit(**_JIT)
def mlp_offset_outputs(XT, W, nh, offsets, A):
    """mlp_outputs with a fixed offset added to each output's pre-activation:
    a_o = tanh(offsets[o] + tanh([x, 1] w_i) w_o) (zero offsets: mlp_outputs, bit for bit)."""
    ni, n = XT.shape
    no = A.shape[0]
    off = (ni + 1) * nh
    H = np.empty((nh, W.shape[0] * n))
    for p in range(W.shape[0]):
        w = W[p]
        c0 = p * n
        for j in range(nh):
            b = w[ni * nh + j]
            for g in range(n):
                H[j, c0 + g] = b
            for i in range(ni):
                wij = w[i * nh + j]
                for g in range(n):
                    H[j, c0 + g] += wij * XT[i, g]
    for j in range(nh):
        tanh_row(H[j])
    for p in range(W.shape[0]):
        w = W[p]
        c0 = p * n
        for o in range(no):
            start = offsets[o]
            for g in range(n):
                A[o, c0 + g] = start
            for j in range(nh):
                wjo = w[off + j * no + o]
                for g in range(n):
                    A[o, c0 + g] += wjo * H[j, c0 + g]
    for o in range(no):
        tanh_row(A[o])


@numba.njit(**_JIT)
def mlp_mse(XT, goalsT, axes, W, nh, qmap, chain, out):
    """MSE of the MLP of every row of W (P, D) on inputs XT (ni, n) and goals (k, n): out (P,)."""
    A = np.empty((qmap[0].shape[0], W.shape[0] * XT.shape[1]))
    mlp_outputs(XT, W, nh, A)
    _population_mse(A, goalsT, axes, qmap, chain, out)


@numba.njit(**_JIT)
def _graph_rows(XT, p, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, V, A):
    """Program p on inputs XT (ni, n): V (ni + nodes, n) node values, A (no, n) <- outputs.

    Program p evaluates nodes starts[p] .. starts[p] + n_nodes[p] - 1 in order; node m computes
    tanh(bias[m] + response[m] * sum_l link_w[l] * v[link_src[l]]) over l in link_start[m] ..
    link_start[m + 1] - 1. Slots: 0 .. ni-1 hold the inputs, ni + k the k-th node of the
    program; out_slot[p, o] is the slot of output o, -1 for a constant 0 (no path from the inputs).
    """
    ni, n = XT.shape
    s0 = starts[p]
    for k in range(n_nodes[p]):
        m = s0 + k
        row = V[ni + k]
        for g in range(n):
            row[g] = 0.0
        for l in range(link_start[m], link_start[m + 1]):
            w = link_w[l]
            src = V[link_src[l]]
            for g in range(n):
                row[g] += w * src[g]
        b, r = bias[m], response[m]
        for g in range(n):
            row[g] = b + r * row[g]
        tanh_row(row)
    for o in range(A.shape[0]):
        slot = out_slot[p, o]
        for g in range(n):
            A[o, g] = 0.0 if slot < 0 else V[slot, g]


@numba.njit(**_JIT)
def _graph_scratch(XT, n_nodes):
    ni, n = XT.shape
    V = np.empty((ni + max(1, n_nodes.max()), n))
    for i in range(ni):  # loops, not slices (see _tiled)
        for g in range(n):
            V[i, g] = XT[i, g]
    return V


@numba.njit(**_JIT)
def graph_forward(XT, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, no, out):
    """Outputs of every program on inputs XT (ni, n): out (P, no, n) in [-1, 1]."""
    V = _graph_scratch(XT, n_nodes)
    for p in range(starts.shape[0]):
        _graph_rows(XT, p, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, V, out[p])


@numba.njit(**_JIT)
def graph_mse(XT, goalsT, axes, program, qmap, chain, out):
    """MSE of every compiled graph (lab.problem.controllers.compile_programs) on the goals: out (P,)."""
    starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, no = program
    n = XT.shape[1]
    V = _graph_scratch(XT, n_nodes)
    A = np.empty((no, starts.shape[0] * n))
    for p in range(starts.shape[0]):
        _graph_rows(XT, p, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, V,
                    A[:, p * n:(p + 1) * n])
    _population_mse(A, goalsT, axes, qmap, chain, out)


@numba.njit(**_JIT)
def joints_mse(QT, goalsT, axes, chain, turn, out):
    """MSE of joint values QT (P, nq, n) on the goals, the first joint turned when turn[0] is set: out (P,)."""
    P, nq, n = QT.shape
    Q = np.empty((nq, P * n))
    for p in range(P):  # loops, not slices (see _tiled)
        for k in range(nq):
            for g in range(n):
                Q[k, p * n + g] = QT[p, k, g]
    _joints_side_by_side_mse(Q, goalsT, axes, chain, turn, out)


@numba.njit(**_JIT)
def _tiled(G, P):
    """G (k, n) repeated P times side by side: (k, P n)."""
    n = G.shape[1]
    out = np.empty((G.shape[0], P * n))
    for p in range(P):  # loops, not a slice assignment: numba's shape-mismatch message for one
        for a in range(G.shape[0]):  # costs seconds of compile (docs/results/app-speed.md)
            for g in range(n):
                out[a, p * n + g] = G[a, g]
    return out


@numba.njit(**_JIT)
def _heads_setup(XT, goalsT, W, nh, offsets, qmap):
    """A multi-head MLP's scratch: outputs A (heads nq, P n) of every row of W, the goals tiled P
    times, the least errors E so far (+inf), one head's errors Eh and joint values Q (nq, P n)."""
    nq = qmap[0].shape[0]
    N = W.shape[0] * XT.shape[1]
    A = np.empty((offsets.shape[0], N))
    mlp_offset_outputs(XT, W, nh, offsets, A)
    return A, _tiled(goalsT, W.shape[0]), np.full(N, np.inf), np.empty(N), np.empty((nq, N))


@numba.njit(**_JIT)
def _head_joints(A, h, qmap, Q):
    """Q <- head h's joint values from the outputs A."""
    nq = Q.shape[0]
    for o in range(nq):
        for g in range(Q.shape[1]):
            Q[o, g] = A[h * nq + o, g]
        _to_joints_row(Q[o], o, qmap)


@numba.njit(**_JIT)
def _keep_least(Eh, E):
    """E <- the smaller of E and Eh (NaN never is: a goal no head reaches stays +inf)."""
    for g in range(E.shape[0]):
        if Eh[g] < E[g]:
            E[g] = Eh[g]


@numba.njit(**_JIT)
def mlp_heads_mse(XT, goalsT, axes, W, nh, offsets, qmap, chain, out):
    """MSE of multi-hypothesis MLPs (lab.problem.controllers.MLPController with heads > 1): every
    row of W (P, D) has len(offsets) / nq output heads of nq joints (outputs h nq .. (h + 1) nq - 1
    are head h, each with its fixed pre-activation offsets); a goal counts its smallest squared
    error over the heads: out[p] = mean_g min_h || goal_g - fk(joints(head_h(x_g))) ||^2."""
    A, tiled, E, Eh, Q = _heads_setup(XT, goalsT, W, nh, offsets, qmap)
    for h in range(A.shape[0] // Q.shape[0]):
        _head_joints(A, h, qmap, Q)
        fk_turned_sq_errors(Q, tiled, axes, chain, qmap[4], Eh)
        _keep_least(Eh, E)
    _segment_means(E, XT.shape[1], out)


# A tree of several end effectors (robots' trees) as the kernels take it: every effector's own serial
# chain (robots.kinematics.ChainKinematics.effector_arrays) laid end to end,
#     tree = (rot (K, 3, 3), pos (K, 3), kind (K,), identity (K,), ee_pos (E, 3), joints (K,), starts (E + 1,))
# effector e's chain is rows starts[e] .. starts[e + 1] - 1, composed on the joint values of rows
# joints[starts[e]:starts[e + 1]] (its path, root first); its goal is rows e m .. (e + 1) m - 1 of the
# goals (m task axes: a goal (E, m) flattened). A joint that moves several effectors (a humanoid's
# waist) is composed once for each.


@numba.njit(**_JIT)
def tree_sq_errors(Q, goalsT, axes, tree, turns, E):
    """E (N,) <- the sum over effectors of each one's squared task-space error, joint values Q (nq, N),
    goals (E m, N): each effector's chain composed by fk_turned_sq_errors (the serial arm's path,
    unchanged) on its own rows of Q, the errors added in effector order. turns (E, 10): row e the
    serial turn (NO_TURN's layout) of effector e's limb, whose first joint moves that effector alone;
    unset: not turned."""
    rot, pos, kind, identity, ee_pos, joints, starts = tree
    n, m = Q.shape[1], axes.shape[0]
    longest = 0
    for e in range(ee_pos.shape[0]):
        longest = max(longest, starts[e + 1] - starts[e])
    Qe, Ee = np.empty((longest, n)), np.empty(n)
    for g in range(n):
        E[g] = 0.0
    for e in range(ee_pos.shape[0]):
        a, b = starts[e], starts[e + 1]
        for k in range(b - a):
            for g in range(Q.shape[1]):
                Qe[k, g] = Q[joints[a + k], g]
        fk_turned_sq_errors(Qe[:b - a], goalsT[e * m:(e + 1) * m], axes,
                            (rot[a:b], pos[a:b], kind[a:b], identity[a:b], ee_pos[e]), turns[e], Ee)
        for g in range(n):
            E[g] += Ee[g]


@numba.njit(**_JIT)
def tree_turn_joints(Q, goalsT, tree, turns):
    """Q's rows of the turned limbs' first joints <- each turned toward its effector's goal (goalsT
    (3 E, N)), as the fitness turns it (turn_first_joint on that effector's chain)."""
    rot, pos, kind, identity, ee_pos, joints, starts = tree
    for e in range(ee_pos.shape[0]):
        if turns[e, 0] == 0.0:
            continue
        a, b = starts[e], starts[e + 1]
        Qe = np.empty((b - a, Q.shape[1]))
        for k in range(b - a):
            for g in range(Q.shape[1]):
                Qe[k, g] = Q[joints[a + k], g]
        turn_first_joint(Qe, goalsT[3 * e:3 * e + 3], (rot[a:b], pos[a:b], kind[a:b], identity[a:b], ee_pos[e]),
                         turns[e])
        for g in range(Q.shape[1]):
            Q[joints[a], g] = Qe[0, g]


@numba.njit(**_JIT)
def _tree_side_by_side_mse(Q, goalsT, axes, tree, turns, out):
    """Q (nq, P n): joint values of P controllers side by side -> out (P,) <- each one's mean over the
    goals of the summed squared effector errors."""
    n = goalsT.shape[1]
    P = out.shape[0]
    tiled = _tiled(goalsT, P)
    E = np.empty(P * n)
    tree_sq_errors(Q, tiled, axes, tree, turns, E)
    _segment_means(E, n, out)


@numba.njit(**_JIT)
def _tree_population_mse(A, goalsT, axes, qmap, tree, out):
    """_population_mse on a tree: A (nq, P n) outputs -> out (P,); qmap[4] the turns (E, 10)."""
    for o in range(A.shape[0]):
        _to_joints_row(A[o], o, qmap)
    _tree_side_by_side_mse(A, goalsT, axes, tree, qmap[4], out)


@numba.njit(**_JIT)
def tree_mlp_mse(XT, goalsT, axes, W, nh, qmap, tree, out):
    """mlp_mse on a tree: goals (E m, n), each MLP's fitness the mean of the summed effector errors."""
    A = np.empty((qmap[0].shape[0], W.shape[0] * XT.shape[1]))
    mlp_outputs(XT, W, nh, A)
    _tree_population_mse(A, goalsT, axes, qmap, tree, out)


@numba.njit(**_JIT)
def tree_mlp_heads_mse(XT, goalsT, axes, W, nh, offsets, qmap, tree, out):
    """mlp_heads_mse on a tree (goals (E m, n)): every row of W (P, D) has len(offsets) / nq heads of
    nq joints, and a goal counts the smallest over the heads of the summed effector errors. A wired
    network's limb group (lab/problem/wiring.py) calls it on its own effectors: the min over heads
    is then taken per limb group, as the controller picks a head for each group."""
    A, tiled, E, Eh, Q = _heads_setup(XT, goalsT, W, nh, offsets, qmap)
    for h in range(A.shape[0] // Q.shape[0]):
        _head_joints(A, h, qmap, Q)
        tree_sq_errors(Q, tiled, axes, tree, qmap[4], Eh)
        _keep_least(Eh, E)
    _segment_means(E, XT.shape[1], out)


@numba.njit(**_JIT)
def tree_graph_mse(XT, goalsT, axes, program, qmap, tree, out):
    """graph_mse on a tree (goals (E m, n))."""
    starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, no = program
    n = XT.shape[1]
    V = _graph_scratch(XT, n_nodes)
    A = np.empty((no, starts.shape[0] * n))
    for p in range(starts.shape[0]):
        _graph_rows(XT, p, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, V,
                    A[:, p * n:(p + 1) * n])
    _tree_population_mse(A, goalsT, axes, qmap, tree, out)


@numba.njit(**_JIT)
def tree_joints_mse(QT, goalsT, axes, tree, turns, out):
    """joints_mse on a tree: joint values QT (P, nq, n), goals (E m, n) -> out (P,) (turns as tree_sq_errors)."""
    P, nq, n = QT.shape
    Q = np.empty((nq, P * n))
    for p in range(P):  # loops, not slices (see _tiled)
        for k in range(nq):
            for g in range(n):
                Q[k, p * n + g] = QT[p, k, g]
    _tree_side_by_side_mse(Q, goalsT, axes, tree, turns, out)


def pack_tree(chains, paths, nq: int) -> tuple:
    """The tree tuple the tree kernels take (see above), from each effector's chain (rot, pos, kind,
    identity, ee_pos) (robots' effector_arrays(e)) and its path (the joint indices it is composed on,
    root first; robots' path(e)); ValueError naming what is wrong."""
    chains, paths = list(chains), [np.asarray(p, dtype=np.int64).reshape(-1) for p in paths]
    if not chains or len(chains) != len(paths):
        raise ValueError(f"a tree needs one path per effector's chain, got {len(chains)} chains and {len(paths)} paths")
    parts = []
    for e, (chain, path) in enumerate(zip(chains, paths)):
        if len(path) == 0 or path.min() < 0 or path.max() >= nq:
            raise ValueError(f"effector {e}: its path must be joint indices in [0, {nq}), got {path.tolist()}")
        parts.append(check_chain(chain, len(path)))
    rot, pos, kind, identity = (np.ascontiguousarray(np.concatenate([p[i] for p in parts])) for i in range(4))
    ee_pos = np.ascontiguousarray(np.stack([p[4] for p in parts]))
    starts = np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64)
    return rot, pos, kind, identity, ee_pos, np.ascontiguousarray(np.concatenate(paths)), starts


TREE_FIELDS = ("rot", "pos", "kind", "identity", "ee_pos", "joints", "starts")  # pack_tree's arrays, in order


def check_tree(tree, nq: int, effectors: int | None = None) -> tuple:
    """A packed tree (pack_tree's tuple, or a dict of TREE_FIELDS) checked and packed again, for nq
    joints and, when given, `effectors` end effectors; ValueError naming what is wrong."""
    try:
        rot, pos, kind, identity, ee_pos, joints, starts = (np.asarray(a) for a in (
            tuple(tree[k] for k in TREE_FIELDS) if isinstance(tree, dict) else tree))
    except (TypeError, ValueError, KeyError):
        raise ValueError("a tree's chain must be (rot, pos, kind, identity, ee_pos, joints, starts)") from None
    E = len(starts) - 1 if starts.ndim == 1 else -1
    if E < 1 or (effectors is not None and E != effectors) or ee_pos.shape != (E, 3):
        raise ValueError(f"a tree's chain must describe {effectors or 'its'} effectors, got starts of shape "
                         f"{starts.shape} and ee_pos of shape {ee_pos.shape}")
    starts = starts.astype(np.int64)
    if starts[0] != 0 or np.any(np.diff(starts) < 1) or starts[-1] != len(joints):
        raise ValueError(f"a tree's starts must rise from 0 to its {len(joints)} joint rows, got {starts.tolist()}")
    paths = [joints[a:b] for a, b in zip(starts[:-1], starts[1:])]
    chains = [(rot[a:b], pos[a:b], kind[a:b], identity[a:b], ee_pos[e])
              for e, (a, b) in enumerate(zip(starts[:-1], starts[1:]))]
    return pack_tree(chains, paths, nq)


def check_chain(chain, nq: int) -> tuple:
    """The kinematic arrays (rot (k, 3, 3), pos (k, 3), kind (k,), identity (k,), ee_pos (3,)) as the
    kernels take them, for a chain of nq joints; ValueError naming what is wrong."""
    if isinstance(chain, dict):
        chain = tuple(chain[k] for k in ("rot", "pos", "kind", "identity", "ee_pos"))
    try:
        rot, pos, kind, identity, ee_pos = chain
    except (TypeError, ValueError):
        raise ValueError("chain must be (rot, pos, kind, identity, ee_pos)") from None
    rot, pos, ee_pos = (np.ascontiguousarray(np.asarray(a, dtype=np.float64)) for a in (rot, pos, ee_pos))
    kind = np.ascontiguousarray(np.asarray(kind, dtype=np.int64))
    identity = np.ascontiguousarray(np.asarray(identity, dtype=np.bool_))
    if not (rot.shape == (nq, 3, 3) and pos.shape == (nq, 3) and kind.shape == identity.shape == (nq,)
            and ee_pos.shape == (3,)):
        raise ValueError(f"chain must describe {nq} joints: rot ({nq}, 3, 3), pos ({nq}, 3), kind and identity "
                         f"({nq},), ee_pos (3,); got {rot.shape}, {pos.shape}, {kind.shape}, {identity.shape}, "
                         f"{ee_pos.shape}")
    if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(pos)) and np.all(np.isfinite(ee_pos))):
        raise ValueError("chain: its rotations and positions must be finite")
    return rot, pos, kind, identity, ee_pos
