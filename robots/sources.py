"""One string per robot, that `robots.load` rebuilds in any process: a registered name, any
example-robot-data robot ("erd:NAME"), or a URDF file path, each with its tool frame(s) after "#".

    load("ur5")                      # a registered arm (robots/registry.py)
    load("erd:ur3")                  # picks the end of the longest chain and says so: arm.name "erd:ur3#tool0"
    load("erd:tiago", ee="arm_tool_link")
    load("/path/my_arm.urdf#tool0")  # or load("my_arm.urdf", ee="tool0"); ee=("a", "b"): a tree
    load(arm.name) is arm            # the canonical string comes back to the same (cached) arm
    source_status(arm.source, arm.urdf_sha256)   # "unchanged", "changed" or "gone"
    chains(origin_of("erd:tiago"))   # the chains from the root and the frames that end them

The tool frame, when none is given: the chains are the paths from the root link to each leaf link,
counted in actuated joints; a chain stops before a gripper or hand (a mimic joint; the first joint named
finger, gripper, jaw, thumb, knuckle or claw after joints named otherwise; a link where two or more
chains start after 4 or more joints, each shorter than those), whose joints are then locked. The
chain with most joints wins (ties: the first frame's name); its frame is a leaf link, a tool-like name
first (tcp, tool, end effector, tip), the link before the gripper last.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import logging
import os
import re
import threading
import time
from dataclasses import dataclass
from typing import NamedTuple, Sequence

from robots import registry
from robots.arm import Arm, from_urdf
from robots.urdf_tree import Joint, UrdfTree

ERD = "erd:"
log = logging.getLogger("robots")
GRIPPER = re.compile(r"finger|gripper|jaw|thumb|knuckle|claw", re.I)
TOOL_NAMES = (re.compile(r"tcp", re.I), re.compile(r"tool", re.I),
              re.compile(r"eef|end_?effector|(^|_)ee(_|$)", re.I), re.compile(r"tip", re.I))


@dataclass(frozen=True)
class Origin:
    """Where a robot's URDF comes from and how it is read (what the source part of the string names)."""

    source: str  # "ur5", "erd:ur3", "/abs/path/arm.urdf"
    urdf: str
    package_dirs: tuple[str, ...] = ()
    srdf: tuple[str, str] | None = None
    xml_replace: tuple[tuple[str, str], ...] = ()
    posture: tuple[tuple[str, float], ...] = ()
    registered: str | None = None  # the registered name, for a registered robot
    task_axes: tuple[int, ...] = (0, 1, 2)

    def xml(self) -> str:
        with open(self.urdf, encoding="utf-8", errors="replace") as f:
            xml = f.read()
        for old, new in self.xml_replace:
            xml = xml.replace(old, new)
        return xml


class Chain(NamedTuple):
    """A path from the root link to a chain's end: its actuated joints (root first), the frames that end
    it (the preferred first), and the gripper joint it stops before (None if it ends at a leaf)."""

    joints: tuple[Joint, ...]
    frames: tuple[str, ...]
    stops_before: Joint | None


# ---------------------------------------------------------------- the string
def split(robot: str) -> tuple[str, tuple[str, ...] | None]:
    """("source", (frames...) or None) of a robot string; an existing file's path is all source."""
    if os.path.isfile(robot) or "#" not in robot:
        return robot, None
    source, _, frames = robot.rpartition("#")
    names = tuple(f.strip() for f in frames.split(","))
    if not all(names):
        raise ValueError(f"robot {robot!r}: the frames after '#' must be names separated by commas")
    return source, names


def canonical(origin: Origin, frames: tuple[str, ...]) -> str:
    """The string that names this robot with these frames (a registered robot's own frames: its name)."""
    if origin.registered is not None and frames == _registered_frames(origin.registered):
        return origin.registered
    return f"{origin.source}#{','.join(frames)}"


def _registered_frames(name: str) -> tuple[str, ...]:
    ee = registry.SPECS[name].ee_frame
    return (ee,) if isinstance(ee, str) else tuple(ee)


def _erd_names() -> tuple[str, ...]:
    try:
        import example_robot_data as erd
    except ImportError:
        return ()
    return tuple(sorted(erd.ROBOTS))


