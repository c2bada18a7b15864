"""Multi-hypothesis MLPs (TrainConfig.heads > 1): several output heads, the closest one answers.

The fitness counts, per goal, the smallest squared error over the heads; the controller answers
with that head; so the training MSE a run reports is the controller's own error on its goals."""

import json

import numpy as np
import pytest

import lab
import robots
from lab.problem import Problem, kernels
from lab.problem.controllers import MLPController, choose_heads, head_anchors, mlp_size, proposals
from lab.problem.encoding import Encoding
from lab.problem.fitness import goal_errors


@pytest.fixture(scope="module")
def so101():
    return robots.load("so101")


@pytest.fixture(scope="module")
def run(so101):
    return lab.evolve("so101", generations=60, population=12, targets=40, heads=2, seed=3)


def test_the_reported_training_mse_is_the_controllers_error_through_pinocchio(so101, run):
    c = run.controller
    assert c.heads == 2 and run.config.heads == 2
    problem = Problem(so101, Encoding.for_arm(so101, run.config.features, run.config.margin), targets=40)
    assert goal_errors(so101, c, problem.train_goals).mean() == pytest.approx(run.train_mse, rel=1e-9)


def test_the_fitness_is_the_mean_over_goals_of_the_best_head(so101):
    enc = Encoding.for_arm(so101, "reach")
    problem = Problem(so101, enc, targets=50)
    rng = np.random.default_rng(0)
    W = rng.normal(0, 0.5, (6, mlp_size(enc.n_inputs, 4, 2 * enc.n_outputs)))
    shape = MLPController(enc, 4, W[0], 2, None, so101.chain.arrays)
    got = problem.mlp_mse(W, 4, offsets=shape.offsets)
    for w, mse in zip(W, got):
        c = MLPController(enc, 4, w, 2, None, so101.chain.arrays)
        per_head = [np.sum((so101.reach(q) - problem.train_goals) ** 2, axis=1)
                    for q in enc.joints(c.head_outputs(problem.train_goals))]
        assert mse == pytest.approx(np.minimum(*per_head).mean(), rel=1e-9)
        assert np.array_equal(c.choose(problem.train_goals), np.argmin(per_head, axis=0))
    # one head with zero offsets is the paper's MLP, bit for bit
    W1 = W[:, : mlp_size(enc.n_inputs, 4, enc.n_outputs)]
    out = np.empty(len(W1))
    kernels.mlp_heads_mse(*problem._train, problem._axes, W1, 4, np.zeros(enc.n_outputs), problem._qmap,
                          problem._chain, out)
    assert np.array_equal(out, problem.mlp_mse(W1, 4))


def test_each_head_starts_at_its_anchor(so101):
    """With zero weights every head outputs its anchor: heads start on different branches."""
    enc = Encoding.for_arm(so101, "reach")
    anchors = head_anchors(enc, 3)
    c = MLPController(enc, 8, np.zeros(mlp_size(enc.n_inputs, 8, 3 * enc.n_outputs)), 3, None, so101.chain.arrays)
    q = enc.joints(c.head_outputs(so101.sample_goals(4, seed=1)))  # (heads, goals, nq)
    assert np.allclose(q, anchors[:, None, :])
    assert np.allclose(anchors[0], 0.5 * (so101.lower + so101.upper))  # head 0: the single-head start
    # head 1 leans back on every joint; head 2 leans forward with the base mid-range; head 3 is
    # head 1's mirror image in the base joint
    assert np.all(anchors[1] < anchors[0])
    assert anchors[2][0] == anchors[0][0] and np.all(anchors[2][1:] > anchors[0][1:])
    fourth = head_anchors(enc, 4)[3]
    assert fourth[0] - anchors[0][0] == pytest.approx(anchors[0][0] - anchors[1][0])
    assert np.array_equal(fourth[1:], anchors[1][1:])


def test_the_same_seed_gives_the_same_run(run):
    again = lab.evolve("so101", generations=60, population=12, targets=40, heads=2, seed=3)
    assert np.array_equal(again.controller.weights, run.controller.weights)
    assert again.train_mse == run.train_mse


