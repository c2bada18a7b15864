"""Lab: neuro-controllers evolved by CMA-ES and NEAT to solve inverse kinematics.

    import lab
    run = lab.evolve(robot="planar", method="cmaes", generations=1000, population=50, targets=70, seed=0)
    run.controller(goals)        # (n, len(task_axes)) -> (n, nq) within the joint limits
    run.train_mse, run.test_mse  # final best on the training and held-out goals
    lab.load_controller("recordings/....rrd", generation=None)  # a controller back from a Rerun recording
    lab.Runner(config) / lab.ProcessRunner(config)  # a run in a background thread / in a worker process

Nothing here knows about the GUI.
"""

from .config import TrainConfig
from .controllers import Controller, GraphController, MLPController, controller_from_dict
from .evolve import Run, evolve
from .runner import GenerationEvent, Runner, RunSummary

__all__ = [
    "Controller", "GenerationEvent", "GraphController", "MLPController", "ProcessRunner", "RerunLogger", "Run",
    "RunSummary", "Runner", "TrainConfig", "controller_from_dict", "evolve", "load_controller",
]


def __getattr__(name: str):
    """RerunLogger and load_controller import rerun (~0.7 s) only when first used."""
    if name == "ProcessRunner":  # not imported above: `python -m lab.worker` must be its first import
        from .worker import ProcessRunner

        return ProcessRunner
    if name == "RerunLogger":
        from .recording import RerunLogger

        return RerunLogger
    if name == "load_controller":
        from .replay import load_controller

        return load_controller
    raise AttributeError(f"module 'lab' has no attribute {name!r}")
