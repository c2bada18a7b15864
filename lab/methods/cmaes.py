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

import robots
from lab.methods.base import Backend, Options, StepResult, mlp_joints, mlp_shape, option
from lab.methods.registry import LivePlot, Method, SpeedReference, register
from lab.problem.checks import flag, real, whole
from lab.problem.controllers import MAX_HEADS, MLPController, mlp_size

REAL_ARM_GENERATIONS = 45_000  # 4-5 minutes on the 2-core machine (fitness on both cores) for a 5-7 joint arm
# arms whose goals lie on several IK branches that no single-head run serves: their heads, and a
# budget that still fits 5 minutes (README "Real arms"; per generation on one thread, --timing side
# by side: UR5 with two heads 12.4-12.6 ms against 8.0-9.2 for one; SO100 with two 6.5-7.9 ms on two
# threads against 4.8; Z1's 36,000 took 301 s by --timing on 2026-12-02, so 32,000)
MULTI_HEAD_ARMS = {"ur5": dict(heads=2, generations=32_000), "so100": dict(heads=3, generations=26_000),
                   "so101": dict(heads=4, generations=20_000), "z1": dict(heads=2, generations=32_000)}
# arms whose base turns less than a turn, so that the goals behind them lie across the bearing's seam:
# the bearing twice, from the front and from behind (lab/problem/encoding.py, "bearings"). Not SO100:
# seeds 0-2, "sphere" -> "bearings", median 0.83 / 0.83 / 0.80 -> 0.97 / 0.93 / 1.02 % of reach,
# refined 96.6 / 96.0 / 98.2 -> 98.8 / 96.1 / 91.2 % (README "Real arms")
BEARINGS_ARMS = {"so101"}
# the output margin of an arm whose every limited joint turns less than a full turn (SO100, SO101, Z1,
# Panda, Kinova; README "Real arms"): there the limits bind, and uniformly drawn goals often need a
# joint near one, where a margin of 0 asks the output tanh to saturate. Seed 0, margin 0 -> 0.3:
# median SO100 0.83 -> 0.72 %, SO101 1.17 -> 1.04 % (lower on seeds 0-3 too), Z1 0.83 -> 0.67 %,
# Panda 0.51 -> 0.45 %, Kinova 0.48 -> 0.33 % of reach.
# The arms with joints of +-2 pi (UR5, UR10, xArm7) keep 0: their limits lie two turns apart
LIMITED_MARGIN = 0.3
log = logging.getLogger(__name__)
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
        real(self, "sigma0", 0, 1e6, "a positive number", closed_below=False)
        whole(self, "diagonal", 0, 10**9)
        flag(self, "restarts")
        flag(self, "separable")


