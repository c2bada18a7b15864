"""The class board: the "Class" tab of every tab's panel (server.gui), every student run of the session, live.

One row per run (app/classroom/class_runs.py), newest first: the student's name, the settings, its
state (a queued run's place), the generation, the best training MSE, the held-out MSE once it has
ended, and a small curve of its best MSE (log scale). Everything a student typed is escaped
(html.escape) before it is drawn: a name cannot put markup into another tab. The presenter can stop
any run (a shared control: a viewer's click is dropped by the access gate, app/classroom/access.py).
The presenter can also show any run in the shared scene, for the whole class: an ended run with a
recording is opened as the Runs tab opens one (`replay`: its generation slider scrubs the run's
generations, its population at each), any other run's best network is shown as a replayed controller
(`show`); the Runs tab's "Back to live" returns to the class's run. And a **class chart** plots the finished runs' held-out MSE (log scale) against a setting
the presenter picks (hidden units, population, goals, seed, method): the sweep the class has made.
The render loop calls `refresh`; the table and chart are redrawn only when a run has changed.
"""

from __future__ import annotations

import html
import math
import os

import numpy as np

import lab

from app.classroom.class_runs import ClassRuns, describe
from app.training.live import decimate

NONE = "(no run going)"
NOTHING = "(no run with a network yet)"
# the class chart's settings: label -> the run's value of it
AXES = {"hidden units": lambda c: c.hidden, "population": lambda c: c.population, "goals": lambda c: c.targets,
        "seed": lambda c: c.seed, "method": lambda c: lab.methods.get(c.method).label}
ROWS = 60  # rows drawn at most (the newest); the notebook keeps every run


def spark(best: np.ndarray, width: int = 56, height: int = 20) -> str:
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
    return (head + '<table style="font-size:11px;border-collapse:collapse;width:100%;table-layout:auto">'
            "<tr><th>name</th><th>settings</th><th>state</th><th>gen.</th><th>best train MSE</th>"
            "<th>held-out MSE</th><th>curve</th></tr>" + "".join(cells) + "</table>")


