"""Compiled pose-fitness kernels: network + forward kinematics + position and angle error, fused.

The pose counterpart of kernels.py, with its layout (goals along the contiguous axis) and its
building blocks (the MLP and graph forward passes, the output mapping, the chain's frames, the
first joint's turn). For each answer:

    e = ||p - p_g||^2 + L^2 theta^2

p = P + R ee_pos the tool frame's origin, R the chain's last joint frame; the tool's rotation is
R tool. theta: a full pose, the geodesic angle of R_g^T R_tool, atan2(|skew|, (trace - 1) / 2)
(exact near 0 and pi, as robots.pose.rotation_angle); an approach axis, atan2(|a x g|, a . g), a =
R (tool axis). spec = (tool (3, 3), axis in the joint frame (3,), mode (0 full, 1 axis), L^2).

The turn (qmap[4], kernels.NO_TURN's layout) turns the first joint toward the position's bearing;
the frame turns rigidly with it about the joint's axis (Rodrigues), so no second pass of the chain.
The wrist (spec[4], lab.problem.pose_encoding's closed_form_arrays; empty: none): after the turn, the
last three joints are solved in closed form for the goal's rotation on the frame the others leave (two
solutions, as an Euler decomposition about the three joints' own axes; each angle taken by whole
turns into its limits, else clipped), the one nearer the goal kept. The reach (the same array): then,
pass after pass, the elbow (the goal's distance from the shoulder), the shoulder (the goal's bearing
about its axis), the turn and the wrist again (_reach_rows), each goal keeping its best pass; on an
approach-axis arm whose roll follows the flex (the SO arms) a pass solves all five joints
(_approach_pass), and on an arm whose last two wrist axes meet and whose first wrist joint is
parallel to the shoulder (the UR arms, the Z1) a pass is exact too (_wrist_point_pass). A controller whose output or
error is NaN or infinite gets +inf.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lab.problem.kernels import (_JIT, _chain_frames, _graph_rows, _graph_scratch, _segment_means, _tiled,
                                 _to_joints_row, _turn_row, mlp_offset_outputs)


@numba.njit(**_JIT)
def _copy2(src, dst):
    """dst <- src, both (a, b): loops, not a slice assignment, whose shape-mismatch message costs numba
    seconds of compile (docs/results/app-speed.md)."""
    for a in range(src.shape[0]):
        for b in range(src.shape[1]):
            dst[a, b] = src[a, b]


@numba.njit(**_JIT)
def _copy3(src, dst):
    """dst <- src, both (a, b, c)."""
    for a in range(src.shape[0]):
        for b in range(src.shape[1]):
            for c in range(src.shape[2]):
                dst[a, b, c] = src[a, b, c]


@numba.njit(**_JIT)
def _turned_frames(Q, GP, chain, turn, R, P):
    """R (3, 3, N), P (3, N) <- the last joint's frame of Q (nq, N), the first joint turned toward each
    goal position's bearing when turn[0] is set (Q[0] then holds the turned values)."""
    _chain_frames(Q, chain, R, P)
    if turn[0] == 0.0:
        return
    n = Q.shape[1]
    before = Q[0].copy()
    E = np.empty(n)
    _turn_row(P, R, chain[4], Q, GP, turn, E, np.bool_(True))
    for g in range(n):
        d = Q[0, g] - before[g]
        if d != 0.0:
            _turn_column(R, P, g, turn[1], turn[2], turn[3], turn[4], turn[5], turn[6], d)


@numba.njit(**_JIT)
def _turn_column(R, P, g, cx, cy, cz, wx, wy, wz, d):
    """Goal g's frame R[:, :, g], P[:, g] turned rigidly by d about the axis through (cx, cy, cz) along
    the unit (wx, wy, wz) (Rodrigues: K = cos I + sin [w]x + (1 - cos) w w^T)."""
    s, c = math.sin(d), math.cos(d)
    v = 1.0 - c
    k00, k01, k02 = c + v * wx * wx, v * wx * wy - s * wz, v * wx * wz + s * wy
    k10, k11, k12 = v * wy * wx + s * wz, c + v * wy * wy, v * wy * wz - s * wx
    k20, k21, k22 = v * wz * wx - s * wy, v * wz * wy + s * wx, c + v * wz * wz
    for b in range(3):
        r0, r1, r2 = R[0, b, g], R[1, b, g], R[2, b, g]
        R[0, b, g] = k00 * r0 + k01 * r1 + k02 * r2
        R[1, b, g] = k10 * r0 + k11 * r1 + k12 * r2
        R[2, b, g] = k20 * r0 + k21 * r1 + k22 * r2
    u0, u1, u2 = P[0, g] - cx, P[1, g] - cy, P[2, g] - cz
    P[0, g] = cx + k00 * u0 + k01 * u1 + k02 * u2
    P[1, g] = cy + k10 * u0 + k11 * u1 + k12 * u2
    P[2, g] = cz + k20 * u0 + k21 * u1 + k22 * u2


# the wrist's constants (pose_encoding.PoseEncoding.wrist_arrays), by index into the flat array
_W, _PHI, _RAD, _CC = 0, 1, 2, 3
_A2, _A3, _XV, _C, _LO, _HI, _WRAP, _PASSES = 4, 7, 10, 13, 22, 25, 28, 31
# the reach's (the shoulder S, the elbow E and, on an approach-axis arm, the wrist's flex F solved in
# closed form): S, E, F (-1: none), passes, then S's, E's and F's limits (lo, hi) and whether each
# wraps; _W < 0: no wrist (an approach-axis arm's reach alone)
_S, _E, _F, _REACH, _RLO, _RHI, _RWRAP = 32, 33, 34, 35, 36, 39, 42
_SHOULDER, _ELBOW, _FLEX = 0, 1, 2
# the point where the wrist's axes meet (PoseEncoding.wrist_point): 0 none, 1 all three (a spherical
# wrist's centre), 2 the last two, 3 the last two with the first wrist joint parallel to the shoulder
# (a pass then exact: _wrist_point_pass); the point in the last joint's frame; and its offset from the
# tool point in the tool frame (point = tool point + R_tool off)
_WC, _WCV, _WCO = 45, 46, 49
# an approach-axis arm whose roll follows the flex (the SO arms): the exact pass (_approach_pass) also
# solves the first joint (_PAN) and the roll (_ROLL); their limits (lo, hi) and whether each wraps
_PAN, _ROLL = 3, 4
# the first joint turned so that a point's plane across S's axis holds the goal's (_wrist_point_pass)
_PAN_POINT = 5
_END_LO, _END_HI, _END_WRAP = 52, 54, 56


