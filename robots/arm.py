"""`Arm`: one serial arm, or a tree of several end effectors, as a Pinocchio model with batched kinematics.

An arm is built from a URDF and the name of its end-effector frame, or the names of several
(a tree: the feet of a legged robot, the fingertips of a hand). Joints that are not on a path
from the root to an end-effector frame (grippers, fingers, a head) are locked at a reference
posture, so `model` holds those paths only, with a fixed base: the URDF's root link fixed in space.
With E end effectors, a goal is one position per effector: fk gives (..., 3) for one, (..., E, 3)
for several.

Joint coordinates are angles [rad] and lengths [URDF units], one per joint: a
continuous joint is a single angle in [-pi, pi] (Pinocchio stores it as cos/sin).
"""

from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pinocchio as pin

from robots.kinematics import PRISMATIC, ChainKinematics
from robots.urdf_tree import rename_clashing_links, resolve_meshes


@dataclass(frozen=True, eq=False)
class Arm:
    """A serial arm or a tree: Pinocchio model, joint limits, task axes and batched kinematics.

    Attributes:
        name       registry name ("planar", "ur5", "g1", ...)
        model      pinocchio.Model of the paths to the end effectors only (fixed base, other joints
                   locked); its joints are ordered as q
        nq         number of joint coordinates (angles / lengths)
        lower      (nq,) lower joint limits
        upper      (nq,) upper joint limits
        task_axes  end-effector coordinates that make a goal: (0, 1) planar, (0, 1, 2) others
                   (for a tree: the same axes of every effector)
        effectors  names of the end-effector frames in `model`, in order (one for a serial arm)
        effector_ids  their indices in model.frames
        ee_frame, ee_frame_id  the one end-effector frame's name and index (a serial arm only)
        urdf_path  the URDF it was built from
        package_dirs  directories that resolve package:// mesh paths
        joint_names   (nq,) names of the chain's joints, root first
        rest       (nq,) rest posture (the model's reference posture, clipped to the limits)
        source     the string `robots.load` rebuilds the arm from: a registered name, "erd:NAME#frame",
                   "/path/arm.urdf#frame" (robots/sources.py); from_urdf's own: "path#frames"
        urdf_sha256  sha256 of the URDF file's bytes (robots.source_status checks it against the file)
        missing_meshes  links whose visual mesh does not resolve: left out of visual_model
    """

    name: str
    model: pin.Model
    lower: np.ndarray
    upper: np.ndarray
    task_axes: tuple[int, ...]
    effectors: tuple[str, ...]
    effector_ids: tuple[int, ...]
    urdf_path: str
    package_dirs: tuple[str, ...]
    joint_names: tuple[str, ...]
    rest: np.ndarray
    q_ref: np.ndarray = field(repr=False)  # Pinocchio configuration for coordinates off the chain
    chain: ChainKinematics = field(repr=False)
    _visual_builder: object = field(repr=False, default=None)
    source: str = ""  # the string robots.load rebuilds this arm from (robots/sources.py)
    urdf_sha256: str = ""  # of the URDF file's bytes when the arm was built
    missing_meshes: tuple[str, ...] = ()  # links whose visual mesh file does not resolve (drawn without it)

    @property
    def nq(self) -> int:
        return self.chain.n

    @property
    def n_effectors(self) -> int:
        """E, the number of end effectors: 1 for a serial arm."""
        return len(self.effectors)

    @property
    def is_tree(self) -> bool:
        """True for several end effectors: goals are (..., E, len(task_axes)), fk (..., E, 3)."""
        return len(self.effectors) > 1

    @property
    def ee_frame(self) -> str:
        """The end-effector frame's name (a serial arm; a tree has `effectors`)."""
        return self._only_effector("effectors")

    @property
    def ee_frame_id(self) -> int:
        """The end-effector frame's index in model.frames (a serial arm; a tree has `effector_ids`)."""
        return self._only_effector("effector_ids")

    def _only_effector(self, plural: str):
        """The one entry of `plural` (effectors, effector_ids) of a serial arm; a tree has several."""
        if self.is_tree:
            raise AttributeError(f"{self.name} has {self.n_effectors} end effectors "
                                 f"({', '.join(self.effectors)}): use arm.{plural}")
        return getattr(self, plural)[0]

    @property
    def _effector_shape(self) -> tuple[int, ...]:
        """() for a serial arm, (E,) for a tree: the axis fk, reach and goals have per effector."""
        return (len(self.effectors),) if len(self.effectors) > 1 else ()

    @property
    def is_prismatic(self) -> np.ndarray:
        """(nq,) True where the joint is prismatic (a length, not an angle)."""
        return self.chain.kind == PRISMATIC

    # ---------------------------------------------------------------- kinematics
    def _as_batch(self, q) -> tuple[np.ndarray, tuple[int, ...]]:
        q = np.asarray(q)
        try:
            if q.dtype.kind not in "biufO":  # complex, strings, dates: no real angle
                raise TypeError
            q = q.astype(np.float64, copy=False)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: q must hold real numbers, got dtype {q.dtype}") from None
        if q.ndim == 0 or q.shape[-1] != self.nq:
            raise ValueError(
                f"{self.name}: q must have shape (..., {self.nq}) (one value per joint: "
                f"{', '.join(self.joint_names)}), got shape {q.shape}"
            )
        batch = q.shape[:-1]
        return np.ascontiguousarray(q.reshape(-1, self.nq)), batch

    def fk(self, q) -> np.ndarray:
        """End-effector positions in the base frame: q (..., nq) -> (..., 3) for a serial arm,
        (..., E, 3) for a tree (effectors in the order of `effectors`)."""
        flat, batch = self._as_batch(q)
        return self.chain.positions(flat).reshape(*batch, *self._effector_shape, 3)

    def jacobian(self, q) -> np.ndarray:
        """Positional Jacobian of `fk`: q (..., nq) -> (..., 3, nq), d p_ee / d q in the base frame;
        (..., E, 3, nq) for a tree (reshape to (..., 3E, nq) for the stacked Jacobian).
        Column k: a_k x (p_ee - o_k) for a revolute joint (axis a_k through o_k; a continuous
        joint's coordinate is its angle), a_k for a prismatic one, zero for a joint that does not
        move that effector. Equals Pinocchio's computeFrameJacobian(..., ee, LOCAL_WORLD_ALIGNED)[:3]
        (the model has nv == nq)."""
        flat, batch = self._as_batch(q)
        return self.chain.jacobian(flat).reshape(*batch, *self._effector_shape, 3, self.nq)

    def joint_positions(self, q) -> np.ndarray:
        """Base, joint and end-effector origins: q (..., nq) -> (..., 1 + nq + E, 3) (the base, the
        joints in the order of q, the effectors); a serial arm's (..., nq + 2, 3) is a polyline,
        a tree's segments join each point to its `point_parents` entry."""
        flat, batch = self._as_batch(q)
        return self.chain.joint_positions(flat).reshape(*batch, self.nq + 1 + self.n_effectors, 3)

    @property
    def point_parents(self) -> np.ndarray:
        """(1 + nq + E,) the point of `joint_positions` each point hangs from (-1 for the base):
        [-1, 0, 1, ..., nq] for a serial arm."""
        return self.chain.point_parents

    def reach(self, q) -> np.ndarray:
        """The goal coordinates reached by q: (..., nq) -> (..., len(task_axes)), or
        (..., E, len(task_axes)) for a tree."""
        return self.fk(q)[..., list(self.task_axes)]

    def to_3d(self, points) -> np.ndarray:
        """Task coordinates (..., len(task_axes)) -> 3D points (..., 3), zero on the other axes."""
        points = np.asarray(points, dtype=np.float64)
        if points.shape[-1:] != (len(self.task_axes),):
            raise ValueError(f"task points must have shape (..., {len(self.task_axes)}), got {points.shape}")
        out = np.zeros(points.shape[:-1] + (3,))
        out[..., list(self.task_axes)] = points
        return out

    def to_pinocchio(self, q) -> np.ndarray:
        """Angle vectors (..., nq) -> Pinocchio configurations (..., model.nq)."""
        flat, batch = self._as_batch(q)
        return self.chain.to_pinocchio(flat, self.q_ref).reshape(*batch, self.model.nq)

    def from_pinocchio(self, q_pin) -> np.ndarray:
        """Pinocchio configurations (..., model.nq) -> angle vectors (..., nq)."""
        q_pin = np.asarray(q_pin, dtype=np.float64)
        if q_pin.ndim == 0 or q_pin.shape[-1] != self.model.nq:
            raise ValueError(f"{self.name}: a Pinocchio configuration has shape (..., {self.model.nq}), "
                             f"got shape {q_pin.shape}")
        return self.chain.from_pinocchio(q_pin)

    def within_limits(self, q) -> np.ndarray:
        """q (..., nq) moved into the limits: a continuous joint turned by whole turns into
        [lower, lower + 2 pi), then every coordinate clipped to [lower, upper]."""
        flat, batch = self._as_batch(q)
        return _within(flat, self.lower, self.upper, self.chain.continuous).reshape(*batch, self.nq)

    # ---------------------------------------------------------------- sampling
    def sample_q(self, n: int, seed: int | None = None) -> np.ndarray:
        """(n, nq) joint vectors drawn uniformly within the limits."""
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be an integer >= 0, got {n!r}")
        rng = np.random.default_rng(seed)
        return self.lower + (self.upper - self.lower) * rng.random((int(n), self.nq))

    def sample_goals(self, n: int, seed: int | None = None) -> np.ndarray:
        """(n, len(task_axes)) reachable goals, (n, E, len(task_axes)) for a tree: end-effector
        positions of uniformly drawn joint vectors. ValueError, never NaN goals, when the kinematics
        give non-finite positions."""
        goals = self.reach(self.sample_q(n, seed))
        if not np.isfinite(goals).all():
            bad = int((~np.isfinite(goals)).reshape(len(goals), -1).any(axis=-1).sum())
            raise ValueError(f"{self.name}: {bad} of {len(goals)} sampled goals are not finite numbers "
                             f"(joint limits {list(zip(self.lower.tolist(), self.upper.tolist()))})")
        return goals

    @functools.cached_property
    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the task coordinates over 20,000 uniform joint samples (a fixed seed); each
        (len(task_axes),), or (E, len(task_axes)) for a tree (one box per effector)."""
        goals = self.sample_goals(20_000, seed=12345)
        lo, hi = goals.min(axis=0), goals.max(axis=0)
        flat = hi - lo < 1e-9  # a coordinate that never moves: give it a unit range
        return np.where(flat, lo - 0.5, lo), np.where(flat, hi + 0.5, hi)

    @functools.cached_property
    def reach_radius(self) -> float:
        """How far the end effector gets from the base origin [length]: the largest distance over
        20,000 uniform joint samples (a fixed seed) and the rest posture. Errors are reported in %
        of it. The rest posture counts because uniform samples rarely stretch out a many-jointed
        arm: a 20-link snake's farthest sample falls 9% short, its rest posture (straight) is exact.
        For a tree: the largest of `effector_reach`."""
        return float(self.effector_reach.max())

    @functools.cached_property
    def effector_reach(self) -> np.ndarray:
        """(E,) how far each end effector gets from the base origin [length], as `reach_radius`
        measures it (20,000 uniform joint samples, a fixed seed, and the rest posture)."""
        q = np.concatenate([self.sample_q(20_000, seed=1), self.rest[None]])
        p = self.chain.positions(q)  # (N, E, 3)
        reach = np.linalg.norm(p, axis=-1).max(axis=0)
        reach.flags.writeable = False
        return reach

    @functools.cached_property
    def base_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(point, direction) of the first joint's axis in the world frame: its unit direction and its
        point nearest the world origin (from the joint's column of Pinocchio's world-frame Jacobian,
        v = p x w), rounded to 1e-9 (a URDF's rounding leaves an axis through the origin there). The
        SO arms' pan axis stands 4-5 cm beside the origin of their URDF."""
        model = self.model
        data = model.createData()
        pin.computeJointJacobians(model, data, self.to_pinocchio(self.rest))
        joint = int(self.chain.joint_ids[0])
        column = pin.getJointJacobian(model, data, joint, pin.WORLD)[:, model.joints[joint].idx_v]
        v, w = column[:3], column[3:]
        if np.dot(w, w) < 1e-12:  # a prismatic first joint: its direction, through the origin
            return np.zeros(3), v / np.linalg.norm(v)
        return np.round(np.cross(w, v) / np.dot(w, w), 9) + 0.0, w / np.linalg.norm(w)

    @property
    def base_upright(self) -> bool:
        """True when the first joint's axis (base_axis) is vertical, +z or -z (within 1e-9)."""
        return abs(self.base_axis[1][2]) > 1.0 - 1e-9

    # ---------------------------------------------------------------- geometry
    def visual_model(self, keep: bool = True) -> pin.GeometryModel:
        """Visual geometry of the chain (meshes loaded on first call; may take ~1 s). keep: kept for
        the next call, VISUAL_MODELS arms at most (a model holds each mesh's collision tree: 160 MiB
        for the g1, 30 times its vertices); keep=False: a model of its own, kept by nobody."""
        return _visual_cache(self) if keep else self._visual_builder()

    def __repr__(self) -> str:
        if self.is_tree:
            return f"Arm({self.name!r}, nq={self.nq}, effectors={self.effectors!r}, task_axes={self.task_axes})"
        return f"Arm({self.name!r}, nq={self.nq}, ee={self.ee_frame!r}, task_axes={self.task_axes})"


