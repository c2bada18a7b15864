"""Which encoding an arm takes, built or read back in one place above both kinds.

A serial arm (one end effector) takes `Encoding` (encoding.py); a tree of several end effectors takes
`TreeEncoding` (tree_encoding.py), which builds on `Encoding`. This module stands above both, so that
`encoding.py` never imports `tree_encoding.py` and the stack stays strict.
"""

from __future__ import annotations

import robots
from lab.problem.encoding import Encoding
from lab.problem.tree_encoding import TreeEncoding


def encoding_for(arm: robots.Arm, features: str = "cartesian", margin: float = 0.0,
                 turn: bool = False) -> Encoding:
    """The encoding of arm's goals and joints: a `TreeEncoding` (one block of inputs per effector)
    for a tree, an `Encoding` for a serial arm."""
    kind = TreeEncoding if arm.is_tree else Encoding
    return kind.for_arm(arm, features, margin, turn)


def encoding_from_dict(d: dict) -> Encoding:
    """An encoding read back from its `to_dict()`: a tree's carries its "effectors", a pose
    network's its "goal" (lab/problem/pose_encoding.py)."""
    if d.get("goal") == "pose":
        from lab.problem.pose_encoding import PoseEncoding

        return PoseEncoding.from_dict(d)
    return (TreeEncoding if "effectors" in d else Encoding).from_dict(d)
