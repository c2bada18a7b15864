"""The closed-form reach of a pose network (PoseEncoding(reach=k), pose_kernels' reach): after the
wrist, the elbow turned so that the tool's distance from the shoulder is the goal's, the shoulder
turned so that the tool's bearing about its axis is the goal's, then the turn and the wrist again,
k times (on the SO arms, held to an approach axis, the wrist's flex first turns that axis toward the
goal's, and there is no wrist). Checked through Pinocchio: each step does what it says and leaves the frame it reports; the
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
REACHING = FULL_POSE + ["so100", "so101"]


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


def _step(enc, q, T, step):
    """One reach step of the kernel on joint vectors q (n, nq) toward poses T: (q after, the tool frames
    the kernel reports)."""
    Q = np.ascontiguousarray(q.T.copy())
    R, P = np.empty((3, 3, len(q))), np.empty((3, len(q)))
    _chain_frames(Q, enc.chain, R, P)
    GP, GR = enc.goal_arrays(T)
    pose_kernels._reach_rows(Q, GP, GR, enc.chain, enc.spec(), R, P, step, np.empty((3, 0)))
    return Q.T.copy(), P.T + np.einsum("nab,b->na", R.transpose(2, 0, 1), enc.chain[4]), R.transpose(2, 0, 1)


def _one_joint_step(arm, enc, q, j, step, seed):
    """(goals, Pinocchio's tool frames after the step, the joints after it): goals that joint j alone
    reaches (its values of another draw, the rest q's), then the kernel's step on j; checked through
    Pinocchio that only j moved and that the frame the kernel reports is Pinocchio's."""
    other = q.copy()
    other[:, j] = arm.sample_q(len(q), seed=seed)[:, j]
    T = pose.fk_pose(arm, other)
    after, told, R = _step(enc, q, T, step)
    M = pose.fk_pose(arm, after)
    assert np.abs(told - M[:, :3, 3]).max() < 1e-9
    assert np.abs(R @ enc.tool - M[:, :3, :3]).max() < 1e-9
    assert np.array_equal(np.delete(after, j, axis=1), np.delete(q, j, axis=1))
    return T, M, after


@pytest.mark.parametrize("name", REACHING)
def test_each_closed_form_joint_does_what_it_says(name):
    """Through Pinocchio, for goals that one joint alone can reach (another value of it within the
    limits, the rest kept): after the elbow's step the tool's distance from the shoulder point is the
    goal's; after the shoulder's the tool is on the goal; after the flex's (the SO arms) the approach
    axis is the goal's. Only that joint moves, and the frame the kernel reports is Pinocchio's."""
    arm = robots.load(name)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=1)
    S, E, F = enc.reach_joints()
    assert (F >= 0) == (name.startswith("so"))
    q = arm.sample_q(40, seed=1)
    for j, step in ((E, pose_kernels._ELBOW), (S, pose_kernels._SHOULDER), (F, pose_kernels._FLEX)):
        if j < 0:
            continue
        T, M, _ = _one_joint_step(arm, enc, q, j, step, seed=2)
        if step == pose_kernels._ELBOW:
            s = np.array([_shoulder_point(arm, qi, S) for qi in q])
            tool, goals = M[:, :3, 3], T[:, :3, 3]
            assert np.abs(np.linalg.norm(tool - s, axis=1) - np.linalg.norm(goals - s, axis=1)).max() < 1e-9
        elif step == pose_kernels._SHOULDER:
            assert np.abs(M[:, :3, 3] - T[:, :3, 3]).max() < 1e-9
        else:
            assert np.abs(M[:, :3, :3] @ enc.axis - T[:, :3, :3] @ enc.axis).max() < 1e-9


@pytest.mark.parametrize("name", ["so100", "so101"])
def test_the_so_arms_first_joint_and_roll_do_what_they_say(name):
    """Through Pinocchio, on goals that the joint alone can reach: after the first joint's step the
    goal's approach direction has the tool's approach axis's height along the shoulder's axis (the
    plane the shoulder, elbow and flex turn it in then holds it); after the roll's, the tool point has
    the goal's height along the shoulder's axis. Only that joint moves, and the kernel's frame is
    Pinocchio's."""
    arm = robots.load(name)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=1)
    S = enc.reach_joints()[0]
    q = arm.sample_q(40, seed=21)
    for j, step in ((0, pose_kernels._PAN), (arm.nq - 1, pose_kernels._ROLL)):
        T, M, after = _one_joint_step(arm, enc, q, j, step, seed=22)
        for i in range(len(q)):
            c, w = _axis(arm, after[i], S)
            if step == pose_kernels._PAN:
                assert abs(w @ (M[i, :3, :3] @ enc.axis) - w @ (T[i, :3, :3] @ enc.axis)) < 1e-9
            elif np.linalg.norm(np.cross(w, M[i, :3, :3] @ enc.axis)) > 0.05:  # the roll moves that height
                assert abs(w @ (M[i, :3, 3] - c) - w @ (T[i, :3, 3] - c)) < 1e-9


