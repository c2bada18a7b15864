"""Long runs: what a recording logs beyond 10,000 generations (lab.recording.decimation.long_run),
and a recording that stops cleanly, closed and readable, when its disk is nearly full."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

import lab
from lab.recording.decimation import EVERY_UNTIL, long_run, long_run_count
from lab.recording.logger import RerunLogger
from lab.recording.replay import load_controller, read_recording
from lab.running.runner import Runner

ROOT = Path(__file__).resolve().parents[1]


def test_the_long_run_rule():
    assert all(long_run(g) for g in range(EVERY_UNTIL))
    assert [g for g in range(EVERY_UNTIL, EVERY_UNTIL + 40) if long_run(g)] == [10_000, 10_010, 10_020, 10_030]
    assert long_run(100_000) and not long_run(100_010) and long_run(100_100) and not long_run(1_000_100)
    for n in (1, 9_999, 10_000, 10_001, 123_457, 2_000_000):
        assert long_run_count(n) == sum(1 for g in range(n) if long_run(g)), n
    # 10^9 generations (the lab's bound): 55,000 logged, about 25 MB at 460 bytes each
    assert long_run_count(10**9) == 55_000


def test_a_long_runs_recording_logs_by_the_rule_and_its_last_generation(tmp_path):
    generations = EVERY_UNTIL + 1_234
    config = lab.TrainConfig(robot="planar", method="cmaes", generations=generations, population=6, targets=10,
                             test_goals=10, hidden=2)
    runner = Runner(config)
    logger = RerunLogger(runner, path=tmp_path / "long.rrd")
    runner.subscribe(logger)
    summary = runner.run()
    logger.close(wait=True)
    rec = read_recording(logger.path)
    expected = [g for g in range(generations) if long_run(g)] + [generations - 1]
    assert rec.generations.tolist() == expected  # 10,124 rows, not 11,234
    assert rec.summary["state"] == "finished"
    c = load_controller(logger.path)  # the run's final controller is there
    assert runner.problem.controller_mse(c) == pytest.approx(summary.train_mse, rel=0, abs=1e-9)
    # a generation that was not logged replays the controller in force at the last logged one
    doc = rec.controller_doc(10_015)
    assert doc["generation"] <= 10_010


def test_a_recording_stops_closed_and_readable_when_its_disk_is_nearly_full(tmp_path):
    """LAB_RECORDING_RESERVE (bytes a recording leaves free) larger than any disk: the writer's first
    look at the free space stops it. The run goes on and prints its results; one line says why the
    recording stopped and what can be read back; the file has its footer."""
    path = tmp_path / "run.rrd"
    env = dict(os.environ, LAB_RECORDING_RESERVE=str(10**18))
    done = subprocess.run([sys.executable, "-m", "lab", "train", "--robot", "planar", "--generations", "3000",
                           "--population", "10", "--targets", "15", "--test-goals", "10", "--quiet",
                           "--recording", str(path)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out[-3000:]
    assert "training MSE" in done.stdout
    lines = [line for line in out.splitlines() if "stopped:" in line]
    assert len(lines) == 1 and "disk is nearly full" in lines[0] and "can be read back" in lines[0], out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    RrdReader(path).store()  # closed with its footer
    rec = read_recording(path)
    assert rec.last_generation is not None and rec.last_generation < 2999
