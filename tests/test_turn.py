"""The first joint's closed-form turn (Encoding.turn): the kernels, the controllers and the gradient
all answer with the turned joints, and the turn is robots.ik's own closed-form turn."""

import json

import numpy as np
import pytest

import robots
from lab.problem.controllers import MLPController, controller_from_dict, mlp_size
from lab.problem import encoding_for
from lab.problem.fitness import Problem
from robots.ik import _bearing, _turned

ARMS = ["ur5", "so101", "kinova", "z1"]  # joints of +-2 pi, a base of +-110 degrees, a continuous base, 2 heads' arm


def _random_joints(arm, n, seed):
    rng = np.random.default_rng(seed)
    return arm.lower + rng.random((n, arm.nq)) * (arm.upper - arm.lower)


@pytest.mark.parametrize("name", ARMS)
def test_turn_is_the_closed_form_turn_of_robots_ik(name):
    arm = robots.load(name)
    enc = encoding_for(arm, "sphere", 0.3, turn=True)
    goals, q = arm.sample_goals(300, seed=3), _random_joints(arm, 300, 1)
    turned = enc.turned(q[None], goals)[0]
    ref = np.array([_turned(qi, arm.reach(qi[None])[0], g, _bearing(arm), arm.lower, arm.upper,
                            bool(arm.chain.continuous[0])) for qi, g in zip(q, goals)])
    np.testing.assert_allclose(np.angle(np.exp(1j * (turned[:, 0] - ref[:, 0]))), 0.0, atol=1e-9)
    np.testing.assert_array_equal(turned[:, 1:], q[:, 1:])  # only the first joint moves
    assert np.all((turned[:, 0] >= arm.lower[0] - 1e-12) & (turned[:, 0] <= arm.upper[0] + 1e-12))
    # never farther from the goal than before the turn
    before, after = (np.linalg.norm(arm.reach(x) - goals, axis=1) for x in (q, turned))
    assert np.all(after <= before + 1e-12)


@pytest.mark.parametrize("name", ARMS)
@pytest.mark.parametrize("heads", [1, 2])
def test_fitness_scores_the_turned_answer(name, heads):
    """The kernel's MSE (closed-form turned error, no second forward kinematics) equals the error of
    the controller's own (turned) joint values through arm.fk."""
    arm = robots.load(name)
    enc = encoding_for(arm, "sphere", 0.0, turn=True)
    problem = Problem(arm, enc, targets=60, test_goals=10, threads=1)
    rng = np.random.default_rng(2)
    W = rng.normal(0.0, 0.3, (5, mlp_size(enc.n_inputs, 8, arm.nq * heads)))
    nets = [MLPController(enc, 8, w, heads, None, arm.chain.arrays if heads > 1 else None) for w in W]
    offsets = nets[0].offsets if heads > 1 else None
    np.testing.assert_allclose(problem.mlp_mse(W, 8, offsets=offsets),
                               [problem.controller_mse(c) for c in nets], rtol=1e-8)
    plain = Problem(arm, encoding_for(arm, "sphere", 0.0), targets=60, test_goals=10, threads=1)
    assert np.all(problem.mlp_mse(W, 8, offsets=offsets) <= plain.mlp_mse(W, 8, offsets=offsets) * (1 + 1e-12))


def test_turned_controller_round_trips_through_json():
    arm = robots.load("ur5")
    enc = encoding_for(arm, "sphere", 0.0, turn=True)
    c = MLPController(enc, 6, np.random.default_rng(0).normal(0, 0.3, mlp_size(enc.n_inputs, 6, arm.nq)))
    back = controller_from_dict(json.loads(json.dumps(c.to_dict())))
    goals = arm.sample_goals(50, seed=1)
    assert back.encoding.turns
    np.testing.assert_array_equal(back(goals), c(goals))


@pytest.mark.parametrize("name", ["ur5", "solo12"])  # a serial arm's first joint; each leg's hip of a tree
def test_gradient_through_the_turn_matches_finite_differences(name):
    arm = robots.load(name)
    enc = encoding_for(arm, "sphere", 0.0, turn=True)
    problem = Problem(arm, enc, targets=30, test_goals=10, threads=1)
    w = np.random.default_rng(4).normal(0.0, 0.2, mlp_size(enc.n_inputs, 4, arm.nq))
    mse, grad = problem.mlp_gradient(w, 4)
    assert mse == pytest.approx(float(problem.mlp_mse(w[None], 4)[0]), rel=1e-9)
    for i in np.random.default_rng(5).choice(len(w), 12, replace=False):
        e = np.zeros_like(w)
        e[i] = 1e-6
        fd = (problem.mlp_mse((w + e)[None], 4)[0] - problem.mlp_mse((w - e)[None], 4)[0]) / 2e-6
        assert grad[i] == pytest.approx(fd, rel=1e-4, abs=1e-9)


def test_turn_refused_where_it_has_no_closed_form():
    with pytest.raises(ValueError, match="3 task axes"):
        encoding_for(robots.load("planar"), "cartesian", turn=True)
    enc = encoding_for(robots.load("ur5"), "sphere", turn=True)
    with pytest.raises(ValueError, match="needs the goals"):
        enc.joints(np.zeros((3, 6)))
