"""A tree's hip-and-knee limbs solved in closed form for a point goal, and the joints they share
(g1's waist) chosen so that every such limb can reach its goal.

A limb is the part of an effector's path that moves it alone, after the joints it shares with other
effectors (its prefix: g1's waist for a hand, nothing for a foot). The limb has a *hip* when its
first four joints are revolute, the axes of the second and third meet at a point H (a hip's roll and
yaw) or pass within a few millimetres of each other (g1's shoulders, 6.2 mm apart: H the middle of
their common perpendicular), and the fourth's (a knee's, an elbow's) does not pass through H. Each
joint's axis a_i through o_i is taken at the neutral configuration, so that with its prefix at zero
the effector is the product of exponentials

    f(p, r, y, k) = R_0(p) R_1(r) R_2(y) R_3(k) f_0        R_i(t): the turn by t about axis i

(f_0: the effector with these four joints and the prefix at zero, the joints after the knee held).
For a goal g (its prefix's motion undone) and a given first joint p, g' = R_0(-p) g:

    knee:        |o_3 + R_3(k)(f_0 - o_3) - H| = |g' - H|        (turns about axes 1 and 2 keep distances
                 from H), of the form A cos k + B sin k = C: k = atan2(B, A) +- acos(C / sqrt(A^2 + B^2))
    roll, yaw:   R_1(r) R_2(y) v = w,  v = f(0, 0, 0, k) - H, w = g' - H: Paden-Kahan subproblem 2
                 (Murray, Li and Sastry 1994, section 3.3): z = alpha a_1 + beta a_2 +- gamma a_1 x a_2,
                 then y turns v onto z about a_2 and r turns z onto w about a_1

so every p gives up to four solutions, exact when the axes meet (g1's hips; talos-legs'). A point goal
leaves one joint free, and the first is the one swept (`SWEEP` values over its range beside the
seed's own); of the solutions within the limits, the nearest the seed (each joint's change over its
range) is kept. Where the axes pass apart, the solution misses by about their gap, and the goal is
moved by the miss and the limb solved again (`CORRECTIONS` times, each from the same first joint and
the nearest branch): millimetres become micrometres. Where no solution exists with the joint after
the knee as the seed holds it (a leg stretched near full length, where the ankle's pitch sets the
length), that joint takes `HELD_SWEEP` values over its range in turn.

A prefix shared by several hips (g1's waist, under both hands): where one of them finds no solution
under the seed's prefix (the torso turned the wrong way, a hand's goal out of its arm's reach), the
prefix takes the values of a grid over its joints' ranges (`PREFIX_GRID` values on a joint that turns
more than a quarter turn, 3 on the others; first those wide joints alone with the others as the seed
holds them, then the whole grid), and the one nearest the seed's under which every hip of the group is
solved is kept.

`solve(arm, goals, q)` is what robots.ik.refine applies to each proposal of a tree before its first
step (refine's `limbs`): the seed's own limbs where no solution exists, else the solution. Nothing here
knows about networks.
"""

from __future__ import annotations

import itertools
import weakref
from dataclasses import dataclass

import numba
import numpy as np
import pinocchio as pin

from robots.arm import Arm
from robots.kinematics import REVOLUTE, _joint_kind

SWEEP = 16  # first-joint values tried over its range, beside the seed's own
CORRECTIONS = 2  # re-solves with the goal moved by the miss, where a hip's axes do not meet
DENSE_SWEEP = 128  # first-joint values where those give no solution (a leg stretched nearly straight)
HELD_SWEEP = 9  # values of the joint after the knee tried with them, after the seed's own
GRID_SWEEP = 8  # first-joint values tried under each prefix of the grid
PREFIX_GRID = 12  # values of a shared joint that turns more than a quarter turn (3 on the others)
MAX_GAP = 0.05  # the largest gap between a hip's axes, as a fraction of the hip-to-effector distance
_cache: "weakref.WeakKeyDictionary[Arm, tuple[Hip, ...]]" = weakref.WeakKeyDictionary()


