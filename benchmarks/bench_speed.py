"""Cost of a training run against the optimizer's own loop with a trivial fitness (the results:
docs/results/speed.md).

CMA-ES: `lab`'s backend for G generations (50 MLPs x 70 goals evaluated per generation:
network + forward kinematics) against pycma's own ask/tell loop at the same dimension and
population with a trivial fitness, the sphere sum(x^2) (a constant fitness would be unfair to
lab: pycma then has a flat landscape and stops adapting its covariance, which is most of its
cost). NEAT: `lab`'s backend against neat-python's own Population.run with the same
configuration and a trivial fitness (uniform random numbers, so that selection and speciation
have work to do, as in a real run) and neat-python's own DefaultGenome and DefaultSpeciesSet (lab's
backend uses FastGenome and FastSpeciesSet: the same genomes and species, faster;
lab/methods/neat_genome.py, neat_species.py). Both are timed side by
side, interleaved, in this run; the median of the rounds is reported. Every registered method
with a speed reference (Method.reference: the loop, its description and its target) is measured:
CMA-ES <= 1.25x, NEAT <= 1.5x.

    .venv/bin/python benchmarks/bench_speed.py [--generations 1000] [--rounds 3] [--robot planar]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from lab import methods  # noqa: E402
from lab.running.config import TrainConfig  # noqa: E402
from lab.running.runner import build_problem  # noqa: E402


def lab_run(config: TrainConfig) -> float:
    backend = methods.make_backend(build_problem(config), config)
    t = time.perf_counter()
    for _ in range(config.generations):
        backend.step()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--generations", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--robot", default="planar")
    ap.add_argument("--methods", default=",".join(m.name for m in methods.all_methods() if m.reference))
    ap.add_argument("--paper", action="store_true", help="the paper's preset instead of the defaults")
    args = ap.parse_args()
    print(f"robot {args.robot}, {args.generations} generations, population 50, median of {args.rounds} rounds")
    for name in args.methods.split(","):
        method = methods.get(name)
        ref = method.reference
        config = TrainConfig.preset(paper=args.paper, robot=args.robot, method=name, population=50,
                                    generations=args.generations, test_goals=10)
        problem = build_problem(config)
        ours, base = [], []
        for r in range(args.rounds):
            ours.append(lab_run(config.replace(seed=r)))
            base.append(ref.loop(config.replace(seed=r), problem, args.generations))
        a, b = np.median(ours), np.median(base)
        verdict = "PASS" if a / b <= ref.target else "FAIL"
        print(f"{name:6s} lab {a:6.2f} s ({a / args.generations * 1e3:.2f} ms/gen)   {ref.what}: {b:6.2f} s "
              f"({b / args.generations * 1e3:.2f} ms/gen)   ratio {a / b:.2f}x (target <= {ref.target}x) {verdict}")


if __name__ == "__main__":
    main()