def chart_svg(runs: list, axis: str, width: int = 320, height: int = 180) -> str:
    """SVG: each finished run's held-out MSE (log scale) against the setting `axis` (AXES), a point per
    run, its name as the point's tooltip (escaped), and on a numeric setting the class's curve (a line
    through the median held-out MSE at each value); a numeric setting on a linear axis (a log one over a wide
    range of positive values), a method one column each."""
    points = [(AXES[axis](r.config), r.held_out(), r.name) for r in runs if r.state == "finished"]
    points = [(x, y, n) for x, y, n in points if y is not None and math.isfinite(y) and y > 0]
    if not points:
        return f"<small>Class chart: no finished run yet (held-out MSE against {html.escape(axis)}).</small>"
    xs = sorted({x for x, _y, _n in points}, key=lambda v: (isinstance(v, str), v))
    numeric = all(isinstance(x, (int, float)) for x in xs)
    pad_l, pad_b, pad_t, pad_r = 40, 30, 8, 10
    w, h = width - pad_l - pad_r, height - pad_t - pad_b
    if numeric:
        # values over a wide range of positive numbers (hidden units 2 to 64) on a log axis, else linear
        scale = np.log if min(xs) > 0 and max(xs) >= 8 * min(xs) else float
        lo, hi = scale(min(xs)), scale(max(xs))
        span = hi - lo if hi > lo else 1.0
        place = lambda x: pad_l + w * ((scale(x) - lo) / span if hi > lo else 0.5)  # noqa: E731
    else:
        place = lambda x: pad_l + w * (xs.index(x) + 0.5) / len(xs)  # noqa: E731
    logs = np.log10([y for _x, y, _n in points])
    ylo, yhi = float(logs.min()), float(logs.max())
    yspan = yhi - ylo if yhi > ylo else 1.0
    ypos = lambda v: pad_t + h * ((yhi - v) / yspan if yhi > ylo else 0.5)  # noqa: E731
    dots = "".join(
        f'<circle cx="{place(x):.1f}" cy="{ypos(np.log10(y)):.1f}" r="3.5" fill="#d62728" fill-opacity="0.7">'
        f'<title>{html.escape(n)}: {html.escape(str(x))}, held-out MSE {y:.3g}</title></circle>' for x, y, n in points)
    curve = ""
    if numeric and len(xs) > 1:  # the class's curve: the median held-out MSE (in log) at each value
        medians = [(x, float(np.median([np.log10(y) for px, y, _n in points if px == x]))) for x in xs]
        line = " ".join(f"{place(x):.1f},{ypos(m):.1f}" for x, m in medians)
        curve = (f'<polyline points="{line}" fill="none" stroke="#1f77b4" stroke-width="2">'
                 f'<title>the class\'s median held-out MSE at each {html.escape(axis)}</title></polyline>')
    ticks = xs if len(xs) <= 10 else [xs[0], xs[len(xs) // 2], xs[-1]]
    xlabels = "".join(f'<text x="{place(x):.1f}" y="{height - 16}" font-size="9" text-anchor="middle">'
                      f'{html.escape(str(x))}</text>' for x in ticks)
    axes = (f'<line x1="{pad_l}" y1="{pad_t + h}" x2="{pad_l + w}" y2="{pad_t + h}" stroke="#888"/>'
            f'<line x1="{pad_l}" y1="{pad_t}" x2="{pad_l}" y2="{pad_t + h}" stroke="#888"/>'
            f'<text x="{pad_l - 3}" y="{pad_t + 8}" font-size="9" text-anchor="end">{10 ** yhi:.2g}</text>'
            f'<text x="{pad_l - 3}" y="{pad_t + h}" font-size="9" text-anchor="end">{10 ** ylo:.2g}</text>'
            f'<text x="{pad_l + w / 2:.0f}" y="{height - 3}" font-size="10" text-anchor="middle">'
            f'{html.escape(axis)}</text>')
    return (f"<div><small><b>Class chart</b>: held-out MSE (log scale) of {len(points)} finished run"
            f"{'s' * (len(points) != 1)} against {html.escape(axis)}"
            f"{'; the line: the class median at each value' if curve else ''}</small>"
            f'<svg width="{width}" height="{height}" xmlns="http://www.w3.org/2000/svg">{axes}{xlabels}{curve}{dots}</svg></div>')


class ClassBoard:
    def __init__(self, gui, runs: ClassRuns, show=None, replay=None):
        """gui: server.gui (inside the Class tab); show(robot, controller, source, client) -> None or why
        not: shows a network in the shared scene (app.panels.runs.RunsPanel._show); replay(path, client,
        entry) -> None or why not: opens a recording in the Runs tab (app.panels.runs.RunsPanel.open_file)."""
        self.runs, self.show, self.replay = runs, show, replay
        self.table = gui.add_html(board_html(runs))
        self.axis = gui.add_dropdown("Chart against", tuple(AXES), initial_value="hidden units",
                                     hint="the class chart's horizontal axis: a setting of the runs")
        self.chart = gui.add_html(chart_svg([], "hidden units"))
        with gui.add_folder("Presenter: show a run to the class", expand_by_default=False):
            self.show_choice = gui.add_dropdown("Run to show", (NOTHING,), initial_value=NOTHING)
            self.show_button = gui.add_button("Show in the shared scene",
                                              hint="every tab's arms show this run: an ended run's recording opens in "
                                                   "the Runs tab (its slider scrubs the generations), a running run's "
                                                   "best network shows (Back to live returns to the class's run)")
            self.show_message = gui.add_markdown("")
        with gui.add_folder("Presenter: stop a run", expand_by_default=False):
            self.choice = gui.add_dropdown("Run", (NONE,), initial_value=NONE)
            self.stop_button = gui.add_button("Stop this run")
            self.message = gui.add_markdown("")
        self.stop_button.on_click(lambda e: self.stop_chosen())
        self.show_button.on_click(lambda e: self.show_chosen(e.client))
        self.axis.on_update(lambda e: self._draw_chart())
        self._drawn = None
        self._ids: dict[str, str] = {}  # dropdown label -> run id
        self._shows: dict[str, str] = {}  # "Run to show" label -> run id

    def refresh(self) -> None:
        rows = self.runs.rows()
        key = (self.runs.version, tuple((r.id, r.generation, r.state, r.name) for r in rows))
        if key == self._drawn:
            return
        self._drawn = key
        self.table.content = board_html(self.runs)
        going = [r for r in rows if not r.ended]
        self._ids = {f"{r.name} [{r.id[:6]}]": r.id for r in going}
        self._set_options(self.choice, tuple(self._ids) or (NONE,))
        self._shows = {f"{r.name} [{r.id[:6]}]": r.id for r in reversed(rows) if r.controller is not None}
        self._set_options(self.show_choice, tuple(self._shows) or (NOTHING,))
        self._draw_chart()

    @staticmethod
    def _set_options(dropdown, options: tuple) -> None:
        if tuple(dropdown.options) != options:
            value = dropdown.value if dropdown.value in options else options[0]
            dropdown.options = options
            dropdown.value = value

    def _draw_chart(self) -> None:
        axis = self.axis.value if self.axis.value in AXES else "hidden units"
        content = chart_svg(self.runs.rows(), axis)
        if self.chart.content != content:
            self.chart.content = content

    def show_chosen(self, client=None) -> str | None:
        """Show the chosen run to the class: an ended run's recording opened in the Runs tab (its
        generations to scrub), else its best network (refused, saying why, as the Runs panel's replay
        is: another arm while the shared run goes on it)."""
        run = self.runs.runs.get(self._shows.get(self.show_choice.value, ""))
        recorded = run is not None and run.ended and run.recording and os.path.isfile(run.recording)
        if run is None or run.controller is None or self.show is None:
            why = "refused: no run with a network chosen"
        elif recorded and self.replay is not None:
            entry = self.runs.notebook.get(run.id)
            why = self.replay(run.recording, client, entry)
        else:
            why = self.show(run.config.robot, run.controller,
                            f"{run.name}'s run, generation {run.generation}", client)
        how = " (its recording: the Runs tab's slider scrubs its generations)" if recorded and not why else ""
        self.show_message.content = html.escape(why) if why else f"The class sees {html.escape(run.name)}'s run{how}."
        return why

    def stop_chosen(self) -> str | None:
        run_id = self._ids.get(self.choice.value)
        why = "refused: no run chosen" if run_id is None else self.runs.stop(run_id, "stopped by the presenter")
        self.message.content = why or "Stopped."
        return why
