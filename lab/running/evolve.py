"""`lab.evolve`: train one controller, blocking, and return what it learned."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from lab.methods import DEFAULT_METHOD
from lab.running.config import TrainConfig
from lab.problem.controllers import Controller
from lab.running.runner import Runner, RunSummary


@dataclass(frozen=True)
class Run:
    """The result of one training run.

    controller(goals) maps goals (n, len(task_axes)) to joint values (n, nq) within the limits;
    train_mse / test_mse: the final best controller's MSE on the training and held-out goals;
    history: best training MSE so far, per generation.
    """

    config: TrainConfig
    controller: Controller
    train_mse: float
    test_mse: float
    history: np.ndarray
    median_history: np.ndarray
    n_params: int
    seconds: float
    evaluations: int
    state: str
    run_id: str

    @classmethod
    def from_summary(cls, s: RunSummary) -> "Run":
        return cls(s.config, s.controller, s.train_mse, s.test_mse, s.history, s.median_history,
                   s.controller.n_params if s.controller is not None else 0, s.seconds, s.evaluations,
                   s.state, s.run_id)


def evolve(robot="planar", method: str = DEFAULT_METHOD, generations: int | None = None,
           population: int | None = None, targets: int | None = None, seed: int = 0, *, paper: bool = False,
           seconds: float | None = None, goal: str = "position", ee: str | None = None,
           subscribers: Iterable[Callable] = (), **options) -> Run:
    """Evolve a neuro-controller for `robot` with `method` (lab.methods.names()); blocks until done.

    robot: a registered name, erd:NAME (an example-robot-data robot), a URDF file's path, or a
    robots.Arm (robots.load(ROBOT, ee=FRAME)); ee: the tool frame of a robot given by string. The
    run's config.robot is its canonical string (lab/problem/robot.py). Any robot gets its method's
    defaults from its kind, joint count and reach (Method.defaults_for): an arm of a URDF those of a
    registered real arm.

    generations, population, targets: None is the method's default for the arm (the paper's
    protocol, 1000, 50 and 70, unless the method declares others for that arm).
    seconds: a time budget, s of optimizer time: the run ends when it is spent (state "finished",
    with its best controller so far); with generations too, whichever comes first; without them,
    generations are unbounded, and the method's defaults are its defaults for that budget
    (lab.methods.Method.defaults_for). None: no budget.
    paper=True uses the paper's literal method (the method's paper preset); options override
    single settings: TrainConfig's (hidden, features, margin, test_goals, goal_seed) and the
    method's own options by name (CMA-ES: sigma0, diagonal, restarts; NEAT: mutation_power, ...).
    goal="pose": the controller answers tool frames (n, 4, 4) (robots.pose.sample_poses) with joint
    values, its fitness the position error plus the weighted angle (lab/problem/pose_fitness.py;
    a real arm only).
    subscribers get every GenerationEvent (see lab.running.runner).
    """
    config = TrainConfig.preset(paper=paper, robot=robot, method=method, generations=generations,
                                population=population, targets=targets, seed=seed, seconds=seconds,
                                goal=goal, ee=ee, **options)
    runner = Runner(config)
    for s in subscribers:
        runner.subscribe(s)
    summary = runner.run()
    if summary.state == "failed":
        raise RuntimeError(f"training failed: {summary.error}")
    return Run.from_summary(summary)
