"""Bounded growth of the app over long runs: the MSE history the app and its runner keep is
bounded (lab.running.history.History), spread over the whole run, with the latest generation."""

from __future__ import annotations

import numpy as np
import pytest

import lab
from lab.running.history import History


def test_an_unbounded_history_keeps_every_generation():
    h = History()
    for g in range(1000):
        h.append(1.0 / (g + 1), 2.0 / (g + 1))
    gens, best, median = h.arrays()
    assert len(h) == 1000 and gens.tolist() == list(range(1000)) and best[-1] == 1 / 1000 and median[0] == 2


@pytest.mark.parametrize("n", [1, 4095, 4096, 4097, 10_000, 1_000_003])
def test_a_bounded_history_keeps_at_most_its_limit_spread_over_the_run_and_the_latest(n):
    h = History(4096)
    for g in range(n):
        h.append(float(g), float(-g))
    gens, best, median = h.arrays()
    assert len(h) == n and len(gens) <= 4097
    assert gens[0] == 0 and gens[-1] == n - 1 and best[-1] == n - 1 and median[-1] == -(n - 1)
    assert np.all(np.diff(gens) > 0) and np.array_equal(best, gens.astype(float))
    if n <= 4096:
        assert gens.tolist() == list(range(n))
    else:
        assert len(gens) >= 2048  # never fewer than half the limit
        assert np.diff(gens[:-1]).max() == h.stride  # evenly spread


def test_the_apps_state_keeps_a_bounded_history_of_a_long_run():
    from app.training.state import HISTORY_POINTS, LabState

    state = LabState("planar")

    class Fake:
        run_id, config, state = "f" * 12, lab.TrainConfig.preset(robot="planar", generations=10**6), "running"

    state.runner = fake = Fake()
    for g in range(50_000):
        state._on_generation(fake, lab.GenerationEvent(run_id="f", index=g, best=1.0 / (g + 1), gen_best=1.0, median=2.0, worst=3.0,
                                                         evaluations=50 * (g + 1), seconds=0.001 * g, improved=False,
                                                         controller=None))
    p = state.progress()
    assert p["generation"] == 50_000 and len(p["best"]) <= HISTORY_POINTS + 1
    assert p["generations"][-1] == 50_000 and p["best"][-1] == pytest.approx(1 / 50_000)


def test_a_process_runner_with_a_bounded_history_bounds_its_worker_s_too():
    from lab.running.worker import ProcessRunner

    config = lab.TrainConfig.preset(robot="planar", generations=600, population=6, targets=10, test_goals=10)
    runner = ProcessRunner(config, history_limit=64)
    summary = runner.run()
    assert summary.state == "finished" and summary.generations == 600
    assert len(summary.history) <= 65 and len(summary.median_history) == len(summary.history)
    assert summary.history[-1] == pytest.approx(summary.train_mse, rel=1e-9)
    snap = runner.snapshot()
    assert snap.generation == 600 and len(snap.history) <= 65


def test_a_run_track_keeps_bounded_series_and_a_race_compares_at_one_generation():
    """A race's tracks (app/training/live.py RunTrack: best/median and the method's live-plot series, NEAT's
    species dicts included) are bounded like the app's history; the lead line compares both runs'
    best so far at the generation both have reached, read from the thinned step curves."""
    from app.training.live import TRACK_POINTS, RunTrack, lead_line, sample

    tracks = []
    for method, n, scale in (("neat", 20_000, 1.0), ("cmaes", 9_000, 0.5)):
        t = RunTrack(lab.methods.get(method))
        for g in range(n):
            extras = {"species_sizes": {1: 30, 2: 20}, "sigma": 0.1}
            t.add(lab.GenerationEvent(run_id="r", index=g, best=scale / (g + 1), gen_best=1.0, median=2.0, worst=3.0,
                                      evaluations=0, seconds=0.0, improved=False, controller=None, extras=extras))
        tracks.append(t)
    neat, cma = tracks
    gens, best, _ = neat.curves()
    assert len(neat) == 20_000 and len(gens) <= TRACK_POINTS + 1 and gens[-1] == 19_999
    for key in neat.series:
        g, values = neat.series_of(key)
        assert len(g) <= TRACK_POINTS + 1 and g[-1] == 19_999 and values[-1] == {1: 30, 2: 20}
    # the value at a generation between kept points is the latest kept one at or before it
    assert sample(gens, best, [8_999])[0] >= 1.0 / 9_000
    line = lead_line(neat, cma, "NEAT", "CMA-ES")
    assert "generation 9000" in line and "CMA-ES leads" in line


