"""Watching evolution: Step (exactly one generation), the speed cap, every method's population
(its candidates' reach, training error and species) and the rule for which generations keep one."""

from __future__ import annotations

import time

import numpy as np
import pytest

import lab
from conftest import METHODS, wait_until as wait_for
from lab import methods
from lab.recording.population import display_goal, population_logged
from lab.running.runner import POPULATION_PERIOD


def config(method="cmaes", **changes):
    m = methods.get(method)
    base = dict(method=method, generations=100_000, population=max(m.min_population, 20), targets=20, test_goals=20)
    return lab.TrainConfig(**{**base, **changes})



def settled(count, quiet=0.4, timeout=10.0) -> int:
    """count() once it has not changed for `quiet` seconds."""
    last, since, t0 = count(), time.monotonic(), time.monotonic()
    while time.monotonic() - since < quiet and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
        now = count()
        if now != last:
            last, since = now, time.monotonic()
    return last


@pytest.mark.parametrize("where", ["thread", "process"])
def test_each_step_is_exactly_one_more_generation(where):
    from lab.running.worker import ProcessRunner

    r = (lab.Runner if where == "thread" else ProcessRunner)(config())
    seen = []
    r.subscribe(lambda e: seen.append(e.index))
    r.start()
    try:
        assert wait_for(lambda: len(seen) >= 3, 30)
        assert not r.step(), "Step is for a paused run"
        r.pause()
        assert wait_for(lambda: r.holding is not None)  # said once every generation before it is out
        g0 = r.holding
        assert len(seen) == g0
        for k in range(1, 4):
            assert r.step()
            assert wait_for(lambda: r.holding == g0 + k)
            assert len(seen) == g0 + k
        for _ in range(5):  # clicks in a burst: as many generations, no more
            r.step()
        assert wait_for(lambda: r.holding == g0 + 8)
        assert settled(lambda: len(seen)) == g0 + 8
        assert seen == list(range(g0 + 8)) and r.state == "paused"
        r.resume()
        assert wait_for(lambda: len(seen) > g0 + 20)
    finally:
        r.stop(timeout=10)
    assert r.join(10).state == "stopped"


def test_the_speed_cap_holds_generations_per_second_and_unlimited_lifts_it():
    r = lab.Runner(config())
    stamps = []
    r.subscribe(lambda e: stamps.append(time.perf_counter()))
    r.set_speed(10)
    r.start()
    try:
        assert wait_for(lambda: len(stamps) >= 2)
        time.sleep(1.5)
        t = np.array(stamps)
        rate = (len(t) - 1) / (t[-1] - t[0])
        assert 7 <= rate <= 10.5, rate
        r.set_speed(None)
        n = len(stamps)
        time.sleep(0.5)
        assert len(stamps) - n > 25  # uncapped: hundreds a second on a quiet machine
        for bad in (0, -1, float("nan"), "fast"):
            with pytest.raises(ValueError, match="speed"):
                r.set_speed(bad)
    finally:
        r.stop()


def test_the_population_logging_rule():
    logged = [g for g in range(300) if population_logged(g)]
    assert logged == list(range(100)) + list(range(100, 300, 10))
    assert sum(population_logged(g) for g in range(40_000)) == 100 + 3990


@pytest.mark.parametrize("method", METHODS)
def test_every_method_shows_its_population(method):
    """Each candidate's reach is its own controller's, its MSE the step's fitness; species where a
    method has them; asking for the population changes no run."""
    cfg = config(method, generations=12, seed=2)
    r = lab.Runner(cfg)
    events = []
    r.subscribe(events.append)
    summary = r.run()
    plain = lab.Runner(cfg).run()  # no subscriber: no population asked for
    assert np.array_equal(summary.history, plain.history)
    arm = r.problem.arm
    goals = arm.sample_goals(3, seed=5)
    for e in events:
        pop = e.population
        assert pop is not None and pop.generation == e.index  # every one of the first 100
        assert pop.mse.min() == e.gen_best
        assert pop.points.shape == (len(pop), 3)
    last = events[-1].population  # the last generation goes out with its controllers
    assert last.controllers is not None and len(last.controllers) == len(last.mse)
    reach = last.reach(arm, goals)
    for k, c in enumerate(last.controllers):
        assert np.allclose(reach[k], arm.fk(c(goals)), atol=1e-9)
        assert np.isclose(r.problem.controller_mse(c), last.mse[k], rtol=1e-9)
    assert np.allclose(last.points, last.reach(arm, display_goal(arm)[None])[:, 0], atol=1e-4)
    if methods.get(method).controller == "graph":
        sizes = events[-1].extras["species_sizes"]
        assert last.species is not None
        assert dict(zip(*np.unique(last.species, return_counts=True))) == sizes


def test_populations_go_through_the_pipe_at_a_bounded_rate():
    from lab.running.worker import ProcessRunner

    r = ProcessRunner(config(generations=2000))
    events = []
    r.subscribe(events.append)
    t0 = time.perf_counter()
    summary = r.run()
    seconds = time.perf_counter() - t0
    assert summary.state == "finished"
    pops = [e.population for e in events]
    assert [e.index for e, p in zip(events, pops) if p is not None and p.controllers is None] == \
        [g for g in range(2000) if population_logged(g) and pops[g].controllers is None]
    with_controllers = sum(p is not None and p.controllers is not None for p in pops)
    assert 1 <= with_controllers <= seconds / POPULATION_PERIOD + 3
    assert pops[-1].controllers is not None


def test_a_recording_keeps_the_populations_of_the_logging_rule(tmp_path):
    """Every generation up to 100, then every 10th: each candidate's MSE, species and point at the
    display goal, read back as the run sent them."""
    from lab.recording.logger import RerunLogger
    from lab.recording.replay import read_recording

    r = lab.Runner(config("neat", generations=160))
    events = []
    logger = RerunLogger(r, path=tmp_path / "run.rrd")
    r.subscribe(logger)
    r.subscribe(events.append)
    r.run()
    logger.wait()
    rec = read_recording(tmp_path / "run.rrd")
    assert [g for g, _ in rec.populations] == [g for g in range(160) if population_logged(g)]
    for g in (0, 57, 99, 100, 150):
        sent, read = events[g].population, rec.population_at(g + 5 if g >= 100 else g)
        assert read.generation == g
        assert np.array_equal(read.mse, sent.mse) and np.array_equal(read.species, sent.species)
        assert np.array_equal(read.points, sent.points)
