"""Time budgets: what each method reaches on each real arm in 10, 30, 60 and 300 s of optimizer
time, its fitness on one thread (the results: docs/results/budgets.md).

For each arm, method and budget S: `lab.evolve(arm, method, seconds=S, seed=...)` with no other
setting (the method's defaults for that budget on that arm: Method.defaults_for), then the
held-out median position error ||goal - fk(net(goal))|| on 2,000 held-out goals from uniformly
random joint vectors, in mm and in % of the arm's reach (lab.experiments.arms.held_out), and the
generations the budget held. Each run is a process of its own with LAB_THREADS=1 (the fitness on one
thread, what the app's training worker uses); --jobs runs that many side by side (2 on a 2-core
machine: one per core). The figures depend on the machine and its load: read them as ratios
between budgets, arms and methods measured in one sitting, and note the load with them.

    .venv/bin/python benchmarks/bench_budget.py                        # 8 arms x every method x 4 budgets (about 110 min on 2 cores)
    .venv/bin/python benchmarks/bench_budget.py --robots ur5 --methods cmaes --budgets 10,30
    .venv/bin/python benchmarks/bench_budget.py --out budgets.jsonl    # one JSON line per run, appended as it ends
    .venv/bin/python benchmarks/bench_budget.py --table budgets.jsonl  # the table of runs already made
    .venv/bin/python benchmarks/bench_budget.py --table budgets.jsonl --write   # and store them for the app

--write stores the held-out medians in lab/experiments/budgets.json (lab.experiments.budgets), from
which the app tells a user what a method is measured to reach on an arm before a run starts.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

BUDGETS = (10.0, 30.0, 60.0, 300.0)
ONE_RUN = """
import json, os, sys, time
import lab, robots
from lab.experiments.arms import held_out
robot, method, seconds, seed = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
load = os.getloadavg()[0]
run = lab.evolve(robot, method, seconds=seconds, seed=seed)
stats = held_out(robots.load(robot), run.controller)
print(json.dumps(dict(robot=robot, method=method, seconds=seconds, seed=seed, generations=len(run.history),
                      optimizer_s=run.seconds, load_before=load, load_after=os.getloadavg()[0],
                      median_mm=stats["median"], median_pct=stats["median_pct"], p90_pct=stats["p90_pct"],
                      p99_pct=stats["p99_pct"], settings=run.config.to_dict())))
"""


def one_run(robot: str, method: str, seconds: float, seed: int) -> dict:
    env = dict(os.environ, LAB_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", ONE_RUN, robot, method, str(seconds), str(seed)],
                          capture_output=True, text=True, env=env, cwd=ROOT)
    if done.returncode != 0:
        return dict(robot=robot, method=method, seconds=seconds, seed=seed, error=done.stderr.strip()[-500:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def table(rows: list[dict], robots_: list[str], methods_: list[str], budgets: list[float]) -> str:
    """Markdown: a row per arm and method, a column per budget: median % of reach (mm), generations."""
    at = {(r["robot"], r["method"], float(r["seconds"])): r for r in rows}
    head = "| arm | method | " + " | ".join(f"{b:g} s" for b in budgets) + " |"
    lines = [head, "|" + "---|" * (2 + len(budgets))]
    for robot in robots_:
        for method in methods_:
            cells = []
            for b in budgets:
                r = at.get((robot, method, float(b)))
                if r is None:
                    cells.append("")
                elif "error" in r:
                    cells.append("failed")
                else:
                    cells.append(f"{r['median_pct']:.2f} % ({r['median_mm']:.1f} mm), {r['generations']:,} gen")
            lines.append(f"| {robot} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    import lab
    import robots

    real = [n for n in robots.names() if robots.kind(n) == "real"]
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", default=",".join(real), help="comma-separated (default: the real arms)")
    p.add_argument("--methods", default=",".join(lab.methods.names()), help="comma-separated (default: every method)")
    p.add_argument("--budgets", default=",".join(f"{b:g}" for b in BUDGETS), help="seconds, comma-separated")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=int, default=2, help="runs side by side, each on one thread (default 2)")
    p.add_argument("--out", help="append each run's JSON line to this file as it ends")
    p.add_argument("--table", metavar="JSONL", help="print the table of the runs in this file, run nothing")
    p.add_argument("--write", action="store_true",
                   help="store the runs' medians in lab/experiments/budgets.json (what the app quotes)")
    p.add_argument("--machine", default="the lab's 2-core development machine", help="where they were measured (--write)")
    args = p.parse_args()
    robots_, methods_ = args.robots.split(","), args.methods.split(",")
    budgets = [float(b) for b in args.budgets.split(",")]
    for name in robots_:
        robots.load(name)  # an unknown name is refused here, by name, before any run
    for name in methods_:
        lab.methods.get(name)
    if args.table:
        with open(args.table, encoding="utf-8") as f:
            rows = [json.loads(line) for line in f if line.strip()]
        print(table(rows, robots_, methods_, budgets))
        if args.write:
            store(rows, args.machine)
        return
    # the longest runs first, so that the two lanes end together
    jobs = sorted(((r, m, b) for r in robots_ for m in methods_ for b in budgets), key=lambda j: -j[2])
    rows, t0 = [], time.time()
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        for row in pool.map(lambda j: one_run(*j, args.seed), jobs):
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "settings"}), flush=True)
            if args.out:
                with open(args.out, "a", encoding="utf-8") as f:
                    f.write(json.dumps(row) + "\n")
    print(f"\n{len(rows)} runs in {time.time() - t0:.0f} s, {args.jobs} side by side\n")
    print(table(rows, robots_, methods_, budgets))
    if args.write:
        store(rows, args.machine)


def store(rows: list[dict], machine: str) -> None:
    from lab.experiments import budgets

    budgets.write(rows, machine, time.strftime("%Y-%m-%d"))
    print(f"\nwrote {budgets.BUDGETS_FILE}")


if __name__ == "__main__":
    main()
