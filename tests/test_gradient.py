"""The gradient method: its gradient is the fitness's, it descends, it is reproducible."""

import json

import numpy as np
import pytest

import lab
import robots
from lab import methods
from lab.problem import Encoding, Problem
from lab.problem.controllers import mlp_size


def central_differences_of_the_fitness(problem, w, hidden, h=1e-6):
    """d mlp_mse / d w by central differences of the fitness kernel every method is scored by."""
    E = np.eye(w.size) * h
    return (problem.mlp_mse(w + E, hidden) - problem.mlp_mse(w - E, hidden)) / (2 * h)


@pytest.mark.parametrize("robot", ["planar", "scara", "ur5"])
@pytest.mark.parametrize("margin", [0.0, 0.5])
def test_the_gradient_is_the_fitness_gradient(robot, margin):
    """Backpropagation through the tanh layers, the clipped output mapping and the arm's Jacobian
    equals finite differences of problem.mlp_mse; its loss equals the fitness to rounding."""
    arm = robots.load(robot)
    problem = Problem(arm, Encoding.for_arm(arm, "reach", margin), targets=40, test_goals=10)
    enc = problem.encoding
    rng = np.random.default_rng(3)
    for hidden in (3, 6):
        w = rng.normal(0, 0.5, mlp_size(enc.n_inputs, hidden, enc.n_outputs))
        mse, g = problem.mlp_gradient(w, hidden)
        assert mse == pytest.approx(problem.mlp_mse(w[None], hidden)[0], rel=1e-13)
        fd = central_differences_of_the_fitness(problem, w, hidden)
        np.testing.assert_allclose(g, fd, rtol=0, atol=1e-6 * np.abs(g).max())
        assert np.abs(g).max() > 0


def test_a_clipped_output_passes_no_gradient():
    """Weights that throw joint 1's output far past its limit for every goal (margin 2): its
    output weights get no gradient, the others do."""
    arm = robots.load("planar")
    problem = Problem(arm, Encoding.for_arm(arm, "reach", 2.0), targets=30, test_goals=10)
    enc, hidden = problem.encoding, 4
    w = np.random.default_rng(0).normal(0, 0.3, mlp_size(enc.n_inputs, hidden, enc.n_outputs))
    w_o = w[(enc.n_inputs + 1) * hidden:].reshape(hidden, enc.n_outputs)
    w_o[:, 0] = 0.0
    w_o[0, 0] = 50.0
    w[(enc.n_inputs + 1) * hidden - hidden + 0] = 10.0  # hidden unit 0's bias: tanh = 1 on every goal
    _, g = problem.mlp_gradient(w, hidden)
    g_o = g[(enc.n_inputs + 1) * hidden:].reshape(hidden, enc.n_outputs)
    assert np.all(g_o[:, 0] == 0) and np.abs(g_o[:, 1:]).max() > 0


def test_loss_decreases_on_planar_over_200_steps():
    run = lab.evolve("planar", "gradient", generations=200, seed=0, test_goals=100)
    h = np.asarray(run.history)
    assert h[-1] < 0.1 * h[0], (h[0], h[-1])
    assert np.all(np.diff(h) <= 0)  # the best so far never gets worse
    # and the steps themselves go down overall: the last 20 steps' losses are below the first 20's
    backend = methods.make_backend(Problem(robots.load("planar"), Encoding.for_arm(robots.load("planar"), "reach", 2.0),
                                           test_goals=10), lab.TrainConfig(method="gradient", generations=200))
    losses = [backend.step().fitness[0] for _ in range(200)]
    assert max(losses[-20:]) < min(losses[:20])


def test_same_seed_same_run_other_seed_other_run():
    a = lab.evolve("scara", "gradient", generations=60, seed=4, targets=30, test_goals=50)
    b = lab.evolve("scara", "gradient", generations=60, seed=4, targets=30, test_goals=50)
    c = lab.evolve("scara", "gradient", generations=60, seed=5, targets=30, test_goals=50)
    assert [x.hex() for x in a.history] == [x.hex() for x in b.history]
    np.testing.assert_array_equal(a.controller.weights, b.controller.weights)
    assert not np.array_equal(a.history, c.history)


def test_steps_report_the_loss_gradient_norm_rate_and_evaluations():
    arm = robots.load("ur5")
    config = lab.TrainConfig(robot="ur5", method="gradient", generations=10, targets=20, hidden=4, test_goals=10)
    problem = Problem(arm, Encoding.for_arm(arm, config.features, config.margin), targets=20, test_goals=10)
    backend = methods.make_backend(problem, config)
    w0 = backend.w.copy()
    r = backend.step()
    assert r.fitness.shape == (1,) and r.fitness[0] == problem.mlp_mse(w0[None], 4)[0]
    assert r.extras["gradient_norm"] == pytest.approx(np.linalg.norm(problem.mlp_gradient(w0, 4)[1]))
    assert r.extras["learning_rate"] == config.learning_rate  # cosine decay starts at the full rate
    assert r.evaluations == 1 + arm.nq and backend.evaluations == 1 + arm.nq
    np.testing.assert_array_equal(backend.best.weights, w0)  # the weights the step was scored on
    for _ in range(9):
        r = backend.step()
    assert r.extras["learning_rate"] == pytest.approx(config.learning_rate * config.final_rate)


def test_config_round_trips_and_options_are_checked():
    config = lab.TrainConfig(robot="planar", method="gradient", learning_rate=0.02, beta1=0.8, final_rate=1.0)
    assert lab.TrainConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    assert config.options.learning_rate == 0.02 and config.margin == 2.0 and config.generations == 3000
    assert lab.TrainConfig(robot="ur5", method="gradient").margin == 0.0  # real arms: their defaults
    for bad in (dict(learning_rate=0), dict(beta1=1.0), dict(beta2=-0.1), dict(final_rate=1.5), dict(init_scale=0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            lab.TrainConfig(method="gradient", **bad)