@numba.njit(**_JIT)
def _mm(A, B, out, ta=False, tb=False):
    """out <- op(A) op(B) of 3 x 3 matrices, op the transpose where ta / tb."""
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for k in range(3):
                acc += (A[k, a] if ta else A[a, k]) * (B[b, k] if tb else B[k, b])
            out[a, b] = acc


@numba.njit(**_JIT)
def _rz_into(M, t, out):
    """out <- M Rz(t) (3, 3)."""
    c, s = math.cos(t), math.sin(t)
    for a in range(3):
        m0, m1 = M[a, 0], M[a, 1]
        out[a, 0] = c * m0 + s * m1
        out[a, 1] = c * m1 - s * m0
        out[a, 2] = M[a, 2]


@numba.njit(**_JIT)
def _rot_about(axis, t, v, out):
    """out <- v turned by t about the unit axis (Rodrigues)."""
    c, s = math.cos(t), math.sin(t)
    d = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]
    cx = axis[1] * v[2] - axis[2] * v[1]
    cy = axis[2] * v[0] - axis[0] * v[2]
    cz = axis[0] * v[1] - axis[1] * v[0]
    out[0] = v[0] * c + cx * s + axis[0] * d * (1.0 - c)
    out[1] = v[1] * c + cy * s + axis[1] * d * (1.0 - c)
    out[2] = v[2] * c + cz * s + axis[2] * d * (1.0 - c)


@numba.njit(**_JIT)
def _into(t, lo, hi, wrap):
    """t by whole turns into [lo, hi] where that brings it inside, else clipped (a continuous joint:
    into its range's turn)."""
    for k in range(3):
        c = t + (0.0 if k == 0 else (-2.0 * math.pi if k == 1 else 2.0 * math.pi))
        if lo <= c <= hi:
            return c
    if wrap:
        return lo + (t - lo) % (2.0 * math.pi)
    return min(hi, max(lo, t))


