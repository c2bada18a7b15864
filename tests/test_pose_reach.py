"""The closed-form reach of a pose network (PoseEncoding(reach=k), pose_kernels' reach): after the
wrist, the elbow turned so that the tool's distance from the shoulder is the goal's, the shoulder
turned so that the tool's bearing about its axis is the goal's, then the turn and the wrist again,
k times. Checked through Pinocchio: each step does what it says and leaves the frame it reports; the
passes bring the network's answer nearer; a controller round-trips; bad settings are refused by name.
(The fitness with the reach equals Pinocchio's figures: tests/test_pose_training.py.)"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

import lab
import robots
from lab.problem import pose_kernels
from lab.problem.controllers import MLPController, mlp_size
from lab.problem.kernels import _chain_frames
from lab.problem.pose_encoding import PoseEncoding
from robots import pose

FULL_POSE = ["ur5", "ur10", "panda", "xarm7", "kinova", "z1"]


def _axis(arm, q, j):
    """(point, unit direction) of joint j's axis at q, through Pinocchio."""
    model, data = arm.model, arm.model.createData()
    pin.computeJointJacobians(model, data, arm.to_pinocchio(q[None])[0])
    jid = int(arm.chain.joint_ids[j])
    w = pin.getJointJacobian(model, data, jid, pin.WORLD)[3:, model.joints[jid].idx_v]
    return data.oMi[jid].translation.copy(), w / np.linalg.norm(w)


def _shoulder_point(arm, q, S):
    """The point of S's axis nearest joint 0's axis."""
    (c0, w0), (cs, ws) = _axis(arm, q, 0), _axis(arm, q, S)
    b, d = ws @ w0, cs - c0
    return cs + ws * (b * (d @ w0) - d @ ws) / (1.0 - b * b)


def _step(enc, q, goals, elbow):
    """One reach step of the kernel on joint vectors q (n, nq): (q after, tool points the frame says)."""
    Q = np.ascontiguousarray(q.T.copy())
    R, P = np.empty((3, 3, len(q))), np.empty((3, len(q)))
    _chain_frames(Q, enc.chain, R, P)
    pose_kernels._reach_rows(Q, np.ascontiguousarray(goals.T), enc.chain, enc.spec()[4], R, P, elbow)
    return Q.T.copy(), P.T + np.einsum("nab,b->na", R.transpose(2, 0, 1), enc.chain[4])


@pytest.mark.parametrize("name", FULL_POSE)
def test_the_elbow_sets_the_goal_distance_and_the_shoulder_its_bearing(name):
    """A goal the elbow alone can reach (another elbow angle within the limits, the rest kept): after
    the elbow's step the tool's distance from the shoulder point is the goal's. A goal the shoulder
    alone can reach: after its step the tool is on it. Both through Pinocchio, and the frame the
    kernel reports is the one Pinocchio computes for the new joints."""
    arm = robots.load(name)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, wrist=True, reach=1)
    S, E = enc.reach_joints()
    q = arm.sample_q(40, seed=1)
    for j, elbow in ((E, True), (S, False)):
        other = q.copy()
        other[:, j] = arm.sample_q(40, seed=2)[:, j]
        goals = pose.fk_pose(arm, other)[:, :3, 3]
        after, told = _step(enc, q, goals, elbow)
        tool = pose.fk_pose(arm, after)[:, :3, 3]
        assert np.abs(told - tool).max() < 1e-9
        assert np.array_equal(np.delete(after, j, axis=1), np.delete(q, j, axis=1))
        if elbow:
            s = np.array([_shoulder_point(arm, qi, S) for qi in q])
            assert np.abs(np.linalg.norm(tool - s, axis=1) - np.linalg.norm(goals - s, axis=1)).max() < 1e-9
        else:
            assert np.abs(tool - goals).max() < 1e-9


