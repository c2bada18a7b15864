"""Batched forward kinematics of a serial chain, derived from a Pinocchio model.

The chain from the root to the end-effector frame is read off the model once
(joint placements, joint types and axes, the frame placement) and flattened into
arrays that a compiled kernel walks for every configuration:

    T_0e(q) = prod_k [ M_k  J_k(q_k) ] * M_e          (M: fixed SE3, J: joint motion)

Every joint is re-expressed about its local z axis: with A_k a rotation taking z
onto the joint axis a_k,  M_k J_a(q) = (M_k A_k) J_z(q) A_k^T,  and A_k^T is folded
into the next fixed placement. A revolute joint then only mixes two columns of
the running rotation (c, s); a prismatic one adds q times its third column.

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
    """The kinematic chain from a model's root to one frame, as flat arrays.

    Attributes (k over the chain's joints, in order from the root):
        joint_ids  (n,)      Pinocchio joint indices
        rot        (n, 3, 3) fixed rotation before joint k, axis folded to z
        pos        (n, 3)    fixed translation before joint k
        kind       (n,)      REVOLUTE or PRISMATIC
        continuous (n,)      True for a continuous joint (cos/sin in Pinocchio)
        identity   (n,)      True where rot[k] is exactly the identity (skipped by the kernel)
        ee_pos     (3,)      end-effector position in the last joint's z-aligned frame
    """

    def __init__(self, model: pin.Model, frame_id: int):
        frame = model.frames[frame_id]
        chain = [j for j in model.supports[frame.parentJoint] if j != 0]
        n = len(chain)
        self.joint_ids = np.array(chain, dtype=np.int64)
        self.rot = np.empty((n, 3, 3))
        self.pos = np.empty((n, 3))
        self.kind = np.empty(n, dtype=np.int64)
        self.continuous = np.zeros(n, dtype=bool)
        self.idx_q = np.empty(n, dtype=np.int64)  # index into Pinocchio's q
        prev = np.eye(3)  # A_{k-1}^T folded into the next placement
        for k, j in enumerate(chain):
            jm = model.joints[j]
            kind, axis, cont = _joint_kind(jm)
            M = model.jointPlacements[j]
            A = _z_to(axis)
            self.rot[k] = prev @ M.rotation @ A
            self.pos[k] = prev @ M.translation
            self.kind[k] = kind
            self.continuous[k] = cont
            self.idx_q[k] = jm.idx_q
            prev = A.T
        self.ee_pos = prev @ frame.placement.translation
        self.identity = np.array([np.array_equal(r, np.eye(3)) for r in self.rot], dtype=bool)
        self.nq_pin = model.nq

    @property
    def n(self) -> int:
        return len(self.joint_ids)

    @property
    def arrays(self) -> tuple:
        """(rot, pos, kind, identity, ee_pos): the arguments `chain_point` takes after q and i."""
        return self.rot, self.pos, self.kind, self.identity, self.ee_pos

    def positions(self, q: np.ndarray) -> np.ndarray:
        """End-effector positions, (N, n) -> (N, 3)."""
        out = np.empty((q.shape[0], 3))
        _chain_kernel(q, self.rot, self.pos, self.kind, self.identity, self.ee_pos, out, _NO_JOINTS)
        return out

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Positional Jacobian of the end effector, (N, n) -> (N, 3, n): d fk / d q in the base frame."""
        out = np.empty((q.shape[0], 3, self.n))
        _jacobian_kernel(q, self.rot, self.pos, self.kind, self.identity, self.ee_pos, out)
        return out

    def joint_positions(self, q: np.ndarray) -> np.ndarray:
        """Origins of the base, of every joint and of the end effector, (N, n) -> (N, n + 2, 3)."""
        joints = np.zeros((q.shape[0], self.n + 2, 3))
        _chain_kernel(q, self.rot, self.pos, self.kind, self.identity, self.ee_pos, joints[:, -1], joints)
        return joints

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
def chain_point(q, i, rot, pos, kind, identity, ee_pos, joints, axes=None):
    """End-effector position (x, y, z) of configuration q[i] (compiled; for use in other kernels).

    The running rotation R = [r00 .. r22] and position p = (px, py, pz) live in scalars:
    per joint k,  p += R pos[k];  R = R rot[k];  then a revolute joint mixes columns 0 and 1
    of R by (cos q, sin q), a prismatic one adds q R[:, 2] to p. If joints has rows, the
    origin of each joint (before its own motion) is written to joints[i, k + 1]; if axes is given,
    each joint's axis in the base frame (R[:, 2] once its fixed placement is applied) to axes[k].
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    px, py, pz = 0.0, 0.0, 0.0
    for k in range(rot.shape[0]):
        px += r00 * pos[k, 0] + r01 * pos[k, 1] + r02 * pos[k, 2]
        py += r10 * pos[k, 0] + r11 * pos[k, 1] + r12 * pos[k, 2]
        pz += r20 * pos[k, 0] + r21 * pos[k, 1] + r22 * pos[k, 2]
        if joints.shape[0] > 0:
            joints[i, k + 1, 0] = px
            joints[i, k + 1, 1] = py
            joints[i, k + 1, 2] = pz
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
    return (
        px + r00 * ee_pos[0] + r01 * ee_pos[1] + r02 * ee_pos[2],
        py + r10 * ee_pos[0] + r11 * ee_pos[1] + r12 * ee_pos[2],
        pz + r20 * ee_pos[0] + r21 * ee_pos[1] + r22 * ee_pos[2],
    )


@numba.njit(cache=True, nogil=True)
def _chain_kernel(q, rot, pos, kind, identity, ee_pos, out, joints):
    """chain_point for every row of q, into out (N, 3); joint origins into joints if it has rows."""
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = chain_point(q, i, rot, pos, kind, identity, ee_pos, joints)


@numba.njit(cache=True, nogil=True)
def _jacobian_kernel(q, rot, pos, kind, identity, ee_pos, J):
    """J (N, 3, n) <- the end effector's positional Jacobian at every row of q (N, n).

    The chain is walked by chain_point, which gives the end effector and each joint's origin o_k
    and axis a_k in the base frame. Column k is  a_k x (p_ee - o_k)  for a revolute joint and  a_k
    for a prismatic one (the derivative of fk with respect to that joint's coordinate: for a
    continuous joint, its angle).
    """
    n = rot.shape[0]
    axes = np.empty((n, 3))
    origins = np.empty((q.shape[0], n + 2, 3))
    for i in range(q.shape[0]):
        ex, ey, ez = chain_point(q, i, rot, pos, kind, identity, ee_pos, origins, axes)
        for k in range(n):
            ax, ay, az = axes[k, 0], axes[k, 1], axes[k, 2]
            if kind[k] == 0:
                dx, dy, dz = ex - origins[i, k + 1, 0], ey - origins[i, k + 1, 1], ez - origins[i, k + 1, 2]
                J[i, 0, k] = ay * dz - az * dy
                J[i, 1, k] = az * dx - ax * dz
                J[i, 2, k] = ax * dy - ay * dx
            else:
                J[i, 0, k], J[i, 1, k], J[i, 2, k] = ax, ay, az
