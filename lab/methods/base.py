"""What every method provides: its options (a frozen dataclass) and its backend (ask, evaluate, tell).

    class MyOptions(Options):            # @dataclass(frozen=True), fields with defaults
        step: float = option(0.1, "perturbation size")
        def check(self): real(self, "step", 0, 1e6, "a positive number", closed_below=False)

    class MyBackend(Backend):
        def _step(self) -> StepResult:   # one generation: evaluate, update, offer the best
            ...

A backend never starts threads; lab.running.Runner drives it one `step()` at a time.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lab.problem import Problem
from lab.problem.controllers import Controller

if TYPE_CHECKING:
    from lab.running.config import TrainConfig


def option(default, help: str):
    """A field of an Options dataclass: its default and a one-line help (CLI, app, README)."""
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class Options:
    """A method's options. Subclasses are frozen dataclasses whose fields all have defaults
    (use `option(default, help)`); `check()` validates them (lab.problem.checks) and runs on
    construction, so an Options object is always valid."""

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise ValueError naming the field that is wrong; may normalise values in place."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def describe(cls) -> dict:
        """name -> (default, type, help) of every option."""
        return {f.name: (f.default, type(f.default), f.metadata.get("help", "")) for f in dataclasses.fields(cls)}


@dataclass(frozen=True)
class StepResult:
    """What one generation (one step) produced.

    fitness: (population,) training MSE of every controller evaluated (+inf for NaN/inf output)
    extras:  the method's own scalars to log (CMA-ES: sigma, restarts; NEAT: species, nodes, ...),
             named in its Method.search_series
    evaluations: controller evaluations this step counts (None: one per fitness value)
    """

    fitness: np.ndarray
    extras: dict = field(default_factory=dict)
    evaluations: int | None = None


class Backend(ABC):
    """One method on one problem. Not thread-safe: one thread calls step().

    config.options holds the method's Options; self.best / self.best_mse the best controller so
    far and its training MSE (kept by `_offer`)."""

    def __init__(self, problem: Problem, config: TrainConfig):
        self.problem = problem
        self.config = config
        self.options = config.options
        self.generation = 0
        self.evaluations = 0
        self.best: Controller | None = None
        self.best_mse = np.inf

    @abstractmethod
    def _step(self) -> StepResult: ...

    def step(self) -> StepResult:
        """Evaluate and update one generation (on new training goals if the problem resamples them)."""
        if self.problem.resampling:
            self.problem.draw_goals(self.generation)
        result = self._step()
        self.generation += 1
        self.evaluations += len(result.fitness) if result.evaluations is None else int(result.evaluations)
        return result

    @classmethod
    def settings(cls, problem: Problem, config: TrainConfig) -> dict:
        """The hyperparameters a backend of this class runs with on (problem, config); logged
        with the recording. A function of its arguments alone, so no backend has to be built."""
        return config.options.to_dict()

    def hyperparameters(self) -> dict:
        """This backend's settings(problem, config)."""
        return self.settings(self.problem, self.config)

    def _offer(self, mse: float, make_controller) -> None:
        """Keep the best controller so far (make_controller is only called on improvement).

        With resampled training goals, mse (on this generation's goals) is not comparable with
        earlier generations': the candidate is scored on the problem's fixed reference goals
        instead, and kept by that MSE (one more controller evaluation per generation, not counted
        in `evaluations`: it steers no search, only which controller is reported)."""
        if self.problem.resampling:
            if not np.isfinite(mse):
                return
            candidate = make_controller()
            mse = self.problem.controller_mse(candidate, self.problem.reference_goals)
            if np.isfinite(mse) and mse < self.best_mse:
                self.best_mse, self.best = float(mse), candidate
            return
        if np.isfinite(mse) and mse < self.best_mse:
            self.best_mse = float(mse)
            self.best = make_controller()
