"""Trees (several end effectors): a budgeted run per robot and setting, its held-out error per effector.

For each tree and each setting (`--set` groups, `;`-separated, each `name=value,...`), one
`lab.evolve(tree, method, seconds=S, seed=s, **setting)` after the other, then the position error
||goal_e - fk_e(net(goal))|| of every effector on 2,000 held-out goals (lab.experiments.arms.held_out):
the median per effector in % of that effector's reach, their median over goals and effectors, and
the generations the budget held. With --refine, the network's answers refined by at most 3
Gauss-Newton steps (robots.ik.refine: success = the stacked error below 0.1 mm) beside damped least
squares from the rest pose (200 goals). One JSON line per run (--json), else a table.

    .venv/bin/python benchmarks/bench_trees.py --robots talos-legs --seconds 60 --set "features=cartesian;features=sphere"
    .venv/bin/python benchmarks/bench_trees.py --robots talos-legs,solo12 --seconds 120       # the defaults
    .venv/bin/python benchmarks/bench_trees.py --robots g1 --seconds 600 --refine --write-pretrained   # shipped
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

import lab  # noqa: E402
import robots  # noqa: E402
from lab.experiments import arms  # noqa: E402

TREES = tuple(n for n in robots.names() if robots.kind(n) == "tree")


def _value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def settings(text: str) -> list[dict]:
    """'a=1,b=x;c=2' -> [{'a': 1, 'b': 'x'}, {'c': 2}] ('' -> [{}]: the defaults)."""
    out = []
    for group in (text or "").split(";"):
        pairs = [p for p in group.split(",") if p.strip()]
        out.append({k.strip(): _value(v.strip()) for k, v in (p.split("=", 1) for p in pairs)})
    return out or [{}]


def measure(robot: str, method: str, seconds: float, seed: int, setting: dict, refine: bool,
            refine_goals: int = 200, write: bool = False) -> dict:
    arm = robots.load(robot)
    t = time.perf_counter()
    run = lab.evolve(robot, method, seconds=seconds, seed=seed, **setting)
    wall = time.perf_counter() - t
    stats = arms.held_out(arm, run.controller)
    row = {"robot": robot, "method": method, "seconds": seconds, "seed": seed, "setting": setting,
           "features": run.config.features, "hidden": run.config.hidden, "margin": run.config.margin,
           "generations": len(run.history), "wall_s": round(wall, 1), "train_mse": run.train_mse,
           "test_mse": run.test_mse, "median_pct": stats["median_pct"], "median_mm": stats["median"],
           "effectors": {e["effector"]: {k: round(e[k], 3) for k in ("median_pct", "p90_pct", "p99_pct", "median")}
                         for e in stats["effectors"]}}
    if refine:
        goals = arms.held_out_goals(arm, refine_goals)
        r = arms.refined(arm, run.controller, goals)
        d = arms.dls_from_rest(arm, goals, max_iter=200)
        row.update(refine_goals=refine_goals, refined_success=r["success"], refined_us=r["us_per_goal"],
                   dls_success=d["success"], dls_us=d["us_per_goal"])
    if write:
        from app.startup import write_pretrained

        row["wrote"] = write_pretrained(run, stats)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="talos-legs,solo12", help=f"comma-separated, among: {', '.join(TREES)}")
    ap.add_argument("--method", default=lab.methods.DEFAULT_METHOD, help="a registered method (lab.methods.names())")
    ap.add_argument("--seconds", type=float, default=60.0, help="each run's time budget (optimizer time)")
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds")
    ap.add_argument("--set", default="", help="settings to compare: 'name=value,...;name=value,...' (none: the defaults)")
    ap.add_argument("--refine", action="store_true", help="also refine the answers and run damped least squares")
    ap.add_argument("--refine-goals", type=int, default=200, help="held-out goals refined (--refine)")
    ap.add_argument("--write-pretrained", action="store_true",
                    help="also write each run as the app's shipped controller (app/pretrained/<robot>-<method>.json, "
                         "with the held-out stats of every effector)")
    ap.add_argument("--json", action="store_true", help="one JSON line per run")
    args = ap.parse_args()
    if args.refine_goals < 1:
        raise ValueError(f"--refine-goals must be a positive number of goals, got {args.refine_goals}")
    for robot in args.robots.split(","):
        for setting in settings(args.set):
            for seed in (int(s) for s in args.seeds.split(",")):
                row = measure(robot, args.method, args.seconds, seed, setting, args.refine, args.refine_goals,
                              args.write_pretrained)
                if args.json:
                    print(json.dumps(row), flush=True)
                    continue
                per = "  ".join(f"{name} {v['median_pct']:.2f}%" for name, v in row["effectors"].items())
                print(f"{robot:11s} {args.method} {json.dumps(setting):40s} seed {seed}: {row['generations']:6d} gens, "
                      f"median {row['median_pct']:.2f}% ({row['median_mm']:.1f} mm); {per}", flush=True)


if __name__ == "__main__":
    main()
