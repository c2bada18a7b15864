"""NEAT-CMA: NEAT's topology search, with the weights of its best networks tuned by CMA-ES (Lamarckian).

NEAT (neat.py) grows networks from minimal structure, with innovation numbers and speciation, but
moves weights by a fixed step (its weight_mutate_power) that never adapts to the scale the error
needs: on the real arms it stalls at 5-20 % of reach (docs/results/budgets.md). NEAT-CMA is that NEAT,
unchanged, plus a tuning every `tune_every` generations, between the evaluation and the reproduction:
a CMA-ES search (pycma) on the weights and biases of a few networks, their topology fixed, for
`tune_evaluations` networks each. The networks tuned are the best of the generation and the best
network of each larger size (hidden nodes), the next sizes first, `tune_networks` in all: a network
that has just grown a node starts worse than the tuned one it grew from, and would never win if only
the best were tuned. The tuned weights are written back into the genome with its new fitness
(Lamarckian: its children inherit them); selection, crossover and speciation then go on as NEAT's.
A network tuned again while unchanged (an elite) goes on with the same search; a tuning that finds
nothing better leaves the genome as it was.

The searches sample from the backend's own generator, seeded with the run's seed (never numpy's global
one): same seed, same run, in a thread or not. Its evaluations count in the run's (StepResult.evaluations; the extras' "tuned").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lab.methods import neat as neat_method
from lab.methods.base import StepResult, option, real_arm_io
from lab.methods.cmaes import CMAESBackend
from lab.methods.neat import BAD_FITNESS, NEATBackend, NEATOptions, _enabled, _layout, program_hidden
from lab.methods.registry import Method, register
from lab.problem.checks import real, whole
from lab.problem.controllers import join_programs
from lab.problem.robot import arm_kind


@dataclass(frozen=True)
class NEATCMAOptions(NEATOptions):
    tune_every: int = option(1, "generations between two tunings")
    tune_networks: int = option(4, "networks tuned each time: the best, and the best of each larger size")
    tune_evaluations: int = option(120, "networks each tuned network's search evaluates (whole CMA-ES generations)")
    tune_population: int = option(15, "the population of each CMA-ES search")
    tune_sigma: float = option(0.1, "the CMA-ES step a tuning starts with")

    def tuning_batches(self) -> int:
        """CMA-ES generations a tuned network's search makes: tune_evaluations in whole generations."""
        return -(-self.tune_evaluations // self.tune_population)

    def check(self) -> None:
        super().check()
        whole(self, "tune_every", 1, 1_000_000)
        whole(self, "tune_networks", 1, 1_000)
        whole(self, "tune_evaluations", 1, 1_000_000)
        whole(self, "tune_population", 2, 10_000)
        real(self, "tune_sigma", 0, 1e3, "a positive number up to 1,000", closed_below=False)


class NEATCMABackend(NEATBackend):
    def __init__(self, problem, config):
        super().__init__(problem, config)
        self._tuned_evaluations = 0
        self._searches: dict[int, tuple] = {}  # genome key -> (its CMA-ES, the weights it last wrote)
        # the searches sample with this backend's own generator, never numpy's global one (runs in threads)
        self._rng = np.random.default_rng(config.seed)

    @classmethod
    def settings(cls, problem, config) -> dict:
        o = config.options
        return {**super().settings(problem, config), "tune_every": o.tune_every, "tune_networks": o.tune_networks,
                "tune_batches": o.tuning_batches(), "tune_population": o.tune_population, "tune_sigma": o.tune_sigma}

    def _step(self) -> StepResult:
        self._tuned_evaluations = 0
        result = super()._step()
        if self._tuned_evaluations:
            result = StepResult(result.fitness, {**result.extras, "tuned": self._tuned_evaluations},
                                evaluations=(result.evaluations or len(result.fitness)) + self._tuned_evaluations)
        return result

    def _after_evaluation(self, genomes: list, mse: np.ndarray) -> bool:
        """Every tune_every generations: tune the generation's best network and the best of each larger
        size (see the module's docstring); mse and the genomes' fitness follow."""
        o = self.config.options
        if self.population.generation % o.tune_every:
            return False
        # the champion, and challengers: the best genome of each network size (hidden nodes) above the
        # champion's, the next sizes first: a grown network starts worse than the tuned one it grew
        # from, and would never be tuned (nor chosen) if only the best were
        hidden = [program_hidden(self._compiled[g.key]) for g in genomes]
        finite = [i for i in range(len(genomes)) if math.isfinite(mse[i])]
        champion = min(finite, key=lambda i: mse[i]) if finite else 0
        best_of_size: dict[int, int] = {}
        for i in finite:
            h = hidden[i]
            if h > hidden[champion] and (h not in best_of_size or mse[i] < mse[best_of_size[h]]):
                best_of_size[h] = i
        order = [champion] + [best_of_size[h] for h in sorted(best_of_size)][: o.tune_networks - 1]
        # every tuning spends tune_networks searches' evaluations: the champion's search takes those
        # of the sizes that are missing (a step's evaluations are the same in every generation)
        shares = [o.tune_networks - len(order) + 1] + [1] * (len(order) - 1)
        changed = False
        for i, share in zip(order, shares):
            changed |= self._tune(genomes[i], i, mse, share * o.tuning_batches())
        tuned = {genomes[i].key for i in order}
        self._searches = {k: v for k, v in self._searches.items() if k in tuned}
        return changed

    def _tune(self, genome, i: int, mse: np.ndarray, batches: int) -> bool:
        """`batches` CMA-ES generations on genome's weights and biases (genome i of the generation,
        mse[i] its MSE); writes the best it finds back when better. Returns whether it did."""
        import cma

        o = self.config.options
        gc = self.neat_config.genome_config
        keys, _ = _enabled(genome)
        gene_keys, _, link_j, _, _ = _layout(keys, tuple(gc.input_keys), tuple(gc.output_keys))
        bias, response, src, w, end, out = self._compiled[genome.key]
        n_links = len(w)
        x0 = np.asarray(list(w) + list(bias), dtype=np.float64)
        cap = self.params["weight_cap"]
        search = self._searches.get(genome.key)
        if search is not None and np.array_equal(search[1], x0):  # an elite left as we left it: go on
            es = search[0]
        else:
            rng = self._rng
            es = cma.CMAEvolutionStrategy(x0, o.tune_sigma, {
                "popsize": o.tune_population, "seed": np.nan, "randn": lambda *shape: rng.standard_normal(shape),
                "verbose": -9, "verb_log": 0, "CMA_diagonal": len(x0) > 60, "tolfun": 0, "tolx": 0,
                "tolstagnation": 10**9, "tolflatfitness": 10**9, "tolfunhist": 0})
        best_f, best_x = float(mse[i]) if math.isfinite(mse[i]) else math.inf, None
        for _ in range(batches):
            X = np.clip(es.ask(), -cap, cap)  # NEAT's bounds on weights and biases
            parts = [(list(x[n_links:]), response, src, list(x[:n_links]), end, out) for x in X]
            f = self.problem.program_mse(join_programs(parts))
            self._tuned_evaluations += len(X)
            CMAESBackend._tell(es, X, f)
            f = np.where(np.isfinite(f), f, np.inf)
            k = int(np.argmin(f))
            if f[k] < best_f:
                best_f, best_x = float(f[k]), np.array(X[k])
        if best_x is None:
            self._searches[genome.key] = (es, x0)
            return False
        self._searches[genome.key] = (es, best_x)
        for k in range(n_links):
            genome.connections[keys[link_j[k]]].weight = float(best_x[k])
        for k, key in enumerate(gene_keys):
            genome.nodes[key].bias = float(best_x[n_links + k])
        self._compiled[genome.key] = (list(best_x[n_links:]), response, src, list(best_x[:n_links]), end, out)
        mse[i] = best_f
        genome.fitness = -best_f if math.isfinite(best_f) else BAD_FITNESS
        return True


# training goals where NEAT's 300 are too few: measured over seeds at 300 s (docs/results/budgets.md)
ARM_TARGETS = {"ur5": 600}


def step_evaluations(arm, config) -> int:
    """A generation's evaluations: the population, and the tunings' (on average when not every
    generation tunes)."""
    o = config.options
    return int(config.population + o.tune_networks * o.tuning_batches() * o.tune_population / o.tune_every)


def defaults(arm) -> dict:
    """NEAT's defaults on the arm (neat.defaults) and the tuning's (NEATCMAOptions); on a real arm
    hidden nodes added twice as often as NEAT's (add node 0.1): each size's best is tuned, so growth pays
    sooner (UR5, 60 s); on the UR5 600 goals (ARM_TARGETS: with 300 its runs stalled or its grown
    networks overfit; the other arms did as well or better with 300: docs/results/budgets.md)."""
    d = neat_method.defaults(arm)
    if arm_kind(arm) == "real":
        d["add_node"] = 0.1
    if arm.name in ARM_TARGETS:
        d["targets"] = ARM_TARGETS[arm.name]
    return d


def budget_defaults(arm, seconds: float) -> dict:
    return {k: v for k, v in defaults(arm).items() if k != "generations"}


def pose_defaults(arm, seconds: float | None) -> dict:
    return dict(real_arm_io(arm))


METHOD = register(Method(
    name="neat_cma", label="NEAT-CMA", color=(140, 86, 75),
    summary="NEAT's topology search, its best networks' weights tuned by CMA-ES (Lamarckian)",
    backend_class=NEATCMABackend, options=NEATCMAOptions, controller="graph",
    defaults=defaults, budget_defaults=budget_defaults, pose_defaults=pose_defaults, paper=None,
    min_population=2, min_hidden=0,
    search_title="NEAT species and best network size",
    search_series="number of species, nodes and enabled connections of the best genome",
    cost=8.0, compile_seconds=(7.0, 4.5), step_evaluations=step_evaluations, warms_with="neat",
    live_plots=neat_method.METHOD.live_plots,
))
