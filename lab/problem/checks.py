"""Field checks shared by every frozen settings dataclass (TrainConfig, a method's options).

Each raises ValueError naming the field and what it must be, and stores the value in its
canonical type (an int, a float, a bool), so that numpy scalars and the like never travel on.
A value too large to print or to convert (10**400, a string of a million characters) is refused
by the same one line, the value shown in short (`shown`).
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def shown(v, most: int = 60) -> str:
    """repr(v) for an error message, in short: an integer too long to print (Python refuses
    ints of over 4,300 digits) by its size, any other long repr cut at `most` characters."""
    if isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)):
        v = int(v)
        if v.bit_length() > 190:  # over about 57 digits
            return f"an integer near {'-' if v < 0 else ''}10**{int(v.bit_length() * math.log10(2))}"
    text = repr(v)
    return text if len(text) <= most else text[:most] + "..."


def whole(obj, name: str, least: int, most: int | None = None) -> None:
    """Field `name` of obj is a whole number in [least, most]; stored as an int."""
    v = getattr(obj, name)
    if not isinstance(v, numbers.Integral) or isinstance(v, (bool, np.bool_)) or v < least \
            or (most is not None and v > most):
        bound = f">= {least}" if most is None else f"in {least}..{most:,}"
        raise ValueError(f"{name} must be an integer {bound}, got {shown(v)}")
    object.__setattr__(obj, name, int(v))


def real(obj, name: str, lo: float, hi: float, what: str, closed_below: bool = True,
         closed_above: bool = True) -> None:
    """Field `name` of obj is a finite real number within lo..hi (ends closed as given); stored as a float."""
    v = getattr(obj, name)
    try:  # float(10**400) overflows: out of range, as inf is
        x = float(v) if isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) else None
    except OverflowError:
        x = None
    ok = x is not None and math.isfinite(x) and (x >= lo if closed_below else x > lo) and \
        (x <= hi if closed_above else x < hi)
    if not ok:
        raise ValueError(f"{name} must be {what}, got {shown(v)}")
    object.__setattr__(obj, name, x)


def flag(obj, name: str) -> None:
    """Field `name` of obj is True or False (not 'no', not 1); stored as a bool."""
    v = getattr(obj, name)
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {shown(v)}")
    object.__setattr__(obj, name, bool(v))
