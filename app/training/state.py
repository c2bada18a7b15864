"""The server's shared state: one arm, the controller the arms show, and one training run.

Nothing here knows about viser; the panels call these methods and show what they return.
Methods that can be refused return a message (str) and change nothing, or None when done.

Training runs in a process of its own (lab.running.worker.ProcessRunner): the server's threads and the
optimizer do not share a GIL, so neither slows the other down. The runner's subscriber (`_Tap`)
runs in its reader thread and only appends numbers and swaps a reference under a lock. The
render loop polls `version` and redraws when the shown controller has changed.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import numpy as np

import lab
import robots
from lab.running.history import History
from lab.running.runner import speed_period
from lab.running.worker import STOP_GRACE, ProcessRunner

from app.classroom.limits import refusal as limits_refusal
from app.startup import made_for
from app.training.live import RunTrack
from app.training.notebook import Notebook, entry_from_summary

SPEEDS = {"1 generation/s": 1.0, "5 generations/s": 5.0, "20 generations/s": 20.0, "unlimited": None}


def speed_label(generations_per_second: float | None) -> str:
    """The Speed menu's entry for a rate (the nearest one)."""
    if generations_per_second is None:
        return "unlimited"
    return min((k for k, v in SPEEDS.items() if v is not None), key=lambda k: abs(SPEEDS[k] - generations_per_second))

log = logging.getLogger(__name__)
# points of a run's MSE history the app keeps (lab.running.history.History): every generation up to
# this many, then fewer and fewer, so a run of 10^9 generations takes as little memory as one of 5,000
HISTORY_POINTS = 4096
# s a run's end waits for a lock on the notebook (held by another program) before its entry is left to
# the notebook's retrier: well within the STOP_GRACE that Stop gives a run to end
END_WRITE_WAIT = 1.0


@dataclass(frozen=True)
class Shown:
    """What the arms show: a controller for `arm` (or None), where it came from, a version, and the
    goals it answers ("position", or "pose": app/tab/posegoal.py)."""

    arm: robots.Arm
    controller: object | None
    source: str
    version: int
    goal: str = "position"


@dataclass
class Partner:
    """The second run of a race: its runner, recording, live numbers and the controller its arm shows."""

    runner: ProcessRunner
    recording: str | None
    track: RunTrack
    controller: object | None = None
    version: int = 0

    @property
    def label(self) -> str:
        return run_label(self.runner.config)


def run_label(config) -> str:
    """A run in a few words: its method's label and seed ("CMA-ES, seed 0")."""
    return f"{lab.methods.get(config.method).label}, seed {config.seed}"


class _Tap:
    """Runner subscriber: records each generation; on_end writes the notebook entry."""

    def __init__(self, state: "LabState", runner: ProcessRunner, recording: str | None, partner: bool = False):
        self.state, self.runner, self.recording, self.partner = state, runner, recording, partner
        self.started = time.time()

    def __call__(self, event: lab.GenerationEvent) -> None:
        if self.partner:
            self.state._on_partner_generation(self.runner, event)
        else:
            self.state._on_generation(self.runner, event)

    def on_end(self, summary: lab.RunSummary) -> None:
        self.state._on_end(self.runner, summary, self.started, self.recording)


