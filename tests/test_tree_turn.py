"""A tree's limbs turned in closed form (TreeEncoding's turn): the first joint of each limb that moves
one effector alone (not g1's waist) takes the angle that brings that effector nearest its goal,
within its limits; the kernels score exactly the controller's turned answer; only those joints
move; the turn never makes an answer worse; it saves, loads and trains (its gradient: tests/test_turn.py)."""

import json

import numpy as np
import pytest

import lab
import robots
from lab.problem import Problem, encoding_for, encoding_from_dict
from lab.problem.controllers import MLPController, controller_from_dict, mlp_size
from lab.problem.wiring import Wiring

from conftest import METHODS

TREES = ("talos-legs", "solo12", "allegro", "g1")


def _random_joints(arm, n, seed):
    rng = np.random.default_rng(seed)
    return arm.lower + rng.random((n, arm.nq)) * (arm.upper - arm.lower)


def _errors(arm, q, goals, effectors):
    """Summed squared error of the given effectors: (n,)."""
    return np.sum((arm.fk(q)[:, effectors] - goals[:, effectors]) ** 2, axis=(1, 2))


@pytest.mark.parametrize("robot", TREES)
def test_each_turned_joint_takes_the_best_angle_within_its_limits_and_only_it_moves(robot):
    arm = robots.load(robot)
    enc = encoding_for(arm, "reach", 0.0, turn=True)
    paths = [arm.chain.path(e) for e in range(arm.n_effectors)]
    alone = [int(p[0]) for p in paths if sum(int(p[0]) in other for other in paths) == 1]
    assert enc.turned_joints.tolist() == sorted(alone) and len(alone) == (2 if robot == "g1" else arm.n_effectors)
    goals, q = arm.sample_goals(120, seed=3), _random_joints(arm, 120, 1)
    turned = enc.turned(q[None], goals)[0]
    others = np.setdiff1d(np.arange(arm.nq), enc.turned_joints)
    np.testing.assert_array_equal(turned[:, others], q[:, others])
    for j in enc.turned_joints:
        hangs = [e for e in range(arm.n_effectors) if paths[e][0] == j]  # the one effector it moves
        lo, hi = (arm.lower[j], arm.upper[j]) if arm.upper[j] - arm.lower[j] <= 2 * np.pi else (-np.pi, np.pi)
        assert np.all((turned[:, j] >= arm.lower[j] - 1e-12) & (turned[:, j] <= arm.upper[j] + 1e-12))
        best = _errors(arm, turned, goals, hangs)
        for angle in np.linspace(lo, hi, 181):  # no angle on a fine grid within the limits does better
            trial = turned.copy()
            trial[:, j] = angle
            assert np.all(best <= _errors(arm, trial, goals, hangs) + 1e-12)
    before, after = (np.sum((arm.fk(x) - goals) ** 2, axis=(1, 2)) for x in (q, turned))
    assert np.all(after <= before + 1e-12)


@pytest.mark.parametrize("robot", TREES)
def test_the_kernels_score_the_controllers_turned_answer_wired_or_not(robot):
    arm = robots.load(robot)
    enc = encoding_for(arm, "reach", 0.0, turn=True)
    problem = Problem(arm, enc, targets=40, test_goals=10, threads=1)
    W = np.random.default_rng(2).normal(0.0, 0.3, (4, mlp_size(enc.n_inputs, 8, arm.nq)))
    fk = [problem.controller_mse(MLPController(enc, 8, w)) for w in W]
    np.testing.assert_allclose(problem.mlp_mse(W, 8), fk, rtol=1e-9)
    plain = Problem(arm, encoding_for(arm, "reach", 0.0), targets=40, test_goals=10, threads=1)
    assert np.all(problem.mlp_mse(W, 8) <= plain.mlp_mse(W, 8) * (1 + 1e-12))
    wiring = Wiring.for_arm(arm, enc.n_inputs, 8)
    G = np.random.default_rng(3).normal(0.0, 0.3, (3, wiring.dim))
    np.testing.assert_allclose(problem.wired_mse(G, wiring).sum(axis=1), problem.mlp_mse(wiring.expand(G), 8),
                               rtol=1e-12)


def test_a_turned_tree_controller_round_trips_through_json():
    arm = robots.load("g1")
    enc = encoding_for(arm, "reach", 0.0, turn=True)
    c = MLPController(enc, 6, np.random.default_rng(0).normal(0, 0.3, mlp_size(enc.n_inputs, 6, arm.nq)))
    back = controller_from_dict(json.loads(json.dumps(c.to_dict())))
    goals = arm.sample_goals(30, seed=1)
    assert back.encoding.turns and back.encoding.turned_joints.tolist() == enc.turned_joints.tolist()
    np.testing.assert_array_equal(back(goals), c(goals))
    bad = {**c.to_dict()["encoding"], "turn": np.zeros((arm.n_effectors, 10)).tolist()}
    with pytest.raises(ValueError, match="one row on at least"):
        encoding_from_dict(bad)
    waist = np.array(bad["turn"])
    waist[0] = encoding_for(robots.load("solo12"), "reach", turn=True).turn[0]  # any unit axis
    with pytest.raises(ValueError, match="moves other effectors too"):
        encoding_from_dict({**bad, "turn": waist.tolist()})


@pytest.mark.parametrize("method", METHODS)
def test_every_method_trains_a_turned_tree_and_repeats_its_run(method):
    kw = dict(generations=40 if method == "gradient" else 6, population=8, seed=0, targets=30, test_goals=40, turn=True)
    a, b = (lab.evolve("talos-legs", method, **kw) for _ in range(2))
    assert a.config.turn and a.controller.encoding.turns
    assert a.history[-1] < a.history[0]
    assert np.array_equal(a.history, b.history) and a.test_mse == b.test_mse
    goals = robots.load("talos-legs").sample_goals(20, seed=5)
    np.testing.assert_array_equal(a.controller(goals), b.controller(goals))
