"""The backend contract shared by CMA-ES and NEAT."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from ..config import TrainConfig
from ..controllers import Controller
from ..problem import Problem


@dataclass(frozen=True)
class StepResult:
    """What one generation produced.

    fitness: (population,) training MSE of every evaluated controller (+inf for NaN/inf output)
    extras:  backend-specific scalars to log (CMA-ES: sigma, restarts; NEAT: species, nodes, ...)
    """

    fitness: np.ndarray
    extras: dict = field(default_factory=dict)


class Backend(ABC):
    """One evolutionary method on one problem. Not thread-safe: one thread calls step()."""

    method: str

    def __init__(self, problem: Problem, config: TrainConfig):
        self.problem = problem
        self.config = config
        self.generation = 0
        self.evaluations = 0
        self.best: Controller | None = None
        self.best_mse = np.inf

    @abstractmethod
    def _step(self) -> StepResult: ...

    def step(self) -> StepResult:
        """Evaluate and update one generation."""
        result = self._step()
        self.generation += 1
        self.evaluations += len(result.fitness)
        return result

    @classmethod
    def settings(cls, problem: Problem, config: TrainConfig) -> dict:
        """The hyperparameters a backend of this class runs with on (problem, config); logged
        with the recording. A function of its arguments alone, so no backend has to be built."""
        return {}

    def hyperparameters(self) -> dict:
        """This backend's settings(problem, config)."""
        return self.settings(self.problem, self.config)

    def _offer(self, mse: float, make_controller) -> None:
        """Keep the best controller so far (make_controller is only called on improvement)."""
        if np.isfinite(mse) and mse < self.best_mse:
            self.best_mse = float(mse)
            self.best = make_controller()
