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

import threading
import time

import numpy as np
import viser
import viser.uplot

import lab
import robots
from lab import methods

from app.classroom.class_runs import ClassRuns, describe
from app.classroom.limits import in_labels
from app.classroom.lesson import LESSONS, is_lesson, lesson_configs
from app.classroom.student_run import queue_wait, student_length, wait_words
from app import any_robot
from app.panels.train import notify
from app.tab.goals import START_HINT
from app.tab.replay import _versions
from app.tab.run_view import RunView
from app.tab.scene import frame_workspace
from app.training.live import decimate, sample
from app.training.state import Shown
from app.viser_private import client_query

EMPTY = (np.array([1.0, 2.0]), np.full(2, np.nan))
WAIT_PERIOD = 1.0  # s: a queued run's wait is worked out again at most this often (the render loop draws often)
VIEWER_START = "**Start my run** (in *My experiment*) trains one of your own."
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
        length = student_length(arm, d.method)
        try:  # a lesson link opens the folder: the student's part of it is its first line
            lesson = is_lesson(client_query(client))
        except Exception:  # noqa: BLE001 - a tab without a query is an ordinary tab
            lesson = False
        self.lesson: str | None = None  # the lesson link this tab opened (its runs are grouped under it)
        self.folder = gui.add_folder("My experiment (this tab)", order=order, expand_by_default=lesson)
        with self.folder:
            self.part = gui.add_markdown("")  # a lesson's part for this tab (take_part)
            gui.add_markdown("Your own run, trained on the server beside the class's: only this tab sees it "
                             "(and the Class tab lists it for everyone).")
            self.name = gui.add_text("Your name", runs.name_of(self.tab),
                                     hint="a short label on the Class board (letters, digits, spaces, . ' _ -)")
            self.name_note = gui.add_markdown("")  # a refused name: why, and the name the runs carry instead
            # the registered robots and every robot the presenter opened since the server started (app/any_robot.py)
            self.robot = gui.add_dropdown("Robot", any_robot.choices(session.state), initial_value=arm)
            self.method = gui.add_dropdown("Method", tuple(m.label for m in methods.all_methods()),
                                           initial_value=methods.get(d.method).label)
            self.population = gui.add_number("Population", float(d.population), step=1)
            self.hidden = gui.add_number("Hidden units", float(d.hidden), step=1)
            self.goals = gui.add_number("Goals", float(d.targets), step=1, hint="training goals")
            self.generations = gui.add_number("Generations", float(length["generations"] or d.generations), step=1,
                                              hint="the run's length when it has no time budget (sized to show "
                                                   "learning in 5-20 s: docs/results/class.md)")
            self.budget = gui.add_number("Time budget (s)", float(length["seconds"] or 0.0), step=1,
                                         hint="0: none (the generations end the run); else it ends after this "
                                              "many seconds of optimizer time")
            self.seed = gui.add_number("Seed", float(d.seed), step=1)
            # the status and any refusal right above Start: a click shows its answer where the student looks
            self.status = gui.add_markdown("No run yet.")
            self.message = gui.add_markdown("")
            self.start_button = gui.add_button("Start my run", icon=viser.Icon.PLAYER_PLAY)
            self.stop_button = gui.add_button("Stop my run", icon=viser.Icon.PLAYER_STOP, disabled=True)
            self.show_on_arm = gui.add_checkbox("Show my run on my arm", True,
                                                hint="on the arm the class sees, this tab's arms show its best "
                                                     "network; on another robot, that robot is drawn beside the "
                                                     "class's arm (off: the class's network alone)")
            self.plot = gui.add_uplot(
                data=EMPTY, series=(viser.uplot.Series(label="generation"),
                                    viser.uplot.Series(label="my best MSE", stroke="#d62728", width=2)),
                scales={"x": viser.uplot.Scale(time=False), "y": viser.uplot.Scale(distr=3, log=10)},
                aspect=2.0)
        self._defaults_for = (self.robot.value, self.method.value)  # the fields hold their defaults
        # the tab's intro names the button a viewer has (the shared Start is the presenter's)
        session.start_hint = VIEWER_START
        intro = getattr(session, "intro", None)
        if intro is not None and START_HINT in intro.content:
            intro.content = intro.content.replace(START_HINT, VIEWER_START)
        self._renaming = threading.RLock()  # a write-back of the name calls its on_update again
        self.name.on_update(lambda e: self._rename())
        self.robot.on_update(lambda e: self._defaults())
        self.method.on_update(lambda e: self._defaults())
        self.start_button.on_click(lambda e: self.start())
        self.stop_button.on_click(lambda e: self.stop())
        self.show_on_arm.on_update(lambda e: self._show(force=True))
        self._drawn = None  # (run id, generation, state, status) last drawn
        self._wait = (None, 0.0, "")  # (run id, when, words) of a queued run's wait, worked out once a WAIT_PERIOD
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
        with self._renaming:  # one at a time: viser runs the callbacks of quick edits side by side
            self._rename_once()

    def _rename_once(self) -> None:
        if self.name.value == self.runs.name_of(self.tab):  # its name (our own write-back too)
            return
        typed = self.name.value
        why = self.runs.set_name(self.tab, typed)
        if why is not None:
            self._tell(why)
            if self.name.value == typed:  # back to the name it has, unless another was typed meanwhile
                self.name.value = self.runs.name_of(self.tab)
            # said in the folder until a name is taken: the runs carry the name it has, not the typed one
            self.name_note.content = (f"Your name {str(typed)[:40]!r} was {why} Your runs show on the Class "
                                      f"board as **{self.runs.name_of(self.tab)}** until you type another.")
        else:
            self.message.content = ""
            self.name_note.content = ""
            if self.name.value != self.runs.name_of(self.tab):
                self.name.value = self.runs.name_of(self.tab)  # as cleaned

    def _method_name(self) -> str:
        """The registry's name of the chosen method; ValueError naming the value if it is none of them
        (the message gate keeps a tab's dropdown within its options: app/viser_private.py)."""
        return methods.by_label(self.method.value)

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
        length = student_length(self.robot.value, self._method_name())
        self.generations.value = float(length["generations"] or d.generations)
        self.budget.value = float(length["seconds"] or 0.0)

    def config(self) -> lab.TrainConfig:
        """The run of the fields; ValueError naming the field that is wrong."""
        values = {}
        for key, handle in (("population", self.population), ("hidden", self.hidden), ("targets", self.goals),
                            ("generations", self.generations), ("seed", self.seed), ("seconds", self.budget)):
            v = handle.value
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or not float(v).is_integer():
                raise ValueError(f"{handle.label} must be a whole number, got {v!r}")
            values[key] = int(v)
        seconds = values.pop("seconds")
        if seconds < 0:
            raise ValueError(f"{self.budget.label} must be 0 (none) or a positive number of seconds, got {seconds}")
        try:
            return lab.TrainConfig.preset(robot=self.robot.value, method=self._method_name(),
                                          seconds=float(seconds) if seconds else None, **values)
        except ValueError as e:  # the lab names its fields ("targets"); the student reads their labels ("Goals")
            raise ValueError(in_labels(str(e))) from None

    def start(self) -> str | None:
        """Queue this tab's run; refused (said in the tab) beyond the limits, while its run goes, ..."""
        try:
            config = self.config()
        except ValueError as e:
            return self._tell(f"refused: {e}")
        why = self.runs.submit(self.tab, config, lesson=self.lesson)
        if why is not None:
            return self._tell(why)
        self.message.content = self.name_note.content  # the status says where it stands (a refused name stays said)
        self.refresh()
        return None

    def stop(self) -> str | None:
        why = self.runs.stop_tab(self.tab)
        if why is not None:
            return self._tell(why)
        self.refresh()
        return None

    def take_part(self, params: dict) -> str | None:
        """A lesson link's run for this tab, said on the folder's first line (the folder opens unfolded
        on a lesson link). A lesson that makes the class a search (its link's `class_hidden=2.3.4...`)
        gives the hidden units of the tab's seat (app/classroom/class_runs.ClassRuns.lesson_seat: the
        N-th tab to open the lesson gets the N-th value, and seed N // len(values) once the list is
        used up); any other lesson its own run's settings (robot, method, population, generations,
        hidden units, seed; a race's first run). The tab's runs are then grouped under the lesson on
        the Class board. None when done or the query holds no lesson; the refusal, said in the
        folder, when the link does not make a run or its list is not whole numbers."""
        text = params.get("class_hidden")
        if not is_lesson(params) and not text:
            return None
        self.lesson = params.get("lesson") or "1"
        try:
            main, _partner = lesson_configs(params)
        except ValueError as e:
            return self.refuse_part(f"refused: this lesson link does not make a run: {e}")
        hidden, seed = main.hidden, main.seed
        if text:
            try:
                values = [int(v) for v in text.split(".")]
                if not values or min(values) < 0:
                    raise ValueError
            except ValueError:
                return self.refuse_part(f"refused: class_hidden= is whole numbers joined by dots, got {text[:40]!r}")
            seat = self.runs.lesson_seat(self.lesson, self.tab)
            hidden, seed = values[seat % len(values)], seat // len(values)
        self.robot.value, self.method.value = main.robot, methods.get(main.method).label
        self._defaults_for = (self.robot.value, self.method.value)  # their callbacks keep the fields below
        self.population.value, self.goals.value = float(main.population), float(main.targets)
        self.generations.value, self.budget.value = float(main.generations), 0.0
        self.hidden.value, self.seed.value = float(hidden), float(seed)
        title = self.lesson if self.lesson in LESSONS else "this lesson"
        if text:
            part = (f"**Your part of the class's search: {hidden} hidden units, seed {seed}** ({main.robot}, "
                    f"{methods.get(main.method).label}, population {main.population}, {main.generations:,} "
                    f"generations). Press **Start my run**; the Class tab's chart gathers the class's runs.")
        else:
            part = (f"**Your run in this lesson** ({title}): {main.robot}, {methods.get(main.method).label}, "
                    f"population {main.population}, {main.hidden} hidden units, {main.generations:,} generations, "
                    f"seed {seed}; the presenter runs it on the class's arm. Press **Start my run** to train "
                    f"your own, or change a setting first.")
        if getattr(main, "goal", "position") == "pose":
            part += " (Your run reaches for positions; the presenter's run shows the pose goals.)"
        self.part.content = part
        notify(self.client, "My experiment", part.replace("**", ""), error=False)
        return None

    def refuse_part(self, why: str) -> str:
        """A lesson link's refusal, said on the folder's first line and above Start (and as a toast)."""
        self.part.content = why
        return self._tell(why)

    # ------------------------------------------------------------------ the render loop
    def refresh(self) -> None:
        """Status, buttons, curve, and the tab's arms (on the shared arm) or the run's robot beside them;
        cheap when nothing changed."""
        if len(self.robot.options) != len(choices := any_robot.choices(self.session.state)):
            self.robot.options = choices  # the presenter opened another robot: a student may pick it
        run = self.runs.run_of(self.tab)
        if run is None:
            return
        going = not run.ended
        if self.start_button.disabled != going:
            self.start_button.disabled = going
        stoppable = going and not run.stopping  # its Stop under way: another press would do nothing
        if self.stop_button.disabled == stoppable:
            self.stop_button.disabled = not stoppable
        status = run.status()
        if run.state == "queued":  # who is ahead, and the wait from their budgets and this server's pace
            now = time.monotonic()
            if self._wait[0] != run.id or now - self._wait[1] >= WAIT_PERIOD:
                self._wait = (run.id, now, wait_words(*queue_wait(self.runs, run)))
            status = f"{status}: {self._wait[2]}"
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
