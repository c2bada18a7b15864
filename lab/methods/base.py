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
from typing import Protocol

import numpy as np

from lab.problem import Problem
from lab.problem.controllers import Controller, mlp_joints  # noqa: F401 (mlp_joints: methods import it from here)


def option(default, help: str):
    """A field of an Options dataclass: its default and a one-line help (CLI, app, docs)."""
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


class RunSettings(Protocol):
    """What a method reads of a run's settings: the fields every method shares, with the arm's and
    method's defaults filled in, and the method's own Options. lab.running.TrainConfig is one; a
    method never needs to know that class (running/ drives methods/, never the reverse)."""

    method: str  # the method's registered name
    seed: int  # the run's random seed
    generations: int  # the steps the run will take (a schedule may span them)
    population: int  # candidates per generation
    hidden: int  # MLP hidden units; graph methods: hidden nodes of the first networks
    heads: int  # an MLP's output heads (1: single-head networks)
    seconds: float | None  # a time budget of optimizer time (None: none; Backend.progress follows it)
    options: Options  # the method's own settings


# The inputs and output mapping of a real arm, shared by every method that trains an MLP or a graph
# on one (their reasons: docs/results/real-arms.md and docs/results/budgets.md).
# arms whose base turns less than a turn, so that the goals behind them lie across the bearing's seam:
# the bearing twice, from the front and from behind (lab/problem/encoding.py, "bearings"). Not SO100:
# there it raised the median error (docs/log.md)
BEARINGS_ARMS = {"so101"}
# the output margin of an arm whose every limited joint turns less than a full turn (SO100, SO101, Z1,
# Panda, Kinova): there the limits bind, and uniformly drawn goals often need a joint near one, where
# a margin of 0 asks the output tanh to saturate; 0.3 lowers each such arm's median error
# (docs/results/real-arms.md, docs/log.md). The arms with joints of +-2 pi (UR5, UR10, xArm7) keep 0:
# their limits lie two turns apart
LIMITED_MARGIN = 0.3

def margin_of(arm) -> float:
    """A real arm's output margin: LIMITED_MARGIN when every joint with limits turns less than a full
    turn between them (continuous joints take no margin: lab/problem/encoding.py), else 0."""
    limited = ~np.asarray(arm.chain.continuous, bool)
    return LIMITED_MARGIN if bool(np.all((arm.upper - arm.lower)[limited] < 2 * np.pi - 1e-9)) else 0.0


def can_turn(arm) -> bool:
    """Whether the first joint can be turned in closed form toward the goal (lab/problem/encoding.py,
    the turn): a revolute first joint and 3-D goals (not a mobile manipulator's lift, say)."""
    return not bool(arm.is_prismatic[0]) and tuple(arm.task_axes) == (0, 1, 2)


def real_arm_io(arm) -> dict:
    """A real arm's network inputs and output mapping: "sphere" inputs ("bearings" on BEARINGS_ARMS),
    the output margin margin_of(arm), and the first joint turned in closed form toward the goal
    (lab/problem/encoding.py, the turn) where it can be (can_turn: a robot of a URDF whose first joint
    slides, as PR2's and TIAGo's torso lifts, is not turned)."""
    return dict(features="bearings" if arm.name in BEARINGS_ARMS else "sphere", margin=margin_of(arm),
                turn=can_turn(arm))


@dataclass(frozen=True, eq=False)
class Population:
    """The candidates one generation evaluated (Backend.candidates()).

    mse: (n,) each candidate's training MSE (+inf for NaN/inf output), as StepResult.fitness;
    controllers: the n candidates as controllers, or None where they were left out (the recording
        and the pipe carry them only at a bounded rate, lab.running.runner.POPULATION_PERIOD);
    species: (n,) each candidate's species id, or None for a method without species;
    points: (n, 3) each candidate's end-effector point at the recording's display goal ((n, E, 3) on a tree)
        (lab.running.decimation.display_goal), filled in by the runner, or None.
    """

    generation: int
    mse: np.ndarray
    controllers: tuple | None = None
    species: np.ndarray | None = None
    points: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.mse)

    def joints(self, goals: np.ndarray) -> np.ndarray:
        """(n, len(goals), nq): every candidate's joint values for goals (len(goals), len(task_axes))."""
        if self.controllers is None:
            raise ValueError("this population was sent without its controllers")
        return population_joints(self.controllers, goals)

    def reach(self, arm, goals: np.ndarray) -> np.ndarray:
        """(n, len(goals), 3): every candidate's end-effector point for each goal ((n, len(goals), E, 3) on a tree)."""
        q = self.joints(goals)
        p = arm.fk(q.reshape(-1, q.shape[-1]))
        return p.reshape(*q.shape[:2], *p.shape[1:])


