"""lab.solve on a large batch, in chunks (lab.solver.CHUNK goals at a time) and in one batch, side by
side: the peak of Python-traced memory above the goals and the answer, and the wall time (a
million poses grew memory without bound). The one-batch figures are what lab.solve did before it
chunked (CHUNK set to the batch).

    .venv/bin/python benchmarks/bench_solve_chunks.py [--goals 200000] [--robot so100] [--poses]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--goals", type=int, default=200_000)
    p.add_argument("--robot", default="so100")
    p.add_argument("--poses", action="store_true", help="pose goals from the rest pose (no controller)")
    p.add_argument("--steps", type=int, default=0, help="refinement steps (0: the proposals measured)")
    args = p.parse_args()
    sys.path.insert(0, str(ROOT))
    import lab
    import lab.solver as solver
    import robots
    from robots import pose

    arm = robots.load(args.robot)
    if args.poses:
        controller, goals = None, pose.sample_poses(arm, args.goals, seed=1)
    else:
        path = ROOT / "app" / "pretrained" / f"{args.robot}-cmaes.json"
        controller = lab.controller_from_dict(json.loads(path.read_text())["controller"])
        goals = arm.sample_goals(args.goals, seed=1)
    lab.solve(controller, arm, goals[:10], steps=args.steps)  # compiled before timing
    chunk = solver.CHUNK
    figures = {}
    for label, size in (("one batch", len(goals)), (f"chunks of {chunk:,}", chunk)):
        solver.CHUNK = size
        tracemalloc.start()
        t0 = time.perf_counter()
        s = lab.solve(controller, arm, goals, steps=args.steps, progress=False)
        seconds = time.perf_counter() - t0
        _now, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        answer = sum(v.nbytes for v in vars(s).values() if hasattr(v, "nbytes"))
        figures[label] = (peak, seconds)
        print(f"{label:>16}: {args.goals:,} {'poses' if args.poses else 'goals'} of {arm.name}, steps={args.steps}: "
              f"peak {peak / 2**20:6.0f} MiB traced (the goals {goals.nbytes / 2**20:.0f} MiB, the answer "
              f"{answer / 2**20:.0f} MiB), {seconds:.2f} s")
        del s
    solver.CHUNK = chunk
    (p1, t1), (p2, t2) = figures.values()
    print(f"chunked / one batch: peak {p2 / p1:.2f}, time {t2 / t1:.2f}")


if __name__ == "__main__":
    main()
