"""CMA-ES (pycma, ask/tell) on the weights of a fixed-topology MLP (paper, sections 3 and 4.3).

Randomness: pycma samples with this backend's own numpy Generator (option `randn`), so a run
depends on its seed alone, never on numpy's global state, and runs in threads do not interfere.

Restarts (config.restarts): when pycma's own termination criteria fire or the run has not
improved its best by 1% in `STALL` generations, a new CMA-ES starts from a fresh random point
with the remaining budget; the best controller over all starts is kept. The generation count
and the evaluation budget (generations x population) are unchanged.
"""

from __future__ import annotations

import functools
import logging
import warnings
from dataclasses import dataclass

import numpy as np

from lab.methods.base import (BEARINGS_ARMS, LIMITED_MARGIN, Backend, Options, StepResult, margin_of,  # noqa: F401
                              mlp_joints, mlp_shape, option, real_arm_io)
from lab.methods.registry import LivePlot, Method, SpeedReference, register
from lab.problem.checks import flag, real, whole
from lab.problem.controllers import MAX_HEADS, MLPController, mlp_size
from lab.problem.robot import arm_kind
from lab.problem.wiring import Wiring

REAL_ARM_GENERATIONS = 45_000  # a real arm's budget: about 4-5 minutes on two cores for 5-7 joints
# arms whose goals lie on several IK branches that no single-head run serves: their heads, and fewer
# generations, so that the dearer generations of several heads still fit about 5 minutes
# (docs/results/real-arms.md; the timings in docs/log.md)
MULTI_HEAD_ARMS = {"ur5": dict(heads=2, generations=32_000), "so100": dict(heads=3, generations=26_000),
                   "so101": dict(heads=4, generations=20_000), "z1": dict(heads=2, generations=32_000)}
# a tree's settings (tree_defaults), with margin_of's margin (0.3 where every joint turns less than a turn: 0 on
# solo12, whose joints turn +-10 rad); wired per limb group (lab/problem/wiring.py), so hidden is shared out
# over the groups; each limb that moves one effector alone turned in closed form (lab/problem/tree_encoding.py)
TREE_SETTINGS = dict(features="sphere", hidden=64, targets=300, population=50, sigma0=0.05, separable=True, wiring=True,
                     turn=True)
# trees whose settings differ from TREE_SETTINGS (docs/log.md): g1's arm group (the waist and both arms,
# 17 joints) overfits 300 goals
TREE_ARMS = {"g1": dict(targets=600)}
log = logging.getLogger(__name__)
SHORT_BUDGET, SHORT_POPULATION = 15.0, 20  # a real arm's budget of at most 15 s: a population of 20
BUDGET_HEADS = {"so100": 2, "so101": 2}  # a real arm's heads with a time budget (the others: one)
STALL = 150  # generations without 1% improvement that end a start (restarts only)
_STOP_IGNORED = {"maxiter", "maxfevals", "ftarget"}


