"""The warm-up's plan and its estimates (lab/running/warmup.py), without compiling anything.

Checked: a run waits only for the kinematics and its own kernels (a UR5 run never for a tree's); the
opened robot's kernels come first; a spare compiling a step the run does not call is not the run's
worker; each estimate comes from this machine's stored figure for that step, scaled by the steps
done this time, and is no number at all where nothing was measured; a step that compiled stores its
figure for the next warm-up, one that loaded from the cache does not.
"""

from __future__ import annotations

import json

import pytest

import lab
import lab.running.worker as lab_worker
from lab.running import warmup


def keys(steps) -> list[str]:
    return [s.key for s in steps]


def test_a_ur5_run_waits_for_the_kinematics_and_its_own_kernels_never_a_trees():
    steps = warmup.plan(robot="planar")
    for config in (lab.TrainConfig.preset(robot="ur5"), lab.TrainConfig.preset(robot="ur5", seconds=30.0)):
        wanted = warmup.for_run(steps, set(), config)
        assert keys(wanted) == [warmup.KINEMATICS, warmup.run_key(config)]
        assert not any("tree" in k for k in keys(wanted)) and all("trees" not in s.label for s in wanted)
        assert [(s.index, s.steps) for s in wanted] == [(1, 2), (2, 2)]  # "step 2 of 2", not "of 10"
    tree = lab.TrainConfig.preset(robot="talos-legs")
    assert keys(warmup.for_run(steps, {warmup.KINEMATICS}, tree)) == [warmup.run_key(tree)]
    # done already: nothing to wait for
    planar = lab.TrainConfig.preset(robot="planar")
    assert warmup.for_run(steps, {warmup.KINEMATICS, warmup.run_key(planar)}, planar) == []


def test_a_run_whose_kernels_no_step_compiles_gets_a_step_of_its_own():
    config = lab.TrainConfig.preset(robot="planar", goal="position", hidden=7)  # same kernels as planar's
    steps = [s for s in warmup.plan(robot="planar") if s.key == warmup.KINEMATICS]
    wanted = warmup.for_run(steps, set(), config)
    assert keys(wanted) == [warmup.KINEMATICS, warmup.run_key(config)] and wanted[1].label == "CMA-ES for planar"


@pytest.mark.parametrize("robot", ["planar", "ur5", "g1"])
def test_the_opened_robots_kernels_come_right_after_the_kinematics(robot):
    steps = warmup.plan(robot=robot)
    first = lab.TrainConfig.preset(robot=robot)
    assert keys(steps)[:2] == [warmup.KINEMATICS, warmup.run_key(first)]
    assert len(set(keys(steps))) == len(steps)  # each key once
    assert [s.index for s in steps] == list(range(1, len(steps) + 1)) and {s.steps for s in steps} == {len(steps)}