@numba.njit(**_JIT)
def _wrist_rows(Q, GP, GR, chain, spec, R, P):
    """The last three joints of Q (nq, N) solved for each goal's rotation on the frame the joints
    before them leave: Q's last three rows, and R, P (the last joint's frame), rewritten for the
    solution (of two) nearer the goal (||p - p_g||^2 + L^2 theta^2)."""
    rot, pos, kind, identity, ee_pos = chain
    tool, wr, w2 = spec[0], spec[4], spec[3]
    w = int(wr[_W])
    a2, a3, xv, Cm = np.empty(3), np.empty(3), np.empty(3), np.empty((3, 3))
    for a in range(3):
        a2[a], a3[a], xv[a] = wr[_A2 + a], wr[_A3 + a], wr[_XV + a]
        for b in range(3):
            Cm[a, b] = wr[_C + 3 * a + b]
    Rp, T1, T2, Nn, G, Rb, M = (np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
                                np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)))
    v, u, y = np.empty(3), np.empty(3), np.empty(3)
    qb = np.empty(3)
    for g in range(Q.shape[1]):
        # the frame before the wrist: joints 0 .. w - 1, then joint w's fixed placement
        for a in range(3):
            for b in range(3):
                Rp[a, b] = 1.0 if a == b else 0.0
        px, py, pz = 0.0, 0.0, 0.0
        for k in range(w + 1):
            px += Rp[0, 0] * pos[k, 0] + Rp[0, 1] * pos[k, 1] + Rp[0, 2] * pos[k, 2]
            py += Rp[1, 0] * pos[k, 0] + Rp[1, 1] * pos[k, 1] + Rp[1, 2] * pos[k, 2]
            pz += Rp[2, 0] * pos[k, 0] + Rp[2, 1] * pos[k, 1] + Rp[2, 2] * pos[k, 2]
            _mm(Rp, rot[k], T1)
            if k < w:
                _rz_into(T1, Q[k, g], Rp)
            else:
                _copy2(T1, Rp)
        for a in range(3):
            for b in range(3):
                G[a, b] = GR[3 * a + b, g]
        # Nn = Rp^T G tool^T C^T = Rz(t1) Rot(a2, t2) Rot(a3, t3)
        _mm(Rp, G, T1, True, False)
        _mm(T1, tool, T2, False, True)
        _mm(T2, Cm, Nn, False, True)
        d = Nn[2, 0] * a3[0] + Nn[2, 1] * a3[1] + Nn[2, 2] * a3[2]
        c = (d - wr[_CC]) / wr[_RAD]
        delta = math.acos(min(1.0, max(-1.0, c)))
        for a in range(3):
            u[a] = Nn[a, 0] * a3[0] + Nn[a, 1] * a3[1] + Nn[a, 2] * a3[2]
        best = np.inf
        for branch in range(2):
            t2 = wr[_PHI] + (delta if branch == 0 else -delta)
            _rot_about(a2, t2, a3, v)
            t1 = math.atan2(v[0] * u[1] - v[1] * u[0], v[0] * u[0] + v[1] * u[1])
            # M = (Rz(t1) Rot(a2, t2))^T Nn = Rot(a3, t3): t3 the turn of xv about a3
            c1, s1 = math.cos(t1), math.sin(t1)
            for b in range(3):  # T2 = Rz(t1)^T Nn
                T2[0, b] = c1 * Nn[0, b] + s1 * Nn[1, b]
                T2[1, b] = -s1 * Nn[0, b] + c1 * Nn[1, b]
                T2[2, b] = Nn[2, b]
            for b in range(3):  # M = Rot(a2, t2)^T T2, column by column
                for a in range(3):
                    v[a] = T2[a, b]
                _rot_about(a2, -t2, v, y)
                M[0, b], M[1, b], M[2, b] = y[0], y[1], y[2]
            for a in range(3):
                y[a] = M[a, 0] * xv[0] + M[a, 1] * xv[1] + M[a, 2] * xv[2]
            cx = xv[1] * y[2] - xv[2] * y[1]
            cy = xv[2] * y[0] - xv[0] * y[2]
            cz = xv[0] * y[1] - xv[1] * y[0]
            t3 = math.atan2(cx * a3[0] + cy * a3[1] + cz * a3[2], xv[0] * y[0] + xv[1] * y[1] + xv[2] * y[2])
            ts = (t1, t2, t3)
            # the wrist's forward kinematics from the frame before it
            for a in range(3):
                for b in range(3):
                    Rb[a, b] = Rp[a, b]
            bx, by, bz = px, py, pz
            for j in range(3):
                k = w + j
                t = _into(ts[j], wr[_LO + j], wr[_HI + j], wr[_WRAP + j] != 0.0)
                qb[j] = t
                if j > 0:
                    bx += Rb[0, 0] * pos[k, 0] + Rb[0, 1] * pos[k, 1] + Rb[0, 2] * pos[k, 2]
                    by += Rb[1, 0] * pos[k, 0] + Rb[1, 1] * pos[k, 1] + Rb[1, 2] * pos[k, 2]
                    bz += Rb[2, 0] * pos[k, 0] + Rb[2, 1] * pos[k, 1] + Rb[2, 2] * pos[k, 2]
                    _mm(Rb, rot[k], T1)
                else:
                    _copy2(Rb, T1)
                _rz_into(T1, t, Rb)
            ex = bx + Rb[0, 0] * ee_pos[0] + Rb[0, 1] * ee_pos[1] + Rb[0, 2] * ee_pos[2] - GP[0, g]
            ey = by + Rb[1, 0] * ee_pos[0] + Rb[1, 1] * ee_pos[1] + Rb[1, 2] * ee_pos[2] - GP[1, g]
            ez = bz + Rb[2, 0] * ee_pos[0] + Rb[2, 1] * ee_pos[1] + Rb[2, 2] * ee_pos[2] - GP[2, g]
            _mm(G, Rb, T1, True, False)
            _mm(T1, tool, T2)
            sx, sy, sz = T2[2, 1] - T2[1, 2], T2[0, 2] - T2[2, 0], T2[1, 0] - T2[0, 1]
            ang = math.atan2(0.5 * math.sqrt(sx * sx + sy * sy + sz * sz), 0.5 * (T2[0, 0] + T2[1, 1] + T2[2, 2] - 1.0))
            e = ex * ex + ey * ey + ez * ez + w2 * ang * ang
            if e < best:
                best = e
                for j in range(3):
                    Q[w + j, g] = qb[j]
                for a in range(3):
                    for b in range(3):
                        R[a, b, g] = Rb[a, b]
                P[0, g], P[1, g], P[2, g] = bx, by, bz


@numba.njit(**_JIT)
def _bearing(vx, vy, vz, gx, gy, gz, w):
    """The turn about the unit axis w that takes v's direction across w to g's (both projected on the
    plane across w): atan2 of their cross product along w and their dot product."""
    dv = vx * w[0] + vy * w[1] + vz * w[2]
    vx, vy, vz = vx - dv * w[0], vy - dv * w[1], vz - dv * w[2]
    dg = gx * w[0] + gy * w[1] + gz * w[2]
    gx, gy, gz = gx - dg * w[0], gy - dg * w[1], gz - dg * w[2]
    cross = (vy * gz - vz * gy) * w[0] + (vz * gx - vx * gz) * w[1] + (vx * gy - vy * gx) * w[2]
    return math.atan2(cross, vx * gx + vy * gy + vz * gz)