@pytest.mark.parametrize("name", ["so100", "so101", "ur5", "ur10", "z1"])
def test_one_pass_puts_the_arm_on_its_pose_from_near_its_branch(name):
    """The SO arms' pass (_approach_pass) and the UR arms' and Z1's (_wrist_point_pass) solve every
    joint in closed form, so one pass lands the pose exactly from joints a little off it (0.1 rad each:
    each two-solution joint then keeps the pose's own branch) where no limit clips a joint on the way
    (96-100 % of these), and the default passes nearly always (99 %); from arbitrary joint values, most
    poses (71-96 %), through Pinocchio."""
    arm = robots.load(name)
    q = arm.sample_q(300, seed=23)
    T = pose.fk_pose(arm, q)
    off = arm.within_limits(q + np.random.default_rng(24).uniform(-0.1, 0.1, q.shape))
    start = arm.sample_q(300, seed=25)
    for reach, begin, share in ((1, off, 0.93), (None, off, 0.98), (None, start, 0.65)):
        enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=reach)
        d, a = pose.pose_errors(arm, T, enc.finished(begin, T))
        assert np.mean((d < 1e-9) & (a < 1e-9)) > share, (reach, np.quantile(d, 0.9), np.quantile(a, 0.9))


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


@pytest.mark.parametrize("name", ["z1", "panda", "so101"])
def test_each_goal_keeps_its_best_pass(name):
    """A pass is exact for each of its joints, not for the pose: where limits clip a joint the passes
    can drift away, so each goal keeps its best. Then more passes never leave an answer worse (the
    same iterates and more), through Pinocchio, on arbitrary starts where drifting happens."""
    arm = robots.load(name)
    T = pose.sample_poses(arm, 300, seed=8)
    start = arm.sample_q(300, seed=9)
    weight2 = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=1).weight ** 2
    errors = []
    for reach in (1, 2, 6):
        enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=reach)
        d, a = pose.pose_errors(arm, T, enc.finished(start, T))
        errors.append(d * d + weight2 * a * a)
    assert np.all(errors[1] <= errors[0] * (1 + 1e-9) + 1e-15)
    assert np.all(errors[2] <= errors[1] * (1 + 1e-9) + 1e-15)
    assert np.mean(errors[2] < errors[0] * (1 - 1e-6)) > 0.2  # and the later passes help many


def test_the_wrist_point_is_where_the_wrist_axes_meet():
    """PoseEncoding.wrist_point: the Kinova's three wrist axes meet in one point, fixed in the last
    joint's frame; the UR arms' and Z1's last two; the Panda's and xArm7's none. The point, carried by
    the kernels' frames, lies on Pinocchio's axes at random joint vectors."""
    for name, meet in (("kinova", 3), ("ur5", 2), ("z1", 2), ("panda", 0), ("xarm7", 0)):
        arm = robots.load(name)
        enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True)
        found = enc.wrist_point()
        assert (found is None) == (meet == 0), name
        if found is None:
            continue
        point, spherical = found
        assert spherical == (meet == 3), name
        q = arm.sample_q(3, seed=12)
        R, P = np.empty((3, 3, 3)), np.empty((3, 3))
        _chain_frames(np.ascontiguousarray(q.T.copy()), enc.chain, R, P)
        for i in range(3):
            x = P[:, i] + R[:, :, i] @ point
            for j in range(arm.nq - meet, arm.nq):
                c, w = _axis(arm, q[i], j)
                assert np.linalg.norm(np.cross(x - c, w)) < 1e-9, (name, j)