def test_populations_are_logged_on_generations_whose_rows_are_logged():
    from lab.recording.decimation import long_run, population_logged

    logged = [g for g in range(0, 3_000_000, 10) if population_logged(g)]
    assert all(long_run(g) for g in logged)
    assert sum(population_logged(g) for g in range(50_000)) == 100 + 4_990
    assert not population_logged(100_010) and population_logged(100_100)


class _Tab:
    """A tab for the render loop's scheduler: redraws when its period has passed (frames of 1/FPS s)."""

    def __init__(self, presenter: bool, clock: list):
        from app.tab.goals import REDRAW_PERIOD

        self.presenter, self.clock, self.period, self.last, self.draws = presenter, clock, REDRAW_PERIOD, -1e9, []

    def refresh(self) -> bool:
        if self.clock[0] - self.last < self.period:
            return False
        self.last = self.clock[0]
        self.draws.append(self.clock[0])
        return True


@pytest.mark.parametrize("viewers", [5, 100, 400])
def test_a_hall_of_viewer_tabs_redraws_within_its_budget_each_tab_in_turn_and_presenters_at_full_rate(viewers):
    from app.tab.goals import REDRAW_PERIOD
    from app.server import FPS, HALL_REDRAWS, LabApp

    from types import SimpleNamespace

    clock, hall = [0.0], SimpleNamespace(access=SimpleNamespace(restricted=True),  # a classroom's server
                                         _refresh_tab=lambda s: s.refresh())  # (LabApp's catches a tab's failure)
    tabs = [_Tab(True, clock)] + [_Tab(False, clock) for _ in range(viewers)]
    frames, turn, per_frame = int(10 * FPS), 0, []
    for f in range(frames):
        clock[0] = f / FPS
        before = sum(len(t.draws) for t in tabs[1:])
        turn = LabApp._refresh_tabs(hall, tabs, turn)
        per_frame.append(sum(len(t.draws) for t in tabs[1:]) - before)
    period = max(REDRAW_PERIOD, viewers / HALL_REDRAWS)
    assert all(t.period == period for t in tabs[1:])
    assert max(per_frame) <= np.ceil(HALL_REDRAWS / FPS)  # never a burst of every tab in one frame
    assert sum(per_frame) <= HALL_REDRAWS * 10 + viewers  # all viewers together: the budget a second
    # every viewer has its turn, about once a period; the presenter redraws every REDRAW_PERIOD
    gaps = [np.diff(t.draws).max() for t in tabs[1:]]
    assert min(len(t.draws) for t in tabs[1:]) >= 1 and max(gaps) <= period + 2 / FPS + 1e-9
    assert len(tabs[0].draws) >= 10 / (REDRAW_PERIOD + 1 / FPS)


def test_the_ik_thread_solves_a_hall_of_dragging_tabs_within_its_rate():
    import time

    from app.tab.ikworker import IK_PERIOD, IK_RATE, IKWorker

    class Tab:
        def __init__(self):
            self.last_ik, self.solves = 0.0, 0

        def solve_ik(self):
            self.last_ik = time.monotonic()
            self.solves += 1

    worker, tabs = IKWorker(), [Tab() for _ in range(40)]
    end = time.monotonic() + 2.0
    while time.monotonic() < end:  # 40 tabs dragging: every tab asks every 10 ms
        for t in tabs:
            worker.request(t)
        time.sleep(0.01)
    solves = sum(t.solves for t in tabs)
    assert solves <= IK_RATE * 2.0 * 1.25 + len(tabs)  # 40 tabs would be 400 a second at IK_PERIOD
    assert all(t.solves >= 2 for t in tabs) and 40 / IK_PERIOD > IK_RATE


def test_where_every_tab_is_a_presenter_all_tabs_share_the_hall_budget():
    from types import SimpleNamespace

    from app.server import HALL_REDRAWS, LabApp

    clock, server = [0.0], SimpleNamespace(access=SimpleNamespace(restricted=False),  # loopback, no token
                                           _refresh_tab=lambda s: s.refresh())
    tabs = [_Tab(True, clock) for _ in range(200)]
    LabApp._refresh_tabs(server, tabs, 0)
    assert all(t.period == 200 / HALL_REDRAWS for t in tabs)


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        import os

        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/statm"), reason="reads /proc")
def test_the_server_hands_memory_freed_between_live_blocks_back_to_the_system():
    from app.server import release_freed_memory

    if not release_freed_memory():
        pytest.skip("no glibc malloc_trim here")
    blocks = [np.ones(512) for _ in range(60_000)]  # 4 kB each, from malloc's heap: about 240 MB
    keep = blocks[::20]
    del blocks  # 95 % freed, in holes between the kept blocks: the heap's top is not free, nothing goes back
    held = _rss_mb()
    release_freed_memory()
    assert _rss_mb() < held - 50, (held, _rss_mb())  # 80-180 MB seen
    assert all(b[0] == 1.0 for b in keep)