@numba.njit(**_JIT)
def _reach_rows(Q, GP, GR, chain, spec, R, P, step, PT):
    """One joint of Q (nq, N) solved in closed form for each goal, the others held, and R, P (the last joint's
    frame) turned rigidly with it. step _FLEX: joint F, turned so that the tool's approach axis (R axis_j) has
    the goal's bearing about F's axis (GR: the goals' approach directions). _ELBOW: joint E, turned so that the
    tool point's distance from s (the point of joint S's axis nearest joint 0's axis, which S's and joint 0's
    turns keep) is the goal's: with u = p - c the tool point about E's axis (c, w), u = u_par + v, |p(t) - s|^2
    = |a|^2 + |v|^2 + A cos t + B sin t (a = c + u_par - s, A = 2 a.v, B = 2 a.(w x v)), two solutions, the one
    nearer the joint's value kept (or the one nearer that distance once each is taken into the joint's limits).
    _SHOULDER: joint S, turned so that the tool point's bearing about its axis is the goal's. _PAN: joint 0,
    turned so that the goal's approach direction has the tool's approach axis's height along S's axis, which S,
    E, F and the roll keep (across it on the SO-100, 3.7e-6 rad off on the SO-101): the plane they turn that
    axis in then holds the goal's. _ROLL: the last joint, turned so that the tool point's height along S's axis
    is the goal's. Each of these two has two solutions, the one within the limits kept, or of two the nearer the
    joint's value. _PAN_POINT: joint 0, turned so that the goal point (GP) has the tool point's height along S's
    axis, which S, E and the joints after them keep where they turn about axes parallel to S's or through that
    point (two solutions, as _PAN). PT (3, N): each goal's point in the last joint's frame, for the tool point
    (none: PT.shape[1] == 0)."""
    rot, pos, identity, ee_pos = chain[0], chain[1], chain[3], chain[4]
    wr, axis_j = spec[4], spec[1]
    S = int(wr[_S])
    if step < _PAN:
        j = int(wr[_S + step])
        lo, hi, wrap = wr[_RLO + step], wr[_RHI + step], wr[_RWRAP + step] != 0.0
    else:
        last = 1 if step == _ROLL else 0
        j = rot.shape[0] - 1 if step == _ROLL else 0
        lo, hi, wrap = wr[_END_LO + last], wr[_END_HI + last], wr[_END_WRAP + last] != 0.0
    point = PT.shape[1] > 0
    e0, e1, e2 = ee_pos[0], ee_pos[1], ee_pos[2]
    Rp, T1 = np.empty((3, 3)), np.empty((3, 3))
    c0, w0, cs, ws, c, w = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for g in range(Q.shape[1]):
        for a in range(3):
            for b in range(3):
                Rp[a, b] = 1.0 if a == b else 0.0
        px, py, pz = 0.0, 0.0, 0.0
        for k in range(max(j, S) + 1):  # joint k's axis: T1's z through (px, py, pz)
            px += Rp[0, 0] * pos[k, 0] + Rp[0, 1] * pos[k, 1] + Rp[0, 2] * pos[k, 2]
            py += Rp[1, 0] * pos[k, 0] + Rp[1, 1] * pos[k, 1] + Rp[1, 2] * pos[k, 2]
            pz += Rp[2, 0] * pos[k, 0] + Rp[2, 1] * pos[k, 1] + Rp[2, 2] * pos[k, 2]
            if identity[k]:
                _copy2(Rp, T1)
            else:
                _mm(Rp, rot[k], T1)
            if k == 0 or k == S or k == j:
                for a in range(3):
                    pa, wa = (px, py, pz)[a], T1[a, 2]
                    if k == 0:
                        c0[a], w0[a] = pa, wa
                    if k == S:
                        cs[a], ws[a] = pa, wa
                    if k == j:
                        c[a], w[a] = pa, wa
            _rz_into(T1, Q[k, g], Rp)
        if point:
            e0, e1, e2 = PT[0, g], PT[1, g], PT[2, g]
        tx = P[0, g] + R[0, 0, g] * e0 + R[0, 1, g] * e1 + R[0, 2, g] * e2
        ty = P[1, g] + R[1, 0, g] * e0 + R[1, 1, g] * e1 + R[1, 2, g] * e2
        tz = P[2, g] + R[2, 0, g] * e0 + R[2, 1, g] * e1 + R[2, 2, g] * e2
        ux, uy, uz = tx - c[0], ty - c[1], tz - c[2]
        du = ux * w[0] + uy * w[1] + uz * w[2]
        vx, vy, vz = ux - du * w[0], uy - du * w[1], uz - du * w[2]  # the tool point across the axis
        qx, qy, qz = w[1] * vz - w[2] * vy, w[2] * vx - w[0] * vz, w[0] * vy - w[1] * vx  # w x v
        q_now = Q[j, g]
        if step == _FLEX:  # the approach axis a = R axis_j turned toward the goal's about F's axis
            ax = R[0, 0, g] * axis_j[0] + R[0, 1, g] * axis_j[1] + R[0, 2, g] * axis_j[2]
            ay = R[1, 0, g] * axis_j[0] + R[1, 1, g] * axis_j[1] + R[1, 2, g] * axis_j[2]
            az = R[2, 0, g] * axis_j[0] + R[2, 1, g] * axis_j[1] + R[2, 2, g] * axis_j[2]
            best = _into(q_now + _bearing(ax, ay, az, GR[0, g], GR[1, g], GR[2, g], w), lo, hi, wrap)
        elif step >= _PAN:
            if step != _ROLL:  # ws(d) . a = A cos d + B sin d + C, ws turned about joint 0's axis w
                if step == _PAN:  # a: the goal's approach direction; the approach axis's height along
                    ga, gb, gc = GR[0, g], GR[1, g], GR[2, g]  # S's axis, which no joint but the first changes
                    ax = R[0, 0, g] * axis_j[0] + R[0, 1, g] * axis_j[1] + R[0, 2, g] * axis_j[2]
                    ay = R[1, 0, g] * axis_j[0] + R[1, 1, g] * axis_j[1] + R[1, 2, g] * axis_j[2]
                    az = R[2, 0, g] * axis_j[0] + R[2, 1, g] * axis_j[1] + R[2, 2, g] * axis_j[2]
                else:  # a: the goal point from joint 0's axis; the point's own height along S's axis
                    ga, gb, gc = GP[0, g] - c[0], GP[1, g] - c[1], GP[2, g] - c[2]
                    ax, ay, az = tx - c[0], ty - c[1], tz - c[2]
                h = ws[0] * w[0] + ws[1] * w[1] + ws[2] * w[2]
                px_, py_, pz_ = ws[0] - h * w[0], ws[1] - h * w[1], ws[2] - h * w[2]
                A = px_ * ga + py_ * gb + pz_ * gc
                B = (w[1] * pz_ - w[2] * py_) * ga + (w[2] * px_ - w[0] * pz_) * gb + (w[0] * py_ - w[1] * px_) * gc
                target = ws[0] * ax + ws[1] * ay + ws[2] * az - h * (w[0] * ga + w[1] * gb + w[2] * gc)
            else:  # ws . (t(d) - cs) = ws . (c + du w - cs) + A cos d + B sin d, the goal's height
                A = ws[0] * vx + ws[1] * vy + ws[2] * vz
                B = ws[0] * qx + ws[1] * qy + ws[2] * qz
                target = (ws[0] * (GP[0, g] - c[0] - du * w[0]) + ws[1] * (GP[1, g] - c[1] - du * w[1])
                          + ws[2] * (GP[2, g] - c[2] - du * w[2]))
            r = math.sqrt(A * A + B * B)
            if r < 1e-9:
                continue
            mid = math.atan2(B, A)
            half = math.acos(min(1.0, max(-1.0, target / r)))
            best, move_best = q_now, np.inf
            for sign in (1.0, -1.0):  # a solution within the limits first, then the nearer
                t = mid + sign * half
                t = (t + math.pi) % (2.0 * math.pi) - math.pi
                cand = _into(q_now + t, lo, hi, wrap)
                off = (cand - q_now - t) % (2.0 * math.pi)
                move = abs(cand - q_now) + (0.0 if min(off, 2.0 * math.pi - off) < 1e-12 else 100.0)
                if move < move_best:
                    best, move_best = cand, move
        elif step == _ELBOW:
            # s: the point of S's axis nearest joint 0's axis (S's own origin when the two are parallel)
            b = ws[0] * w0[0] + ws[1] * w0[1] + ws[2] * w0[2]
            dx, dy, dz = cs[0] - c0[0], cs[1] - c0[1], cs[2] - c0[2]
            den = 1.0 - b * b
            ts = 0.0
            if den > 1e-9:
                ts = (b * (dx * w0[0] + dy * w0[1] + dz * w0[2]) - (dx * ws[0] + dy * ws[1] + dz * ws[2])) / den
            sx, sy, sz = cs[0] + ts * ws[0], cs[1] + ts * ws[1], cs[2] + ts * ws[2]
            ax, ay, az = c[0] + du * w[0] - sx, c[1] + du * w[1] - sy, c[2] + du * w[2] - sz
            A = 2.0 * (ax * vx + ay * vy + az * vz)
            B = 2.0 * (ax * qx + ay * qy + az * qz)
            gx, gy, gz = GP[0, g] - sx, GP[1, g] - sy, GP[2, g] - sz
            base = ax * ax + ay * ay + az * az + vx * vx + vy * vy + vz * vz
            want = gx * gx + gy * gy + gz * gz
            r = math.sqrt(A * A + B * B)
            if r < 1e-12:
                continue
            mid = math.atan2(B, A)
            half = math.acos(min(1.0, max(-1.0, (want - base) / r)))
            best, fit_best, move_best = q_now, np.inf, np.inf
            for sign in (1.0, -1.0):
                t = mid + sign * half
                t = (t + math.pi) % (2.0 * math.pi) - math.pi
                cand = _into(q_now + t, lo, hi, wrap)
                d = cand - q_now
                fit = abs(base + A * math.cos(d) + B * math.sin(d) - want)
                move = abs((d + math.pi) % (2.0 * math.pi) - math.pi)
                if fit < fit_best - 1e-9 * want or (fit <= fit_best + 1e-9 * want and move < move_best):
                    best, fit_best, move_best = cand, fit, move
        else:
            best = _into(q_now + _bearing(vx, vy, vz, GP[0, g] - c[0], GP[1, g] - c[1], GP[2, g] - c[2], w),
                         lo, hi, wrap)
        d = best - q_now
        if d == 0.0:
            continue
        Q[j, g] = best
        _turn_column(R, P, g, c[0], c[1], c[2], w[0], w[1], w[2], d)  # the frame turns with the joint


