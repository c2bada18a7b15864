"""A run with a time budget (TrainConfig.seconds): it ends when its optimizer time reaches
the budget, state "finished", with its best controller; generations and seconds: whichever comes first;
pauses do not count; the config, lab.evolve, `python -m lab train --seconds`, the methods' hook for
budget defaults, the classroom bounds and the app's "Time budget (s)" field."""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import pytest

import lab
import robots
from app.classroom.limits import CLASSROOM, refusal
from conftest import wait_until
from lab import methods
from lab.running.config import UNBOUNDED

SMALL = dict(robot="planar", population=8, targets=10, test_goals=10)


class Events:
    def __init__(self):
        self.events = []

    def __call__(self, event):
        self.events.append(event)


def test_a_budget_ends_the_run_finished_after_the_generation_that_spends_it():
    runner = lab.Runner(lab.TrainConfig(seconds=1.0, **SMALL))
    seen = Events()
    runner.subscribe(seen)
    s = runner.run()
    assert s.state == "finished" and s.ended_by == "seconds" and s.controller is not None
    assert runner.config.generations == UNBOUNDED and s.generations == len(seen.events) < UNBOUNDED
    # ended because of the budget: the generation before it was under it, the last one reached it
    assert seen.events[-2].seconds < 1.0 <= seen.events[-1].seconds == s.seconds
    assert np.isfinite(s.train_mse) and s.train_mse == pytest.approx(s.history[-1], rel=0, abs=1e-9)
    assert seen.events[-1].population is not None and seen.events[-1].population.controllers is not None


def test_generations_or_seconds_whichever_comes_first():
    few = lab.Runner(lab.TrainConfig(generations=5, seconds=60.0, **SMALL)).run()
    assert few.state == "finished" and few.ended_by == "generations" and few.generations == 5 and few.seconds < 60
    many = lab.Runner(lab.TrainConfig(generations=10**6, seconds=0.3, **SMALL)).run()
    assert many.state == "finished" and many.ended_by == "seconds" and many.generations < 10**6
    assert many.seconds >= 0.3
    plain = lab.Runner(lab.TrainConfig(generations=5, **SMALL)).run()
    assert plain.ended_by == "generations"


def test_a_pause_does_not_count_against_the_budget():
    runner = lab.Runner(lab.TrainConfig(seconds=1.0, **SMALL))
    paused_at = []

    def pause_midway(event):  # from the run's own thread, once half the budget is spent
        if not paused_at and event.seconds >= 0.5:
            paused_at.append(event.index)
            runner.pause()

    runner.subscribe(pause_midway)
    t0 = time.monotonic()
    runner.start()
    try:
        assert wait_until(lambda: runner.holding is not None)
        time.sleep(1.0)  # longer than the budget left: optimizer time, not wall time, counts
        assert runner.state == "paused" and not runner.done
        assert runner.snapshot().generation == paused_at[0] + 1
        runner.resume()
        s = runner.join(30)
    finally:
        runner.stop(timeout=5)
    assert s.state == "finished" and s.ended_by == "seconds" and s.generations > paused_at[0] + 1
    assert 1.0 <= s.seconds and time.monotonic() - t0 >= s.seconds + 1.0


def test_a_stopped_budgeted_run_is_stopped_not_finished():
    runner = lab.Runner(lab.TrainConfig(seconds=60.0, **SMALL)).start()
    assert wait_until(lambda: runner.snapshot().generation >= 3)
    runner.stop()
    s = runner.join(5)
    assert s.state == "stopped" and s.ended_by is None


def test_a_budget_in_a_worker_process():
    s = lab.ProcessRunner(lab.TrainConfig(seconds=0.3, **SMALL)).run()
    assert s.state == "finished" and s.ended_by == "seconds" and s.seconds >= 0.3 and s.controller is not None


def test_evolve_with_a_budget():
    run = lab.evolve("planar", seconds=0.3, population=8, targets=10, test_goals=10)
    assert run.state == "finished" and run.seconds >= 0.3 and run.config.seconds == 0.3
    assert run.config.generations == UNBOUNDED and 0 < len(run.history) < UNBOUNDED
    assert run.controller(robots.load("planar").sample_goals(3, seed=1)).shape == (3, 3)


