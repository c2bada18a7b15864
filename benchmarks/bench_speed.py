"""Cost of a training run against the optimizer's own loop with a trivial fitness.

CMA-ES: `lab`'s backend for G generations (50 MLPs x 70 goals evaluated per generation:
network + forward kinematics) against pycma's own ask/tell loop at the same dimension and
population with a trivial fitness, the sphere sum(x^2) (a constant fitness would be unfair to
lab: pycma then has a flat landscape and stops adapting its covariance, which is most of its
cost). NEAT: `lab`'s backend against neat-python's own Population.run with the same
configuration and a trivial fitness (uniform random numbers, so that selection and speciation
have work to do, as in a real run) and neat-python's own DefaultGenome and DefaultSpeciesSet (lab's
backend uses FastGenome and FastSpeciesSet: the same genomes and species, faster;
lab/backends/neat_genome.py, neat_species.py). Both are timed side by
side, interleaved, in this run; the median of the rounds is reported. Targets: CMA-ES <= 1.25x,
NEAT <= 1.5x.

    .venv/bin/python benchmarks/bench_speed.py [--generations 1000] [--rounds 3] [--robot planar]
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    import cma  # noqa: E402
import neat  # noqa: E402

from lab.backends import make_backend  # noqa: E402
from lab.backends.neat import make_neat_config, neat_parameters  # noqa: E402
from lab.config import TrainConfig  # noqa: E402
from lab.runner import build_problem  # noqa: E402


def lab_run(config: TrainConfig) -> float:
    backend = make_backend(build_problem(config), config)
    t = time.perf_counter()
    for _ in range(config.generations):
        backend.step()
    return time.perf_counter() - t


def pycma_loop(dim: int, popsize: int, generations: int, sigma0: float, seed: int) -> float:
    rng = np.random.default_rng(seed)
    es = cma.CMAEvolutionStrategy(rng.normal(0, 0.1, dim), sigma0,
                                  {"popsize": popsize, "seed": np.nan, "verbose": -9, "verb_log": 0,
                                   "randn": lambda *s: rng.standard_normal(s), "maxiter": np.inf})
    t = time.perf_counter()
    for _ in range(generations):
        X = es.ask()
        es.tell(X, np.sum(np.square(X), axis=1).tolist())
    return time.perf_counter() - t


def neat_loop(config: TrainConfig, n_inputs: int, n_outputs: int) -> float:
    cfg = make_neat_config(n_inputs, n_outputs, config.population, config.hidden, config.seed,
                           neat_parameters(config), genome_type=neat.DefaultGenome,
                           species_set_type=neat.DefaultSpeciesSet)  # neat-python's own classes
    saved = random.getstate()
    pop = neat.Population(cfg, seed=config.seed)

    rng = np.random.default_rng(config.seed)

    def trivial(genomes, _config):
        for (_, g), f in zip(genomes, rng.random(len(genomes)).tolist()):
            g.fitness = f

    t = time.perf_counter()
    stdout, sys.stdout = sys.stdout, open(os.devnull, "w")  # its closing "meets fitness threshold" line
    try:
        pop.run(trivial, config.generations)
    finally:
        sys.stdout.close()
        sys.stdout = stdout
    random.setstate(saved)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--generations", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--robot", default="planar")
    ap.add_argument("--paper", action="store_true", help="the paper's preset instead of the defaults")
    args = ap.parse_args()
    print(f"robot {args.robot}, {args.generations} generations, population 50, median of {args.rounds} rounds")
    for method, target in (("cmaes", 1.25), ("neat", 1.5)):
        config = TrainConfig.preset(paper=args.paper, robot=args.robot, method=method,
                                    generations=args.generations, test_goals=10)
        problem = build_problem(config)
        enc = problem.encoding
        ours, base = [], []
        for r in range(args.rounds):
            ours.append(lab_run(config.replace(seed=r)))
            if method == "cmaes":
                dim = make_backend(problem, config).dim
                base.append(pycma_loop(dim, config.population, args.generations, config.sigma0, r))
                what = f"pycma ask/tell, dim {dim}, sphere"
            else:
                base.append(neat_loop(config.replace(seed=r), enc.n_inputs, enc.n_outputs))
                what = "neat-python Population.run, random fitness"
        a, b = np.median(ours), np.median(base)
        verdict = "PASS" if a / b <= target else "FAIL"
        print(f"{method:6s} lab {a:6.2f} s ({a / args.generations * 1e3:.2f} ms/gen)   {what}: {b:6.2f} s "
              f"({b / args.generations * 1e3:.2f} ms/gen)   ratio {a / b:.2f}x (target <= {target}x) {verdict}")


if __name__ == "__main__":
    main()
