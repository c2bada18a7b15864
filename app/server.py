"""`LabApp`: the viser server, the shared scene and panels, one `TabSession` per tab, the render loop.

    app = LabApp(host="127.0.0.1", port=8080)   # viser takes the next port when one is taken
    print(app.url)                             # the URL really served
    app.stop()

Shared by all tabs (server.scene / server.gui): the floor grid, the training goals, the error
map, the training panel, the network drawing and the runs list; one training run at a time.
Per tab (client.scene / client.gui): goal markers, arms and the IK ghost. Callbacks run in
viser's thread pool, training in a worker process (lab.running.worker.ProcessRunner) whose events a
reader thread takes in; the render loop (30 Hz) redraws tabs when the shown controller changes
and refreshes progress, plot, map and network.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import math
import os
import sys
import threading
import time
import warnings
import weakref
from collections import deque

import numpy as np
import viser

import lab
import lab.running.worker as lab_worker
from lab.recording.service import WriterService

from app import any_robot
from app.classroom.access import Access, is_loopback
from app.classroom.class_runs import ClassRuns
from app.classroom.lesson import lesson_link, lesson_params, open_lesson
from app.classroom.limits import limits_for
from app.failures import FailureLog
from app.panels.class_board import ClassBoard
from app.panels.my_run import MyRunPanel
from app.panels.runs import RunsPanel
from app.panels.train import TrainingPanel, budget_for, notify
from app.panels.views import error_map, has_map, map_grid, map_key, map_legend, network_svg
from app.tab.goals import MORE, READY_ID, REDRAW_PERIOD, TabSession, fmt_len
from app.tab.phone import fold_on_phone, follow_portrait
from app.tab.replay import TabReplay
from app.tab.scene import frame_workspace, shown_goals
from app.training.notebook import DEFAULT_PATH, Notebook
from app.training.state import LabState
from app.viser_private import client_host, client_query, install_loop_safe_wakeups, install_message_gate
from app.viser_private import install_page_head

log = logging.getLogger(__name__)

FPS = 30.0
# Until a tab's own panel has arrived and viser has folded its own tool panel away above it (the tab's
# intro starts with a marker, app/tab/goals.py READY: it is then at the top of the panel's scroll area),
# the page shows one line instead of viser's tool panel ("Inactive", its websocket URL, Save Canvas, the
# scene tree), which it would show for 1-2 s. A marker that goes again (a phone's panel folded,
# app/tab/phone.py) shows the page at once, one elsewhere after 3 s; after 30 s without the lab, viser's
# page as it is.
PAGE_HEAD = (
    "<style>html:not([data-lab-ready]) #root{visibility:hidden}"
    "html:not([data-lab-ready]) body::before{content:'Neuro-IK Lab: connecting\\2026';position:fixed;top:45%;"
    "left:0;right:0;text-align:center;font:18px system-ui,sans-serif;color:#777}</style>"
    "<script>(function(){var d=document.documentElement,t0=Date.now(),seen=0;var i=setInterval(function(){"
    "var m=document.getElementById('" + READY_ID + "'),v=m&&m.closest('.mantine-ScrollArea-viewport'),now=Date.now();"
    "if(m&&!seen)seen=now;"
    "if((m&&(!v||m.getBoundingClientRect().top-v.getBoundingClientRect().top<60))||(seen&&(!m||now-seen>3000))"
    "||now-t0>30000){d.setAttribute('data-lab-ready','');clearInterval(i);}},50);})();</script>")
PANEL_LABEL = "Neuro-IK Lab"  # the panel's title (on a phone: the bar that opens it)
# A lecture hall: every viewer tab redraws the presenter's run (arms, population, table). Together
# they redraw at most this many times a second (each in turn, a few a frame), so a tab's period
# grows beyond REDRAW_PERIOD with the number of viewers (100 tabs: each once a second); a tab's own
# drags move its arm at once, and presenter tabs keep REDRAW_PERIOD. See benchmarks/bench_app.py.
HALL_REDRAWS = 100.0
# The shared panel and views go to every tab (each tab's copy serialized and compressed on its own):
# beyond HALL_TABS tabs their periods grow in proportion (100 tabs: the panel each second, the error
# map and network every 4 s).
HALL_TABS = 25
# glibc keeps memory that Python and numpy freed in its arenas (a run's events, populations, messages to
# the tabs): a server up for a day of classes grew by about 1 MB a run (benchmarks/bench_app.py --soak),
# flat once it hands that back, which it does this often
TRIM_PERIOD = 30.0  # s
# A tab whose redraw fails in the render loop is reset (its goals back to the defaults, its scene rebuilt)
# at most this often: the loop serves the other tabs, and the log has the first traceback, then a count
TAB_RESET_PERIOD = 5.0  # s


def release_freed_memory() -> bool:
    """Return the allocator's free memory to the system (glibc's malloc_trim; False where there is none)."""
    global _malloc_trim
    if _malloc_trim is None:
        try:
            _malloc_trim = ctypes.CDLL("libc.so.6").malloc_trim  # ctypes lets go of the GIL meanwhile
        except (OSError, AttributeError):
            _malloc_trim = False
    if not _malloc_trim:
        return False
    _malloc_trim(0)
    return True


_malloc_trim = None
PANEL_PERIOD = 0.25  # s: progress, plot and status
VIEWS_PERIOD = 1.0  # s: error map and network drawing (each a few ms and a few kB per tab)
# Python hands the GIL over every 5 ms by default: a marker callback waiting behind another thread
# (the render loop redrawing ten tabs, the run's reader thread) would wait that long. 1 ms keeps
# drags under 5 ms (see benchmarks/bench_app.py); training, in its own process, is not affected.
SWITCH_INTERVAL = 0.001
# A tab that closes while the render loop redraws it gets that redraw's last messages after its
# connection is gone; viser warns once per tab. Benign here (the session is dropped on disconnect),
# and a classroom's terminal would fill with it as students close their tabs.
warnings.filterwarnings("ignore", message="Queued a .* on a closed connection", category=UserWarning)


def rerun_recorder(folder: str, service=None):
    """A recorder for LabState: a lab.recording.logger.RerunLogger per run (None when the module is
    missing), written by `service` (a lab.recording.service.WriterService: one process for all the
    app's recordings) or, without one, by a writer process a run."""
    try:
        from lab.recording.logger import RerunLogger
    except ImportError:
        return None

    def record(runner):
        logger = RerunLogger(runner, path=folder.rstrip("/") + "/", service=service)
        runner.subscribe(logger)
        record.live.add(logger)
        return logger

    # a run's end waits for its recording to be complete (the Runs list then shows whole files), but
    # not when the app stops: LabApp.stop lets the writers finish their files on their own
    record.live = weakref.WeakSet()
    return record


class LabApp:
    def __init__(self, host: str = "127.0.0.1", port: int = 8080, *, robot: str = "planar",
                 notebook: str | Notebook = DEFAULT_PATH, recordings: str = "recordings", startup=True,
                 record: bool = True, presenter_token: str | None = None, open_access: bool = False,
                 limits: dict[str, int] | None = None, speed: float | None = None,
                 class_workers: int | None = None, class_runner=None, goal: str = "position"):
        """notebook: a Notebook or its path (NotebookError, before anything starts, if the path holds
        something else). presenter_token, open_access: who may change shared state (app/classroom/access.py:
        beyond loopback only tabs opened with `presenter_url`; on loopback every tab unless a token
        is given; open_access: every tab, on purpose). limits: bounds raised (or set) at start,
        app/classroom/limits.py: beyond loopback the classroom's bounds apply, with these in their place.
        speed: generations a second runs start at (None: as fast as they go; `python -m app`: 20).
        class_workers: students' own runs at once (app/classroom/class_runs.py; None: the cores the
        shared run and the server leave, at least 1); class_runner: makes their runners (None: local worker
        processes; lab.running.ray_runner.RayRunner: a Ray cluster's actors). goal: "position" or "pose"
        (a real arm's tool frame: app/tab/posegoal.py; ValueError naming why on another robot).
        startup: True (each arm's shipped controller, else a quickly trained one),
        a controller (shown on the arm it was made for), or None. Sets the interpreter's GIL switch interval to SWITCH_INTERVAL (process-wide)."""
        notebook = notebook if isinstance(notebook, Notebook) else Notebook(notebook)
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))
        startups = None
        if startup is True:  # each arm opens with its shipped controller (app/pretrained/)
            from app.startup import startup_controller

            startup, startups = None, startup_controller
        # a warmed-up training process, the kernels of this robot's Start (its time budget: budget_for) first
        lab_worker.prestart(robot, first=lab.TrainConfig.preset(robot=robot, seconds=budget_for(robot) or None))
        # one writer process for every recording of the app (the shared runs' and the students'), started
        # with the first: a class's runs do not each pay a process's start and exit (docs/results/class.md)
        self.writers = WriterService(start=False) if record else None
        self.state = LabState(robot, notebook, startup=startup, startups=startups,
                              recorder=rerun_recorder(recordings, self.writers) if record else None,
                              limits=limits_for(is_loopback(host), limits), speed=speed, goal=goal)
        self.startup_note = self.state.shown.source
        self.recordings = recordings
        self.access = Access(host, presenter_token, open_access)
        self.upload_refusal = self.access.refusal  # uploads: viewers are refused as a transfer starts
        # students' own runs (a viewer's "My experiment"), queued to worker processes of their own
        self.class_runs = ClassRuns(notebook, self.state.limits, workers=class_workers, runner=class_runner,
                                    recorder=rerun_recorder(recordings.rstrip("/") + "/class", self.writers)
                                    if record else None)
        # the render loop, the run's reader and viser's thread pool all update handles: each update's
        # wake-up of viser's sender must reach its event loop safely (see app/viser_private.py)
        install_loop_safe_wakeups()
        install_message_gate()  # a tab's invalid GUI values are dropped, logged once a minute
        install_page_head(PAGE_HEAD)  # no viser tool panel while the page connects
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.access.install(self.server, notify=self._tell)  # before any tab can change anything
        self.host = host
        self.sessions: dict[int, TabSession] = {}
        self._sessions_lock = threading.Lock()
        self._gone: set[int] = set()  # ids of tabs that closed while their scene was being built (until _connect sees it)
        self.latency: deque = deque(maxlen=100_000)  # (tab, callback start, pose flushed) of marker updates
        self._stop = threading.Event()
        self.failures = FailureLog(log)  # the render loop's: a traceback once per tab, then a count a minute
        self.passes = 0  # render loop passes done
        gui = self.server.gui
        # a classroom shows no "share" button (a public tunnel; only a presenter could use it anyway)
        gui.configure_theme(control_width="large", show_share_button=not self.access.restricted)
        gui.set_panel_label(PANEL_LABEL)
        tabs = gui.add_tab_group(order=1)
        with tabs.add_tab("Train", viser.Icon.BRAIN):
            self.panel = TrainingPanel(gui, self.state, on_robot=self.switch_robot)
        with tabs.add_tab("Views", viser.Icon.EYE):
            self.network = gui.add_html(network_svg(None))
            # on by default for a planar arm, drawn in its plane under it; a spatial arm's map (a slice
            # of its workspace) is off at first and, turned on, lies on the floor: it never hides the arm
            self.show_map = gui.add_checkbox("Error map", len(self.state.arm.task_axes) == 2,
                                             hint="the shown network's error over a grid of reachable goals")
            self.map_legend = gui.add_markdown("")
        with tabs.add_tab("Runs", viser.Icon.LIST):
            self.runs = RunsPanel(gui, self)
        # an uploaded URDF (the Train panel's More robots…) is kept beside the uploaded recordings, under their limits
        self.panel.more.upload_folder, self.panel.more.guard = os.path.join(recordings, "uploads"), self.runs.uploads
        with tabs.add_tab("Class", viser.Icon.USERS) as class_tab:
            self.board = ClassBoard(gui, self.class_runs, show=self.runs._show, replay=self.runs.open_file,
                                    tab=class_tab)
        with tabs.add_tab("About", viser.Icon.INFO_CIRCLE):
            gui.add_markdown(MORE)
        self.show_map.on_update(lambda e: self._show_map(self.show_map.value and has_map(self.state.arm)
                                                         and self.state.shown.goal == "position"))
        self._drawn = (-1, None)  # (shown version, arm) of the map and the network
        # the render loop and callers must not interleave draws, nor rebuilds of the shared scene (two
        # threads adding /floor at once make viser remove the handle the other is still setting up)
        self._views_lock = threading.RLock()
        self._keys = itertools.count()  # the map legends' numbers, in their names
        self._build_shared()
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        self._thread = threading.Thread(target=self._loop, name="app-render", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    @property
    def presenter_url(self) -> str:
        """A link whose tab is a presenter (the plain URL when every tab is one)."""
        return self.access.link(self.url)

    def _tell(self, client_id: int, text: str) -> None:
        notify(self.server.get_clients().get(client_id), "Refused", text)

    # ------------------------------------------------------------------ tabs
    def _connect(self, client: viser.ClientHandle) -> None:
        presenter = self.access.connected(client)  # a viewer: its line, its shared controls shown disabled
        try:  # a lesson link's settings (app/classroom/lesson.py), and the address the tab reached us at
            query, host = client_query(client), client_host(client)
        except Exception:  # noqa: BLE001 - a tab without them is an ordinary tab
            log.exception("cannot read the query of tab %s", client.client_id)
            query, host = {}, None
        fold_on_phone(client.gui, PANEL_LABEL)  # a phone's panel folds to its bar: the arm in view
        session = TabSession(client, self.state, self.latency)
        session.presenter = presenter
        session.page_url = f"http://{host}" if host else self.url
        follow_portrait(client, lambda: session.ws)  # a phone held upright sees the whole workspace
        self.board.follow_phone(client)  # and its Class tab the board's columns that fit
        # a viewer replays in its own tab (a presenter replays for every tab, in the Runs tab)
        session.replay = None if presenter else TabReplay(client, session, self.runs)
        # a viewer's own run (a presenter has the shared Train panel): app/panels/my_run.py
        session.my_run = None if presenter else MyRunPanel(client, session, self.class_runs)
        with self._sessions_lock:
            gone = client.client_id in self._gone  # the tab closed while its scene was being built
            self._gone.discard(client.client_id)  # seen: no closed tab's id is kept for good
            if not gone:
                self.sessions[client.client_id] = session
        if gone:
            self.class_runs.drop_tab(client.client_id)
            self.board.forget(client.client_id)
            session.close()
            self.access.disconnected(client.client_id)
            return
        # a lesson changes the shared settings (the presenter's to do); its text goes to any tab
        open_lesson(self, session, query, client, presenter)
        self._write_lesson_links([session])

    def _write_lesson_links(self, sessions) -> None:
        """Each tab's lesson link for the panel's current settings (at the address that tab used); a
        presenter's tab on a server with a token also its own presenter link (the token in it)."""
        params = lesson_params(self.panel)
        token = self.access.token if self.access.restricted else None
        for s in sessions:
            try:
                own = lesson_link(s.page_url, {"token": token, **params}) if token and s.presenter else None
                s.show_lesson(lesson_link(s.page_url, params), params, presenter_link=own)
            except Exception:  # noqa: BLE001 - one tab's failure never stops the others'
                self._tab_failed(s, "lesson link")

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._sessions_lock:
            session = self.sessions.pop(client.client_id, None)
            if session is None:  # its _connect has not registered it yet: it drops it when it does
                self._gone.add(client.client_id)
        self.access.disconnected(client.client_id)
        self.class_runs.drop_tab(client.client_id)  # its queued run dropped, its running run stopped
        self.board.forget(client.client_id)  # its narrow table (a phone's), its large chart
        if session is not None:
            session.close()

    # ------------------------------------------------------------------ shared scene
    def switch_robot(self, name: str) -> str | None:
        """Show another arm in every tab (refused while a run is going)."""
        msg = self.state.set_robot(name)
        if msg is None:
            self._build_shared()
            self.panel.robot.options = any_robot.choices(self.state, more=True)  # a robot opened: in the menus
            self.panel.robot.value = self.state.arm.name  # the canonical string (erd:ur3 -> erd:ur3#tool0)
        return msg

    def _build_shared(self) -> None:
        with self._views_lock:
            self._build_shared_locked()

    def _build_shared_locked(self) -> None:
        arm = self.state.arm
        ws = frame_workspace(arm)
        scene = self.server.scene
        self.server.initial_camera.position = ws["camera"]
        self.server.initial_camera.look_at = ws["center"]
        size = ws["size"]
        scene.add_grid("/floor", width=1.6 * size, height=1.6 * size, cell_size=ws["cell"],
                       section_size=10 * ws["cell"], position=(ws["center"][0], ws["center"][1], ws["floor_z"]))
        goals = shown_goals(self.training_goals(), arm.n_effectors)  # a run trains on all; a few hundred drawn
        # a tree's goals are a point per effector each: smaller, so the robot shows; beyond the paper's
        # 70 goals (300 on a real arm) smaller too, down to half
        shrink = max(0.5, math.sqrt(70 / max(70, len(goals) // arm.n_effectors)))
        self.goal_dots = scene.add_point_cloud(
            "/training_goals", points=goals.astype(np.float32), colors=(200, 30, 30),
            point_size=(0.004 if arm.is_tree else 0.008) * shrink * size, point_shape="circle")
        self._map_z = -0.05 * size  # just under the planar arm (its visuals reach z = -0.04 size)
        self._floor_z = ws["floor_z"] + 0.002 * size  # a spatial arm's map lies on the floor
        if self._drawn[1] is not arm:  # each arm opens with its own default
            self.show_map.value = len(arm.task_axes) == 2
            self.show_map.disabled = not has_map(arm)  # a tree's goal is a point per effector: no map
        self._map = scene.add_image("/error_map", np.zeros((1, 1, 4), np.uint8), 1.0, 1.0, visible=False)
        # the map's legend in the scene, beside the map (app/panels/views.py map_key): the last arm's goes,
        # and this one's has a name of its own (a name given again with its children can leave a copy in
        # the browser: app/tab/scene.py)
        if getattr(self, "_map_key", None) is not None:
            self._map_key.remove()
        self._map_key = scene.add_frame(f"/error_map_key/{arm.name}-{next(self._keys)}", show_axes=False,
                                        visible=False)
        if has_map(arm):
            key, z = map_key(arm, lambda d: fmt_len(arm, d)), self._floor_z if len(arm.task_axes) == 3 else self._map_z
            base = self._map_key.name
            scene.add_image(f"{base}/bar", key.image, key.width, key.height, format="png",
                            position=(*key.center, z), cast_shadow=False, receive_shadow=False)
            for end, (xy, text, anchor) in (("top", key.top), ("bottom", key.bottom)):
                scene.add_label(f"{base}/{end}", text, position=(*xy, z), anchor=anchor)
        self._drawn = (-1, arm)  # built for this arm: the render loop draws the views, without a second build

    def training_goals(self) -> np.ndarray:
        """3D points of the goals the current (or the next default) run trains on."""
        arm = self.state.arm
        r = self.state.runner
        if r is not None and r.problem.arm is arm:
            goals = r.problem.train_goals
        else:  # the goals of a run with the arm's defaults (the About text says how many)
            d = lab.TrainConfig.preset(robot=arm.name)
            goals = arm.sample_goals(d.targets, seed=d.goal_seed)
        goals = np.asarray(goals)
        if goals.shape[-2:] == (4, 4):  # a pose run's goals: their positions
            return goals[:, :3, 3].reshape(-1, 3)
        return arm.to_3d(goals).reshape(-1, 3)  # a tree's: every effector's point of every goal

    def _draw_views(self) -> None:
        """Error map and network of the shown controller, when it has changed."""
        with self._views_lock:  # else a slow draw of an older controller can land after a newer one
            self._draw_views_locked()

    def _draw_views_locked(self) -> None:
        shown = self.state.shown
        if (shown.version, shown.arm) == self._drawn:
            return
        if self._drawn[1] is not shown.arm:
            self._build_shared()
        self._drawn = (shown.version, shown.arm)
        self.network.content = network_svg(shown.controller)
        if shown.goal == "pose":  # the map is over positions: a pose goal has an orientation too
            self._show_map(False)
            self.map_legend.content = ("No error map for pose goals: the map is a network's error over a grid "
                                       "of positions, and a pose goal also has an orientation.")
            return
        if not has_map(shown.arm):
            self._show_map(False)
            self.map_legend.content = (
                f"No error map on the {shown.arm.name}: a goal there is a point for each of its "
                f"{shown.arm.n_effectors} end effectors, not one point of a plane.")
            return
        image, err, scale = error_map(shown.arm, shown.controller)
        grid = map_grid(shown.arm)
        z = self._floor_z if len(shown.arm.task_axes) == 3 else self._map_z
        center = np.array([*grid.center[:2], z])
        self._map = self.server.scene.add_image(
            "/error_map", image, render_width=grid.n * grid.cell, render_height=grid.n * grid.cell,
            format="png", position=center, cast_shadow=False, receive_shadow=False, visible=self.show_map.value)
        self._map_key.visible = self.show_map.value
        self.map_legend.content = map_legend(shown.arm, err, lambda d: fmt_len(shown.arm, d))

    def _show_map(self, visible: bool) -> None:
        """The error map and its legend in the scene, shown or hidden."""
        self._map.visible = self._map_key.visible = visible

    # ------------------------------------------------------------------ render loop
    def _loop(self) -> None:
        """Tabs every frame (each redraws at most every REDRAW_PERIOD; viewers within HALL_REDRAWS), the panel 4 times a
        second, the error map, network and runs list once a second (at once after a change of arm);
        those two less often with more than HALL_TABS tabs; freed memory back to the system every
        TRIM_PERIOD."""
        period, last_panel, last_views, turn, last_trim = 1.0 / FPS, 0.0, 0.0, 0, time.perf_counter()
        while not self._stop.is_set():
            t0 = time.perf_counter()
            try:
                with self._sessions_lock:
                    sessions = list(self.sessions.values())
                turn = self._refresh_tabs(sessions, turn)
                hall = max(1.0, len(sessions) / HALL_TABS)
                if t0 - last_panel > PANEL_PERIOD * hall:
                    last_panel = t0
                    self.panel.refresh()
                    self.access.sync_viewers()
                    self._refresh_class(sessions)
                if t0 - last_views > VIEWS_PERIOD * hall or self._drawn[1] is not self.state.arm:
                    last_views = t0
                    self._draw_views()
                    self.runs.refresh()
                    self._write_lesson_links(sessions)
                    self._sync_replays(sessions)
                if t0 - last_trim > TRIM_PERIOD:
                    last_trim = t0
                    release_freed_memory()
            except Exception:  # the loop must survive anything one frame does: a traceback once, then a count
                self.failures.failed("loop", "render loop")
            self.passes += 1
            self._stop.wait(max(0.0, period - (time.perf_counter() - t0)))

    def _refresh_class(self, sessions: list) -> None:
        """The class board and each viewer's own run (its status, curve and arm)."""
        self.board.refresh()
        self._tell_lost(sessions)
        for s in sessions:
            if getattr(s, "my_run", None) is not None:
                try:
                    s.my_run.refresh()
                except Exception:  # noqa: BLE001 - one tab's panel never stops the others'
                    self._tab_failed(s, "My experiment panel")

    def _tell_lost(self, sessions: list) -> None:
        """Each presenter's tab told once when students' runs cannot go where they go (a Ray cluster
        lost: ClassRuns.unavailable, probed at most every few seconds; a tab that connects meanwhile
        too), once when they can again; the Class board says it meanwhile."""
        lost = self.class_runs.unavailable()
        for s in sessions:
            if s.presenter and getattr(s, "told_lost", None) != lost:
                s.told_lost = lost
                notify(s.client, "Ray cluster lost" if lost else "Ray cluster back",
                       f"{lost}; students' new runs are refused until it answers again" if lost
                       else "It answers again: students' runs go to it.", error=lost is not None)

    def _sync_replays(self, sessions: list) -> None:
        """Each viewer tab's own replay (a method: no loop variable of the render loop keeps the last
        tab, its client and its scene alive after it has closed)."""
        for s in sessions:
            if getattr(s, "replay", None) is not None:
                try:
                    s.replay.sync()
                except Exception:  # noqa: BLE001 - one tab's failure never stops the others'
                    self._tab_failed(s, "replay")

    def _refresh_tab(self, s) -> bool:
        """s.refresh(); a failure is the tab's alone: logged once (then counted), the tab reset."""
        try:
            return s.refresh()
        except Exception:  # noqa: BLE001 - whatever one tab holds, the loop serves the others
            self._tab_failed(s, "redraw")
            return False

    def _tab_failed(self, s, what: str) -> None:
        """Call in an `except` block of the render loop for tab s: the first failure's traceback (later
        ones counted, app/failures.py); the tab reset (its goals back to the defaults, its scene rebuilt:
        TabSession.build) and told, at most every TAB_RESET_PERIOD."""
        cid = s.client.client_id
        self.failures.failed(("tab", cid, what), f"render loop: tab {cid}'s {what}")
        now = time.monotonic()
        if now - getattr(s, "reset_at", -math.inf) < TAB_RESET_PERIOD or s.closed:
            return
        s.reset_at = now
        try:
            s.build()
            s.version = -1  # the next pass redraws it all
            notify(s.client, "Reset", f"This tab's {what} failed; its goals are back at their defaults.")
        except Exception:  # noqa: BLE001 - a tab that cannot be rebuilt is left as it is, logged once
            self.failures.failed(("reset", cid), f"render loop: reset of tab {cid}")

    def _refresh_tabs(self, sessions: list, turn: int) -> int:
        """Refresh every presenter tab of a restricted server (a classroom's), and the other tabs in
        turn from `turn` until HALL_REDRAWS / FPS of them have redrawn this frame; their period is
        stretched so that all of them together stay within HALL_REDRAWS a second (on a server where
        every tab is a presenter, all tabs share that budget). Returns where the next frame's turn
        starts."""
        restricted = self.access.restricted
        viewers = [s for s in sessions if not (s.presenter and restricted)]
        hall = max(REDRAW_PERIOD, len(viewers) / HALL_REDRAWS)
        for s in sessions:
            if s.presenter and restricted:
                self._refresh_tab(s)
        for s in viewers:
            s.period = hall
        if not viewers:
            return 0
        budget, n = max(1, math.ceil(HALL_REDRAWS / FPS)), len(viewers)
        turn %= n
        for k in range(n):
            s = viewers[(turn + k) % n]
            if self._refresh_tab(s):
                budget -= 1
                if budget == 0:
                    return (turn + k + 1) % n
        return turn

    def stop(self) -> None:
        self._stop.set()
        self.class_runs.shutdown()  # every student run ends, stopped, in the notebook
        for logger in list(getattr(self.state.recorder, "live", ())):
            logger.block_on_end = False  # the writer finishes the file after we have gone
        self.state.reset() if self.state.running else None
        self._thread.join(timeout=5)
        if self.writers is not None:  # its process ends once the files it writes are closed
            self.writers.close()
        self.server.stop()
