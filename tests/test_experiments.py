"""lab.experiments: Welch's test against scipy, hand values and the paper's own Table 4; the
experiment resumes, retries a failing run once and reports it, writes outputs that parse, and
runs the same way on a local Ray instance. Tiny budgets: a few runs of a few generations."""

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as st

from lab.__main__ import main as lab_main
from lab.experiments import ReproduceConfig, reproduce, train_run, welch
from lab.experiments import paper
from lab.experiments.runs import ConfigMismatch

TINY = dict(runs=3, generations=20, population=10, test_goals=200, progress=False)


# ---------------------------------------------------------------- train functions run by the workers
# Module-level so spawned workers import them; they share state through files (env var inherited).
def _marker(spec, kind: str) -> Path:
    folder = Path(os.environ["LAB_TEST_MARKERS"])
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{kind}-{spec.name}-{os.getpid()}-{np.random.default_rng().integers(1 << 62)}"


def counting_train(spec):
    _marker(spec, "ran").touch()
    return train_run(spec)


def flaky_train(spec):
    """Fails the first attempt of every run, then trains."""
    first = Path(os.environ["LAB_TEST_MARKERS"]) / f"first-{spec.name}"
    if not first.exists():
        first.parent.mkdir(parents=True, exist_ok=True)
        first.touch()
        raise RuntimeError(f"injected failure of {spec.name}")
    return train_run(spec)


def broken_seed1_train(spec):
    """Seed 1 always fails; the others train."""
    if spec.seed == 1:
        raise ValueError("injected permanent failure")
    return train_run(spec)


def nan_seed1_train(spec):
    """Seed 1's result has a NaN training MSE (as a diverged run would); the others train."""
    result = train_run(spec)
    return {**result, "train_mse": float("nan")} if spec.seed == 1 else result


def crash_once_train(spec):
    """The worker process dies (no exception) at the first attempt of seed 0."""
    first = Path(os.environ["LAB_TEST_MARKERS"]) / f"crash-{spec.name}"
    if spec.seed == 0 and not first.exists():
        first.parent.mkdir(parents=True, exist_ok=True)
        first.touch()
        os._exit(3)
    return train_run(spec)


def ran(folder: Path) -> int:
    return len(list(folder.glob("ran-*"))) if folder.exists() else 0


@pytest.fixture
def markers(tmp_path, monkeypatch):
    folder = tmp_path / "markers"
    monkeypatch.setenv("LAB_TEST_MARKERS", str(folder))
    return folder


# ---------------------------------------------------------------- statistics
def test_welch_hand_values():
    # x: mean 2, s^2 = 1 (n 3); y: mean 7, s^2 = 20/3 (n 4); se^2 = 1/3 + 5/3 = 2
    w = welch([1, 2, 3], [4, 6, 8, 10])
    assert w.t == pytest.approx(-5 / np.sqrt(2), rel=1e-12)
    assert w.df == pytest.approx(4 / (1 / 18 + 25 / 27), rel=1e-12)  # = 216/53
    assert w.p_two == pytest.approx(2 * w.p_less, rel=1e-12)
    assert w.p_one == w.p_less and w.p_less + w.p_greater == pytest.approx(1.0)


def test_welch_equals_scipy():
    rng = np.random.default_rng(4)
    for n_x, n_y in ((30, 30), (10, 10), (5, 17)):
        x, y = rng.lognormal(0, 1.5, n_x), rng.normal(3, 0.5, n_y)
        w = welch(x, y)
        ref = st.ttest_ind(x, y, equal_var=False)
        assert w.t == pytest.approx(ref.statistic, rel=1e-12)
        assert w.df == pytest.approx(ref.df, rel=1e-12)
        assert w.p_two == pytest.approx(ref.pvalue, rel=1e-9)
        for alt, p in (("less", w.p_less), ("greater", w.p_greater)):
            assert p == pytest.approx(st.ttest_ind(x, y, equal_var=False, alternative=alt).pvalue, rel=1e-9)


@pytest.mark.parametrize("robot,t,df,p", [("planar", -0.9162, 29.3269, 0.1835), ("scara", 3.2418, 29.0019, 0.0015)])
def test_paper_table4_from_its_table3(robot, t, df, p):
    """The paper's Table 4 follows from its Table 3 columns; its p is one-sided."""
    w = welch(paper.column(robot, "cmaes"), paper.column(robot, "neat"))
    assert round(w.t, 4) == t and round(w.df, 4) == df and round(w.p_one, 4) == p
    assert w.p_two == pytest.approx(2 * w.p_one)
    printed = paper.tests()[(robot, "all")]
    assert (printed["t"], printed["df"], printed["p"]) == (t, df, p)
    assert w.decision(sided="one") == printed["decision"]


