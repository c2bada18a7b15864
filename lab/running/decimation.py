"""What a run hands on of its generations, by rule: which generations a recording logs, which
populations go out (the runner's events, the recording, the app), and the goal each population's
reach is taken at. Each generation rule is one named function of the generation index.

- `long_run(g)`: the per-generation numbers (best, median and worst MSE, their log10, the search
  state) and the controller in force: every generation below 10,000, then every 10th below 100,000,
  every 100th below 10^6, ... (a tenth of the rate per tenfold of generations: at most 9,000 more
  logged generations per decade). A run's last generation is always logged. At about 460 bytes
  a logged generation, 10^9 generations make about 25 MB instead of 460 GB.

- `population_logged(g)`: a generation's whole population (each candidate's MSE, species and point):
  every generation below 100, then every 10th, and only generations long_run logs (so beyond
  100,000 it thins as long_run does); 50,000 generations of a real arm keep 5,090 populations.

- `display_goal(arm)`: the goal at which the runner takes each candidate's end-effector point
  (Population.points) and the recording draws the cloud: the app's first goal marker's starting
  place, so a replayed cloud is the one a tab showed before its marker was moved.

A rule is a pure function (same answer for the same index, in any process), so the runner, the
app, the recording's writer and the tests agree on what a file holds. The runner applies them,
so they live here, below lab.recording (which re-exports them: lab.recording.decimation).
"""

from __future__ import annotations

import numpy as np

EVERY_UNTIL = 10_000  # every generation below this one is logged
POPULATION_EVERY_FIRST = 100  # generations 0 .. 99: each one's population
POPULATION_THEN_EVERY = 10  # beyond: every 10th
DISPLAY_SEED = 7  # app/tab/goals.py's markers start at arm.sample_goals(k + 1, seed=7)[k] (a tree's first: at rest)


def long_run(generation: int) -> bool:
    """Whether a recording logs generation `generation` (0-based) of a long run."""
    if generation < EVERY_UNTIL:
        return True
    step, bound = 10, EVERY_UNTIL * 10
    while generation >= bound:
        step, bound = step * 10, bound * 10
    return generation % step == 0


def long_run_count(generations: int) -> int:
    """How many of generations 0..generations-1 long_run logs (the last one aside)."""
    n, lo, step = min(generations, EVERY_UNTIL), EVERY_UNTIL, 10
    while generations > lo:
        hi = min(generations, lo * 10)
        n += (hi - 1) // step - (lo - 1) // step
        lo, step = lo * 10, step * 10
    return n


def population_logged(generation: int) -> bool:
    """Whether generation (from 0) has its population logged (the live views' and the recording's rule)."""
    if generation < POPULATION_EVERY_FIRST:
        return True
    return generation % POPULATION_THEN_EVERY == 0 and long_run(generation)


def display_goal(arm) -> np.ndarray:
    """The goal the recording draws the population's reach for, where the app's first marker starts:
    (len(task_axes),) arm.sample_goals(1, seed=DISPLAY_SEED)[0]; a tree's (E, len(task_axes)) is where
    its effectors are at rest (a humanoid standing, not a random goal's folded pose)."""
    if getattr(arm, "is_tree", False):
        return np.asarray(arm.reach(arm.rest), dtype=np.float64)
    return np.asarray(arm.sample_goals(1, seed=DISPLAY_SEED)[0], dtype=np.float64)
