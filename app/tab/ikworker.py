"""The IK thread: damped least-squares queries for the tabs' first goals, off the marker callbacks.

A tab asks with `IK_WORKER.request(tab)`; the thread calls `tab.solve_ik()` (which reads the
marker's latest position), each tab at most once per IK_PERIOD (longer when more than
IK_RATE x IK_PERIOD tabs drag at once: all of them together are solved at most IK_RATE times a
second), and spends at most IK_DUTY of its time solving, so many tabs dragging at once slow the
ghost arms, not training.
"""

from __future__ import annotations

import threading
import time

IK_DUTY = 0.1  # fraction of the time the IK thread may spend solving, all tabs together (a goal out of reach: ~4 ms)
IK_PERIOD = 0.1  # s: at most one IK query per tab this often (the marker's latest position)
IK_RATE = 100.0  # queries a second, all tabs together (a lecture hall: 20 tabs dragging, each 5 times a second)
ACTIVE = 1.0  # s: a tab that was solved this recently counts as dragging


class IKWorker:
    """One thread solving IK off the marker callbacks, for the tabs that asked, each tab at most
    once per IK_PERIOD; a query reads the marker when it starts, so a drag ends solved."""

    def __init__(self):
        self._cond = threading.Condition()
        self._due: dict = {}  # tab -> time it may run
        self._solved: dict = {}  # id(tab) -> when it was last solved (the tabs dragging now)
        self._thread = None

    def request(self, tab) -> None:
        """Solve for `tab` (an app.tab.goals.TabSession) when its turn comes; one pending query per tab."""
        with self._cond:
            if tab not in self._due:
                now = time.monotonic()
                period = max(IK_PERIOD, len(self._solved) / IK_RATE)
                self._due[tab] = max(now, tab.last_ik + period)
                self._cond.notify()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="app-ik", daemon=True)
                self._thread.start()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._due:
                    self._cond.wait()
                tab, due = min(self._due.items(), key=lambda kv: kv[1])
                if due > time.monotonic():
                    self._cond.wait(due - time.monotonic())
                    continue
                del self._due[tab]
                now = time.monotonic()
                self._solved[id(tab)] = now  # ids, not tabs: a closed tab is not kept alive here
                for t in [t for t, at in self._solved.items() if now - at > ACTIVE]:
                    del self._solved[t]
            t0 = time.perf_counter()
            try:
                tab.solve_ik()
            except Exception:  # a closed tab, a removed node: the next request starts afresh
                pass
            del tab  # not held while this thread waits: a closed tab (its client, its scene) is let go
            # at most IK_DUTY of the time solving: with many tabs dragging, IK waits, training does not
            time.sleep((time.perf_counter() - t0) * (1 - IK_DUTY) / IK_DUTY)


IK_WORKER = IKWorker()
