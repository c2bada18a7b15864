"""The claims experiment's design: the methods and arms it compares, its budgets, checkpoints and
the thresholds its report judges runs by (the runs, claims.py, and the report, claims_report.py,
both read them here; see claims.py for the experiment in words).
"""

from __future__ import annotations

import numpy as np

# The compared methods, each at its defaults (x, y order of the Welch tests): the one place in
# this experiment that names methods (tests/test_methods.py allows it). The first is the
# reference: its population sets the budget, its speed the time limit, and it is the method of
# the fixed-vs-resampled comparison; the last is the gradient method, the others are evolved.
METHODS = ("cmaes", "neat", "neat_cma", "gradient")
# the paper's arms, its "highly redundant" snakes, two real arms, and two of the robots the paper names
# as its reason (a 12-joint biped, a 29-joint humanoid): trees of several end effectors
ROBOTS = ("planar", "scara", "planar-10", "planar-20", "ur5", "panda", "talos-legs", "g1")
RESAMPLE_ROBOTS = ("planar", "scara")
# seconds per generation of the reference method with its defaults on each arm, measured on this
# 2-core machine (2026-11-24, under load ~2-4; the trees 2026-12-04, idle, with their turn): the
# equal-time limit is generations x this
SECONDS_PER_GENERATION = {"planar": 0.003, "scara": 0.003, "planar-10": 0.0035, "planar-20": 0.006,
                          "ur5": 0.009, "panda": 0.010, "talos-legs": 0.012, "g1": 0.023}
CAP = 10  # equal-time runs: generation cap, x the method's equal-budget generations
CHECKPOINTS = 12  # held-out error at this many log-spaced points of the budget (and at the end)
FIRST_CHECKPOINT = 0.01  # the first at 1% of the budget
POOR_FACTOR = 10.0  # stuck: held-out error above POOR_FACTOR x the best run of any method on the arm
POOR_REACH = 0.10  # stuck, absolute: held-out error above 10% of the arm's reach
TARGET_REACH = 0.05  # "time to reach": held-out error at or below 5% of the arm's reach
DEFAULT_RUNS = 5  # seeds: 10 is the full test; cut to fit 10 minutes on 2 cores
DEFAULT_GENERATIONS = 400  # the reference method's generations (E = 400 x 50 = 20,000 evaluations)
BUDGETS = ("evaluations", "seconds")


def generations_for(budget: int, per_step: int) -> int:
    """Steps of a method that counts per_step evaluations a step within `budget` evaluations
    (at least one): it uses budget - per_step < evaluations <= budget."""
    return max(1, int(budget) // int(per_step))


def stuck(errors: dict, absolute: float, factor: float = POOR_FACTOR) -> dict:
    """{method: (relative, absolute, n)}: how many runs of each method have a held-out error above
    factor x the best run of any method (relative) and above `absolute`. errors: {method: [error per run]}."""
    finite = [e for v in errors.values() for e in v if np.isfinite(e)]
    best = min(finite) if finite else np.inf
    return {m: (int(sum(e > factor * best for e in v)), int(sum(e > absolute for e in v)), len(v))
            for m, v in errors.items()}
