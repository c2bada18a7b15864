"""The training panel, shared by every tab (server.gui): settings, run controls, progress.

The method menu and the method's option fields come from the methods registry (lab.methods):
a method registered there appears here with its options, and picking a robot or a method fills
the fields with that pair's defaults. Settings are validated by lab.TrainConfig as they change: an invalid value is put back to
the last valid one and the reason is shown (in the panel and as a notification in the tab
that typed it). Start while a run is going is refused the same way. A time budget (Settings, "Time
budget (s)"; 0 or empty: none) ends the run after that many seconds of optimizer time; typing one
fills the fields with the method's defaults for that budget (generations unbounded,
lab.running.config.UNBOUNDED, unless typed after), and the status line shows the time left. Picking
a real arm puts REAL_ARM_BUDGET in that field (a paper arm or a snake: none), so that Reset then
Start shows the arm converge within a minute; a run with a budget is never slowed by the Speed
menu (the budget is its pace). Buttons only call LabState; the render loop calls `refresh` to show progress.
"""

from __future__ import annotations

import json
import threading

import numpy as np
import viser
import viser.uplot

import lab
import robots
from lab import methods
from lab.experiments import budgets
from lab.problem.encodings import encoding_from_dict
from lab.running.config import UNBOUNDED

from app import any_robot
from app.classroom.limits import refusal as limits_refusal
from app.panels.teaching import RaceFields, Watching
from app.startup import pretrained_path
from app.tab.posegoal import GOAL_LABELS, goal_label, pose_refusal, takes_poses
from app.training.live import decimate, lead_line, sample
from app.training.state import SPEEDS, run_label, speed_label

# a real arm's time budget in the panel: s of optimizer time, within which CMA-ES's defaults for it
# bring every real arm to about 1 % of its reach (docs/results/budgets.md); a tree gets it too (not
# measured there: the panel quotes no expectation for a tree)
REAL_ARM_BUDGET = 30.0


def budget_for(robot: str) -> float:
    """The time budget field's value when `robot` is picked: REAL_ARM_BUDGET on a real arm or a tree
    (a real robot of several end effectors), else 0 (none)."""
    return REAL_ARM_BUDGET if robots.kind(robot) in ("real", "tree", "custom") else 0.0

def expectation(robot: str, method: str, seconds: float | None, goal: str = "position") -> str:
    """What `method` is measured to reach on `robot` in `seconds` (lab.experiments.budgets), in words,
    said plainly when that is too coarse to be an IK answer (median beyond POOR_PCT % of the reach),
    with the method that does best in the same time; "" where nothing was measured. Pose goals:
    pose_expectation."""
    if goal == "pose":
        return pose_expectation(robot, method)
    if not any_robot.registered(robot):  # nothing measured: what the lab made of it (frame, capsules)
        try:
            return any_robot.page_note(robots.load(robot))
        except Exception:  # noqa: BLE001 - a field being typed: no line
            return ""
    e = budgets.expected(robot, method, seconds)
    if e is None:
        return ""
    label = methods.get(method).label
    said = (f"Measured on {e['machine'] or 'one machine'}: {label} on {robot} in {e['seconds']:g} s, a median "
            f"error of {e['median_mm']:.1f} mm ({e['median_pct']:.2f} % of its reach).")
    if e["median_pct"] <= budgets.POOR_PCT:
        return said
    others = [(x, m) for m in methods.names() if m != method
              if (x := budgets.expected(robot, m, seconds)) is not None]
    best = min(others, key=lambda xm: xm[0]["median_pct"], default=None)
    instead = (f" {methods.get(best[1]).label} reaches {best[0]['median_mm']:.1f} mm in {best[0]['seconds']:g} s."
               if best is not None and best[0]["median_pct"] < e["median_pct"] else "")
    return (f"**{label}'s network will miss most goals on this arm by about {e['median_mm']:.0f} mm "
            f"({e['median_pct']:.0f} % of its reach): a rough first guess, not an IK answer.{instead}** {said}")


