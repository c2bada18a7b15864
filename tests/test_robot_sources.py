"""robots.load on any robot: a registered name, "erd:NAME", a URDF path; one string rebuilds the same arm;
the frame picked without ee=; joints the lab cannot model refused by name; the URDF's identity."""

import logging
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

import robots
from robots import sources
from robots.describe import describe

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
OWN = os.path.join(DATA, "own_arm.urdf")  # revolute, continuous, prismatic, revolute, revolute; a mimic finger


@pytest.fixture
def own(tmp_path):
    """A copy of the tests' own arm that a test may change."""
    path = tmp_path / "own_arm.urdf"
    shutil.copy(OWN, path)
    return str(path)


# ---------------------------------------------------------------- one string per robot
def test_the_name_of_a_loaded_arm_loads_the_same_arm():
    for robot in ("ur5", "g1", "erd:ur10", "erd:panda#panda_link8", OWN + "#tool0"):
        arm = robots.load(robot)
        assert robots.load(arm.name) is arm and robots.load(arm.source) is arm and robots.load(arm) is arm
    assert robots.load("ur5").name == "ur5"  # a registered arm keeps its name
    assert robots.load("ur5", ee="tool0") is robots.load("ur5")
    assert robots.load("erd:ur10", ee="tool0").name == "erd:ur10#tool0"


def test_a_relative_path_and_ee_give_the_canonical_absolute_string(monkeypatch):
    monkeypatch.chdir(DATA)
    arm = robots.load("own_arm.urdf", ee="tool0")
    assert arm.name == arm.source == f"{OWN}#tool0"
    assert robots.kind(arm.name) == "custom" and robots.in_metres(arm.name)
    tree = robots.load(OWN, ee=("tool0", "link3"))
    assert tree.is_tree and tree.name == f"{OWN}#tool0,link3" and robots.load(tree.name) is tree


def test_frames_given_twice_must_agree_and_bad_ee_is_named():
    with pytest.raises(ValueError, match="give them once"):
        robots.load(OWN + "#tool0", ee="link5")
    with pytest.raises(ValueError, match="end-effector frame 'tool9' not found"):
        robots.load(OWN, ee="tool9")
    with pytest.raises(ValueError, match="end-effector frame 'nope' not found"):
        robots.load("erd:ur10#nope")
    with pytest.raises(ValueError, match="ee must be a frame name"):
        robots.load(OWN, ee=3)
    with pytest.raises(ValueError, match="differs from the arm's own effectors"):
        robots.load(robots.load("ur5"), ee="wrist_3_link")


def test_unknown_robots_are_refused_listing_close_names():
    with pytest.raises(ValueError, match="unknown robot 'erd:NO_SUCH'; known robots: planar, scara") as e:
        robots.load("erd:NO_SUCH")
    assert "erd:NAME" in str(e.value)
    with pytest.raises(ValueError, match="did you mean .*erd:ur10"):
        robots.load("erd:ur100")
    with pytest.raises(ValueError, match="did you mean ur5"):
        robots.load("ur55")
    with pytest.raises(FileNotFoundError, match="no URDF file at"):
        robots.load("/no/such/arm.urdf")


def test_an_sdf_only_robot_is_refused_saying_so():
    with pytest.raises(ValueError, match="ships it as an SDF model"):
        robots.load("erd:cassie")


# ---------------------------------------------------------------- the frame picked
@pytest.mark.parametrize("name", ["ur5", "ur10", "panda", "so100", "so101", "z1", "xarm7", "kinova"])
def test_the_frame_picked_on_an_erd_arm_is_the_one_the_registry_chose(name, caplog):
    """Without ee=, the end of the longest chain, stopped before the gripper: the registered arms' frames."""
    spec = robots.registry.SPECS[name]
    origin = sources.origin_of("erd:" + spec.erd)
    frame, message = sources.pick("erd:" + spec.erd, origin)
    assert frame == spec.ee_frame
    assert f"picked tool frame {frame!r}" in message and "pass ee= to choose" in message


def test_the_pick_is_said_once_and_names_the_frame_and_its_joints(caplog):
    sources._picked.clear()
    with caplog.at_level(logging.WARNING, logger="robots"):
        arm = robots.load("erd:ur3")
        robots.load("erd:ur3")
    said = [r.getMessage() for r in caplog.records if "picked tool frame" in r.getMessage()]
    assert said == ["robots.load('erd:ur3'): picked tool frame 'tool0' (end of the longest chain, 6 joints); "
                    "pass ee= to choose; other frames at its end: ee_link, wrist_3_link"]
    assert arm.name == "erd:ur3#tool0" and arm.nq == 6


