"""Which generations' populations are kept, and where their cloud is drawn (shared by the runner,
the recording and the app).

    population_logged(g)     # every generation up to 100, then every 10th
    display_goal(arm)        # the goal the recording draws each candidate's reach for

A population is every candidate of a generation (lab.methods.Population): its training MSE, its
species where the method has them, and its end-effector point at the display goal. A long run
logs about a tenth of its generations: 40,000 generations of a real arm keep 4,090 populations.
The display goal is the app's first goal marker's starting place, so a replayed cloud is the one
a tab showed before its marker was moved.
"""

from __future__ import annotations

import numpy as np

EVERY_FIRST = 100  # generations 0 .. 99: each one
THEN_EVERY = 10  # beyond: every 10th
DISPLAY_SEED = 7  # app/goals.py's markers start at arm.sample_goals(k + 1, seed=7)[k]


def population_logged(generation: int) -> bool:
    """Whether generation (from 0) has its population logged: each of the first EVERY_FIRST,
    then every THEN_EVERY-th."""
    return generation < EVERY_FIRST or generation % THEN_EVERY == 0


def display_goal(arm) -> np.ndarray:
    """(len(task_axes),) the goal the recording draws the population's reach for."""
    return np.asarray(arm.sample_goals(1, seed=DISPLAY_SEED)[0], dtype=np.float64)
