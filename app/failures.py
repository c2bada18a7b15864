"""Failures of a task that repeats (the render loop, 30 passes a second), logged without filling the log.

    failures = FailureLog(log)
    try:
        session.refresh()
    except Exception:
        failures.failed(("tab", 3), "tab 3's redraw")   # the first: its traceback; then a count a minute

A key's first failure is logged with its traceback; the later ones are counted, and one line (no
traceback) says how many there were, at most once every `period` seconds. Before this, one tab's
bad goal made the render loop log a 30-line traceback 30 times a second (issue #55).
"""

from __future__ import annotations

import logging
import threading
import time


class FailureLog:
    def __init__(self, logger: logging.Logger, period: float = 60.0, keys: int = 10_000):
        """period: seconds between two lines for one key after its first; keys: at most this many keys
        are remembered (the quiet ones are forgotten first: tabs come and go)."""
        self.log, self.period, self.keys = logger, period, keys
        self._seen: dict = {}  # key -> [time of the last line, failures since]
        self._lock = threading.Lock()

    def failed(self, key, what: str) -> bool:
        """Call in an `except` block: logs the exception being handled (the first for `key`: with its
        traceback; later: a count at most every `period` s). True for key's first failure."""
        now = time.monotonic()
        with self._lock:
            entry = self._seen.get(key)
            if entry is None:
                if len(self._seen) >= self.keys:
                    quiet = sorted(self._seen, key=lambda k: self._seen[k][0])[: len(self._seen) // 2]
                    for k in quiet:
                        del self._seen[k]
                self._seen[key] = [now, 0]
            else:
                entry[1] += 1
                if now - entry[0] < self.period:
                    return False
                count, entry[0], entry[1] = entry[1], now, 0
        if entry is None:
            self.log.exception("%s failed (logged once; later failures are counted)", what)
            return True
        import sys

        error = sys.exc_info()[1]
        self.log.error("%s failed %d more times in the last %.0f s (the last: %s: %.120s)", what, count,
                       self.period, type(error).__name__, error)
        return False

    def forget(self, key) -> None:
        with self._lock:
            self._seen.pop(key, None)