@functools.cache
def _cma():
    """pycma, imported on first use (about 1 s)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Could not import matplotlib"
        import cma
    # sep-CMA-ES's diagonal decoding warns of a large step of one weight: not an error (filtered
    # once here, not per generation on the hot path)
    warnings.filterwarnings("ignore", "elements of z2", UserWarning)
    # sep-CMA-ES adapts its step size by two-point adaptation (TPA), whose mirrored pair pycma checks
    # to the last bit; with ~400 weights that check can fail by rounding (seen once in 8 x 6,000
    # generations): a diagnostic, not an error
    warnings.filterwarnings("ignore", "TPA: apparent inconsistency", UserWarning)
    return cma


@dataclass(frozen=True)
class CMAESOptions(Options):
    sigma0: float = option(0.2, "initial step size")
    diagonal: int = option(100, "generations that adapt only the diagonal of C first (pycma CMA_diagonal)")
    restarts: bool = option(False, "restart from a new point when a start stagnates (same budget)")
    separable: bool = option(False, "sep-CMA-ES: a diagonal C for the whole run, linear time and memory in "
                                    "the number of weights (pycma CMA_diagonal=True; diagonal is then unused)")

    def check(self) -> None:
        real(self, "sigma0", 0, 1e6, "a positive number up to 1,000,000", closed_below=False)
        whole(self, "diagonal", 0, 10**9)
        flag(self, "restarts")
        flag(self, "separable")


class CMAESBackend(Backend):
    def __init__(self, problem, config):
        super().__init__(problem, config)
        self.shape = mlp_shape(problem, config)  # a zero-weight MLP of this run's hidden size and heads
        self.offsets = None if self.shape.heads == 1 else self.shape.offsets
        # a tree's limb-wired network (lab/problem/wiring.py): the search is over the wired weights alone,
        # one CMA-ES per limb group on that group's share of the error (the groups share no weight)
        self.wiring = (Wiring.for_arm(problem.arm, problem.encoding.n_inputs, config.hidden, config.heads)
                       if getattr(config, "wiring", False) else None)
        self.dim = self.shape.n_params if self.wiring is None else self.wiring.dim
        self._dims = (self.dim,) if self.wiring is None else self.wiring.sizes
        self.rng = np.random.default_rng(config.seed)
        self.restarts = 0
        self._start()
        tpa = _cma().evolution_strategy.TPA_dimension  # pycma's step-size rule is TPA from this dimension on
        if problem.resampling and self.options.separable and self.dim >= tpa:
            log.warning("resampled goals with sep-CMA-ES on %d weights: pycma adapts the step size by two-point "
                        "adaptation above %d weights, and with new goals every generation the step size collapses "
                        "(docs/log.md); fixed goals train better here", self.dim, tpa)

    def _start(self) -> None:
        self.searches = [self._search(d) for d in self._dims]
        self.es = self.searches[0]
        self._start_best = np.inf
        self._start_best_gen = self.generation
        self._group_best = [np.inf] * len(self.searches)  # a split search: each group's best so far
        self._group_x = [None] * len(self.searches)

    def _search(self, dim: int):
        x0 = self.rng.normal(0.0, 0.1, dim)
        opts = {
            "popsize": self.config.population,
            "randn": lambda *shape: self.rng.standard_normal(shape),
            "seed": np.nan,  # never touch numpy's global random state
            "verbose": -9,
            "verb_log": 0,
            "maxiter": np.inf,
            # sep-CMA-ES (True: diagonal throughout, with its own learning rates), or a fast,
            # diagonal-only start of `diagonal` generations (0: full C from the first)
            "CMA_diagonal": True if self.options.separable else self.options.diagonal,
        }
        return _cma().CMAEvolutionStrategy(x0, self.options.sigma0, opts)

    @classmethod
    def settings(cls, problem, config) -> dict:
        o = config.options
        wired = ({"wiring": True, "dim": Wiring.for_arm(problem.arm, problem.encoding.n_inputs, config.hidden,
                                                        config.heads).dim}
                 if getattr(config, "wiring", False) else {})
        return {"dim": mlp_size(problem.encoding.n_inputs, config.hidden, problem.encoding.n_outputs * config.heads),
                **wired, "hidden": config.hidden, **({"heads": config.heads} if config.heads > 1 else {}),
                "sigma0": o.sigma0, "diagonal": o.diagonal, "popsize": config.population, "restarts": o.restarts,
                "separable": o.separable, "stall_generations": STALL, "cma": _cma().__version__}

    def _step(self) -> StepResult:
        if len(self.searches) > 1:
            return self._split_step()
        X = np.asarray(self.es.ask())
        if self.wiring is None:
            f = self.problem.mlp_mse(X, self.config.hidden, offsets=self.offsets)
        else:
            f = self.problem.wired_mse(X, self.wiring, offsets=self.offsets).sum(axis=1)
        self._tell(self.es, X, f)
        i = int(np.argmin(f))
        self._offer(f[i], lambda: self.mlp(X[i].copy()))
        self._asked = X
        # the spread of the sampled weights: their standard deviation across the population, the
        # mean over the weights (sigma times the mean scale of C's axes, as sampled)
        extras = {"sigma": float(self.es.sigma), "restarts": self.restarts,
                  "weight_spread": float(np.mean(np.std(X, axis=0)))}
        if self.options.restarts and self._start_is_over(float(f[i])):
            self.restarts += 1
            self._start()
        return StepResult(f, extras)

    def _split_step(self) -> StepResult:
        """One generation of a wired tree's searches, one per limb group: candidate p is every group's
        p-th sample; each search is told its group's share of the error."""
        parts = [np.asarray(es.ask()) for es in self.searches]
        X = np.concatenate(parts, axis=1)
        F = self.problem.wired_mse(X, self.wiring, offsets=self.offsets)  # (P, groups)
        for k, es in enumerate(self.searches):
            self._tell(es, parts[k], F[:, k])
        f = F.sum(axis=1)
        if self.problem.resampling:  # this generation's best of each group, scored on the reference goals
            best = np.concatenate([parts[k][int(np.argmin(F[:, k]))] for k in range(len(parts))])
            self._offer(float(np.min(F, axis=0).sum()), lambda: self.mlp(best))
        else:  # the groups share no weight: the best of each so far make the best network so far
            for k in range(len(parts)):
                i = int(np.argmin(F[:, k]))
                if F[i, k] < self._group_best[k]:
                    self._group_best[k], self._group_x[k] = float(F[i, k]), parts[k][i].copy()
            if all(x is not None for x in self._group_x):
                combined = np.concatenate(self._group_x)
                self._offer(float(sum(self._group_best)), lambda: self.mlp(combined))
        self._asked = X
        extras = {"sigma": float(np.mean([es.sigma for es in self.searches])), "restarts": self.restarts,
                  "weight_spread": float(np.mean(np.std(X, axis=0)))}
        if self.options.restarts and self._start_is_over(float(np.min(F, axis=0).sum())):
            self.restarts += 1
            self._start()
        return StepResult(f, extras)

    @staticmethod
    def _tell(es, X, f) -> None:
        """Tell a search its candidates' errors (a non-finite one ranked below every finite one)."""
        finite = np.isfinite(f)
        worst = f[finite].max() if finite.any() else 1.0
        es.tell(list(X), np.where(finite, f, 10.0 * worst + 1e6).tolist())
        if es.sm.randn is np.random.randn:
            # pycma 4.x switches from the diagonal to the full sampler (CMA_diagonal) with a new
            # sampler that draws from numpy's global, unseeded generator: give it ours back
            es.sm.randn = es.opts["randn"]

    keeps_candidates = True

    def mlp(self, weights) -> MLPController:
        """An MLP of this run's shape with these weights."""
        s = self.shape
        if self.wiring is not None:
            weights = self.wiring.expand(weights)
        return MLPController(s.encoding, s.hidden, weights, s.heads, s.anchors, s.chain)

    def _candidate_controllers(self):
        return [self.mlp(x) for x in self._asked]

    def _candidate_joints(self, goals):
        W = self._asked if self.wiring is None else self.wiring.expand(self._asked)
        return mlp_joints(self.problem.encoding, self.config.hidden, W, goals, self.shape)

    def _start_is_over(self, gen_best: float) -> bool:
        if gen_best < 0.99 * self._start_best:
            self._start_best, self._start_best_gen = gen_best, self.generation
        if self.generation - self._start_best_gen >= STALL:
            return True
        return bool(set(self.es.stop()) - _STOP_IGNORED)