def test_a_multi_head_controller_survives_its_dict_and_fits_only_its_arm(so101, run):
    from app.startup import made_for

    c = lab.controller_from_dict(json.loads(json.dumps(run.controller.to_dict())))
    goals = so101.sample_goals(30, seed=9)
    assert np.array_equal(c(goals), run.controller(goals))
    assert made_for(c, so101) and not made_for(c, robots.load("so100"))
    moved = c.to_dict()
    moved["chain"]["pos"][1][0] += 0.01  # the same joints and limits, another geometry
    assert not made_for(lab.controller_from_dict(moved), so101)


def test_a_population_of_multi_head_mlps_gives_each_ones_answer(so101, run):
    from lab.methods.base import population_joints

    enc = run.controller.encoding
    rng = np.random.default_rng(1)
    cs = [MLPController(enc, run.controller.hidden, rng.normal(0, 0.3, run.controller.n_params), 2,
                        run.controller.anchors, so101.chain.arrays) for _ in range(4)]
    goals = so101.sample_goals(7, seed=2)
    assert np.array_equal(population_joints(cs, goals), np.stack([c(goals) for c in cs]))


def test_choose_heads_ignores_a_head_that_gives_nan(so101):
    enc = Encoding.for_arm(so101, "reach")
    goals = so101.sample_goals(3, seed=4)
    q = np.stack([np.full((3, so101.nq), np.nan), so101.sample_q(3, seed=5)])
    assert np.array_equal(choose_heads(enc, so101.chain.arrays, q, goals), [1, 1, 1])


@pytest.mark.parametrize("method", ["neat", "gradient"])
def test_methods_with_single_head_networks_refuse_heads(method):
    with pytest.raises(ValueError, match=r"heads must be 1 for .* \(its networks have one head\), got 2"):
        lab.TrainConfig(robot="planar", method=method, heads=2)


def test_heads_are_checked_and_one_head_is_written_as_before():
    with pytest.raises(ValueError, match="heads"):
        lab.TrainConfig(robot="so101", heads=10)
    with pytest.raises(ValueError, match="heads"):
        lab.TrainConfig(robot="so101", heads=0)
    assert "heads" not in lab.TrainConfig(robot="planar").to_dict()
    d = lab.TrainConfig(robot="so101", heads=3).to_dict()
    assert d["heads"] == 3 and lab.TrainConfig.from_dict(d).heads == 3


def test_the_fitness_threads_change_nothing(monkeypatch):
    """Two heads on 40 x 120 goals split into two slices on two threads: the same run, bit for bit."""
    runs = []
    for n in ("1", "2"):
        monkeypatch.setenv("LAB_THREADS", n)
        runs.append(lab.evolve("so100", generations=15, population=40, targets=120, heads=2, seed=1))
    assert np.array_equal(runs[0].history, runs[1].history)
    assert np.array_equal(runs[0].controller.weights, runs[1].controller.weights)


def test_a_multi_head_controller_proposes_every_head_the_nearest_first(so101):
    """lab.problem.controllers.proposals: a multi-head MLP's heads, ordered by their seed error per
    goal (the first is the controller's own answer); a one-head controller's one answer."""
    arm = so101
    enc = Encoding.for_arm(arm, "reach")
    w = np.random.default_rng(4).normal(0, 0.3, mlp_size(enc.n_inputs, 6, 3 * enc.n_outputs))
    c = MLPController(enc, 6, w, 3, head_anchors(enc, 3), arm.chain.arrays)
    goals = arm.sample_goals(50, seed=5)
    P = proposals(c, goals)
    assert P.shape == (3, 50, arm.nq) and np.allclose(P[0], c(goals))
    err = np.linalg.norm(arm.reach(P.reshape(-1, arm.nq)).reshape(3, 50, 3) - goals, axis=2)
    assert np.all(np.diff(err, axis=0) >= -1e-12)
    heads = enc.joints(c.head_outputs(goals))
    assert np.allclose(np.sort(P, axis=0), np.sort(heads, axis=0))
    single = lab.evolve("planar", generations=2, population=6, seed=0).controller
    g = robots.load("planar").sample_goals(5, seed=1)
    assert np.array_equal(proposals(single, g), single(g)[None])
