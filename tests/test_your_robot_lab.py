"""A robot the registry does not name, on the lab's side: lab.evolve, lab.solve,
lab.controller_from_dict, TrainConfig and `python -m lab train|solve|export` take its string
(erd:NAME, a URDF path) or the Arm itself; its defaults are a registered real arm's of its size;
lab.solve's default on pose goals is the compiled solver on TRAC-IK's terms; lab.pretrained returns
the shipped controllers; the ONNX file of a controller computes what the lab's network does."""

import json
import os

import numpy as np
import pytest

import lab
import robots
from lab import methods
from lab.problem.robot import arm_kind, robot_name, robot_slug
from robots import pose

def _ur3_urdf() -> str:
    """example-robot-data's UR3 by its URDF path (its table's "ur3" is UR5Loader in version 5.0.0)."""
    from robots.registry import _erd_paths

    return os.path.join(os.path.dirname(_erd_paths("ur5")[0]), "ur3_robot.urdf")


UR3, PANDA = _ur3_urdf(), "erd:panda"  # a 6-joint arm the registry lacks; the Panda under a name its defaults do not know
SMALL = dict(generations=2, population=8, targets=10, test_goals=10)


@pytest.fixture(scope="module")
def ur3():
    return robots.load(UR3, ee="tool0")


def test_an_example_robot_data_arm_trains_with_no_settings_and_the_arm_itself_is_taken(ur3):
    """lab.evolve(arm) was refused "unknown robot Arm('ur3', ...)": now the Arm and its string both
    train, the run's config carries the canonical string, which rebuilds the same arm."""
    run = lab.evolve(ur3, seconds=3, seed=0)
    assert run.state == "finished" and run.config.robot == ur3.name == f"{UR3}#tool0"
    assert robots.load(run.config.robot).nq == 6 and len(run.history) >= 2
    goals = ur3.sample_goals(5, seed=2)
    q = run.controller(goals)
    assert q.shape == (5, 6) and np.all(ur3.within_limits(q) == q)
    same = lab.evolve(UR3, ee="tool0", **SMALL)
    assert same.config.robot == ur3.name
    assert lab.TrainConfig(robot=ur3, **SMALL) == lab.TrainConfig(robot=UR3, ee="tool0", **SMALL)
    assert lab.TrainConfig.from_dict(same.config.to_dict()) == same.config


def test_an_arm_of_from_urdf_is_named_by_its_path_and_one_no_string_rebuilds_is_refused(ur3, tmp_path):
    """lab.evolve(robots.from_urdf(path, "tool0")) was refused: such an arm is named by its URDF's path and
    frame where robots.load rebuilds the same arm from them; one with other limits is refused by name."""
    plain = robots.from_urdf(UR3, "tool0")
    assert plain.name == "ur3_robot" and robot_name(plain) == ur3.name
    narrow = robots.from_urdf(UR3, "tool0", limits={"shoulder_pan_joint": (-1.0, 1.0)})
    with pytest.raises(ValueError, match="cannot be named by a string robots.load rebuilds.*another arm"):
        robot_name(narrow)
    with pytest.raises(ValueError, match="unknown robot"):
        lab.TrainConfig(robot=str(tmp_path / "no-such.urdf"))


@pytest.mark.parametrize("method", ["cmaes", "neat", "gradient", "neat_cma"])
@pytest.mark.parametrize("seconds", [None, 60.0])
def test_an_unknown_arm_gets_the_defaults_of_a_registered_arm_of_its_size(method, seconds):
    """The Panda's URDF under erd:panda is an arm the methods know nothing of by name: every default is
    the registered Panda's (they were keyed by robots.kind(name), "custom" for it, which gave it the
    paper's settings without the turn); a 6-joint arm gets a registered 6-joint arm's pose heads."""
    known, unknown = robots.load("panda"), robots.load(PANDA)
    assert arm_kind(unknown) == "real" and robots.kind(unknown.name) != "real"
    m = methods.get(method)
    assert m.defaults_for(unknown, seconds) == m.defaults_for(known, seconds)
    pose_known, pose_unknown = m.defaults_for(known, seconds, "pose"), m.defaults_for(unknown, seconds, "pose")
    assert pose_unknown == pose_known
    a = lab.TrainConfig(robot=PANDA, method=method, seconds=seconds).to_dict()
    b = lab.TrainConfig(robot="panda", method=method, seconds=seconds).to_dict()
    assert {**a, "robot": "panda"} == b