VISUAL_MODELS = 2  # the visual models kept (visual_model); robots.visual keeps each arm's vertices instead


@functools.lru_cache(maxsize=VISUAL_MODELS)
def _visual_cache(arm: Arm) -> pin.GeometryModel:
    return arm._visual_builder()


def from_urdf(
    urdf_path: str | os.PathLike,
    ee_frame: str | Sequence[str],
    *,
    name: str | None = None,
    task_axes: Sequence[int] = (0, 1, 2),
    package_dirs: Sequence[str] = (),
    xml_replace: Sequence[tuple[str, str]] = (),
    reference: np.ndarray | None = None,
    limits: dict[str, tuple[float, float]] | None = None,
    srdf: tuple[str, str] | None = None,
    posture: dict[str, float] | None = None,
    source: str | None = None,
    _rename_links: bool = False,
) -> Arm:
    """Build an `Arm` from a URDF file and the name of its end-effector frame, or a sequence of names
    (a tree of several end effectors: feet, fingertips, hands; one name, or a sequence of one, is a
    serial arm). The URDF's root link is fixed in space (no free-flyer); joints on no path from the
    root to an effector are locked. Refused by name: a frame the URDF lacks, a frame given twice, two
    frames on one link (moved by the same joint), a frame on the root link (no joint moves it).

    xml_replace: text substitutions applied to the URDF before parsing (name fixes).
    reference:   Pinocchio configuration of the full model at which off-chain joints are locked.
    limits:      overrides of joint limits by joint name.
    srdf:        (SRDF path, posture name) giving the reference posture, when `reference` is None.
    posture:     joint values by joint name set over the reference posture (a URDF without an SRDF
                 posture: a humanoid's bent knees); the rest posture follows it.
    source:      the string robots.load rebuilds this arm from (default: "path#frame1,frame2").

    Also refused by name, with what to do: a joint of several axes (floating, planar) or a mimic joint
    on a chain, a chain of more than MAX_JOINTS joints. Visual meshes that do not resolve are left out
    of visual_model (their links: `missing_meshes`).
    """
    urdf_path = os.path.realpath(os.fspath(urdf_path))
    name = name or os.path.splitext(os.path.basename(urdf_path))[0]
    axes = tuple(task_axes)
    if not (1 <= len(axes) <= 3 and all(isinstance(a, (int, np.integer)) and not isinstance(a, bool)
                                        and 0 <= a <= 2 for a in axes) and len(set(axes)) == len(axes)):
        raise ValueError(f"{name}: task_axes must be distinct axes among 0, 1, 2 (x, y, z), got {axes!r}")
    try:
        with open(urdf_path, "rb") as f:
            raw = f.read()
        xml = raw.decode("utf-8")
    except OSError as e:
        raise OSError(f"{name}: cannot read URDF {urdf_path}: {e.strerror}") from e
    except UnicodeDecodeError as e:
        raise ValueError(f"{name}: {urdf_path} is not UTF-8 text (byte {e.start}): not a URDF file") from e
    for old, new in xml_replace:
        xml = xml.replace(old, new)
    if _rename_links:
        xml, _ = rename_clashing_links(xml)
    try:
        full = pin.buildModelFromXML(xml)
    except Exception as e:  # Pinocchio raises ValueError/RuntimeError with its parser's text
        raise ValueError(f"{name}: {urdf_path} is not a valid URDF: {e}") from e
    frames = _effector_names(ee_frame, name)
    frame_ids = _effector_frames(full, frames, name, urdf_path)

    on_chain = set().union(*(full.supports[full.frames[f].parentJoint] for f in frame_ids))
    locked = [j for j in range(1, full.njoints) if j not in on_chain]
    q_full = _with_posture(full, _reference(full, reference, srdf, name), posture or {}, name)
    _check_chain_joints(full, sorted(on_chain - {0}), xml, frames, name)
    try:
        model = pin.buildReducedModel(full, locked, q_full) if locked else full
    except ValueError as e:  # a link and a joint of one name (anymal_c's): read again with the link renamed
        if _rename_links or "Several frames match" not in str(e):
            raise
        return from_urdf(urdf_path, ee_frame, name=name, task_axes=task_axes, package_dirs=package_dirs,
                         xml_replace=xml_replace, reference=reference, limits=limits, srdf=srdf, posture=posture,
                         source=source, _rename_links=True)
    frame_ids = tuple(_find_frame(model, f, name, urdf_path) for f in frames)
    chain = ChainKinematics(model, frame_ids)

    joint_names = tuple(model.names[int(j)] for j in chain.joint_ids)
    lower, upper = _limits(model, chain, limits or {}, name)
    q_ref = pin.neutral(model)
    arm_q_ref = _reduce_reference(full, model, q_full)
    rest = _within(chain.from_pinocchio(arm_q_ref)[None], lower, upper, chain.continuous)[0]
    dirs = tuple(package_dirs)
    ee_names = tuple(model.frames[f].name for f in frame_ids)
    vis_xml, missing = resolve_meshes(xml, os.path.dirname(urdf_path), dirs)

    def build_visual() -> pin.GeometryModel:
        vis_full = pin.buildGeomFromUrdfString(full, vis_xml, pin.GeometryType.VISUAL, package_dirs=list(dirs))
        if not locked:
            return vis_full
        _, vis = pin.buildReducedModel(full, vis_full, locked, q_full)
        return vis

    for a in (lower, upper, rest, q_ref):  # load() shares one Arm per name: nobody may change it
        a.flags.writeable = False
    return Arm(
        name=name, model=model, lower=lower, upper=upper, task_axes=tuple(int(a) for a in task_axes),
        effectors=ee_names, effector_ids=frame_ids, urdf_path=urdf_path, package_dirs=dirs, joint_names=joint_names,
        rest=rest, q_ref=q_ref, chain=chain, _visual_builder=build_visual,
        source=source if source is not None else f"{urdf_path}#{','.join(frames)}",
        urdf_sha256=hashlib.sha256(raw).hexdigest(), missing_meshes=missing,
    )