@numba.njit(**_JIT)
def _pose_rows(R, P, GP, GR, chain, spec, D, A):
    """D (N,) <- squared position errors, A (N,) <- angles, of the frames R, P against the goals."""
    tool, axis_j, mode = spec[0], spec[1], spec[2]
    e0, e1, e2 = chain[4][0], chain[4][1], chain[4][2]
    t00, t01, t02, t10, t11, t12, t20, t21, t22 = (tool[0, 0], tool[0, 1], tool[0, 2], tool[1, 0], tool[1, 1],
                                                   tool[1, 2], tool[2, 0], tool[2, 1], tool[2, 2])
    a0, a1, a2 = axis_j[0], axis_j[1], axis_j[2]
    for g in range(R.shape[2]):
        r00, r01, r02 = R[0, 0, g], R[0, 1, g], R[0, 2, g]
        r10, r11, r12 = R[1, 0, g], R[1, 1, g], R[1, 2, g]
        r20, r21, r22 = R[2, 0, g], R[2, 1, g], R[2, 2, g]
        dx = GP[0, g] - (P[0, g] + r00 * e0 + r01 * e1 + r02 * e2)
        dy = GP[1, g] - (P[1, g] + r10 * e0 + r11 * e1 + r12 * e2)
        dz = GP[2, g] - (P[2, g] + r20 * e0 + r21 * e1 + r22 * e2)
        D[g] = dx * dx + dy * dy + dz * dz
        if mode == 1:
            ax = r00 * a0 + r01 * a1 + r02 * a2
            ay = r10 * a0 + r11 * a1 + r12 * a2
            az = r20 * a0 + r21 * a1 + r22 * a2
            gx, gy, gz = GR[0, g], GR[1, g], GR[2, g]
            cx, cy, cz = ay * gz - az * gy, az * gx - ax * gz, ax * gy - ay * gx
            A[g] = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * gx + ay * gy + az * gz)
            continue
        # the tool's rotation M = R tool
        m00 = r00 * t00 + r01 * t10 + r02 * t20
        m01 = r00 * t01 + r01 * t11 + r02 * t21
        m02 = r00 * t02 + r01 * t12 + r02 * t22
        m10 = r10 * t00 + r11 * t10 + r12 * t20
        m11 = r10 * t01 + r11 * t11 + r12 * t21
        m12 = r10 * t02 + r11 * t12 + r12 * t22
        m20 = r20 * t00 + r21 * t10 + r22 * t20
        m21 = r20 * t01 + r21 * t11 + r22 * t21
        m22 = r20 * t02 + r21 * t12 + r22 * t22
        # E = G^T M (G the goal's rotation, row-major in GR)
        g00, g01, g02, g10, g11, g12, g20, g21, g22 = (GR[0, g], GR[1, g], GR[2, g], GR[3, g], GR[4, g], GR[5, g],
                                                       GR[6, g], GR[7, g], GR[8, g])
        E00 = g00 * m00 + g10 * m10 + g20 * m20
        E11 = g01 * m01 + g11 * m11 + g21 * m21
        E22 = g02 * m02 + g12 * m12 + g22 * m22
        E01 = g00 * m01 + g10 * m11 + g20 * m21
        E10 = g01 * m00 + g11 * m10 + g21 * m20
        E02 = g00 * m02 + g10 * m12 + g20 * m22
        E20 = g02 * m00 + g12 * m10 + g22 * m20
        E12 = g01 * m02 + g11 * m12 + g21 * m22
        E21 = g02 * m01 + g12 * m11 + g22 * m21
        sx, sy, sz = E21 - E12, E02 - E20, E10 - E01
        A[g] = math.atan2(0.5 * math.sqrt(sx * sx + sy * sy + sz * sz), 0.5 * (E00 + E11 + E22 - 1.0))


