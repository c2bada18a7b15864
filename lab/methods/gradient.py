"""Gradient descent (Adam) on the weights of the paper's MLP, through the arm's kinematics.

Not in the paper: a baseline that uses what evolution does not, the derivative of the fitness.
The network, its weight layout and its output mapping are CMA-ES's (lab.problem.controllers.
MLPController); the loss is the fitness every method minimizes, the mean over the fixed training
goals of ||p - p'||^2. Its gradient comes by backpropagation through the output mapping (whose clip
to the joint limits passes no gradient outside them) and the two tanh layers, times the arm's
positional Jacobian (Problem.mlp_gradient, robots.Arm.jacobian). One step() is one Adam step on
the whole training set (no mini-batches): the fitness it reports is the loss of the weights it
started the step with (mlp_mse, the kernel every MLP method is scored by), and those weights are
offered as the best controller.

Evaluations, in the lab's unit (one controller on every training goal): 1 + nq per step: one
forward pass for the loss and nq for the Jacobian, what forward-mode or finite differences would
pay (this backend's analytic Jacobian walks the chain once per goal, so the count is an upper
bound of its kinematic work, never an understatement). `population` is not used.

Randomness: only the initial weights, from the backend's own numpy Generator (seed): same seed,
same run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lab.methods.base import Backend, Options, StepResult, can_turn, option, real_arm_io
from lab.methods.registry import LivePlot, Method, register
from lab.problem.checks import real
from lab.problem.controllers import MLPController, mlp_size
from lab.problem.robot import arm_kind
from lab.problem.wiring import Wiring


TREE_TARGETS = 3000  # a tree's training goals (defaults)


@dataclass(frozen=True)
class GradientOptions(Options):
    learning_rate: float = option(0.01, "Adam step size (the largest change of a weight per step, about)")
    beta1: float = option(0.9, "Adam: decay of the running mean of the gradient, in [0, 1)")
    beta2: float = option(0.999, "Adam: decay of the running mean of the squared gradient, in [0, 1)")
    adam_epsilon: float = option(1e-8, "Adam: added to the root of the squared-gradient mean")
    init_scale: float = option(0.1, "std of the initial weights, drawn from a normal (CMA-ES's start: 0.1)")
    final_rate: float = option(0.1, "learning rate at the last step as a fraction of learning_rate "
                                    "(cosine decay over the run's generations; 1: constant)")

    def check(self) -> None:
        real(self, "learning_rate", 0, 10, "a positive number up to 10", closed_below=False)
        real(self, "beta1", 0, 1, "a number in [0, 1)", closed_above=False)
        real(self, "beta2", 0, 1, "a number in [0, 1)", closed_above=False)
        real(self, "adam_epsilon", 0, 1, "a positive number up to 1", closed_below=False)
        real(self, "init_scale", 0, 100, "a positive number up to 100", closed_below=False)
        real(self, "final_rate", 0, 1, "a fraction in [0, 1]")


class GradientBackend(Backend):
    def __init__(self, problem, config):
        super().__init__(problem, config)
        enc = problem.encoding
        self.dim = mlp_size(enc.n_inputs, config.hidden, enc.n_outputs)
        self.rng = np.random.default_rng(config.seed)
        self.w = self.rng.normal(0.0, self.options.init_scale, self.dim)
        # a tree's limb-wired network (lab/problem/wiring.py): the weights off the wiring stay zero
        self.mask = (Wiring.for_arm(problem.arm, enc.n_inputs, config.hidden).mask
                     if getattr(config, "wiring", False) else None)
        if self.mask is not None:
            self.w = np.where(self.mask, self.w, 0.0)
        self.m = np.zeros(self.dim)
        self.v = np.zeros(self.dim)

    @classmethod
    def settings(cls, problem, config) -> dict:
        enc = problem.encoding
        return {"dim": mlp_size(enc.n_inputs, config.hidden, enc.n_outputs), "hidden": config.hidden,
                **config.options.to_dict(), "evaluations_per_step": 1 + problem.arm.nq}

    def learning_rate(self, step: int) -> float:
        """Cosine decay from learning_rate at step 0 to final_rate x learning_rate at the last step
        (with a time budget: over the run's progress, time spent / budget, Backend.progress)."""
        o = self.options
        last = max(self.config.generations - 1, 1)
        frac = min(step, last) / last
        if self.config.seconds is not None:
            frac = min(max(frac, self.progress), 1.0)
        return float(o.learning_rate * (o.final_rate + (1.0 - o.final_rate) * 0.5 * (1.0 + np.cos(np.pi * frac))))

    def _step(self) -> StepResult:
        o = self.options
        hidden = self.config.hidden
        w = self.w
        f = float(self.problem.mlp_mse(w[None], hidden)[0])  # the fitness, as every method's
        self._evaluated = w
        self._offer(f, lambda: MLPController(self.problem.encoding, hidden, w.copy()))
        _, g = self.problem.mlp_gradient(w, hidden)
        if self.mask is not None:
            g = np.where(self.mask, g, 0.0)
        norm = float(np.linalg.norm(g))
        lr = self.learning_rate(self.generation)
        if np.isfinite(norm):  # a NaN gradient (weights blown up) moves nothing
            t = self.generation + 1
            self.m = o.beta1 * self.m + (1.0 - o.beta1) * g
            self.v = o.beta2 * self.v + (1.0 - o.beta2) * g * g
            m_hat = self.m / (1.0 - o.beta1 ** t)
            v_hat = self.v / (1.0 - o.beta2 ** t)
            self.w = w - lr * m_hat / (np.sqrt(v_hat) + o.adam_epsilon)
        return StepResult(np.array([f]), {"gradient_norm": norm, "learning_rate": lr},
                          evaluations=1 + self.problem.arm.nq)


    keeps_candidates = True

    def _candidate_controllers(self):
        """Its single network: the weights this step evaluated."""
        return [MLPController(self.problem.encoding, self.config.hidden, self._evaluated)]


def defaults(arm) -> dict:
    """The settings the gradient method runs with on an arm when none are given (the comparisons
    behind them: docs/results/paper-budget.md, docs/results/real-arms.md; their figures:
    docs/log.md).

    The paper's arms and the snakes: CMA-ES's inputs ("reach"), hidden size and output margin 2.
    A margin clips outputs beyond a limit and passes them no gradient, yet it wins by far on the
    planar arm: as for CMA-ES, a goal at a joint limit then asks no saturated tanh. Learning rate
    0.03 (the best of 0.003, 0.01 and 0.03 at 3000 steps), 3000 steps (about a second on planar).
    Real arms: CMA-ES's real-arm network, goals, inputs and turn (real_arm_io: the first joint turned
    in closed form toward the goal, whose gradient is then stationary in that joint), output margin 0
    (a margin clips, and a clipped output passes no gradient), the default learning rate and 20,000
    steps (about 20-30 s).
    Trees (several end effectors): "sphere" inputs in each limb frame, each limb that moves one
    effector alone turned in closed form (as CMA-ES's trees), TREE_TARGETS training goals: with 300,
    a full-batch descent fits them and generalizes badly (the comparisons: docs/log.md)."""
    if arm_kind(arm) in ("paper", "snake"):
        return dict(features="reach", margin=2.0, hidden=5, population=1, generations=3000, learning_rate=0.03)
    if arm_kind(arm) == "tree":
        return dict(features="sphere", margin=0.0, hidden=32, targets=TREE_TARGETS, population=1, generations=20_000,
                    turn=True)
    return dict(real_arm_io(arm), margin=0.0, hidden=32, targets=300, population=1, generations=20_000)


def budget_defaults(arm, seconds: float) -> dict:
    """With a time budget: defaults(arm) without its generations; the learning rate decays over the
    budget (learning_rate: Backend.progress)."""
    return {k: v for k, v in defaults(arm).items() if k != "generations"}


POSE_TURN = True  # pose goals: the first joint turned toward the position's bearing (docs/log.md)


def pose_defaults(arm, seconds: float | None) -> dict:
    """Pose goals (TrainConfig.goal "pose", a real arm), over defaults_for's: the real-arm network and
    inputs, the first joint turned when POSE_TURN (its gradient is then taken with that joint held:
    lab.problem.pose_fitness.PoseProblem.mlp_gradient), chosen by short runs (docs/log.md); no closed-
    form reach (the elbow and shoulder it solves would be held too: on a 6-joint arm no joint is left
    to learn)."""
    return dict(real_arm_io(arm), margin=0.0, turn=POSE_TURN and can_turn(arm), reach=0)


METHOD = register(Method(
    name="gradient", label="Gradient (Adam)", color=(44, 160, 44),
    summary="Adam on the MLP's weights, gradient by backpropagation through the arm's Jacobian",
    backend_class=GradientBackend, options=GradientOptions, controller="mlp",
    defaults=defaults, budget_defaults=budget_defaults, pose_defaults=pose_defaults, paper=None, min_population=1, min_hidden=1,
    search_title="Adam: gradient norm and learning rate",
    search_series="the norm of the loss gradient and the learning rate per step",
    cost=1.0, compile_seconds=(2.0, 0.5), step_evaluations=lambda arm, config: 1 + arm.nq,
    ablations=("margin=0.0", "margin=0.5", "hidden=16", "learning_rate=0.01", "final_rate=1.0"),
    live_plots=(
        LivePlot("gradient_norm", "Gradient norm", log=True, about=(
            "The length of the loss gradient the single network follows: the steepness of the error "
            "surface where its weights are. It falls as the network settles into a minimum; spikes are "
            "steep walls, where Adam's step-size normalisation keeps the step bounded.")),
    ),
))
