"""Multi-head networks on trees: each limb group answers with its own head. The fitness counts, per
goal and per group, the smallest of the heads' errors; the controller answers with exactly those
heads; refinement may take each group from another proposal."""

import json

import numpy as np
import pytest

import lab
import robots
from lab.problem import Problem, encoding_for
from lab.problem.controllers import MLPController, controller_from_dict, proposals
from lab.problem.fitness import goal_errors, tree_arrays
from lab.problem.wiring import Wiring, limb_groups
from robots.ik import refine

FAST = dict(targets=30, test_goals=40)


def brute_force(arm, Q, goals):
    """Per goal, each limb group's head of least summed effector error, by arm.reach: (n, nq) joints
    and (n,) summed squared errors."""
    err = np.sum((arm.reach(Q) - goals) ** 2, axis=-1)  # (heads, n, E)
    best, total = Q[0].copy(), np.zeros(len(goals))
    for group in limb_groups(arm):
        joints = np.unique(np.concatenate([arm.chain.path(e) for e in group]))
        per_head = err[:, :, group].sum(axis=-1)  # (heads, n)
        h = np.argmin(per_head, axis=0)
        best[:, joints] = Q[h, np.arange(len(goals))][:, joints]
        total += per_head.min(axis=0)
    return best, total


@pytest.mark.parametrize("robot", ["g1", "talos-legs"])
def test_a_tree_network_answers_each_limb_group_with_its_nearest_head_and_the_fitness_scores_that(robot):
    arm = robots.load(robot)
    enc = encoding_for(arm, "sphere", 0.3, turn=True)
    heads, hidden = 3, 9
    wiring = Wiring.for_arm(arm, enc.n_inputs, hidden, heads)
    shape = MLPController(enc, hidden, np.zeros(wiring.size), heads, None, tree_arrays(arm))
    problem = Problem(arm, enc, targets=25, test_goals=10)
    rng = np.random.default_rng(3)
    G = rng.normal(0, 0.6, (4, wiring.dim))
    F = problem.wired_mse(G, wiring, offsets=shape.offsets)  # (P, groups)
    goals = problem.train_goals
    for g, f in zip(G, F):
        net = MLPController(enc, hidden, wiring.expand(g), heads, None, tree_arrays(arm))
        Q = enc.joints(net.head_outputs(goals), goals)  # (heads, n, nq)
        joints, total = brute_force(arm, Q, goals)
        np.testing.assert_allclose(net(goals), joints, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.sum(), total.mean(), rtol=1e-9)
        # what the controller answers is what was scored
        np.testing.assert_allclose(goal_errors(arm, net, goals).mean(), f.sum(), rtol=1e-9)
        # the first proposal is the answer; each is no nearer than the one before, group by group
        P = proposals(net, goals)
        assert P.shape == (heads, len(goals), arm.nq) and np.array_equal(P[0], net(goals))
        back = controller_from_dict(json.loads(json.dumps(net.to_dict())))
        assert np.array_equal(back(goals), net(goals))
    with pytest.raises(ValueError, match="output offsets"):
        problem.wired_mse(G, wiring)


def test_a_tree_trains_with_heads_reproducibly_and_its_logged_error_is_the_controllers():
    arm = robots.load("g1")
    runs = [lab.evolve("g1", "cmaes", generations=4, population=8, seed=1, heads=2, **FAST) for _ in range(2)]
    a, b = runs
    assert a.controller.heads == 2 and a.controller.tree_heads.groups == [[0, 1], [2], [3]]
    assert np.array_equal(a.controller.weights, b.controller.weights)
    problem_goals = arm.sample_goals(FAST["targets"], seed=0)
    assert np.isclose(goal_errors(arm, a.controller, problem_goals).mean(), a.train_mse, rtol=1e-9)


def test_heads_on_a_tree_need_the_wiring():
    with pytest.raises(ValueError, match="wired per limb group"):
        lab.TrainConfig(robot="talos-legs", method="cmaes", heads=2, wiring=False)


def test_refinement_takes_each_limb_group_from_the_proposal_that_solves_it():
    """Proposal 0 puts the legs on the goal's own joints and the arms anywhere, proposal 1 the other
    way round: without the limbs' closed form neither alone is refined within tolerance in 3 steps,
    the two mixed by group are; with it, proposal 0 alone is."""
    arm = robots.load("g1")
    rng = np.random.default_rng(0)
    true = arm.lower + (arm.upper - arm.lower) * rng.random((30, arm.nq))
    goals = arm.reach(true)
    legs = np.unique(np.concatenate([arm.chain.path(e) for e in (2, 3)]))
    arms = np.setdiff1d(np.arange(arm.nq), legs)
    other = arm.lower + (arm.upper - arm.lower) * rng.random((30, arm.nq))
    p0, p1 = true.copy(), true.copy()
    p0[:, arms], p1[:, legs] = other[:, arms], other[:, legs]
    mixed = refine(arm, goals, np.stack([p0, p1]), steps=3, limbs=False)
    assert mixed.converged.all()
    assert refine(arm, goals, p0[None], steps=3, limbs=False).converged.mean() < 0.5
    assert refine(arm, goals, p1[None], steps=3, limbs=False).converged.mean() < 0.5
    assert refine(arm, goals, p0[None], steps=3).converged.all()
    np.testing.assert_allclose(np.linalg.norm(arm.reach(mixed.q) - goals, axis=-1).max(axis=1), mixed.error, atol=1e-9)
