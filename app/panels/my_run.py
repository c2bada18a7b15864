"""A viewer's own experiment on a classroom server: the folder "My experiment (this tab)" (client.gui).

A viewer's tab (app/classroom/access.py: a tab without the presenter link on a restricted server)
gets a name field ("Your name"), the settings of a run (robot, method, population, hidden units,
goals, generations or a time budget, seed; the server's limits bound them), "Start my run" and
"Stop my run", a status line (its place in the queue, its generation, its end) and its own
convergence curve. The run goes to the class's queue (app/classroom/class_runs.py) and trains in a
worker process of its own; nothing shared changes. While it trains on the arm the class sees, this
tab's arms show its best network (TabSession.own, as the tab's own replay does); on another robot,
that robot is drawn in this tab's own scene beside the class's arm (app/tab/run_view.py: scaled to
its size, "your run: so100" above it, a goal the student drags, the run's best network reaching for
it), the camera framing both. "Show my run on my arm" turns either off (the class's network on the
tab's arms, the other robot gone, the camera on the class's arm again). A presenter's tab, and every tab of a server where every tab is a presenter (loopback
without a token), has no such folder: it has the shared Train panel.
"""

from __future__ import annotations

import numpy as np
import viser
import viser.uplot

import lab
import robots
from lab import methods

from app.classroom.class_runs import ClassRuns, describe
from app.panels.train import notify
from app.tab.replay import _versions
from app.tab.run_view import RunView
from app.tab.scene import frame_workspace
from app.training.live import decimate, sample
from app.training.state import Shown

EMPTY = (np.array([1.0, 2.0]), np.full(2, np.nan))
MINE = "my run"  # the start of the source of what this tab's arms show from its run