def reference_loop(config, problem, generations: int) -> float:
    """Seconds of pycma's own ask/tell loop at the same dimension and population with a trivial
    fitness, the sphere sum(x^2) (benchmarks/bench_speed.py; a constant fitness would be unfair:
    pycma then stops adapting its covariance, which is most of its cost)."""
    import time

    enc = problem.encoding
    rng = np.random.default_rng(config.seed)
    dim = mlp_size(enc.n_inputs, config.hidden, enc.n_outputs * config.heads)
    es = _cma().CMAEvolutionStrategy(rng.normal(0, 0.1, dim), config.options.sigma0,
                                     {"popsize": config.population, "seed": np.nan, "verbose": -9, "verb_log": 0,
                                      "randn": lambda *s: rng.standard_normal(s), "maxiter": np.inf})
    t = time.perf_counter()
    for _ in range(generations):
        X = es.ask()
        es.tell(X, np.sum(np.square(X), axis=1).tolist())
    return time.perf_counter() - t


def defaults(arm) -> dict:
    """The settings CMA-ES runs with on an arm when none are given, each chosen by a measured
    comparison (benchmarks/bench_quality.py for the paper's arms: docs/results/paper-budget.md;
    benchmarks/bench_arms.py for the real ones: docs/results/real-arms.md; the before and after
    of each choice, and what was tried and not kept: docs/log.md).

    The paper's arms: "reach" inputs (the slack of reach), a wide output margin (2.0), 5 hidden
    units. The snakes (planar-10, planar-20) take the same: they are planar, in the paper's units,
    with the planar arm's reach and ranges of pi, so the planar arm's settings are the closest
    measured choice (their 10-20 outputs may want more hidden units: not measured yet).

    Real arms (5-7 joints, some of range 4 pi), for a budget of about four minutes on two cores
    (the fitness in two threads, pycma on one):
    - features "sphere" (lab/problem/encoding.py): the slack of reach about the shoulder as well
      as about the base axis, so that the elbow's fold near full reach, where most refinement
      failures were, is nearly linear in an input. SO101 (BEARINGS_ARMS): "bearings", the bearing
      from the front and from behind: its base turns +-110 degrees, so the goals behind it are
      reached folded back, and a bearing from the front alone has its seam among them;
    - margin margin_of(arm): none where joints turn 4 pi (a wide range throws outputs onto the
      limits), LIMITED_MARGIN where every limited joint turns less than a turn;
    - hidden 32 (about 400 weights), targets 300, population 50, sigma0 0.05 (a larger net starts
      saturated with a larger first step), separable (sep-CMA-ES: cost linear in the weights),
      REAL_ARM_GENERATIONS generations;
    - heads (MULTI_HEAD_ARMS; lab/problem/controllers.py, head_anchors), with fewer generations so
      that the time stays about the same: UR5 two, since a single network must cut its workspace
      between elbow branches and its worst goals lie along the cut; Z1 and the SO arms two or more,
      since the goals behind the base are reached only folded back over the shoulder, a branch no
      single-head run finds (the second head starts leaning back). On the SO arms the goals behind
      the base near its axis need the arm curled forward over the axis, the tip beyond it (the
      third head starts there); SO101's fourth is the second's mirror image in the base joint."""
    if arm_kind(arm) in ("paper", "snake"):
        return dict(features="reach", margin=2.0, hidden=5)
    if arm_kind(arm) == "tree":
        return tree_defaults(arm)
    return {**dict(features="bearings" if arm.name in BEARINGS_ARMS else "sphere", margin=margin_of(arm),
                   hidden=32, targets=300, population=50, generations=REAL_ARM_GENERATIONS, sigma0=0.05,
                   separable=True),
            **MULTI_HEAD_ARMS.get(arm.name, {})}


