"""Robots: Pinocchio models of serial arms and trees, with batched forward kinematics.

    import robots
    robots.names()                  # every robot load() accepts; names(trees=False): the serial arms alone
    arm = robots.load("planar")     # also "scara", "ur5", "panda", ...
    arm.fk(q)                       # (..., nq) -> (..., 3) end-effector positions
    arm.jacobian(q)                 # (..., nq) -> (..., 3, nq) positional Jacobian of fk
    arm.sample_goals(70, seed=0)    # (70, len(arm.task_axes)) reachable goals
    robots.kind("ur5")              # "paper" (the paper's arms, its units), "snake" (planar-10/-20,
                                    # the paper's units), "real" (metres) or "tree" (metres)
    robots.pose.sample_poses(arm, 70, seed=0)  # (70, 4, 4) tool-frame poses (robots/pose.py)
    tree = robots.load("g1")        # several end effectors (tree.effectors): fk (..., E, 3),
                                    # jacobian (..., E, 3, nq), goals (n, E, len(task_axes))
    arm = robots.load("erd:ur3")    # any example-robot-data robot, or a URDF path; ee="tool0" or
                                    # "erd:ur3#tool0"; arm.name rebuilds it anywhere (robots/sources.py)
    robots.source_status(arm.source, arm.urdf_sha256)  # "unchanged", "changed" or "gone"

Nothing here knows about networks or evolution.
"""

from robots import pose
from robots.arm import Arm, from_urdf
from robots.registry import in_metres, kind, names
from robots.sources import load
from robots.sources import source_status

__all__ = ["Arm", "from_urdf", "in_metres", "kind", "load", "names", "pose", "source_status"]