def _within(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, continuous: np.ndarray) -> np.ndarray:
    """Arm.within_limits on (N, nq): continuous coordinates turned by whole turns into
    [lower, lower + 2 pi) (those already there kept bit for bit), then all clipped."""
    lo = lower[continuous]
    x = q[:, continuous]
    q = q.copy()
    q[:, continuous] = np.where((x >= lo) & (x < lo + 2 * np.pi), x, lo + np.mod(x - lo, 2 * np.pi))
    return np.clip(q, lower, upper)


def _effector_names(ee_frame, name: str) -> tuple[str, ...]:
    """from_urdf's ee_frame as a tuple of names: one name, or a non-empty sequence of names."""
    frames = (ee_frame,) if isinstance(ee_frame, str) else ee_frame
    try:
        frames = tuple(frames)
    except TypeError:
        frames = ()
    if not frames or not all(isinstance(f, str) for f in frames):
        raise ValueError(f"{name}: the end effector must be a frame name or a non-empty sequence of frame names, "
                         f"got {ee_frame!r}")
    return frames


def _effector_frames(full: pin.Model, frames: tuple[str, ...], name: str, urdf_path: str) -> tuple[int, ...]:
    """The frame index of each effector in the full model; refused by name: a frame given twice, two
    frames on one link (moved by the same joint: their positions are tied), a frame no joint moves."""
    ids, by_joint = [], {}
    for f in frames:
        fid = _find_frame(full, f, name, urdf_path)
        if fid in ids:
            raise ValueError(f"{name}: end-effector frame {f!r} is given twice")
        joint = full.frames[fid].parentJoint
        if joint == 0:
            root = next((fr.name for fr in full.frames if fr.type == pin.FrameType.BODY and fr.parentJoint == 0),
                        "the root")
            raise ValueError(f"{name}: frame {f!r} in {urdf_path} is not moved by any joint (it is on the root "
                             f"link {root!r}): an end effector needs a joint between it and the root")
        if joint in by_joint:
            link = next((fr.name for fr in full.frames if fr.type == pin.FrameType.BODY and fr.parentJoint == joint),
                        full.names[joint])
            raise ValueError(f"{name}: end-effector frames {by_joint[joint]!r} and {f!r} are on one link ({link!r}, "
                             f"moved by joint {full.names[joint]!r}): their positions are tied; give one effector "
                             "per link")
        ids.append(fid)
        by_joint[joint] = f
    return tuple(ids)


