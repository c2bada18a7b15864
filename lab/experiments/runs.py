"""One run of the experiment: its spec, the function that trains it, and the per-run JSON store.

    spec = RunSpec("planar", "cmaes", seed=3, generations=1000, population=50)
    result = train_run(spec)        # a plain dict: train/test MSE, history, seconds, seed, config, controller
    store = RunStore(out / "runs")
    store.save(spec, result)        # runs/planar-cmaes-s003.json, written atomically (temp file + os.replace)
    store.load(spec)                # the stored dict, or None when the run has not finished

A run is finished when its JSON exists and its stored config equals spec.config() (and its stored
spec the spec): a rerun with the same settings skips it. A stored run that cannot be read, or whose
numbers the reports read are missing, of the wrong type or not finite (RunSpec.damage), is named
and done again; a new result with such numbers counts as a failed attempt (retried, then reported). A run that failed twice is kept as
runs/<name>.failed.json (error and traceback) until a later attempt succeeds.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

import robots
from lab import methods
from lab.running.config import TrainConfig


@dataclass(frozen=True, order=True)
class RunSpec:
    robot: str
    method: str
    seed: int
    generations: int = 1000
    population: int = 50
    targets: int = 70
    test_goals: int = 1000
    paper: bool = False

    @property
    def name(self) -> str:
        return f"{self.robot}-{self.method}-s{self.seed:03d}"

    def cost(self) -> float:
        """Rough relative run time (the method's declared cost x the arm's joints), to submit the
        longest runs first."""
        return methods.get(self.method).cost * robots.load(self.robot).nq

    RESULT_FIELDS = {"seed": "count", "train_mse": "value", "test_mse": "value", "history": "series",
                     "seconds": "value", "evaluations": "count"}  # what the reports read (train_run's result)
    OPTIONAL_FIELDS = {"wall_seconds": "value", "cpu_seconds": "value"}

    def damage(self, result) -> str | None:
        """What is wrong with a result of this run for the reports (a field missing, of the wrong type,
        NaN or infinite), or None."""
        if not isinstance(result, dict):
            return f"not a stored run but {type(result).__name__}"
        return damage(result, self.RESULT_FIELDS, self.OPTIONAL_FIELDS)

    def config(self) -> TrainConfig:
        """The TrainConfig lab.evolve builds for this run (validated)."""
        return TrainConfig.preset(paper=self.paper, robot=self.robot, method=self.method,
                                  generations=self.generations, population=self.population,
                                  targets=self.targets, seed=self.seed, test_goals=self.test_goals)


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _value(v) -> bool:
    return _real(v) and math.isfinite(v) and v >= 0


def series_ok(v) -> bool:
    """A non-empty list of numbers >= 0 (inf allowed: a generation with no finite error; NaN not)."""
    return isinstance(v, list) and len(v) > 0 and all(_real(x) and x >= 0 for x in v)


_KINDS = {  # what a field of a result must be, and how it is said
    "count": (_count, "a whole number >= 0"),
    "value": (_value, "a finite number >= 0"),
    "series": (series_ok, "a non-empty list of numbers >= 0 (no NaN)"),
}


def damage(data: dict, fields: dict[str, str], optional: dict[str, str] | None = None) -> str | None:
    """What is wrong with `data` (a run's result): its fields of `fields` (name -> a kind of _KINDS)
    missing or not of their kind, or those of `optional` present and not of their kind; None if nothing."""
    problems = []
    for name, kind in [*fields.items(), *(optional or {}).items()]:
        ok, what = _KINDS[kind]
        if name not in data:
            if name in fields:
                problems.append(f"{name} is missing")
        elif not ok(data[name]):
            v = data[name]
            shown = repr(v) if not isinstance(v, list) else f"a list with {_first_bad(v)}"
            problems.append(f"{name} is {shown}, not {what}")
    return "; ".join(problems[:3]) + ("; ..." if len(problems) > 3 else "") if problems else None


def _first_bad(v: list) -> str:
    bad = [x for x in v if not (_real(x) and x >= 0)]
    return f"{bad[0]!r} in it" if bad else "nothing in it"


def train_run(spec: RunSpec) -> dict:
    """Train one run with lab.evolve and return its result as JSON-ready data."""
    import lab

    t0, c0 = time.perf_counter(), time.process_time()
    run = lab.evolve(spec.robot, spec.method, spec.generations, spec.population, spec.targets, spec.seed,
                     paper=spec.paper, test_goals=spec.test_goals)
    return {
        "name": spec.name, "robot": spec.robot, "method": spec.method, "seed": spec.seed,
        "spec": asdict(spec), "config": run.config.to_dict(),
        "train_mse": run.train_mse, "test_mse": run.test_mse,
        "history": [float(v) for v in run.history],  # best training MSE so far, per generation
        "seconds": run.seconds,  # optimizer time (lab.Run.seconds)
        "wall_seconds": time.perf_counter() - t0,  # with problem setup and held-out evaluation
        "cpu_seconds": time.process_time() - c0,  # this process's CPU time for the run
        "evaluations": run.evaluations, "n_params": run.n_params,
        "controller": run.controller.to_dict() if run.controller is not None else None,
        "host": platform.node(), "pid": os.getpid(), "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def attempt(train, spec: RunSpec) -> dict:
    """Call train(spec) in a worker; never raises: {"ok": True, "result": ...} or the error."""
    try:
        return {"ok": True, "result": train(spec)}
    except Exception as e:  # reported and retried by the scheduler, never dropped
        return {"ok": False, "error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}


def write_json_atomic(path: Path, data) -> None:
    """Write JSON to a temp file in the same folder, fsync, then os.replace: never a half file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o644)  # mkstemp makes 0600 files
        with os.fdopen(fd, "w") as f:
            json.dump(data, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ConfigMismatch(ValueError):
    """A stored run was made with other settings than the ones asked for."""


class RunStore:
    """runs/<name>.json per finished run, runs/<name>.failed.json per run that failed twice."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)

    def check_writable(self) -> None:
        """Create the folder and write a probe file there; OSError naming the folder if it cannot be."""
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=self.folder, prefix=".write-test-")
            os.close(fd)
            os.unlink(probe)
        except OSError as e:
            raise OSError(f"cannot write the runs to {self.folder}: {e.strerror or e}") from e

    def path(self, spec: RunSpec) -> Path:
        return self.folder / f"{spec.name}.json"

    def failed_path(self, spec: RunSpec) -> Path:
        return self.folder / f"{spec.name}.failed.json"

    def load(self, spec: RunSpec, overwrite: bool = False) -> dict | None:
        """The stored result, None if absent or unreadable; ConfigMismatch if made with other settings
        (None instead with overwrite: the run is redone)."""
        path = self.path(spec)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as e:
            print(f"note: {path} is damaged ({type(e).__name__}: {e}); the run is done again", file=sys.stderr)
            return None
        if not isinstance(data, dict) or not isinstance(data.get("config"), dict) or \
                not isinstance(data.get("spec", {}), dict):
            why = "not a stored run" if not isinstance(data, dict) or not isinstance(data.get("config"), dict) \
                else f"spec is {data['spec']!r}, not a dict"
            print(f"note: {path} is damaged ({why}); the run is done again", file=sys.stderr)
            return None
        expected = spec.config().to_dict()
        # a spec may hold more than its config (claims.ClaimSpec: a time limit): both must match
        stored_spec, asked_spec = data.get("spec", asdict(spec)), asdict(spec)
        if data.get("config") != expected or stored_spec != asked_spec:
            if overwrite:
                return None
            stored = {**(stored_spec if isinstance(stored_spec, dict) else {}), **data.get("config", {})}
            diff = {k: (stored.get(k), v) for k, v in {**asked_spec, **expected}.items() if stored.get(k) != v}
            raise ConfigMismatch(f"{self.path(spec)} was made with other settings "
                                 f"(stored vs asked: {diff}); use another --out or --overwrite")
        why = spec.damage(data)
        if why is not None:
            print(f"note: {path} is damaged ({why}); the run is done again", file=sys.stderr)
            return None
        return data

    def save(self, spec: RunSpec, result: dict) -> None:
        write_json_atomic(self.path(spec), result)
        self.failed_path(spec).unlink(missing_ok=True)

    def save_failure(self, spec: RunSpec, failure: dict) -> None:
        write_json_atomic(self.failed_path(spec), {"name": spec.name, "spec": asdict(spec), **failure})