def test_several_chains_are_listed_by_chain():
    """A two-armed robot: both arms' frames, the longest first (left before right on a tie); a mobile
    manipulator: the arm, not a wheel or the head."""
    frame, message = sources.pick("erd:baxter", sources.origin_of("erd:baxter"))
    assert frame == "left_gripper"
    assert "candidates by chain: 7 joints (left_s0 .. left_w2): left_gripper" in message
    assert "7 joints (right_s0 .. right_w2): right_gripper" in message
    found = sources.chains(sources.origin_of("erd:tiago"))
    assert [j.name for j in found[0].joints] == ["torso_lift_joint"] + [f"arm_{k}_joint" for k in range(1, 8)]
    assert found[0].stops_before.name == "hand_thumb_joint"  # the hand's fingers are not the chain
    assert {"head_2_link", "wheel_left_link"} <= {f for c in found[1:] for f in c.frames}
    arm = robots.load("erd:tiago")
    assert arm.nq == 8 and arm.is_prismatic[0]  # the torso's lift is a prismatic joint, handled


def test_a_tree_of_two_hands_loads_by_frames():
    arm = robots.load("erd:baxter", ee=("left_gripper", "right_gripper"))
    assert arm.is_tree and arm.nq == 14 and arm.fk(arm.rest).shape == (2, 3)


# ---------------------------------------------------------------- joints the lab cannot model
def test_prismatic_and_continuous_joints_on_the_chain_are_handled():
    arm = robots.load(OWN)
    assert arm.ee_frame == "tool0"  # the prismatic fingers (a gripper, one a mimic) are not the chain
    assert arm.joint_names == ("base_yaw", "shoulder", "slide", "elbow", "wrist")
    assert list(arm.is_prismatic) == [False, False, True, False, False]
    assert list(arm.chain.continuous) == [False, True, False, False, False]
    np.testing.assert_allclose(arm.lower, [-2.5, -np.pi, 0, -2, -3])
    np.testing.assert_allclose(arm.upper, [2.5, np.pi, 0.2, 2, 3])
    q = arm.sample_q(50, seed=0)  # fk equals Pinocchio's, the slide and the whole turn included
    data = arm.model.createData()
    for x, p in zip(arm.to_pinocchio(q), arm.fk(q)):
        pin.framesForwardKinematics(arm.model, data, x)
        np.testing.assert_allclose(p, data.oMf[arm.ee_frame_id].translation, atol=1e-12)
    np.testing.assert_allclose(arm.fk(q + 2 * np.pi * arm.chain.continuous), arm.fk(q), atol=1e-12)


def test_a_mimic_joint_on_the_chain_is_refused_naming_it_and_the_frame_before_it():
    with pytest.raises(ValueError, match="joint\\(s\\) finger_right_joint on the chain to 'finger_right' mimic "
                                         "another joint.*pass ee='link5'"):
        robots.load(OWN, ee="finger_right")
    assert robots.load(OWN, ee="finger_left").nq == 6  # a prismatic finger that mimics nobody is a joint


def test_a_floating_or_planar_joint_on_the_chain_is_refused_by_name(own):
    text = open(own).read().replace('name="slide" type="prismatic"', 'name="slide" type="planar"')
    with open(own, "w") as f:
        f.write(text)
    with pytest.raises(ValueError, match="joint 'slide' on the chain to 'tool0' is a joint of 3 axes.*make it fixed"):
        robots.load(own, ee="tool0")
    assert robots.load(own, ee="link2").nq == 2  # a frame before it loads


def test_a_chain_of_more_than_forty_joints_is_refused(tmp_path):
    links = "".join(f'<link name="l{k}"/>' for k in range(42))
    joints = "".join(f'<joint name="j{k}" type="revolute"><parent link="l{k - 1}"/><child link="l{k}"/>'
                     f'<origin xyz="0.1 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>'
                     f'</joint>' for k in range(1, 42))
    path = tmp_path / "long.urdf"
    path.write_text(f'<robot name="long">{links}{joints}</robot>')
    with pytest.raises(ValueError, match="hold 41 joints, more than the lab's 40.*joint 41 is 'j41'"):
        robots.load(str(path))
    assert robots.load(str(path), ee="l40").nq == 40


# ---------------------------------------------------------------- identity, meshes
def test_the_sha256_follows_the_file_and_a_changed_file_is_rebuilt(own):
    arm = robots.load(own)
    assert robots.source_status(arm.source, arm.urdf_sha256) == "unchanged"
    text = open(own).read().replace('upper="2.5"', 'upper="2.4"')
    with open(own, "w") as f:
        f.write(text)
    assert robots.source_status(arm.source, arm.urdf_sha256) == "changed"
    again = robots.load(arm.name)
    assert again is not arm and again.urdf_sha256 != arm.urdf_sha256 and again.upper[0] == 2.4
    os.remove(own)
    assert robots.source_status(arm.source, arm.urdf_sha256) == "gone"
    assert robots.source_status("erd:no_such_robot#tool0", arm.urdf_sha256) == "gone"
    ur5 = robots.load("ur5")
    assert ur5.source == "ur5" and robots.source_status("ur5", ur5.urdf_sha256) == "unchanged"


