"""A lost Ray node never wedges the class: with the raylet of the local Ray instance killed
(SIGKILL, as the OOM killer does), the runs going fail, a run started afterwards fails within the bound
with a message naming the cluster instead of waiting for a CPU for good, its worker slot is freed, new
runs are refused with that reason and the Class board says the cluster is lost. A run that no node
takes (every CPU busy) gives up after RayRunner.start_wait s and its pending actor is cancelled. The
class's side of it (refused, the queued runs failed, the board's line, back when it answers) without
Ray. A Ray instance of this module's own, shut down after: its raylet is killed."""

from __future__ import annotations

import logging
import os
import signal

import pytest

import lab
from app.classroom.class_runs import ClassRuns
from app.classroom.limits import CLASSROOM
from app.panels.class_board import board_html
from app.training.notebook import Notebook
from conftest import wait_until
from lab.running.runner import Runner

try:
    import ray
except ImportError:  # the ray extra is not installed: the class's side is still tested
    ray = None

needs_ray = pytest.mark.skipif(ray is None, reason='Ray is not installed (pip install -e ".[ray]")')

SHORT = dict(robot="planar", method="cmaes", generations=20, population=10)
LONG = dict(robot="planar", method="cmaes", generations=100_000, population=10)  # runs until stopped
START_WAIT = 20.0  # s: the bound the tests give a run that waits for a CPU (60 s in the app)


@pytest.fixture
def notebook(tmp_path):
    return Notebook(str(tmp_path / "notebook.db"))


# ---------------------------------------------------------------------- the class's side, without Ray
class ThreadRunners:
    """A runner factory (the lab's thread Runner) that says, as RayRunner.unavailable does, whether
    runs can go where it sends them."""

    def __init__(self):
        self.lost: str | None = None

    def unavailable(self) -> str | None:
        return self.lost

    def __call__(self, config, history_limit=None):
        runner = Runner(config, history_limit=history_limit)
        runner.stop_or_kill = lambda grace=None: runner.stop(wait=True) or False
        return runner


def test_while_the_runners_cluster_is_lost_new_runs_are_refused_the_queued_fail_and_the_board_says_so(notebook):
    make = ThreadRunners()
    runs = ClassRuns(notebook, CLASSROOM, workers=1, runner=make)
    assert runs.submit(1, lab.TrainConfig(**LONG)) is None
    assert runs.submit(2, lab.TrainConfig(**SHORT)) is None
    first, queued = runs.run_of(1), runs.run_of(2)
    assert queued.state == "queued" and "New runs are refused" not in board_html(runs)
    make.lost = "the Ray cluster at 10.0.0.9:6379 is lost: no live node has a CPU"
    why = runs.submit(3, lab.TrainConfig(**SHORT))
    assert why.startswith("refused: the Ray cluster at 10.0.0.9:6379 is lost") and "until it answers again" in why
    assert runs.run_of(3) is None
    board = board_html(runs)  # every tab's Class board, the presenter's too
    assert "The Ray cluster at 10.0.0.9:6379 is lost" in board and "New runs are refused" in board
    # the running run's end frees its slot: the queued one would wait for a CPU none offers, it fails now
    assert runs.stop(first.id, wait=True) is None
    assert wait_until(lambda: first.ended and queued.ended, 60), (first.status(), queued.status())
    assert queued.state == "failed" and "10.0.0.9:6379 is lost" in queued.status(), queued.status()
    assert runs.running() == [] and runs.place(queued) == (None, 0)
    # it answers again: runs go to it
    make.lost = None
    assert "New runs are refused" not in board_html(runs)
    assert runs.submit(3, lab.TrainConfig(**SHORT)) is None
    assert wait_until(lambda: runs.run_of(3).ended, 120) and runs.run_of(3).state == "finished"


# ---------------------------------------------------------------------- on a local Ray instance
@pytest.fixture(scope="module")
def cluster():
    """A local Ray instance of this module's own (2 CPUs), its watch probing every second."""
    from lab.running import ray_runner, ray_watch

    if ray.is_initialized():  # another module's instance: this one kills its raylet
        ray.shutdown()
    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=80 * 1024 * 1024,
             log_to_driver=False, runtime_env={"env_vars": ray_runner.ONE_THREAD})
    watch, saved = ray_watch.WATCH, (ray_runner.START_WAIT, ray_watch.WATCH.period)
    watch.joined("local")
    ray_runner.START_WAIT, watch.period = START_WAIT, 1.0
    try:
        yield ray_runner
    finally:
        ray_runner.START_WAIT, watch.period = saved
        ray.shutdown()
        watch.joined(None)


def gcs_address() -> str:
    return ray.get_runtime_context().gcs_address


def raylet_pid() -> int:
    """The raylet of this process's Ray instance (its command line names the session)."""
    session = ray.get_runtime_context().get_session_name()
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/comm") as f:
                comm = f.read().strip()
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmdline = f.read().decode(errors="replace")
        except OSError:
            continue
        if comm == "raylet" and session in cmdline:
            found.append(int(pid))
    assert len(found) == 1, f"raylets of {session}: {found}"
    return found[0]