@numba.njit(**_JIT)
def pose_parts(Q, GP, GR, chain, spec, D, A):
    """D (N,) <- squared position errors, A (N,) <- angles [rad] of joint values Q (nq, N) (no turn)."""
    n = Q.shape[1]
    R, P = np.empty((3, 3, n)), np.empty((3, n))
    _chain_frames(Q, chain, R, P)
    _pose_rows(R, P, GP, GR, chain, spec, D, A)


@numba.njit(**_JIT)
def pose_sq_errors(Q, GP, GR, chain, turn, spec, E):
    """E (N,) <- ||p - p_g||^2 + L^2 theta^2 of joint values Q (nq, N), the first joint turned first
    when turn[0] is set (Q[0] then holds the turned values)."""
    n = Q.shape[1]
    R, P, A = np.empty((3, 3, n)), np.empty((3, n)), np.empty(n)
    _turned_and_wrist(Q, GP, GR, chain, turn, spec, R, P)
    _pose_rows(R, P, GP, GR, chain, spec, E, A)
    w2 = spec[3]
    for g in range(n):
        E[g] += w2 * A[g] * A[g]


@numba.njit(**_JIT)
def finish_joints(Q, GP, GR, chain, turn, spec):
    """Q (nq, N) <- as the fitness answers: the first joint turned (turn[0] set), then the wrist
    solved (spec[4] not empty)."""
    n = Q.shape[1]
    R, P = np.empty((3, 3, n)), np.empty((3, n))
    _turned_and_wrist(Q, GP, GR, chain, turn, spec, R, P)


@numba.njit(**_JIT)
def finish_joints_errors(Q, GP, GR, chain, turn, spec, D, A):
    """finish_joints, then D (N,) <- the squared position errors and A (N,) <- the angles [rad] of the
    answers it leaves (pose_parts without a second walk of the chain)."""
    n = Q.shape[1]
    R, P = np.empty((3, 3, n)), np.empty((3, n))
    _turned_and_wrist(Q, GP, GR, chain, turn, spec, R, P)
    _pose_rows(R, P, GP, GR, chain, spec, D, A)


@numba.njit(**_JIT)
def _turned_and_wrist(Q, GP, GR, chain, turn, spec, R, P):
    """R, P <- the last joint's frame of Q after the turn and the wrist: the first joint turned toward
    the position's bearing (turn[0] set), then the wrist solved (spec[4] not empty); with the turn and
    a wrist of two passes, the turn again on the solved wrist's tool point and the wrist again. Then
    the reach's passes, each goal keeping the joint values of its least error (||p - p_g||^2 + L^2
    theta^2) before and after each pass: a pass is exact for each of its joints in turn, not for the
    pose, and where the limits clip a joint or an offset couples them the passes can drift away.
    Where the wrist's axes meet in a point (spec[4][_WC] set), the reach works on that point instead
    (_centred)."""
    wr = spec[4]
    if wr.shape[0] > _WC and wr[_WC] != 0.0 and wr[_REACH] > 0.0:
        _centred(Q, GP, GR, chain, turn, spec, R, P)
        return
    _turned_frames(Q, GP, chain, turn, R, P)
    if wr.shape[0] == 0:
        return
    wrist = wr[_W] >= 0.0
    if wrist:
        _wrist_rows(Q, GP, GR, chain, spec, R, P)
        if turn[0] != 0.0 and wr[_PASSES] > 1.0:
            _turned_frames(Q, GP, chain, turn, R, P)
            _wrist_rows(Q, GP, GR, chain, spec, R, P)
    passes = int(wr[_REACH])
    if passes == 0:
        return
    n = Q.shape[1]
    D, A = np.empty(n), np.empty(n)
    _pose_rows(R, P, GP, GR, chain, spec, D, A)
    w2 = spec[3]
    best = D + w2 * A * A
    Qb, Rb, Pb = Q.copy(), R.copy(), P.copy()
    none = np.empty((3, 0))
    for _ in range(passes):
        if wr[_F] >= 0.0 and int(wr[_F]) == Q.shape[0] - 2:
            _approach_pass(Q, GP, GR, chain, spec, R, P)
        else:
            if wr[_F] >= 0.0:
                _reach_rows(Q, GP, GR, chain, spec, R, P, _FLEX, none)
            _reach_rows(Q, GP, GR, chain, spec, R, P, _ELBOW, none)
            _reach_rows(Q, GP, GR, chain, spec, R, P, _SHOULDER, none)
            _turned_frames(Q, GP, chain, turn, R, P)
        if wrist:
            _wrist_rows(Q, GP, GR, chain, spec, R, P)
        _pose_rows(R, P, GP, GR, chain, spec, D, A)
        for g in range(n):
            D[g] += w2 * A[g] * A[g]
        _keep_best(D, best, Q, R, P, Qb, Rb, Pb)
    _copy2(Qb, Q)
    _copy3(Rb, R)
    _copy2(Pb, P)


