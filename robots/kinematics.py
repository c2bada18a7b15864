"""Batched forward kinematics of a kinematic tree (a serial chain as its simplest case), from a Pinocchio model.

The joints on the paths from the root to the end-effector frames are read off the model once
(joint placements, joint types and axes, each joint's parent, the frames' placements) and
flattened into arrays that a compiled kernel walks for every configuration. Joint k's frame is

    T_k(q) = T_parent(k)(q) M_k J_k(q_k)        (T of the root: identity; M: fixed SE3, J: joint motion)

and an end effector e sits at T_j(e)(q) M_e, j(e) the joint that carries it. Joints are numbered
as the model numbers them (parents first), which is also the order of the joint vector q. A
serial chain is the tree whose joint k has parent k - 1 and one end effector on its last joint.

Every joint is re-expressed about its local z axis: with A_k a rotation taking z
onto the joint axis a_k,  M_k J_a(q) = (M_k A_k) J_z(q) A_k^T,  and A_k^T is folded
into the fixed placements of the joint's children and effectors. A revolute joint then only mixes
two columns of the running rotation (c, s); a prismatic one adds q times its third column.

Angles: a continuous joint (Pinocchio's RUB*, nq = 2 as cos/sin) is one angle here;
`ChainKinematics.to_pinocchio` maps angle vectors onto Pinocchio configurations.
"""

from __future__ import annotations

import numpy as np
import numba
import pinocchio as pin

REVOLUTE, PRISMATIC = 0, 1


def _joint_kind(jm: pin.JointModel) -> tuple[int, np.ndarray, bool]:
    """(REVOLUTE or PRISMATIC, unit axis in the joint frame, continuous?) of one joint.

    Read off the joint's motion subspace S = (linear; angular), so every one-axis joint type
    (RX.., RUBX.., PX.., and the unaligned ones, whose axis the JointModel variant hides) is one
    case: a revolute joint moves along its angular part, a prismatic one along its linear part.
    """
    short = jm.shortname()  # e.g. JointModelRZ, JointModelRUBY, JointModelPrismaticUnaligned
    if jm.nv == 1 and jm.nq in (1, 2):  # nq 2: a continuous joint, stored as (cos, sin)
        data = jm.createData()
        jm.calc(data, np.array([1.0, 0.0]) if jm.nq == 2 else np.zeros(1))
        S = np.asarray(data.S, dtype=float).reshape(6)
        lin, ang = np.linalg.norm(S[:3]), np.linalg.norm(S[3:])
        if lin < 1e-12 < ang:
            return REVOLUTE, S[3:] / ang, jm.nq == 2
        if ang < 1e-12 < lin and jm.nq == 1:
            return PRISMATIC, S[:3] / lin, False
    raise ValueError(
        f"joint type {short} is not supported by the batched kinematics "
        "(serial chains of revolute, continuous and prismatic joints only)"
    )