class CMAESBackend(Backend):
    def __init__(self, problem, config):
        super().__init__(problem, config)
        self.shape = mlp_shape(problem, config)  # a zero-weight MLP of this run's hidden size and heads
        self.offsets = None if self.shape.heads == 1 else self.shape.offsets
        self.dim = self.shape.n_params
        self.rng = np.random.default_rng(config.seed)
        self.restarts = 0
        self._start()
        tpa = _cma().evolution_strategy.TPA_dimension  # pycma's step-size rule is TPA from this dimension on
        if problem.resampling and self.options.separable and self.dim >= tpa:
            log.warning("resampled goals with sep-CMA-ES on %d weights: pycma adapts the step size by two-point "
                        "adaptation above %d weights, and with new goals every generation it collapses (SO100: "
                        "sigma 1.8e-5 against 7.5e-4 with fixed goals after 3,000 generations; README, "
                        "'resample'); fixed goals train better here", self.dim, tpa)

    def _start(self) -> None:
        x0 = self.rng.normal(0.0, 0.1, self.dim)
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
        self.es = _cma().CMAEvolutionStrategy(x0, self.options.sigma0, opts)
        self._start_best = np.inf
        self._start_best_gen = self.generation

    @classmethod
    def settings(cls, problem, config) -> dict:
        o = config.options
        return {"dim": mlp_size(problem.encoding.n_inputs, config.hidden, problem.encoding.n_outputs * config.heads),
                "hidden": config.hidden, **({"heads": config.heads} if config.heads > 1 else {}),
                "sigma0": o.sigma0, "diagonal": o.diagonal, "popsize": config.population, "restarts": o.restarts,
                "separable": o.separable, "stall_generations": STALL, "cma": _cma().__version__}

    def _step(self) -> StepResult:
        X = np.asarray(self.es.ask())
        f = self.problem.mlp_mse(X, self.config.hidden, offsets=self.offsets)
        finite = np.isfinite(f)
        worst = f[finite].max() if finite.any() else 1.0
        self.es.tell(list(X), np.where(finite, f, 10.0 * worst + 1e6).tolist())
        if self.es.sm.randn is np.random.randn:
            # pycma 4.x switches from the diagonal to the full sampler (CMA_diagonal) with a new
            # sampler that draws from numpy's global, unseeded generator: give it ours back
            self.es.sm.randn = self.es.opts["randn"]
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

    keeps_candidates = True

    def mlp(self, weights) -> MLPController:
        """An MLP of this run's shape with these weights."""
        s = self.shape
        return MLPController(s.encoding, s.hidden, weights, s.heads, s.anchors, s.chain)

    def _candidate_controllers(self):
        return [self.mlp(x) for x in self._asked]

    def _candidate_joints(self, goals):
        return mlp_joints(self.problem.encoding, self.config.hidden, self._asked, goals, self.shape)

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


def margin_of(arm) -> float:
    """A real arm's output margin: LIMITED_MARGIN when every joint with limits turns less than a full
    turn between them (continuous joints take no margin: lab/problem/encoding.py), else 0."""
    limited = ~np.asarray(arm.chain.continuous, bool)
    return LIMITED_MARGIN if bool(np.all((arm.upper - arm.lower)[limited] < 2 * np.pi - 1e-9)) else 0.0


