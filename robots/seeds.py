"""A table of joint vectors drawn within an arm's limits and the positions they reach: for a goal, the
entries that reach nearest it are starts for refinement (robots.ik.refine) on any arm, with no
network and no closed form.

    from robots import seeds
    table = seeds.table(arm)              # SIZE entries, built once per arm (a fixed seed), then cached
    q0 = table.nearest(goals, k=4)        # (4, n, nq): each goal's 4 nearest entries, nearest first

A network trained for a minute on an arm it was never told about leaves a few goals on a branch no
Gauss-Newton step leaves (a joint held at its limit, the elbow on the wrong side): more steps do not
help there, another start does. The nearest entries are such starts: they lie within the limits, and
some reach the goal from the branch that solves it. The figures: docs/results/your-robot.md.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np
from scipy.spatial import cKDTree

SIZE = 4096  # entries of an arm's table (3.5-15 ms to build: docs/results/your-robot.md)
SEED = 20_241  # the generator's seed: the same table on every machine that draws the same numbers


class SeedTable:
    """SIZE joint vectors of `arm` drawn uniformly within its limits (arm.sample_q, seed SEED) and the
    rest pose, with the goal coordinates each reaches (a tree: its effectors' stacked), in a k-d tree."""

    def __init__(self, arm, size: int = SIZE, seed: int = SEED):
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
            raise ValueError(f"a seed table needs a whole number of entries >= 1, got {size!r}")
        q = np.concatenate([arm.rest[None], arm.sample_q(int(size), seed)])
        points = arm.reach(q).reshape(len(q), -1)
        finite = np.isfinite(points).all(axis=1)
        if not finite.any():
            raise ValueError(f"{arm.name}: no joint vector of the seed table reaches a finite position")
        self.q, self.points = q[finite], points[finite]
        self.nq = arm.nq
        self._tree = cKDTree(self.points)

    def __len__(self) -> int:
        return len(self.q)

    def nearest(self, goals, k: int) -> np.ndarray:
        """(k, n, nq): for each of the n goals ((n, len(task_axes)), a tree's (n, E, len(task_axes))),
        the k entries that reach nearest it (Euclidean distance over the stacked coordinates), nearest
        first."""
        goals = np.asarray(goals, dtype=np.float64)
        k = int(min(max(k, 1), len(self.q)))
        flat = goals.reshape(len(goals), -1)
        if flat.shape[1:] != self.points.shape[1:]:
            raise ValueError(f"goals of shape {goals.shape} do not match the table's {self.points.shape[1]} coordinates")
        if not len(flat):
            return np.zeros((k, 0, self.nq))
        _, idx = self._tree.query(flat, k=k)
        idx = np.asarray(idx).reshape(len(flat), k)
        return np.ascontiguousarray(np.transpose(self.q[idx], (1, 0, 2)))


_tables: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def table(arm) -> SeedTable:
    """The arm's SeedTable of SIZE entries, built on the first call and kept while the arm lives."""
    with _lock:
        found = _tables.get(arm)
        if found is None:
            found = _tables[arm] = SeedTable(arm)
        return found