def population_joints(controllers, goals: np.ndarray) -> np.ndarray:
    """(n, g, nq) joint values of n controllers on goals (g, task dims): one compiled call when
    they are all MLPs of one shape or all graphs of one encoding, one call each otherwise."""
    from lab.problem.controllers import GraphController, MLPController, compile_programs, run_programs

    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    first = controllers[0]
    enc = first.encoding
    same = all(c.encoding is enc for c in controllers)  # one pickle keeps them one object
    if same and all(isinstance(c, MLPController) and c.hidden == first.hidden and c.heads == first.heads
                    and np.array_equal(c.anchors, first.anchors) for c in controllers):
        return mlp_joints(enc, first.hidden, np.stack([c.weights for c in controllers]), goals, first)
    elif same and all(isinstance(c, GraphController) for c in controllers):
        a = run_programs(compile_programs(controllers), enc.inputs(goals))
    else:
        return np.stack([c(goals) for c in controllers])
    return enc.joints(a, goals)  # (n, goals, nq)


def mlp_shape(problem: Problem, config: RunSettings):
    """A zero-weight MLPController of the run's shape (config.hidden, config.heads; several heads carry
    the arm's kinematic chain): what a method's networks are built like (MLPController(s.encoding,
    s.hidden, weights, s.heads, s.anchors, s.chain))."""
    from lab.problem.controllers import MLPController, mlp_size

    from lab.problem.tree_encoding import tree_arrays

    enc, heads, arm = problem.encoding, config.heads, problem.arm
    chain = None if heads == 1 else tree_arrays(arm) if arm.is_tree else arm.chain.arrays
    return MLPController(enc, config.hidden, np.zeros(mlp_size(enc.n_inputs, config.hidden, enc.n_outputs * heads)),
                         heads, None, chain)


@dataclass(frozen=True)
class StepResult:
    """What one generation (one step) produced.

    fitness: (population,) training MSE of every controller evaluated (+inf for NaN/inf output)
    extras:  the method's own scalars to log (CMA-ES: sigma, restarts; NEAT: species, nodes, ...),
             named in its Method.search_series; values that are not numbers (NEAT's species
             sizes, a {species id: size} mapping) are for its Method.live_plots only
    evaluations: controller evaluations this step counts (None: one per fitness value)
    """

    fitness: np.ndarray
    extras: dict = field(default_factory=dict)
    evaluations: int | None = None


class Backend(ABC):
    """One method on one problem. Not thread-safe: one thread calls step().

    config.options holds the method's Options; self.best / self.best_mse the best controller so
    far and its training MSE (kept by `_offer`)."""

    def __init__(self, problem: Problem, config: RunSettings):
        self.problem = problem
        self.config = config
        self.options = config.options
        self.generation = 0
        self.evaluations = 0
        self.best: Controller | None = None
        self.best_mse = np.inf
        # the share of the run done before this step: generations done / generations, or with a time
        # budget optimizer time spent / budget if that is larger (the runner sets it; a schedule may follow it)
        self.progress = 0.0

    @abstractmethod
    def _step(self) -> StepResult: ...

    def step(self) -> StepResult:
        """Evaluate and update one generation (on new training goals if the problem resamples them)."""
        if self.problem.resampling:
            self.problem.draw_goals(self.generation)
        result = self._step()
        self._fitness = result.fitness
        self.generation += 1
        self.evaluations += len(result.fitness) if result.evaluations is None else int(result.evaluations)
        return result

    keeps_candidates = False  # True: the backend implements _candidate_controllers() (a population method)

    def candidates(self, controllers: bool = True) -> Population | None:
        """The candidates of the last step (None before the first step): their training MSE and
        species, and with `controllers` each one's controller.

        A backend that does not keep its candidates (keeps_candidates False: a method with one
        network, or a plug-in that says no more) shows its best controller so far: a population of
        one. Controllers are built here only, when asked (at a bounded rate), never in step();
        nothing here draws random numbers, so asking never changes a run."""
        fitness = getattr(self, "_fitness", None)
        if fitness is None:
            return None
        if not self.keeps_candidates:
            if self.best is None:
                return None
            return Population(self.generation - 1, np.array([self.best_mse]), (self.best,) if controllers else None)
        species = self._candidate_species()
        return Population(self.generation - 1, np.asarray(fitness, float),
                          tuple(self._candidate_controllers()) if controllers else None,
                          None if species is None else np.asarray(species, np.int64))

    def candidate_reach(self, goals: np.ndarray) -> np.ndarray:
        """(n, len(goals), 3) ((n, len(goals), E, 3) on a tree): each candidate's end-effector points for each goal, in the order of
        candidates() (through _candidate_joints where the backend has a faster way than its controllers)."""
        goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
        q = self._candidate_joints(goals) if self.keeps_candidates else None
        if q is None:
            return self.candidates().reach(self.problem.arm, goals)
        p = self.problem.arm.fk(q.reshape(-1, q.shape[-1]))
        return p.reshape(*q.shape[:2], *p.shape[1:])

    def _candidate_controllers(self) -> list:
        """The last step's candidates as controllers, in the order of its fitness (keeps_candidates)."""
        raise NotImplementedError

    def _candidate_species(self) -> list | None:
        """Each candidate's species id, or None for a method without species."""
        return None

    def _candidate_joints(self, goals: np.ndarray) -> np.ndarray | None:
        """(n, len(goals), nq) joint values of the candidates, or None: from their controllers."""
        return None

    @classmethod
    def settings(cls, problem: Problem, config: RunSettings) -> dict:
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
