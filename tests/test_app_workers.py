"""A training worker that does not answer (stopped with SIGSTOP, as a hung or swapped-out process
would be): Stop ends it after a bounded wait, the class is told, its notebook entry keeps the
generations it had sent, and Start and Reset work again (app/training/state.py: stop,
lab/running/worker.py: ProcessRunner.kill)."""

from __future__ import annotations

import os
import signal
import time

import lab
from conftest import wait_until


def test_a_race_whose_partner_worker_is_stopped_is_ended_after_a_bounded_wait(app, wait_ended):
    state, panel = app.state, app.panel
    state.stop_grace = 1.0
    config = lab.TrainConfig.preset(robot="planar", method="cmaes", population=10, generations=100_000, seed=0)
    partner = lab.TrainConfig.preset(robot="planar", method="cmaes", population=10, generations=100_000, seed=1)
    stopped_pid = None
    try:
        assert state.start(config, partner) is None
        runner, other = state.runner, state.partner.runner
        assert wait_until(lambda: len(state.partner.track) >= 3 and state.progress()["generation"] >= 3)
        stopped_pid = other.pid
        os.kill(stopped_pid, signal.SIGSTOP)
        time.sleep(0.3)
        sent = len(state.partner.track)  # what the partner had sent before it stopped answering
        t0 = time.monotonic()
        panel.buttons["Stop"].value = True
        took = time.monotonic() - t0
        assert took < 1.0 + 5.0, took  # the bounded wait, then the kill
        assert runner.state == "stopped" and other.state == "stopped"
        wait_ended(stopped_pid, 10)
        # the class is told: the shared message and the status
        assert "did not answer Stop" in panel.message.content and "killed" in panel.message.content
        panel.refresh(force=True)
        assert "did not answer Stop" in panel.status.content
        entries = {e["run_id"]: e for e in state.notebook.entries()}
        entry = entries[other.run_id]
        assert entry["state"] == "stopped" and entry["generations"] == sent > 0
        assert "killed" in (entry["error"] or "")
        assert entries[runner.run_id]["state"] == "stopped" and entries[runner.run_id]["error"] is None
        # Start and Reset work again
        assert state.start(config) is None and state.running
        assert state.notice is None
        panel.buttons["Reset"].value = True
        assert not state.running and state.progress()["generation"] == 0
        stopped_pid = None
    finally:
        if stopped_pid is not None:
            try:
                os.kill(stopped_pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        state.stop_grace = 5.0
        state.reset()


def test_a_stopped_worker_is_killed_by_stop_or_kill_and_keeps_its_generations(wait_ended):
    from lab.running.worker import ProcessRunner

    runner = ProcessRunner(lab.TrainConfig.preset(robot="planar", method="cmaes", population=10,
                                                  generations=100_000, seed=2))
    seen = []
    runner.subscribe(seen.append)
    runner.start()
    try:
        assert wait_until(lambda: len(seen) >= 3)
        os.kill(runner.pid, signal.SIGSTOP)
        time.sleep(0.3)
        sent = len(seen)
        t0 = time.monotonic()
        assert runner.stop_or_kill(grace=0.5) is True
        assert time.monotonic() - t0 < 5.0
        summary = runner.join(5)
        assert summary is not None and summary.state == "stopped" and summary.generations == sent
        assert "killed" in summary.error and summary.controller is not None
        wait_ended(runner.pid, 10)
    finally:
        try:
            os.kill(runner.pid, signal.SIGCONT)
        except ProcessLookupError:
            pass
        runner.stop(wait=True, timeout=5)


def test_a_worker_that_answered_stop_is_not_killed_while_its_reader_lags(monkeypatch, caplog):
    """On a busy machine the reader may read the worker's end after Stop's grace: the worker that
    answered (it ended and exited) is not killed, and its run ends as its own summary says."""
    import logging

    from lab.running import worker

    runner = worker.ProcessRunner(lab.TrainConfig.preset(robot="planar", method="cmaes", population=10,
                                                         generations=100_000, seed=3))
    runner.set_speed(20)  # what it sends while the reader sleeps stays far below the pipe's size
    seen = []
    runner.subscribe(seen.append)
    runner.start()
    try:
        assert wait_until(lambda: len(seen) >= 3)
        monkeypatch.setattr(worker, "READ_PERIOD", 4.0)  # the reader's next read comes seconds late
        assert wait_until(lambda: runner._answered())  # it has read a batch and sleeps on the next
        with caplog.at_level(logging.WARNING, logger=worker.__name__):
            assert runner.stop_or_kill(grace=0.5) is False
        summary = runner.join(30)
        assert summary is not None and summary.state == "stopped" and summary.error is None
        assert summary.controller is not None and not any("killed" in r.getMessage() for r in caplog.records)
    finally:
        runner.stop(wait=True, timeout=10)
