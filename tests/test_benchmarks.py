"""Every benchmark script at least starts: its imports resolve and its options parse (--help)."""

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = sorted((Path(__file__).resolve().parents[1] / "benchmarks").glob("bench_*.py"))


@pytest.mark.parametrize("script", BENCHMARKS, ids=lambda p: p.name)
def test_benchmark_starts(script):
    done = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage:" in done.stdout


def _bench(name: str):
    sys.path.insert(0, str(BENCHMARKS[0].parent))
    try:
        return __import__(name)
    finally:
        sys.path.pop(0)


def _bench_arms():
    return _bench("bench_arms")


def test_bench_arms_reuses_a_shipped_run_only_when_it_is_that_seeds_run():
    """--reuse-shipped: the shipped file stands for lab.evolve(robot, seed=s) only when its settings
    are exactly that call's; its controller is the file's, unchanged."""
    import json

    import numpy as np

    import robots
    from app.startup import pretrained_path

    bench = _bench_arms()
    with open(pretrained_path("ur5"), encoding="utf-8") as f:
        doc = json.load(f)
    seed = doc["settings"]["seed"]
    run = bench.shipped_run("ur5", seed)
    assert run is not None and run.config.to_dict() == doc["settings"] and run.train_mse == doc["train_mse"]
    goals = robots.load("ur5").sample_goals(5, seed=3)
    shipped = bench.lab.controller_from_dict(doc["controller"])
    assert np.array_equal(run.controller(goals), shipped(goals))
    assert bench.shipped_run("ur5", seed + 1) is None  # another seed: trained, not taken from the file


def test_bench_arms_failure_sectors_count_every_held_out_goal_once():
    import numpy as np

    import robots
    from lab.experiments import arms

    bench = _bench_arms()
    n = len(arms.held_out_goals(robots.load("so101")))

    def counts(line):
        pairs = [p.split("/") for p in line.split(": ")[-1].split()]
        return [int(a) for a, _ in pairs], [int(b) for _, b in pairs]

    fails, goals = counts(bench.failure_sectors("so101", np.zeros(n)))
    assert len(goals) == 12 and sum(goals) == n and sum(fails) == 0
    fails, goals = counts(bench.failure_sectors("so101", np.ones(n)))  # 1 m: every goal fails
    assert fails == goals


def test_bench_tree_refine_counts_a_goal_failed_when_one_effector_is():
    """A tree goal succeeds only when every effector does: the failed goals are at least the worst
    effector's failures and at most their sum; each group alone succeeds at least as often."""
    row = _bench("bench_tree_refine").measure("talos-legs", 60, 0)
    failed = round(60 * (1 - row["refined_3"]))
    fails = list(row["fails_by_effector"].values())
    assert len(fails) == 2 and max(fails) <= failed <= sum(fails)
    assert all(g["refined_3"] >= row["refined_3"] for g in row["groups"])
    assert row["refined_3"] <= row["refined_8"] <= row["refined_20"]
