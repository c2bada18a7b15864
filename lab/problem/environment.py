"""The lab's environment variables, each read and checked here, in the lab's lowest layer.

    LAB_THREADS=n                  threads a generation's fitness is split over: an integer >= 1
    LAB_METHODS=module,module      modules that register methods: importable module names, by commas
    LAB_RECORDING_RESERVE=bytes    free space under which a recording stops: an integer >= 0

Unset or empty: the default. A value that is not accepted raises SettingError (a ValueError) whose
one line names the variable, the value and what is accepted; `python -m lab` and `python -m app`
print it as `error: ...` and exit with 2, before any work (check_all).
"""

from __future__ import annotations

import os

THREADS = "LAB_THREADS"
METHODS = "LAB_METHODS"
RECORDING_RESERVE = "LAB_RECORDING_RESERVE"
VARIABLES = (THREADS, METHODS, RECORDING_RESERVE)


class SettingError(ValueError):
    """An environment variable of the lab holds a value it does not accept (the message says which and why)."""


def _raw(name: str) -> str | None:
    raw = os.environ.get(name)
    return None if raw is None or not raw.strip() else raw


def _integer(name: str, minimum: int, what: str) -> int | None:
    raw = _raw(name)
    if raw is None:
        return None
    try:
        n = int(raw)
    except ValueError:
        n = None
    if n is None or n < minimum:
        raise SettingError(f"{name} must be an integer >= {minimum}, got {raw!r} ({what})")
    return n


def threads() -> int | None:
    """LAB_THREADS: the fitness threads of this process, or None when unset."""
    return _integer(THREADS, 1, "the threads a generation's fitness is split over; unset: the cores, at most 4")


def recording_reserve() -> int | None:
    """LAB_RECORDING_RESERVE: bytes a recording leaves free on its filesystem, or None when unset."""
    return _integer(RECORDING_RESERVE, 0, "bytes a recording leaves free on its disk; "
                                          "unset: 2 % of the filesystem, at most 256 MiB")


def method_modules() -> tuple[str, ...]:
    """LAB_METHODS: the names of the modules that register methods (not imported here)."""
    raw = _raw(METHODS)
    if raw is None:
        return ()
    modules = tuple(s.strip() for s in raw.split(",") if s.strip())
    for m in modules:
        if not all(part.isidentifier() for part in m.split(".")):
            raise SettingError(f"{METHODS} must be module names separated by commas, got {raw!r} "
                               f"({m!r} is not a module name)")
    return modules


def cannot_import(raw_module: str, error: BaseException) -> SettingError:
    """The SettingError of a LAB_METHODS module that failed to import (lab.methods.registry raises it)."""
    return SettingError(f"{METHODS} must be names of importable modules that register methods, got "
                        f"{os.environ.get(METHODS)!r} (importing {raw_module!r}: {type(error).__name__}: {error})")


def check_all() -> None:
    """Read every variable: SettingError for the first one not accepted (the LAB_METHODS modules
    are imported by lab.methods when its registry is first asked)."""
    threads()
    method_modules()
    recording_reserve()
