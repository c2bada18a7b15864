"""Robots: Pinocchio models of serial arms with batched forward kinematics.

    import robots
    robots.names()                  # every name load() accepts
    arm = robots.load("planar")     # also "scara", "ur5", "panda", ...
    arm.fk(q)                       # (..., nq) -> (..., 3) end-effector positions
    arm.jacobian(q)                 # (..., nq) -> (..., 3, nq) positional Jacobian of fk
    arm.sample_goals(70, seed=0)    # (70, len(arm.task_axes)) reachable goals
    robots.kind("ur5")              # "paper" (the paper's arms, its units), "snake" (planar-10/-20,
                                    # the paper's units) or "real" (metres)

Nothing here knows about networks or evolution.
"""

from robots.arm import Arm, from_urdf
from robots.registry import in_metres, kind, load, names

__all__ = ["Arm", "from_urdf", "in_metres", "kind", "load", "names"]