def pose_expectation(robot: str, method: str) -> str:
    """What the shipped pose network of `method` on `robot` measured on held-out poses (its file's
    held_out, written by benchmarks/bench_pose_train.py), in words; "" where the method shipped none
    (no pose run was measured at the panel's budgets: docs/pose.md has the figures)."""
    try:
        with open(pretrained_path(robot, method, goal="pose"), encoding="utf-8") as f:
            doc = json.load(f)
        h = doc["held_out"]
        mm, deg, seconds = float(h["median_mm"]), float(h["median_deg"]), float(doc["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    try:
        encoding = encoding_from_dict(doc["controller"]["encoding"])
    except (KeyError, TypeError, ValueError):
        encoding = None
    closed = ("" if not getattr(encoding, "reach", 0) else "; every joint solved in closed form"
              if encoding.exact_pass else "; wrist, elbow and shoulder solved in closed form")
    return (f"Shipped {methods.get(method).label} pose network ({seconds:.0f} s): {mm:.1f} mm, {deg:.1f}° "
            f"median on held-out poses{closed}.")


SHARED = ("population", "generations", "hidden", "seed")  # the TrainConfig fields shown
# the convergence plot's width / height: low enough that the plot, its axis and its key stay in view
# at 1366 x 768 during a run, below the run controls and a two-line status (tests/test_app_browser.py)
PLOT_ASPECT = 3.6
# uPlot in viser 1.1 never finds its x range when a chart starts empty: start with two NaN points
EMPTY_PLOT = (np.array([0.0, 1.0]), np.full(2, np.nan), np.full(2, np.nan))


def notify(client, title: str, body: str, error: bool = True) -> None:
    if client is not None:
        client.add_notification(title, body, auto_close_seconds=6.0, color="red" if error else "green")


class TrainingPanel:
    def __init__(self, gui, state, on_robot=None):
        """gui: a viser GuiApi (inside the Train tab); state: LabState; on_robot(name): switch the scene."""
        self.state, self.on_robot = state, on_robot
        self.gui = gui
        d = lab.TrainConfig.preset(robot=state.arm.name, seconds=budget_for(state.arm.name) or None)
        # what a presenter uses comes first, so that it is in view on a projector (1366 x 768): the
        # arm and method, the run controls, the speed, the progress and the convergence plot; the
        # numbers behind a run, the race and the method's views follow
        self.robot = gui.add_dropdown("Robot", any_robot.choices(state, more=True), initial_value=state.arm.name,
                                      hint="the registered robots, those opened since the server started, and More robots…: "
                                           "any example-robot-data robot or a URDF of your own")
        self.more = any_robot.MoreRobots(gui, lambda name: (self.on_robot or self.state.set_robot)(name), notify)
        # position or pose goals (app/tab/posegoal.py): a shared control, so the classroom gate covers it
        self.goal = gui.add_dropdown("Goal", tuple(GOAL_LABELS), initial_value=goal_label(state.goal),
                                     hint="Position: drag the goal; Pose (real arms): drag and turn it, the "
                                          "network answers the tool's position and orientation")
        self.goal.on_update(self._on_goal)
        self.goal.visible = takes_poses(state.arm.name)  # a menu of one choice is only noise (and a row)
        self.method = gui.add_dropdown("Method", tuple(m.label for m in methods.all_methods()),
                                       initial_value=methods.get(d.method).label)
        self.expected = gui.add_markdown(expectation(d.robot, d.method, d.seconds, state.goal))  # what it will be worth
        actions = {"Start": self.start, "Pause": self.pause, "Resume": self.resume, "Step": self.step,
                   "Stop": self.stop, "Reset": self.reset, "Trained network": self.trained}
        icons = {"Start": viser.Icon.PLAYER_PLAY, "Pause": viser.Icon.PLAYER_PAUSE, "Step": viser.Icon.PLAYER_TRACK_NEXT,
                 "Resume": viser.Icon.PLAYER_PLAY, "Stop": viser.Icon.PLAYER_STOP, "Reset": viser.Icon.REFRESH,
                 "Trained network": viser.Icon.SCHOOL}
        hints = {"Start": "train a new network from scratch and watch it learn",
                 "Step": "while paused: exactly one more generation",
                 "Reset": "stop the run and show an untrained network (the first generation of the next run)",
                 "Trained network": "stop the run and show the network trained for this arm (shipped with the lab)"}
        self.buttons = {}
        for name, action in actions.items():
            button = self.buttons[name] = gui.add_button(name, icon=icons[name], hint=hints.get(name))
            button.on_click(lambda event, action=action: action(event.client))
        self._buttons_shown = None
        self.speed = gui.add_dropdown("Speed", tuple(SPEEDS), initial_value=speed_label(state.speed),
                                      hint="at most this many generations a second, so that a class can follow (a run with a time budget goes at full speed)")
        self.speed.on_update(lambda event: self._simple(lambda: self.state.set_speed(SPEEDS[self.speed.value]),
                                                        event.client))
        self.progress_bar = gui.add_progress_bar(0.0, animated=False)
        self.status = gui.add_markdown("Idle.")
        self.message = gui.add_markdown("")
        self.curves_folder = gui.add_folder("Convergence: training MSE (log scale)")
        self._racing = None
        self._build_curves(racing=False)
        self.settings_folder = gui.add_folder("Settings", expand_by_default=False)
        with self.settings_folder:
            # float fields, so that a fraction typed in the browser reaches us (and is refused) instead
            # of being truncated by viser's int cast
            self.population = gui.add_number("Population", float(d.population), step=1)
            self.generations = gui.add_number("Generations", float(d.generations), step=1)
            self.budget = gui.add_number(
                "Time budget (s)", budget_for(d.robot), step=1,
                hint="end the run after this many seconds of optimizer time, with its best network (0: no "
                     "budget); typing one sets the method's defaults for it, generations unbounded "
                     f"({UNBOUNDED:,}) unless you type fewer: whichever comes first ends the run")
            self.hidden = gui.add_number("Hidden units", float(d.hidden), step=1)
            self.seed = gui.add_number("Seed", float(d.seed), step=1)
            self.options_folder = gui.add_folder("Method options", expand_by_default=False)
            self.options: dict = {}  # option name -> its field, for the selected method
            self._options_lock = threading.RLock()  # callbacks of several tabs may rebuild them at once
            self._build_options(d)
        self.race = RaceFields(gui, self)
        self.watching = Watching(gui, self)  # the population's legend and the live plots
        self.legend, self.statistics = self.watching.legend, self.watching.statistics
        self._show_buttons()
        self._valid = {id(h): h.value for h in self._fields()}
        self._reverting = False
        for h in (self.robot, self.method, self.population, self.generations, self.budget, self.hidden, self.seed):
            h.on_update(self._on_field)
        self._shown_gen = -1

    def _fields(self):
        return (self.robot, self.method, self.population, self.generations, self.budget, self.hidden, self.seed,
                *self.options.values())

    def _build_options(self, config: lab.TrainConfig) -> None:
        """One field per option of config's method, at config's values (the old fields go)."""
        with self._options_lock:
            self._build_options_locked(config)

    def _build_options_locked(self, config: lab.TrainConfig) -> None:
        for handle in self.options.values():
            handle.remove()
        self.options = {}
        describe = type(config.options).describe()
        with self.options_folder:
            for name, value in config.options.to_dict().items():
                label, hint = name.replace("_", " ").capitalize(), describe[name][2]
                if isinstance(value, bool):
                    handle = self.gui.add_checkbox(label, value, hint=hint)
                else:
                    handle = self.gui.add_number(label, float(value), step=1 if isinstance(value, int) else None,
                                                 hint=hint)
                handle.on_update(self._on_field)
                self.options[name] = handle

    def _method_name(self) -> str:
        return next(m.name for m in methods.all_methods() if m.label == self.method.value)

    def _fill_defaults(self) -> None:
        """The selected robot's and method's defaults into the fields (our own writes, not checked)."""
        with self._options_lock:
            try:
                seconds = self.seconds()
            except ValueError:
                seconds = None
            d = lab.TrainConfig.preset(robot=self.robot.value, method=self._method_name(), seed=int(self.seed.value),
                                       seconds=seconds)
            self.expected.content = expectation(d.robot, d.method, d.seconds, self.state.goal)
            self._reverting = True
            try:
                for name in SHARED:
                    getattr(self, name).value = float(getattr(d, name))
                self._build_options(d)
            finally:
                self._reverting = False
            self._valid = {id(h): h.value for h in self._fields()}

    # ------------------------------------------------------------------ settings
    def seconds(self) -> float | None:
        """The time budget field: None for 0 or empty (no budget), else its seconds; ValueError
        naming the field when it is not a positive number."""
        v = self.budget.value
        if v is None or v == "" or (isinstance(v, (int, float)) and not isinstance(v, bool) and v == 0):
            return None
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or v < 0:
            raise ValueError(f"time budget (s) must be a positive number of seconds (0: none), got {v!r}")
        return float(v)

    def config(self) -> lab.TrainConfig:
        """The TrainConfig of the fields; ValueError (with the reason) when they are invalid."""
        values = {}
        for name in SHARED:
            handle = getattr(self, name)
            v = handle.value
            if not isinstance(v, (int, float)) or not float(v).is_integer():
                raise ValueError(f"{handle.label.lower()} must be a whole number, got {v!r}")
            values[name] = int(v)
        method = methods.get(self._method_name())
        kinds = {name: kind for name, (_d, kind, _h) in method.options.describe().items()}
        options = {}
        for name, handle in self.options.items():
            v = handle.value
            if kinds.get(name) is int:
                if not isinstance(v, (int, float)) or not float(v).is_integer():
                    raise ValueError(f"{handle.label.lower()} must be a whole number, got {v!r}")
                v = int(v)
            options[name] = v
        if self.state.goal == "pose":
            options["goal"] = "pose"
        try:
            config = lab.TrainConfig.preset(robot=self.robot.value, method=method.name, seconds=self.seconds(),
                                            **values, **options)
        except TypeError as e:
            if "goal" in str(e):
                raise ValueError("training a pose network is not in this lab yet (lab.TrainConfig has no goal): "
                                 "pick Goal: Position to train") from None
            raise
        if (why := limits_refusal(config, self.state.limits)) is not None:
            raise ValueError(why)
        return config

    def _on_field(self, event) -> None:
        if self._reverting:  # our own write-back of a refused value
            return
        handle = event.target
        if handle is self.robot and self.robot.value == any_robot.MORE:  # not a robot: the folder to pick one
            self._reverting = True
            try:
                self.robot.value = self.state.arm.name
            finally:
                self._reverting = False
            self.more.show()
            return
        if handle is self.method and self.method.value != self._valid[id(self.method)]:
            self._fill_defaults()  # each method's own defaults (its hidden size, its options)
            return
        if handle is self.budget:  # the method's defaults for the new budget (or for none), checked first
            try:
                d = lab.TrainConfig.preset(robot=self.robot.value, method=self._method_name(), seconds=self.seconds())
                if (why := limits_refusal(d, self.state.limits)) is not None:
                    raise ValueError(why)
            except (ValueError, TypeError) as e:
                self.refuse(event.client, f"{handle.label}: {e}")
                self._revert(handle)
                return
            self._fill_defaults()
            self.message.content = ""
            return
        try:
            self.config()
        except (ValueError, TypeError) as e:
            self.refuse(event.client, f"{handle.label}: {e}")
            self._revert(handle)
            return
        if handle is self.robot and self.robot.value != self.state.arm.name:
            msg = self.on_robot(self.robot.value) if self.on_robot else self.state.set_robot(self.robot.value)
            if msg:
                self.refuse(event.client, msg)
                self._revert(handle)
                return
        if handle is self.robot:
            self._reverting = True
            try:
                self.budget.value = budget_for(self.robot.value)  # a real arm's live budget, or none
            finally:
                self._reverting = False
            self._fill_defaults()  # the new arm's defaults
        self._valid[id(handle)] = handle.value
        self.message.content = ""

    def _on_goal(self, event) -> None:
        """Position or pose goals for every tab (refused while a run goes, and on an arm without poses)."""
        kind = GOAL_LABELS.get(self.goal.value)
        if kind is None or kind == self.state.goal:
            return
        msg = self.set_goal(kind)
        if msg:
            self.refuse(event.client, msg)
            self.goal.value = goal_label(self.state.goal)
        else:
            self.message.content = ""

    def set_goal(self, kind: str) -> str | None:
        """The state's goal kind (refused with a line naming why); the menu follows."""
        if kind == "pose" and (why := pose_refusal(self.state.arm.name)) is not None:
            return f"refused: {why}"
        msg = self.state.set_goal(kind)
        if msg is None and self.goal.value != goal_label(kind):
            self.goal.value = goal_label(kind)
        if msg is None:  # what a run is worth changes with the goal
            try:
                seconds = self.seconds()
            except ValueError:
                seconds = None
            self.expected.content = expectation(self.robot.value, self._method_name(), seconds, kind)
        return msg

    def _revert(self, handle) -> None:
        self._reverting = True
        try:
            handle.value = self._valid[id(handle)]
        finally:
            self._reverting = False

    def refuse(self, client, message: str) -> None:
        text = message if message.startswith("refused") else f"refused: {message}"
        self.message.content = f"**{text[0].upper() + text[1:]}**"
        notify(client, "Refused", text)

    # ------------------------------------------------------------------ buttons
    def start(self, client=None) -> str | None:
        try:
            config = self.config()
        except (ValueError, TypeError) as e:
            msg = f"refused: {e}"
        else:
            if config.robot != self.state.arm.name and self.on_robot and not self.state.running:
                msg = self.on_robot(config.robot)
                if msg:
                    self.refuse(client, msg)
                    return msg
            try:
                partner = self.race.config(config)
            except (ValueError, TypeError) as e:
                msg = f"refused: race partner: {e}"
            else:
                msg = self.state.start(config, partner)
        if msg:
            self.refuse(client, msg)
        else:
            self.message.content = ""
        return msg

    def _simple(self, action, client) -> str | None:
        msg = action()
        if msg:
            self.refuse(client, msg)
        else:
            self.message.content = ""
        return msg

    def pause(self, client=None):
        return self._simple(self.state.pause, client)

    def step(self, client=None):
        return self._simple(self.state.step, client)

    def resume(self, client=None):
        return self._simple(self.state.resume, client)

    def stop(self, client=None):
        msg = self._simple(self.state.stop, client)
        self._tell_notice()
        return msg

    def reset(self, client=None):
        """Stop any run and show an untrained network: the first generation's best of the run that
        Start would begin with these settings (the startup controller when they are invalid)."""
        try:
            config = self.config()
        except (ValueError, TypeError):
            config = None
        self.state.reset(untrained=config)
        self.message.content = ""
        self._tell_notice()
        self._shown_gen = -1
        self.refresh(force=True)

    def trained(self, client=None):
        """Stop any run and show the arm's trained network again (the one it opened with)."""
        self.state.reset()
        self.message.content = ""
        self._tell_notice()
        self._shown_gen = -1
        self.refresh(force=True)

    def _show_buttons(self) -> None:
        """Only the run controls that apply now: Start, Reset and Trained network when no run
        goes; Pause, Stop and Reset while one runs; Resume, Step, Stop and Reset while paused."""
        states = {r.state for r in self.state.runners()}
        now = "running" if "running" in states else "paused" if "paused" in states else "idle"
        if now == self._buttons_shown:
            return
        self._buttons_shown = now
        shown = {"idle": ("Start", "Reset", "Trained network"), "running": ("Pause", "Stop", "Reset"),
                 "paused": ("Resume", "Step", "Stop", "Reset")}[now]
        for name, button in self.buttons.items():
            button.visible = name in shown
        self.expected.visible = now == "idle"  # what a method is worth: before a run, not over the plot during one

    def _tell_notice(self) -> None:
        """A run's end the class should know of (a worker killed after Stop): in the shared message."""
        if self.state.notice:
            self.message.content = f"**{self.state.notice}**"

    # ------------------------------------------------------------------ progress
    def _build_curves(self, racing: bool) -> None:
        """The convergence plot: best and median MSE, and the race partner's beside them."""
        if racing == self._racing:
            return
        if self._racing is not None:
            self.plot.remove()
        self._racing = racing
        series = [viser.uplot.Series(label="generation"),
                  viser.uplot.Series(label="best MSE", stroke="#d62728", width=2),
                  viser.uplot.Series(label="median MSE", stroke="#1f77b4", width=1)]
        if racing:
            series += [viser.uplot.Series(label="best MSE, partner", stroke="#9467bd", width=2),
                       viser.uplot.Series(label="median MSE, partner", stroke="#17becf", width=1, dash=[4, 4])]
        with self.curves_folder:
            self.plot = self.gui.add_uplot(
                data=EMPTY_PLOT + ((np.full(2, np.nan),) * 2 if racing else ()), series=tuple(series),
                scales={"x": viser.uplot.Scale(time=False), "y": viser.uplot.Scale(distr=3, log=10)},
                aspect=PLOT_ASPECT)

    def refresh(self, force: bool = False) -> None:
        """Show the run's progress (called by the render loop, a few times a second)."""
        if self.goal.value != goal_label(self.state.goal):  # a robot without poses put it back to Position
            self.goal.value = goal_label(self.state.goal)
        if self.goal.visible != (poses := takes_poses(self.state.arm.name)):  # shown on the arms with poses
            self.goal.visible = poses
        p = self.state.progress()
        n = p["generation"]
        partner = self.state.partner
        going = p["state"] == "running" or (partner is not None and partner.runner.state == "running")
        self._show_buttons()
        self.watching.refresh_population(force)
        # what the status says changes without a new generation too: a run's end (Finished, Stopped,
        # Failed), its partner's, a notice; a paused or ended run is redrawn only when one of them changes
        shown = (n, p["state"], p["run_id"], p["recording"], p["error"], self.state.notice,
                 None if partner is None else (partner.runner.state, len(partner.track)))
        if shown == self._shown_gen and not force and not going:
            return
        self._shown_gen = shown
        done = n / p["total"] if p["total"] else 0.0
        if p["budget"]:  # a time budget: whichever of the two ends the run is nearer its end
            done = max(done, min(p["seconds"] / p["budget"], 1.0))
        self.progress_bar.value = 100.0 * done
        self._build_curves(racing=partner is not None)
        self.watching.build_live()
        # the app keeps a bounded, thinned history per run (app/training/state.py, app/training/live.py):
        # every series is sampled at one set of generations; a race is drawn up to the generation both
        # runs have reached (uPlot has no gaps for NaN in a log scale: a shorter series padded with NaN
        # dropped to the axis); the status says each run's count
        runs = [(p["generations"] - 1, p["best"], p["median"])] + ([partner.track.curves()] if partner else [])
        m = min((int(g[-1]) + 1 if len(g) else 0) for g, _, _ in runs)
        at = decimate(m)
        columns = [at + 1.0]
        for gens, best, median in runs:
            for values in (best, median):
                columns.append(np.maximum(np.nan_to_num(sample(gens, values, at), posinf=1e12, nan=1e12), 1e-12))
        self.plot.data = tuple(columns) if m else EMPTY_PLOT + ((np.full(2, np.nan),) * 2 if partner else ())
        self.status.content = self.status_line(p)
        self.watching.refresh_live(force)

    def pace(self, p: dict) -> str:
        """What a run's pace is when it is not the Speed menu's: ", 3.1 generations/s: all this robot
        allows here" (a run slower than its cap), or the budget's full speed; else nothing."""
        rate = p.get("generations_per_s") or 0.0
        if p["state"] not in ("running", "paused") or p["generation"] < 3 or rate <= 0:
            return ""
        speed = self.state.speed
        if p["budget"]:
            return f", {rate:.1f} generations/s (a run with a time budget goes as fast as the robot allows, whatever Speed says)"
        if speed is not None and rate < 0.8 * speed:
            return f", {rate:.1f} generations/s: all {self.state.arm.name} allows here (Speed caps at {speed:g})"
        return ""

    def status_line(self, p: dict) -> str:
        """The status (markdown): the run's state (Running, Paused, Finished, Stopped, Failed and why)
        with its generation, time and best MSE; what a run waits for before its first generation; the
        race partner's state; the notice of the last run's end."""
        n, partner = p["generation"], self.state.partner
        best_s = f"{p['best'][-1]:.4g}" if n else "-"
        rec = f"  \nRecording: `{p['recording']}`" if p["recording"] else ""
        total = "" if p["budget"] and p["total"] >= UNBOUNDED else f" / {p['total']}"
        going = p["state"] in ("running", "paused")
        if not p["budget"]:
            left = ""
        elif going:
            left = f", {max(p['budget'] - p['seconds'], 0.0):.1f} s of {p['budget']:g} s left"
        else:
            left = f", {min(p['seconds'], p['budget']):.1f} s of its {p['budget']:g} s"
        if p.get("preparing"):  # the kernels compile before the first generation (a cold cache, once)
            status = (f"**{p['state'].capitalize()}**: preparing the training kernels: {p['preparing']}; "
                      "the run starts the moment they are ready")
        else:
            status = (f"**{p['state'].capitalize()}**: generation {n}{total}{left}, "
                      f"best MSE {best_s}, {p['evals_per_s']:,.0f} evaluations/s{self.pace(p)}")
        if p["state"] == "failed" and p.get("error"):
            status += f"  \nIt failed: {p['error']}"
        status += rec
        if partner is not None:
            waits = getattr(partner.runner, "preparing", None) if partner.runner.state == "running" else None
            status += (f"  \nPartner ({partner.label}): **{partner.runner.state.capitalize()}**, "
                       + (f"preparing the training kernels: {waits}" if waits else f"generation {len(partner.track)}")
                       + (f", recording `{partner.recording}`" if partner.recording else ""))
            summary = partner.runner.join(0) if partner.runner.state == "failed" else None
            if summary is not None and summary.state == "failed" and summary.error:
                status += f"  \nThe partner failed: {summary.error}"
            status += "  \n" + lead_line(self.state.track, partner.track, run_label(self.state.runner.config),
                                          partner.label)
        if self.state.notice:
            status += f"  \n{self.state.notice}"
        return status