def _unknown(robot) -> ValueError:
    known = registry.names()
    text = f"unknown robot {robot!r}; known robots: {', '.join(known)}"
    if isinstance(robot, str):
        key = robot[len(ERD):] if robot.startswith(ERD) else robot
        erd_names = _erd_names()
        close = [n for n in difflib.get_close_matches(key, list(known), n=3, cutoff=0.6)]
        close += [ERD + n for n in difflib.get_close_matches(key, list(erd_names), n=4, cutoff=0.6)]
        if close:
            text += f"; did you mean {', '.join(close)}?"
        text += ("; or 'erd:NAME', any robot of example-robot-data (python -c 'import example_robot_data as e; "
                 "print(sorted(e.ROBOTS))'), or a URDF file's path")
    return ValueError(text)


def origin_of(source: str) -> Origin:
    """The Origin a string's source part names; ValueError naming close names when it names none."""
    if source in registry.SPECS:
        spec = registry.SPECS[source]
        if spec.urdf is not None:
            return Origin(source, os.path.join(registry.URDF_DIR, spec.urdf), registered=source,
                          task_axes=spec.task_axes)
        path, share, srdf = registry._erd_paths(spec.erd)
        return Origin(source, path, (share,), srdf, spec.xml_replace, spec.posture, source, spec.task_axes)
    if source.startswith(ERD):
        return _erd_origin(source[len(ERD):])
    if source.lower().endswith(".urdf") or os.path.isfile(source):
        path = os.path.abspath(os.path.expanduser(source))
        if not os.path.isfile(path):
            raise FileNotFoundError(f"robot {source!r}: no URDF file at {path}")
        # package://pkg/... meshes: pkg is looked for beside the URDF's folder and two levels above it
        here = os.path.dirname(path)
        dirs = tuple(dict.fromkeys(os.path.abspath(os.path.join(here, *[os.pardir] * k)) for k in range(4)))
        return Origin(path, path, dirs)
    raise _unknown(source)


@functools.cache
def _erd_origin(name: str) -> Origin:
    import example_robot_data as erd

    loader = erd.ROBOTS.get(name)
    if loader is None:
        raise _unknown(ERD + name)
    if not loader.urdf_filename:
        raise ValueError(f"robot 'erd:{name}': example-robot-data ships it as an SDF model "
                         f"({loader.sdf_filename}), not a URDF; the lab reads URDF files only")
    path, share, srdf = registry._erd_paths(name)
    # the fixes the registry applies to the same file (a joint named as a link, a humanoid's knees)
    spec = next((s for s in registry.SPECS.values() if s.erd == name), None)
    fixes = (spec.xml_replace, spec.posture) if spec else ((), ())
    return Origin(ERD + name, path, (share,), srdf, *fixes)


# ---------------------------------------------------------------- chains and the frame picked
def chains(origin: Origin, tree: UrdfTree | None = None) -> list[Chain]:
    """The URDF's chains, most joints first (ties: the first frame's name): the distinct paths of
    actuated joints from the root to a leaf link, cut before a gripper or hand; a path that is the start
    of a longer one is not a chain of its own. A chain's frames are the links after its last joint (up
    to the gripper), a tool-like name first, then the farthest out."""
    tree = tree or UrdfTree.parse(origin.xml())
    hands = _hand_links(tree)
    ends: dict[tuple[str, ...], dict] = {}
    for leaf in tree.leaves():
        joints, cut, after = [], None, []  # after: the links past the last joint kept
        for j in tree.path(leaf):
            if j.type in MOVING:
                gripper = joints and GRIPPER.search(j.name) and not any(GRIPPER.search(k.name) for k in joints)
                if j.mimic is not None or gripper or j.parent in hands:
                    cut = j
                    break
                joints.append(j)
                after = [j.child]
            else:
                after.append(j.child)
        if not joints:
            continue
        end = ends.setdefault(tuple(j.name for j in joints), dict(joints=tuple(joints), frames={}, cut=None))
        for depth, link in enumerate(after):
            key = (_tool_rank(link), -depth, link)
            end["frames"][link] = min(end["frames"].get(link, key), key)
        end["cut"] = end["cut"] or cut
    keys = list(ends)
    out = []
    for key, end in ends.items():
        if any(len(other) > len(key) and other[:len(key)] == key for other in keys):
            continue
        frames = tuple(sorted(end["frames"], key=end["frames"].get))
        out.append(Chain(end["joints"], frames, end["cut"]))
    return sorted(out, key=lambda c: (-len(c.joints), c.frames[0]))


