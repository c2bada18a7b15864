"""lab.experiments.claims (`python -m lab claims`): the smoke size writes claims.md with every arm,
method and verdict and resumes without running anything; the equal-budget and stuck-run arithmetic
on hand-made numbers; resampled goals are reproducible by seed and differ from the fixed goals; a
time limit stops a run; a stored run made with another time limit is refused."""

import json
from dataclasses import asdict

import numpy as np
import pytest

import lab
import robots
from lab import methods
from lab.__main__ import main as lab_main
from lab.experiments import claims as C
from lab.experiments.claims_report import judge_arm, reached
from lab.experiments.runs import ConfigMismatch, RunStore
from lab.running.runner import Runner, TimeLimit, build_problem


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """The smoke size: --runs 2 --generations 50 (under a minute on 2 cores)."""
    out = tmp_path_factory.mktemp("claims")
    assert lab_main(["claims", "--runs", "2", "--generations", "50", "--out", str(out), "--quiet"]) == 0
    return out


def test_smoke_writes_every_arm_method_and_verdict(smoke):
    md = (smoke / "claims.md").read_text()
    for robot in C.ROBOTS:
        assert f"| {robot} | " in md and (smoke / f"claims_{robot}.png").stat().st_size > 10_000
    for m in C.METHODS:
        label = methods.get(m).label
        for robot in C.ROBOTS:  # a row per arm and method in both settings
            assert md.count(f"| {robot} | {label} | 2 |") == 2
    assert "## Verdicts" in md and md.count("Rule: ") == 2
    assert "**The numbers" in md.split("### Claim (ii)")[1] and "**The numbers" in md.split("### Conclusion")[1]
    assert "2 seeds instead of 10;" in md and (smoke / "claims_resampled.png").exists()
    runs = list((smoke / "runs").glob("*.json"))
    assert len(runs) == len(C.ROBOTS) * len(C.METHODS) * 2 * 2 + len(C.RESAMPLE_ROBOTS) * 2


def test_resuming_runs_nothing_new(smoke):
    before = {p.name: p.stat().st_mtime_ns for p in (smoke / "runs").glob("*.json")}
    result = C.claims(C.ClaimsConfig(runs=2, generations=50, out=smoke, progress=False))
    assert result.experiment.executed == 0 and result.experiment.resumed == len(before)
    assert {p.name: p.stat().st_mtime_ns for p in (smoke / "runs").glob("*.json")} == before


def test_equal_budget_runs_spend_the_budget(smoke):
    """Every equal-budget run counts at most E evaluations and less than one step short of it."""
    config = C.ClaimsConfig(runs=2, generations=50, out=smoke)
    for path in (smoke / "runs").glob("*.json"):
        d = json.loads(path.read_text())
        if d["kind"] == "seconds":
            assert d["seconds"] >= d["spec"]["seconds"] or d["generations"] == d["spec"]["generations"]
            continue
        budget = config.budget(d["robot"])
        per = methods.get(d["method"]).evaluations_per_step(robots.load(d["robot"]), lab.TrainConfig.from_dict(d["config"]))
        assert budget - per < d["evaluations"] <= budget, d["name"]
        assert d["checkpoints"]["error"][-1] == d["held_out"] and len(d["checkpoints"]["error"]) == C.CHECKPOINTS


