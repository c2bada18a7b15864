"""The paper's experiment: every method on every arm, `runs` independent runs with distinct seeds.

    from lab.experiments import ReproduceConfig, reproduce
    exp = reproduce(ReproduceConfig(runs=30, generations=1000, population=50, out="results/paper"))
    exp.executed, exp.resumed, exp.failures, exp.wall_seconds

Run i of every arm and method uses seed `seed + i`; the 70 training and 1,000 held-out goals are
fixed across runs (goal_seed, as in the paper). Runs go to local processes (all cores) or, with
`ray`, to a Ray cluster. Each finished run is stored at once (runs.RunStore), so a rerun with the
same `out` resumes: it executes only the runs not stored yet. A run that fails is reported and
retried once; if it fails again it is kept in runs/<name>.failed.json and listed in report.md and
in `failures`, never dropped. The outputs (tables, figures, generalization, recording, report) are
then written from all stored runs (report.write_outputs).
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass, field
from pathlib import Path

import robots

from lab import methods
from lab.experiments import paper
from lab.recording.logger import not_a_folder
from lab.experiments.runs import RunSpec, RunStore, train_run


@dataclass(frozen=True)
class ReproduceConfig:
    runs: int = 30
    generations: int = 1000
    population: int = 50
    methods: tuple[str, ...] = paper.METHODS
    robots: tuple[str, ...] = ("planar", "scara")
    out: Path = Path("results/paper")
    paper: bool = False  # the paper's literal method (TrainConfig.preset(paper=True)) or the tuned defaults
    seed: int = 0  # run i uses seed + i
    targets: int = 70
    test_goals: int = 1000
    workers: int | None = None  # local processes (None: all cores)
    ray: str | None = None  # a Ray address ("local" starts one); None: local processes
    retries: int = 1
    overwrite: bool = False  # redo stored runs made with other settings instead of refusing
    progress: bool = True
    recording: bool = True  # the Rerun recording of all runs (experiment.rrd)

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "methods", tuple(self.methods))
        object.__setattr__(self, "robots", tuple(self.robots))
        for name in ("runs", "generations", "population", "targets", "test_goals"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if not self.methods or any(m not in methods.names() for m in self.methods):
            raise ValueError(f"methods must be among {', '.join(methods.names())}, got {', '.join(self.methods) or 'none'}")
        if not self.robots or any(r not in robots.names() for r in self.robots):
            raise ValueError(f"robots must be among {', '.join(robots.names())}, got {', '.join(self.robots) or 'none'}")
        if len(set(self.methods)) != len(self.methods) or len(set(self.robots)) != len(self.robots):
            raise ValueError("methods and robots must not repeat")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries!r}")
        blocker = not_a_folder(self.out)
        if blocker is not None:
            raise ValueError(f"out must be a folder, but {blocker} is a file")

    def specs(self) -> list[RunSpec]:
        """Every run, by arm, method and seed; each validated as a TrainConfig."""
        specs = [RunSpec(r, m, self.seed + i, self.generations, self.population, self.targets,
                         self.test_goals, self.paper)
                 for r in self.robots for m in self.methods for i in range(self.runs)]
        for s in specs:  # ValueError naming the field (e.g. population < 4 for CMA-ES) before any work
            s.config()
        return specs


@dataclass
class Experiment:
    """What reproduce() did: results by run name (stored and new), failures after the retry."""

    config: ReproduceConfig
    specs: list[RunSpec]
    results: dict[str, dict] = field(default_factory=dict)
    failures: list[dict] = field(default_factory=list)
    retried: list[dict] = field(default_factory=list)  # runs that failed once, then succeeded
    executed: int = 0  # runs executed by this call (the others were resumed from the store)
    resumed: int = 0
    wall_seconds: float = 0.0
    executor: str = ""
    started: str = ""
    load_before: tuple = ()
    load_after: tuple = ()
    outputs: dict[str, Path] = field(default_factory=dict)

    def values(self, robot: str, method: str, key: str = "train_mse") -> list[float]:
        return [self.results[s.name][key] for s in self.specs
                if s.robot == robot and s.method == method and s.name in self.results]

    def runs_of(self, robot: str, method: str) -> list[dict]:
        return [self.results[s.name] for s in self.specs
                if s.robot == robot and s.method == method and s.name in self.results]


def _log(msg: str) -> None:
    from tqdm import tqdm

    tqdm.write(msg, file=sys.stderr)


def _outcome(future) -> dict:
    try:
        return future.result()
    except Exception as e:  # the worker died, or Ray lost the task
        return {"ok": False, "error": f"{type(e).__name__}: {e}", "traceback": ""}


def _execute(exp: Experiment, pending: list[RunSpec], executor, train, store: RunStore, bar) -> None:
    """Submit every pending run, store each result as it arrives, retry failures `retries` times."""
    attempts: dict[RunSpec, list[str]] = {}
    inflight = {}

    def submit(spec: RunSpec) -> None:
        attempts.setdefault(spec, [])
        inflight[executor.submit(train, spec)] = spec

    for spec in pending:
        submit(spec)
    while inflight:
        done, _ = wait(inflight, return_when=FIRST_COMPLETED)
        for fut in done:
            spec = inflight.pop(fut)
            out = _outcome(fut)
            if out["ok"] and (why := spec.damage(out["result"])) is not None:  # e.g. a NaN MSE: never a blank
                out = {"ok": False, "error": f"its result cannot be reported: {why}", "traceback": ""}
            errors = attempts[spec]
            if out["ok"]:
                result = dict(out["result"], attempts=len(errors) + 1, errors=errors)
                store.save(spec, result)
                exp.results[spec.name] = result
                if errors:
                    exp.retried.append({"name": spec.name, "errors": errors})
                bar.update(1)
                continue
            errors.append(out["error"])
            if len(errors) <= exp.config.retries:
                _log(f"run {spec.name} failed (attempt {len(errors)}): {out['error']}; retrying")
                submit(spec)
            else:
                failure = {"name": spec.name, "attempts": len(errors), "errors": errors,
                           "error": out["error"], "traceback": out.get("traceback", "")}
                store.save_failure(spec, failure)
                exp.failures.append(failure)
                _log(f"run {spec.name} FAILED after {len(errors)} attempts: {out['error']}")
                bar.update(1)
                bar.set_postfix(failed=len(exp.failures))


def reproduce(config: ReproduceConfig, train=train_run, write: bool = True, desc: str = "reproduce") -> Experiment:
    """Run (or resume) the experiment, then write its outputs to config.out (unless write=False).

    train(spec) -> result dict is the function each worker calls (runs.train_run); it must be
    importable by the workers (a module-level function). Other experiments (claims.py) schedule
    their runs with it too: config needs specs(), out, overwrite, workers, ray, progress, retries.
    """
    from tqdm import tqdm

    from lab.experiments.executors import ProcessExecutor, RayExecutor

    t0 = time.perf_counter()
    specs = config.specs()
    exp = Experiment(config, specs, started=time.strftime("%Y-%m-%d %H:%M:%S %z"),
                     load_before=os.getloadavg())
    store = RunStore(config.out / "runs")
    store.check_writable()  # before any run: an --out that cannot take files was found after the first
    pending = []
    for spec in specs:
        stored = store.load(spec, overwrite=config.overwrite)
        if stored is None:
            pending.append(spec)
        else:
            exp.results[spec.name] = stored
    exp.resumed, exp.executed = len(specs) - len(pending), len(pending)
    pending.sort(key=lambda spec: spec.cost(), reverse=True)  # longest runs first
    executor = RayExecutor(config.ray) if config.ray else ProcessExecutor(config.workers)
    with tqdm(total=len(specs), initial=exp.resumed, unit="run", desc=desc,
              disable=not config.progress, dynamic_ncols=True) as bar:
        if pending:
            with executor:
                exp.executor = executor.describe()
                _execute(exp, pending, executor, train, store, bar)
        else:
            exp.executor = "none (every run was stored)"
    exp.wall_seconds = time.perf_counter() - t0
    exp.load_after = os.getloadavg()
    if write:
        from lab.experiments.report import write_outputs

        write_outputs(exp)
    return exp