def tree_defaults(arm) -> dict:
    """The settings CMA-ES runs with on a tree of several end effectors (robots' kind "tree": legs, a
    hand, a humanoid) when none are given: one network answers all joints for all effectors' goals
    (lab/problem/tree_encoding.py), wired per limb group (lab/problem/wiring.py: each group of limbs
    that share no joint its own hidden units, hearing only its effectors' goals, and its own search on
    its own share of the error), the first joint of every limb that moves one effector alone turned
    in closed form toward its goal (a leg's hip, a finger's base; not a humanoid's waist), the real
    arms' search otherwise (sep-CMA-ES, population 50, 300 goals, sigma0 0.05), 64 hidden units over
    the groups; TREE_ARMS where a tree differs (g1: 600 goals). TREE_SETTINGS chosen by budgeted runs (the
    comparison and its figures: docs/log.md)."""
    return {**TREE_SETTINGS, "margin": margin_of(arm), "generations": REAL_ARM_GENERATIONS, **TREE_ARMS.get(arm.name, {})}


def budget_defaults(arm, seconds: float) -> dict:
    """The settings CMA-ES runs with on an arm with a time budget of `seconds` s of optimizer time
    (TrainConfig.seconds) when none are given, each chosen by measurement on the eight real arms
    (benchmarks/bench_budget.py: docs/results/budgets.md; what was tried: docs/log.md).

    The paper's arms and the snakes: defaults(arm) without its generations (the budget ends the run).
    A real arm: defaults(arm) without its generations, with the first joint turned in closed form
    toward the goal (real_arm_io: the network then learns the goal's distance from the base axis
    and its height, not its bearing), and for a budget of at most SHORT_BUDGET s a population of
    SHORT_POPULATION (more, cheaper generations in the time). Heads: BUDGET_HEADS, fewer than
    without a budget (MULTI_HEAD_ARMS): with the bearing solved, UR5 and Z1 need no second head, and
    the SO arms two (the second leaning back, for the goals behind the base); fewer heads are
    cheaper generations."""
    d = {k: v for k, v in defaults(arm).items() if k != "generations"}
    if arm_kind(arm) != "real":
        return d
    d.update(real_arm_io(arm), heads=BUDGET_HEADS.get(arm.name, 1))
    if seconds <= SHORT_BUDGET:
        d["population"] = SHORT_POPULATION
    return d


