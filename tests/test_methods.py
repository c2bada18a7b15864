"""The methods registry: every part of the lab reads it, a method is added from outside in one
file, and the refactor into it changed no run (bit for bit against values recorded before)."""

import ast
import dataclasses
import json
import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lab
from conftest import METHODS
from lab import methods

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = json.loads((Path(__file__).parent / "data" / "golden_runs.json").read_text())


# ---------------------------------------------------------------- recorded runs
# Relative tolerance against the recorded values. They were recorded on one machine (Python 3.11,
# numpy 2.4); the compiled kernels round differently on a CPU of another vector width, Python 3.12's
# sum() and numpy 2.5 change pycma's last bits, and 40 generations amplify a last-bit difference to
# at most 6e-10 relative (measured on Python 3.13 with numpy 2.5). A change of the method itself
# moves these numbers by far more. Docs: docs/api.md, "Reproducibility".
GOLDEN_RTOL = 1e-6


def assert_close(got, want, rtol=GOLDEN_RTOL, where="controller"):
    """Equal structure and strings; numbers equal to rtol (integers exactly)."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and sorted(got) == sorted(want), where
        for key in want:
            assert_close(got[key], want[key], rtol, f"{where}.{key}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            assert_close(g, w, rtol, f"{where}[{i}]")
    elif isinstance(want, float):
        assert got == pytest.approx(want, rel=rtol, abs=1e-12), where
    else:
        assert got == want, where


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_runs_equal_the_values_recorded_before_the_registry(name):
    """tests/data/golden_runs.json was written at commit 6712b02, before methods had a registry
    (lab.evolve with these settings): every number of the run and the final controller must be
    the same, to GOLDEN_RTOL on any machine (bit for bit on the machine that recorded them)."""
    robot, method = name.split("-")
    extra = {"diagonal": 10} if method == "cmaes" else {}
    run = lab.evolve(robot, method, generations=40, population=16, targets=30, seed=3, test_goals=200, **extra)
    want = GOLDEN[name]
    hexes = lambda values: [float.fromhex(h) for h in values]  # noqa: E731
    np.testing.assert_allclose(run.history, hexes(want["history"]), rtol=GOLDEN_RTOL)
    np.testing.assert_allclose(run.median_history, hexes(want["median"]), rtol=GOLDEN_RTOL)
    np.testing.assert_allclose([run.train_mse, run.test_mse], hexes([want["train_mse"], want["test_mse"]]),
                               rtol=GOLDEN_RTOL)
    assert run.evaluations == want["evaluations"]
    assert_close(json.loads(json.dumps(run.controller.to_dict())), want["controller"])


def test_the_recorded_controllers_are_the_ones_whose_digest_was_recorded():
    """The controllers stored beside the digests are the recorded ones, bit for bit."""
    for name, want in GOLDEN.items():
        text = json.dumps(want["controller"], sort_keys=True)
        assert hashlib.sha256(text.encode()).hexdigest() == want["controller_sha256"], name


# ---------------------------------------------------------------- every registered method
@pytest.mark.parametrize("method", METHODS)
def test_every_method_trains_and_its_config_round_trips(method):
    m = methods.get(method)
    config = lab.TrainConfig(robot="scara", method=method, generations=4, population=max(m.min_population, 10),
                             targets=10, test_goals=20)
    assert isinstance(config.options, m.options)
    assert lab.TrainConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    runner = lab.Runner(config)
    summary = runner.run()
    assert summary.state == "finished" and summary.generations == 4
    # evaluations are what the steps count: one per fitness value (a population method: its
    # population per generation) unless a step says otherwise (the gradient method: 1 + nq)
    backend = m.backend(runner.problem, config)
    steps = [backend.step() for _ in range(4)]
    assert summary.evaluations == backend.evaluations >= 4
    if all(r.evaluations is None for r in steps):
        assert summary.evaluations == 4 * config.population
    # what the method declares a step counts (experiments at equal budget rely on it)
    assert summary.evaluations == 4 * m.evaluations_per_step(runner.problem.arm, config)
    assert np.isfinite(summary.train_mse) and summary.controller.kind == m.controller


@pytest.mark.parametrize("method", METHODS)
def test_every_option_is_checked_by_name(method):
    m = methods.get(method)
    for name, (default, kind, help_text) in m.options.describe().items():
        assert help_text, f"{method}.{name} has no help text"
        bad = "x" if kind is not bool else "no"
        with pytest.raises(ValueError, match=name):
            lab.TrainConfig(method=method, **{name: bad})


def test_an_option_of_another_method_is_refused_by_name():
    with pytest.raises(ValueError, match="sigma0: not an option of neat"):
        lab.TrainConfig(method="neat", sigma0=0.3)
    with pytest.raises(ValueError, match="not an option"):
        lab.evolve("planar", "neat", sigma0=0.3)


def test_old_recordings_hold_every_methods_options_and_still_load():
    old = {"robot": "planar", "method": "neat", "generations": 10, "population": 20, "targets": 70, "seed": 0,
           "test_goals": 1000, "goal_seed": 0, "features": "polar", "margin": 0.5, "hidden": 0, "sigma0": 0.2,
           "diagonal": 100, "restarts": False, "mutation_power": 0.05, "add_node": 0.002, "add_connection": 0.002,
           "paper": False}
    c = lab.TrainConfig.from_dict(old, strict=False)
    assert c.options == methods.get("neat").options() and c.mutation_power == 0.05


def test_unknown_and_duplicate_methods_are_refused():
    with pytest.raises(ValueError, match="unknown method 'ga'; known methods: " + ", ".join(METHODS)):
        methods.get("ga")
    cmaes = methods.get("cmaes")
    with pytest.raises(ValueError, match="already registered"):
        methods.register(dataclasses.replace(cmaes, label="another CMA-ES"))
    assert methods.register(cmaes) is cmaes  # the same declaration again is harmless


def test_the_cli_offers_every_methods_options():
    from lab.__main__ import method_options

    offered = method_options()
    for m in methods.all_methods():
        assert set(m.options.names()) <= set(offered)


# ---------------------------------------------------------------- adding a method from outside
def test_the_custom_method_example_trains_records_and_reloads(tmp_path):
    """examples/custom_method.py registers random search with public names only, trains it,
    records it, reloads its last controller and checks the held-out MSE equals the logged one."""
    path = tmp_path / "random.rrd"
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "custom_method.py"), str(path)],
                          capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    line = proc.stdout.strip().splitlines()[-1]
    reloaded, logged = (float(s.split(" (")[0]) for s in line.split("held-out MSE ")[1].split(", "))
    assert reloaded == logged and np.isfinite(reloaded)
    assert lab.read_recording(path).protocol["method"] == "random"
    assert len((ROOT / "examples" / "custom_method.py").read_text().splitlines()) < 80


# ---------------------------------------------------------------- nobody asks which method runs
PAPER_PLACE = ROOT / "lab" / "experiments" / "paper.py"
# the claims experiment declares the methods it compares in one tuple there (claims_design.METHODS)
CLAIMS_PLACE = ROOT / "lab" / "experiments" / "claims_design.py"


def _method_literals(path: Path) -> list[str]:
    """String constants in code (not docstrings) that are a registered method's name."""
    tree = ast.parse(path.read_text())
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
                  and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and n.value in METHODS
            and id(n) not in docstrings]


def test_no_code_outside_the_methods_package_names_a_method():
    """Outside lab/methods only the experiments name methods, each in one place: the paper's two
    in lab/experiments/paper.py, the claims experiment's in lab/experiments/claims_design.py (one tuple);
    the rest reads the registry."""
    files = [p for d in ("lab", "app", "robots", "benchmarks", "examples") for p in (ROOT / d).rglob("*.py")
             if "methods" not in p.relative_to(ROOT).parts[:2]]
    naming = {str(p.relative_to(ROOT)): lits for p in files if (lits := _method_literals(p))}
    assert set(naming) <= {str(PAPER_PLACE.relative_to(ROOT)), str(CLAIMS_PLACE.relative_to(ROOT))}, naming
    claims = naming.get(str(CLAIMS_PLACE.relative_to(ROOT)), [])
    assert len(claims) == len(set(claims)), claims  # each named once: the one tuple