def _find_frame(model: pin.Model, ee_frame: str, name: str, urdf_path: str) -> int:
    matches = [i for i, f in enumerate(model.frames) if f.name == ee_frame]
    if not matches:
        raise ValueError(
            f"{name}: end-effector frame {ee_frame!r} not found in {urdf_path}; "
            f"frames: {', '.join(sorted({f.name for f in model.frames}))}"
        )
    # a link and a joint may share a name: prefer the link (BODY) frame
    bodies = [i for i in matches if model.frames[i].type == pin.FrameType.BODY]
    return (bodies or matches)[0]


MAX_REVOLUTE_LIMIT = 1e3  # rad: |limit| of a revolute joint beyond this is a broken file (~160 turns)
MAX_PRISMATIC_LIMIT = 1e3  # m (or the paper's units): |limit| of a prismatic joint beyond this is refused
# (limits of +-1e308 passed as finite, and drew NaN joint values: upper - lower overflows)


def _limits(model, chain, overrides, name) -> tuple[np.ndarray, np.ndarray]:
    names = [model.names[int(j)] for j in chain.joint_ids]
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ValueError(f"{name}: limits for {', '.join(map(repr, unknown))}, which is not a joint of the chain "
                         f"({', '.join(names)})")
    lower = np.empty(chain.n)
    upper = np.empty(chain.n)
    for k, jname in enumerate(names):
        if jname in overrides:
            lo, hi = (float(v) for v in overrides[jname])
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"{name}: limits of {jname!r} must be finite with lower < upper, got ({lo}, {hi})")
            lower[k], upper[k] = lo, hi
        elif chain.continuous[k]:
            lower[k], upper[k] = -np.pi, np.pi
        else:
            i = chain.idx_q[k]
            lower[k], upper[k] = model.lowerPositionLimit[i], model.upperPositionLimit[i]
            if np.isfinite(lower[k]) and np.isfinite(upper[k]) and lower[k] > upper[k]:
                raise ValueError(f"{name}: joint {jname!r} has inverted limits in the URDF (lower {lower[k]:g} > "
                                 f"upper {upper[k]:g}); fix the file or override them with limits=")
        if not (np.isfinite(lower[k]) and np.isfinite(upper[k]) and lower[k] < upper[k]):
            if chain.kind[k] == PRISMATIC:
                raise ValueError(f"{name}: prismatic joint {jname!r} has no finite limits")
            lower[k], upper[k] = -np.pi, np.pi
        bound, unit = ((MAX_PRISMATIC_LIMIT, "m") if chain.kind[k] == PRISMATIC else (MAX_REVOLUTE_LIMIT, "rad"))
        if max(abs(lower[k]), abs(upper[k])) > bound:
            kind = "prismatic" if chain.kind[k] == PRISMATIC else "revolute"
            where = "given in limits=" if jname in overrides else "in the URDF"
            fix = "" if jname in overrides else "; fix the file or override them with limits="
            raise ValueError(f"{name}: {kind} joint {jname!r} has absurd limits {where} ({lower[k]:g}, {upper[k]:g}): "
                             f"a {kind} joint's limits must be within +-{bound:g} {unit}{fix}")
    return lower, upper


