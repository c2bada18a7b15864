"""One writer process for many recordings (lab/recording/service.py): each recording is the file a
writer process of its own would write (controllers back exactly, the lock held until it is closed),
they go through one process, a SIGKILL of the app still leaves every file closed with its footer,
and a serving process that died is started again for the next recording."""

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

import lab
from lab.recording import busy
from lab.recording.logger import RerunLogger
from lab.recording.replay import load_controller, read_recording
from lab.recording.service import WriterService
from lab.running.runner import Runner

SHORT = dict(robot="planar", generations=60, population=10, targets=15, test_goals=10)
ROOT = Path(__file__).resolve().parents[1]


def served_run(service, path, seed=0, **changes):
    runner = Runner(lab.TrainConfig(method="cmaes", seed=seed, **{**SHORT, **changes}))
    logger = RerunLogger(runner, path=path, service=service)
    assert busy.being_written(path)  # held from the start, by the logger and then the service
    runner.subscribe(logger)
    return runner, logger, runner.run()


def test_recordings_one_after_another_and_at_once_go_through_one_process(tmp_path):
    service = WriterService()
    try:
        done = [served_run(service, tmp_path / "first.rrd")]
        threads = [threading.Thread(target=lambda k=k: done.append(served_run(service, tmp_path / f"at-once-{k}.rrd",
                                                                              seed=k)))
                   for k in (1, 2, 3)]
        [t.start() for t in threads]
        [t.join(120) for t in threads]
        assert len(done) == 4
        for runner, logger, summary in done:
            assert logger.pid == service.pid  # one process wrote them all
            assert not busy.being_written(logger.path)  # closed: its lock let go
            rec = read_recording(logger.path)
            assert rec.last_generation == summary.generations - 1 and rec.summary["state"] == "finished"
            assert runner.problem.controller_mse(load_controller(logger.path)) == pytest.approx(rec.best[-1], rel=0,
                                                                                                 abs=1e-12)
            logger.wait(60)  # compacted: the file is still whole
            RrdReader(logger.path).store()
    finally:
        service.close()


def test_a_serving_process_that_died_is_started_again(tmp_path, caplog):
    service = WriterService()
    try:
        runner = Runner(lab.TrainConfig(method="cmaes", **{**SHORT, "generations": 100000}))
        logger = RerunLogger(runner, path=tmp_path / "orphan.rrd", service=service)
        runner.subscribe(logger)
        runner.start()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if (read_recording(logger.path).last_generation or 0) >= 10:
                    break
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
        old = service.pid
        os.kill(old, signal.SIGKILL)
        logger.wait(10)
        runner.stop()
        assert runner.join(30).state == "stopped"
        with pytest.raises(RuntimeError, match="stopped"):
            logger.close()
        assert read_recording(logger.path).last_generation >= 10  # what it had written still loads
        _, again, summary = served_run(service, tmp_path / "again.rrd")
        assert again.pid != old and read_recording(again.path).last_generation == summary.generations - 1
    finally:
        service.close()


APP_SCRIPT = textwrap.dedent("""
    import sys, lab
    from lab.recording.logger import RerunLogger
    from lab.recording.service import WriterService
    from lab.running.runner import Runner
    service = WriterService()
    runners = []
    for k in range(2):
        runner = Runner(lab.TrainConfig(robot="planar", method="cmaes", generations=100000, population=10, targets=15,
                                        test_goals=10, seed=k))
        runner.subscribe(RerunLogger(runner, path=sys.argv[1] + f"/run{k}.rrd", service=service))
        runner.start()
        runners.append(runner)
    print(service.pid, flush=True)
    for runner in runners:
        runner.join()
""")


def test_the_app_killed_leaves_every_served_file_closed(tmp_path, wait_ended):
    proc = subprocess.Popen([sys.executable, "-c", APP_SCRIPT, str(tmp_path)], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    pid = int(proc.stdout.readline())
    paths = [tmp_path / "run0.rrd", tmp_path / "run1.rrd"]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if all((read_recording(p).last_generation or 0) >= 10 for p in paths):
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    wait_ended(pid)  # the serving process ends once the app's pipes have, every file closed first
    for p in paths:
        RrdReader(p).store()  # the footer: closed
        assert read_recording(p).last_generation >= 10 and not busy.being_written(p)
