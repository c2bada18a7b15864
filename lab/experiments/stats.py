"""Welch's unequal-variance t-test, written out, as the paper's Tables 4 and 5 use it.

For samples x (n_x) and y (n_y) with means m and sample variances s^2 (ddof=1):

    t  = (m_x - m_y) / sqrt(s_x^2/n_x + s_y^2/n_y)
    df = (s_x^2/n_x + s_y^2/n_y)^2 / ((s_x^2/n_x)^2/(n_x - 1) + (s_y^2/n_y)^2/(n_y - 1))   (Welch-Satterthwaite)

p values from Student's t with df degrees of freedom:
- two-sided: P(|T| >= |t|) = 2 sf(|t|);
- one-sided "less" (H1: mu_x < mu_y): cdf(t); "greater" (H1: mu_x > mu_y): sf(t);
- one-sided in the observed direction: min(less, greater) = two-sided / 2. This is what the
  paper prints as "Significance" (its Table 4: t = -0.9162, df = 29.3269 gives 0.1835 = cdf(t)).

x is CMA-ES and y is NEAT throughout, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats as _st

ALPHA = 0.05


@dataclass(frozen=True)
class WelchTest:
    t: float
    df: float
    p_two: float  # two-sided
    p_less: float  # one-sided, H1: mean x < mean y
    p_greater: float  # one-sided, H1: mean x > mean y
    mean_x: float
    mean_y: float
    n_x: int
    n_y: int

    @property
    def p_one(self) -> float:
        """One-sided p in the direction the means differ (the paper's "Significance")."""
        return min(self.p_less, self.p_greater)

    def decision(self, alpha: float = ALPHA, sided: str = "two", x: str = "CMA-ES", y: str = "NEAT") -> str:
        """'<x> mean lower', '<y> mean lower' or 'no significant difference' at alpha."""
        p = self.p_two if sided == "two" else self.p_one
        if not np.isfinite(p) or p >= alpha:
            return "no significant difference"
        return f"{x} mean lower" if self.t < 0 else f"{y} mean lower"


def welch(x, y) -> WelchTest:
    """Welch's t-test of x against y (1-D samples, at least 2 values each)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    nx, ny = len(x), len(y)
    if nx < 2 or ny < 2:
        raise ValueError(f"Welch's t-test needs at least 2 values per sample, got {nx} and {ny}")
    vx, vy = x.var(ddof=1) / nx, y.var(ddof=1) / ny  # squared standard errors
    se2 = vx + vy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (x.mean() - y.mean()) / np.sqrt(se2)
        df = se2**2 / (vx**2 / (nx - 1) + vy**2 / (ny - 1))
    if not (np.isfinite(t) and np.isfinite(df)):
        nan = float("nan")
        return WelchTest(float(t), float(df), nan, nan, nan, float(x.mean()), float(y.mean()), nx, ny)
    less, greater = float(_st.t.cdf(t, df)), float(_st.t.sf(t, df))
    return WelchTest(float(t), float(df), float(2 * _st.t.sf(abs(t), df)), less, greater,
                     float(x.mean()), float(y.mean()), nx, ny)


def best(values, k: int = 10) -> np.ndarray:
    """The k smallest values (the paper's "best 10 runs"), ascending."""
    return np.sort(np.asarray(values, dtype=np.float64))[:k]