@numba.njit(**_JIT)
def _approach_pass(Q, GP, GR, chain, spec, R, P):
    """One exact pass of an approach-axis arm whose roll follows the flex (the SO arms): the first
    joint puts S's axis across the goal's approach direction, the flex turns the approach axis onto
    the goal's, the roll puts the tool point at the goal's height along S's axis; the tool's offset
    from the flex's origin is then final, so the elbow and the shoulder place that origin at the goal
    less the offset, and the flex turns the approach axis back. Exact where no joint meets a limit
    (the branch of each two-solution joint: the one nearer the joint's value)."""
    none = np.empty((3, 0))
    _reach_rows(Q, GP, GR, chain, spec, R, P, _PAN, none)
    _reach_rows(Q, GP, GR, chain, spec, R, P, _FLEX, none)
    _reach_rows(Q, GP, GR, chain, spec, R, P, _ROLL, none)
    PT, GW = _origin_and_goal(Q, GP, chain, R, Q.shape[0] - 2)
    _reach_rows(Q, GW, GR, chain, spec, R, P, _ELBOW, PT)
    _reach_rows(Q, GW, GR, chain, spec, R, P, _SHOULDER, PT)
    _reach_rows(Q, GP, GR, chain, spec, R, P, _FLEX, none)


@numba.njit(**_JIT)
def _origin_and_goal(Q, GP, chain, R, j):
    """(PT, GJ), each (3, N): joint j's origin in the last joint's frame (the joints after j carry it:
    PT = -M^T o, M and o the last frame's rotation and origin in joint j's turned frame), and where it
    must go for the tool point to be on GP with the tool turned as R has it, GP - R (ee_pos - PT)."""
    rot, pos, ee_pos = chain[0], chain[1], chain[4]
    n, nq = Q.shape[1], Q.shape[0]
    PT, GJ = np.empty((3, n)), np.empty((3, n))
    M, T1 = np.empty((3, 3)), np.empty((3, 3))
    for g in range(n):
        for a in range(3):
            for b in range(3):
                M[a, b] = 1.0 if a == b else 0.0
        ox, oy, oz = 0.0, 0.0, 0.0
        for k in range(j + 1, nq):
            ox += M[0, 0] * pos[k, 0] + M[0, 1] * pos[k, 1] + M[0, 2] * pos[k, 2]
            oy += M[1, 0] * pos[k, 0] + M[1, 1] * pos[k, 1] + M[1, 2] * pos[k, 2]
            oz += M[2, 0] * pos[k, 0] + M[2, 1] * pos[k, 1] + M[2, 2] * pos[k, 2]
            _mm(M, rot[k], T1)
            _rz_into(T1, Q[k, g], M)
        for a in range(3):
            PT[a, g] = -(M[0, a] * ox + M[1, a] * oy + M[2, a] * oz)
        for a in range(3):
            GJ[a, g] = GP[a, g] - (R[a, 0, g] * (ee_pos[0] - PT[0, g]) + R[a, 1, g] * (ee_pos[1] - PT[1, g])
                                   + R[a, 2, g] * (ee_pos[2] - PT[2, g]))
    return PT, GJ


@numba.njit(**_JIT)
def _wrist_point_pass(Q, GP, GR, GW, chain, cchain, spec, R, P):
    """One exact pass of an arm whose last two axes meet in a point and whose first wrist joint is
    parallel to the shoulder and the elbow (the UR arms, the Z1): the first joint turns the plane the
    three parallel joints move that point in until it holds the goal's point (GW); the wrist turns
    the tool to the goal's orientation; the tool's offset from the first wrist joint's origin is then
    final, so the elbow and the shoulder place that origin on the goal less the offset; the wrist
    again. Exact where no joint meets a limit (each two-solution joint: as _reach_rows and
    _wrist_rows choose)."""
    none = np.empty((3, 0))
    _reach_rows(Q, GW, GR, cchain, spec, R, P, _PAN_POINT, none)
    _wrist_rows(Q, GP, GR, chain, spec, R, P)
    PT, GJ = _origin_and_goal(Q, GP, chain, R, Q.shape[0] - 3)
    _reach_rows(Q, GJ, GR, chain, spec, R, P, _ELBOW, PT)
    _reach_rows(Q, GJ, GR, chain, spec, R, P, _SHOULDER, PT)
    _wrist_rows(Q, GP, GR, chain, spec, R, P)


@numba.njit(**_JIT)
def _keep_best(D, best, Q, R, P, Qb, Rb, Pb):
    """Each goal g whose error D[g] is below best[g]: best[g] <- D[g], and its joint values and frame
    copied into Qb, Rb, Pb."""
    for g in range(D.shape[0]):
        if D[g] < best[g]:
            best[g] = D[g]
            for a in range(Q.shape[0]):  # loops, not slices: numba's shape-mismatch message costs
                Qb[a, g] = Q[a, g]  # seconds of compile (docs/results/app-speed.md)
            for a in range(3):
                Pb[a, g] = P[a, g]
                for b in range(3):
                    Rb[a, b, g] = R[a, b, g]