def test_missing_meshes_are_named_and_left_out_of_the_visual_model():
    arm = robots.load(OWN)
    assert arm.missing_meshes == ("base_link",)
    kinds = [type(g.geometry).__name__ for g in arm.visual_model(keep=False).geometryObjects]
    assert kinds == ["Cylinder"]  # link1's; base_link's mesh does not resolve
    erd = robots.load("erd:ur10")  # package:// meshes of example-robot-data resolve
    assert erd.missing_meshes == () and len(erd.visual_model(keep=False).geometryObjects) == 7


# ---------------------------------------------------------------- describe
def test_describe_names_the_chains_joints_limits_and_frames():
    out = subprocess.run([sys.executable, "-m", "robots", "describe", OWN], capture_output=True, text=True,
                         timeout=300, cwd=os.path.dirname(DATA))
    assert out.returncode == 0, out.stderr
    text = out.stdout
    for pattern in (r"chain 1: 5 joints, stops before 'finger_left_joint'", r"base_yaw +revolute +\[-2.5, 2.5\] rad",
                    r"shoulder +continuous", r"slide +prismatic +\[0, 0.2\] m", r"frames: tool0, link5",
                    r"finger_right_joint \(prismatic, mimics finger_left_joint\)", r"tool frame picked .*: tool0",
                    r"meshes not found .*: base_link"):
        assert re.search(pattern, text), (pattern, text)
    bad = subprocess.run([sys.executable, "-m", "robots", "describe", OWN, "--ee", "finger_right"],
                         capture_output=True, text=True, timeout=300, cwd=os.path.dirname(DATA))
    assert bad.returncode == 2 and "the lab refuses finger_right" in bad.stdout and "pass ee='link5'" in bad.stdout
    none = subprocess.run([sys.executable, "-m", "robots", "describe", "erd:NO_SUCH"], capture_output=True,
                          text=True, timeout=300)
    assert none.returncode == 2 and "unknown robot 'erd:NO_SUCH'" in none.stderr


def test_describe_lists_a_humanoids_chains():
    text, loads = describe("erd:talos")
    assert loads and text.count("chain ") >= 5
    assert re.search(r"chain 1: 9 joints, stops before 'gripper_left_joint'", text)
    assert re.search(r"leg_left_4_joint +revolute +\[", text)


def test_the_joints_with_nothing_to_draw_are_named():
    from robots.visual import undrawn_joints

    arm = robots.load(OWN)  # only link1 (moved by base_yaw) has a visual that resolves
    assert undrawn_joints(arm) == ("shoulder", "slide", "elbow", "wrist")
    assert undrawn_joints(robots.load("ur5")) == ()


def test_package_meshes_resolve_under_the_package_dirs_with_any_number_of_slashes(tmp_path):
    from robots.urdf_tree import resolve_meshes

    mesh = tmp_path / "share" / "pkg" / "meshes" / "a.stl"
    mesh.parent.mkdir(parents=True)
    mesh.write_text("solid a\nendsolid a\n")
    (tmp_path / "rel.stl").write_text("solid b\nendsolid b\n")
    xml = ('<robot name="m"><link name="a"><visual><geometry><mesh filename="package:///pkg/meshes/a.stl"/>'
           '</geometry></visual></link><link name="b"><visual><geometry><mesh filename="rel.stl"/></geometry>'
           '</visual></link><link name="c"><visual><geometry><mesh filename="package://pkg/none.stl"/></geometry>'
           '</visual></link></robot>')
    out, missing = resolve_meshes(xml, str(tmp_path), (str(tmp_path / "share"),))
    assert missing == ("c",)
    assert str(tmp_path / "rel.stl") in out and "package:///pkg/meshes/a.stl" in out and "none.stl" not in out


def test_a_link_named_as_a_joint_is_read_again_renamed():
    """anymal_c names a link and a joint LF_HAA (Pinocchio cannot reduce such a model): it loads, its joints keep
    their names."""
    arm = robots.load("erd:anymal_c")
    assert arm.ee_frame == "LF_FOOT" and arm.joint_names == ("LF_HAA", "LF_HFE", "LF_KFE")
    assert np.isfinite(arm.fk(arm.sample_q(10, seed=0))).all()


def test_a_robot_finger_is_one_chain_not_a_gripper():
    arm = robots.load("erd:finger_edu")
    assert arm.nq == 3 and arm.ee_frame == "finger_tip_link"


def test_a_frame_not_in_the_urdf_is_named_with_close_names_and_the_candidates():
    with pytest.raises(ValueError, match=r"end-effector frame 'tool_0' not found .*did you mean tool0.*candidate tool "
                                         r"frames by chain: 6 joints \(shoulder_pan_joint .. wrist_3_joint\): tool0"):
        robots.load("erd:ur10", ee="tool_0")


def test_a_registered_arm_takes_another_frame_under_a_name_of_its_own():
    arm = robots.load("ur5", ee="wrist_3_link")
    assert arm.name == "ur5#wrist_3_link" and arm.nq == 6 and robots.kind(arm.name) == "custom"
    assert robots.load("ur5#wrist_3_link") is arm and arm is not robots.load("ur5")
    with pytest.raises(ValueError, match="the paper's arms and the snakes have one tool frame, 'ee'"):
        robots.load("planar", ee="link2")
