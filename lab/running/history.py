"""A run's best and median MSE per generation, in memory that is bounded when asked.

    h = History()             # every generation (lab.evolve, experiments: run.history per generation)
    h = History(limit=4096)   # at most 4096 points: the app, whose runs may last 10^9 generations
    h.append(best, median); len(h)  # generations appended
    gens, best, median = h.arrays()  # the kept points (0-based generation, values), the latest always

Bounded: every generation until the limit, then the stride doubles each time the buffer fills (every
2nd, then every 4th, ... generation is kept), so the kept points stay spread over the whole run and
memory stays at 3 arrays of `limit` numbers whatever the run's length.
"""

from __future__ import annotations

import numpy as np


class History:
    def __init__(self, limit: int | None = None):
        if limit is not None and limit < 2:
            raise ValueError(f"a history limit must be at least 2, got {limit}")
        self.limit = limit
        self.n = 0  # generations appended
        self.stride = 1
        if limit is None:
            self._best: list[float] = []
            self._median: list[float] = []
        else:
            self._gen = np.empty(limit, np.int64)
            self._vals = np.empty((limit, 2))
            self._k = 0  # points kept
            self._latest = (0, np.nan, np.nan)

    def __len__(self) -> int:
        return self.n

    def append(self, best: float, median: float) -> None:
        g, self.n = self.n, self.n + 1
        if self.limit is None:
            self._best.append(best)
            self._median.append(median)
            return
        self._latest = (g, best, median)
        if g % self.stride:
            return
        if self._k == self.limit:  # full: keep every other point, and from now on every 2 * stride-th
            keep = self._gen[: self._k] % (2 * self.stride) == 0
            k = int(keep.sum())
            self._gen[:k], self._vals[:k] = self._gen[: self._k][keep], self._vals[: self._k][keep]
            self._k, self.stride = k, 2 * self.stride
            if g % self.stride:
                return
        self._gen[self._k], self._vals[self._k] = g, (best, median)
        self._k += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(generations, best, median) of the kept points, oldest first; the latest generation always."""
        if self.limit is None:
            return np.arange(self.n), np.array(self._best, float), np.array(self._median, float)
        gens, vals = self._gen[: self._k].copy(), self._vals[: self._k].copy()
        if self.n and (not self._k or gens[-1] != self._latest[0]):
            gens = np.append(gens, self._latest[0])
            vals = np.vstack([vals, [self._latest[1:]]])
        return gens, vals[:, 0], vals[:, 1]

    def last(self) -> float:
        """The latest best MSE (nan before the first generation)."""
        if not self.n:
            return float("nan")
        return self._best[-1] if self.limit is None else float(self._latest[1])


class Thinned:
    """Any values per generation (a method's live statistics: numbers, or {species: size}), kept by
    History's rule: every generation until `limit` values are held, then every 2nd, 4th, ... one.

        t = Thinned(4096); t.append(value); gens, values = t.items()   # the latest always included
    """

    def __init__(self, limit: int):
        if limit < 2:
            raise ValueError(f"a thinned series' limit must be at least 2, got {limit}")
        self.limit, self.n, self.stride = limit, 0, 1
        self._gens: list[int] = []
        self._values: list = []
        self._latest = None

    def __len__(self) -> int:
        return self.n

    def append(self, value) -> None:
        g, self.n = self.n, self.n + 1
        self._latest = (g, value)
        if g % self.stride:
            return
        if len(self._gens) == self.limit:
            keep = [i for i, k in enumerate(self._gens) if k % (2 * self.stride) == 0]
            self._gens = [self._gens[i] for i in keep]
            self._values = [self._values[i] for i in keep]
            self.stride *= 2
            if g % self.stride:
                return
        self._gens.append(g)
        self._values.append(value)

    def items(self) -> tuple[list[int], list]:
        """(0-based generations, values) of the kept points, oldest first; the latest always."""
        gens, values = list(self._gens), list(self._values)
        if self.n and (not gens or gens[-1] != self._latest[0]):
            gens.append(self._latest[0])
            values.append(self._latest[1])
        return gens, values
