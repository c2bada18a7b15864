"""Real arms: a controller's held-out position error, and a learned seed made exact.

    stats = held_out(arm, controller)           # median / p90 / p99 error, in the arm's unit and in % of reach
    seed = refined(arm, controller, goals)      # the network's output + at most 3 Gauss-Newton steps
    base = dls_from_rest(arm, goals)            # damped least squares from the rest pose, same tolerance

Held-out goals are drawn from uniformly random joint vectors (arm.sample_goals with the held-out
seed, as lab.problem.Problem's); reach = arm.reach_radius (the farthest end-effector position
from the base origin over 20,000 joint samples). benchmarks/bench_arms.py prints these per arm,
and `python -m app.startup` stores them with the app's shipped controllers.

A tree (several end effectors): held_out gives the same numbers per effector ("effectors": each one's
median, p90 and p99 in mm and in % of ITS reach, arm.effector_reach[e]) and overall ("median" and
"median_pct": the median over every goal and effector, each error in % of its own effector's reach);
refined and dls_from_rest take a tree's goals (n, E, 3), their error the norm of all effectors'
errors stacked (robots.ik), to the same tolerance.
"""

from __future__ import annotations

import time

import numpy as np

import robots
from lab.problem.controllers import proposals
from lab.problem.fitness import TEST_SEED_OFFSET
from robots.ik import default_tolerance, dls_ik, refine

HELD_OUT = 2000
OTHER_GOALS = 2  # the goal seed of a second held-out set, tuned on by nobody (0: the held-out goals; 1: validation)


def held_out_goals(arm: robots.Arm, n: int = HELD_OUT, goal_seed: int = 0) -> np.ndarray:
    """n goals from uniformly random joint vectors: arm.sample_goals(n, seed=goal_seed + TEST_SEED_OFFSET)."""
    return arm.sample_goals(n, seed=goal_seed + TEST_SEED_OFFSET)


def tolerance(arm: robots.Arm) -> float:
    """'Exact': refine's default tolerance (robots.ik.default_tolerance): 0.1 mm on a real arm; on the
    paper's arms the same fraction of the workspace (1e-4)."""
    return default_tolerance(arm)


def position_errors(arm: robots.Arm, controller, goals: np.ndarray) -> np.ndarray:
    """||goal - reach(controller(goal))|| per goal [the arm's length unit]: (n,), a tree's (n, E), per effector."""
    return np.linalg.norm(arm.reach(controller(goals)) - goals, axis=-1)


def error_stats(arm: robots.Arm, errors: np.ndarray) -> dict:
    """Median, 90th and 99th percentile of errors, in the arm's unit (mm for a real arm) and in % of reach."""
    scale = 1000.0 if robots.in_metres(arm.name) else 1.0
    out = {"unit": "mm" if scale == 1000.0 else "paper units", "reach": arm.reach_radius * scale}
    for name, q in (("median", 50), ("p90", 90), ("p99", 99)):
        v = float(np.percentile(errors, q))
        out[name], out[f"{name}_pct"] = v * scale, 100.0 * v / arm.reach_radius
    return out


def held_out(arm: robots.Arm, controller, n: int = HELD_OUT, goal_seed: int = 0) -> dict:
    errors = position_errors(arm, controller, held_out_goals(arm, n, goal_seed))
    return tree_error_stats(arm, errors) if arm.is_tree else error_stats(arm, errors)


def tree_error_stats(arm: robots.Arm, errors: np.ndarray) -> dict:
    """A tree's errors (n, E): error_stats of each effector in % of its own reach (arm.effector_reach[e]),
    under "effectors" (with its name), and the median over all goals and effectors, in the arm's unit
    ("median") and in % of each error's own effector's reach ("median_pct")."""
    scale = 1000.0 if robots.in_metres(arm.name) else 1.0
    reach = np.asarray(arm.effector_reach, dtype=np.float64)
    out = {"unit": "mm" if scale == 1000.0 else "paper units", "reach": arm.reach_radius * scale,
           "median": float(np.median(errors)) * scale, "median_pct": float(np.median(100.0 * errors / reach)),
           "effectors": []}
    for e, name in enumerate(arm.effectors):
        row = {"effector": name, "reach": float(reach[e]) * scale}
        for label, q in (("median", 50), ("p90", 90), ("p99", 99)):
            v = float(np.percentile(errors[:, e], q))
            row[label], row[f"{label}_pct"] = v * scale, 100.0 * v / float(reach[e])
        out["effectors"].append(row)
    return out


def refined(arm: robots.Arm, controller, goals: np.ndarray, steps: int = 3, most: int = 8) -> dict:
    """The network's output refined by a turn of the base joint and at most `steps` Gauss-Newton steps
    (robots.ik.refine; a multi-head network proposes every head's answer, and the one nearest its
    goal after the first step goes on), timed together (one batched forward pass + the turn and the steps):
    success = error below tolerance(arm); success_without_turn: the same steps without the turn
    (untimed). by_steps[k - 1]: the success rate with at most k steps, k = 1 .. most (untimed: a goal's first
    k steps are the same whatever the limit, so one run of `most` steps gives them all)."""
    t0 = time.perf_counter()
    q0 = proposals(controller, goals)
    r = refine(arm, goals, q0, steps=steps, tol=tolerance(arm))
    seconds = time.perf_counter() - t0
    ok = r.error < tolerance(arm)
    longer = refine(arm, goals, q0, steps=most, tol=tolerance(arm))
    done = longer.error < tolerance(arm)
    by_steps = [float(np.mean(done & (longer.steps <= k))) for k in range(1, most + 1)]
    steps_alone = refine(arm, goals, q0, steps=steps, tol=tolerance(arm), turn=False).error < tolerance(arm)
    return {"success": float(ok.mean()), "us_per_goal": 1e6 * seconds / len(goals), "by_steps": by_steps,
            "success_without_turn": float(steps_alone.mean()),
            "mean_steps": float(r.steps[ok].mean()) if ok.any() else float("nan"), "errors": r.error}


def dls_from_rest(arm: robots.Arm, goals: np.ndarray, max_iter: int = 500) -> dict:
    """Damped least squares (robots.ik.dls_ik) from the rest pose to the same tolerance."""
    t0 = time.perf_counter()
    results = [dls_ik(arm, g, tol=tolerance(arm), max_iter=max_iter) for g in goals]
    seconds = time.perf_counter() - t0
    ok = np.array([r.converged for r in results])
    return {"success": float(ok.mean()), "us_per_goal": 1e6 * seconds / len(goals),
            "mean_iterations": float(np.mean([r.iterations for r in results]))}