def test_paper_table5_is_not_its_table3_best10():
    """The printed Table 5 has self-consistent p values but does not follow from Table 3's best 10."""
    for robot, t, df in (("planar", -41.8133, 17.6121), ("scara", -37.2144, 9.0269)):
        w = welch(np.sort(paper.column(robot, "cmaes"))[:10], np.sort(paper.column(robot, "neat"))[:10])
        assert (round(w.t, 4), round(w.df, 4)) == (t, df)
        printed = paper.tests()[(robot, "best10")]
        assert abs(printed["t"] - w.t) > 1
        assert st.t.cdf(printed["t"], printed["df"]) == pytest.approx(printed["p"], rel=1e-3)


# ---------------------------------------------------------------- the experiment
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    return reproduce(ReproduceConfig(out=out, **TINY)), out


def test_outputs_exist_and_parse(tiny):
    exp, out = tiny
    assert exp.executed == 12 and exp.resumed == 0 and not exp.failures and len(exp.results) == 12
    stored = {p.stem: json.loads(p.read_text()) for p in (out / "runs").glob("*.json")}
    assert len(stored) == 12
    seeds = {(d["robot"], d["method"]): set() for d in stored.values()}
    for d in stored.values():
        seeds[(d["robot"], d["method"])].add(d["seed"])
        assert len(d["history"]) == 20 and np.all(np.diff(d["history"]) <= 0)  # best so far
        assert d["config"]["population"] == 10 and d["test_mse"] > 0 and d["seconds"] > 0
    assert all(s == {0, 1, 2} for s in seeds.values()) and len(seeds) == 4

    rows = list(csv.DictReader(open(out / "table3.csv")))
    assert [r["rank"] for r in rows[-2:]] == ["mean", "std"]
    col = [float(r["planar_cmaes"]) for r in rows[:-2] if r["planar_cmaes"]]
    ours = sorted(d["train_mse"] for d in stored.values() if d["robot"] == "planar" and d["method"] == "cmaes")
    assert col == ours
    assert float(rows[-2]["planar_cmaes"]) == pytest.approx(np.mean(ours))
    assert float(rows[-1]["planar_cmaes"]) == pytest.approx(np.std(ours, ddof=1))
    assert float(rows[0]["paper_scara_neat"]) == 10.344

    x = [d["train_mse"] for d in stored.values() if d["robot"] == "scara" and d["method"] == "cmaes"]
    y = [d["train_mse"] for d in stored.values() if d["robot"] == "scara" and d["method"] == "neat"]
    t4 = (out / "table4.md").read_text()
    assert f"{welch(x, y).t:.4f}" in t4 and "-0.9162" in t4 and "one-sided" in t4 and "two-sided" in t4
    assert "-44.5719" in (out / "table5.md").read_text()
    assert (out / "generalization.md").read_text().count("| 0 |") == 4  # seed 0 of each arm and method
    report = (out / "report.md").read_text()
    assert "tuned defaults" in report and "Time taken" in report and "table4.md" in report
    assert report.startswith("# Reproduction of Martín H., de Lope and Santos (2009)")  # the paper's three authors

    import matplotlib.image

    for name in ("fig5_planar.png", "fig6_scara.png"):
        img = matplotlib.image.imread(out / name)
        assert img.ndim == 3 and img.shape[0] > 400

    from rerun.chunk import RrdReader

    entities = {ch.entity_path for ch in RrdReader(str(out / "experiment.rrd")).stream() if not ch.is_static}
    assert len([e for e in entities if e.startswith("/mse/")]) == 12
    assert "/mse/scara/neat/seed_002" in entities and "/best/planar/cmaes" in entities


def test_resume_skips_finished_runs(tiny, markers):
    exp, out = tiny
    config = ReproduceConfig(out=out, **TINY)
    again = reproduce(config, train=counting_train, write=False)
    assert (again.executed, again.resumed, ran(markers)) == (0, 12, 0)
    assert again.results == exp.results
    more = reproduce(ReproduceConfig(out=out, methods=("cmaes",), **{**TINY, "runs": 4}), train=counting_train,
                     write=False)
    assert (more.executed, more.resumed, ran(markers)) == (2, 6, 2)  # seed 3 on each arm
    with pytest.raises(ConfigMismatch, match="generations"):
        reproduce(ReproduceConfig(out=out, **{**TINY, "generations": 21}), write=False)