def test_pose_goals_on_an_unknown_six_joint_arm_train_with_a_generic_encoding(ur3):
    """No closed-form wrist or reach (those are measured per arm): the turn and four heads, as the
    registered 6-joint arms; a run trains and its controller answers poses."""
    config = lab.TrainConfig(robot=ur3, goal="pose", seconds=2)
    assert (config.heads, config.turn, config.reach, config.features) == (4, True, 0, "sphere")
    run = lab.evolve(ur3, goal="pose", seconds=2, population=8)
    poses = pose.sample_poses(ur3, 4, seed=3)
    assert run.controller.goal == "pose" and run.controller(poses).shape == (4, 6)
    s = lab.solve(run.controller, ur3, poses)
    assert s.network_error is not None and s.success == 1.0


def test_lab_solve_on_poses_defaults_to_the_compiled_solver_on_trac_iks_terms(ur3):
    """The first call an engineer makes: within 1e-5 m and 1e-5 rad (it was 0.1 mm and 0.1 degree,
    3 steps from the rest pose: a few % solved); steps given keep refinement and its tolerances."""
    poses = pose.sample_poses(ur3, 40, seed=5)
    s = lab.solve(None, ur3, poses)
    assert (s.tol, s.angle_tol) == (1e-5, 1e-5) and s.success >= 0.95
    p, a = pose.pose_errors(ur3, poses, s.q)
    np.testing.assert_array_equal(s.converged, (p < 1e-5) & (a < 1e-5))
    assert lab.solve(None, UR3, poses[:3]).tol == 1e-5  # by its string too
    refined = lab.solve(None, ur3, poses[:5], steps=3)
    assert refined.tol == 1e-4 and refined.angle_tol == pytest.approx(np.radians(0.1))
    loose = lab.solve(None, ur3, poses[:5], tol=1e-3, angle_tol=1e-3)
    assert (loose.tol, loose.angle_tol) == (1e-3, 1e-3)
    position = lab.solve(None, ur3, ur3.sample_goals(5, seed=1))
    assert position.tol == 1e-4 and position.angle is None and np.all(position.steps <= 3)


def test_the_first_pose_solve_that_compiles_says_so(monkeypatch, capsys, ur3):
    """A first pose solve whose kernels are neither loaded nor cached on disk prints one line before it
    compiles (it compiled for 39 s without a word); one that loads them from the cache, and every later
    one, print nothing; where the cache cannot be read, a first solve still running after a while says it."""
    import threading
    import time
    from types import SimpleNamespace

    from lab import solver

    poses = pose.sample_poses(ur3, 2, seed=8)
    real = solver.pose_solve

    class Slow(real.PoseSolver):
        def solve(self, *args, **kwargs):
            time.sleep(0.05)
            return super().solve(*args, **kwargs)

    monkeypatch.setattr(solver, "pose_solve", SimpleNamespace(PoseSolver=Slow))
    monkeypatch.setattr(solver, "_pose_kernels", lambda controller: [SimpleNamespace(signatures=[])])
    for cached, says in ((False, True), (True, False), (None, True)):
        monkeypatch.setattr(solver, "_solved_once", threading.Event())
        monkeypatch.setattr(solver, "_solver_cached", lambda kernels, cached=cached: cached)
        monkeypatch.setattr(solver, "COMPILE_NOTICE_AFTER", 0.01)
        lab.solve(None, ur3, poses)
        assert (solver.COMPILE_NOTICE in capsys.readouterr().err) == says, cached
        lab.solve(None, ur3, poses)  # the second: silent
        assert solver.COMPILE_NOTICE not in capsys.readouterr().err
    lab.solve(None, ur3, ur3.sample_goals(2, seed=1))  # position goals: no word of the pose solver
    assert solver.COMPILE_NOTICE not in capsys.readouterr().err