def test_the_budget_is_carried_to_and_from_dict():
    config = lab.TrainConfig.preset(robot="ur5", seconds=30)
    d = json.loads(json.dumps(config.to_dict()))
    assert d["seconds"] == 30.0 and d["generations"] == UNBOUNDED
    assert lab.TrainConfig.from_dict(d) == config and config.replace(seed=3).seconds == 30.0
    old = lab.TrainConfig.preset(robot="ur5").to_dict()
    assert "seconds" not in old  # no budget: written as before budgets existed
    assert lab.TrainConfig.from_dict(old).seconds is None
    # with generations given, the budget does not change them
    assert lab.TrainConfig.preset(robot="ur5", seconds=30, generations=500).generations == 500


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "30", True, [30]])
def test_a_bad_budget_is_refused_by_name(bad):
    with pytest.raises(ValueError, match="seconds must be a positive finite number"):
        lab.TrainConfig(robot="planar", seconds=bad)


@pytest.mark.parametrize("method", lab.methods.names())
def test_budget_defaults_leave_todays_defaults_alone_and_fit_every_arm(method):
    for robot in robots.names():
        plain, budgeted = lab.TrainConfig.preset(robot=robot, method=method), \
            lab.TrainConfig.preset(robot=robot, method=method, seconds=45)
        m, arm = methods.get(method), robots.load(robot)
        assert m.defaults_for(arm) == dict(m.defaults(arm))  # no budget: the defaults as they were
        assert budgeted.seconds == 45.0 and budgeted.generations <= UNBOUNDED
        assert refusal(budgeted, CLASSROOM) is None, (robot, method)
        assert plain.seconds is None


def test_a_method_chooses_its_schedule_from_the_budget():
    """Method.budget_defaults(arm, seconds): TrainConfig.preset uses it when a budget is given."""
    base = methods.get("cmaes")
    seen = []

    def budget_defaults(arm, seconds):
        seen.append((arm.name, seconds))
        return {**base.defaults(arm), "population": 10 + int(seconds), "sigma0": 0.3,
                **({"generations": 7} if seconds < 2 else {})}

    methods.register(dataclasses.replace(base, name="cmaesbudget", budget_defaults=budget_defaults))
    try:
        c = lab.TrainConfig.preset(robot="planar", method="cmaesbudget", seconds=5)
        assert (c.population, c.sigma0, c.generations) == (15, 0.3, UNBOUNDED) and seen[-1] == ("planar", 5.0)
        short = lab.TrainConfig.preset(robot="planar", method="cmaesbudget", seconds=1)
        assert short.generations == 7  # the method's generations bound the run besides the budget
        assert lab.TrainConfig.preset(robot="planar", method="cmaesbudget", seconds=5, population=9).population == 9
        plain = lab.TrainConfig.preset(robot="planar", method="cmaesbudget")
        assert (plain.population, plain.sigma0, plain.generations) == (50, base.options().sigma0, 1000)
        # a method without the hook: its defaults less their generations
        methods.register(dataclasses.replace(base, name="cmaesplain", budget_defaults=None))
        assert lab.TrainConfig.preset(robot="planar", method="cmaesplain", seconds=5).generations == UNBOUNDED
        assert lab.TrainConfig.preset(robot="planar", method="cmaesplain", seconds=5).population == 50
    finally:
        methods.unregister("cmaesbudget")
        if "cmaesplain" in methods.names():
            methods.unregister("cmaesplain")


