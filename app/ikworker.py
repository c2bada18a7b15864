"""The IK thread: damped least-squares queries for the tabs' first goals, off the marker callbacks.

A tab asks with `IK_WORKER.request(tab)`; the thread calls `tab.solve_ik()` (which reads the
marker's latest position), each tab at most once per IK_PERIOD, and spends at most IK_DUTY of
its time solving, so many tabs dragging at once slow the ghost arms, not training.
"""

from __future__ import annotations

import threading
import time

IK_DUTY = 0.25  # fraction of the time the IK thread may spend solving, all tabs together
IK_PERIOD = 0.1  # s: at most one IK query per tab this often (the marker's latest position)


class IKWorker:
    """One thread solving IK off the marker callbacks, for the tabs that asked, each tab at most
    once per IK_PERIOD; a query reads the marker when it starts, so a drag ends solved."""

    def __init__(self):
        self._cond = threading.Condition()
        self._due: dict = {}  # tab -> time it may run
        self._thread = None

    def request(self, tab) -> None:
        """Solve for `tab` (an app.goals.TabSession) when its turn comes; one pending query per tab."""
        with self._cond:
            if tab not in self._due:
                self._due[tab] = max(time.monotonic(), tab.last_ik + IK_PERIOD)
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
            t0 = time.perf_counter()
            try:
                tab.solve_ik()
            except Exception:  # a closed tab, a removed node: the next request starts afresh
                pass
            # at most IK_DUTY of the time solving: with many tabs dragging, IK waits, training does not
            time.sleep((time.perf_counter() - t0) * (1 - IK_DUTY) / IK_DUTY)


IK_WORKER = IKWorker()
