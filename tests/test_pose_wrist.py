"""The closed-form wrist of a pose network (PoseEncoding(wrist=True), pose_kernels' wrist): the last
three joints solved for the goal's orientation on the frame the others leave. Checked: the true
joints before the wrist give the goal's pose back exactly; the gradient method holds the wrist and
its loss equals the fitness (the fitness against Pinocchio with the wrist: tests/test_pose_training.py);
a controller round-trips; arms without such a wrist are refused by name."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lab
import robots
from lab.problem.controllers import MLPController, mlp_size
from lab.problem.pose_encoding import PoseEncoding
from lab.problem.pose_fitness import PoseProblem
from robots import pose

FULL_POSE = ["ur5", "ur10", "panda", "xarm7", "kinova", "z1"]


@pytest.mark.parametrize("name", FULL_POSE)
def test_the_true_arm_joints_and_the_solved_wrist_give_the_pose_back(name):
    """Any wrist joints given, the solved ones (the nearer of two) put the tool exactly on the pose
    when the joints before the wrist are the pose's own (its wrist is within the limits, so one of the
    two solutions is it)."""
    arm = robots.load(name)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, turn=False, wrist=True)
    q = arm.sample_q(300, seed=1)
    T = pose.fk_pose(arm, q)
    wrong = q.copy()
    wrong[:, -3:] = arm.sample_q(300, seed=2)[:, -3:]
    solved = enc.finished(wrong, T)
    assert np.array_equal(solved[:, :-3], q[:, :-3])
    assert np.all(solved >= arm.lower - 1e-12) and np.all(solved <= arm.upper + 1e-12)
    d, a = pose.pose_errors(arm, T, solved)
    assert d.max() < 1e-9 and a.max() < 1e-9


@pytest.mark.parametrize("name", ["ur5", "kinova"])
def test_the_gradient_method_holds_the_wrist_and_its_loss_is_the_fitness(name):
    """The wrist's joints are solved, not learnt: the gradient method holds them (as the turned joint),
    and its loss is the compiled fitness (which tests/test_pose_training.py holds to Pinocchio)."""
    arm = robots.load(name)
    enc = PoseEncoding.for_arm(arm, "sphere", 0.3, True, wrist=True, reach=0)
    problem = PoseProblem(arm, enc, targets=30, test_goals=5, goal_seed=3)
    assert list(enc.turned_joints) == [0, arm.nq - 3, arm.nq - 2, arm.nq - 1]
    w = np.random.default_rng(1).normal(0.0, 0.4, mlp_size(enc.n_inputs, 6, enc.n_outputs))
    loss, grad = problem.mlp_gradient(w, 6)
    assert loss == pytest.approx(problem.mlp_mse(w[None], 6)[0], rel=1e-9)
    assert np.all(np.isfinite(grad))


def test_a_wrist_controller_round_trips_and_its_orientation_is_exact_where_the_limits_allow():
    arm = robots.load("ur5")
    enc = PoseEncoding.for_arm(arm, "sphere", 0.0, True, wrist=True)
    w = np.random.default_rng(4).normal(0.0, 0.3, mlp_size(enc.n_inputs, 8, enc.n_outputs))
    c = MLPController(enc, 8, w)
    back = lab.controller_from_dict(json.loads(json.dumps(c.to_dict())))
    assert back.encoding.wrist
    T = pose.sample_poses(arm, 100, seed=5)
    assert np.array_equal(back(T), c(T))
    assert np.median(pose.pose_errors(arm, T, c(T))[1]) < 1e-9  # the UR5's wrist joints turn +-2 pi


def test_arms_without_a_closed_form_wrist_are_refused_by_name():
    with pytest.raises(ValueError, match="full pose"):
        PoseEncoding.for_arm(robots.load("so100"), "sphere", 0.0, True, wrist=True)
    plain = PoseEncoding.for_arm(robots.load("ur5"), "sphere", wrist=False)
    assert not plain.wrist and "wrist" not in plain.to_dict()
    # the default: the wrist on the arms held to a full pose, none on the SO arms
    assert PoseEncoding.for_arm(robots.load("ur5"), "sphere").wrist
    assert not PoseEncoding.for_arm(robots.load("so100"), "sphere").wrist
    with pytest.raises(ValueError, match="wrist_passes"):
        PoseEncoding(plain.position, plain.chain, plain.tool, None, plain.weight, True, 3)
