"""NEAT-CMA (lab/methods/neat_cma.py): NEAT with its best networks' weights tuned by CMA-ES. A tuning
only ever improves a genome, writes back exactly the network it scored, spends the evaluations the
method declares, and the same seed gives the same run."""

import math

import numpy as np
import pytest

import lab
import robots
from lab import methods
from lab.methods.neat import genome_to_controller
from lab.running.runner import build_problem

METHOD = "neat_cma"


def backend_of(robot="ur5", **settings):
    config = lab.TrainConfig.preset(robot=robot, method=METHOD, **{"targets": 40, "test_goals": 50,
                                                                    "population": 20, **settings})
    problem = build_problem(config)
    return methods.get(METHOD).backend(problem, config), problem, config


def test_a_tuning_never_worsens_a_genome_and_writes_back_the_network_it_scored():
    backend, problem, _ = backend_of()
    seen = []
    tune = backend._tune

    def watched(genome, i, mse, batches):
        before = float(mse[i])
        changed = tune(genome, i, mse, batches)
        # the genome now holds the tuned weights: its network scores what the tuning found, and its
        # fitness says so (NEAT's selection reads it)
        controller = genome_to_controller(genome, backend.neat_config, problem.encoding)
        seen.append((before, float(mse[i]), changed, problem.controller_mse(controller), -genome.fitness))
        return changed

    backend._tune = watched
    for _ in range(6):
        backend.step()
    assert seen and any(changed for _, _, changed, _, _ in seen)
    for before, after, changed, scored, fitness in seen:
        assert after <= before or not math.isfinite(before)
        assert changed == (after < before)
        assert scored == pytest.approx(after, rel=1e-9) and fitness == pytest.approx(after, rel=1e-12)


def test_the_best_controller_scores_what_the_run_logged_and_the_seed_fixes_the_run():
    runs = [lab.evolve("ur5", METHOD, generations=8, population=20, targets=40, test_goals=50, seed=3)
            for _ in range(2)]
    a, b = runs
    assert np.array_equal(a.history, b.history) and a.train_mse == b.train_mse
    problem = build_problem(a.config)
    assert problem.controller_mse(a.controller) == pytest.approx(a.train_mse, rel=1e-9)
    other = lab.evolve("ur5", METHOD, generations=8, population=20, targets=40, test_goals=50, seed=4)
    assert not np.array_equal(other.history, a.history)


def test_every_generation_spends_the_declared_evaluations():
    backend, problem, config = backend_of(tune_networks=3, tune_evaluations=20, tune_population=8)
    per_step = methods.get(METHOD).evaluations_per_step(problem.arm, config)
    assert per_step == config.population + 3 * 3 * 8  # 20 evaluations are 3 whole CMA-ES generations of 8
    for _ in range(4):
        result = backend.step()
        assert result.evaluations == per_step and result.extras["tuned"] == per_step - config.population


def test_tuning_every_k_generations_and_the_defaults_per_arm():
    backend, _, config = backend_of(tune_every=3)
    tuned = [backend.step().extras.get("tuned", 0) for _ in range(6)]
    assert [t > 0 for t in tuned] == [True, False, False, True, False, False]
    neat = methods.get("neat").defaults(robots.load("ur5"))
    mine = methods.get(METHOD).defaults(robots.load("ur5"))
    # NEAT's real-arm settings, hidden nodes added more often; more goals on the UR5 alone
    assert mine == {**neat, "add_node": 0.1, "targets": 600}
    neat, mine = (methods.get(m).defaults(robots.load("panda")) for m in ("neat", METHOD))
    assert mine == {**neat, "add_node": 0.1}
    assert methods.get(METHOD).defaults(robots.load("planar")) == methods.get("neat").defaults(robots.load("planar"))


@pytest.mark.parametrize("name, value", [("tune_networks", 0), ("tune_population", 1), ("tune_every", 0),
                                         ("tune_sigma", 0.0), ("tune_evaluations", 2.5)])
def test_bad_tuning_settings_are_refused_by_name(name, value):
    with pytest.raises(ValueError, match=name):
        lab.TrainConfig(method=METHOD, **{name: value})


def test_a_controller_of_the_method_saves_and_reloads():
    run = lab.evolve("planar", METHOD, generations=5, population=12, seed=0)
    again = lab.controller_from_dict(run.controller.to_dict())
    goals = robots.load("planar").sample_goals(20, seed=1)
    assert np.array_equal(again(goals), run.controller(goals))