class LabState:
    def __init__(self, robot: str = "planar", notebook: Notebook | None = None, startup=None,
                 recorder=None, startups=None, limits: dict | None = None, speed: float | None = None,
                 goal: str = "position"):
        """startup: controller shown first (or None); startups: callable(robot name) -> (controller,
        note), the controller an arm opens with (app.startup.startup_controller), called once per arm;
        recorder: callable(runner) -> object with .path that records the run
        (lab.recording.RerunLogger), or None for no recordings. limits: the bounds this server puts
        on settings (app/classroom/limits.py; None: the lab's own). speed: generations a second every
        run starts with (None: as fast as it goes). goal: "position" or "pose" (a real arm only:
        app/tab/posegoal.py); startups is called as startups(robot, "pose") for pose goals."""
        from app.tab.posegoal import GOALS, pose_refusal

        if goal not in GOALS:
            raise ValueError(f"goal must be one of {', '.join(GOALS)}, got {goal!r}")
        if goal == "pose" and (why := pose_refusal(robot)) is not None:
            raise ValueError(why)
        self.goal = goal
        self.limits = limits
        self._lock = threading.RLock()
        self.notebook = notebook or Notebook()
        self.recorder = recorder
        self.runner: ProcessRunner | None = None
        self.recording: str | None = None
        self.track: RunTrack | None = None  # the run's live numbers and population (app/training/live.py)
        self.partner: Partner | None = None  # a race's second run
        self.speed: float | None = speed  # generations per second (None: no cap), for every run
        self.stop_grace = STOP_GRACE  # s Stop waits for a worker before killing it (stop())
        self.notice: str | None = None  # what the class is told about the last run's end (the status shows it)
        self.replaying = False  # the arms show a replayed controller, not the run's best
        self.replayed_population = None  # the population a replayed recording logged at its generation
        self._startup = startup
        self._startups, self._opened = startups, {}  # robot name -> (controller, note) it opened with
        self._replaced = None  # (controller, source) a tree's run replaced on the arms (kept_the_better)
        self._version = 0
        self._shown = Shown(robots.load(robot), None, "none", 0)
        self.opened_robots = [self._shown.arm.name]  # every robot shown since the server started (the Robot menus: app/any_robot.py)
        self._clear_history()
        self._show_startup()

    # ------------------------------------------------------------------ reading
    @property
    def shown(self) -> Shown:
        return self._shown

    @property
    def arm(self) -> robots.Arm:
        return self._shown.arm

    @property
    def running(self) -> bool:
        return any(r.state in ("running", "paused") for r in self.runners())

    def runners(self) -> list:
        """The current run and, in a race, its partner."""
        with self._lock:
            return [r for r in (self.runner, self.partner.runner if self.partner else None) if r is not None]

    def progress(self) -> dict:
        """Plot data and counters of the current run (copies, any thread)."""
        with self._lock:
            r = self.runner
            gens, best, median = self._history.arrays()
            ended = r is not None and r.state in ("finished", "stopped", "failed")
            summary = r.join(0) if ended else None  # kept with the state, before join() returns
            return dict(
                generation=len(self._history), total=r.config.generations if r else 0,
                state=r.state if r else "idle", best=best, median=median, generations=gens + 1,
                evals_per_s=self._evals / self._seconds if self._seconds > 0 else 0.0,
                # generations a second of optimizer time: what the robot allows here (Speed only caps it)
                generations_per_s=len(self._history) / self._seconds if self._seconds > 0 else 0.0,
                recording=self.recording, run_id=r.run_id if r else None,
                seconds=self._seconds, budget=r.config.seconds if r else None,  # optimizer s so far; the time budget
                # what the run waits for before its first generation (the training kernels compiling:
                # "step 2 of 7 (...), about 12 s"), None when nothing; why a failed run failed
                preparing=getattr(r, "preparing", None) if r is not None and r.state == "running" else None,
                error=summary.error if summary is not None else None,
            )

    # ------------------------------------------------------------------ changing what is shown
    def show(self, controller, source: str, arm: robots.Arm | None = None) -> str | None:
        """Show a controller on the arms (refused, with the reason, when it was made for another arm)."""
        with self._lock:
            arm = arm or self._shown.arm
            if controller is not None and not made_for(controller, arm):
                return f"refused: this controller was not made for the {arm.name} arm ({source})"
            kind = "pose" if getattr(controller, "goal", "position") == "pose" else "position"
            if controller is not None and kind != self.goal:
                return (f"refused: this is a {kind} controller and the goals are {self.goal}s: pick Goal: "
                        f"{kind.capitalize()} in the Train panel first ({source})")
            self._version += 1
            self._shown = Shown(arm, controller, source, self._version, self.goal)
            return None

    def show_replay(self, controller, source: str) -> str | None:
        """Show a replayed controller; training keeps going but no longer moves the arms."""
        with self._lock:
            msg = self.show(controller, source)
            if msg is None:
                self.replaying = True
            return msg

    def live(self) -> None:
        """Back to the run's best controller (or the startup controller when there is no run)."""
        with self._lock:
            self.replaying = False
            self.replayed_population = None
            snap = self.runner.snapshot() if self.runner is not None else None
            if snap is not None and snap.controller is not None and self.runner.config.robot == self.arm.name \
                    and getattr(self.runner.config, "goal", "position") == self.goal:
                self.show(snap.controller, f"run {self.runner.run_id[:6]}, generation {snap.generation}")
            else:
                self._show_startup()

    def _show_startup(self) -> None:
        arm = self.arm
        key = arm.name if self.goal == "position" else (arm.name, self.goal)
        if self._startups is not None and key not in self._opened:
            try:
                self._opened[key] = self._startups(arm.name) if self.goal == "position" else \
                    self._startups(arm.name, self.goal)
            except Exception as e:  # noqa: BLE001 - an arm without a controller still shows
                log.warning("no startup controller for %s (%s goals): %s", arm.name, self.goal, e)
                self._opened[key] = (None, "none (train one)")
        if key in self._opened:
            start, note = self._opened[key]
        else:
            start, note = self._startup, "startup controller"
        if start is None and key in self._opened:  # the arm has none: its own words (app/any_robot.py NO_NETWORK)
            pass
        elif start is None or not made_for(start, arm) or \
                ("pose" if getattr(start, "goal", "position") == "pose" else "position") != self.goal:
            start, note = None, "none (train one)"
        self.show(start, note)

    def set_goal(self, goal: str) -> str | None:
        """Position or pose goals for every tab (refused while a run is going, and pose goals on an
        arm that takes none: app/tab/posegoal.py); the arm's startup controller for them is shown."""
        from app.tab.posegoal import GOALS, pose_refusal

        if goal not in GOALS:
            return f"refused: the goal is one of {', '.join(GOALS)}, not {goal!r}"
        if goal == self.goal:
            return None
        if self.running:
            return f"refused: a {self.runner.config.robot} run is going; stop it before changing the goal"
        if goal == "pose" and (why := pose_refusal(self.arm.name)) is not None:
            return f"refused: {why}"
        with self._lock:
            self.goal = goal
            self.replaying = False
            self.show(None, "none")
            self._show_startup()
        return None

    def set_robot(self, name: str) -> str | None:
        if name == self.arm.name:
            return None
        if self.running:
            return f"refused: a {self.runner.config.robot} run is going; stop it before changing the robot"
        try:
            arm = robots.load(name)
        except Exception as e:  # an unknown name or a broken model: keep the current arm
            return f"refused: {e}"
        from app.tab.posegoal import pose_refusal

        with self._lock:
            if self.goal == "pose" and pose_refusal(name) is not None:
                self.goal = "position"  # the arm takes no pose goals: the panel's Goal follows
            self.show(None, "none", arm)
            self._show_startup()
            if arm.name not in self.opened_robots:
                self.opened_robots.append(arm.name)
        return None

    # ------------------------------------------------------------------ training
    def start(self, config: lab.TrainConfig, partner: lab.TrainConfig | None = None) -> str | None:
        """Start a run; with `partner`, a race: a second run on the same arm and the same training
        goals (its robot, targets and goal seed are config's), each in its own worker process."""
        with self._lock:
            if self.running:
                return f"refused: a run is going (generation {len(self._history)}); stop it first"
            for c in (config, partner):
                if c is not None and (why := limits_refusal(c, self.limits)) is not None:
                    return f"refused: {why}"
            if partner is not None and (partner.robot, partner.targets, partner.goal_seed, partner.resample) != \
                    (config.robot, config.targets, config.goal_seed, config.resample):
                return "refused: a race runs on the same arm and the same goals (robot, targets, goal seed)"
            if config.robot != self.arm.name:
                msg = self.set_robot(config.robot)
                if msg:
                    return msg
            goal = getattr(config, "goal", "position")
            if partner is not None and getattr(partner, "goal", "position") != goal:
                return "refused: a race runs both runs on the same goals (position or pose)"
            if goal != self.goal and (msg := self.set_goal(goal)):
                return msg
            try:
                runners = [ProcessRunner(c, history_limit=HISTORY_POINTS) for c in (config, partner) if c is not None]
            except Exception as e:
                return f"refused: cannot build this run: {e}"
            recordings = [self._record(r) for r in runners]
            self.notice = None
            shown = self._shown  # a tree's run ends no worse than what it replaces (kept_the_better)
            self._replaced = (shown.controller, shown.source) if shown.arm.is_tree and shown.controller is not None \
                and shown.arm.name == config.robot and self.goal == goal and not self.replaying else None
            self._clear_history()
            self.runner, self.recording, self.replaying = runners[0], recordings[0], False
            self.track = RunTrack(lab.methods.get(config.method))
            self.partner = None
            if partner is not None:
                self.partner = Partner(runners[1], recordings[1], RunTrack(lab.methods.get(partner.method)))
            for r, rec, is_partner in zip(runners, recordings, (False, True)):
                r.subscribe(_Tap(self, r, rec, partner=is_partner))
                r.set_speed(self._speed_of(r))
            for r in runners:
                r.start()
            return None

    def _record(self, runner) -> str | None:
        if self.recorder is None:
            return None
        try:
            path = getattr(self.recorder(runner), "path", None)
            return str(path) if path else None
        except Exception as e:  # a run without a recording is still a run
            log.warning("no recording for this run: %s", e)
            return None

    def _going(self) -> list:
        return [r for r in self.runners() if r.state in ("running", "paused")]

    def pause(self) -> str | None:
        going = [r for r in self._going() if r.state == "running"]
        if not going:
            return "refused: no run is going"
        for r in going:
            r.pause()

    def resume(self) -> str | None:
        paused = [r for r in self._going() if r.state == "paused"]
        if not paused:
            return "refused: no run is paused"
        for r in paused:
            r.resume()

    def step(self) -> str | None:
        """Exactly one more generation of each paused run (refused unless every run going is paused)."""
        going = self._going()
        if not going:
            return "refused: no run is going (Step advances a paused run by one generation)"
        if any(r.state != "paused" for r in going):
            return "refused: Step works while the run is paused (press Pause first)"
        for r in going:
            r.step()

    def set_speed(self, generations_per_second: float | None) -> str | None:
        """Cap every run without a time budget at this many generations a second (None: no cap), now
        and for later runs."""
        try:
            speed_period(generations_per_second)
        except ValueError as e:
            return f"refused: {e}"
        self.speed = generations_per_second
        for r in self.runners():
            r.set_speed(self._speed_of(r))

    def _speed_of(self, runner) -> float | None:
        """The cap a run goes at: the Speed menu's, except for a run with a time budget, which goes at
        full speed (its budget is its pace: capped, it would train less than its budget allows)."""
        return None if runner.config.seconds is not None else self.speed

    def stop(self) -> str | None:
        """Stop every run going. A worker that has not ended its run stop_grace s after Stop is killed:
        its run ends "stopped" with the generations it had sent (the notebook entry's error says it
        was killed), and `notice` says so to the class."""
        going = self._going()
        if not going:
            return "refused: no run is going"
        for r in going:
            r.stop(wait=False)
        deadline = time.monotonic() + self.stop_grace
        for r in going:
            r.join(max(0.0, deadline - time.monotonic()))
        silent = [r for r in going if not r.done]
        partner = self.partner.runner if self.partner is not None else None
        for r in silent:
            r.kill(f"the training process did not answer Stop within {self.stop_grace:g} s and was killed")
        for r in silent:
            r.join(10)
        if silent:
            self.notice = "; ".join(
                f"the {'partner' if r is partner else 'run'}'s training process ({run_label(r.config)}) did not "
                f"answer Stop within {self.stop_grace:g} s and was killed; its entry keeps the "
                f"{r.snapshot().generation} generations it had sent" for r in silent)
            self.notice = self.notice[0].upper() + self.notice[1:] + "."

    def reset(self, untrained: lab.TrainConfig | None = None) -> None:
        """Stop any run and clear the progress; show the startup controller again or, given a
        config, the untrained network that config's run starts from (the best of its first
        generation, the same controller its first event will show)."""
        self.notice = None
        if self.running:
            self.stop()  # a worker that does not answer is killed: `notice` says so
        first = self.untrained(untrained) if untrained is not None else None
        with self._lock:
            self.runner, self.recording, self.partner, self.track = None, None, None, None
            self._clear_history()
            self.replaying = False
            if first is not None and untrained.robot == self.arm.name:
                self.show(first, f"untrained (generation 1 of {run_label(untrained)})")
            else:
                self._show_startup()

    @staticmethod
    def untrained(config: lab.TrainConfig):
        """The best controller of config's first generation (None when it cannot be made)."""
        try:
            first = lab.TrainConfig.from_dict({**config.to_dict(), "generations": 1})
            return lab.Runner(first).run().controller
        except Exception:  # noqa: BLE001 - the startup controller is shown instead
            log.exception("cannot make the untrained network of %s", config)
            return None

    def _clear_history(self) -> None:
        self._history = History(HISTORY_POINTS)
        self._evals, self._seconds = 0, 0.0

    def _on_generation(self, runner: ProcessRunner, event: lab.GenerationEvent) -> None:
        with self._lock:
            if runner is not self.runner:  # a run that was reset away
                return
            self._history.append(event.best, event.median)
            self._evals, self._seconds = event.evaluations, event.seconds
            if self.track is not None:
                self.track.add(event)
            if (event.improved or event.index == 0) and not self.replaying:
                self._version += 1
                self._shown = Shown(self._shown.arm, event.controller,
                                    f"run {runner.run_id[:6]}, generation {event.index + 1}", self._version, self.goal)

    def _on_partner_generation(self, runner: ProcessRunner, event: lab.GenerationEvent) -> None:
        with self._lock:
            partner = self.partner
            if partner is None or runner is not partner.runner:
                return
            partner.track.add(event)
            if event.improved or event.index == 0:
                partner.controller, partner.version = event.controller, partner.version + 1

    def _on_end(self, runner, summary, started, recording) -> None:
        """The run's notebook entry. A write that fails (the file locked by another program, a full
        disk) loses nothing: the notebook lists the entry and retries it (the Runs panel says so).
        The end of the run waits END_WRITE_WAIT s at most for a lock: Stop waits for this end."""
        try:
            entry = entry_from_summary(summary, started, recording)
        except Exception:  # noqa: BLE001 - a bug of ours: said, and the app goes on
            log.exception("could not make the notebook entry of run %s", summary.run_id)
            return
        try:
            self.notebook.add(entry, timeout=END_WRITE_WAIT)
        except Exception:  # noqa: BLE001 - an entry that is not JSON (a bug of ours)
            log.exception("could not write the notebook entry of run %s", summary.run_id)
        self.kept_the_better(runner, summary)

    def kept_the_better(self, runner, summary) -> bool:
        """A tree's run that ends worse than the controller it replaced on the arms (a humanoid's
        shipped network, which 30 s of training do not match): that controller is shown again, and
        `notice` says so; the run stays in the notebook. Both are measured on the run's own held-out
        goals (lab.running.runner.build_problem: what its summary's test_mse is). Whether it kept it."""
        with self._lock:
            replaced = self._replaced if runner is self.runner else None
        if replaced is None or summary.controller is None or summary.state == "failed":
            return False
        controller, source = replaced
        try:
            from lab.running.runner import build_problem

            problem = build_problem(summary.config)
            before = float(problem.controller_mse(controller, problem.test_goals))
        except Exception:  # noqa: BLE001 - the run's own controller stays shown
            log.exception("cannot compare run %s with the controller it replaced", summary.run_id)
            return False
        after = float(summary.test_mse)
        if not after > before:
            return False
        with self._lock:
            if runner is not self.runner or self.replaying or self._shown.arm.name != summary.config.robot:
                return False  # reset, replaced or replaying since: leave the arms alone
            self.show(controller, source)
            self.notice = (f"The run ended at held-out MSE {after:.3g}, worse than the controller it replaced "
                           f"({before:.3g}): the robot shows that one again ({source}). The run is in the "
                           "notebook (Runs), where it can be shown.")
        return True


