"""Evolution backends behind one interface (`Backend`): each `step()` advances one generation.

    backend = make_backend(problem, config)     # CMA-ES or NEAT, by config.method
    result = backend.step()                     # evaluates and updates one generation
    backend.best, backend.best_mse              # best controller so far and its training MSE

Backends never start threads; `lab.runner.Runner` drives them.
"""

from __future__ import annotations

from ..config import TrainConfig
from ..problem import Problem
from .base import Backend, StepResult


def make_backend(problem: Problem, config: TrainConfig) -> Backend:
    if config.method == "cmaes":
        from .cmaes import CMAESBackend

        return CMAESBackend(problem, config)
    if config.method == "neat":
        from .neat import NEATBackend

        return NEATBackend(problem, config)
    raise ValueError(f"unknown method {config.method!r}")


__all__ = ["Backend", "StepResult", "make_backend"]