class MyRunPanel:
    def __init__(self, client, session, runs: ClassRuns, order: float = 0.7):
        """order: above the shared panel's tabs (1), below the tab's replay folder (0.5): a student finds
        it without scrolling past the shared Train panel; folded until opened."""
        self.client, self.session, self.runs = client, session, runs
        self.tab = client.client_id
        gui = client.gui
        arm = session.state.arm.name
        d = lab.TrainConfig.preset(robot=arm)
        self.folder = gui.add_folder("My experiment (this tab)", order=order, expand_by_default=False)
        with self.folder:
            gui.add_markdown("Your own run, trained on the server beside the class's: only this tab sees it "
                             "(and the Class tab lists it for everyone).")
            self.name = gui.add_text("Your name", runs.name_of(self.tab),
                                     hint="a short label on the Class board (letters, digits, spaces, . ' _ -)")
            self.robot = gui.add_dropdown("Robot", robots.names(), initial_value=arm)
            self.method = gui.add_dropdown("Method", tuple(m.label for m in methods.all_methods()),
                                           initial_value=methods.get(d.method).label)
            self.population = gui.add_number("Population", float(d.population), step=1)
            self.hidden = gui.add_number("Hidden units", float(d.hidden), step=1)
            self.goals = gui.add_number("Goals", float(d.targets), step=1, hint="training goals")
            self.generations = gui.add_number("Generations", 200.0, step=1)
            self.budget = gui.add_number("Time budget (s)", 0.0, step=1,
                                         hint="0: none (the generations end the run); else it ends after this "
                                              "many seconds of optimizer time")
            self.seed = gui.add_number("Seed", float(d.seed), step=1)
            self.start_button = gui.add_button("Start my run", icon=viser.Icon.PLAYER_PLAY)
            self.stop_button = gui.add_button("Stop my run", icon=viser.Icon.PLAYER_STOP, disabled=True)
            self.show_on_arm = gui.add_checkbox("Show my run on my arm", True,
                                                hint="on the arm the class sees, this tab's arms show its best "
                                                     "network; on another robot, that robot is drawn beside the "
                                                     "class's arm (off: the class's network alone)")
            self.status = gui.add_markdown("No run yet.")
            self.message = gui.add_markdown("")
            self.plot = gui.add_uplot(
                data=EMPTY, series=(viser.uplot.Series(label="generation"),
                                    viser.uplot.Series(label="my best MSE", stroke="#d62728", width=2)),
                scales={"x": viser.uplot.Scale(time=False), "y": viser.uplot.Scale(distr=3, log=10)},
                aspect=2.0)
        self._defaults_for = (self.robot.value, self.method.value)  # the fields hold their defaults
        self.name.on_update(lambda e: self._rename())
        self.robot.on_update(lambda e: self._defaults())
        self.method.on_update(lambda e: self._defaults())
        self.start_button.on_click(lambda e: self.start())
        self.stop_button.on_click(lambda e: self.stop())
        self.show_on_arm.on_update(lambda e: self._show(force=True))
        self._drawn = None  # (run id, generation, state, status) last drawn
        self._shown_version = None
        self.view: RunView | None = None  # the run's robot in this tab's scene, when it is not the class's
        self._view_key = None  # (run id, robot, the class's arm) it was drawn for
        self._view_version = None
        self._view_broken = None  # the key of a view that could not be drawn (not tried again)

    # ------------------------------------------------------------------ actions
    def _tell(self, text: str, error: bool = True) -> str:
        self.message.content = text
        if error:
            notify(self.client, "My experiment", text)
        return text

    def _rename(self) -> None:
        if self.name.value == self.runs.name_of(self.tab):  # its name (our own write-back too)
            return
        why = self.runs.set_name(self.tab, self.name.value)
        if why is not None:
            self._tell(why)
            self.name.value = self.runs.name_of(self.tab)  # back to the name it has
        else:
            self.message.content = ""
            if self.name.value != self.runs.name_of(self.tab):
                self.name.value = self.runs.name_of(self.tab)  # as cleaned

    def _method_name(self) -> str:
        return next(m.name for m in methods.all_methods() if m.label == self.method.value)

    def _defaults(self) -> None:
        """The robot's and method's defaults into the fields (when they have changed: a write of the same
        robot or method, as a lesson's take_part makes, keeps the fields)."""
        if (self.robot.value, self.method.value) == self._defaults_for:
            return
        self._defaults_for = (self.robot.value, self.method.value)
        try:
            d = lab.TrainConfig.preset(robot=self.robot.value, method=self._method_name())
        except ValueError as e:
            self._tell(f"refused: {e}")
            return
        self.population.value, self.hidden.value, self.goals.value = float(d.population), float(d.hidden), float(d.targets)

    def config(self) -> lab.TrainConfig:
        """The run of the fields; ValueError naming the field that is wrong."""
        values = {}
        for key, handle in (("population", self.population), ("hidden", self.hidden), ("targets", self.goals),
                            ("generations", self.generations), ("seed", self.seed), ("seconds", self.budget)):
            v = handle.value
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or not float(v).is_integer():
                raise ValueError(f"{handle.label.lower()} must be a whole number, got {v!r}")
            values[key] = int(v)
        seconds = values.pop("seconds")
        if seconds < 0:
            raise ValueError(f"time budget (s) must be 0 (none) or a positive number of seconds, got {seconds}")
        return lab.TrainConfig.preset(robot=self.robot.value, method=self._method_name(),
                                      seconds=float(seconds) if seconds else None, **values)

    def start(self) -> str | None:
        """Queue this tab's run; refused (said in the tab) beyond the limits, while its run goes, ..."""
        try:
            config = self.config()
        except ValueError as e:
            return self._tell(f"refused: {e}")
        why = self.runs.submit(self.tab, config)
        if why is not None:
            return self._tell(why)
        self.message.content = ""  # the status says where it stands
        self.refresh()
        return None

    def stop(self) -> str | None:
        why = self.runs.stop_tab(self.tab)
        if why is not None:
            return self._tell(why)
        self.refresh()
        return None

    def take_part(self, params: dict) -> str | None:
        """A lesson that makes the class a search (its link's `class_hidden=2.3.4...`): this tab's fields
        get the lesson's run with the hidden units of its seat (app/classroom/class_runs.ClassRuns.
        lesson_seat: the N-th tab to open the lesson gets the N-th value, and seed N // len(values)
        once the list is used up). None when done or the link asks for nothing; the refusal, said in
        the tab, when the list is not whole numbers within the server's limits."""
        text = params.get("class_hidden")
        if not text:
            return None
        try:
            values = [int(v) for v in text.split(".")]
            if not values or min(values) < 0:
                raise ValueError
        except ValueError:
            return self._tell(f"refused: class_hidden= is whole numbers joined by dots, got {text[:40]!r}")
        seat = self.runs.lesson_seat(params.get("lesson", "1"), self.tab)
        hidden, seed = values[seat % len(values)], seat // len(values)
        try:
            base = lab.TrainConfig.preset(robot=params.get("robot", self.robot.value),
                                          method=params.get("method", self._method_name()))
            population = int(params.get("population", base.population))
            generations = int(params.get("generations", base.generations))
        except ValueError as e:
            return self._tell(f"refused: {e}")
        self.robot.value, self.method.value = base.robot, methods.get(base.method).label
        self._defaults_for = (self.robot.value, self.method.value)  # their callbacks keep the fields below
        self.population.value, self.goals.value = float(population), float(base.targets)
        self.generations.value, self.budget.value = float(generations), 0.0
        self.hidden.value, self.seed.value = float(hidden), float(seed)
        self._tell(f"Your part of the class's search: {hidden} hidden units, seed {seed}. Press **Start my run**.",
                   error=False)
        return None

    # ------------------------------------------------------------------ the render loop
    def refresh(self) -> None:
        """Status, buttons, curve, and the tab's arms (on the shared arm) or the run's robot beside them;
        cheap when nothing changed."""
        run = self.runs.run_of(self.tab)
        if run is None:
            return
        going = not run.ended
        if self.start_button.disabled != going:
            self.start_button.disabled = going
        if self.stop_button.disabled == going:
            self.stop_button.disabled = not going
        status = run.status()
        drawn = (run.id, run.generation, run.state, status)
        if drawn != self._drawn:
            self._drawn = drawn
            best = run.best()
            held = run.held_out()
            text = (f"**{status[0].upper() + status[1:]}**  \n{describe(run.config)}" +
                    (f"  \nbest training MSE {best:.4g}" if best is not None else "") +
                    (f", held-out MSE {held:.4g}" if held is not None else "") +
                    (f"  \nYour {run.config.robot} stands left of the class's arm: drag its goal."
                     if run.config.robot != self.session.state.arm.name and run.controller is not None else ""))
            self.status.content = text
            gens, values, _median = run.track.curves()
            m = int(gens[-1]) + 1 if len(gens) else 0
            at = decimate(m)
            self.plot.data = (at + 1.0, np.maximum(np.nan_to_num(sample(gens, values, at), posinf=1e12, nan=1e12),
                                                   1e-12)) if m else EMPTY
        self._show()

    def _show(self, force: bool = False) -> None:
        """This tab's arms show the run's best while it is on the shared arm (and Show is on), never
        over the tab's own replay; on another robot, that robot beside the class's arm (_show_other)."""
        s = self.session
        own = s.own
        mine = own is not None and own.source.startswith(MINE)
        run = self.runs.run_of(self.tab)
        has = run is not None and run.controller is not None and self.show_on_arm.value
        self._show_other(run if has and run.config.robot != s.state.arm.name else None)
        wanted = has and run.config.robot == s.state.arm.name
        if not wanted:
            if mine and force:
                s.own = None
            return
        if own is not None and not mine:
            return  # the tab's replay has the arms
        # a new best (or Show turned on): once shown, "Back to the shared view" of the tab's replay
        # folder gives the arms back to the class's network until the next new best
        if force or self._shown_version != (run.id, run.version):
            self._shown_version = (run.id, run.version)
            s.own = Shown(s.state.arm, run.controller, f"{MINE} ({run.name}), generation {run.generation}",
                          next(_versions))

    def _show_other(self, run) -> None:
        """The run's robot in this tab's own scene (None: none), drawn again when the class's arm changes."""
        shared = self.session.state.arm
        key = None if run is None else (run.id, run.config.robot, shared.name)
        if key != self._view_key and self.view is not None:
            self.view.remove()
            self.view, self._view_version = None, None
        self._view_key = key
        if run is None:
            return
        if self.view is None and key != self._view_broken:
            try:
                arm = robots.load(run.config.robot)
                self.view = RunView(self.client, arm, frame_workspace(shared), f"your run: {arm.name}")
            except Exception as e:  # noqa: BLE001 - its numbers and curve still show
                self._view_broken = key
                self.message.content = f"your run's robot cannot be drawn here: {e}"
                return
        if self.view is not None and self._view_version != run.version:
            self._view_version = run.version
            self.view.set_controller(run.controller)

    def close(self) -> None:
        self.runs.drop_tab(self.tab)
        if self.view is not None:
            self.view.remove()
            self.view = None
