"""A robot as the lab takes it: a name robots.load knows, or the robots.Arm itself.

    robot_name("erd:ur3")                # the canonical string that robots.load rebuilds in any process
    robot_name(arm)                      # an Arm: its name (robots.load(arm.name) rebuilds it)
    load_arm("my_arm.urdf", ee="tool0")  # the Arm
    arm_kind(arm)                        # "paper", "snake", "real" or "tree": what the methods' defaults ask

Three forms name a robot (robots.load): a registered name ("ur5"), an example-robot-data robot by
that package's name ("erd:ur3"), a URDF file's path (with its tool frame, "/path/arm.urdf#tool0").
Configurations, recordings and worker processes carry the string; lab.evolve, lab.solve,
lab.controller_from_dict and TrainConfig take the Arm as well, as its string.
"""

from __future__ import annotations

import os
import re

import robots
from lab.problem.checks import shown


def check_robot(robot) -> None:
    """ValueError, naming the robot and the known ones, unless `robot` is an Arm or a string whose source
    robots.load can read (a registered name, erd:NAME of example-robot-data, a URDF file): checked
    without building the arm, before any work."""
    if isinstance(robot, robots.Arm):
        return
    if not isinstance(robot, str) or not robot:
        load_arm(robot)  # the message of a robot that is no string
    from robots import sources

    try:
        sources.origin_of(sources.split(robot)[0])
    except OSError as e:
        raise ValueError(f"unknown robot {robot!r}: {e}") from None


def load_arm(robot, ee: str | None = None) -> robots.Arm:
    """The Arm of `robot` (an Arm as it is; a string as robots.load builds it, with the tool frame `ee`
    where given). ValueError naming the robot, and what robots.load said, otherwise."""
    if isinstance(robot, robots.Arm):
        if ee is not None and ee not in robot.effectors:
            raise ValueError(f"ee={ee!r} given with an Arm whose end effector is {', '.join(robot.effectors)}: "
                             "load the arm with that frame (robots.load(robot, ee=...))")
        return robot
    if not isinstance(robot, str) or not robot:
        raise ValueError(f"unknown robot {shown(robot)}; known robots: {', '.join(robots.names())}; or erd:NAME (an "
                         "example-robot-data robot), a URDF file's path, or a robots.Arm")
    try:
        return robots.load(robot) if ee is None else robots.load(robot, ee=ee)
    except TypeError as e:  # a robots.load without ee (this lab's robots/ older than its lab/)
        raise ValueError(f"{robot}: this robots.load takes no tool frame (ee={ee!r}): {e}") from None
    except OSError as e:
        raise ValueError(f"unknown robot {robot!r}: {e}") from None


def robot_name(robot, ee: str | None = None) -> str:
    """The canonical string of `robot` (a string or an Arm): what configurations, recordings and
    workers carry; robots.load(robot_name(r)) rebuilds the same arm. ValueError, naming why, for a
    robot that cannot be loaded, and for an Arm whose name robots.load does not rebuild."""
    arm = load_arm(robot, ee)
    if not isinstance(robot, robots.Arm):
        return arm.name
    # an Arm: its name where robots.load rebuilds it from that (robots.load's arms), else its URDF's
    # path and frames where those rebuild the same arm (an arm of robots.from_urdf)
    tried = []
    path = getattr(arm, "urdf_path", None)
    for name in (arm.name, *((f"{os.path.abspath(path)}#{','.join(arm.effectors)}",) if path else ())):
        try:
            again = robots.load(name)
        except (ValueError, OSError, TypeError) as e:
            tried.append(f"{name}: {e}")
            continue
        if _same(again, arm):
            return again.name
        tried.append(f"{name}: robots.load builds another arm ({again.nq} joints, limits or axes differ)")
    raise ValueError(f"the Arm {arm.name!r} cannot be named by a string robots.load rebuilds ({'; '.join(tried)}); "
                     "load it with robots.load(ROBOT, ee=FRAME) (ROBOT: a registered name, erd:NAME or a URDF path)")


def _same(a: robots.Arm, b: robots.Arm) -> bool:
    """Whether two arms have the same joints, limits, effectors, task axes and kinematics."""
    import numpy as np

    return (a.nq == b.nq and tuple(a.joint_names) == tuple(b.joint_names) and tuple(a.effectors) == tuple(b.effectors)
            and tuple(a.task_axes) == tuple(b.task_axes) and np.allclose(a.lower, b.lower)
            and np.allclose(a.upper, b.upper) and (a.is_tree or all(
                np.shape(x) == np.shape(y) and np.allclose(x, y) for x, y in zip(a.chain.arrays, b.chain.arrays))))


def arm_kind(arm: robots.Arm) -> str:
    """What kind of robot an Arm is, for the methods' defaults: the registry's kind for a registered
    name ("paper", "snake", "real", "tree"); otherwise "tree" for several end effectors, else "real"
    (a URDF's arm, in metres: it gets a registered real arm's defaults for its joint count)."""
    kind = robots.kind(arm.name)
    if kind in ("paper", "snake", "real", "tree"):
        return kind
    return "tree" if arm.is_tree else "real"


def robot_slug(name: str) -> str:
    """A robot's string as a file name's part: "erd:ur3" -> "erd-ur3", "/a/b/arm.urdf#tool0" -> "arm-tool0"."""
    base, _, frame = str(name).partition("#")
    if os.sep in base or base.endswith(".urdf"):
        base = os.path.splitext(os.path.basename(base))[0]
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", f"{base}-{frame}" if frame else base).strip("-.")
    return slug[:60] or "robot"