def defaults(arm) -> dict:
    """The settings CMA-ES runs with on an arm when none are given.

    The paper's arms (measured in benchmarks/bench_quality.py, README "Quality"): the slack-of-reach
    input and a wide output margin. Real arms (benchmarks/bench_arms.py, README "Real arms"): 6-7
    joints, some of range 4 pi, want no margin there (a wide range throws outputs onto the limits)
    and a small one (0.3, margin_of) where every limited joint turns less than a turn, a
    larger network (32 hidden units, about 400 weights), more goals (300), a small first step
    (0.05: a larger net starts saturated) and sep-CMA-ES, whose cost is linear in the weights, for
    a budget of about four minutes on the two cores (the fitness in two threads, pycma on one).
    Their inputs are "sphere" (lab/problem/encoding.py): the slack of reach about the shoulder
    as well as about the base axis, so that the elbow's fold near full reach, where most
    refinement failures were, is nearly linear in an input (seed 0, held-out goals, "reach" ->
    "sphere": UR10 median 1.87 -> 0.59 % of reach and refined 97.3 -> 99.8 %, Panda 1.04 -> 0.48 %
    and 99.2 -> 99.8 %, Kinova 1.39 -> 0.46 % and 87.1 -> 99.9 %; README, "Real arms").

    The snakes (planar-10, planar-20) get the paper's-arm settings for now: they are planar, in
    the paper's units, with the planar arm's reach and ranges of pi, so the input scaling, the
    margin and the budget measured on the planar arm are the closest measured choice; their 10-20
    outputs may want more hidden units (not measured yet).

    UR5, SO100, SO101 and Z1 (MULTI_HEAD_ARMS): several heads (lab/problem/controllers.py,
    head_anchors). On the SO arms and Z1 the goals behind the base are reached only with the arm
    folded back over its shoulder, a branch no single-head run found; the second head starts
    leaning back. On the SO arms the goals behind the base near its axis need a third branch, the
    arm curled forward over the axis (the tip beyond it), which the front head answered with the
    base at its limit, 15-40 mm off (127 of SO101's 132 failures): the third head starts there,
    SO101's fourth is the second's mirror image in the base joint. Seeds 0-2, every head's answer
    refined (robots.ik.refine's proposals), success within 3 steps: SO100 two heads (32,000
    generations) -> three (26,000) 97.45 / 97.55 / 97.75 -> 99.5 / 98.9 / 96.5 %, at a median of
    0.72 / 0.67 / 0.67 -> 0.70 / 0.87 / 1.06 % of reach; SO101 three (26,000) -> four (20,000)
    94.45 / 94.25 / 94.25 -> 99.2 / 99.4 / 99.5 %, median 1.04 / 0.90 / 0.94 -> 0.91 / 0.93 / 0.90 %
    (README "Real arms"). Before them, seed 0, "sphere" inputs, held-out median and refined
    success: SO101 one head
    1.43 % of reach, 84.4 %; two 1.10 %, 87.8 %; three (26,000 generations) 1.45 %, 92.3 %. Z1 (32,000
    generations, so that two heads fit the 5 minutes) 0.79 -> 0.83 %, 98.7 -> 99.8 %. UR5 (32,000)
    0.85 -> 0.61 %, 98.6 -> 99.1 %, p99 10.5 -> 2.6 %: a single network must cut its workspace between
    elbow branches, and its worst seeds lay along the cut ("reach" inputs, before: the median got
    worse, 1.23 -> 1.75 %). SO100 ("reach" inputs then): one head to two 1.78 -> 1.58 %, 85.7 -> 91.3 %;
    three heads (24,000; the third then the mirrored folded head, not the curled one) 1.55 %, 90.6 %,
    worse than two. Two heads cost 1.3-2x the time of one a generation, three about 1.4x two.

    SO101 (BEARINGS_ARMS): "bearings" inputs, the bearing measured from the front and from behind.
    Its base turns +-110 degrees, so the goals behind it are reached folded back, and the bearing
    measured as before had its seam right among them, where its refinement failures were (110 of
    138 more than 120 degrees from its front). Seeds 0-3, "sphere" -> "bearings": median 1.25 / 1.48 /
    1.36 / 1.39 -> 1.17 / 1.18 / 1.15 / 1.28 % of reach, refined 93.1 / 93.5 / 92.3 / 92.1 -> 93.4 /
    93.4 / 92.5 / 93.4 %."""
    if robots.kind(arm.name) in ("paper", "snake"):
        return dict(features="reach", margin=2.0, hidden=5)
    return {**dict(features="bearings" if arm.name in BEARINGS_ARMS else "sphere", margin=margin_of(arm),
                   hidden=32, targets=300, population=50, generations=REAL_ARM_GENERATIONS, sigma0=0.05,
                   separable=True),
            **MULTI_HEAD_ARMS.get(arm.name, {})}


METHOD = register(Method(
    name="cmaes", label="CMA-ES", color=(31, 119, 180),
    summary="CMA-ES (pycma) on the weights of a fixed-topology MLP",
    backend_class=CMAESBackend, options=CMAESOptions, controller="mlp",
    defaults=defaults,
    # the paper fixes no hidden size or step size: the values a reader of the paper would pick
    paper=dict(features="cartesian", margin=0.0, hidden=8, sigma0=0.5, diagonal=0, restarts=False),
    min_population=4, min_hidden=1, max_heads=MAX_HEADS,
    search_title="CMA-ES step size and restarts", search_series="CMA-ES step size sigma and the number of restarts",
    cost=1.0, ablations=("features=polar", "features=cartesian", "margin=0.5", "hidden=8", "sigma0=0.4", "diagonal=0"),
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
