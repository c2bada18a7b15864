"""Pose controllers: train them, measure them, and write the shipped ones.

    python benchmarks/bench_pose_train.py --robots ur5,panda --seconds 270 --write-pretrained
    python benchmarks/bench_pose_train.py --robots ur5 --seconds 60 --set heads=2 --set reach=3
    python benchmarks/bench_pose_train.py --from-pretrained                       # measure the shipped files

Each arm is trained by lab.evolve(arm, method, goal="pose", seconds=S, seed=0, ...) (the method's
pose defaults, overridden by --set), then measured on --n pose goals of --eval-seed (robots.pose.
sample_poses; no training or tuning used that seed): the network alone's median position error [mm]
and angle [degrees] (on the SO arms the approach axis's), the share within 0.1 mm and 0.1 degree
after at most 3 refinement steps (lab.solve, every head's answer proposed; without and with its
sweep of one joint, lab.solver.SWEEP), and the time a goal takes there. --write-pretrained writes
app/pretrained/<arm>-pose-<method>.json in the position
controllers' format (benchmarks/bench_arms.py). Run it with LAB_THREADS=1 beside other work.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import lab  # noqa: E402
import robots  # noqa: E402
from lab import methods  # noqa: E402
from robots import pose  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PRETRAINED = ROOT / "app" / "pretrained"
ARMS = ("ur5", "panda", "so100", "ur10", "xarm7", "kinova", "z1", "so101")
EVAL_SEED = 4_040_404  # the held-out pose goals: no training run and no tuning used this seed


def parse_value(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def measure(controller, arm, n: int, seed: int) -> dict:
    """The network alone and refined (<= 3 steps) on n pose goals of seed."""
    T = pose.sample_poses(arm, n, seed=seed)
    alone = lab.solve(controller, arm, T, steps=0)
    t = time.perf_counter()
    plain = lab.solve(controller, arm, T, steps=3, sweep=0)
    t_plain = time.perf_counter() - t
    t = time.perf_counter()
    s = lab.solve(controller, arm, T, steps=3)
    per_goal = (time.perf_counter() - t) / n
    return {"median_mm": 1000 * float(np.median(alone.error)), "p90_mm": 1000 * float(np.quantile(alone.error, 0.9)),
            "median_deg": float(np.degrees(np.median(alone.angle))),
            "p90_deg": float(np.degrees(np.quantile(alone.angle, 0.9))),
            "refined": float(s.success), "refine_us": 1e6 * per_goal,
            "refined_no_sweep": float(plain.success), "refine_no_sweep_us": 1e6 * t_plain / n}


def write_pretrained(run, held_out: dict, method: str) -> Path:
    """app/pretrained/<arm>-pose-<method>.json in the position controllers' format (app.startup.
    write_pretrained: settings, train_mse, test_mse, seconds, held_out, controller); held_out: the
    network alone's median position error in mm (the app shows it) and this script's other figures."""
    path = PRETRAINED / f"{run.config.robot}-pose-{method}.json"
    doc = {"settings": run.config.to_dict(), "train_mse": run.train_mse, "test_mse": run.test_mse,
           "seconds": run.seconds, "held_out": {"unit": "mm", "median": held_out["median_mm"], **held_out},
           "controller": run.controller.to_dict()}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc))
    os.replace(tmp, path)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", default=",".join(ARMS))
    p.add_argument("--method", default=methods.DEFAULT_METHOD, choices=methods.names())
    p.add_argument("--seconds", type=float, default=270.0, help="each arm's time budget (optimizer time)")
    p.add_argument("--generations", type=int, default=None, help="instead of a budget")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n", type=int, default=2000, help="held-out pose goals")
    p.add_argument("--eval-seed", type=int, default=EVAL_SEED)
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a setting over the defaults")
    p.add_argument("--write-pretrained", action="store_true")
    p.add_argument("--from-pretrained", action="store_true", help="measure the shipped pose files, train nothing")
    args = p.parse_args(argv)
    overrides = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}
    print(f"# load {open('/proc/loadavg').read().split()[:3]}  LAB_THREADS={os.environ.get('LAB_THREADS')}  "
          f"eval seed {args.eval_seed}, {args.n} poses")
    print("| arm | method | settings | training | network alone: median (p90) position | angle | "
          "refined <= 3 steps: within 0.1 mm and 0.1 deg, no sweep (time/goal) | with the sweep | time/goal |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.robots.split(","):
        arm = robots.load(name)
        if args.from_pretrained:
            doc = json.loads((PRETRAINED / f"{name}-pose-{args.method}.json").read_text())
            controller, config = lab.controller_from_dict(doc["controller"]), lab.TrainConfig.from_dict(doc["settings"])
            train = f"{doc['seconds']:.0f} s"
        else:
            budget = {} if args.generations else {"seconds": args.seconds}
            run = lab.evolve(name, args.method, generations=args.generations, seed=args.seed, goal="pose",
                             **budget, **overrides)
            controller, config = run.controller, run.config
            train = f"{len(run.history):,} gen, {run.seconds:.0f} s"
        m = measure(controller, arm, args.n, args.eval_seed)
        if args.write_pretrained and not args.from_pretrained:
            write_pretrained(run, {**m, "goals": args.n, "seed": args.eval_seed}, args.method)
        settings = f"heads {config.heads}, turn {config.turn}, {config.features}, margin {config.margin:g}, " \
                   f"hidden {config.hidden}" + (f", reach {config.reach}" if config.reach else "")
        settings += "".join(f", {k}={v}" for k, v in overrides.items()
                            if k not in ("heads", "turn", "features", "margin", "hidden", "reach"))
        print(f"| {name} | {args.method} | {settings} | {train} | {m['median_mm']:.1f} mm ({m['p90_mm']:.1f}) | "
              f"{m['median_deg']:.2f} deg ({m['p90_deg']:.2f}) | {100 * m['refined_no_sweep']:.1f} % "
              f"({m['refine_no_sweep_us']:.0f} us) | {100 * m['refined']:.1f} % | "
              f"{m['refine_us']:.0f} us |", flush=True)
    print(f"# load {open('/proc/loadavg').read().split()[:3]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
