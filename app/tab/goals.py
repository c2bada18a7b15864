"""One browser tab: its own goal markers, the arms at the controller's pose, the IK ghost.

Each goal is a transform gizmo per end effector (one on a serial arm; a foot, a hand, a fingertip
each on a tree), constrained to the task axes (the plane z = 0 for the planar arm), an arm drawn
at q = controller(goal) (the first solid, the others translucent) and a label with the
end-effector error ||goal - reach(q)|| (on a tree the worst effector's, beside the marker dragged
last). The first goal also has two ghost arms:
the network's answer refined by one closed-form turn of the base joint and at most 3 Gauss-Newton
steps (robots.ik.refine: the practical use of a learned IK), and damped least squares from the rest pose (robots.ik.dls_ik), each with
its error and time.

In pose mode (app/tab/posegoal.py) each gizmo also turns: the goal is the 4 x 4 tool frame of its
position and orientation, the arm shows a pose controller's answer for it, the label gives the
position error in mm and the angle error in degrees, and the refined ghost is lab.solve's compiled
solver (robots.pose_solve) from the network's answers (and the ghost's last answer), then random
restarts, at most POSE_SOLVE_SECONDS; the blue ghost robots.ik.dls_pose_ik.

A marker update moves its arm at once, in the callback (in viser's event loop: one network
forward pass, one forward kinematics, nq pose messages, then a flush); the IK query runs in its own thread, at
most 10 times a second per tab; `refresh` (called by the render loop) redraws all goals when
the controller changes, at most 5 times a second. A lock per tab keeps them apart.
Poses go out through viser_private.set_pose inside client.atomic() (see there: viser's setters cost
most of the server's time while dragging).
"""

from __future__ import annotations

import asyncio
import dataclasses
import threading
import time
from collections import deque

import numpy as np

import lab
import robots
from lab.problem.controllers import proposals
from lab.running.decimation import DISPLAY_SEED, display_goal
from lab.recording.population import ramp
from robots.ik import RefineResult, dls_ik, dls_pose_ik, refine

from app.tab import posegoal

from app.tab.extras import GoalExtras, TabExtras
from app.training.live import swatch
from app.tab.ikworker import IK_WORKER
from app.tab.scene import MAX_GOAL_DOTS, ArmView, frame_workspace, to_world
from app.viser_private import set_pose

MAX_GOALS = 8
START_HINT = "**Start** trains a new one."  # a viewer's tab says its own button instead (app/panels/my_run.py)
INTRO = "**Drag the arrows** to move the goal: the arm follows a neural network. **Start** trains a new one."
INTRO_POSE = "**Drag the arrows and rings**: the tool follows a neural network. **Start** trains a new one."
# the page shows the lab once this element, first in the tab's intro, is there (app/server.py PAGE_HEAD)
READY_ID = "lab-ready"
READY = f'<span id="{READY_ID}"></span>'
INTRO_TREE = ("**Drag the arrows** of a foot, a hand or a fingertip: the whole robot follows a neural network. "
              "**Start** trains a new one.")


