"""Students' own runs on a classroom server: their names, a queue, a few worker processes, the board's rows.

    runs = ClassRuns(notebook, limits, workers=1)
    runs.set_name(tab_id, "Ada")                 # None, or why not ("taken", bad characters, too long)
    runs.submit(tab_id, TrainConfig(...))        # None (queued, started when a worker is free) or why not
    runs.run_of(tab_id).status()                 # "queued, place 2 of 3", "running, generation 40", ...
    runs.stop_tab(tab_id); runs.drop_tab(tab_id) # a student's Stop; a closed tab (its name freed too)
    runs.shutdown()                              # the server stops: every queued and running run ends, stopped
    ClassRuns(notebook, limits, recorder=rerun_recorder("recordings/class"))  # each run recorded (.rrd)

Nothing here knows viser (the panels are app/panels/my_run.py and app/panels/class_board.py). Each
run trains in a worker process of its own (lab.running.worker.ProcessRunner, as the shared run does,
but never the prestarted spare, which stays for the presenter's next Start): one of `workers` warm
workers (lab.running.worker.WarmWorkers, kept from the first run on: a run taken, its replacement
starts and warms up while it trains, so the next run does not wait ~2 s for a process). At most `workers` run at
once (default: the cores the shared run and the server leave, at least 1); the others wait in one
queue, first come first served. A tab has one run at a time (queued or running), within the server's
limits (app/classroom/limits.py); the queue holds at most MAX_QUEUED runs. A run's end writes its
notebook entry (app/training/notebook.py) with the student's name and its recording; at shutdown the
queued runs are written too, stopped, with 0 generations.

With a recorder (app.server.rerun_recorder, as the shared run's), each run is recorded as the shared
run is: a lab.recording.logger.RerunLogger subscribed to its runner before it starts, whose writer is a
process of its own (the runner's reader thread only hands each generation's numbers to a pipe); the
run's end waits for its file to be closed before its notebook entry names it, so an entry's recording
is whole; the next queued run starts first, so a writer's close costs the class no worker's time.

Names are labels, not identities: at most NAME_MAX characters, letters, digits, spaces and . _ ' -
(anything else is refused, naming the characters), unique per server among the open tabs (compared
after NFKC and case folding, name_key: a fullwidth "ＡＤＡ" is the "Ada" it looks like). A tab without one is "student N".
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
import time
import unicodedata
import uuid
from collections import deque

import lab
from lab.running.worker import STOP_GRACE, ProcessRunner, WarmWorkers

from app.classroom.limits import refusal as limits_refusal
from app.training.live import RunTrack
from app.training.notebook import entry_from_summary

log = logging.getLogger(__name__)

NAME_MAX = 24  # characters of a display name
NAME_PUNCTUATION = " .'_-"
MAX_QUEUED = 60  # runs waiting at most: a flood of tabs gets a refusal, never an unbounded queue
HISTORY_POINTS = 4096  # a student run's kept history (as the shared run's, app/training/state.py)
ENDED = ("finished", "stopped", "failed")


def default_workers(cores: int | None = None) -> int:
    """Worker processes for students' runs: the cores left by the shared run and the server (its
    drag loop and redraws), at least 1."""
    cores = cores if cores is not None else (os.cpu_count() or 2)
    return max(1, cores - 2)


def local_runner(config: lab.TrainConfig, history_limit: int | None = None,
                 warm: WarmWorkers | None = None) -> ProcessRunner:
    """A student run's runner on this machine: a worker process of its own, never the prestarted spare
    (warm: one of these warm workers; ClassRuns keeps `workers` of them)."""
    return ProcessRunner(config, history_limit=history_limit, spare=warm if warm is not None else False)


def clean_name(text) -> tuple[str | None, str | None]:
    """(the name, None) or (None, why it is refused). Runs of spaces fold into one; the ends are trimmed."""
    if not isinstance(text, str):
        return None, "a name is text"
    name = " ".join(text.split())
    if not name:
        return None, "a name needs at least one letter or digit"
    bad = sorted({c for c in name if not (c.isalnum() or c in NAME_PUNCTUATION)})
    if bad:
        shown = " ".join(repr(c) for c in bad[:8]) + (" ..." if len(bad) > 8 else "")
        return None, f"a name has letters, digits, spaces and . ' _ - only, not {shown}"
    if len(name) > NAME_MAX:
        return None, f"a name has at most {NAME_MAX} characters, this one has {len(name)}"
    if not any(c.isalnum() for c in name):
        return None, "a name needs at least one letter or digit"
    return name, None


def name_key(name: str) -> str:
    """What two names are compared by: NFKC folding (fullwidth, ligatures, compatibility forms) and
    case folding, NFKC again after it (Unicode's NFKC_Casefold, near enough): "ＡＤＡ", "ada" and "Ada" are one."""
    return unicodedata.normalize("NFKC", unicodedata.normalize("NFKC", name).casefold())


def describe(config: lab.TrainConfig) -> str:
    """A run's settings in a few words ("planar, CMA-ES, pop 20, 16 hidden, 70 goals, 20 gen, seed 0")."""
    length = f"{config.seconds:g} s" if config.seconds is not None else f"{config.generations:,} gen"
    return (f"{config.robot}, {lab.methods.get(config.method).label}, pop {config.population}, "
            f"{config.hidden} hidden, {config.targets} goals, {length}, seed {config.seed}")


class StudentRun:
    """One student's run: queued, then running in a worker process, then finished, stopped or failed."""

    def __init__(self, tab: int, name: str, config: lab.TrainConfig, owner: "ClassRuns", lesson: str | None = None):
        self.tab, self.name, self.config, self._owner = tab, name, config, owner
        self.lesson = lesson  # the lesson link it was started from ("class-as-a-search"; None: none)
        self.board = owner.boards  # the board it was started on (ClassRuns.new_board)
        self.id = uuid.uuid4().hex[:12]  # the runner's run_id once it starts
        self.state = "queued"
        self.runner: ProcessRunner | None = None
        self.track = RunTrack(lab.methods.get(config.method))
        self.summary = None
        self.note: str | None = None  # why it stopped or failed, when not by its own end
        self.stopping = False  # a Stop is under way (one thread waits for its worker: ClassRuns.stop)
        self.freed = False  # its worker is done: the next queued run starts while its recording is closed
        self.submitted = time.time()
        self.started: float | None = None
        self.ended_at: float | None = None  # time.time() of its end (ClassRuns._ended)
        self.recording: str | None = None  # its .rrd, when the server records student runs
        self.logger = None  # its RerunLogger
        self.controller = None  # the best so far (the tab's own arm shows it)
        self.version = 0  # bumped when `controller` changes

    @property
    def ended(self) -> bool:
        return self.state in ENDED

    @property
    def generation(self) -> int:
        return len(self.track)

    def best(self) -> float | None:
        """The best training MSE so far (None before the first generation)."""
        _gens, best, _median = self.track.curves()
        return float(best[-1]) if len(best) else None

    def held_out(self) -> float | None:
        """The held-out MSE of its final controller (None until it has ended with one)."""
        s = self.summary
        return float(s.test_mse) if s is not None and s.controller is not None else None

    def status(self) -> str:
        """Its state in words: "queued, place 2 of 3", "running, generation 40 of 100", "finished", ..."""
        if self.state == "queued":
            place, of = self._owner.place(self)
            return f"queued, place {place} of {of}" if place else "queued"
        total = "" if self.config.seconds is not None else f" of {self.config.generations:,}"
        if self.state in ("running", "paused"):
            waits = getattr(self.runner, "preparing", None) if self.runner is not None else None
            if waits:
                return f"running: preparing the training kernels ({waits})"
            return f"running, generation {self.generation}{total}"
        text = f"{self.state}, {self.generation} generation{'s' if self.generation != 1 else ''}"
        why = self.note or (self.summary.error if self.summary is not None else None)
        return text + (f" ({why})" if why else "")

    # the runner's subscriber: each generation, and its end
    def __call__(self, event) -> None:
        self.track.add(event)
        if event.improved or event.index == 0:
            self.controller, self.version = event.controller, self.version + 1

    def on_end(self, summary) -> None:
        self._owner._ended(self, summary)


class ClassRuns:
    def __init__(self, notebook, limits: dict | None, workers: int | None = None,
                 stop_grace: float = STOP_GRACE, runner=None, recorder=None):
        """notebook: where ended runs go (app.training.notebook.Notebook); limits: the server's bounds
        (None: the lab's own); workers: runs at once (None: default_workers()); runner: makes a run's
        runner, runner(config, history_limit=N) (None: a local worker process, local_runner; a Ray
        cluster's: lab.running.ray_runner.RayRunner); recorder: callable(runner) -> a logger with .path,
        subscribed to the runner (app.server.rerun_recorder), or None: no recordings."""
        self.notebook, self.limits, self.recorder = notebook, limits, recorder
        # why runs cannot go where the runner sends them now (a lost Ray cluster: RayRunner.unavailable)
        self._unavailable = getattr(runner, "unavailable", None)
        self.workers = max(1, int(workers)) if workers is not None else default_workers()
        self.warm = WarmWorkers(self.workers) if runner is None else None  # the local runs' warm workers
        self.make_runner = runner or (lambda config, history_limit=None: local_runner(config, history_limit, self.warm))
        self.stop_grace = stop_grace
        self._lock = threading.RLock()
        self.runs: dict[str, StudentRun] = {}  # every run of the session, in order (the board's rows)
        self._queue: deque[StudentRun] = deque()
        self._names: dict[int, str] = {}  # tab -> its name
        self._numbers = itertools.count(1)
        self.closed = False
        self.version = 0  # bumped at every change of a run's state (the board redraws)
        self._seats: dict[str, dict[int, int]] = {}  # a lesson -> {open tab: its seat} (lesson_seat)
        self._next_seat: dict[str, int] = {}  # a lesson -> the seat its next tab gets
        self.board_since = 0.0  # time.time() of the presenter's "New board": earlier runs leave the board
        self.boards = 1  # the board's number (1 until the presenter's first New board)

    # ------------------------------------------------------------------ names
    def name_of(self, tab: int) -> str:
        """The tab's name (a new "student N", not taken, the first time)."""
        with self._lock:
            name = self._names.get(tab)
            while name is None:
                candidate = f"student {next(self._numbers)}"
                if not self._taken(candidate, tab):
                    name = self._names[tab] = candidate
            return name

    def _taken(self, name: str, tab: int) -> bool:
        key = name_key(name)
        return any(name_key(n) == key for t, n in self._names.items() if t != tab)

    def set_name(self, tab: int, text) -> str | None:
        """Give the tab this name (None) or refuse, saying why (cleaned as clean_name; taken)."""
        name, why = clean_name(text)
        if why is not None:
            return f"refused: {why}"
        with self._lock:
            if self._taken(name, tab):
                return f"refused: the name {name!r} is taken; pick another"
            self._names[tab] = name
            for run in self.runs.values():  # the tab's runs carry its name on the board
                if run.tab == tab and not run.ended:
                    run.name = name
            self.version += 1
        return None

    def lesson_seat(self, lesson: str, tab: int) -> int:
        """The tab's seat in a lesson (0 for the first tab that opened it, 1 for the next, ...; the same
        seat when it opens it again): a lesson that gives each student a part of a search hands out the
        seat's part."""
        with self._lock:
            seats = self._seats.setdefault(lesson, {})
            if tab not in seats:
                seats[tab] = self._next_seat.get(lesson, 0)
                self._next_seat[lesson] = seats[tab] + 1
            return seats[tab]

    # ------------------------------------------------------------------ runs
    def run_of(self, tab: int) -> StudentRun | None:
        """The tab's latest run (None when it has none)."""
        with self._lock:
            for run in reversed(self.runs.values()):
                if run.tab == tab:
                    return run
            return None

    def place(self, run: StudentRun) -> tuple[int | None, int]:
        """(its 1-based place in the queue or None, the queue's length)."""
        with self._lock:
            queue = list(self._queue)
        return (queue.index(run) + 1 if run in queue else None), len(queue)

    def submit(self, tab: int, config: lab.TrainConfig, lesson: str | None = None) -> str | None:
        """Queue the tab's run (started at once when a worker is free); refused, saying why, while
        the tab has a run queued or running, beyond the server's limits, when the queue is full or the
        server is stopping. lesson: the lesson link the tab opened (the board groups its runs)."""
        if (why := limits_refusal(config, self.limits)) is not None:
            return f"refused: {why}"
        if (lost := self.unavailable()) is not None:  # refused, not run here instead: see docs/classroom.md
            return f"refused: {lost}; no new run until it answers again"
        with self._lock:
            if self.closed:
                return "refused: the server is stopping"
            mine = self.run_of(tab)
            if mine is not None and not mine.ended:
                return f"refused: your run is {mine.status()}; one run at a time per tab (stop it first)"
            if len(self._queue) >= MAX_QUEUED:
                return f"refused: the class's queue is full ({MAX_QUEUED} runs wait); try again when some have run"
            run = StudentRun(tab, self.name_of(tab), config, self, lesson)
            self.runs[run.id] = run
            self._queue.append(run)
            self.version += 1
            self._pump()
        return None

    def unavailable(self) -> str | None:
        """None, or why new runs are refused now, naming where they would go ("the local Ray instance at
        HOST:PORT is lost: ..."); cheap (the runner's own watch, probed at most every few seconds)."""
        return self._unavailable() if self._unavailable is not None else None

    def running(self) -> list[StudentRun]:
        with self._lock:
            return [r for r in self.runs.values() if r.state in ("running", "paused")]

    def _pump(self) -> None:
        """Start queued runs while a worker is free (under the lock)."""
        while self._queue and not self.closed and sum(not r.freed for r in self.running()) < self.workers:
            run = self._queue.popleft()
            if (lost := self.unavailable()) is not None:  # it would wait for a CPU none offers: it fails now
                log.warning("student run %s not started: %s", run.id, lost)
                run.state, run.note = "failed", f"it could not start: {lost}"
                self.version += 1
                continue
            try:
                runner = self.make_runner(run.config, history_limit=HISTORY_POINTS)
                runner.run_id = run.id
                runner.subscribe(run)  # before the logger: its end starts the next run, then closes the file
                self._record(run, runner)
                run.runner, run.state, run.started = runner, "running", time.time()
                runner.start()
            except Exception as e:  # noqa: BLE001 - a run that cannot start fails; the queue goes on
                log.exception("student run %s could not start", run.id)
                run.state, run.note = "failed", f"it could not start: {e}"
            self.version += 1

    def _record(self, run: StudentRun, runner) -> None:
        if self.recorder is None:
            return
        try:
            run.logger = self.recorder(runner)
            run.recording = str(run.logger.path)
        except Exception as e:  # noqa: BLE001 - a run without a recording is still a run
            log.warning("no recording for student run %s: %s", run.id, e)
            run.logger = run.recording = None

    def _ended(self, run: StudentRun, summary) -> None:
        """A run's end (its reader thread): the next queued run starts, this one's recording is closed
        (its writer's close no longer holds up the class's next run), then its state and its notebook
        entry, which names a whole recording."""
        with self._lock:
            run.freed = True
            self._pump()
        if run.logger is not None:  # the file whole (its logger's own on_end, after this, finds it closed)
            try:
                run.logger.close(summary, block=run.logger.block_on_end)
            except RuntimeError:  # said once (failure()), the run's entry names what is readable
                log.warning("%s", run.logger.failure())
        with self._lock:
            run.summary, run.state = summary, summary.state
            run.ended_at = time.time()  # its wall time, start to end (a queued run's wait estimate: app/classroom/student_run.py)
            run.track.population = None  # an ended run keeps its numbers, not its last population's networks
            if summary.controller is not None:
                run.controller, run.version = summary.controller, run.version + 1
            self.version += 1
        self._write(run, summary)
        with self._lock:
            self._pump()

    def _write(self, run: StudentRun, summary=None) -> None:
        try:
            if summary is not None:
                entry = entry_from_summary(summary, run.started or run.submitted, run.recording)
            else:  # a queued run the server's stop ended before it started
                entry = {"run_id": run.id, "robot": run.config.robot, "method": run.config.method,
                         "seed": run.config.seed, "settings": run.config.to_dict(), "state": "stopped",
                         "generations": 0, "evaluations": 0, "seconds": 0.0, "train_mse": None, "test_mse": None,
                         "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(run.submitted)),
                         "recording": None, "controller": None}
            entry["student"] = run.name
            if run.lesson:
                entry["lesson"] = run.lesson
            if run.note and not entry.get("error"):
                entry["error"] = run.note
            self.notebook.add(entry, timeout=1.0)
        except Exception:  # noqa: BLE001 - a bug of ours: logged, the class goes on
            log.exception("could not write the notebook entry of student run %s", run.id)

    def stop(self, run_id: str, note: str | None = None, wait: bool = False) -> str | None:
        """Stop a run: a queued one leaves the queue (stopped, never started), a running one ends after
        its generation in flight (its worker killed if it has not stop_grace s later). Refused when
        there is no such run or it has ended; a run already stopping is left to the Stop under way."""
        with self._lock:
            run = self.runs.get(run_id)
            if run is None:
                return "refused: no such run"
            if run.ended:
                return f"refused: this run has already {run.state}"
            if run.stopping:  # its Stop is under way: one thread a run, however often Stop is pressed
                return None
            run.note = note
            if run.state == "queued":
                self._queue.remove(run)
                run.state = "stopped"
                self.version += 1
                return None
            runner, run.stopping = run.runner, True
            self.version += 1
        if wait:
            runner.stop_or_kill(self.stop_grace)
        else:
            threading.Thread(target=runner.stop_or_kill, args=(self.stop_grace,), daemon=True,
                             name=f"class-stop-{run_id}").start()
        return None

    def stop_tab(self, tab: int, note: str | None = None) -> str | None:
        """The tab's own Stop."""
        run = self.run_of(tab)
        if run is None or run.ended:
            return "refused: you have no run queued or running"
        return self.stop(run.id, note or "stopped by its student")

    def drop_tab(self, tab: int) -> None:
        """A tab has closed: its queued run is dropped, its running run stops, its name is free again."""
        run = self.run_of(tab)
        if run is not None and not run.ended:
            self.stop(run.id, "its tab closed")
        with self._lock:
            self._names.pop(tab, None)
            for lesson in [k for k, seats in self._seats.items() if tab in seats]:  # a closed tab holds no seat
                del self._seats[lesson][tab]
                if not self._seats[lesson]:  # the lesson's last tab: it starts again from seat 0
                    del self._seats[lesson], self._next_seat[lesson]

    def shutdown(self) -> None:
        """The server stops: every queued run ends stopped (its notebook entry written, 0 generations)
        and every running run stops (its worker killed after stop_grace s); returns once they have ended."""
        with self._lock:
            self.closed = True
            if self.warm is not None:
                self.warm.close()
            queued, self._queue = list(self._queue), deque()
            for run in queued:
                run.state, run.note = "stopped", "the server stopped before it started"
            running = self.running()
            for run in running:
                run.note = "the server stopped"
                if run.logger is not None:  # its writer finishes the file on its own: the server stops now
                    run.logger.block_on_end = False
            self.version += 1
        for run in queued:
            self._write(run)
        for run in running:
            run.runner.stop(wait=False)
        for run in running:
            run.runner.stop_or_kill(self.stop_grace)
        for run in running:
            run.runner.join(10)

    def rows(self) -> list[StudentRun]:
        with self._lock:
            return list(self.runs.values())

    def new_board(self) -> int:
        """The presenter's fresh board: the runs queued before now leave the board and its chart (a
        run still queued or running stays listed until it ends); the notebook keeps every one. Returns
        the new board's number."""
        with self._lock:
            self.board_since = time.time()
            self.boards += 1
            self.version += 1
            return self.boards

    def board_rows(self, going: bool = True) -> list[StudentRun]:
        """The current board's runs (submitted since the last New board), and with `going` the earlier
        ones still queued or running."""
        with self._lock:
            return [r for r in self.runs.values()
                    if r.board == self.boards or (going and not r.ended)]