def _reference(full: pin.Model, reference, srdf, name: str) -> np.ndarray:
    """The full model's configuration at which off-chain joints are locked: `reference`, else the
    SRDF's named posture, else neutral."""
    if reference is not None:
        q = np.asarray(reference, dtype=np.float64)
        if q.shape != (full.nq,):
            raise ValueError(f"{name}: reference must be a Pinocchio configuration of shape ({full.nq},), "
                             f"got shape {q.shape}")
        return q
    if srdf is None or srdf[1] is None:  # no SRDF, or one that names no posture (ur5's)
        return pin.neutral(full)
    pin.loadReferenceConfigurations(full, srdf[0], False)
    if srdf[1] not in full.referenceConfigurations:
        known = ", ".join(sorted(entry.key() for entry in full.referenceConfigurations)) or "none"
        raise ValueError(f"{name}: posture {srdf[1]!r} is not in {srdf[0]} (postures: {known})")
    return np.array(full.referenceConfigurations[srdf[1]])


def _with_posture(full: pin.Model, q: np.ndarray, posture: dict, name: str) -> np.ndarray:
    """q with the joints named in `posture` set to their values (a continuous joint as cos, sin)."""
    q = np.array(q, dtype=np.float64)
    for jname, value in posture.items():
        if not isinstance(jname, str) or not full.existJointName(jname):
            raise ValueError(f"{name}: posture for {jname!r}, which is not a joint of the URDF")
        jm = full.joints[full.getJointId(jname)]
        value = float(value)
        if jm.nv != 1 or not np.isfinite(value):
            raise ValueError(f"{name}: posture of {jname!r} must be one finite value of a one-axis joint, got {value}")
        if jm.nq == 2:
            q[jm.idx_q], q[jm.idx_q + 1] = np.cos(value), np.sin(value)
        else:
            q[jm.idx_q] = value
    return q


