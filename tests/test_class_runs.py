"""Students' own runs (app/classroom/class_runs.py): names, the queue, limits, a tab's close, the
server's stop; each run in a worker process of its own, its end in the notebook. The app's side
(a viewer tab's "My experiment", the Class board): tests/test_app_class.py."""

from __future__ import annotations

import html
import os

import pytest

import lab
from app.classroom.class_runs import MAX_QUEUED, ClassRuns, clean_name, default_workers
from app.classroom.limits import CLASSROOM
from app.training.notebook import Notebook
from conftest import process_ended, wait_until

SHORT = dict(robot="planar", method="cmaes", generations=20, population=10)
LONG = dict(robot="planar", method="cmaes", generations=100_000, population=10)  # runs until stopped


@pytest.fixture
def notebook(tmp_path):
    return Notebook(str(tmp_path / "notebook.db"))


def test_names_are_cleaned_refused_when_taken_and_freed_when_the_tab_closes(notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    assert clean_name("  Ada   Lovelace ") == ("Ada Lovelace", None)
    assert clean_name("Zoë O'Neil-2")[0] == "Zoë O'Neil-2"
    for bad in ("<b>x</b>", "<script>alert(1)</script>", "a&amp;b", 'x" onmouseover="y', "`x`", "[a](http://e)"):
        name, why = clean_name(bad)
        assert name is None and "not" in why, bad
        assert runs.set_name(1, bad).startswith("refused:")
    assert clean_name("x" * 25)[0] is None and "24" in clean_name("x" * 25)[1]
    assert clean_name("   ")[0] is None and clean_name("...")[0] is None
    a, b = runs.name_of(1), runs.name_of(2)
    assert a != b and a.startswith("student ") and runs.name_of(1) == a
    assert runs.set_name(1, "Ada") is None and runs.name_of(1) == "Ada"
    why = runs.set_name(2, " ada ")
    assert why is not None and "taken" in why and runs.name_of(2) == b
    assert runs.set_name(2, b) is None  # its own name again
    assert runs.set_name(3, b) is not None  # a generated name is taken too
    runs.drop_tab(1)
    assert runs.set_name(2, "Ada") is None  # free once its tab has closed
    assert html.escape("<b>") != "<b>"  # (the board escapes whatever it shows: test_app_class)


def test_default_workers_leave_the_shared_run_and_the_server_their_cores():
    assert default_workers(2) == 1 and default_workers(1) == 1 and default_workers(16) == 14


def test_a_run_finishes_in_its_own_process_and_its_notebook_entry_names_the_student(notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    assert runs.set_name(7, "Grace") is None
    assert runs.submit(7, lab.TrainConfig(**SHORT, seed=3)) is None
    run = runs.run_of(7)
    assert wait_until(lambda: run.runner is not None and run.runner.pid is not None, 60)
    assert run.runner.pid != os.getpid()
    assert wait_until(lambda: run.ended, 300), run.status()
    assert run.state == "finished" and run.generation == 20 and run.status().startswith("finished, 20 generations")
    assert run.best() is not None and run.held_out() is not None and run.controller is not None
    entry = notebook.get(run.id)
    assert entry["state"] == "finished" and entry["student"] == "Grace" and entry["generations"] == 20
    assert entry["seed"] == 3 and entry["test_mse"] == pytest.approx(run.held_out())


def test_one_run_per_tab_the_limits_the_queue_a_closed_tab_and_the_servers_stop(notebook, wait_ended):
    runs = ClassRuns(notebook, CLASSROOM, workers=1, stop_grace=5.0)
    # beyond the server's limits: refused, naming the setting and the bound
    why = runs.submit(1, lab.TrainConfig(**{**LONG, "population": CLASSROOM["population"] + 1}))
    assert why.startswith("refused:") and "population" in why and f"{CLASSROOM['population']}" in why
    assert runs.run_of(1) is None
    assert runs.submit(1, lab.TrainConfig(**LONG)) is None
    first = runs.run_of(1)
    assert wait_until(lambda: first.generation > 0, 300), first.status()
    assert "one run at a time" in runs.submit(1, lab.TrainConfig(**SHORT))  # the tab's second run
    # a second tab waits: one worker
    assert runs.submit(2, lab.TrainConfig(**LONG)) is None
    second = runs.run_of(2)
    assert second.state == "queued" and second.status() == "queued, place 1 of 1"
    assert runs.stop(second.id + "x") == "refused: no such run"
    # tab 1 closes: its running run stops, the queued one starts
    pid = first.runner.pid
    runs.drop_tab(1)
    assert wait_until(lambda: first.ended, 60) and first.state == "stopped"
    wait_ended(pid)
    assert notebook.get(first.id)["state"] == "stopped" and notebook.get(first.id)["error"] == "its tab closed"
    assert wait_until(lambda: second.state == "running", 60)
    # a third tab queues; a tab that closes while queued is dropped (never started, no entry)
    assert runs.submit(3, lab.TrainConfig(**LONG)) is None
    third = runs.run_of(3)
    assert runs.submit(4, lab.TrainConfig(**LONG)) is None
    fourth = runs.run_of(4)
    assert fourth.status() == "queued, place 2 of 2"
    runs.drop_tab(3)
    assert third.state == "stopped" and third.runner is None and notebook.get(third.id) is None
    assert fourth.status() == "queued, place 1 of 1"
    # the server stops: the running run and the queued one end stopped, both in the notebook
    assert wait_until(lambda: second.generation > 0, 300)
    pid = second.runner.pid
    runs.shutdown()
    assert second.state == "stopped" and fourth.state == "stopped"
    wait_ended(pid)
    assert notebook.get(second.id)["state"] == "stopped" and notebook.get(second.id)["error"] == "the server stopped"
    e = notebook.get(fourth.id)
    assert e["state"] == "stopped" and e["generations"] == 0 and e["student"] == runs.name_of(4)
    assert runs.submit(5, lab.TrainConfig(**SHORT)) == "refused: the server is stopping"


def test_a_students_run_takes_a_worker_started_and_warmed_before_it_was_submitted(notebook):
    """Issue #57: a class of 30 runs pays no process start a run. From the first run on, `workers` warm
    workers wait (its replacement started when one is taken): the next run trains in one of them,
    started before it was submitted, and N runs start at most N + workers processes. A run ends with
    its last message, not after its worker's teardown; the server's stop ends the waiting workers."""
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    assert runs.warm.pids() == []  # nothing started before a student's first run
    assert runs.submit(1, lab.TrainConfig(**SHORT)) is None
    first = runs.run_of(1)
    assert wait_until(lambda: first.ended, 300), first.status()
    waiting = runs.warm.pids()
    assert len(waiting) == 1 and first.runner.pid not in waiting
    for tab in (2, 3):
        assert runs.submit(tab, lab.TrainConfig(**SHORT, seed=tab)) is None
        run = runs.run_of(tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        assert run.state == "finished" and run.runner.pid in waiting  # started before this run was submitted
        assert notebook.get(run.id)["generations"] == 20
        waiting = runs.warm.pids()
        assert len(waiting) == 1 and run.runner.pid not in waiting  # its replacement waits
    assert runs.warm.started <= 3 + runs.workers
    runs.shutdown()
    assert runs.warm.pids() == [] and wait_until(lambda: all(process_ended(p) for p in waiting), 30)


def test_the_next_run_starts_while_the_last_runs_recording_is_still_being_closed(notebook):
    """A recording's writer closes its file after the run (seconds on a busy machine): the queue's next
    run starts at once, and the ended run's notebook entry is written only once its file is whole."""
    import threading

    class HeldLogger:  # a recording whose close waits until the test lets it
        def __init__(self):
            self.path, self.block_on_end, self.closed, self.release = "held.rrd", True, False, threading.Event()

        def __call__(self, event):
            pass

        def on_end(self, summary):
            self.close(summary, block=self.block_on_end)

        def close(self, summary=None, block=True):
            if block and not self.closed:
                self.release.wait(120)
            self.closed = True

        def failure(self):
            return None

    loggers = []

    def recorder(runner):
        loggers.append(HeldLogger())
        runner.subscribe(loggers[-1])
        return loggers[-1]

    runs = ClassRuns(notebook, CLASSROOM, workers=1, recorder=recorder)
    try:
        assert runs.submit(1, lab.TrainConfig(**SHORT)) is None and runs.submit(2, lab.TrainConfig(**SHORT)) is None
        first, second = runs.run_of(1), runs.run_of(2)
        assert wait_until(lambda: second.state == "running", 300), (first.status(), second.status())
        assert not loggers[0].closed and notebook.get(first.id) is None and not first.ended
    finally:
        for logger in loggers:
            logger.release.set()
    assert wait_until(lambda: first.ended and second.ended, 300), (first.status(), second.status())
    assert loggers[0].closed and notebook.get(first.id)["recording"] == "held.rrd" and first.state == "finished"
    runs.shutdown()


def test_the_queue_is_bounded(notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    runs._pump = lambda: None  # nothing starts: only the queue's bound is tried
    for tab in range(MAX_QUEUED):
        assert runs.submit(tab, lab.TrainConfig(**SHORT)) is None
    why = runs.submit(MAX_QUEUED, lab.TrainConfig(**SHORT))
    assert why.startswith("refused:") and "queue is full" in why


def test_a_recorded_runs_recording_ends_with_its_final_controller_and_its_entry_names_it(notebook, tmp_path):
    """With a recorder (as the server has), a student run is recorded: its entry names a whole .rrd whose
    last controller is the run's final one, its logged error that controller's training MSE."""
    import numpy as np

    from app.server import rerun_recorder
    from lab.recording.replay import read_recording

    runs = ClassRuns(notebook, CLASSROOM, workers=1, recorder=rerun_recorder(str(tmp_path / "class")))
    assert runs.submit(7, lab.TrainConfig(**SHORT, seed=2)) is None
    run = runs.run_of(7)
    assert wait_until(lambda: run.ended, 300), run.status()
    assert run.state == "finished"
    entry = notebook.get(run.id)
    assert entry["recording"] == run.recording and os.path.isfile(run.recording)
    assert os.path.dirname(run.recording) == str(tmp_path / "class")
    rec = read_recording(run.recording)
    assert rec.last_generation == run.generation - 1 and rec.summary is not None
    doc = rec.controller_doc()
    controller = lab.controller_from_dict(doc["controller"])
    problem = run.runner.problem
    goals = problem.train_goals
    assert np.array_equal(controller(goals), run.summary.controller(goals))  # bit for bit
    q = controller(goals)
    mse = float(np.mean(np.sum((problem.arm.reach(q) - goals) ** 2, axis=-1)))
    assert doc["best_mse"] == pytest.approx(mse, rel=1e-6) == pytest.approx(run.summary.train_mse, rel=1e-9)
