"""The paper's claims put to the test: `python -m lab claims --out DIR`.

Claim (ii): evolving the network "converges avoiding local optimal solutions, one of the main
drawbacks of neural network training based on gradient descent when applied to highly redundant
robot morphologies". Conclusion: a fixed set of training goals trains better than goals drawn
anew each generation.

    from lab.experiments.claims import ClaimsConfig, claims
    exp = claims(ClaimsConfig(runs=2, generations=50, out="/tmp/claims"))

Claim (ii): on each arm of ROBOTS, `runs` seeds of each method of METHODS (each with its
defaults for the arm), twice:
- at equal budget in evaluations (one controller evaluated on all its training goals, as each
  backend counts them): E = generations x the reference method's population on the arm; each
  method runs E // (its evaluations per step) steps (Method.evaluations_per_step);
- at equal time: every method gets T = generations x SECONDS_PER_GENERATION[arm] seconds of
  optimizer time (about what the reference method takes for E on this machine), stopped by
  lab.running.TimeLimit; its generation cap is CAP x its equal-budget generations (the gradient
  method's learning-rate decay spans that cap). These runs depend on the machine's speed and load.
Fixed vs resampled goals: the reference method on RESAMPLE_ROBOTS at equal budget, with
TrainConfig.resample (the fixed runs are the equal-budget runs above).

Each run stores, besides the reproduce runs' numbers, its held-out error (the median position
error over lab.experiments.arms' 2,000 held-out goals, in the arm's unit: mm for real arms, the
paper's units otherwise) at CHECKPOINTS log-spaced points of its budget and at its end, and its
training curve (best MSE so far against evaluations and seconds, thinned). Runs are scheduled,
stored and resumed by reproduce.reproduce (processes on all cores, or Ray).
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

import robots
from lab import methods
from lab.experiments.claims_design import (  # noqa: F401 (the design, named here too: claims.METHODS, ...)
    BUDGETS, CAP, CHECKPOINTS, DEFAULT_GENERATIONS, DEFAULT_RUNS, FIRST_CHECKPOINT, METHODS, POOR_FACTOR, POOR_REACH,
    RESAMPLE_ROBOTS, ROBOTS, SECONDS_PER_GENERATION, TARGET_REACH, generations_for, stuck,
)
from lab.experiments.runs import RunSpec, series_ok
from lab.recording.logger import not_a_folder


@dataclass(frozen=True)
class ClaimSpec(RunSpec):
    """A run of the claims experiment: RunSpec (population and targets None: the method's
    defaults) plus its budget: `budget` evaluations, or a limit of `seconds` (generations is then a cap)."""

    kind: str = "evaluations"  # "evaluations" (equal budget), "seconds" (equal time) or "resampled"
    budget: int = 0  # the arm's evaluation budget E (progress of "evaluations" and "resampled" runs)
    seconds: float = 0.0  # the time limit of a "seconds" run
    resample: bool = False

    @property
    def name(self) -> str:
        return f"{self.robot}-{self.method}-{self.kind}-s{self.seed:03d}"

    RESULT_FIELDS = {"seed": "count", "train_mse": "value", "test_mse": "value", "held_out": "value",
                     "generations": "count", "evaluations": "count", "seconds": "value"}  # train_claim's, as read
    CHECKPOINTS = ("evaluations", "seconds", "error")

    def damage(self, result) -> str | None:
        why = super().damage(result)
        if why is not None:
            return why
        cp = result.get("checkpoints")
        if not (isinstance(cp, dict) and all(series_ok(cp.get(k)) for k in self.CHECKPOINTS)
                and len({len(cp[k]) for k in self.CHECKPOINTS}) == 1):
            return (f"checkpoints is {str(cp)[:80]}, not lists of numbers >= 0 (no NaN) of one length under "
                    f"{', '.join(self.CHECKPOINTS)}")
        return None

    def config(self):
        from lab.running.config import TrainConfig

        return TrainConfig.preset(robot=self.robot, method=self.method, generations=self.generations,
                                  population=self.population, targets=self.targets, seed=self.seed,
                                  test_goals=self.test_goals, resample=self.resample)

    def cost(self) -> float:
        if self.kind == "seconds":
            return self.seconds
        return self.budget / 50 * SECONDS_PER_GENERATION[self.robot] * methods.get(self.method).cost


@dataclass(frozen=True)
class ClaimsConfig:
    runs: int = DEFAULT_RUNS
    generations: int = DEFAULT_GENERATIONS
    out: Path = Path("results/claims")
    seed: int = 0  # run i uses seed + i
    seconds: float | None = None  # the equal-time limit for every arm (None: generations x SECONDS_PER_GENERATION)
    test_goals: int = 1000  # the Problem's held-out MSE (the claims' held-out error uses arms.held_out_goals)
    workers: int | None = None
    ray: str | None = None
    retries: int = 1
    overwrite: bool = False
    progress: bool = True

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        for name in ("runs", "generations", "test_goals"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.seconds is not None and not (np.isfinite(self.seconds) and self.seconds > 0):
            raise ValueError(f"seconds must be a positive number, got {self.seconds!r}")
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")
        blocker = not_a_folder(self.out)
        if blocker is not None:
            raise ValueError(f"out must be a folder, but {blocker} is a file")

    def budget(self, robot: str) -> int:
        """The arm's evaluation budget E: generations of the reference method at its population."""
        ref = RunSpec(robot, METHODS[0], 0, self.generations, None, None).config()
        return self.generations * methods.get(METHODS[0]).evaluations_per_step(robots.load(robot), ref)

    def time_limit(self, robot: str) -> float:
        return self.seconds if self.seconds is not None else self.generations * SECONDS_PER_GENERATION[robot]

    def specs(self) -> list[ClaimSpec]:
        specs = []
        for robot in ROBOTS:
            arm, budget = robots.load(robot), self.budget(robot)
            for method in METHODS:
                m = methods.get(method)
                per = m.evaluations_per_step(arm, RunSpec(robot, method, 0, 1, None, None).config())
                gens = generations_for(budget, per)
                for i in range(self.runs):
                    common = dict(robot=robot, method=method, seed=self.seed + i, population=None, targets=None,
                                  test_goals=self.test_goals, budget=budget)
                    specs.append(ClaimSpec(generations=gens, kind="evaluations", **common))
                    specs.append(ClaimSpec(generations=CAP * gens, kind="seconds", seconds=self.time_limit(robot),
                                           **common))
                    if robot in RESAMPLE_ROBOTS and method == METHODS[0]:
                        specs.append(ClaimSpec(generations=gens, kind="resampled", resample=True, **common))
        for s in specs:
            s.config()  # ValueError naming the field before any work
        return specs