def _z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation matrix whose third column is `axis` (unit)."""
    a = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, a)
    x /= np.linalg.norm(x)
    y = np.cross(a, x)
    return np.column_stack([x, y, a])


class ChainKinematics:
    """The joints from a model's root to one or more frames (the end effectors), as flat arrays:
    a serial chain for one frame, a tree for several.

    Attributes (k over the joints on a path to an effector, in the model's order, parents first;
    e over the effectors, in the order given):
        joint_ids  (n,)      Pinocchio joint indices
        parent     (n,)      index k of each joint's parent joint, -1 for a joint on the root
        rot        (n, 3, 3) fixed rotation before joint k, axis folded to z
        pos        (n, 3)    fixed translation before joint k
        kind       (n,)      REVOLUTE or PRISMATIC
        continuous (n,)      True for a continuous joint (cos/sin in Pinocchio)
        identity   (n,)      True where rot[k] is exactly the identity (skipped by the kernel)
        frame_ids  (E,)      the effectors' Pinocchio frame indices
        ee_joint   (E,)      index k of the joint that carries each effector
        effector_pos (E, 3)  each effector's position in its joint's z-aligned frame
        on_path    (E, n)    True where joint k moves effector e (is on the path from the root to it)
        ee_pos     (3,)      effector_pos[0], of a serial chain (one effector) only
    """

    def __init__(self, model: pin.Model, frame_ids):
        frame_ids = [int(frame_ids)] if np.ndim(frame_ids) == 0 else [int(f) for f in frame_ids]
        frames = [model.frames[f] for f in frame_ids]
        joints = sorted({j for f in frames for j in model.supports[f.parentJoint] if j != 0})
        n = len(joints)
        index = {j: k for k, j in enumerate(joints)}
        self.joint_ids = np.array(joints, dtype=np.int64)
        self.parent = np.array([index.get(int(model.parents[j]), -1) for j in joints], dtype=np.int64)
        self.rot = np.empty((n, 3, 3))
        self.pos = np.empty((n, 3))
        self.kind = np.empty(n, dtype=np.int64)
        self.continuous = np.zeros(n, dtype=bool)
        self.idx_q = np.empty(n, dtype=np.int64)  # index into Pinocchio's q
        folded = []  # A_k^T of each joint, folded into the placements of its children and effectors
        for k, j in enumerate(joints):
            jm = model.joints[j]
            kind, axis, cont = _joint_kind(jm)
            M = model.jointPlacements[j]
            A = _z_to(axis)
            prev = folded[self.parent[k]] if self.parent[k] >= 0 else np.eye(3)
            self.rot[k] = prev @ M.rotation @ A
            self.pos[k] = prev @ M.translation
            self.kind[k] = kind
            self.continuous[k] = cont
            self.idx_q[k] = jm.idx_q
            folded.append(A.T)
        self.frame_ids = np.array(frame_ids, dtype=np.int64)
        self.ee_joint = np.array([index.get(f.parentJoint, -1) for f in frames], dtype=np.int64)
        self.effector_pos = np.array(
            [(folded[k] if k >= 0 else np.eye(3)) @ f.placement.translation for k, f in zip(self.ee_joint, frames)]
        ).reshape(len(frames), 3)
        self.on_path = np.zeros((len(frames), n), dtype=bool)
        for e, k in enumerate(self.ee_joint):
            while k >= 0:
                self.on_path[e, k] = True
                k = self.parent[k]
        self.identity = np.array([np.array_equal(r, np.eye(3)) for r in self.rot], dtype=bool)
        self.nq_pin = model.nq
        self.serial = len(frames) == 1 and bool(np.all(self.parent == np.arange(n) - 1)) and (
            n == 0 or self.ee_joint[0] == n - 1)
        self._ee_pos = np.ascontiguousarray(self.effector_pos[0]) if self.serial else None

    @property
    def n(self) -> int:
        return len(self.joint_ids)

    @property
    def n_effectors(self) -> int:
        return len(self.frame_ids)

    @property
    def ee_pos(self) -> np.ndarray:
        """(3,) the end effector's position in the last joint's z-aligned frame (a serial chain only)."""
        if self._ee_pos is None:
            raise ValueError(f"a tree of {self.n_effectors} end effectors has no single ee_pos: use effector_pos")
        return self._ee_pos

    @property
    def arrays(self) -> tuple:
        """(rot, pos, kind, identity, ee_pos) of a serial chain: what a kernel that composes the chain
        joint after joint (the lab's fitness kernels) takes. A tree has no such chain: ValueError."""
        if self._ee_pos is None:
            raise ValueError(f"a tree of {self.n_effectors} end effectors is not a serial chain: "
                             "use tree_arrays (each joint's parent, each effector's joint)")
        return self.rot, self.pos, self.kind, self.identity, self._ee_pos

    def path(self, e: int) -> np.ndarray:
        """Indices k of the joints that move effector e, root first: its serial chain within the tree."""
        return np.flatnonzero(self.on_path[e])

    @property
    def limb_groups(self) -> list[list[int]]:
        """The effectors grouped so that no two groups share a joint (limb_groups of their paths)."""
        return limb_groups([self.path(e) for e in range(self.n_effectors)])

    def effector_arrays(self, e: int) -> tuple:
        """(rot, pos, kind, identity, ee_pos) of effector e's own serial chain, the joints path(e) in
        order: what `arrays` is for a serial arm. Each joint's fixed placement is folded relative to
        its parent, which is the previous joint on the path, so composing these joint after joint on
        q[..., path(e)] gives effector e (the lab's chain kernels can take a tree one effector at a time)."""
        k = self.path(e)
        return (np.ascontiguousarray(self.rot[k]), np.ascontiguousarray(self.pos[k]),
                np.ascontiguousarray(self.kind[k]), np.ascontiguousarray(self.identity[k]),
                np.ascontiguousarray(self.effector_pos[e]))

    @property
    def tree_arrays(self) -> tuple:
        """(rot, pos, kind, identity, parent, ee_joint, effector_pos): the arguments `tree_points`
        takes after q and i; any tree, a serial chain included."""
        return self.rot, self.pos, self.kind, self.identity, self.parent, self.ee_joint, self.effector_pos

    @property
    def point_parents(self) -> np.ndarray:
        """(1 + n + E,) for each point of `joint_positions` (the root, the joints' origins, the effectors)
        the index of the point it hangs from, -1 for the root: the segments of a stick figure. A serial
        chain's is [-1, 0, 1, ..., n]: a polyline."""
        return np.concatenate([[-1], self.parent + 1, self.ee_joint + 1]).astype(np.int64)

    def positions(self, q: np.ndarray) -> np.ndarray:
        """End-effector positions, (N, n) -> (N, E, 3)."""
        out = np.empty((q.shape[0], self.n_effectors, 3))
        _tree_kernel(q, *self.tree_arrays, out, _NO_JOINTS)
        return out

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Positional Jacobians of the end effectors, (N, n) -> (N, E, 3, n): d fk / d q in the base
        frame; column k of effector e is zero where joint k does not move it (on_path)."""
        out = np.empty((q.shape[0], self.n_effectors, 3, self.n))
        _jacobian_kernel(q, *self.tree_arrays, self.on_path, out)
        return out

    def joint_positions(self, q: np.ndarray) -> np.ndarray:
        """Origins of the root, of every joint and of every end effector, (N, n) -> (N, 1 + n + E, 3)."""
        E = self.n_effectors
        points = np.zeros((q.shape[0], self.n + 1 + E, 3))
        out = np.empty((q.shape[0], E, 3))
        _tree_kernel(q, *self.tree_arrays, out, points)
        points[:, self.n + 1:] = out
        return points

    def to_pinocchio(self, q: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
        """Angle vectors (N, n) -> Pinocchio configurations (N, model.nq), other coordinates from q_ref."""
        out = np.tile(q_ref, (q.shape[0], 1))
        for k in range(self.n):
            i = self.idx_q[k]
            if self.continuous[k]:
                out[:, i] = np.cos(q[:, k])
                out[:, i + 1] = np.sin(q[:, k])
            else:
                out[:, i] = q[:, k]
        return out

    def from_pinocchio(self, q_pin: np.ndarray) -> np.ndarray:
        """Pinocchio configurations (..., model.nq) -> angle vectors (..., n): a continuous
        joint's (cos, sin) becomes its angle in [-pi, pi]."""
        q_pin = np.asarray(q_pin, dtype=np.float64)
        cols = []
        for k in range(self.n):
            i = self.idx_q[k]
            if self.continuous[k]:
                cols.append(np.arctan2(q_pin[..., i + 1], q_pin[..., i]))
            else:
                cols.append(q_pin[..., i])
        return np.stack(cols, axis=-1)


_NO_JOINTS = np.empty((0, 0, 3))


@numba.njit(cache=True, nogil=True, inline="always")
def tree_points(q, i, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, out, o, joints, axes=None):
    """End-effector positions of configuration q[i] into out[o] (E, 3) (compiled; for use in other kernels).

    Joints in order (parents first); joint k starts from its parent's frame (the identity for a
    joint on the root; F[parent[k]] unless the parent is joint k - 1, whose frame is still at
    hand): p += R pos[k];  R = R rot[k];  then a revolute joint mixes columns 0 and 1 of R by
    (cos q, sin q), a prismatic one adds q R[:, 2] to p; its frame goes to F[k] = (R row by row,
    p) (F: scratch of shape (n, 12)). Effector e is p + R effector_pos[e] of
    its joint's frame. A serial chain keeps its running R and p from joint to joint: the same
    operations, in the same order, as the lab's kernels, which compose a serial chain.
    If joints has rows, the origin of each joint (before its own motion) is written to
    joints[o, k + 1]; if axes is given, each joint's axis in the base frame (R[:, 2] once its fixed
    placement is applied) to axes[k]. o: the row of out and joints (i, or 0 for scratch of one row).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    px, py, pz = 0.0, 0.0, 0.0
    for k in range(rot.shape[0]):
        b = parent[k]
        if b < 0:
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
            px, py, pz = 0.0, 0.0, 0.0
        elif b != k - 1:  # a branch: the parent's frame, kept; else the previous joint's, still at hand
            r00, r01, r02, r10, r11, r12 = F[b, 0], F[b, 1], F[b, 2], F[b, 3], F[b, 4], F[b, 5]
            r20, r21, r22, px, py, pz = F[b, 6], F[b, 7], F[b, 8], F[b, 9], F[b, 10], F[b, 11]
        px += r00 * pos[k, 0] + r01 * pos[k, 1] + r02 * pos[k, 2]
        py += r10 * pos[k, 0] + r11 * pos[k, 1] + r12 * pos[k, 2]
        pz += r20 * pos[k, 0] + r21 * pos[k, 1] + r22 * pos[k, 2]
        if joints.shape[0] > 0:
            joints[o, k + 1, 0] = px
            joints[o, k + 1, 1] = py
            joints[o, k + 1, 2] = pz
        if not identity[k]:
            m = rot[k]
            a00 = r00 * m[0, 0] + r01 * m[1, 0] + r02 * m[2, 0]
            a01 = r00 * m[0, 1] + r01 * m[1, 1] + r02 * m[2, 1]
            a02 = r00 * m[0, 2] + r01 * m[1, 2] + r02 * m[2, 2]
            a10 = r10 * m[0, 0] + r11 * m[1, 0] + r12 * m[2, 0]
            a11 = r10 * m[0, 1] + r11 * m[1, 1] + r12 * m[2, 1]
            a12 = r10 * m[0, 2] + r11 * m[1, 2] + r12 * m[2, 2]
            a20 = r20 * m[0, 0] + r21 * m[1, 0] + r22 * m[2, 0]
            a21 = r20 * m[0, 1] + r21 * m[1, 1] + r22 * m[2, 1]
            a22 = r20 * m[0, 2] + r21 * m[1, 2] + r22 * m[2, 2]
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = a00, a01, a02, a10, a11, a12, a20, a21, a22
        if axes is not None:
            axes[k, 0], axes[k, 1], axes[k, 2] = r02, r12, r22
        x = q[i, k]
        if kind[k] == 0:  # revolute about local z
            c = np.cos(x)
            s = np.sin(x)
            r00, r01 = c * r00 + s * r01, c * r01 - s * r00
            r10, r11 = c * r10 + s * r11, c * r11 - s * r10
            r20, r21 = c * r20 + s * r21, c * r21 - s * r20
        else:  # prismatic along local z
            px += x * r02
            py += x * r12
            pz += x * r22
        F[k, 0], F[k, 1], F[k, 2], F[k, 3], F[k, 4], F[k, 5] = r00, r01, r02, r10, r11, r12
        F[k, 6], F[k, 7], F[k, 8], F[k, 9], F[k, 10], F[k, 11] = r20, r21, r22, px, py, pz
    for e in range(ee_joint.shape[0]):
        j = ee_joint[e]
        ex, ey, ez = effector_pos[e, 0], effector_pos[e, 1], effector_pos[e, 2]
        if j < 0:  # a frame on the root (from_urdf refuses it as an effector)
            out[o, e, 0], out[o, e, 1], out[o, e, 2] = ex, ey, ez
        else:
            out[o, e, 0] = F[j, 9] + F[j, 0] * ex + F[j, 1] * ey + F[j, 2] * ez
            out[o, e, 1] = F[j, 10] + F[j, 3] * ex + F[j, 4] * ey + F[j, 5] * ez
            out[o, e, 2] = F[j, 11] + F[j, 6] * ex + F[j, 7] * ey + F[j, 8] * ez


@numba.njit(cache=True, nogil=True)
def _tree_kernel(q, rot, pos, kind, identity, parent, ee_joint, effector_pos, out, joints):
    """tree_points for every row of q, into out (N, E, 3); joint origins into joints if it has rows."""
    F = np.empty((rot.shape[0], 12))
    for i in range(q.shape[0]):
        tree_points(q, i, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, out, i, joints)


@numba.njit(cache=True, nogil=True)
def _jacobian_kernel(q, rot, pos, kind, identity, parent, ee_joint, effector_pos, on_path, J):
    """J (N, E, 3, n) <- every effector's positional Jacobian at every row of q (N, n).

    The tree is walked by tree_points, which gives the effectors and each joint's origin o_k
    and axis a_k in the base frame. Column k of effector e is  a_k x (p_e - o_k)  for a revolute
    joint and  a_k  for a prismatic one (the derivative of fk with respect to that joint's
    coordinate: for a continuous joint, its angle), where joint k moves e (on_path), else zero.
    """
    n = rot.shape[0]
    E = ee_joint.shape[0]
    axes = np.empty((n, 3))
    origins = np.empty((1, n + 1, 3))  # scratch of one row: it stays in cache
    F = np.empty((n, 12))
    p = np.empty((1, E, 3))
    for i in range(q.shape[0]):
        tree_points(q, i, rot, pos, kind, identity, parent, ee_joint, effector_pos, F, p, 0, origins, axes)
        for e in range(E):
            ex, ey, ez = p[0, e, 0], p[0, e, 1], p[0, e, 2]
            for k in range(n):
                if not on_path[e, k]:
                    J[i, e, 0, k], J[i, e, 1, k], J[i, e, 2, k] = 0.0, 0.0, 0.0
                    continue
                ax, ay, az = axes[k, 0], axes[k, 1], axes[k, 2]
                if kind[k] == 0:
                    dx, dy, dz = ex - origins[0, k + 1, 0], ey - origins[0, k + 1, 1], ez - origins[0, k + 1, 2]
                    J[i, e, 0, k] = ay * dz - az * dy
                    J[i, e, 1, k] = az * dx - ax * dz
                    J[i, e, 2, k] = ax * dy - ay * dx
                else:
                    J[i, e, 0, k], J[i, e, 1, k], J[i, e, 2, k] = ax, ay, az


def limb_groups(paths) -> list[list[int]]:
    """Effectors grouped so that no two groups share a joint (connected by shared joints), from each
    effector's path (the joint indices that move it): each group's effectors in order, the groups by
    their first effector. A biped's two legs are two groups, a humanoid's arms and waist one (the
    waist moves both hands). A group's effectors depend on its joints alone."""
    sets = [set(int(j) for j in p) for p in paths]
    group = list(range(len(sets)))

    def root(e):
        while group[e] != e:
            e = group[e]
        return e

    for a in range(len(sets)):
        for b in range(a + 1, len(sets)):
            if sets[a] & sets[b]:
                group[root(b)] = root(a)
    out: dict[int, list[int]] = {}
    for e in range(len(sets)):
        out.setdefault(root(e), []).append(e)
    return sorted(out.values())