MAX_JOINTS = 40  # joints on the chains to the effectors: the lab's encodings and kernels stop here


def _check_chain_joints(full: pin.Model, joints: list[int], xml: str, frames: tuple[str, ...], name: str) -> None:
    """Refuse, naming the joint and what to do, what the lab cannot model on the chains to the
    effectors: a joint of several axes (floating, planar, spherical), a mimic joint, more than MAX_JOINTS joints."""
    to = ("chain to " if len(frames) == 1 else "chains to ") + ", ".join(map(repr, frames))
    for j in joints:
        jm = full.joints[j]
        if jm.nv != 1:
            before = full.names[full.parents[j]] if full.parents[j] else "none (it is the first joint)"
            raise ValueError(
                f"{name}: joint {full.names[j]!r} on the {to} is a joint of {jm.nv} axes: {jm.shortname()} is not "
                "supported (one-axis revolute, continuous and prismatic joints only); make it fixed in the URDF "
                f"(the lab fixes the root link in space), or pick an end effector before it (the joint before it: {before})")
    mimics = _mimic_joints(xml) & {full.names[j] for j in joints}
    if mimics:
        first = min(full.getJointId(m) for m in mimics)
        parent = full.frames[full.frames[full.getFrameId(full.names[first], pin.FrameType.JOINT)].parentFrame].name
        fix = (f"pass ee={parent!r} (the link before {full.names[first]!r}) to stop the chain before it"
               if parent and full.parents[first] else "drop the <mimic> tag to make it a joint of its own")
        raise ValueError(f"{name}: joint(s) {', '.join(sorted(mimics))} on the {to} mimic "
                         f"another joint; mimic joints are supported only off the chain (locked): {fix}")
    if len(joints) > MAX_JOINTS:
        raise ValueError(f"{name}: the {to} hold {len(joints)} joints, more than the lab's {MAX_JOINTS}; pick an "
                         f"end effector nearer the root (joint {MAX_JOINTS + 1} is {full.names[joints[MAX_JOINTS]]!r})")


def _mimic_joints(xml: str) -> set[str]:
    """Names of the URDF's joints that mimic another (Pinocchio reads them as free joints here)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return set()
    return {j.get("name") for j in root.iter("joint") if j.find("mimic") is not None}


def _reduce_reference(full: pin.Model, model: pin.Model, q_full: np.ndarray) -> np.ndarray:
    """The reduced model's configuration that matches q_full joint by joint (by name)."""
    q = pin.neutral(model)
    for j in range(1, model.njoints):
        jf = full.getJointId(model.names[j])
        jm, jfm = model.joints[j], full.joints[jf]
        q[jm.idx_q : jm.idx_q + jm.nq] = q_full[jfm.idx_q : jfm.idx_q + jfm.nq]
    return q