def test_the_reach_of_a_spherical_wrist_places_its_centre_then_turns_the_tool():
    """On the Kinova the reach places the wrist's centre (the turn, the elbow and the shoulder, apart
    from the wrist) and then solves the wrist once: from arbitrary joint values the answer is exactly
    on the pose for most goals (84-87 % of these; the others on a branch the limits close), through
    Pinocchio."""
    arm = robots.load("kinova")
    T = pose.sample_poses(arm, 300, seed=13)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True)
    assert enc.reach and enc.wrist_point()[1]
    start = arm.sample_q(300, seed=14)
    d, a = pose.pose_errors(arm, T, enc.finished(start, T))
    assert np.mean((d < 1e-9) & (a < 1e-9)) > 0.75, (np.median(d), np.median(a))
    centre = enc.wrist_point()[0]
    offset = enc.tool.T @ (centre - np.asarray(enc.chain[4]))
    goal_centres = T[:, :3, 3] + np.einsum("nab,b->na", T[:, :3, :3], offset)
    model, data = arm.model, arm.model.createData()
    last = int(arm.chain.joint_ids[-1])
    distances = []
    for reach in (1, 2, 6):  # each goal keeps its nearest pass: more passes never leave the centre farther
        q = PoseEncoding.for_arm(arm, "sphere", 0.0, True, reach=reach).finished(start, T)
        out = []
        for qi, g in zip(q, goal_centres):
            pin.forwardKinematics(model, data, arm.to_pinocchio(qi[None])[0])
            out.append(np.linalg.norm(data.oMi[last].translation + data.oMi[last].rotation @ centre - g))
        distances.append(np.array(out))
    assert np.all(distances[1] <= distances[0] + 1e-12) and np.all(distances[2] <= distances[1] + 1e-12)


def test_a_reach_controller_round_trips_and_the_gradient_method_holds_its_joints():
    arm = robots.load("panda")
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, wrist=True, reach=2)
    assert enc.reach_joints() == (1, 3, -1) and list(enc.turned_joints) == [0, 1, 3, 4, 5, 6]
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
        with pytest.raises(ValueError, match="needs the turn of the first joint and, on an arm held to a full pose"):
            PoseEncoding.for_arm(arm, "sphere", turn=turn, wrist=wrist, reach=2)
    for bad in (-1, 17, 1.5, True):
        with pytest.raises(ValueError, match="reach must be a number of passes"):
            PoseEncoding(plain.position, plain.chain, plain.tool, None, plain.weight, True, 2, bad)


def test_training_settings_carry_the_reach_by_method_and_arm():
    """The evolutionary methods' pose runs get the arm's passes (REACH_PASSES), the gradient method
    none (it would hold every joint of a 6-joint arm); position runs and runs without the turn none;
    a reach where it cannot apply is refused by name."""
    assert lab.TrainConfig(robot="panda", goal="pose").reach == 8
    assert lab.TrainConfig(robot="panda", goal="pose").to_dict()["reach"] == 8
    assert lab.TrainConfig(robot="ur5", goal="pose", method="gradient").reach == 0
    assert lab.TrainConfig(robot="ur5", goal="pose", turn=False).reach == 0
    assert lab.TrainConfig(robot="so100", goal="pose").reach == 8
    assert "reach" not in lab.TrainConfig(robot="ur5").to_dict()
    assert lab.TrainConfig(robot="ur5", goal="pose").replace(method="gradient", heads=1).reach == 0  # its own
    with pytest.raises(ValueError, match="reach .* is for pose goals"):
        lab.TrainConfig(robot="ur5", reach=3)
    assert lab.TrainConfig(robot="so100", goal="pose", reach=2).reach == 2  # the SO arms: no wrist, a flex
    with pytest.raises(ValueError, match="ur5 runs with turn=False"):
        lab.TrainConfig(robot="ur5", goal="pose", turn=False, reach=2)
    run = lab.evolve("ur5", goal="pose", generations=2, population=6, targets=10, test_goals=5, reach=2)
    assert run.controller.encoding.reach == 2 and run.config.reach == 2
    again = lab.evolve("ur5", goal="pose", generations=2, population=6, targets=10, test_goals=5, reach=2)
    assert np.allclose(run.history, again.history, rtol=1e-9, atol=0)  # the same seed, the same run
    T = pose.sample_poses(robots.load("ur5"), 20, seed=1)
    assert np.allclose(run.controller(T), again.controller(T), rtol=0, atol=1e-9)


def test_the_command_line_takes_the_reach_and_refuses_it_by_name(capsys):
    from lab.__main__ import main as lab_main

    assert lab_main(["train", "--robot", "ur5", "--reach", "2", "--generations", "2", "--no-recording",
                     "--quiet"]) == 2
    assert "reach (the closed-form elbow and shoulder) is for pose goals" in capsys.readouterr().err
    assert lab_main(["train", "--robot", "ur5", "--goal", "pose", "--reach", "0", "--generations", "1",
                     "--population", "6", "--targets", "10", "--test-goals", "5", "--no-recording", "--quiet"]) == 0