def test_a_spare_compiling_what_the_run_does_not_call_is_not_its_worker():
    ur5 = lab.TrainConfig.preset(robot="ur5")
    tree = lab.TrainConfig.preset(robot="talos-legs")
    w = lab_worker.Warmup(pid=1)
    w.key, w.label, w.compiling = warmup.run_key(tree), "CMA-ES for trees of several end effectors", True
    assert lab_worker._busy_elsewhere(w, ur5)  # the UR5 run would wait on the tree's step
    assert not lab_worker._busy_elsewhere(w, tree)  # the tree's own: worth waiting for
    w.key = warmup.KINEMATICS
    assert not lab_worker._busy_elsewhere(w, ur5)  # every run calls the kinematics
    w.key, w.compiling = warmup.run_key(tree), False
    assert not lab_worker._busy_elsewhere(w, ur5)  # loading from the cache: milliseconds


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty numba cache folder of its own (the figures live beside it), on a machine as busy as
    when its figures were taken (busy() = 1: the load average of a shared box is no test's input)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(warmup, "busy", lambda: 1.0)
    return tmp_path


def test_the_estimates_come_from_this_machines_stored_figures_scaled_by_the_steps_done(cache):
    steps = {s.key: s for s in warmup.plan(robot="planar")}
    kin, cma = steps[warmup.KINEMATICS], steps["cmaes/arm/1/position"]
    assert warmup.figures_path() == str(cache / warmup.FIGURES)
    (cache / warmup.FIGURES).write_text(json.dumps({warmup.KINEMATICS: 4.0, "cmaes/arm/1/position": 30.0}))
    estimate = warmup.Estimate()
    assert estimate.seconds(kin) == 4.0 and estimate.seconds(cma) == 30.0
    estimate.finished(kin, 8.0, compiled=True)  # twice as slow as last time: a busier machine
    assert estimate.seconds(cma) == pytest.approx(60.0)
    # and stored for the next warm-up, with how busy the machine was
    stored = json.loads((cache / warmup.FIGURES).read_text())
    assert stored[warmup.KINEMATICS] == 8.0 and stored[warmup.LOADS] == {warmup.KINEMATICS: 1.0}


def test_before_a_long_step_is_done_the_estimates_follow_the_load(cache, monkeypatch):
    """A figure taken on a quiet machine, a machine three times busier now: three times the figure;
    a short step (mostly imports) does not yet scale them."""
    (cache / warmup.FIGURES).write_text(json.dumps({"cmaes/arm/1/position": 30.0, warmup.KINEMATICS: 2.0,
                                                    warmup.LOADS: {"cmaes/arm/1/position": 1.0}}))
    steps = {s.key: s for s in warmup.plan(robot="planar")}
    monkeypatch.setattr(warmup, "busy", lambda: 3.0)
    estimate = warmup.Estimate()
    assert estimate.seconds(steps["cmaes/arm/1/position"]) == pytest.approx(90.0)
    estimate.finished(steps[warmup.KINEMATICS], 3.0, compiled=True)  # 3 s: too short to tell
    assert estimate.seconds(steps["cmaes/arm/1/position"]) == pytest.approx(90.0)


def test_a_step_never_timed_here_has_no_estimate_until_a_step_is_done(cache):
    steps = {s.key: s for s in warmup.plan(robot="planar")}
    kin, cma = steps[warmup.KINEMATICS], steps["cmaes/arm/1/position"]
    estimate = warmup.Estimate()
    assert estimate.seconds(kin) is None and estimate.seconds(cma) is None  # no figure, nothing done: no number
    estimate.finished(kin, 4 * warmup.REFERENCE_SECONDS[warmup.KINEMATICS], compiled=True)  # 10 s: long enough
    compile_seconds = lab.methods.get("cmaes").compile_seconds[0]
    assert estimate.seconds(cma) == pytest.approx(4 * compile_seconds)  # the reference, scaled by this machine


def test_a_step_that_loaded_from_the_cache_changes_neither_the_scale_nor_the_figures(cache):
    (cache / warmup.FIGURES).write_text(json.dumps({warmup.KINEMATICS: 4.0, "cmaes/arm/1/position": 30.0}))
    steps = {s.key: s for s in warmup.plan(robot="planar")}
    estimate = warmup.Estimate()
    estimate.finished(steps[warmup.KINEMATICS], 0.05, compiled=False)
    assert estimate.seconds(steps["cmaes/arm/1/position"]) == 30.0
    assert warmup.stored_figures() == {warmup.KINEMATICS: 4.0, "cmaes/arm/1/position": 30.0}
    assert warmup.stored_loads() == {}


@pytest.mark.parametrize("text", ["not json", "[1, 2]", '{"kinematics": "soon", "x": -3}'])
def test_an_unreadable_figures_file_is_no_figure(cache, text):
    (cache / warmup.FIGURES).write_text(text)
    assert warmup.stored_figures() == {}
    warmup.store_figure(warmup.KINEMATICS, 3.0)  # and the next step writes a good one
    assert warmup.stored_figures() == {warmup.KINEMATICS: 3.0} and warmup.stored_loads() == {warmup.KINEMATICS: 1.0}


def test_a_spare_started_for_other_kernels_than_the_pages_first_start_is_started_again(monkeypatch):
    """python -m app starts the spare at once with the robot alone; the page's Start on a real arm has a
    time budget, which can change its kernels: the spare is started again for those."""
    spawned = []

    class Proc:
        def __init__(self):
            self.killed, self.warmup = False, lab_worker.Warmup(pid=0)

        def poll(self):
            return 1 if self.killed else None

        def kill(self):
            self.killed = True

        def wait(self):
            return 1

    def spawn(spare):
        spawned.append((lab_worker._first_robot, lab_worker._first_config))
        return Proc()

    monkeypatch.setattr(lab_worker, "_spawn", spawn)
    monkeypatch.setattr(lab_worker, "_keep_spare", lab_worker._keep_spare)  # as it was, after
    monkeypatch.setattr(lab_worker, "_spare", None)
    monkeypatch.setattr(lab_worker, "_first_robot", "planar")
    monkeypatch.setattr(lab_worker, "_first_config", None)
    lab_worker.prestart("ur5")
    first = lab_worker._spare
    budget = lab.TrainConfig.preset(robot="ur5", seconds=30.0)  # one head: not the UR5's defaults' two
    assert warmup.run_key(budget) != warmup.run_key(lab.TrainConfig.preset(robot="ur5"))
    lab_worker.prestart("ur5", first=budget)
    assert first.killed and first.warmup.abandoned and lab_worker._spare is not first  # its end is not told
    assert spawned == [("ur5", None), ("ur5", budget.to_dict())]
    lab_worker.prestart("ur5", first=budget)  # the same kernels: the spare stays
    assert len(spawned) == 2


def test_an_abandoned_spares_end_is_not_told_as_kernels_ready():
    import os
    import threading

    told = []

    def listen(w) -> None:
        told.append((w.abandoned, w.done))

    lab_worker.on_warmup(listen)
    try:
        for abandoned in (True, False):
            read, write = os.pipe()
            w = lab_worker.Warmup(pid=99)
            w.abandoned = abandoned
            t = threading.Thread(target=lab_worker._follow, args=(read, w))
            t.start()
            os.write(write, b"step 1 2 - kinematics forward kinematics\n")
            os.close(write)  # killed: no "done" line
            t.join(10)
            assert w.done
        assert [abandoned for abandoned, done in told if done] == [False]  # only the other one's end
    finally:
        lab_worker._listeners.remove(listen)
