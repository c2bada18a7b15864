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
The chart (app/panels/class_chart.py) compares only runs that differ in the setting it plots (the
largest group of runs with every other setting equal, seeds as repeats) and says how many it left out.
The render loop calls `refresh`; the table and chart are redrawn only when a run has changed.

The presenter's **board** controls (shared controls: a viewer's click is dropped by the gate): **New
board** starts a fresh board for a lesson (ClassRuns.new_board: the earlier runs leave the table and
the chart, a run still going stays listed until it ends; the notebook keeps every run), **Show the
chart large** opens the chart in the presenter's own tab, in a column of its own at the left (large
type, a grid, each point's student on hover: what a projector shows the room at 1366 x 768), and
**Download the class's runs** sends the session's runs as a CSV file to the presenter's tab
(app/classroom/gradebook.py: name, lesson, board, every setting, state, generations, training and
held-out MSE, seconds, recording). The table groups the runs of each lesson link under its name.

On a phone (app/tab/phone.py is_phone: a canvas as narrow as viser's bottom sheet, held upright) the
seven columns wrap each cell onto several lines and cut the curve off: each phone tab gets, in its own
Class tab, the table of the columns that fit (name, state, held-out MSE: `board_html(runs,
narrow=True)`), with a style that hides the shared wide table in that tab only. A tab turned wide
again loses it (the wide table shows again); a closed tab's entry goes (`forget`).
"""

from __future__ import annotations

import html
import math
import os
import threading
import time

import numpy as np

from app.classroom.class_runs import ClassRuns, describe
from app.classroom.gradebook import class_csv
from app.panels.class_chart import AXES, chart_svg
from app.tab.phone import is_phone
from app.training.live import decimate

NONE = "(no run going)"
NOTHING = "(no run with a network yet)"
BIG_WIDTH, BIG_HEIGHT = 940, 720  # px: the large chart's window in the presenter's tab (1366 x 768: the lab's panel beside it)
ROWS = 60  # rows drawn at most (the newest); the notebook keeps every run
WIDE = "lab-board-wide"  # the class of the shared table's block, hidden in a phone's tab
HIDE_WIDE = f"<style>.{WIDE}{{display:none}}</style>"  # in a phone tab's own table: the wide one goes


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


WIDE_COLUMNS = ("name", "settings", "state", "gen.", "best train MSE", "held-out MSE", "curve")
NARROW_COLUMNS = ("name", "state", "held-out MSE")  # what a phone's width holds


def _row(r, narrow: bool = False) -> str:
    name, state, held = f"<b>{html.escape(r.name)}</b>", html.escape(r.status()), fmt(r.held_out())
    if narrow:
        cells = (name, state, held)
    else:
        _gens, best, _median = r.track.curves()
        cells = (name, html.escape(describe(r.config)), state, str(r.generation), fmt(r.best()), held, spark(best))
    return "<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def lost_html(runs: ClassRuns) -> str:
    """A line in red when the students' runs cannot go where they go (a Ray cluster lost), else ""."""
    lost = runs.unavailable()
    return ("" if lost is None else f'<div style="color:#c00"><b>{html.escape(lost[0].upper() + lost[1:])}.</b> '
            "New runs are refused until it answers again; runs waiting for it have failed.</div>")


def board_html(runs: ClassRuns, narrow: bool = False) -> str:
    """The current board's runs (ClassRuns.board_rows), newest first, those of each lesson link under
    its name (the lesson of the newest run first), then the runs started without one; a lost Ray
    cluster's line (lost_html) first. narrow: a phone's, its columns NARROW_COLUMNS, with the style
    that hides the wide table (in the block of class WIDE) in the tab it is drawn in."""
    if narrow:
        return f'{HIDE_WIDE}<div class="lab-board-narrow">{lost_html(runs)}{_board_html(runs, NARROW_COLUMNS)}</div>'
    return f'<div class="{WIDE}">{lost_html(runs)}{_board_html(runs, WIDE_COLUMNS)}</div>'


def _board_html(runs: ClassRuns, columns: tuple) -> str:
    rows = runs.board_rows()
    earlier = len(runs.rows()) - len([r for r in rows if r.board == runs.boards])
    note = (f" Board {runs.boards}: {earlier} earlier run{'s' * (earlier != 1)} left the board (the notebook "
            f"keeps them; Download has them all)." if runs.boards > 1 else "")
    if not rows:
        return ("<small>No student run yet. A student's tab (a viewer's) has the folder <b>My experiment</b>: "
                f"its runs appear here as they queue, train and end.{note}</small>")
    going = sum(not r.ended for r in rows)
    head = (f"<small>{len(rows)} run{'s' * (len(rows) != 1)} on this board, {going} queued or running, "
            f"{runs.workers} at once.{note}</small>")
    newest = list(reversed(rows))[:ROWS]
    groups: dict = {}
    for r in newest:
        groups.setdefault(r.lesson or "", []).append(r)
    cells = []
    for lesson, group in sorted(groups.items(), key=lambda kv: kv[0] == ""):
        if len(groups) > 1 or lesson:
            title = (f"Lesson {html.escape(lesson if lesson != '1' else 'link (shared settings)')}" if lesson
                     else "Runs started without a lesson link")
            cells.append(f'<tr><td colspan="{len(columns)}" style="background:#eef;font-weight:bold">{title}: '
                         f"{len(group)} run{'s' * (len(group) != 1)}</td></tr>")
        cells.extend(_row(r, narrow=columns == NARROW_COLUMNS) for r in group)
    size = 13 if columns == NARROW_COLUMNS else 11  # a phone's: fewer columns, larger type
    return (head + f'<table style="font-size:{size}px;border-collapse:collapse;width:100%;table-layout:auto">'
            "<tr>" + "".join(f"<th>{c}</th>" for c in columns) + "</tr>" + "".join(cells) + "</table>")


class ClassBoard:
    def __init__(self, gui, runs: ClassRuns, show=None, replay=None, tab=None):
        """gui: server.gui (inside the Class tab); show(robot, controller, source, client) -> None or why
        not: shows a network in the shared scene (app.panels.runs.RunsPanel._show); replay(path, client,
        entry) -> None or why not: opens a recording in the Runs tab (app.panels.runs.RunsPanel.open_file);
        tab: the Class tab's handle (a phone tab's own narrow table goes in it; None: no narrow table)."""
        self.runs, self.show, self.replay, self.tab = runs, show, replay, tab
        self._phones: dict[int, object] = {}  # a phone tab's id -> its own narrow table (follow_phone)
        self._phones_lock = threading.Lock()
        self.table = gui.add_html(board_html(runs))
        self.axis = gui.add_dropdown("Chart against", tuple(AXES), initial_value="hidden units",
                                     hint="the class chart's horizontal axis: a setting of the runs")
        self.chart = gui.add_html(chart_svg([], "hidden units"))
        with gui.add_folder("Presenter: board, chart, grade book"):
            self.new_button = gui.add_button("New board", hint="a fresh board for a lesson: the runs so far leave the "
                                                                "table and the chart (the notebook keeps them)")
            self.big_button = gui.add_button("Show the chart large", hint="the chart in your own tab, large, for the "
                                                                          "projector (a point's student on hover)")
            self.csv_button = gui.add_button("Download the class's runs (CSV)",
                                             hint="every run since the server started, a row each: name, lesson, board, every "
                                                  "setting, state, generations, errors, seconds, recording")
            self.board_message = gui.add_markdown("")
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
        self.new_button.on_click(lambda e: self.new_board())
        self.big_button.on_click(lambda e: self.show_big(e.client))
        self.csv_button.on_click(lambda e: self.download(e.client))
        self._big: dict[int, tuple] = {}  # a presenter tab's id -> (its large chart's column, its html, its lab panel)
        self._drawn = None
        self._ids: dict[str, str] = {}  # dropdown label -> run id
        self._shows: dict[str, str] = {}  # "Run to show" label -> run id

    def refresh(self) -> None:
        rows = self.runs.rows()
        key = (self.runs.version, self.runs.unavailable(), tuple((r.id, r.generation, r.state, r.name) for r in rows))
        if key == self._drawn:
            return
        self._drawn = key
        self.table.content = board_html(self.runs)
        self._draw_phones()
        going = [r for r in rows if not r.ended]
        self._ids = {f"{r.name} [{r.id[:6]}]": r.id for r in going}
        self._set_options(self.choice, tuple(self._ids) or (NONE,))
        self._shows = {f"{r.name} [{r.id[:6]}]": r.id for r in reversed(rows) if r.controller is not None}
        self._set_options(self.show_choice, tuple(self._shows) or (NOTHING,))
        self._draw_chart()

    # ------------------------------------------------------------------ a phone's narrow table
    def follow_phone(self, client) -> None:
        """Give `client`'s tab the narrow table while its canvas is a phone's (is_phone), each time its
        camera reports its size: added when it becomes one, removed when it turns wide."""

        def on_camera(camera) -> None:
            try:
                phone = is_phone(camera)
            except (AssertionError, ZeroDivisionError):  # no size reported yet
                return
            self._set_phone(client, phone)

        client.camera.on_update(on_camera)
        on_camera(client.camera)  # viser calls a tab connected once its first camera message came

    def _set_phone(self, client, phone: bool) -> None:
        cid = client.client_id
        with self._phones_lock:  # one tab context at a time (a tab handle has one restore slot)
            if phone == (cid in self._phones) or self.tab is None:
                return
            if phone:
                with self.tab:  # the tab's own element, in the shared Class tab, beside the wide table
                    self._phones[cid] = client.gui.add_html(board_html(self.runs, narrow=True),
                                                            order=self.table.order + 0.5)
            else:
                self._remove(self._phones.pop(cid))

    @staticmethod
    def _remove(handle) -> None:
        try:
            handle.remove()
        except Exception:  # noqa: BLE001 - that tab has gone
            pass

    def _draw_phones(self) -> None:
        with self._phones_lock:
            if not self._phones:
                return
            content = board_html(self.runs, narrow=True)
            for cid, handle in list(self._phones.items()):
                try:
                    if handle.content != content:
                        handle.content = content
                except Exception:  # noqa: BLE001 - that tab has gone
                    self._phones.pop(cid, None)

    def forget(self, client_id: int) -> None:
        """A closed tab: its narrow table and large chart entries go (viser drops their elements)."""
        with self._phones_lock:
            self._phones.pop(client_id, None)
        self._big.pop(client_id, None)

    @staticmethod
    def _set_options(dropdown, options: tuple) -> None:
        if tuple(dropdown.options) != options:
            value = dropdown.value if dropdown.value in options else options[0]
            dropdown.options = options
            dropdown.value = value

    def _draw_chart(self) -> None:
        axis = self.axis.value if self.axis.value in AXES else "hidden units"
        rows = self.runs.board_rows(going=False)
        content = chart_svg(rows, axis)
        if self.chart.content != content:
            self.chart.content = content
        big = chart_svg(rows, axis, big=True)
        for cid, (_column, shown, _main) in list(self._big.items()):
            try:
                if shown.content != big:
                    shown.content = big
            except Exception:  # noqa: BLE001 - that tab has gone
                self._big.pop(cid, None)

    # ------------------------------------------------------------------ the presenter's board controls
    def new_board(self) -> str:
        """A fresh board: the runs so far leave the table and chart (the notebook keeps every one)."""
        n = self.runs.new_board()
        text = (f"Board {n} since {time.strftime('%H:%M')}: the earlier runs left the table and the chart "
                f"(the notebook and Download keep them).")
        self.board_message.content = text
        self.refresh()
        return text

    def show_big(self, client) -> str | None:
        """The chart, large, in a column at the left of `client`'s own tab (a presenter's: the board's
        buttons are shared controls), redrawn with the board; its button closes it."""
        if client is None:
            return "refused: no tab to show the chart in"
        if client.client_id in self._phones:  # a phone's bottom sheet folds a panel into a closed section
            why = ("refused: the large chart is for a wide screen (the projector's tab); on a phone the "
                   "board's chart above is the whole chart")
            self.board_message.content = why
            return why
        self.close_big(client.client_id)
        gui = client.gui
        axis = self.axis.value if self.axis.value in AXES else "hidden units"
        column = gui.add_panel()
        with column.add_tab("Class chart"):
            close = gui.add_button("Close the chart")
            shown = gui.add_html(chart_svg(self.runs.board_rows(going=False), axis, big=True))
        column.float(x=8, y=8, width=BIG_WIDTH, height=BIG_HEIGHT)  # over the scene, beside a lesson's column
        # the lab's panel folded to its rail while the chart is shown: docked right beside a lesson's
        # column, it leaves the scene too narrow for the chart, which then lay over the panel
        gui.main_panel.minimize()
        close.on_click(lambda _e, cid=client.client_id: self.close_big(cid))
        self._big[client.client_id] = (column, shown, gui.main_panel)
        return None

    def close_big(self, client_id: int) -> None:
        column, _shown, main = self._big.pop(client_id, (None, None, None))
        if column is not None:
            try:
                column.remove()
                main.expand()  # the lab's panel back
            except Exception:  # noqa: BLE001 - that tab has gone
                pass

    def download(self, client) -> str | None:
        """Every run of the session as a CSV file (app/classroom/gradebook.py), sent to `client`'s tab."""
        if client is None:
            return "refused: no tab to send the file to"
        rows = self.runs.rows()
        name = f"class-runs-{time.strftime('%Y-%m-%d-%H%M')}.csv"
        client.send_file_download(name, class_csv(rows), save_immediately=True)
        self.board_message.content = f"Sent {name}: {len(rows)} run{'s' * (len(rows) != 1)}."
        return None

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
