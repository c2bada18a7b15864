"""Quality at the paper's budget: held-out MSE of each design choice over many seeds (the results:
docs/results/paper-budget.md).

Every variant is trained at the paper's budget (population 50, 1000 generations, 70 fixed
training goals) on each arm for --seeds seeds; the table gives the median and worst training
and held-out MSE (1,000 held-out goals) beside the paper's best run (Table 3). Runs go to all
cores as processes, one BLAS thread each.

    .venv/bin/python benchmarks/bench_quality.py --method cmaes --seeds 10
    .venv/bin/python benchmarks/bench_quality.py --method neat --seeds 10 --robots planar
    .venv/bin/python benchmarks/bench_quality.py --variants "paper;features=polar,hidden=12"
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from lab import methods  # noqa: E402
from lab.experiments import paper  # noqa: E402


def default_variants(method: str) -> list[str]:
    """The paper's method (where the method has a paper preset), this project's defaults, and the
    defaults with one choice undone (the method's declared ablations)."""
    m = methods.get(method)
    return (["paper"] if m.paper is not None else []) + ["default", *m.ablations]


def paper_best(robot: str, method: str) -> str:
    """The best of the paper's 30 runs (Table 3), or '-' where the paper has none."""
    column = paper.column(robot, method)
    return f"{column.min():.4f}" if column is not None else "-"


def parse_variant(text: str) -> dict:
    """'paper' | 'default' | 'key=value,key=value' (on top of the defaults)."""
    if text in ("paper", "default"):
        return {"paper": text == "paper"}
    out = {}
    for item in text.split(","):
        key, value = item.split("=")
        out[key] = {"True": True, "False": False}.get(value, value)
        for cast in (int, float):
            try:
                out[key] = cast(value)
                break
            except ValueError:
                pass
    return out


def one_run(args) -> tuple:
    robot, method, variant, seed, generations = args
    import lab

    opts = parse_variant(variant)
    run = lab.evolve(robot, method, generations=generations, seed=seed, **opts)
    return robot, variant, seed, run.train_mse, run.test_mse, run.n_params, run.seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", default=methods.DEFAULT_METHOD, choices=methods.names())
    ap.add_argument("--robots", default="planar,scara")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--generations", type=int, default=1000)
    ap.add_argument("--variants", default=None, help="';'-separated; default: paper, default and the method's ablations")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    args = ap.parse_args()
    variants = args.variants.split(";") if args.variants else default_variants(args.method)
    jobs = [(r, args.method, v, s, args.generations) for r in args.robots.split(",") for v in variants
            for s in range(args.seeds)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(one_run, jobs))
    print(f"{args.method}, {args.seeds} seeds x {args.generations} generations, population 50, 70 goals; "
          f"{len(jobs)} runs in {time.perf_counter() - t0:.0f} s")
    print(f"{'robot':7s} {'variant':34s} {'params':>6s} {'train med':>10s} {'train worst':>11s} "
          f"{'held-out med':>12s} {'held-out worst':>14s} {'s/run':>6s}  paper best")
    for robot in args.robots.split(","):
        for v in variants:
            rows = [r for r in results if r[0] == robot and r[1] == v]
            tr = np.array([r[3] for r in rows])
            te = np.array([r[4] for r in rows])
            print(f"{robot:7s} {v:34s} {rows[0][5]:6d} {np.median(tr):10.4f} {tr.max():11.4f} "
                  f"{np.median(te):12.4f} {te.max():14.4f} {np.mean([r[6] for r in rows]):6.1f}  "
                  f"{paper_best(robot, args.method)}")


if __name__ == "__main__":
    main()
