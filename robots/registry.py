"""The robots `robots.load` knows: the paper's two arms, two planar snakes, serial arms of
example-robot-data, and trees of several end effectors of example-robot-data (legged robots and a
humanoid with their root link fixed in space, a hand).

Each entry names where the URDF comes from, the end-effector frame (or frames) and the task axes.
example-robot-data URDFs are located without building their (slow) mesh models:
the loader classes of `example_robot_data` give the file's path.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

from robots.arm import Arm, from_urdf
from robots.snake import SNAKES

URDF_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "urdf")


@dataclass(frozen=True)
class ArmSpec:
    """How to build one named arm (or tree: ee_frame a tuple of frame names)."""

    ee_frame: str | tuple[str, ...]
    urdf: str | None = None  # a file under robots/urdf/
    erd: str | None = None  # an example-robot-data name
    task_axes: tuple[int, ...] = (0, 1, 2)
    kind: str = "real"  # "paper": the paper's arms, in its units; "real": a real arm, in metres;
    # "snake": a hyper-redundant planar arm of equal links (robots/snake.py), in the paper's units;
    # "tree": a real robot with several end effectors, in metres
    xml_replace: tuple[tuple[str, str], ...] = ()
    posture: tuple[tuple[str, float], ...] = ()  # joint values over the reference posture (from_urdf's posture)
    description: str = ""
    extra: dict = field(default_factory=dict)


SPECS: dict[str, ArmSpec] = {
    "planar": ArmSpec("ee", urdf="planar.urdf", task_axes=(0, 1), kind="paper",
                      description="the paper's three-link planar arm (Table 1, eq. 3)"),
    "scara": ArmSpec("ee", urdf="scara.urdf", kind="paper",
                     description="the paper's SCARA arm (Table 2, eq. 4)"),
    **{name: ArmSpec("ee", urdf=f"{name}.urdf", task_axes=(0, 1), kind="snake",
                     description=f"hyper-redundant planar snake, {n} equal links of total reach 23.375 "
                                 "(robots/snake.py)")
       for name, n in SNAKES.items()},
    "ur5": ArmSpec("tool0", erd="ur5", description="Universal Robots UR5, 6 DoF"),
    "ur10": ArmSpec("tool0", erd="ur10", description="Universal Robots UR10, 6 DoF"),
    "panda": ArmSpec("panda_hand_tcp", erd="panda", description="Franka Emika Panda, 7 DoF (fingers locked)"),
    "so100": ArmSpec(
        "gripper", erd="so100", description="SO-100 low-cost arm, 5 DoF (jaw locked)",
        # its URDF names a link and a joint "gripper", which breaks pin.buildReducedModel
        xml_replace=(('<joint name="gripper"', '<joint name="gripper_joint"'),),
    ),
    "so101": ArmSpec("gripper_frame_link", erd="so101", description="SO-101 low-cost arm, 5 DoF (jaw locked)"),
    "z1": ArmSpec("gripperStator", erd="z1", description="Unitree Z1, 6 DoF (gripper locked)"),
    "xarm7": ArmSpec("link_eef", erd="xarm7", description="UFactory xArm7, 7 DoF"),
    "kinova": ArmSpec("j2s6s200_end_effector", erd="kinova",
                      description="Kinova Jaco j2s6s200, 6 DoF (3 continuous joints)"),
    # trees: several end effectors on one kinematic tree, the URDF read without a free-flyer (its root
    # link fixed in space); the joints on no path to an effector (Talos' torso, arms and head) locked
    "talos-legs": ArmSpec(("left_sole_link", "right_sole_link"), erd="talos_legs", kind="tree",
                          description="PAL Talos' legs, 12 DoF, two feet (base_link fixed; the rest of Talos "
                                      "locked at half_sitting)"),
    "solo12": ArmSpec(("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"), erd="solo12", kind="tree",
                      description="ODRI Solo-12 quadruped, 12 DoF, four feet (base_link fixed)"),
    "allegro": ArmSpec(("link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip"), erd="allegro_right_hand",
                       kind="tree", description="Wonik Allegro right hand, 16 DoF, four fingertips (palm fixed)"),
    "g1": ArmSpec(("left_rubber_hand", "right_rubber_hand", "left_ankle_roll_link", "right_ankle_roll_link"),
                  erd="g1", kind="tree",
                  # no SRDF: the rest posture is Unitree's standing one (unitree_rl_gym's G1 default joint
                  # angles), knees bent; straight legs (neutral) are a singular start for dls_ik
                  posture=tuple((f"{side}_{joint}_joint", v) for side in ("left", "right")
                                for joint, v in (("hip_pitch", -0.1), ("knee", 0.3), ("ankle_pitch", -0.2))),
                  description="Unitree G1 humanoid, 29 DoF, two hands and two feet (pelvis fixed)"),
}


def names(trees: bool = True) -> tuple[str, ...]:
    """Every robot `load` knows by name, the trees of several end effectors (kind "tree") last;
    trees=False: the serial arms alone (one end effector)."""
    return tuple(n for n, spec in SPECS.items() if trees or spec.kind != "tree")


def kind(name: str) -> str:
    """What kind of arm a name is: "paper" (the paper's two arms, in its units), "snake" (a
    hyper-redundant planar arm of robots/snake.py, in the paper's units), "real" (a real arm, in
    metres), "tree" (a real robot with several end effectors, in metres), or "custom" (an arm made
    with from_urdf under another name, or loaded as "erd:NAME" or a URDF path: in metres)."""
    spec = SPECS.get(name) if isinstance(name, str) else None
    return spec.kind if spec is not None else "custom"


def in_metres(name: str) -> bool:
    """Whether an arm's lengths are metres (real and custom arms) rather than the paper's units
    (the paper's arms and the snakes): what error reports scale to mm."""
    return kind(name) not in ("paper", "snake")


@functools.cache
def _build(name: str) -> Arm:
    spec = SPECS[name]
    if spec.urdf is not None:
        return from_urdf(os.path.join(URDF_DIR, spec.urdf), spec.ee_frame, name=name,
                         task_axes=spec.task_axes, source=name)
    path, share, srdf = _erd_paths(spec.erd)
    return from_urdf(path, spec.ee_frame, name=name, task_axes=spec.task_axes,
                     package_dirs=(share,), xml_replace=spec.xml_replace, srdf=srdf,
                     posture=dict(spec.posture) or None, source=name)


def _erd_paths(erd_name: str) -> tuple[str, str, tuple[str, str] | None]:
    """(URDF path, share dir for package:// meshes, (SRDF, posture) or None) of an example-robot-data robot."""
    import example_robot_data as erd

    loader = erd.ROBOTS[erd_name]
    sub = os.path.join(loader.path, loader.urdf_subpath, loader.urdf_filename)
    model_path = loader.model_path or erd.getModelPath(sub)
    urdf = os.path.realpath(os.path.join(model_path, sub))
    share = os.path.realpath(os.path.join(model_path, os.pardir, os.pardir))
    srdf = None
    if loader.srdf_filename:
        srdf_path = os.path.join(model_path, loader.path, loader.srdf_subpath, loader.srdf_filename)
        srdf = (os.path.realpath(srdf_path), loader.ref_posture)
    return urdf, share, srdf