def test_python_m_lab_train_seconds(capsys):
    from lab.__main__ import main

    assert main(["train", "--seconds", "0.5", "--population", "8", "--targets", "10", "--test-goals", "10",
                 "--no-recording", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "(budget 0.5 s, spent)" in out and "held-out MSE" in out
    assert main(["train", "--seconds", "-1", "--no-recording", "--quiet"]) == 2
    assert "seconds must be a positive" in capsys.readouterr().err


def test_a_shared_server_bounds_the_budget_not_the_generations_of_a_budgeted_run():
    assert refusal(lab.TrainConfig.preset(robot="ur5", seconds=600), CLASSROOM) is None
    why = refusal(lab.TrainConfig.preset(robot="ur5", seconds=601), CLASSROOM)
    assert "Time budget (s)" in why and "at most 600" in why and "--limit seconds=N" in why
    assert "generations" in refusal(lab.TrainConfig.preset(robot="planar", generations=10**6), CLASSROOM)


def test_the_panels_time_budget_starts_a_budgeted_run(app):
    panel, state = app.panel, app.state
    before = panel.generations.value
    try:
        panel.budget.value = -3.0  # refused by name, put back
        assert panel.budget.value == 0 and "time budget" in panel.message.content.lower()
        panel.budget.value = 1.0  # the method's defaults for a budget: generations unbounded
        assert panel.generations.value == UNBOUNDED and panel.config().seconds == 1.0
        panel.population.value = 20.0
        panel.race.enabled.value = True  # a race partner gets the same budget
        assert panel.race.config(panel.config()).seconds == 1.0
        panel.race.enabled.value = False
        assert panel.start() is None
        assert wait_until(lambda: state.runner.state == "running" and state.progress()["generation"] > 2)
        panel.refresh(force=True)
        assert "s of 1 s left" in panel.status.content and f"/ {UNBOUNDED}" not in panel.status.content
        assert wait_until(lambda: state.runner.done, timeout=60)
        assert state.runner.state == "finished" and state.runner.join().ended_by == "seconds"
        assert wait_until(lambda: state.notebook.entries() and
                          state.notebook.entries()[-1]["run_id"] == state.runner.run_id)
        entry = state.notebook.entries()[-1]
        assert entry["state"] == "finished" and entry["settings"]["seconds"] == 1.0 and entry["seconds"] >= 1.0
        panel.refresh(force=True)
        status = panel.status.content  # an ended run says so and the time it used, not the time left
        assert status.startswith("**Finished**") and "of its 1 s" in status and "left" not in status, status
        assert panel.progress_bar.value == 100.0
        panel.budget.value = 0.0  # no budget: the defaults without one again
        assert panel.generations.value == before and panel.config().seconds is None
    finally:
        state.reset()
        panel.budget.value = 0.0
        panel.population.value, panel.generations.value = 50.0, before


def test_a_recording_holds_the_budget(tmp_path):
    runner = lab.Runner(lab.TrainConfig(seconds=0.3, **SMALL))
    logger = lab.RerunLogger(runner, path=tmp_path / "budget.rrd")
    runner.subscribe(logger)
    s = runner.run()
    logger.close(wait=True)
    rec = lab.read_recording(tmp_path / "budget.rrd")
    config = rec.protocol["config"]
    assert config["seconds"] == 0.3 and config["generations"] == UNBOUNDED
    assert len(rec.generations) == s.generations and s.ended_by == "seconds"


def test_expected_quotes_the_largest_measured_budget_within_the_run(tmp_path):
    """lab.experiments.budgets: a run of S s is quoted the figure of the largest budget measured
    not above S (never more time than it has), the smallest one below them all; written whole."""
    from lab.experiments import budgets

    path = str(tmp_path / "budgets.json")
    rows = [dict(robot="ur5", method="neat", seconds=s, median_pct=p, median_mm=10 * p, generations=1)
            for s, p in ((10.0, 30.0), (60.0, 12.0), (300.0, 8.0))]
    budgets.write(rows + [dict(robot="ur5", method="cmaes", seconds=60.0, error="boom")], "here", "2026-12-04", path)
    assert budgets.expected("ur5", "neat", 59, path)["median_pct"] == 30.0
    assert budgets.expected("ur5", "neat", 60, path)["median_pct"] == 12.0
    assert budgets.expected("ur5", "neat", None, path)["median_pct"] == 8.0
    assert budgets.expected("ur5", "neat", 5, path)["seconds"] == 10.0
    assert budgets.expected("ur5", "cmaes", 60, path) is None  # a failed run is not a figure
    budgets.write([dict(robot="ur5", method="cmaes", seconds=60.0, median_pct=0.5, median_mm=5.0)], "here", "d", path)
    assert budgets.expected("ur5", "neat", 60, path)["median_pct"] == 12.0  # merged, not replaced
    with open(path, "w") as f:
        f.write("[1, 2]")
    budgets._measured.cache_clear()
    with pytest.raises(ValueError, match="not a budgets file"):
        budgets.expected("ur5", "neat", 60, path)
    budgets._measured.cache_clear()


def test_budget_defaults_on_a_real_arm_turn_the_first_joint_for_every_method():
    """With a time budget, every method's real-arm defaults turn the first joint in closed form;
    the paper's arms keep their defaults."""
    import robots
    from lab import methods

    for name in ("ur5", "so101"):
        for method in methods.names():
            config = lab.TrainConfig(robot=name, method=method, seconds=30)
            assert config.turn, (name, method)
    assert not lab.TrainConfig(robot="planar", seconds=30).turn
    assert robots.kind("ur5") == "real"
