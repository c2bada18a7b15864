"""A presenter's Start on a tree, as an audience sees it: a run that ends worse than the controller
it replaced gives the arms back to that controller, and says so; the status says the pace the robot
allows when it is not the Speed menu's; the scene draws a few hundred of the training goals, the run
trains on all of them. No browser, no viser."""

from __future__ import annotations

import types

import numpy as np
import pytest

import lab
import robots
from app.startup import load_pretrained
from app.tab.scene import MAX_GOAL_DOTS, shown_goals
from app.training import state as state_module
from app.training.notebook import Notebook
from lab.running.runner import build_problem


class FakeRunner:
    """A ProcessRunner that runs nothing (the state's bookkeeping only)."""

    def __init__(self, config, **_kw):
        self.config, self.state, self.run_id = config, "running", "fake00"

    def subscribe(self, _f):
        pass

    def set_speed(self, _s):
        pass

    def start(self):
        return self

    def snapshot(self):
        return types.SimpleNamespace(controller=None, generation=0)


@pytest.fixture
def g1_state(tmp_path, monkeypatch):
    monkeypatch.setattr(state_module, "ProcessRunner", FakeRunner)
    state = state_module.LabState("g1", Notebook(str(tmp_path / "nb.db")), startups=lambda robot: load_pretrained(robot))
    config = lab.TrainConfig.preset(robot="g1", seconds=30.0)
    assert state.start(config) is None
    return state, config


def ended(config, controller, test_mse):
    return types.SimpleNamespace(config=config, controller=controller, state="finished", test_mse=test_mse,
                                 run_id="fake00")


def test_a_tree_run_that_ends_worse_gives_the_arms_back_to_the_controller_it_replaced(g1_state):
    state, config = g1_state
    shipped, source = state._replaced
    assert source.startswith("shipped") or "median" in source, source
    # the run's own controller was shown as it trained; it ends far worse than the shipped network
    state.show(lab.controller_from_dict(shipped.to_dict()), "run fake00, generation 90")
    problem = build_problem(config)
    before = problem.controller_mse(shipped, problem.test_goals)
    assert state.kept_the_better(state.runner, ended(config, object(), 10 * before))
    assert state.shown.controller is shipped and state.shown.source == source
    assert "worse than the controller it replaced" in state.notice and f"{before:.3g}" in state.notice


def test_a_tree_run_that_ends_better_keeps_its_own_controller(g1_state):
    state, config = g1_state
    mine = object()
    state.show(state._replaced[0], "run fake00, generation 90")
    shown = state.shown
    assert not state.kept_the_better(state.runner, ended(config, mine, 0.0))
    assert state.shown is shown and state.notice is None


def test_a_run_reset_away_leaves_the_arms_alone(g1_state):
    state, config = g1_state
    runner = state.runner
    state.runner = None  # reset (the next Start, another robot)
    assert not state.kept_the_better(runner, ended(config, object(), 1e9))


def test_a_serial_arms_run_is_its_own(tmp_path, monkeypatch):
    """Only a tree's run is measured against what it replaced: a student's planar run shows its own result."""
    monkeypatch.setattr(state_module, "ProcessRunner", FakeRunner)
    state = state_module.LabState("planar", Notebook(str(tmp_path / "nb.db")),
                                  startups=lambda robot: load_pretrained(robot))
    assert state.start(lab.TrainConfig.preset(robot="planar")) is None
    assert state._replaced is None


@pytest.mark.parametrize("robot, effectors", [("g1", 4), ("talos-legs", 2), ("ur5", 1)])
def test_the_scene_draws_a_few_hundred_goal_dots_of_all_the_training_goals(robot, effectors):
    arm = robots.load(robot)
    config = lab.TrainConfig.preset(robot=robot, seconds=30.0)
    goals = arm.to_3d(arm.sample_goals(config.targets, seed=config.goal_seed)).reshape(-1, 3)
    assert len(goals) == config.targets * effectors  # what the run trains on: every goal
    dots = shown_goals(goals, effectors)
    assert len(dots) <= MAX_GOAL_DOTS and len(dots) % effectors == 0
    if len(goals) <= MAX_GOAL_DOTS:
        assert np.array_equal(dots, goals)
    else:  # whole goals, every effector's dot of each, spread over all of them
        kept = dots.reshape(-1, effectors, 3)
        by_goal = goals.reshape(-1, effectors, 3)
        index = [int(np.flatnonzero((by_goal == g).all(axis=(1, 2)))[0]) for g in kept]
        assert index == sorted(index) and index[0] == 0 and index[-1] == len(by_goal) - 1
        assert len(kept) >= MAX_GOAL_DOTS // effectors - 1


def test_the_status_says_the_pace_the_robot_allows():
    from app.panels.train import TrainingPanel

    panel = types.SimpleNamespace(state=types.SimpleNamespace(speed=20.0, arm=robots.load("g1")))
    p = dict(state="running", generation=40, generations_per_s=3.1, budget=None)
    assert TrainingPanel.pace(panel, p) == ", 3.1 generations/s: all g1 allows here (Speed caps at 20)"
    assert "time budget" in TrainingPanel.pace(panel, {**p, "budget": 30.0})
    assert TrainingPanel.pace(panel, {**p, "generations_per_s": 19.5}) == ""  # at its cap: Speed says it
    assert TrainingPanel.pace(panel, {**p, "state": "finished"}) == ""


def test_the_apps_scene_draws_the_thinned_dots_of_a_humanoids_goals(tmp_path):
    from conftest import make_app

    app = make_app(tmp_path, robot="g1", startup=None)
    try:
        config = lab.TrainConfig.preset(robot="g1")
        assert len(app.training_goals()) == config.targets * 4  # a Start trains on all of them
        assert len(app.goal_dots.points) <= MAX_GOAL_DOTS
        assert f"over {config.targets:,} fixed goals ({MAX_GOAL_DOTS // 4} of them in red)" in \
            __import__("app.tab.goals", fromlist=["about"]).about(app.state.arm, config)
    finally:
        app.stop()
