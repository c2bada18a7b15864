"""Lab: neuro-controllers evolved (CMA-ES, NEAT, or a method of your own) to solve inverse kinematics.

    import lab
    run = lab.evolve(robot="planar", method="cmaes", generations=1000, population=50, targets=70, seed=0)
    run.controller(goals)        # (n, len(task_axes)) -> (n, nq) within the joint limits
    run.train_mse, run.test_mse  # final best on the training and held-out goals
    lab.solve(run.controller, "ur5", goals)  # the network, then refinement: q, each goal's error (lab/solver.py)
    lab.solve(None, arm, poses)  # pose goals (n, 4, 4): the compiled solver, 5 ms a pose, 1e-5 m and 1e-5 rad
    lab.evolve("erd:ur3", seconds=60)  # any robot: a registered name, erd:NAME, a URDF path, or a robots.Arm
    lab.pretrained("panda", goal="pose")  # a controller the project ships (lab/shipped.py)
    lab.evolve("ur5", seconds=60)  # a time budget: 60 s of optimizer time, then its best controller
    lab.load_controller("recordings/....rrd", generation=None)  # a controller back from a Rerun recording
    lab.Runner(config) / lab.ProcessRunner(config)  # a run in a background thread / in a worker process
    lab.methods.names(), lab.methods.register(...)  # the methods (examples/custom_method.py adds one)

Sub-packages, in the direction data flows:
    problem/     encoding, controllers, compiled kernels, the fitness (Problem)
    methods/     the registry and one module per method (CMA-ES, NEAT)
    running/     TrainConfig, the Runner (thread) and ProcessRunner (worker process), evolve, warm-up
    recording/   the Rerun logger, its writer process, replay, what recordings draw
    experiments/ the paper's tables and figures (python -m lab reproduce)
Nothing here knows about the GUI.
"""

from lab import methods
from lab.methods import Backend, Method, Options, StepResult
from lab.problem.environment import SettingError
from lab.problem.controllers import Controller, GraphController, MLPController, controller_from_dict
from lab.running.config import TrainConfig
from lab.running.evolve import Run, evolve
from lab.running.runner import GenerationEvent, Runner, RunSummary
from lab.shipped import pretrained
from lab.solver import Solution, solve

__all__ = [
    "Backend", "Controller", "GenerationEvent", "GraphController", "MLPController", "Method", "Options",
    "ProcessRunner", "RerunLogger", "Run", "RunSummary", "Runner", "SettingError", "Solution", "StepResult", "TrainConfig",
    "controller_from_dict", "evolve", "load_controller", "methods", "pretrained", "read_recording", "solve",
]


def __getattr__(name: str):
    """ProcessRunner, RerunLogger, load_controller and read_recording are imported when first used
    (rerun: ~0.7 s)."""
    if name == "ProcessRunner":  # not imported above: `python -m lab.running.worker` must be its first import
        from lab.running.worker import ProcessRunner

        return ProcessRunner
    if name == "RerunLogger":
        from lab.recording.logger import RerunLogger

        return RerunLogger
    if name in ("load_controller", "read_recording"):
        from lab.recording import replay

        return getattr(replay, name)
    raise AttributeError(f"module 'lab' has no attribute {name!r}")
