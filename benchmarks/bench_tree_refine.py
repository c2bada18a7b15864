"""Where a tree's refinement fails: the shipped controller's answers refined on held-out goals, the
failures split by effector and limb group, and what other refinements would have given.

For each tree, its shipped controller (app/pretrained/<tree>-cmaes.json) answers 2,000 held-out goals
(lab.experiments.arms.held_out_goals) and robots.ik.refine takes it from there; success: every
effector within 0.1 mm (refine's default tolerance). Printed per tree:

- refined: the share of goals within tolerance after at most 3, 8 and 20 steps (a multi-head network:
  every head's answer proposed, each limb group's nearest first, and refine mixes them by group);
- without limbs: the same in 3 steps with refine(..., limbs=False), no limb solved in closed form
  (robots.limbs) first, and the time per goal of both (the forward pass excluded; numba's kernels
  compiled before the clock starts);
- fails by effector: how many goals each effector misses after 3 steps (a goal fails when one does);
- by group: each limb group's success alone (lab.problem.wiring.limb_groups: groups share no joint);
- limb by limb: each group refined on its own (the other effectors' goals set where they already
  are, so each group's step length and stop are its own), 3 steps;
- flips, upper bound: each group's answer and every joint of it turned by +-pi (within limits), each
  refined 3 steps, a group counted as solved when any of them is (more than a refinement could
  pick: it sees every try's end);
- at a limit: the share of the group's 3-step failures whose network answer holds a joint of the
  group at a limit, beside that share among all its answers.

    .venv/bin/python benchmarks/bench_tree_refine.py                      # every tree
    .venv/bin/python benchmarks/bench_tree_refine.py --robots g1 --goals 500 --goal-seed 2
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

import robots  # noqa: E402
from app.startup import load_pretrained  # noqa: E402
from lab.experiments import arms  # noqa: E402
from lab.problem.controllers import proposals  # noqa: E402
from lab.problem.wiring import limb_groups  # noqa: E402
from robots.ik import default_tolerance, refine  # noqa: E402

TREES = tuple(n for n in robots.names() if robots.kind(n) == "tree")


def group_errors(arm, q, goals, group) -> np.ndarray:
    """(n,) the worst distance of the group's effectors from their goals."""
    return np.linalg.norm(arm.reach(q)[:, group] - goals[:, group], axis=-1).max(axis=1)


def alone(arm, q, goals, group, steps: int, flips: bool = True):
    """The group refined on its own: the other effectors' goals where q already puts them."""
    held = arm.reach(q).copy()
    held[:, group] = goals[:, group]
    return refine(arm, held, q[None], steps=steps, flips=flips).q


def measure(robot: str, n: int, goal_seed: int) -> dict:
    arm = robots.load(robot)
    controller, _ = load_pretrained(robot)
    goals = arms.held_out_goals(arm, n, goal_seed)
    seeds = proposals(controller, goals)  # (heads, n, nq): every head's, each limb group's nearest first
    q0 = seeds[0]  # the network's answer
    tol = default_tolerance(arm)
    out = {"robot": robot, "goals": n, "goal_seed": goal_seed, "heads": len(seeds)}
    refine(arm, goals[:4], seeds[:, :4], steps=3)  # numba's kernels compiled outside the clock
    for limbs in (False, True):
        start = time.perf_counter()
        r3 = refine(arm, goals, seeds, steps=3, limbs=limbs)
        out["us_per_goal" if limbs else "us_per_goal_without_limbs"] = 1e6 * (time.perf_counter() - start) / n
        out["refined_3" if limbs else "refined_3_without_limbs"] = float(r3.converged.mean())
    for steps in (8, 20):
        out[f"refined_{steps}"] = float(refine(arm, goals, seeds, steps=steps).converged.mean())
    miss = np.linalg.norm(arm.reach(r3.q) - goals, axis=-1) >= tol  # (n, E)
    out["fails_by_effector"] = dict(zip(arm.effectors, miss.sum(axis=0).tolist()))
    groups = limb_groups(arm)
    lower, upper = arm.lower, arm.upper
    q_limb, solved_any = q0.copy(), np.ones(n, bool)
    out["groups"] = []
    for group in groups:
        joints = sorted({int(j) for e in group for j in arm.chain.path(e)})
        ok = group_errors(arm, r3.q, goals, group) < tol
        q_limb = alone(arm, q_limb, goals, group, 3)
        tries = [q0]
        for j in joints:
            for half in (math.pi, -math.pi):
                qf = q0.copy()
                qf[:, j] += half
                inside = (lower[j] <= qf[:, j]) & (qf[:, j] <= upper[j])
                tries.append(np.where(inside[:, None], qf, q0))
        any_ok = np.zeros(n, bool)
        for qt in tries:
            any_ok |= group_errors(arm, alone(arm, qt, goals, group, 3, flips=False), goals, group) < tol
        solved_any &= any_ok
        at_limit = (np.isclose(q0[:, joints], lower[joints], atol=1e-6)
                    | np.isclose(q0[:, joints], upper[joints], atol=1e-6)).any(axis=1)
        out["groups"].append({"effectors": [arm.effectors[e] for e in group], "joints": len(joints),
                              "refined_3": float(ok.mean()), "flips_upper_bound": float(any_ok.mean()),
                              "failures_at_a_limit": float(at_limit[~ok].mean()) if (~ok).any() else 0.0,
                              "answers_at_a_limit": float(at_limit.mean())})
    out["limb_by_limb_3"] = float((np.linalg.norm(arm.reach(q_limb) - goals, axis=-1) < tol).all(axis=1).mean())
    out["flips_upper_bound"] = float(solved_any.mean())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default=",".join(TREES), help=f"comma-separated, among: {', '.join(TREES)}")
    ap.add_argument("--goals", type=int, default=arms.HELD_OUT, help="held-out goals (default 2,000)")
    ap.add_argument("--goal-seed", type=int, default=0, help="0: the held-out goals; 2: arms.OTHER_GOALS")
    ap.add_argument("--json", action="store_true", help="one JSON line per tree")
    args = ap.parse_args()
    for robot in args.robots.split(","):
        if robot not in TREES:
            ap.error(f"{robot!r} is not a tree; the trees: {', '.join(TREES)}")
        row = measure(robot, args.goals, args.goal_seed)
        if args.json:
            print(json.dumps(row), flush=True)
            continue
        print(f"{robot} ({row['heads']} head{'s' if row['heads'] > 1 else ''}): refined {100 * row['refined_3']:.2f} / {100 * row['refined_8']:.2f} / "
              f"{100 * row['refined_20']:.2f} % (3 / 8 / 20 steps); limb by limb {100 * row['limb_by_limb_3']:.2f} %; "
              f"flips, upper bound {100 * row['flips_upper_bound']:.2f} %")
        print(f"  3 steps: {100 * row['refined_3']:.2f} %, {row['us_per_goal']:.0f} us per goal; without limbs "
              f"{100 * row['refined_3_without_limbs']:.2f} %, {row['us_per_goal_without_limbs']:.0f} us per goal")
        print(f"  fails by effector (3 steps): {row['fails_by_effector']}")
        for g in row["groups"]:
            print(f"  {'+'.join(g['effectors'])} ({g['joints']} joints): {100 * g['refined_3']:.2f} %, flips upper "
                  f"bound {100 * g['flips_upper_bound']:.2f} %, a joint at a limit in "
                  f"{100 * g['failures_at_a_limit']:.0f} % of its failures ({100 * g['answers_at_a_limit']:.0f} % of all "
                  "answers)", flush=True)


if __name__ == "__main__":
    main()
