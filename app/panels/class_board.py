"""The class board: the "Class" tab of every tab's panel (server.gui), every student run of the session, live.

One row per run (app/classroom/class_runs.py), newest first: the student's name, the settings, its
state (a queued run's place), the generation, the best training MSE, the held-out MSE once it has
ended, and a small curve of its best MSE (log scale). Everything a student typed is escaped
(html.escape) before it is drawn: a name cannot put markup into another tab. The presenter can stop
any run (a shared control: a viewer's click is dropped by the access gate, app/classroom/access.py).
The render loop calls `refresh`; the table is redrawn only when a run has changed.
"""

from __future__ import annotations

import html
import math

import numpy as np

from app.classroom.class_runs import ClassRuns, describe
from app.training.live import decimate

NONE = "(no run going)"
ROWS = 60  # rows drawn at most (the newest); the notebook keeps every run


def spark(best: np.ndarray, width: int = 90, height: int = 22) -> str:
    """A small SVG polyline of a best-MSE curve on a log scale (empty below 2 points)."""
    values = np.asarray(best, float)
    values = values[np.isfinite(values) & (values > 0)]
    if len(values) < 2:
        return ""
    values = np.log10(values[decimate(len(values), 60)])
    lo, hi = float(values.min()), float(values.max())
    span = hi - lo if hi > lo else 1.0
    x = np.linspace(1, width - 1, len(values))
    y = 1 + (height - 2) * (hi - values) / span
    pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(x, y))
    return (f'<svg width="{width}" height="{height}" xmlns="http://www.w3.org/2000/svg">'
            f'<polyline points="{pts}" fill="none" stroke="#d62728" stroke-width="1.5"/></svg>')


def fmt(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.3g}"


def board_html(runs: ClassRuns) -> str:
    rows = runs.rows()
    if not rows:
        return ("<small>No student run yet. A student's tab (a viewer's) has the folder <b>My experiment</b>: "
                "its runs appear here as they queue, train and end.</small>")
    going = sum(not r.ended for r in rows)
    head = (f"<small>{len(rows)} run{'s' * (len(rows) != 1)} since the server started, {going} queued or running, "
            f"{runs.workers} at once.</small>")
    cells = []
    for r in list(reversed(rows))[:ROWS]:
        _gens, best, _median = r.track.curves()
        cells.append(
            "<tr>" + "".join(f"<td>{c}</td>" for c in (
                f"<b>{html.escape(r.name)}</b>", html.escape(describe(r.config)), html.escape(r.status()),
                str(r.generation), fmt(r.best()), fmt(r.held_out()), spark(best))) + "</tr>")
    return (head + '<table style="font-size:11px;border-collapse:collapse">'
            "<tr><th>name</th><th>settings</th><th>state</th><th>gen.</th><th>best train MSE</th>"
            "<th>held-out MSE</th><th>curve</th></tr>" + "".join(cells) + "</table>")


class ClassBoard:
    def __init__(self, gui, runs: ClassRuns):
        """gui: server.gui (inside the Class tab)."""
        self.runs = runs
        self.table = gui.add_html(board_html(runs))
        with gui.add_folder("Presenter: stop a run", expand_by_default=False):
            self.choice = gui.add_dropdown("Run", (NONE,), initial_value=NONE)
            self.stop_button = gui.add_button("Stop this run")
            self.message = gui.add_markdown("")
        self.stop_button.on_click(lambda e: self.stop_chosen())
        self._drawn = None
        self._ids: dict[str, str] = {}  # dropdown label -> run id

    def refresh(self) -> None:
        rows = self.runs.rows()
        key = (self.runs.version, tuple((r.id, r.generation, r.state, r.name) for r in rows))
        if key == self._drawn:
            return
        self._drawn = key
        self.table.content = board_html(self.runs)
        going = [r for r in rows if not r.ended]
        self._ids = {f"{r.name} [{r.id[:6]}]": r.id for r in going}
        options = tuple(self._ids) or (NONE,)
        if tuple(self.choice.options) != options:
            value = self.choice.value if self.choice.value in options else options[0]
            self.choice.options = options
            self.choice.value = value

    def stop_chosen(self) -> str | None:
        run_id = self._ids.get(self.choice.value)
        why = "refused: no run chosen" if run_id is None else self.runs.stop(run_id, "stopped by the presenter")
        self.message.content = why or "Stopped."
        return why