MOVING = ("revolute", "continuous", "prismatic", "floating", "planar")
HAND_AFTER = 4  # a hand or gripper: where chains branch after this many joints or more, each shorter


def _hand_links(tree: UrdfTree) -> set[str]:
    """Links where a hand or gripper starts: two or more chains of joints begin there, after HAND_AFTER
    joints or more from the root, each shorter than the joints before it (not a humanoid's waist)."""
    depth: dict[str, int] = {}

    def below(link: str, seen=()) -> int:  # most joints on a path down from link
        if link not in depth:
            depth[link] = 0 if link in seen else max(
                ((j.type in MOVING) + below(j.child, seen + (link,)) for j in tree.children.get(link, [])), default=0)
        return depth[link]

    hands = set()
    for link in tree.links:
        branches = [(j.type in MOVING) + below(j.child) for j in tree.children.get(link, [])]
        before = sum(j.type in MOVING for j in tree.path(link))
        if before >= HAND_AFTER and sum(b > 0 for b in branches) >= 2 and max(branches) < before:
            hands.add(link)
    return hands


def _tool_rank(name: str) -> int:
    return next((k for k, pattern in enumerate(TOOL_NAMES) if pattern.search(name)), len(TOOL_NAMES))


def candidates_text(found: list[Chain], limit: int = 8) -> str:
    """The candidate frames by chain, one clause each: "7 joints (j1 .. j7): tool, flange"."""
    def frames(c: Chain) -> str:
        more = f" (+{len(c.frames) - 4} more)" if len(c.frames) > 4 else ""
        return ", ".join(c.frames[:4]) + more

    parts = [f"{len(c.joints)} joint{'s' * (len(c.joints) != 1)} ({c.joints[0].name} .. {c.joints[-1].name}): "
             f"{frames(c)}" for c in found[:limit]]
    if len(found) > limit:
        parts.append(f"and {len(found) - limit} more chains (python -m robots describe)")
    return "; ".join(parts)


def pick(robot: str, origin: Origin) -> tuple[str, str]:
    """(frame, message) the lab picks on a robot named without its frame: the end of the longest chain."""
    found = chains(origin)
    if not found:
        raise ValueError(f"robot {robot!r}: no joint moves any link of {origin.urdf} (no chain to pick a tool "
                         "frame from)")
    best = found[0]
    stop = f", stopped before the gripper's joint {best.stops_before.name!r}" if best.stops_before else ""
    message = (f"robots.load({robot!r}): picked tool frame {best.frames[0]!r} (end of the longest chain, "
               f"{len(best.joints)} joints{stop}); pass ee= to choose")
    if len(found) > 1:
        message += f"; candidates by chain: {candidates_text(found)}"
    elif len(best.frames) > 1:
        message += f"; other frames at its end: {', '.join(best.frames[1:])}"
    return best.frames[0], message


# ---------------------------------------------------------------- load
_lock = threading.RLock()
_arms: dict[tuple[str, str], Arm] = {}  # (canonical string, URDF sha256) -> Arm
_picked: dict[tuple[str, str], tuple[str]] = {}  # (string without frames, URDF sha256) -> (the frame picked,)