@numba.njit(**_JIT)
def _centred(Q, GP, GR, chain, turn, spec, R, P):
    """The reach on the point where the wrist's axes meet, placed on the goal's (the goal's position
    plus the point's offset from the tool, turned by the goal's rotation) by the turn, the elbow and
    the shoulder, pass after pass. A spherical wrist (_WC 1): no wrist joint moves its centre, so
    position and orientation are apart: each goal keeps its nearest pass, then the wrist is solved
    once, and the passes converge as on a 3-joint arm. The last two axes (_WC 2): only the first wrist
    joint moves the point, so the wrist is solved after each pass, each goal keeping its best pass
    (||p - p_g||^2 + L^2 theta^2); the point moves far less with the wrist than the tool point does.
    With that joint parallel to the shoulder (_WC 3), each pass is _wrist_point_pass, exact."""
    wr = spec[4]
    n = Q.shape[1]
    centre = np.empty(3)
    for a in range(3):
        centre[a] = wr[_WCV + a]
    cchain = (chain[0], chain[1], chain[2], chain[3], centre)
    GW = np.empty((3, n))
    for g in range(n):
        for a in range(3):
            GW[a, g] = GP[a, g] + (GR[3 * a, g] * wr[_WCO] + GR[3 * a + 1, g] * wr[_WCO + 1]
                                   + GR[3 * a + 2, g] * wr[_WCO + 2])
    spherical = wr[_WC] == 1.0
    _turned_frames(Q, GW, cchain, turn, R, P)
    best, D, A = np.empty(n), np.empty(n), np.empty(n)
    _centred_errors(Q, GP, GR, GW, chain, spec, centre, spherical, R, P, best, A)
    Qb, Rb, Pb = Q.copy(), R.copy(), P.copy()
    none = np.empty((3, 0))
    w2 = spec[3]
    for _ in range(int(wr[_REACH])):
        if wr[_WC] == 3.0:
            _wrist_point_pass(Q, GP, GR, GW, chain, cchain, spec, R, P)
            _pose_rows(R, P, GP, GR, chain, spec, D, A)
            for g in range(n):
                D[g] += w2 * A[g] * A[g]
        else:
            _reach_rows(Q, GW, GR, cchain, spec, R, P, _ELBOW, none)
            _reach_rows(Q, GW, GR, cchain, spec, R, P, _SHOULDER, none)
            _turned_frames(Q, GW, cchain, turn, R, P)
            _centred_errors(Q, GP, GR, GW, chain, spec, centre, spherical, R, P, D, A)
        _keep_best(D, best, Q, R, P, Qb, Rb, Pb)
    _copy2(Qb, Q)
    _copy3(Rb, R)
    _copy2(Pb, P)
    if spherical:
        _wrist_rows(Q, GP, GR, chain, spec, R, P)


@numba.njit(**_JIT)
def _centred_errors(Q, GP, GR, GW, chain, spec, centre, spherical, R, P, D, A):
    """D (N,) <- what _centred keeps the least of: a spherical wrist's centre's squared distance from
    the goal's; else, the wrist solved first, ||p - p_g||^2 + L^2 theta^2 (A: the angles)."""
    if spherical:
        _centre_sq_errors(R, P, GW, centre, D)
        return
    _wrist_rows(Q, GP, GR, chain, spec, R, P)
    _pose_rows(R, P, GP, GR, chain, spec, D, A)
    w2 = spec[3]
    for g in range(D.shape[0]):
        D[g] += w2 * A[g] * A[g]


@numba.njit(**_JIT)
def _centre_sq_errors(R, P, GW, centre, D):
    """D (N,) <- the squared distance of the wrist's centre (P + R centre) from the goal's, GW (3, N)."""
    for g in range(R.shape[2]):
        d2 = 0.0
        for a in range(3):
            d = P[a, g] + R[a, 0, g] * centre[0] + R[a, 1, g] * centre[1] + R[a, 2, g] * centre[2] - GW[a, g]
            d2 += d * d
        D[g] = d2


@numba.njit(**_JIT)
def _heads_mse(A, heads, GP, GR, qmap, chain, spec, n, out):
    """A (heads nq, P n) outputs of P controllers side by side -> out (P,) <- the mean over goals of
    the least error over the heads."""
    nq = qmap[0].shape[0]
    P = out.shape[0]
    GPt, GRt = _tiled(GP, P), _tiled(GR, P)
    E = np.full(P * n, np.inf)
    Eh = np.empty(P * n)
    Q = np.empty((nq, P * n))
    for h in range(heads):
        for o in range(nq):
            Q[o] = A[h * nq + o]
            _to_joints_row(Q[o], o, qmap)
        pose_sq_errors(Q, GPt, GRt, chain, qmap[4], spec, Eh)
        for g in range(P * n):
            if Eh[g] < E[g]:  # NaN never is: a goal no head reaches stays +inf
                E[g] = Eh[g]
    _segment_means(E, n, out)


@numba.njit(**_JIT)
def pose_mlp_mse(XT, GP, GR, W, nh, offsets, qmap, chain, spec, out):
    """The pose fitness of the MLP of every row of W (P, D) on inputs XT (ni, n) and pose goals (GP
    (3, n), GR): out (P,). offsets (heads nq,): each head's fixed output pre-activation offsets
    (zeros for one head); a goal counts its least error over the heads."""
    nq = qmap[0].shape[0]
    heads = offsets.shape[0] // nq
    n = XT.shape[1]
    A = np.empty((heads * nq, W.shape[0] * n))
    mlp_offset_outputs(XT, W, nh, offsets, A)
    _heads_mse(A, heads, GP, GR, qmap, chain, spec, n, out)


@numba.njit(**_JIT)
def pose_graph_mse(XT, GP, GR, program, qmap, chain, spec, out):
    """The pose fitness of every compiled graph (lab.problem.controllers.compile_programs): out (P,)."""
    starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, no = program
    n = XT.shape[1]
    V = _graph_scratch(XT, n_nodes)
    A = np.empty((no, starts.shape[0] * n))
    for p in range(starts.shape[0]):
        _graph_rows(XT, p, starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot, V,
                    A[:, p * n:(p + 1) * n])
    _heads_mse(A, 1, GP, GR, qmap, chain, spec, n, out)