POSE_GENERATIONS = 20_000  # pose goals without a budget, one head: about 5 minutes on one core (docs/log.md)
# a real arm's heads for pose goals (the others: one): a pose has up to 8 IK branches (shoulder, elbow,
# wrist), and with the bearing solved by the turn, heads serve the elbow and wrist branches; UR5, 120 s:
# 4 heads 80 degrees median angle and 13.7 % refined, against 1 head's 106 degrees and 8.9 % in 240 s
# (docs/log.md). With the reach, 240 s, refined in 3 steps: SO-100 two (98.6 % against one head's 85.4
# %), SO-101 four (60.1 % against two heads' 47.8 % and one's 36.6 %)
FULL_POSE_HEADS = 4  # every registered arm held to a full pose (6-7 joints) has 4; so has an arm of a URDF
POSE_HEADS = {**{name: FULL_POSE_HEADS for name in ("ur5", "ur10", "panda", "xarm7", "kinova", "z1", "so101")},
              "so100": 2}


def pose_defaults(arm, seconds: float | None) -> dict:
    """What differs for pose goals (TrainConfig.goal "pose", a real arm), over defaults_for's: the
    real arm's inputs and output mapping with the first joint turned in closed form toward the
    position's bearing (real_arm_io: any exact answer has that bearing, and the orientation turns
    with it), POSE_HEADS heads, and without a budget POSE_GENERATIONS generations; chosen by short
    budgeted runs (docs/log.md). An arm outside the registry: FULL_POSE_HEADS where it has 6 joints or more,
    as the registered arms of its size."""
    heads = POSE_HEADS.get(arm.name, FULL_POSE_HEADS if arm.nq >= 6 else 1)
    d = dict(real_arm_io(arm), heads=heads)
    if seconds is None:  # four heads cost about 3.5x a generation (UR5, one thread: 35-44 ms against 10-12)
        d["generations"] = POSE_GENERATIONS if heads == 1 else POSE_GENERATIONS * 3 // 10
    return d


METHOD = register(Method(
    name="cmaes", label="CMA-ES", color=(31, 119, 180),
    summary="CMA-ES (pycma) on the weights of a fixed-topology MLP",
    backend_class=CMAESBackend, options=CMAESOptions, controller="mlp",
    defaults=defaults, budget_defaults=budget_defaults, pose_defaults=pose_defaults,
    # the paper fixes no hidden size or step size: the values a reader of the paper would pick
    paper=dict(features="cartesian", margin=0.0, hidden=8, sigma0=0.5, diagonal=0, restarts=False),
    min_population=4, min_hidden=1, max_heads=MAX_HEADS,
    search_title="CMA-ES step size and restarts", search_series="CMA-ES step size sigma and the number of restarts",
    class_generations=3000,  # a student's default run on a paper arm (docs/results/class.md)
    cost=1.0, compile_seconds=(10.0, 11.0), ablations=("features=polar", "features=cartesian", "margin=0.5", "hidden=8", "sigma0=0.4", "diagonal=0"),
    reference=SpeedReference("pycma ask/tell, sphere", 1.25, reference_loop),
    live_plots=(
        LivePlot("sigma", "CMA-ES step size σ", log=True, about=(
            "σ is how far CMA-ES samples new weight vectors around its mean: large at first to explore, it "
            "shrinks as the population closes in on good weights. A σ that stops shrinking while the error "
            "stays high means the search is stuck or the step size keeps growing to escape a plateau.")),
        LivePlot("weight_spread", "Spread of the sampled weights", log=True, about=(
            "The standard deviation of each weight across this generation's samples, averaged over the "
            "weights: σ times the shape CMA-ES has learnt. It follows σ, and falls faster along directions "
            "where the error is steep.")),
    ),
))