def about(arm: robots.Arm, config) -> str:
    """The About text for `arm` with `config` (the current run's on this arm, else the panel's defaults
    for it: lab.TrainConfig.preset): its network's size (a method that grows its network: where it
    starts), its number of fixed training goals and the unit of its lengths."""
    method = lab.methods.get(config.method)
    if method.controller == "mlp":
        network = f"A tanh network ({config.hidden} hidden units)"
    else:
        network = f"A tanh network that {method.label} grows (from {config.hidden} hidden units)"
    if arm.is_tree:
        maps = f"a goal, a point for each of its {arm.n_effectors} end effectors, to the robot's {arm.nq} joint angles"
    else:
        maps = f"a goal to the arm's {arm.nq} joint angles"
    unit = "mm" if robots.in_metres(arm.name) else "the paper's units"
    shown = max(1, MAX_GOAL_DOTS // arm.n_effectors)
    red = "red" if config.targets <= shown else f"{shown:,} of them in red"  # app/tab/scene.py shown_goals
    return (f"{network} maps {maps}, never shown a right answer: its fitness "
            f"is the {'robot' if arm.is_tree else 'arm'}'s error over {config.targets:,} fixed goals ({red}), through "
            f"forward kinematics. Lengths in {unit}.")


MORE = (
    "The fitness is the mean squared distance between the training goals and where the network's joint "
    "angles put the end effector. **CMA-ES** evolves the weights of a fixed network, **NEAT** its wiring "
    "and weights together, and **Gradient (Adam)**, the baseline the paper argues against, follows the "
    "gradient through the arm's Jacobian. Goals the network never trained on measure how well it "
    "generalizes. Reset shows an untrained network; *Trained network* the one trained for this arm.  \n"
    "J. A. Martín H., J. de Lope and M. Santos (2009), *A method to learn the inverse kinematics of "
    "multi-link robots by evolving neuro-controllers*.")
POPULATION_KEY = ("<small>Each candidate of the generation at the goal, coloured by its training error:"
                  + "".join(swatch(c, "") for c in ramp([0.0, 0.25, 0.5, 0.75, 1.0]))
                  + " from the best (dark purple) to the worst (yellow).</small>")
GHOST = (120, 200, 255)  # damped least squares from the rest pose
REFINED = (255, 170, 60)  # the network's answer refined
REFINE_STEPS = 3
# a pose goal's refined ghost: lab.solve's compiled solver (robots.pose_solve) from the network's answers
# and the ghost's last answer (a drag moves a little), then restarts: exact on 99.9-100 % of poses in
# 0.1-0.2 ms on average (docs/results/pose.md), at most this long, in the IK thread
POSE_SOLVE_SECONDS = 0.01
POSE_DLS_SECONDS = 0.05  # s: the blue ghost's damped least squares with restarts, at most this long
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
REDRAW_PERIOD = 0.2  # s: redraws caused by training (and table updates) at most 5 times a second
SAME_POSE = 1e-4  # rad (or length): a redraw moves an arm only when a joint changes more than this


def fmt_len(arm: robots.Arm, d: float) -> str:
    """A length in the arm's units: metres as mm (below 1 mm in µm, so a refined answer's 0.01 mm
    does not read as 0.0 or 0.1 mm), the paper's lengths as they are, followed by "units"."""
    if not np.isfinite(d):
        return "∞"
    if not robots.in_metres(arm.name):  # the paper's arms and the snakes: the paper's length units
        return f"{d:.3f} units" if d >= 1e-3 else f"{d:.1e} units"
    return f"{1000 * d:.1f} mm" if d >= 1e-3 else f"{1e6 * d:.0f} µm"


def marker_name(index: int, effector: int = 0) -> str:
    """The scene node of goal `index`'s marker for one end effector: /tab/goal{index}/marker for the
    first (a serial arm's only one), /tab/goal{index}/marker{effector} for the others of a tree."""
    return f"/tab/goal{index}/marker{effector or ''}"


def effector_errors(arm: robots.Arm, q, goal) -> np.ndarray:
    """(E,) each end effector's distance ||goal - reach(q)|| (one entry on a serial arm)."""
    return np.atleast_1d(np.linalg.norm(arm.reach(q) - goal, axis=-1))


class GoalView(GoalExtras):
    def __init__(self, tab: "TabSession", index: int, position: np.ndarray):
        """position: the goal's 3D point (3,), or one per end effector (E, 3) on a tree; in pose mode
        (tab.goal_kind "pose") its 4 x 4 tool frame (or a 3D point: the gizmo then starts unturned)."""
        self.tab, self.index = tab, index
        arm, scene, ws = tab.arm, tab.client.scene, tab.ws
        base = f"/tab/goal{index}"
        self.pose_mode = getattr(tab, "goal_kind", "position") == "pose"
        position = np.asarray(position, float)
        wxyz = IDENTITY
        if self.pose_mode and position.shape == (4, 4):
            wxyz, position = posegoal.matrix_to_wxyz(position[:3, :3]), position[:3, 3]
        points = position.reshape(-1, 3)
        if len(points) != arm.n_effectors:
            raise ValueError(f"{arm.name}: a goal is {arm.n_effectors} point(s) (one per end effector), "
                             f"got {len(points)}")
        self.markers = [scene.add_transform_controls(
            marker_name(index, e), scale=ws["gizmo"], position=p, wxyz=wxyz, disable_rotations=not self.pose_mode,
            active_axes=tuple(k in arm.task_axes for k in range(3)), translation_limits=ws["limits"][e],
            depth_test=False) for e, p in enumerate(points)]
        self.marker = self.markers[0]
        self.dragged = 0  # the effector whose marker moved last: the label stands beside it
        self.arm_view = ArmView(scene, arm, f"{base}/arm", opacity=None if index == 0 else 0.35)
        # the label stands up and to the left of the marker (label_offset): clear of the panel on the right
        self.label = scene.add_label(f"{base}/label", "", position=points[0], anchor="bottom-right")
        self.ghost = ArmView(scene, arm, f"{base}/ik", opacity=0.3, tint=GHOST) if index == 0 else None
        self.refined = ArmView(scene, arm, f"{base}/refined", opacity=0.45, tint=REFINED) if index == 0 else None
        self.cloud = self.faint = None  # the population: end-effector points, faint arms
        self.partner_view = None  # a race partner's arm (goal 1 only), made when a race starts
        self.partner_error = self.partner_angle = np.nan
        self.error, self.net_s = np.nan, np.nan  # error: the worst effector's
        self.errors = np.full(arm.n_effectors, np.nan)  # each effector's
        self.angle = np.nan  # pose mode: the network's answer's angle error [rad]
        self.ik = None
        self.ik_error = np.nan  # the DLS answer's worst effector error
        self.ik_angle = np.nan  # pose mode: its angle error [rad]
        self.seeded = None  # (worst effector error, steps, seconds[, angle]) of the network's answer refined
        for e, marker in enumerate(self.markers):
            marker.on_update(self._callback(e))

    def _callback(self, effector: int):
        async def moved(event) -> None:
            await self._on_update(event, effector)
        return moved

    @property
    def goal(self) -> np.ndarray:
        """The goal in task coordinates: (len(task_axes),), or (E, len(task_axes)) on a tree."""
        axes = list(self.tab.arm.task_axes)
        if len(self.markers) == 1:
            return np.asarray(self.marker.position, float)[axes]
        return np.array([m.position for m in self.markers], float)[:, axes]

    @property
    def pose(self) -> np.ndarray:
        """The goal's 4 x 4 tool frame: the gizmo's position and orientation (pose mode)."""
        return posegoal.gizmo_pose(self.marker.position, self.marker.wxyz)

    @property
    def query(self) -> np.ndarray:
        """What the controller answers: the goal (position mode) or its pose (pose mode)."""
        return self.pose if self.pose_mode else self.goal

    def errors_of(self, q, query=None) -> tuple[np.ndarray, float]:
        """(each effector's distance, angle error [rad] or NaN) of joints q for this goal (or `query`)."""
        query = self.query if query is None else query
        if self.pose_mode:
            d, a = posegoal.errors(self.tab.arm, query, q)
            return np.array([d]), a
        return effector_errors(self.tab.arm, q, query), np.nan

    def error_text(self, error: float, angle: float) -> str:
        """A distance in the arm's units, and in pose mode the angle in degrees."""
        text = fmt_len(self.tab.arm, error)
        return f"{text}, {posegoal.fmt_angle(angle)}" if self.pose_mode else text

    async def _on_update(self, _event, effector: int = 0) -> None:
        """Runs in viser's event loop, which saves the hop to its thread pool (slow while training
        keeps the cores busy: docs/results/app-speed.md); when a redraw holds the tab's lock, the
        update goes to the thread pool rather than block the loop."""
        t0 = time.perf_counter()
        self.dragged = effector
        if self.tab.lock.acquire(blocking=False):
            try:
                self._move(t0)
            finally:
                self.tab.lock.release()
        else:
            await asyncio.get_running_loop().run_in_executor(None, self._move_locked, t0)

    def _move_locked(self, t0: float) -> None:
        with self.tab.lock:
            self._move(t0)

    def _move(self, t0: float) -> None:
        if self.tab.closed or all(g is not self for g in self.tab.goals):
            return
        self.update(self.tab.controller())
        if self.partner_view is not None:
            self.update_partner(self.tab.partner_controller())
        self.tab.client.flush()
        self.tab.latency.append((self.tab.client.client_id, t0, time.perf_counter()))
        if self.ghost is not None:
            self.tab.request_ik()
        self.tab.table_dirty = True

    def update(self, controller, moved: bool = True) -> None:
        """Arm at controller(goal) and its error; the rest pose when there is no controller.
        moved=False (a redraw for a new controller): poses that change less than SAME_POSE
        in every joint are not sent again."""
        arm, query = self.tab.arm, self.query
        if controller is None:
            q, self.net_s = arm.rest, np.nan
            self.errors, self.angle = np.full(arm.n_effectors, np.nan), np.nan
        else:
            t = time.perf_counter()
            q = controller(query[None])[0]
            self.net_s = time.perf_counter() - t
            self.errors, self.angle = self.errors_of(q, query)
        self.error = float(self.errors.max())
        with self.tab.client.atomic():  # one wake-up of the sender for all the messages
            if moved or self.arm_view.q is None or np.max(np.abs(q - self.arm_view.q)) > SAME_POSE:
                self.arm_view.set_q(q)
            if moved:
                at = np.asarray(self.markers[min(self.dragged, len(self.markers) - 1)].position)
                set_pose(self.label, at + self.tab.ws["label_offset"], IDENTITY)
            text = "no controller" if controller is None else f"net {self.error_text(self.error, self.angle)}" + (
                f" (worst of {len(self.markers)})" if len(self.markers) > 1 else "")
            if text != self.label.text:
                self.label.text = text

    def set_ik(self, result, seeded=None, goal=None) -> None:
        """The DLS answer (robots.ik.IKResult), and the refined network answer (RefineResult or None),
        for `goal` (the goal they were solved for; by default the marker's); their errors as the
        network's: the worst effector's distance."""
        goal = self.query if goal is None else goal
        self.ik = result
        errors, self.ik_angle = self.errors_of(result.q, goal)
        self.ik_error = float(errors.max())
        with self.tab.client.atomic():
            self.ghost.set_q(result.q)
            self.ghost.visible = True
            if seeded is not None:
                errors, angle = self.errors_of(seeded.q[0], goal)
                self.seeded = (float(errors.max()), int(seeded.steps[0]), seeded.seconds, angle)
                self.refined.set_q(seeded.q[0])
            else:
                self.seeded = None
            self.refined.visible = seeded is not None

    def remove(self) -> None:
        for view in (self.arm_view, self.ghost, self.refined, self.partner_view):
            if view is not None:
                view.remove()
        for h in (self.cloud, self.faint):
            if h is not None:
                h.remove()
        for marker in self.markers:
            marker.remove()
        self.label.remove()


class TabSession(TabExtras):
    """Goals and arms of one client (tab); `app` gives the shared state and the shown controller."""

    def __init__(self, client, state, latency: deque | None = None):
        """latency: where to append (client id, callback start, pose flushed) [perf_counter s]
        for every marker update."""
        self.client, self.state = client, state
        self.lock = threading.RLock()
        self.closed = False
        self.latency = deque(maxlen=10_000) if latency is None else latency
        self.goals: list[GoalView] = []
        gui = client.gui
        # what the lab is and what to do, above the shared panels (each tab its own copy)
        self.intro = gui.add_markdown(INTRO, order=0)  # build() says what to drag on a tree
        with gui.add_folder("About this lab", order=0.5):
            self.about = gui.add_markdown("")  # build() says it for the arm
        self.folder = gui.add_folder("Goals and what to draw (this tab)", order=2)
        with self.folder:
            self.add_button = gui.add_button("Add goal")  # no icons: viser reads each from a zip file
            self.remove_button = gui.add_button("Remove goal")
            self.show_population = gui.add_checkbox(
                "Population", True, hint="every candidate of the current generation at its reach for each goal")
            self.faint_arms = gui.add_checkbox("Population as faint arms", True,
                                               hint="each candidate drawn as a whole arm, not only its reach")
            self.by_species = gui.add_checkbox("Colour by species", False,
                                               hint="for a method with species (NEAT); else by training MSE")
            self.population_key = gui.add_html(POPULATION_KEY)
            self.show_ik = gui.add_checkbox("Classical IK beside it", False,
                                            hint="for goal 1: orange, the network's answer made exact by at most 3 "
                                                 "Gauss-Newton steps; blue, damped least squares from the rest pose")
            self.table = gui.add_markdown("")
            with gui.add_folder("Details: errors and timings", expand_by_default=False):
                self.details = gui.add_markdown("")
        with gui.add_folder("Share this lesson", order=3, expand_by_default=False):
            self.lesson = gui.add_markdown("")
        self.page_url = ""
        for toggle in (self.show_population, self.faint_arms, self.by_species):
            toggle.on_update(lambda e: self._population_changed())
        self.add_button.on_click(lambda e: self.add_goal())
        self.remove_button.on_click(lambda e: self.remove_goal())
        self.show_ik.on_update(lambda e: self._toggle_ik())
        self.version = -1
        self.own = None  # the tab's own replay (app.training.state.Shown), if any
        self.table_dirty = False
        self.last_ik = self.last_draw = self.last_population = 0.0
        # redraws caused by training, at most every `period` s: the render loop lengthens it for a hall
        # of viewers (LabApp: all viewer tabs together redraw at most HALL_REDRAWS times a second)
        self.period = REDRAW_PERIOD
        self.presenter = True
        self.population_drawn = None  # (population version, goals, toggles) last drawn
        self.partner_version = None
        self.build()

    @property
    def shown(self):
        """What this tab's arms show: the tab's own replay (app/tab/replay.py) while it has one for the
        shared arm, else the shared state's."""
        own = self.own
        if own is not None and own.arm is self.state.arm and own.goal == self.state.shown.goal:
            return own
        return self.state.shown

    def controller(self):
        shown = self.shown
        return shown.controller if shown.arm is self.arm and shown.goal == self.goal_kind else None

    def markers(self):
        return [m for g in self.goals for m in g.markers]

    def build(self) -> None:
        """(Re)build the goals for the state's current arm; camera framed on its workspace."""
        with self.lock:
            for g in self.goals:
                g.remove()
            self.goals = []
            self.arm = self.state.arm
            self.goal_kind = self.state.shown.goal  # "position" or "pose": the goals' kind
            self.ws = frame_workspace(self.arm)
            intro = READY + (INTRO_TREE if self.arm.is_tree else INTRO_POSE if self.goal_kind == "pose" else INTRO)
            intro = intro.replace(START_HINT, getattr(self, "start_hint", START_HINT))  # a viewer's: Start my run
            if self.intro.content != intro:
                self.intro.content = intro
            self.write_about()
            self.client.camera.position = self.ws["camera"]
            self.client.camera.look_at = self.ws["center"]
            self.add_goal(self._default_goal(0))

    def write_about(self) -> None:
        """The About text of the run whose goals the scene shows in red (the current run on this
        arm, else the one the panel would start: app.server's training_goals)."""
        r = self.state.runner
        if self.__dict__.get("_about_of") == (r, self.arm):  # said already: a redraw of the same run
            return
        self._about_of = (r, self.arm)
        config = r.config if r is not None and r.problem.arm is self.arm else lab.TrainConfig.preset(robot=self.arm.name)
        text = about(self.arm, config)
        if self.about.content != text:
            self.about.content = text

    def _default_goal(self, k: int) -> np.ndarray:
        """Goal k's starting place: the first where the runs draw the population (display_goal: on a
        tree, where its effectors are at rest, so a humanoid stands), the others sampled."""
        if self.goal_kind == "pose":  # a reachable pose: the tool frame of the joints behind that goal
            return posegoal.default_pose(self.arm, k if k else 0, seed=7 if k else DISPLAY_SEED)
        goal = display_goal(self.arm) if k == 0 else self.arm.sample_goals(k + 1, seed=7)[k]
        return to_world(self.arm, goal)

    def add_goal(self, position=None) -> str | None:
        with self.lock:
            if len(self.goals) >= MAX_GOALS:
                msg = f"refused: at most {MAX_GOALS} goals per tab"
                self.client.add_notification("Refused", msg, auto_close_seconds=5, color="red")
                return msg
            k = len(self.goals)
            goal = GoalView(self, k, self._default_goal(k) if position is None else np.asarray(position, float))
            self.goals.append(goal)
            goal.update(self.controller())
            if goal.ghost is not None:
                goal.ghost.visible = goal.refined.visible = False
                self.request_ik()
            self.write_table()
        return None

    def remove_goal(self) -> str | None:
        with self.lock:
            if len(self.goals) <= 1:
                msg = "refused: the last goal stays (add another one first)"
                self.client.add_notification("Refused", msg, auto_close_seconds=5, color="red")
                return msg
            self.goals.pop().remove()
            self.write_table()
        return None

    def request_ik(self) -> None:
        """Solve IK for the first goal in the IK thread (app/tab/ikworker.py)."""
        if not self.closed and self.show_ik.value:
            IK_WORKER.request(self)

    def solve_ik(self) -> None:
        self.last_ik = time.monotonic()
        with self.lock:
            goal = self.goals[0] if self.goals and not self.closed else None
            arm, target = self.arm, goal.query if goal is not None else None
            controller = self.controller()
            last = goal.refined.q if goal is not None and goal.seeded is not None else None
        if goal is None:
            return
        if goal.pose_mode:
            result = dls_pose_ik(arm, target, seconds=POSE_DLS_SECONDS)
        else:
            result = dls_ik(arm, target)
        seeded = None
        if controller is not None:  # the network's answer, made exact (timed with its forward pass)
            t0 = time.perf_counter()
            if goal.pose_mode:  # the network's answers, then the ghost's last one (a drag moves a little)
                own = controller.proposals(target[None]) if hasattr(controller, "proposals") else \
                    np.asarray(controller(target[None]), dtype=np.float64)[None]
                q0 = own if last is None else np.concatenate([own, np.asarray(last, float)[None, None]])
                s = lab.solve(None, arm, target[None], q0=q0, seconds=POSE_SOLVE_SECONDS)
                seeded = RefineResult(s.q, s.error, s.steps, s.seconds, angle=s.angle, tol=s.tol, angle_tol=s.angle_tol)
            else:
                seeded = refine(arm, target[None], proposals(controller, target[None]), steps=REFINE_STEPS)
            seeded = dataclasses.replace(seeded, seconds=time.perf_counter() - t0)
        with self.lock:
            if self.goals and self.goals[0] is goal and not self.closed:
                goal.set_ik(result, seeded, target)
                self.client.flush()
                self.table_dirty = True
                if not np.allclose(goal.query, target):
                    self.request_ik()  # the marker moved while solving: solve where it is now

    def _toggle_ik(self) -> None:
        with self.lock:
            g = self.goals[0] if self.goals else None
            if g is not None and g.ghost is not None:
                g.ghost.visible = g.refined.visible = False
                self.request_ik()
                self.write_table()

    def refresh(self) -> bool:
        """Redraw every goal with the shown controller when it changed (at most every `period`
        while training; at once for another arm); the table when stale; the population and a race
        partner's arm (refresh_population). All in one frame to the tab (one atomic block). True
        when it sent anything."""
        with self.client.atomic():
            return self._refresh()

    def _refresh(self) -> bool:
        shown, now = self.shown, time.monotonic()
        drew = self.refresh_population(now) if shown.arm is self.arm else False
        if now - self.last_draw < self.period and shown.arm is self.arm:
            return drew
        if shown.version == self.version:
            if self.table_dirty:
                with self.lock:
                    self.table_dirty = False
                    self.write_table()
                self.last_draw = now
                return True
            return drew
        with self.lock:
            if self.closed:
                return drew
            if shown.arm is not self.arm or shown.goal != self.goal_kind:
                self.build()
            controller = shown.controller if shown.arm is self.arm and shown.goal == self.goal_kind else None
            for g in self.goals:
                g.update(controller, moved=False)
            self.write_about()  # a new run may train another method or on other goals
            self.version = shown.version  # after the poses: a reader that sees it sees them
            self.write_table(shown)
            self.table_dirty = False
        self.last_draw = now
        return True

    def write_table(self, shown=None) -> None:
        """The error of the network's answer at each goal (a tree's: its worst effector's, each
        effector's in the details fold); the classical solvers' errors and the timings in the
        details fold."""
        shown, arm = shown or self.shown, self.arm
        errors = ", ".join(f"goal {g.index + 1}: **{g.error_text(g.error, g.angle)}**" for g in self.goals)
        g0_partner = (self.goals[0] if self.goals and self.goals[0].partner_view is not None
                      and self.goals[0].partner_view.visible else None)
        partner = (f"; race partner (purple), goal 1: "
                   f"{g0_partner.error_text(g0_partner.partner_error, g0_partner.partner_angle)}" if g0_partner else "")
        what = f"the worst of {arm.n_effectors} effectors" if arm.is_tree else (
            "the goal's pose (position, angle)" if self.goal_kind == "pose" else "the goal")
        self.table.content = f"Network: {shown.source}  \nDistance to {what}: {errors}{partner}"
        rows = ["| goal | network | refined | DLS |", "|---|---|---|---|"]
        show = self.show_ik.value
        for g in self.goals:
            first = g.index == 0 and show
            ik = g.error_text(g.ik_error, g.ik_angle) if first and g.ik is not None else ""
            seeded = g.error_text(g.seeded[0], g.seeded[3]) if first and g.seeded is not None else ""
            rows.append(f"| {g.index + 1} | {g.error_text(g.error, g.angle)} | {seeded} | {ik} |")
        how = (f"at most {REFINE_STEPS} Gauss-Newton steps" if self.goal_kind != "pose" else
               f"compiled Levenberg-Marquardt steps from it, then from random joint vectors (at most "
               f"{1e3 * POSE_SOLVE_SECONDS:.0f} ms)")
        lines = [f"Refined: the network's answer made exact by {how}; DLS: damped "
                 "least squares from the rest pose (turn on *Classical IK beside it*)."
                 + (" On this robot each is the worst of its effectors' distances." if arm.is_tree else ""),
                 "", *rows]
        if arm.is_tree:  # each effector's distance under the network's answer
            lines += ["", "| goal | " + " | ".join(arm.effectors) + " |", "|---" * (1 + arm.n_effectors) + "|"]
            lines += [f"| {g.index + 1} | " + " | ".join(fmt_len(arm, e) for e in g.errors) + " |" for g in self.goals]
        g0 = self.goals[0] if self.goals else None
        if g0 is not None and g0.ik is not None and show and np.isfinite(g0.net_s):
            line = f"Goal 1: network, one forward pass {1e6 * g0.net_s:.0f} µs"
            if g0.seeded is not None:
                line += f"; refined, {g0.seeded[1]} steps, {1e3 * g0.seeded[2]:.2f} ms"
            line += (f"; DLS from rest, {g0.ik.iterations} iterations, {1e3 * g0.ik.seconds:.2f} ms"
                     f"{'' if g0.ik.converged else ' (not converged)'}")
            lines += ["", line]
        self.details.content = "\n".join(lines)

    def close(self) -> None:
        with self.lock:
            self.closed = True
