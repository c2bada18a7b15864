"""An arm's visual geometry as plain arrays, and its joints' poses: what any viewer needs to draw it.

    geoms = visual_geometry(arm)   # one VisualGeometry per visual object of the chain
    poses = joint_poses(arm, q)    # {joint index: (position (3,), wxyz (4,))} in the base frame
    undrawn_joints(arm)            # the chain's joints whose link has nothing to draw (no visual, or a
                                   # mesh that does not resolve: arm.missing_meshes)

Meshes come from the geometry's BVH as Pinocchio loaded it (already scaled), so .dae and .stl
files need no loader of their own; the paper's arms are boxes and cylinders. Used by the app
(viser) and by the recordings (Rerun).
"""

from __future__ import annotations

import functools
import warnings
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from robots.arm import Arm


class VisualGeometry(NamedTuple):
    """One visual object: the joint it moves with, its placement in that joint's frame
    (position, wxyz), its kind ("Box", "Cylinder", "Sphere" or "Mesh"), its parameters
    (Box: (size (3,),); Cylinder: (radius, length); Sphere: (radius,); Mesh: (V (k, 3) float32,
    F (m, 3) uint32)) and its colour (r, g, b, a) in [0, 1]."""

    joint: int
    position: np.ndarray
    wxyz: np.ndarray
    kind: str
    params: tuple
    rgba: np.ndarray


def se3_pose(M: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
    """(position, wxyz) of an SE3 (Pinocchio's quaternions are xyzw)."""
    xyzw = pin.Quaternion(M.rotation).coeffs()
    return np.array(M.translation, float), np.array([xyzw[3], xyzw[0], xyzw[1], xyzw[2]])


@functools.lru_cache(maxsize=32)
def visual_geometry(arm: Arm) -> tuple[VisualGeometry, ...]:
    """The chain's visual objects (an unknown geometry type is left out): their vertices and faces, kept
    per arm; the model they are read from (with each mesh's collision tree, 30 times larger) is not."""
    out = []
    for g in arm.visual_model(keep=False).geometryObjects:
        geo = g.geometry
        kind = type(geo).__name__
        pos, wxyz = se3_pose(g.placement)
        rgba = np.clip(np.asarray(g.meshColor, float), 0, 1)
        if kind == "Box":
            params = (2 * np.asarray(geo.halfSide),)
        elif kind == "Cylinder":
            params = (float(geo.radius), 2 * float(geo.halfLength))
        elif kind == "Sphere":
            params = (float(geo.radius),)
        elif hasattr(geo, "num_tris"):  # BVH mesh, already scaled by Pinocchio
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                V = np.asarray(geo.vertices(), dtype=np.float32)
                tris = (geo.tri_indices(i) for i in range(geo.num_tris))
                F = np.array([(t[0], t[1], t[2]) for t in tris], dtype=np.uint32)
            kind, params = "Mesh", (V, F.reshape(-1, 3))
        else:
            continue
        out.append(VisualGeometry(int(g.parentJoint), pos, wxyz, kind, params, rgba))
    return tuple(out)


def joint_poses(arm: Arm, q, data: pin.Data | None = None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{joint index 1 .. njoints-1: (position, wxyz)} of the arm at joint values q (nq,), base frame."""
    data = data if data is not None else arm.model.createData()
    pin.forwardKinematics(arm.model, data, arm.to_pinocchio(np.asarray(q, dtype=np.float64)))
    return {j: se3_pose(data.oMi[j]) for j in range(1, arm.model.njoints)}


def undrawn_joints(arm: Arm) -> tuple[str, ...]:
    """The chain's joints whose moving link no visual object draws (the URDF gives it no <visual>, or its
    mesh file does not resolve: `arm.missing_meshes` names those links); a viewer draws a capsule there."""
    drawn = {g.joint for g in visual_geometry(arm)}
    return tuple(arm.model.names[int(j)] for j in arm.chain.joint_ids if int(j) not in drawn)