@dataclass(frozen=True, eq=False)
class Hip:
    """One limb's hip and knee (module docstring): the effector, the prefix's joints, the limb's four
    joints (first, the two whose axes meet, the knee) and the joint after the knee (-1: none), the
    axes and origins at the neutral configuration, H, the gap between the meeting axes [length]."""

    effector: int
    prefix: tuple[int, ...]
    joints: tuple[int, int, int, int]
    after: int
    axes: np.ndarray  # (4, 3)
    origins: np.ndarray  # (4, 3)
    H: np.ndarray
    gap: float

    @property
    def exact(self) -> bool:
        """Whether the second and third axes meet (to 1e-9 of a length unit): solutions are exact."""
        return self.gap < 1e-9

    def nearest(self, arm: Arm, goal: np.ndarray, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each goal (n, 3), in the prefix's neutral frame, with the joints after the knee as q
        (n, nq) holds them and the first joint at each of p (n, m): of the (up to) four solutions for
        each p (two knees, two signs of subproblem 2) within the limits (a joint turned by whole turns
        into its range when that brings it there), the one nearest q's own four joints (each change
        over the joint's range): (values (n, 4), found (n,))."""
        joints = list(self.joints)
        qz = q.copy()
        qz[:, list(self.prefix) + joints] = 0.0
        u = arm.reach(qz)[:, self.effector] - self.origins[3]  # (n, 3): f_0 - o_3
        lo, hi = arm.lower[joints], arm.upper[joints]
        values, found = np.zeros((len(q), 4)), np.zeros(len(q), dtype=bool)
        _nearest_kernel(self.axes, self.origins, self.H, np.ascontiguousarray(u), np.ascontiguousarray(goal),
                        np.ascontiguousarray(p), lo, hi, np.ascontiguousarray(q[:, joints]),
                        1.0 / np.maximum(hi - lo, 1e-9), values, found)
        return values, found


@numba.njit(cache=True, nogil=True)
def _nearest_kernel(axes, origins, H, u, goal, p, lo, hi, seed, scale, values, found):
    """Hip.nearest's loop (the module docstring's two steps), goal by goal, in scalars."""
    a0x, a0y, a0z = axes[0, 0], axes[0, 1], axes[0, 2]
    a1x, a1y, a1z = axes[1, 0], axes[1, 1], axes[1, 2]
    a2x, a2y, a2z = axes[2, 0], axes[2, 1], axes[2, 2]
    a3x, a3y, a3z = axes[3, 0], axes[3, 1], axes[3, 2]
    c12 = a1x * a2x + a1y * a2y + a1z * a2z
    nx, ny, nz = a1y * a2z - a1z * a2y, a1z * a2x - a1x * a2z, a1x * a2y - a1y * a2x
    nn = nx * nx + ny * ny + nz * nz
    hx, hy, hz = origins[3, 0] - H[0], origins[3, 1] - H[1], origins[3, 2] - H[2]
    cand = np.empty(4)
    for i in range(goal.shape[0]):
        ux, uy, uz = u[i, 0], u[i, 1], u[i, 2]
        ua = ux * a3x + uy * a3y + uz * a3z
        cx, cy, cz = ux - ua * a3x, uy - ua * a3y, uz - ua * a3z  # u across the knee's axis
        A = 2.0 * (cx * hx + cy * hy + cz * hz)
        B = 2.0 * ((a3y * cz - a3z * cy) * hx + (a3z * cx - a3x * cz) * hy + (a3x * cy - a3y * cx) * hz)
        base = hx * hx + hy * hy + hz * hz + ux * ux + uy * uy + uz * uz + 2.0 * ua * (a3x * hx + a3y * hy + a3z * hz)
        R = max(np.sqrt(A * A + B * B), 1e-300)
        phi = np.arctan2(B, A)
        gx, gy, gz = goal[i, 0] - origins[0, 0], goal[i, 1] - origins[0, 1], goal[i, 2] - origins[0, 2]
        best = np.inf
        for j in range(p.shape[1]):
            wx, wy, wz = _turn(gx, gy, gz, a0x, a0y, a0z, -p[i, j])
            wx, wy, wz = wx + origins[0, 0] - H[0], wy + origins[0, 1] - H[1], wz + origins[0, 2] - H[2]
            ratio = (wx * wx + wy * wy + wz * wz - base) / R
            if abs(ratio) > 1.0:
                continue
            half = np.arccos(ratio)
            wa1 = wx * a1x + wy * a1y + wz * a1z
            for kk in range(2):
                k = phi + half if kk == 0 else phi - half
                vx, vy, vz = _turn(ux, uy, uz, a3x, a3y, a3z, k)
                vx, vy, vz = vx + hx, vy + hy, vz + hz
                va2 = vx * a2x + vy * a2y + vz * a2z
                alpha = (c12 * va2 - wa1) / (c12 * c12 - 1.0)
                beta = (c12 * wa1 - va2) / (c12 * c12 - 1.0)
                g2 = (vx * vx + vy * vy + vz * vz - alpha * alpha - beta * beta - 2.0 * alpha * beta * c12) / nn
                if g2 < 0.0:
                    continue
                gamma = np.sqrt(g2)
                for sign in (1.0, -1.0):
                    zx = alpha * a1x + beta * a2x + sign * gamma * nx
                    zy = alpha * a1y + beta * a2y + sign * gamma * ny
                    zz = alpha * a1z + beta * a2z + sign * gamma * nz
                    cand[0] = p[i, j]
                    cand[1] = _subangle(zx, zy, zz, wx, wy, wz, a1x, a1y, a1z)
                    cand[2] = _subangle(vx, vy, vz, zx, zy, zz, a2x, a2y, a2z)
                    cand[3] = k
                    dist = 0.0
                    for t in range(4):
                        x = cand[t]
                        if x < lo[t] and x + 2.0 * np.pi <= hi[t]:
                            x += 2.0 * np.pi
                        elif x > hi[t] and x - 2.0 * np.pi >= lo[t]:
                            x -= 2.0 * np.pi
                        if x < lo[t] or x > hi[t]:
                            dist = np.inf
                            break
                        cand[t] = x
                        dist += ((x - seed[i, t]) * scale[t]) ** 2
                    if dist < best:
                        best = dist
                        values[i, 0], values[i, 1], values[i, 2], values[i, 3] = cand[0], cand[1], cand[2], cand[3]
                        found[i] = True


@numba.njit(cache=True, nogil=True, inline="always")
def _turn(vx, vy, vz, ax, ay, az, angle):
    """(vx, vy, vz) turned by angle about the unit axis (ax, ay, az) (Rodrigues)."""
    c, s = np.cos(angle), np.sin(angle)
    d = (vx * ax + vy * ay + vz * az) * (1.0 - c)
    return (vx * c + (ay * vz - az * vy) * s + ax * d, vy * c + (az * vx - ax * vz) * s + ay * d,
            vz * c + (ax * vy - ay * vx) * s + az * d)


@numba.njit(cache=True, nogil=True, inline="always")
def _subangle(bx, by, bz, cx, cy, cz, ax, ay, az):
    """The turn about the unit axis a that takes b's projection onto c's (Paden-Kahan subproblem 1)."""
    db, dc = bx * ax + by * ay + bz * az, cx * ax + cy * ay + cz * az
    bx, by, bz = bx - db * ax, by - db * ay, bz - db * az
    cx, cy, cz = cx - dc * ax, cy - dc * ay, cz - dc * az
    cross = (by * cz - bz * cy) * ax + (bz * cx - bx * cz) * ay + (bx * cy - by * cx) * az
    return np.arctan2(cross, bx * cx + by * cy + bz * cz)


def hips(arm: Arm) -> tuple[Hip, ...]:
    """The hips of a tree's limbs (module docstring), one per effector that has one; () on a serial
    arm or a limb without one (solo12's three-joint legs; allegro's fingers, whose second and third
    axes are parallel: its thumb has one)."""
    if not arm.is_tree:
        return ()
    if arm not in _cache:
        _cache[arm] = _find_hips(arm)
    return _cache[arm]


def _find_hips(arm: Arm) -> tuple[Hip, ...]:
    chain, model = arm.chain, arm.model
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    pin.updateFramePlacements(model, data)
    paths = [list(map(int, chain.path(e))) for e in range(arm.n_effectors)]
    found = []
    for e, path in enumerate(paths):
        shared = {j for f, other in enumerate(paths) if f != e for j in other}
        own = [j for j in path if j not in shared]
        start = path.index(own[0]) if own else len(path)
        limb = path[start:start + 4]
        if len(limb) < 4 or any(chain.kind[j] != REVOLUTE for j in path[:start + 4]) or path[start:] != own:
            continue  # _local_goals undoes a prefix of revolute joints only
        axes, origins = [], []
        for j in limb:
            placement = data.oMi[int(chain.joint_ids[j])]
            axis = placement.rotation @ _joint_kind(model.joints[int(chain.joint_ids[j])])[1]
            axes.append(axis / np.linalg.norm(axis))
            origins.append(placement.translation.copy())
        a1, a2 = axes[1], axes[2]
        normal = np.cross(a1, a2)
        if np.linalg.norm(normal) < 1e-6:  # parallel: no point to turn about (a finger's flexions)
            continue
        t = np.linalg.solve(np.column_stack([a1, -a2, normal]), origins[2] - origins[1])
        H = origins[1] + t[0] * a1 + 0.5 * t[2] * normal
        gap = abs(t[2]) * float(np.linalg.norm(normal))
        effector = data.oMf[int(chain.frame_ids[e])].translation
        knee_off = np.linalg.norm(np.cross(axes[3], H - origins[3]))
        if gap > MAX_GAP * np.linalg.norm(effector - H) or knee_off < 1e-6:
            continue
        after = path[start + 4] if len(path) > start + 4 else -1
        found.append(Hip(e, tuple(path[:start]), tuple(limb), after, np.array(axes), np.array(origins), H,
                         float(gap)))
    return tuple(found)


def _local_goals(arm: Arm, hip: Hip, goals: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The effector's goals (n, 3) with the prefix's motion undone: in the frame the prefix has at zero."""
    if not hip.prefix:
        return goals
    chain = arm.chain
    n = len(q)
    R, p = np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.zeros((n, 3))
    R0, p0 = np.eye(3), np.zeros(3)
    for k in hip.prefix:  # the chain's own composition (robots.kinematics.tree_points), at q and at zero
        p = p + R @ chain.pos[k]
        R = R @ chain.rot[k]
        p0, R0 = p0 + R0 @ chain.pos[k], R0 @ chain.rot[k]
        c, s = np.cos(q[:, k]), np.sin(q[:, k])
        R[:, :, 0], R[:, :, 1] = c[:, None] * R[:, :, 0] + s[:, None] * R[:, :, 1], \
            c[:, None] * R[:, :, 1] - s[:, None] * R[:, :, 0]
    local = np.einsum("nji,nj->ni", R, goals - p)
    return local @ R0.T + p0


def _solve_hip(arm: Arm, hip: Hip, goals: np.ndarray, q: np.ndarray, sweep: int,
               full: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """q (n, nq) with this hip's limb solved where a solution exists, and the (n,) mask of the goals
    solved; full=False: without the sweep of the joint after the knee and the corrections (a prefix's
    trial)."""
    goal = _local_goals(arm, hip, goals[:, hip.effector], q)
    joints, j0 = list(hip.joints), hip.joints[0]
    p = np.concatenate([q[:, [j0]], np.broadcast_to(np.linspace(arm.lower[j0], arm.upper[j0], sweep),
                                                    (len(q), sweep))], axis=1)
    values, found = hip.nearest(arm, goal, q, p)
    q = q.copy()
    q[np.ix_(found, joints)] = values[found]
    if full and not found.all():  # the thin cases: a denser sweep, the joint after the knee swept too
        miss = np.flatnonzero(~found)
        dense = np.broadcast_to(np.linspace(arm.lower[j0], arm.upper[j0], DENSE_SWEEP), (len(miss), DENSE_SWEEP))
        held = [None] if hip.after < 0 else \
            [None, *np.linspace(arm.lower[hip.after], arm.upper[hip.after], HELD_SWEEP)]
        for v in held:
            q_try = q[miss].copy()
            if v is not None:
                q_try[:, hip.after] = v
            values, ok = hip.nearest(arm, goal[miss], q_try, np.ascontiguousarray(dense))
            rows = miss[ok]
            q[rows] = q_try[ok]
            q[np.ix_(rows, joints)] = values[ok]
            found[rows] = True
            miss = miss[~ok]
            if not len(miss):
                break
    if full and not hip.exact and found.any():  # the goal moved by the miss, the same first joint and nearest branch
        rows = np.flatnonzero(found)
        target = goal[rows].copy()
        for _ in range(CORRECTIONS):
            reached = _local_goals(arm, hip, arm.reach(q[rows])[:, hip.effector], q[rows])
            target = target + goal[rows] - reached
            values, ok = hip.nearest(arm, target, q[rows], q[rows][:, [j0]])
            q[np.ix_(rows[ok], joints)] = values[ok]
    return q, found


def solve(arm: Arm, goals, q, *, sweep: int = SWEEP) -> tuple[np.ndarray, np.ndarray]:
    """Every hip of a tree re-solved from the seeds q (n, nq) toward goals (n, E, 3) (module
    docstring): (q (n, nq), solved (n, E)), solved True for an effector whose hip found a solution
    (exact when its axes meet, within the corrections' residual otherwise); the other joints, and a
    limb without a solution, as q holds them, but for a shared prefix moved so that all its hips solve.
    Never farther: a limb group (robots.kinematics.limb_groups) whose effectors end farther from
    their goals than the seed put them keeps the seed's joints (solved False there)."""
    goals = np.asarray(goals, dtype=np.float64)
    q = np.array(q, dtype=np.float64, copy=True)
    if goals.ndim != 3 or goals.shape[1:] != (arm.n_effectors, 3) or q.shape != (len(goals), arm.nq):
        raise ValueError(f"{arm.name}: limbs.solve takes goals (n, {arm.n_effectors}, 3) and q (n, {arm.nq}), "
                         f"got {goals.shape} and {q.shape}")
    solved = np.zeros((len(q), arm.n_effectors), dtype=bool)
    seed, found = q.copy(), hips(arm)
    for prefix in dict.fromkeys(h.prefix for h in found):
        group = [h for h in found if h.prefix == prefix]
        for hip in group:
            q, solved[:, hip.effector] = _solve_hip(arm, hip, goals, q, sweep)
        effectors = [h.effector for h in group]
        miss = np.flatnonzero(~solved[:, effectors].all(axis=1))
        if not prefix or not len(miss):
            continue
        q[miss], moved = _prefix_grid(arm, group, goals[miss], q[miss], sweep)
        solved[np.ix_(miss[moved], effectors)] = True
    if found:  # never farther: a limb group keeps the seed's joints where they put it nearer its goals
        before = np.linalg.norm(arm.reach(seed) - goals, axis=-1)
        after = np.linalg.norm(arm.reach(q) - goals, axis=-1)
        for group in arm.chain.limb_groups:
            joints = np.unique(np.concatenate([arm.chain.path(e) for e in group]))
            worse = after[:, group].max(axis=1) > before[:, group].max(axis=1)
            q[np.ix_(worse, joints)] = seed[np.ix_(worse, joints)]
            solved[np.ix_(worse, group)] = False
    return q, solved


def _prefix_grid(arm: Arm, group: list[Hip], goals: np.ndarray, q: np.ndarray, sweep: int):
    """For seeds whose shared prefix leaves a hip of the group unsolved: the prefixes of the grid
    (module docstring), the nearest the seed's under which every hip solves, tried in two rounds (the
    joints that turn more than a quarter turn over their grid, the others as the seed holds them; then the
    whole grid for the seeds still unsolved); (q, moved (n,)): q as given where no prefix solves all."""
    prefix = list(group[0].prefix)
    lo, hi = arm.lower[prefix], arm.upper[prefix]
    wide = hi - lo > 0.5 * np.pi
    out, moved = q.copy(), np.zeros(len(q), dtype=bool)
    for whole in (False, True):
        rows = np.flatnonzero(~moved)
        if not len(rows) or (not whole and not wide.any()):
            continue
        axes = [np.linspace(a, b, PREFIX_GRID if w else 3) if whole or w else [np.nan]
                for a, b, w in zip(lo, hi, wide)]
        grid = np.array(list(itertools.product(*axes)))  # (K, len(prefix)); NaN: the seed's value
        K = len(grid)
        tiled = np.repeat(q[rows], K, axis=0)
        tiled[:, prefix] = np.where(np.isnan(grid), tiled[:, prefix].reshape(len(rows), K, -1),
                                    grid).reshape(-1, len(prefix))
        goals_t = np.repeat(goals[rows], K, axis=0)
        ok = np.ones(len(tiled), dtype=bool)
        for hip in group:
            tiled, found = _solve_hip(arm, hip, goals_t, tiled, GRID_SWEEP, full=False)
            ok &= found
        dist = np.sum(((tiled[:, prefix] - np.repeat(q[rows][:, prefix], K, axis=0)) / (hi - lo)) ** 2, axis=1)
        dist = np.where(ok, dist, np.inf).reshape(len(rows), K)
        pick = dist.argmin(axis=1)
        best = np.isfinite(dist[np.arange(len(rows)), pick])
        chosen = tiled.reshape(len(rows), K, -1)[np.arange(len(rows)), pick][best]
        for hip in group:  # the prefix chosen, each hip solved again in full from the seed's own limb
            chosen[:, list(hip.joints)] = q[rows[best]][:, list(hip.joints)]
            chosen, _ = _solve_hip(arm, hip, goals[rows[best]], chosen, sweep)
        out[rows[best]] = chosen
        moved[rows[best]] = True
    return out, moved
