"""Which generations' populations are kept, and where their cloud is drawn (shared by the runner,
the recording and the app).

    population_logged(g)     # every generation up to 100, then every 10th (lab/recording/decimation.py)
    display_goal(arm)        # the goal the recording draws each candidate's reach for

A population is every candidate of a generation (lab.methods.Population): its training MSE, its
species where the method has them, and its end-effector point at the display goal. A long run
logs about a tenth of its generations: 50,000 generations of a real arm keep 5,090 populations.
The display goal is the app's first goal marker's starting place, so a replayed cloud is the one
a tab showed before its marker was moved.
"""

from __future__ import annotations

import numpy as np

from lab.recording.decimation import population_logged  # noqa: F401 - the rule lives with the others

DISPLAY_SEED = 7  # app/goals.py's markers start at arm.sample_goals(k + 1, seed=7)[k]


_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
SPECIES = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                    [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8)


def ramp(t: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (NaN: 1) -> (n, 3) uint8 along a viridis-like ramp (dark purple to yellow)."""
    t = np.clip(np.nan_to_num(np.asarray(t, float), nan=1.0), 0, 1) * (len(_RAMP) - 1)
    i = np.minimum(t.astype(int), len(_RAMP) - 2)
    f = (t - i)[:, None]
    return ((1 - f) * _RAMP[i] + f * _RAMP[i + 1]).astype(np.uint8)


def mse_scale(mse: np.ndarray) -> tuple[float, float]:
    """(lowest, highest) finite MSE of a population: the ends of its colour scale (NaN, NaN if none)."""
    finite = np.asarray(mse, float)[np.isfinite(mse)]
    return (float(finite.min()), float(finite.max())) if len(finite) else (np.nan, np.nan)


def mse_colors(mse: np.ndarray) -> np.ndarray:
    """(n, 3) uint8: each candidate's training MSE on one log scale, from the population's best (dark
    purple) to its worst (yellow); NaN or inf as the worst. The app and the recordings use this one."""
    mse = np.asarray(mse, float)
    lo, hi = mse_scale(mse)
    if not np.isfinite(lo):
        return ramp(np.ones(len(mse)))
    ll, lh = np.log10(max(lo, 1e-300)), np.log10(max(hi, 1e-300))
    if lh <= ll:
        return ramp(np.zeros(len(mse)))
    return ramp((np.log10(np.maximum(np.nan_to_num(mse, nan=hi, posinf=hi), 1e-300)) - ll) / (lh - ll))


def species_colors(species: np.ndarray) -> np.ndarray:
    """(n, 3) uint8: one colour per species id (a palette of 10, by id)."""
    return SPECIES[np.asarray(species, np.int64) % len(SPECIES)]


def display_goal(arm) -> np.ndarray:
    """(len(task_axes),) the goal the recording draws the population's reach for."""
    return np.asarray(arm.sample_goals(1, seed=DISPLAY_SEED)[0], dtype=np.float64)