def test_failing_run_is_retried_once_and_reported(tmp_path, markers):
    small = dict(runs=3, generations=5, population=8, test_goals=100, methods=("cmaes",), robots=("planar",),
                 progress=False, recording=False)
    exp = reproduce(ReproduceConfig(out=tmp_path / "flaky", **small), train=flaky_train)
    assert len(exp.results) == 3 and not exp.failures and len(exp.retried) == 3
    assert all(r["attempts"] == 2 and "injected failure" in r["errors"][0] for r in exp.results.values())
    assert "succeeded on retry" in (tmp_path / "flaky" / "report.md").read_text()

    out = tmp_path / "broken"
    exp = reproduce(ReproduceConfig(out=out, **small), train=broken_seed1_train)
    assert len(exp.results) == 2 and [f["name"] for f in exp.failures] == ["planar-cmaes-s001"]
    assert exp.failures[0]["attempts"] == 2 and "injected permanent" in exp.failures[0]["error"]
    failed = json.loads((out / "runs" / "planar-cmaes-s001.failed.json").read_text())
    assert "Traceback" in failed["traceback"]
    assert "planar-cmaes-s001 failed 2 times" in (out / "report.md").read_text()
    rows = list(csv.DictReader(open(out / "table3.csv")))
    assert len([r for r in rows[:-2] if r["planar_cmaes"]]) == 2

    again = reproduce(ReproduceConfig(out=out, **small))  # a rerun retries only the failed run
    assert (again.executed, len(again.results), again.failures) == (1, 3, [])
    assert not (out / "runs" / "planar-cmaes-s001.failed.json").exists()


def test_crashed_worker_is_retried(tmp_path, markers):
    exp = reproduce(ReproduceConfig(out=tmp_path, runs=2, generations=5, population=8, test_goals=100,
                                    methods=("cmaes",), robots=("planar",), progress=False, recording=False),
                    train=crash_once_train)
    assert len(exp.results) == 2 and not exp.failures
    assert exp.results["planar-cmaes-s000"]["attempts"] == 2


def test_cli_paper_preset_and_errors(tmp_path, capsys):
    argv = ["reproduce", "--runs", "2", "--generations", "5", "--population", "8", "--methods", "neat",
            "--robots", "scara", "--paper", "--quiet", "--no-recording", "--out", str(tmp_path)]
    assert lab_main(argv) == 0
    assert "2/2 runs (2 executed" in capsys.readouterr().out
    assert "paper's literal method" in (tmp_path / "report.md").read_text()
    stored = json.loads((tmp_path / "runs" / "scara-neat-s001.json").read_text())
    assert stored["config"]["paper"] is True and stored["config"]["mutation_power"] == 1.0
    assert not (tmp_path / "experiment.rrd").exists()
    assert lab_main(argv + ["--generations", "6"]) == 2  # other settings than the stored runs: refused
    assert "other settings" in capsys.readouterr().err
    assert lab_main(["reproduce", "--methods", "sgd", "--out", str(tmp_path / "x")]) == 2
    report = (tmp_path / "report.md").read_bytes()
    for out in (tmp_path / "report.md", tmp_path / "report.md" / "sub"):  # a file, or a path through one
        assert lab_main(["reproduce", "--runs", "1", "--generations", "2", "--out", str(out)]) == 2
        assert f"out must be a folder, but {tmp_path / 'report.md'} is a file" in capsys.readouterr().err
    assert (tmp_path / "report.md").read_bytes() == report  # and it is left as it was


def test_ray_local_instance(tmp_path):
    ray = pytest.importorskip("ray", reason="ray is an optional extra: pip install -e '.[ray]'")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)  # never a running cluster
    try:
        exp = reproduce(ReproduceConfig(out=tmp_path, runs=2, generations=10, population=8, test_goals=100,
                                        robots=("planar",), ray="auto", progress=False, recording=False))
    finally:
        ray.shutdown()
    assert len(exp.results) == 4 and not exp.failures and exp.executor.startswith("Ray")
    assert (tmp_path / "table4.md").exists()
    assert exp.results["planar-neat-s001"]["history"] == train_run(
        exp.specs[3])["history"]  # the same run as in a local process, number for number


@pytest.mark.parametrize("content", ["{not json", "[1, 2, 3]", '{"config": 5}'])
def test_a_damaged_stored_run_is_named_and_done_again(tmp_path, content, capsys):
    from lab.experiments.runs import RunSpec, RunStore

    spec = RunSpec("planar", "cmaes", seed=0, generations=5, population=8)
    store = RunStore(tmp_path / "runs")
    store.folder.mkdir()
    store.path(spec).write_text(content)
    assert store.load(spec) is None
    err = capsys.readouterr().err
    assert str(store.path(spec)) in err and "done again" in err


@pytest.mark.parametrize("field, value, why", [
    ("train_mse", "a", "train_mse is 'a'"), ("train_mse", float("nan"), "train_mse is nan"),
    ("test_mse", float("inf"), "test_mse is inf"), ("history", [0.5, "x"], "history"),
    ("seed", 1.5, "seed is 1.5"), ("seconds", None, "seconds is missing"),
    ("spec", "planar", "spec is 'planar'")])
