"""Field checks shared by every frozen settings dataclass (TrainConfig, a method's options).

Each raises ValueError naming the field and what it must be, and stores the value in its
canonical type (an int, a float, a bool), so that numpy scalars and the like never travel on.
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def whole(obj, name: str, least: int, most: int | None = None) -> None:
    """Field `name` of obj is a whole number in [least, most]; stored as an int."""
    v = getattr(obj, name)
    if not isinstance(v, numbers.Integral) or isinstance(v, (bool, np.bool_)) or v < least \
            or (most is not None and v > most):
        bound = f">= {least}" if most is None else f"in {least}..{most:,}"
        raise ValueError(f"{name} must be an integer {bound}, got {v!r}")
    object.__setattr__(obj, name, int(v))


def real(obj, name: str, lo: float, hi: float, what: str, closed_below: bool = True,
         closed_above: bool = True) -> None:
    """Field `name` of obj is a finite real number within lo..hi (ends closed as given); stored as a float."""
    v = getattr(obj, name)
    ok = isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v) and \
        (v >= lo if closed_below else v > lo) and (v <= hi if closed_above else v < hi)
    if not ok:
        raise ValueError(f"{name} must be {what}, got {v!r}")
    object.__setattr__(obj, name, float(v))


def flag(obj, name: str) -> None:
    """Field `name` of obj is True or False (not 'no', not 1); stored as a bool."""
    v = getattr(obj, name)
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {v!r}")
    object.__setattr__(obj, name, bool(v))
