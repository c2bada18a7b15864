"""The seed table (robots/seeds.py) in lab.solve, side by side: each shipped position controller's
held-out goals solved by `lab.solve(controller, arm, goals)` with table=0 (the network's proposals
and at most 3 refinement steps alone) and with the default (the goals those miss tried again from the
table's nearest entries), and from no network at all (`lab.solve(None, arm, goals)`: the rest pose,
then the table).

    python benchmarks/bench_seed_table.py                        # every robot with a shipped controller
    python benchmarks/bench_seed_table.py --robots ur5,planar-20 --goals 500

One process, one thread (OPENBLAS_NUM_THREADS=1). Per robot: the share within 0.1 mm (the paper's
arms: 1e-3 of their units) and the wall ms a goal of each way (the first call, which builds the
table and loads the kernels, not timed), and how many goals the table was tried on. Prints a
markdown table (docs/results/your-robot.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PRETRAINED = Path(__file__).resolve().parents[1] / "app" / "pretrained"


def shipped_robots() -> list[str]:
    return sorted(p.name[: -len("-cmaes.json")] for p in PRETRAINED.glob("*-cmaes.json") if "-pose-" not in p.name)


def row(name: str, n_goals: int) -> dict:
    import lab
    import robots
    from lab.experiments import arms
    from lab.solver import TABLE

    arm = robots.load(name)
    with open(PRETRAINED / f"{name}-cmaes.json", encoding="utf-8") as f:
        controller = lab.controller_from_dict(json.load(f)["controller"])
    goals = arms.held_out_goals(arm, n_goals)
    out = {"robot": name, "goals": n_goals, "table": TABLE, "load": round(os.getloadavg()[0], 1)}
    for key, c, table in (("network", controller, 0), ("with_table", controller, TABLE), ("no_network", None, TABLE)):
        lab.solve(c, arm, goals[:8], table=table, progress=False)  # the table built, the kernels loaded
        t = time.perf_counter()
        s = lab.solve(c, arm, goals, table=table, progress=False)
        out[key] = 100 * s.success
        out[f"{key}_ms"] = 1000 * (time.perf_counter() - t) / len(goals)
        if key == "network":
            out["tried"] = int((~s.converged).sum())
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python benchmarks/bench_seed_table.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default=None, help="comma-separated, among those with a shipped controller")
    ap.add_argument("--goals", type=int, default=2000, help="held-out goals a robot")
    args = ap.parse_args(argv)
    names = args.robots.split(",") if args.robots else shipped_robots()
    unknown = sorted(set(names) - set(shipped_robots()))
    if unknown:
        sys.exit(f"error: no shipped position controller for: {', '.join(unknown)}")
    logging.getLogger("robots").setLevel(logging.ERROR)
    print(f"| robot | goals | network + 3 steps, % | ms a goal | + the seed table, % | ms a goal | goals tried on "
          f"the table | no network (rest pose, table), % | ms a goal | load |\n|---|---|---|---|---|---|---|---|---|---|")
    for name in names:
        r = row(name, args.goals)
        print(f"| {name} | {r['goals']} | {r['network']:.2f} | {r['network_ms']:.3f} | **{r['with_table']:.2f}** "
              f"| {r['with_table_ms']:.3f} | {r['tried']} | {r['no_network']:.2f} | {r['no_network_ms']:.3f} "
              f"| {r['load']} |", flush=True)


if __name__ == "__main__":
    main()