def test_equal_budget_arithmetic_by_hand():
    assert C.generations_for(50_000, 50) == 1000
    assert C.generations_for(50_000, 1 + 3) == 12_500  # gradient on planar: 1 + nq a step
    assert C.generations_for(50_000, 1 + 20) == 2380  # planar-20: 2380 x 21 = 49,980 <= 50,000
    assert C.generations_for(10, 21) == 1  # never zero
    config = C.ClaimsConfig(runs=1, generations=40, out="/tmp/unused-claims")
    assert config.budget("planar") == 40 * 50
    gens = {(s.robot, s.method, s.kind): s.generations for s in config.specs()}
    assert gens[("planar-20", C.METHODS[-1], "evaluations")] == 2000 // 21
    assert gens[("planar-20", C.METHODS[-1], "seconds")] == C.CAP * (2000 // 21)
    assert gens[("ur5", C.METHODS[1], "evaluations")] == 40 * 50 // 100  # NEAT's 100 genomes on a real arm


def test_stuck_fraction_by_hand():
    errors = {"a": [1.0, 2.0, 10.5, 30.0], "b": [0.5, 4.0, 6.0], "c": [np.inf, 0.9]}
    # best run of any method: 0.5; relative: > 5.0; absolute: > 3.0 (inf counts as stuck)
    assert C.stuck(errors, absolute=3.0) == {"a": (2, 2, 4), "b": (1, 2, 3), "c": (1, 1, 2)}
    assert C.stuck(errors, absolute=100.0, factor=2.0) == {"a": (3, 0, 4), "b": (2, 0, 3), "c": (1, 1, 2)}


def test_judging_an_arm_and_reaching_a_target_by_hand():
    g, evolved = C.METHODS[-1], C.METHODS[:-1]  # the gradient method last, the evolved ones before it
    num = {g: {"median": 1.0, "abs": 0, "rel": 0}}
    for k, m in enumerate(evolved):  # medians 2, 3, 4 ...; the first stuck once
        num[m] = {"median": 2.0 + k, "abs": int(k == 0), "rel": 0}
    assert judge_arm(num) == "contradicted"
    num[g] = {"median": 4.0, "abs": 2, "rel": 1}
    assert judge_arm(num) == "supported"
    num[g] = {"median": 1.5, "abs": 2, "rel": 1}  # lowest error but stuck more often
    assert judge_arm(num) == "mixed"
    run = {"checkpoints": {"evaluations": [10, 20, 40], "seconds": [0.1, 0.2, 0.4], "error": [5.0, 2.0, 1.0]}}
    assert reached(run, 2.0) == (20.0, 0.2) and reached(run, 0.5) == (np.inf, np.inf)


def test_resampled_goals_are_reproducible_by_seed_and_differ_from_the_fixed_ones():
    def problem(seed, resample=True):
        return build_problem(lab.TrainConfig(robot="scara", seed=seed, targets=30, resample=resample, test_goals=10))

    p, q, other, fixed = problem(3), problem(3), problem(4), problem(3, resample=False)
    assert p.resampling and not fixed.resampling
    np.testing.assert_array_equal(p.reference_goals, fixed.train_goals)  # the fixed set is the reference
    p.draw_goals(5)
    q.draw_goals(0)
    q.draw_goals(5)  # the goals of generation 5 whatever came before
    other.draw_goals(5)
    np.testing.assert_array_equal(p.train_goals, q.train_goals)
    assert p.train_goals.shape == fixed.train_goals.shape
    assert not np.allclose(p.train_goals, fixed.train_goals) and not np.allclose(p.train_goals, other.train_goals)
    q.draw_goals(6)
    assert not np.allclose(p.train_goals, q.train_goals)
    # whole runs: the same seed gives the same run; fixed goals give another one
    kw = dict(generations=15, population=8, targets=20, test_goals=50, seed=2)
    a, b = lab.evolve("planar", resample=True, **kw), lab.evolve("planar", resample=True, **kw)
    c = lab.evolve("planar", **kw)
    assert list(a.history) == list(b.history) and a.test_mse == b.test_mse
    assert list(a.history) != list(c.history)
    # the best so far is kept by its MSE on the fixed goals: history never rises, ends at train_mse
    assert np.all(np.diff(a.history) <= 0) and a.history[-1] == pytest.approx(a.train_mse, rel=1e-9)
    assert a.config.resample and "resample" not in c.config.to_dict()  # fixed configs read as before


def test_a_time_limit_stops_a_run():
    runner = Runner(lab.TrainConfig(robot="planar", method=C.METHODS[0], generations=10**6, population=8,
                                    targets=10, test_goals=10))
    runner.subscribe(TimeLimit(runner, 0.3))
    s = runner.run()
    assert s.state == "stopped" and 0.3 <= s.seconds < 5.0 and s.generations < 10**6
    with pytest.raises(ValueError, match="positive"):
        TimeLimit(runner, 0.0)


def _stored_claim(spec) -> dict:
    """A stored claims run with every number the report reads (made up)."""
    return {"spec": asdict(spec), "config": spec.config().to_dict(), "seed": spec.seed, "train_mse": 0.5,
            "test_mse": 0.6, "held_out": 12.0, "generations": 30, "evaluations": 240, "seconds": 1.0,
            "checkpoints": {"evaluations": [8, 240], "seconds": [0.1, 1.0], "error": [float("inf"), 12.0]}}


def test_a_stored_run_with_another_time_limit_is_refused(tmp_path):
    spec = C.ClaimSpec("planar", C.METHODS[0], 0, generations=30, population=None, targets=None, kind="seconds",
                       budget=100, seconds=1.0)
    store = RunStore(tmp_path)
    store.save(spec, _stored_claim(spec))
    assert store.load(spec) is not None
    other = C.ClaimSpec(**{**asdict(spec), "seconds": 2.0})
    with pytest.raises(ConfigMismatch, match="seconds"):
        store.load(other)
    assert store.load(other, overwrite=True) is None



@pytest.mark.parametrize("field, value, why", [
    ("held_out", float("nan"), "held_out is nan"), ("train_mse", "a", "train_mse is 'a'"),
    ("evaluations", None, "evaluations is missing"),
    ("checkpoints", {"evaluations": [8], "seconds": [0.1], "error": ["x"]}, "checkpoints is"),
    ("checkpoints", {"evaluations": [8, 9], "seconds": [0.1], "error": [1.0]}, "of one length")])
def test_a_stored_claims_run_with_bad_numbers_is_named_and_done_again(tmp_path, capsys, field, value, why):
    """`lab claims` resumed over a run whose held-out error is NaN, or whose numbers are missing or of
    the wrong type: its file and what is wrong are named, and it is run again (not a crash, not a blank)."""
    spec = C.ClaimSpec("planar", C.METHODS[0], 0, generations=30, population=None, targets=None,
                       kind="evaluations", budget=240)
    store = RunStore(tmp_path)
    stored = _stored_claim(spec)
    if value is None:
        del stored[field]
    else:
        stored[field] = value
    store.save(spec, stored)
    assert store.load(spec) is None
    err = capsys.readouterr().err
    assert f"{store.path(spec)} is damaged" in err and why in err and "done again" in err, err

def test_ray_local_instance(tmp_path):
    """--ray: the same runs on a local Ray instance; an equal-budget run is the same, number for
    number, as in a local process (the equal-time runs depend on the machine's speed)."""
    ray = pytest.importorskip("ray", reason="ray is an optional extra: pip install -e '.[ray]'")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)  # never a running cluster
    try:
        result = C.claims(C.ClaimsConfig(out=tmp_path, runs=1, generations=5, ray="auto", progress=False))
    finally:
        ray.shutdown()
    exp = result.experiment
    assert len(exp.results) == len(exp.specs) and not exp.failures and exp.executor.startswith("Ray")
    assert (tmp_path / "claims.md").exists()
    for spec in exp.specs:
        if spec.kind == "evaluations" and spec.robot == "scara":
            local = C.train_claim(spec)
            for key in ("curve", "checkpoints"):
                local[key].pop("seconds"), exp.results[spec.name][key].pop("seconds")
            for key in ("held_out", "train_mse", "evaluations", "curve", "checkpoints", "controller"):
                assert exp.results[spec.name][key] == local[key], (spec.name, key)
