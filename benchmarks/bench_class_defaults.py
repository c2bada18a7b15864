"""What a student's default run reaches, and in how long: My experiment's default on each robot and
method (app/classroom/student_run.student_length), trained with lab.evolve on one thread.

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 LAB_THREADS=1 \\
        python benchmarks/bench_class_defaults.py --robots planar scara ur5 --seeds 0 1

    python benchmarks/bench_class_defaults.py --robots planar scara --methods cmaes --seeds 0 1 2 3 4 \\
        --generations 1000 2000 3000     # candidate lengths side by side

Prints one markdown row per robot, method and seed (and length): the default (generations or time budget), the
generations run, the seconds of optimizer time, the training and held-out MSE. Each robot's first
run pays the compile of its kernels unless the cache is warm: run `python -m lab.running.warmup`
first, or read the second seed's seconds. The table and its command: docs/results/class.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import lab  # noqa: E402

from app.classroom.student_run import student_length  # noqa: E402


def measure(robot: str, method: str, seed: int, generations: int | None = None) -> dict:
    length = student_length(robot, method) if generations is None else {"generations": generations, "seconds": None}
    kwargs = {"seconds": length["seconds"]} if length["seconds"] else {"generations": length["generations"]}
    t0 = time.perf_counter()
    run = lab.evolve(robot, method, seed=seed, **kwargs)
    return {"robot": robot, "method": method, "seed": seed, "default": length, "generations": len(run.history),
            "seconds": run.seconds, "wall": time.perf_counter() - t0, "train": run.train_mse, "test": run.test_mse}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", nargs="+", default=["planar", "scara", "ur5"])
    p.add_argument("--methods", nargs="+", help="default: the methods with a student's run length (class_generations)",
                   default=[m for m in lab.methods.names() if lab.methods.get(m).class_generations is not None])
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--generations", nargs="+", type=int, default=[None],
                   help="lengths to compare, in generations, instead of the default (the candidates for class_generations)")
    args = p.parse_args(argv)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, load {os.getloadavg()[0]:.1f}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')} LAB_THREADS={os.environ.get('LAB_THREADS')}")
    print("| robot | method | default | seed | generations | seconds (optimizer) | training MSE | held-out MSE |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for robot in args.robots:
        for method in args.methods:
            for seed, generations in ((s, g) for g in args.generations for s in args.seeds):
                r = measure(robot, method, seed, generations)
                d = r["default"]
                default = f"{d['seconds']:g} s budget" if d["seconds"] else f"{d['generations']:,} generations"
                print(f"| {robot} | {method} | {default} | {seed} | {r['generations']:,} | {r['seconds']:.1f} | "
                      f"{r['train']:.3g} | {r['test']:.3g} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
