"""How a population is drawn, in the recordings and the app: its colours.

    mse_colors(mse), species_colors(species)   # (n, 3) uint8, one colour per candidate
    population_logged(g), display_goal(arm)    # the rules of which populations are kept and where
                                               # their cloud is drawn (lab/running/decimation.py)

A population is every candidate of a generation (lab.methods.Population): its training MSE, its
species where the method has them, and its end-effector point at the display goal.
"""

from __future__ import annotations

import numpy as np

from lab.running.decimation import DISPLAY_SEED, display_goal, population_logged  # noqa: F401 - named here too

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
