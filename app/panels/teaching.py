"""The Train tab's views for a class: the population's legend with the method's statistics, the
live plots each method declares (lab.methods.LivePlot), and a race partner's settings. Read
generically from the runs' RunTracks (app/training/live.py); nothing here names a method.
"""

from __future__ import annotations

import time

import numpy as np
import viser
import viser.uplot

import lab
from lab import methods

from app.training.live import line_data, population_legend, stacked_svg
from app.training.state import run_label

LIVE_PERIOD = 1.0  # s: the legend, statistics and live plots change at most once a second (to every tab)
# uPlot in viser 1.1 never finds its x range when a chart starts empty: start with two NaN points
EMPTY_LINE = (np.array([0.0, 1.0]), np.full(2, np.nan))


class Watching:
    """The Population folder (legend, statistics) and the Live plots folder of the training panel."""

    def __init__(self, gui, panel):
        self.gui, self.panel = gui, panel
        with gui.add_folder("Population"):
            self.legend = gui.add_html(population_legend(None, False, _fmt))
            self.statistics = gui.add_markdown("")
        self.live_folder = gui.add_folder("Live plots")
        self.live: list = []  # (LivePlot, its RunTrack or None, what shows it, its folder)
        self._live_for = None
        self._population_shown = None
        self._population_at = self._live_at = -LIVE_PERIOD
        self.build_live()

    def lanes(self) -> list:
        """(label, track) of the run and its race partner (the selected method's plots when idle)."""
        st = self.panel.state
        lanes = []
        if st.track is not None and st.runner is not None:
            lanes.append((run_label(st.runner.config), st.track))
        if st.partner is not None:
            lanes.append((st.partner.label + " (partner)", st.partner.track))
        return lanes

    def build_live(self) -> None:
        """One plot per LivePlot of each run's method, each with its 'what you see' text (folded away
        with its folder)."""
        lanes = self.lanes()
        key = tuple((label, id(track)) for label, track in lanes) or self.panel.method.value
        if key == self._live_for:
            return
        self._live_for = key
        for *_, folder in self.live:
            folder.remove()
        self.live = []
        plotted = lanes or [(self.panel.method.value, None)]
        with self.live_folder:
            for label, track in plotted:
                method = track.method if track is not None else methods.get(self.panel._method_name())
                for plot in method.live_plots:
                    title = f"{plot.title} ({label})" if lanes else plot.title
                    folder = self.gui.add_folder(title)
                    with folder:
                        if plot.kind == "stacked":
                            shown = self.gui.add_html(stacked_svg([], [], plot.title))
                        else:
                            shown = self.gui.add_uplot(
                                data=EMPTY_LINE, title=plot.title, aspect=2.0,
                                series=(viser.uplot.Series(label="generation"),
                                        viser.uplot.Series(label=plot.key, stroke=method.hex, width=2)),
                                scales={"x": viser.uplot.Scale(time=False),
                                        "y": viser.uplot.Scale(distr=3, log=10) if plot.log else viser.uplot.Scale()})
                        with self.gui.add_folder("What you see", expand_by_default=True):
                            self.gui.add_markdown(plot.about)
                    self.live.append((plot, track, shown, folder))

    def refresh_population(self, force: bool = False) -> None:
        """The population legend and the method's statistics (set only when they change, at most
        every LIVE_PERIOD: every tab gets each change of the shared panel)."""
        now = time.monotonic()
        if now - self._population_at < LIVE_PERIOD and not force:
            return
        self._population_at = now
        lanes = self.lanes()
        replayed = self.panel.state.replayed_population if self.panel.state.replaying else None
        if replayed is not None:
            legend = population_legend(replayed, False, _fmt, "Replay, recorded cloud at goal 1's starting place: ")
        else:
            legends = []
            for label, t in lanes:
                p = t.population
                legends.append(population_legend(p, False, _fmt, f"{label}: " if len(lanes) > 1 else ""))
                if p is not None and p.species is not None:
                    legends[-1] += "<br>" + population_legend(p, True, _fmt, "", head=False)
            legend = "<br>".join(legends) if legends else population_legend(None, False, _fmt)
        stats = "  \n".join(s for s in (f"{label}: {t.statistics()}" if len(lanes) > 1 else t.statistics()
                                        for label, t in lanes) if s)
        if (legend, stats) != self._population_shown:
            self._population_shown = (legend, stats)
            self.legend.content, self.statistics.content = legend, stats

    def refresh_live(self, force: bool = False) -> None:
        """The live plots' data, at most every LIVE_PERIOD."""
        now = time.monotonic()
        if now - self._live_at < LIVE_PERIOD and not force:
            return
        self._live_at = now
        for plot, track, shown, _folder in self.live:
            if track is None:
                continue
            gens, values = track.series_of(plot.key)
            if plot.kind == "stacked":
                shown.content = stacked_svg(gens, values, plot.title)
            elif values:
                x, y = line_data(gens, values)
                shown.data = (x, np.maximum(y, 1e-300) if plot.log else y)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


class RaceFields:
    """The race partner's settings: a second run on the same arm and goals, of another method, other
    settings or another seed."""

    def __init__(self, gui, panel):
        self.panel = panel
        with gui.add_folder("Race", expand_by_default=False):
            self.enabled = gui.add_checkbox("Race a second run", False,
                                            hint="two runs at once on the same arm and goals, each in its own process")
            self.method = gui.add_dropdown("Partner method", tuple(m.label for m in methods.all_methods()),
                                           initial_value=panel.method.value)
            self.population = gui.add_number("Partner population", float(panel.population.value), step=1)
            self.hidden = gui.add_number("Partner hidden units", float(panel.hidden.value), step=1)
            self.seed = gui.add_number("Partner seed", float(panel.seed.value) + 1, step=1)
        self.method.on_update(lambda _e: self._fill_defaults())

    def _method_name(self) -> str:
        """The registry's name of the chosen method; ValueError naming the value if it is none of them
        (the message gate keeps a tab's dropdown within its options: app/viser_private.py)."""
        return methods.by_label(self.method.value)

    def _fill_defaults(self) -> None:
        d = lab.TrainConfig.preset(robot=self.panel.robot.value, method=self._method_name())
        self.population.value, self.hidden.value = float(d.population), float(d.hidden)

    def config(self, main: lab.TrainConfig) -> lab.TrainConfig | None:
        """The partner's TrainConfig (None without a race): main's arm, goals, generations and time budget."""
        if not self.enabled.value:
            return None
        values = {}
        for name in ("population", "hidden", "seed"):
            v = getattr(self, name).value
            if not isinstance(v, (int, float)) or not float(v).is_integer():
                raise ValueError(f"{name} must be a whole number, got {v!r}")
            values[name] = int(v)
        return lab.TrainConfig.preset(robot=main.robot, method=self._method_name(), generations=main.generations,
                                      targets=main.targets, goal_seed=main.goal_seed, seconds=main.seconds, **values,
                                      **({"goal": "pose"} if getattr(main, "goal", "position") == "pose" else {}))