def test_lab_pretrained_returns_the_shipped_controller_with_its_recorded_figure():
    from lab.experiments import arms
    from lab.shipped import pretrained_path

    arm = robots.load("planar")
    controller = lab.pretrained("planar")
    with open(pretrained_path("planar"), encoding="utf-8") as f:
        recorded = json.load(f)["held_out"]
    assert arms.held_out(arm, controller)["median"] == pytest.approx(recorded["median"], rel=1e-6)
    posed = lab.pretrained(robots.load("ur5"), goal="pose")
    poses = pose.sample_poses(robots.load("ur5"), 20, seed=9)
    assert posed.goal == "pose" and lab.solve(posed, "ur5", poses).success == 1.0
    with pytest.raises(ValueError, match="no shipped position controller of cmaes for erd:panda#panda_hand_tcp "
                                         "\\(shipped: .*ur5"):
        lab.pretrained(PANDA)


def test_controller_from_dict_checks_the_arm_it_is_given(ur3):
    d = lab.pretrained("ur5").to_dict()
    assert lab.controller_from_dict(d, "ur5").encoding.n_outputs == 6
    with pytest.raises(ValueError, match="ur3_robot.urdf#tool0: this controller carries another arm's kinematics"):
        lab.controller_from_dict(d, ur3)
    with pytest.raises(ValueError, match="so100: this controller answers 6 joints, the arm has 5"):
        lab.controller_from_dict(d, robots.load("so100"))
    with pytest.raises(ValueError, match="panda: this controller answers 6 joints, the arm has 7"):
        lab.controller_from_dict(d, "panda")