def file_sha256(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


_hashed: dict[str, tuple[tuple[int, int, int], str]] = {}  # path -> ((inode, mtime_ns, size), sha256)


def _sha_now(path: str) -> str:
    """file_sha256, read again unless the file's inode, modification time and size are those of a
    reading made more than 2 s after that modification (file times tick coarsely: a change within the
    same tick keeps the time)."""
    st = os.stat(path)
    stamp = (st.st_ino, st.st_mtime_ns, st.st_size)
    if path in _hashed and _hashed[path][0] == stamp:
        return _hashed[path][1]
    sha = file_sha256(path)
    if time.time_ns() - st.st_mtime_ns > 2_000_000_000:
        _hashed[path] = (stamp, sha)
    return sha


def _frames_of(ee, robot) -> tuple[str, ...] | None:
    if ee is None:
        return None
    frames = (ee,) if isinstance(ee, str) else ee
    try:
        frames = tuple(frames)
    except TypeError:
        frames = ()
    if not frames or not all(isinstance(f, str) and f and "," not in f and "#" not in f for f in frames):
        raise ValueError(f"robot {robot!r}: ee must be a frame name or a non-empty sequence of frame names, "
                         f"got {ee!r}")
    return frames


def load(robot, ee: str | Sequence[str] | None = None) -> Arm:
    """The Arm a robot string names (see the module's doc), built once per string and file content.
    ee: the tool frame, or several (a tree); given both in the string (after '#') and here, they must agree."""
    if isinstance(robot, Arm):
        frames = _frames_of(ee, robot.name)
        if frames is not None and frames != robot.effectors:
            raise ValueError(f"{robot.name}: ee={ee!r} differs from the arm's own effectors {robot.effectors}; "
                             f"load it with robots.load({robot.source or robot.name!r}, ee=...)")
        return robot
    if not isinstance(robot, str) or not robot:
        raise _unknown(robot)
    if ee is None and robot in registry.SPECS:
        return registry._build(robot)  # the registered arms, as before
    source, frames = split(robot)
    given = _frames_of(ee, robot)
    if frames is not None and given is not None and frames != given:
        raise ValueError(f"robot {robot!r} names frames {', '.join(frames)} and ee= names {', '.join(given)}; "
                         "give them once")
    frames = frames or given
    origin = origin_of(source)
    with _lock:
        sha = _sha_now(origin.urdf)
        if frames is None:
            if origin.registered is not None:
                frames = _registered_frames(origin.registered)
            elif (source, sha) in _picked:
                frames = _picked[(source, sha)]
            else:
                frame, message = pick(robot, origin)
                log.warning(message)
                frames = _picked[(source, sha)] = (frame,)
        name = canonical(origin, frames)
        if name in registry.SPECS:
            return registry._build(name)
        if (name, sha) not in _arms:
            if origin.registered is not None and registry.SPECS[origin.registered].kind in ("paper", "snake"):
                raise ValueError(f"robot {robot!r}: the paper's arms and the snakes have one tool frame, "
                                 f"{_registered_frames(origin.registered)[0]!r}")
            _check_frames(robot, origin, frames)
            _arms[(name, sha)] = from_urdf(
                origin.urdf, frames if len(frames) > 1 else frames[0], name=name, task_axes=origin.task_axes,
                package_dirs=origin.package_dirs, xml_replace=origin.xml_replace, srdf=origin.srdf,
                posture=dict(origin.posture) or None, source=name)
        return _arms[(name, sha)]


def _check_frames(robot: str, origin: Origin, frames: tuple[str, ...]) -> None:
    """ValueError for a frame the URDF lacks, naming the closest names and the candidate frames by chain."""
    try:
        tree = UrdfTree.parse(origin.xml())
    except ValueError:
        return  # from_urdf names what is wrong with the file
    known = set(tree.links) | set(tree.joints)
    for f in frames:
        if f not in known:
            close = difflib.get_close_matches(f, sorted(known), n=4, cutoff=0.6)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise ValueError(f"{robot}: end-effector frame {f!r} not found in {origin.urdf}{hint}; candidate tool "
                             f"frames by chain: {candidates_text(chains(origin, tree))}")


def source_status(source: str, sha256: str) -> str:
    """Whether a robot's URDF, stored as (source string, sha256), is still the file the string names:
    "unchanged", "changed" (the file's bytes differ) or "gone" (no such robot or file any more)."""
    if not isinstance(source, str) or not source:
        return "gone"
    try:
        origin = origin_of(split(source)[0])
        now = file_sha256(origin.urdf)
    except (ValueError, OSError, ImportError):
        return "gone"
    return "unchanged" if now == sha256 else "changed"