class _Curve:
    """A subscriber: the thinned training curve and the held-out error at log-spaced checkpoints."""

    def __init__(self, spec: ClaimSpec, arm, goals: np.ndarray):
        from lab.experiments.arms import error_stats, position_errors

        self.spec, self.arm, self.goals = spec, arm, goals
        self._error = lambda c: (error_stats(arm, position_errors(arm, c, goals))["median"]
                                 if c is not None else float("inf"))
        self.marks = list(np.geomspace(FIRST_CHECKPOINT, 1.0, CHECKPOINTS)[:-1])
        self.curve = {"generation": [], "evaluations": [], "seconds": [], "best": []}
        self.checkpoints = {"generation": [], "evaluations": [], "seconds": [], "error": []}
        self._next = 0
        self.last = None

    def progress(self, event) -> float:
        if self.spec.kind == "seconds":
            return event.seconds / self.spec.seconds
        return event.evaluations / self.spec.budget

    def _add(self, table: dict, event, **values) -> None:
        for k, v in (("generation", event.index), ("evaluations", event.evaluations), ("seconds", event.seconds),
                     *values.items()):
            table[k].append(float(v) if k in ("seconds", "best", "error") else int(v))

    def __call__(self, event) -> None:
        self.last = event
        if event.index >= self._next:
            self._add(self.curve, event, best=event.best)
            self._next = max(event.index + 1, int(event.index * 1.03))
        if self.marks and self.progress(event) >= self.marks[0]:
            error = self._error(event.controller)
            while self.marks and self.progress(event) >= self.marks[0]:
                self.marks.pop(0)
                self._add(self.checkpoints, event, error=error)

    def finish(self, controller) -> float:
        """The final held-out error; the marks not reached (a run ended early) get it too."""
        error = self._error(controller)
        if self.last is not None:
            if self.curve["generation"][-1:] != [self.last.index]:
                self._add(self.curve, self.last, best=self.last.best)
            for _ in range(len(self.marks) + 1):
                self._add(self.checkpoints, self.last, error=error)
        return error


def train_claim(spec: ClaimSpec) -> dict:
    """One run of the claims experiment (what each worker calls): a Runner with a _Curve
    subscriber (and a TimeLimit for an equal-time run)."""
    import platform

    from lab.experiments.arms import held_out_goals
    from lab.running.runner import Runner, TimeLimit

    t0, c0 = time.perf_counter(), time.process_time()
    runner = Runner(spec.config())
    arm = runner.problem.arm
    curve = _Curve(spec, arm, held_out_goals(arm))
    runner.subscribe(curve)
    if spec.kind == "seconds":
        runner.subscribe(TimeLimit(runner, spec.seconds))
    s = runner.run()
    if s.state == "failed":
        raise RuntimeError(f"training failed: {s.error}")
    held_out = curve.finish(s.controller)
    return {
        "name": spec.name, "robot": spec.robot, "method": spec.method, "seed": spec.seed, "kind": spec.kind,
        "spec": asdict(spec), "config": s.config.to_dict(), "state": s.state,
        "train_mse": s.train_mse, "test_mse": s.test_mse, "held_out": held_out,
        "unit": "mm" if robots.in_metres(spec.robot) else "paper units",
        "generations": s.generations, "evaluations": s.evaluations, "seconds": s.seconds,
        "curve": curve.curve, "checkpoints": curve.checkpoints,
        "wall_seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
        "controller": s.controller.to_dict() if s.controller is not None else None,
        "host": platform.node(), "pid": os.getpid(), "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


@dataclass
class ClaimsResult:
    """What claims() did: the scheduled experiment (reproduce.Experiment) and the files written."""

    config: ClaimsConfig
    experiment: object
    outputs: dict = field(default_factory=dict)

    def runs(self, robot: str, method: str, kind: str) -> list[dict]:
        exp = self.experiment
        return [exp.results[s.name] for s in exp.specs
                if (s.robot, s.method, s.kind) == (robot, method, kind) and s.name in exp.results]


def claims(config: ClaimsConfig, train=train_claim, write: bool = True) -> ClaimsResult:
    """Run (or resume) every run, then write claims.md and the figures to config.out."""
    from lab.experiments.reproduce import reproduce

    result = ClaimsResult(config, reproduce(config, train=train, write=False, desc="claims"))
    if write:
        from lab.experiments.claims_report import write_claims

        write_claims(result)
    return result