@pytest.mark.parametrize("name", ["ur5", "z1"])
def test_more_passes_bring_an_answer_near_its_pose(name):
    """Joints a little off the pose's (0.1 rad each): the orientation stays exact, and the passes take
    the position error down (the median by more than 10x after four; with the turn, which they need)."""
    arm = robots.load(name)
    q = arm.sample_q(200, seed=3)
    T = pose.fk_pose(arm, q)
    off = arm.within_limits(q + np.random.default_rng(4).uniform(-0.1, 0.1, q.shape))
    medians = []
    for reach in (0, 1, 4):
        enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, wrist=True, reach=reach)
        d, a = pose.pose_errors(arm, T, enc.finished(off, T))
        medians.append(np.median(d))
        assert np.median(a) < 1e-9
    assert medians[2] < medians[1] < medians[0] and medians[2] < 0.1 * medians[0]


def test_a_reach_controller_round_trips_and_the_gradient_method_holds_its_joints():
    arm = robots.load("panda")
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, wrist=True, reach=2)
    assert enc.reach_joints() == (1, 3) and list(enc.turned_joints) == [0, 1, 3, 4, 5, 6]
    w = np.random.default_rng(4).normal(0.0, 0.3, mlp_size(enc.n_inputs, 8, enc.n_outputs))
    c = MLPController(enc, 8, w)
    back = lab.controller_from_dict(json.loads(json.dumps(c.to_dict())))
    assert back.encoding.reach == 2
    T = pose.sample_poses(arm, 100, seed=5)
    assert np.array_equal(back(T), c(T))
    # a file written before the reach reads as none
    d = c.to_dict()
    del d["encoding"]["reach"]
    assert lab.controller_from_dict(d).encoding.reach == 0


def test_bad_reach_settings_are_refused_by_name():
    arm = robots.load("ur5")
    plain = PoseEncoding.for_arm(arm, "sphere", turn=True, wrist=False)
    assert plain.reach == 0 and "reach" not in plain.to_dict()
    for wrist, turn in ((False, True), (True, False)):
        with pytest.raises(ValueError, match="needs the closed-form wrist and the turn"):
            PoseEncoding.for_arm(arm, "sphere", turn=turn, wrist=wrist, reach=2)
    for bad in (-1, 17, 1.5, True):
        with pytest.raises(ValueError, match="reach must be a number of passes"):
            PoseEncoding(plain.position, plain.chain, plain.tool, None, plain.weight, True, 2, bad)


def test_training_settings_carry_the_reach_by_method_and_arm():
    """The evolutionary methods' pose runs get the arm's passes (REACH_PASSES), the gradient method
    none (it would hold every joint of a 6-joint arm); position runs, the SO arms and runs without
    the turn none; a reach where it cannot apply is refused by name."""
    assert lab.TrainConfig(robot="panda", goal="pose").reach == 8
    assert lab.TrainConfig(robot="panda", goal="pose").to_dict()["reach"] == 8
    assert lab.TrainConfig(robot="ur5", goal="pose", method="gradient").reach == 0
    assert lab.TrainConfig(robot="ur5", goal="pose", turn=False).reach == 0
    assert lab.TrainConfig(robot="so100", goal="pose").reach == 0
    assert "reach" not in lab.TrainConfig(robot="ur5").to_dict()
    with pytest.raises(ValueError, match="reach .* is for pose goals"):
        lab.TrainConfig(robot="ur5", reach=3)
    with pytest.raises(ValueError, match="so100 has no such wrist"):
        lab.TrainConfig(robot="so100", goal="pose", reach=2)
    with pytest.raises(ValueError, match="ur5 runs with turn=False"):
        lab.TrainConfig(robot="ur5", goal="pose", turn=False, reach=2)
    run = lab.evolve("ur5", goal="pose", generations=2, population=6, targets=10, test_goals=5, reach=2)
    assert run.controller.encoding.reach == 2 and run.config.reach == 2


def test_the_command_line_takes_the_reach_and_refuses_it_by_name(capsys):
    from lab.__main__ import main as lab_main

    assert lab_main(["train", "--robot", "ur5", "--reach", "2", "--generations", "2", "--no-recording",
                     "--quiet"]) == 2
    assert "reach (the closed-form elbow and shoulder) is for pose goals" in capsys.readouterr().err
    assert lab_main(["train", "--robot", "ur5", "--goal", "pose", "--reach", "0", "--generations", "1",
                     "--population", "6", "--targets", "10", "--test-goals", "5", "--no-recording", "--quiet"]) == 0
