"""Evolution backends behind one interface (`Backend`): each `step()` advances one generation.

    backend = make_backend(problem, config)     # CMA-ES or NEAT, by config.method
    result = backend.step()                     # evaluates and updates one generation
    backend.best, backend.best_mse              # best controller so far and its training MSE
    backend_type(method).settings(problem, config)   # its hyperparameters, without building one

Backends never start threads; `lab.runner.Runner` drives them.
"""

from __future__ import annotations

from ..config import TrainConfig
from ..problem import Problem
from .base import Backend, StepResult


def backend_type(method: str) -> type[Backend]:
    """The Backend class of one method ("cmaes" or "neat"), imported on first use."""
    if method == "cmaes":
        from .cmaes import CMAESBackend

        return CMAESBackend
    if method == "neat":
        from .neat import NEATBackend

        return NEATBackend
    raise ValueError(f"unknown method {method!r}")


def make_backend(problem: Problem, config: TrainConfig) -> Backend:
    return backend_type(config.method)(problem, config)


__all__ = ["Backend", "StepResult", "backend_type", "make_backend"]