@needs_ray
def test_a_run_no_node_takes_gives_up_after_its_bound_naming_the_cluster_and_frees_nothing(cluster):
    busy = [cluster.RayRunner(lab.TrainConfig(**LONG, seed=s)) for s in (1, 2)]  # both CPUs
    late = cluster.RayRunner(lab.TrainConfig(**SHORT))
    late.start_wait = 5.0
    try:
        for runner in busy:
            runner.start()
        assert wait_until(lambda: all(r.snapshot().generation > 0 for r in busy), 240), [r.preparing for r in busy]
        late.start()
        assert late.preparing == "waiting for a CPU on the Ray cluster"
        summary = late.join(120)  # bounded: it gives up
        assert summary is not None and summary.state == "failed" and summary.generations == 0
        assert "its Ray worker never started" in summary.error and "within 5 s" in summary.error, summary.error
        assert gcs_address() in summary.error, summary.error
        assert cluster.RayRunner.unavailable() is None  # the cluster itself answers
    finally:  # the next test needs both CPUs
        for runner in (late, *busy):
            runner.stop_or_kill(60)
    # its pending actor was cancelled: it never takes a CPU afterwards
    assert wait_until(lambda: ray.available_resources().get("CPU", 0) == 2, 60), ray.available_resources()


@needs_ray
def test_a_killed_raylet_fails_the_runs_going_and_the_next_within_the_bound_and_the_class_is_told(
        cluster, notebook, caplog):
    caplog.set_level(logging.WARNING)
    runs = ClassRuns(notebook, CLASSROOM, workers=2, runner=cluster.RayRunner)
    for tab, seed in ((1, 1), (2, 2), (3, 3)):
        assert runs.submit(tab, lab.TrainConfig(**LONG, seed=seed)) is None
    a, b, c = (runs.run_of(tab) for tab in (1, 2, 3))
    assert wait_until(lambda: a.generation > 0 and b.generation > 0, 240), (a.status(), b.status())
    assert c.state == "queued"
    address = gcs_address()
    os.kill(raylet_pid(), signal.SIGKILL)  # as the OOM killer does
    # the runs going fail (their actors die with the node); the queued one then starts, or is failed
    # before it starts: none waits for a CPU for good
    assert wait_until(lambda: a.ended and b.ended, 180), (a.status(), b.status())
    for run in (a, b):
        assert run.state == "failed" and "its Ray worker was lost" in run.status(), run.status()
    assert wait_until(lambda: c.ended, START_WAIT + 60), c.status()
    assert c.state == "failed" and address in c.status() and "lost" in c.status(), c.status()
    assert runs.running() == []  # every slot free
    # the class is told: new runs refused with the reason, the board (the presenter's tab too), the log
    lost = runs.unavailable()
    assert lost is not None and address in lost and "is lost" in lost, lost
    why = runs.submit(4, lab.TrainConfig(**SHORT))
    assert why is not None and why.startswith("refused: ") and address in why and "is lost" in why, why
    board = board_html(runs)
    assert "is lost" in board and address in board and "New runs are refused" in board
    assert any(address in r.getMessage() and "is lost" in r.getMessage() for r in caplog.records
               if r.name == "lab.running.ray_watch")
    # a run made directly on the lost cluster fails at once too
    runner = cluster.RayRunner(lab.TrainConfig(**SHORT)).start()
    summary = runner.join(START_WAIT + 30)
    assert summary is not None and summary.state == "failed" and address in summary.error, summary


def test_the_presenters_tab_is_told_once_when_the_runners_cluster_is_lost_and_once_when_it_is_back(tmp_path):
    from conftest import make_app, tab_of

    make = ThreadRunners()
    app = make_app(tmp_path, class_runner=make, class_workers=1, startup=None)  # loopback: a presenter tab
    tab = tab_of(app.url)
    later = None
    try:
        def told(title, probe=tab):
            return [m["props"] for _t, m in list(probe.messages)
                    if "Notification" in m["type"] and m.get("props", {}).get("title") == title]

        make.lost = "the Ray cluster at 10.0.0.9:6379 is lost: no live node has a CPU"
        assert wait_until(lambda: told("Ray cluster lost"), 30)
        assert wait_until(lambda: "New runs are refused" in app.board.table.content, 30)
        (lost,) = told("Ray cluster lost")
        assert "10.0.0.9:6379 is lost" in lost["body"] and lost["color"] == "red"
        later = tab_of(app.url)  # a presenter's tab opened while it is lost is told too
        assert wait_until(lambda: told("Ray cluster lost", later), 30)
        make.lost = None
        assert wait_until(lambda: told("Ray cluster back"), 30)
        assert wait_until(lambda: "New runs are refused" not in app.board.table.content, 30)
        assert len(told("Ray cluster lost")) == 1  # once, not every render pass
    finally:
        for probe in (tab, later):
            if probe is not None:
                probe.close()
        app.stop()