def test_a_stored_run_with_wrong_or_missing_fields_is_named_and_done_again(tmp_path, markers, capsys, field,
                                                                             value, why):
    """A stored run whose numbers are of the wrong type, missing or not finite (a NaN training MSE) is
    named (its file and what is wrong) and run again; the experiment goes on and its tables show
    every run. Such a run stopped the experiment ("could not convert string to float: 'a'", no file
    named), or a NaN run was shown as "—" and counted as nothing."""
    small = dict(runs=2, generations=5, population=8, test_goals=100, methods=("cmaes",), robots=("planar",),
                 progress=False, recording=False)
    first = reproduce(ReproduceConfig(out=tmp_path, **small))
    path = tmp_path / "runs" / "planar-cmaes-s001.json"
    stored = json.loads(path.read_text())
    if value is None:
        del stored[field]
    else:
        stored[field] = value
    path.write_text(json.dumps(stored))
    capsys.readouterr()
    again = reproduce(ReproduceConfig(out=tmp_path, **small), train=counting_train)
    err = capsys.readouterr().err
    assert f"{path} is damaged" in err and why in err and "done again" in err, err
    assert (again.executed, again.resumed, ran(markers), again.failures) == (1, 1, 1, [])
    assert again.results["planar-cmaes-s001"]["history"] == first.results["planar-cmaes-s001"]["history"]
    rows = list(csv.DictReader(open(tmp_path / "table3.csv")))
    assert len([r for r in rows[:-2] if r["planar_cmaes"]]) == 2 and "—" not in (tmp_path / "table3.md").read_text()


def test_a_run_whose_result_is_nan_is_a_failure_not_a_blank(tmp_path, markers):
    """A run that returns a NaN training MSE is retried, then reported as failed (never stored as a
    result, never a silent "—" in the tables)."""
    small = dict(runs=2, generations=5, population=8, test_goals=100, methods=("cmaes",), robots=("planar",),
                 progress=False, recording=False)
    exp = reproduce(ReproduceConfig(out=tmp_path, **small), train=nan_seed1_train)
    assert list(exp.results) == ["planar-cmaes-s000"] and [f["name"] for f in exp.failures] == ["planar-cmaes-s001"]
    assert "train_mse is nan" in exp.failures[0]["error"]
    assert not (tmp_path / "runs" / "planar-cmaes-s001.json").exists()
    report = (tmp_path / "report.md").read_text()
    assert "planar-cmaes-s001 failed 2 times" in report and "train_mse is nan" in report


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_reproduce_stopped_by_a_signal_leaves_no_worker_running(tmp_path, sig, wait_ended):
    """`lab reproduce` ended by SIGTERM (a service manager) or even SIGKILL: its pool workers end with it."""
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "lab", "reproduce", "--runs", "4", "--generations", "100000",
                             "--population", "8", "--robots", "planar", "--methods", "cmaes", "--out",
                             str(tmp_path / "out"), "--no-recording", "--quiet", "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    workers = []
    while time.monotonic() < deadline and len(workers) < 2:
        time.sleep(0.5)
        workers = [c for c in _children(proc.pid) if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
    assert len(workers) >= 2, "no pool workers started"
    time.sleep(2.0)  # they are training now
    proc.send_signal(getattr(signal, sig))
    proc.wait(30)
    for pid in workers:
        wait_ended(pid, timeout=15)
    if sig == "SIGTERM":
        assert proc.returncode == 130 and "the same command resumes" in proc.stderr.read()


def test_an_unwritable_out_is_refused_before_any_run(tmp_path, capsys):
    import stat

    from lab.__main__ import main as lab_main

    import subprocess

    out = tmp_path / "locked"
    out.mkdir()
    out.chmod(stat.S_IRUSR | stat.S_IXUSR)
    mounted = False
    if os.access(out, os.W_OK):  # root ignores the mode: a read-only filesystem instead
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(out)],
                                 capture_output=True).returncode == 0
        if not mounted:
            pytest.skip("no read-only folder can be made here")
    try:
        assert lab_main(["reproduce", "--runs", "1", "--generations", "2", "--out", str(out), "--quiet",
                         "--no-recording"]) == 2
        assert f"cannot write the runs to {out / 'runs'}" in capsys.readouterr().err
    finally:
        if mounted:
            subprocess.run(["umount", str(out)], capture_output=True)
        out.chmod(stat.S_IRWXU)


def test_more_workers_than_cores_are_capped_with_a_note(tmp_path, capsys):
    from lab.__main__ import main as lab_main

    assert lab_main(["reproduce", "--runs", "1", "--generations", "2", "--population", "8", "--robots", "planar",
                     "--methods", "cmaes", "--workers", "100000", "--out", str(tmp_path), "--quiet",
                     "--no-recording"]) == 0
    assert f"--workers 100000 capped at {os.cpu_count()}" in capsys.readouterr().err