def test_python_m_lab_train_takes_a_robot_string_and_its_tool_frame(capsys, tmp_path):
    from lab.__main__ import main

    args = ["train", "--robot", UR3, "--ee", "tool0", "--generations", "2", "--population", "8", "--targets", "10",
            "--test-goals", "10", "--quiet", "--recording", str(tmp_path)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"robot {UR3}#tool0" in out
    assert [p.name.startswith("ur3_robot-tool0-cmaes-s0-") for p in tmp_path.iterdir()] == [True]
    assert main(["train", "--robot", UR3, "--ee", "no_such_frame", "--generations", "1", "--no-recording"]) == 2
    assert "no_such_frame" in capsys.readouterr().err


def test_robot_slug_keeps_file_names_plain():
    assert robot_slug("ur5") == "ur5" and robot_slug("planar-10") == "planar-10"
    assert robot_slug("erd:ur3#tool0") == "erd-ur3-tool0"
    assert robot_slug("/home/me/arms/My Arm.urdf#tool 0") == "My-Arm-tool-0"


# ---------------------------------------------------------------- ONNX
def _onnx_outputs(path, goals):
    ort = pytest.importorskip("onnxruntime")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(["outputs", "joints"], {"goals": np.asarray(goals, dtype=np.float64)})


@pytest.mark.parametrize("robot, goal", [("ur5", "position"), ("so101", "position"), ("kinova", "position"),
                                         ("scara", "position"), ("panda", "pose"), ("so100", "pose")])
def test_the_onnx_file_computes_the_labs_network_to_1e6(robot, goal, tmp_path):
    """Every input encoding the shipped controllers use (sphere, bearings, reach; a pose's 6-D rotation
    and an approach axis), every head, continuous joints wrapped (the Kinova): onnxruntime's outputs
    and mapped joints equal the lab's within 1e-6 on held-out goals."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from lab import export

    arm, controller = robots.load(robot), lab.pretrained(robot, goal=goal)
    goals = pose.sample_poses(arm, 300, seed=11) if goal == "pose" else arm.sample_goals(300, seed=11)
    path = tmp_path / "c.onnx"
    assert export.save(controller, path, goals, robot=robot) <= 1e-6
    outputs, joints = _onnx_outputs(path, goals)
    want_outputs, want_joints = export.lab_outputs(controller, goals)
    assert outputs.shape == (getattr(controller, "heads", 1), 300, arm.nq)
    np.testing.assert_allclose(outputs, want_outputs, rtol=0, atol=1e-6)
    np.testing.assert_allclose(joints, want_joints, rtol=0, atol=1e-6)
    if not controller.encoding.turns and getattr(controller, "heads", 1) == 1:  # then "joints" is the answer
        np.testing.assert_allclose(joints[0], controller(goals), rtol=0, atol=1e-6)


def test_a_neat_controller_is_exported_and_a_trees_is_refused_by_name(tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from lab import export

    run = lab.evolve("planar", "neat", generations=15, population=20, targets=10, test_goals=10, seed=1)
    assert run.controller.kind == "graph"
    goals = robots.load("planar").sample_goals(200, seed=3)
    assert export.save(run.controller, tmp_path / "n.onnx", goals) <= 1e-6
    _, joints = _onnx_outputs(tmp_path / "n.onnx", goals)
    np.testing.assert_allclose(joints[0], run.controller(goals), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="a tree's controller"):
        export.to_onnx(lab.pretrained("solo12"))


def test_python_m_lab_export_writes_and_checks_a_controller_file(capsys, tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from lab.__main__ import main
    from lab.shipped import pretrained_path

    out = tmp_path / "panda.onnx"
    assert main(["export", str(pretrained_path("panda", "pose")), "--onnx", str(out), "--goals", "100"]) == 0
    said = capsys.readouterr().out
    assert out.is_file() and "checked with onnxruntime on 100 held-out goals of panda" in said
    assert "the closed-form wrist" in said and "the first joint's turn" in said
    assert main(["export", str(tmp_path / "missing.json"), "--onnx", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err


LIFT_ARM = """<robot name="lift_arm">
  <link name="base"/><link name="torso"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tool"/>
  <joint name="lift" type="prismatic"><parent link="base"/><child link="torso"/>
    <axis xyz="0 0 1"/><limit lower="0" upper="0.4" effort="1" velocity="1"/></joint>
  <joint name="yaw" type="revolute"><parent link="torso"/><child link="l1"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 0 1"/><limit lower="-2.5" upper="2.5" effort="1" velocity="1"/></joint>
  <joint name="pitch" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.25 0 0"/></joint>
</robot>
"""


def test_a_robot_whose_first_joint_slides_trains_with_every_method_and_no_settings(tmp_path):
    """A mobile manipulator's torso lift (PR2, TIAGo) as the first joint: the first joint cannot be
    turned toward the goal in closed form, so no method's defaults turn it (they did, and every run
    was refused: "the turn needs a revolute first joint"), and each method trains with no settings."""
    import lab
    import robots

    path = tmp_path / "lift_arm.urdf"
    path.write_text(LIFT_ARM)
    arm = robots.load(str(path), ee="tool")
    assert arm.is_prismatic[0] and arm.nq == 4
    for name in lab.methods.names():
        method = lab.methods.get(name)
        assert not method.defaults_for(arm).get("turn", False), name
        assert not method.defaults_for(arm, seconds=5.0).get("turn", False), name
        run = lab.evolve(arm, name, generations=2, population=8, targets=20, test_goals=20, seed=0)
        assert len(run.history) >= 1 and run.test_mse == run.test_mse  # trained, a finite error
