"""Students' runs on a Ray cluster (lab/running/ray_runner.py, `python -m app --ray ADDRESS`): a run
streams its generations live from its actor and ends as a local run does; Stop; a lost actor fails its
run and the queue goes on; the class's queue and notebook with Ray runners; the app's errors for a
missing Ray and an unreachable cluster. One local Ray instance (2 CPUs) for the module."""

from __future__ import annotations

import socket
import sys

import numpy as np
import pytest

import lab
from app.classroom.class_runs import ClassRuns
from app.classroom.limits import CLASSROOM
from app.training.notebook import Notebook
from conftest import wait_until

try:
    import ray
except ImportError:  # the ray extra is not installed: the Ray tests are skipped, the error line is tested
    ray = None

needs_ray = pytest.mark.skipif(ray is None, reason='Ray is not installed (pip install -e ".[ray]")')

SHORT = dict(robot="planar", method="cmaes", generations=20, population=10)
LONG = dict(robot="planar", method="cmaes", generations=100_000, population=10)  # runs until stopped


@pytest.fixture(scope="module")
def cluster():
    from lab.running import ray_runner

    started = not ray.is_initialized()
    if started:
        ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=80 * 1024 * 1024,
                 log_to_driver=False, runtime_env={"env_vars": ray_runner.ONE_THREAD})
    yield ray_runner
    if started:
        ray.shutdown()


@pytest.fixture
def notebook(tmp_path):
    return Notebook(str(tmp_path / "notebook.db"))


class Seen:
    """A subscriber: every event, with whether its run had ended when it came; the summary at the end."""

    def __init__(self, runner):
        self.runner, self.events, self.ended_before, self.summary = runner, [], [], None

    def __call__(self, event):
        self.events.append(event)
        self.ended_before.append(self.runner.done)

    def on_end(self, summary):
        self.summary = summary


@needs_ray
def test_a_ray_run_streams_live_its_best_is_what_it_streamed_and_stop_ends_it(cluster):
    runner = cluster.RayRunner(lab.TrainConfig(**LONG, seed=1), history_limit=4096)
    seen = Seen(runner)
    runner.subscribe(seen)
    runner.start()
    assert wait_until(lambda: len(seen.events) >= 5, 180), runner.preparing
    # live: generations arrive while the run goes on in its actor (it has 100,000 to go)
    assert not runner.done and runner.state == "running" and not any(seen.ended_before)
    assert runner.node_id is not None and runner.pid is not None
    assert runner.stop_or_kill(60) is False  # it ended after its generation in flight: not killed
    summary = runner.join(10)
    assert summary.state == "stopped" and summary.error is None and seen.summary is summary
    assert summary.run_id == runner.run_id and all(e.run_id == runner.run_id for e in seen.events)
    # every generation it trained reached the subscriber, in order, before the end
    assert summary.generations == len(seen.events) == runner.snapshot().generation
    assert [e.index for e in seen.events] == list(range(len(seen.events)))
    last = seen.events[-1]
    assert summary.history[-1] == last.best
    # the best controller's error is what was streamed: its training MSE, recomputed here
    assert summary.train_mse == pytest.approx(last.best, rel=1e-9)
    assert runner.problem.controller_mse(last.controller) == pytest.approx(last.best, rel=1e-9)
    goals = runner.problem.test_goals[:5]
    assert np.array_equal(summary.controller(goals), last.controller(goals))


@needs_ray
def test_a_finished_ray_run_has_the_summary_of_the_same_run_trained_here(cluster):
    from lab.running.runner import Runner

    config = lab.TrainConfig(**SHORT, seed=3)
    runner = cluster.RayRunner(config)
    seen = Seen(runner)
    runner.subscribe(seen)
    remote = runner.run()
    local = Runner(config).run()
    assert remote.state == local.state == "finished" and remote.ended_by == local.ended_by == "generations"
    assert remote.generations == local.generations == len(seen.events) == 20
    assert remote.evaluations == local.evaluations and remote.error is None
    assert np.array_equal(remote.history, local.history) and np.array_equal(remote.median_history, local.median_history)
    assert remote.train_mse == pytest.approx(local.train_mse) and remote.test_mse == pytest.approx(local.test_mse)
    assert np.isfinite(remote.test_mse) and remote.controller is not None


@needs_ray
def test_a_lost_ray_worker_fails_its_run_with_a_message_and_the_next_queued_run_starts(cluster, notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1, runner=cluster.RayRunner)
    assert runs.set_name(1, "Ada") is None and runs.set_name(2, "Grace") is None
    assert runs.submit(1, lab.TrainConfig(**LONG)) is None
    assert runs.submit(2, lab.TrainConfig(**SHORT, seed=4)) is None
    first, second = runs.run_of(1), runs.run_of(2)
    assert wait_until(lambda: first.generation > 0, 180), first.status()
    assert second.state == "queued"
    ray.kill(first.runner._actor)  # as a crashed worker process or a node gone
    assert wait_until(lambda: first.ended, 120), first.status()
    assert first.state == "failed" and "its Ray worker was lost" in first.status(), first.status()
    assert first.summary.generations == first.generation > 0  # what it streamed counts
    assert wait_until(lambda: notebook.get(first.id) is not None, 60)  # noted just after it ended
    entry = notebook.get(first.id)
    assert entry["state"] == "failed" and entry["student"] == "Ada" and "its Ray worker was lost" in entry["error"]
    assert wait_until(lambda: second.ended, 300), second.status()
    assert second.state == "finished" and notebook.get(second.id)["student"] == "Grace"


@needs_ray
def test_the_class_queue_on_ray_finishes_two_runs_and_notes_them(cluster, notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1, runner=cluster.RayRunner)
    assert runs.submit(1, lab.TrainConfig(**SHORT, seed=5)) is None
    assert runs.submit(2, lab.TrainConfig(**SHORT, seed=6)) is None
    a, b = runs.run_of(1), runs.run_of(2)
    assert b.state == "queued"  # one at a time
    assert wait_until(lambda: a.ended and b.ended, 300), (a.status(), b.status())
    for run, seed in ((a, 5), (b, 6)):
        assert run.state == "finished" and run.generation == 20 and run.controller is not None
        entry = notebook.get(run.id)
        assert entry["state"] == "finished" and entry["generations"] == 20 and entry["seed"] == seed
        assert entry["student"] == run.name and entry["test_mse"] == pytest.approx(run.held_out())
    assert b.started > a.started


def _app_main(tmp_path, *args):
    from app.__main__ import main

    return main(["--port", "0", "--no-record", "--notebook", str(tmp_path / "notebook.db"), *args])


def test_ray_not_installed_is_an_error_naming_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray: ImportError
    assert _app_main(tmp_path, "--ray", "local") == 2
    err = capsys.readouterr().err
    assert "Ray is not installed" in err and 'pip install -e ".[ray]"' in err


@needs_ray
def test_a_ray_address_where_nothing_listens_is_an_error_at_once(tmp_path, capsys):
    with socket.socket() as s:  # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert _app_main(tmp_path, "--ray", f"127.0.0.1:{port}") == 2
    assert "nothing answers there" in capsys.readouterr().err
    assert _app_main(tmp_path, "--ray", "nohost") == 2
    assert "HOST:PORT" in capsys.readouterr().err
