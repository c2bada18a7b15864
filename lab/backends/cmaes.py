"""CMA-ES (pycma, ask/tell) on the weights of a fixed-topology MLP (paper, sections 3 and 4.3).

Randomness: pycma samples with this backend's own numpy Generator (option `randn`), so a run
depends on its seed alone, never on numpy's global state, and runs in threads do not interfere.

Restarts (config.restarts): when pycma's own termination criteria fire or the run has not
improved its best by 1% in `STALL` generations, a new CMA-ES starts from a fresh random point
with the remaining budget; the best controller over all starts is kept. The generation count
and the evaluation budget (generations x population) are unchanged.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..controllers import MLPController, mlp_size
from .base import Backend, StepResult

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # "Could not import matplotlib"
    import cma

STALL = 150  # generations without 1% improvement that end a start (restarts only)
_STOP_IGNORED = {"maxiter", "maxfevals", "ftarget"}


class CMAESBackend(Backend):
    method = "cmaes"

    def __init__(self, problem, config):
        super().__init__(problem, config)
        enc = problem.encoding
        self.dim = mlp_size(enc.n_inputs, config.hidden, enc.n_outputs)
        self.rng = np.random.default_rng(config.seed)
        self.restarts = 0
        self._start()

    def _start(self) -> None:
        x0 = self.rng.normal(0.0, 0.1, self.dim)
        opts = {
            "popsize": self.config.population,
            "randn": lambda *shape: self.rng.standard_normal(shape),
            "seed": np.nan,  # never touch numpy's global random state
            "verbose": -9,
            "verb_log": 0,
            "maxiter": np.inf,
            "CMA_diagonal": self.config.diagonal,  # a fast, diagonal-only start (0: full C from the first)
        }
        self.es = cma.CMAEvolutionStrategy(x0, self.config.sigma0, opts)
        self._start_best = np.inf
        self._start_best_gen = self.generation

    @classmethod
    def settings(cls, problem, config) -> dict:
        enc = problem.encoding
        return {"dim": mlp_size(enc.n_inputs, config.hidden, enc.n_outputs), "hidden": config.hidden,
                "sigma0": config.sigma0, "diagonal": config.diagonal, "popsize": config.population,
                "restarts": config.restarts, "stall_generations": STALL, "cma": cma.__version__}

    def _step(self) -> StepResult:
        X = np.asarray(self.es.ask())
        f = self.problem.mlp_mse(X, self.config.hidden)
        finite = np.isfinite(f)
        worst = f[finite].max() if finite.any() else 1.0
        self.es.tell(list(X), np.where(finite, f, 10.0 * worst + 1e6).tolist())
        if self.es.sm.randn is np.random.randn:
            # pycma 4.x switches from the diagonal to the full sampler (CMA_diagonal) with a new
            # sampler that draws from numpy's global, unseeded generator: give it ours back
            self.es.sm.randn = self.es.opts["randn"]
        i = int(np.argmin(f))
        self._offer(f[i], lambda: MLPController(self.problem.encoding, self.config.hidden, X[i].copy()))
        extras = {"sigma": float(self.es.sigma), "restarts": self.restarts}
        if self.config.restarts and self._start_is_over(float(f[i])):
            self.restarts += 1
            self._start()
        return StepResult(f, extras)

    def _start_is_over(self, gen_best: float) -> bool:
        if gen_best < 0.99 * self._start_best:
            self._start_best, self._start_best_gen = gen_best, self.generation
        if self.generation - self._start_best_gen >= STALL:
            return True
        return bool(set(self.es.stop()) - _STOP_IGNORED)
