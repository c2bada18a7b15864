"""The background runner: drives a backend in a thread, one generation at a time.

    runner = Runner(TrainConfig(robot="planar", method="cmaes"))
    runner.subscribe(callback)       # callback(event: GenerationEvent), once per generation
    runner.start()                   # returns at once; runner.pause() / resume() / stop()
    runner.step()                    # while paused: exactly one more generation, then paused again
    runner.set_speed(5)              # at most 5 generations a second (None: as fast as it goes)
    runner.snapshot()                # a consistent view of the current best, from any thread
    summary = runner.join()          # blocks until the run ends

Subscribers run in the runner's thread, in subscription order, after each generation: keep
them fast or hand work to a thread of their own (the Rerun logger does). A subscriber that
raises is reported and unsubscribed; the run goes on. A subscriber may also have an
`on_end(summary)` method, called once when the run ends (finished, stopped or failed).
stop() returns within one generation. A run with a time budget (TrainConfig.seconds) ends
"finished" after the generation whose optimizer time (pauses, speed-cap waits and subscribers
excluded) reaches it; with generations too, whichever comes first (RunSummary.ended_by says which).
NumPy's BLAS is limited to one thread while a run goes
(pycma slows threefold when threaded BLAS meets another busy process on two cores).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
import uuid
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

import robots

from lab.methods import Backend, Population, make_backend
from lab.running.config import TrainConfig
from lab.running.decimation import display_goal, population_logged
from lab.running.history import History
from lab.problem.controllers import Controller
from lab.problem.encodings import encoding_for
from lab.problem import Problem

log = logging.getLogger(__name__)

POPULATION_PERIOD = 0.2  # s: at most this often a population goes out with its controllers (the tabs redraw at 5 Hz)


@dataclass(frozen=True)
class GenerationEvent:
    """One generation: index from 0; best = best training MSE so far (of `controller`);
    gen_best/median/worst over this generation's population; evaluations so far; seconds of
    run time so far (pauses excluded); wall_time: when the generation ended (Unix time);
    population: the generation's candidates (lab.methods.Population) on the generations
    lab.running.decimation.population_logged names (their MSE, species and points at the display
    goal), with their controllers at most every POPULATION_PERIOD and whenever the run holds
    (paused, a Step, the last generation); None otherwise."""

    run_id: str
    index: int
    best: float
    gen_best: float
    median: float
    worst: float
    evaluations: int
    seconds: float
    controller: Controller
    improved: bool
    extras: dict = field(default_factory=dict)
    wall_time: float = field(default_factory=time.time)
    population: Population | None = None  # this generation's candidates, when sent (see Runner)


@dataclass(frozen=True)
class Snapshot:
    state: str
    generation: int  # generations completed
    best: float
    controller: Controller | None
    history: np.ndarray  # best MSE so far, per generation (per kept generation if the runner's history is bounded)


@dataclass(frozen=True)
class RunSummary:
    run_id: str
    config: TrainConfig
    state: str  # "finished", "stopped" or "failed"
    generations: int
    evaluations: int
    seconds: float
    controller: Controller | None
    train_mse: float
    test_mse: float
    history: np.ndarray
    median_history: np.ndarray
    error: str | None = None
    # what ended a finished run: "generations" (all of them ran) or "seconds" (its time budget was
    # spent); None for a stopped or failed one
    ended_by: str | None = None

    def numbers(self) -> dict:
        """The summary's JSON-ready numbers (what recordings and the notebook store)."""
        return {"state": self.state, "generations": self.generations, "evaluations": self.evaluations,
                "seconds": self.seconds, "train_mse": self.train_mse, "test_mse": self.test_mse, "error": self.error}


def build_problem(config: TrainConfig) -> Problem:
    arm = robots.load(config.robot)
    if config.goal == "pose":  # tool frames (n, 4, 4): lab/problem/pose_fitness.py
        from lab.problem.pose_fitness import pose_problem

        return pose_problem(arm, config.features, config.margin, config.turn, config.targets, config.test_goals,
                            config.goal_seed, config.seed if config.resample else None, reach=config.reach)
    enc = encoding_for(arm, config.features, config.margin, config.turn)
    return Problem(arm, enc, targets=config.targets, test_goals=config.test_goals, goal_seed=config.goal_seed,
                   resample_seed=config.seed if config.resample else None)


class RunBase:
    """What every runner shares: subscribers, state, history, snapshot, join. The training itself is
    the subclass's: Runner trains in a thread of this process, lab.running.worker.ProcessRunner in a process
    of its own; subscribers cannot tell them apart."""

    def __init__(self, config: TrainConfig, problem: Problem | None = None, history_limit: int | None = None):
        """history_limit: keep at most this many points of the best and median MSE history
        (lab.running.history.History; None: every generation, as lab.evolve's run.history gives)."""
        self.config = config
        self.problem = problem or build_problem(config)
        self.run_id = uuid.uuid4().hex[:12]
        self._subscribers: list = []
        self._lock = threading.Lock()
        self._state = "idle"
        self._history = History(history_limit)  # best and median MSE per generation (bounded if asked)
        self._best: tuple[float, Controller | None] = (float("inf"), None)  # updated with the history
        self._seconds = 0.0
        self._evaluations = 0
        self._summary: RunSummary | None = None
        self._done = threading.Event()
        # generations done when the run last began to hold (paused, every one of them published to
        # the subscribers before this is set); None while it runs or a Step or resume is pending
        self.holding: int | None = None

    # ------------------------------------------------------------------ subscribers
    def subscribe(self, callback):
        """Call callback(event) after every generation; returns a function that unsubscribes."""
        with self._lock:
            self._subscribers.append(callback)
        return lambda: self.unsubscribe(callback)

    def unsubscribe(self, callback) -> None:
        with self._lock:
            if callback in self._subscribers:
                self._subscribers.remove(callback)

    # ------------------------------------------------------------------ reading
    @property
    def state(self) -> str:
        return self._state

    def join(self, timeout: float | None = None) -> RunSummary | None:
        self._done.wait(timeout)
        return self._summary

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def snapshot(self) -> Snapshot:
        with self._lock:
            return Snapshot(self._state, len(self._history), *self._best, self._history.arrays()[1])

    # ------------------------------------------------------------------ for the subclasses
    def _claim(self) -> None:
        """idle -> running, once."""
        with self._lock:
            if self._state != "idle":
                raise RuntimeError(f"this run was already started (state: {self._state})")
            self._state = "running"

    def _set_state(self, old: str, new: str) -> bool:
        with self._lock:
            if self._state != old:
                return False
            self._state = new
            return True

    def _publish(self, event: GenerationEvent) -> None:
        """Record a generation, then hand it to every subscriber, in subscription order."""
        with self._lock:
            self._best = (event.best, event.controller)
            self._history.append(event.best, event.median)
            self._seconds, self._evaluations = event.seconds, event.evaluations
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(event)
            except Exception:
                log.exception("subscriber %r failed; unsubscribed", callback)
                self.unsubscribe(callback)

    def _summarize(self, state: str, controller: Controller | None, error: str | None = None,
                   ended_by: str | None = None) -> RunSummary:
        """The run's summary, the one way every runner makes it: the numbers of the last
        generation published, the final controller scored on the training and held-out goals."""
        p = self.problem
        with self._lock:
            _gens, history, median = self._history.arrays()
            generations = len(self._history)
            seconds, evaluations = self._seconds, self._evaluations
        scored = controller is not None
        return RunSummary(
            run_id=self.run_id, config=self.config, state=state, generations=generations, evaluations=evaluations,
            seconds=seconds, controller=controller,
            train_mse=p.controller_mse(controller) if scored else float("inf"),
            test_mse=p.controller_mse(controller, p.test_goals) if scored else float("inf"),
            history=history, median_history=median, error=error,
            ended_by=ended_by if state == "finished" else None)

    def _conclude(self, summary: RunSummary) -> None:
        """The run has ended: keep its summary, call every subscriber's on_end, release join()."""
        with self._lock:
            self._summary = summary
            self._state = summary.state
            subscribers = list(self._subscribers)
        for callback in subscribers:
            on_end = getattr(callback, "on_end", None)
            if on_end is not None:
                try:
                    on_end(summary)
                except Exception:
                    log.exception("subscriber %r failed at the end of the run", callback)
        self._done.set()


class RemoteRunBase(RunBase):
    """A runner whose generations run elsewhere (lab.running.worker.ProcessRunner: a worker process;
    lab.running.ray_runner.RayRunner: a Ray actor), steered by commands sent there in order. The
    subclass says how a command travels (_command), what stands for the run there (_remote), what a
    Stop before the first generation kills (_stop_early) and how the run there is ended (_end_now);
    `backend` is None (the backend lives there)."""

    backend = None
    SPEED_COMMAND = "speed"  # the command that caps the generations a second there

    def __init__(self, config: TrainConfig, blas_threads: int | None = 1, history_limit: int | None = None):
        super().__init__(config, history_limit=history_limit)
        self.blas_threads, self.history_limit = blas_threads, history_limit
        self._send_lock = threading.Lock()
        self._stop_asked = False
        self._speed: float | None = None
        self._killed: str | None = None  # why the run there was killed (its summary's error)

    @property
    def _remote(self):
        """The process or actor that runs it (None before start)."""
        raise NotImplementedError

    def _command(self, *message) -> None:
        raise NotImplementedError

    def _stop_early(self) -> str | None:
        """Why a Stop now kills the run there at once (it has no generation to keep yet), or None."""
        return None

    def _end_now(self) -> None:
        raise NotImplementedError

    def _sent_at_start(self) -> None:
        """The speed and a Stop asked before start(), sent after the run's own start command."""
        if self._speed is not None:
            self._command(self.SPEED_COMMAND, self._speed)
        if self._stop_asked:
            self._command("stop")

    def run(self) -> RunSummary:
        """Run until done; returns the summary."""
        return self.start().join()

    def pause(self) -> None:
        if self._set_state("running", "paused"):
            self._command("pause")

    def resume(self) -> None:
        if self._set_state("paused", "running"):
            self.holding = None
            self._command("resume")

    def step(self) -> bool:
        """While paused: exactly one more generation there, then paused again (the pause went before
        any step, in the same order). False when the run is not paused."""
        with self._lock:
            if self._state != "paused":
                return False
            self.holding = None
        self._command("step")
        return True

    def set_speed(self, generations_per_second: float | None) -> None:
        """Cap the run at this many generations a second (None: no cap); ValueError for a bad value."""
        speed_period(generations_per_second)  # checked here, where the caller sees the error
        self._speed = generations_per_second
        if self._remote is not None:
            self._command(self.SPEED_COMMAND, generations_per_second)

    def stop(self, wait: bool = True, timeout: float | None = None) -> None:
        """Ask the run to end after the generation in flight; with wait, block until it has."""
        self._stop_asked = True
        if self._remote is None:
            return
        if (why := self._stop_early()) is not None:
            self.kill(why, quiet=True)
        self._command("stop")
        if wait:
            self._done.wait(timeout)

    def kill(self, reason: str, quiet: bool = False) -> None:
        """End the run there at once; it ends "stopped" with the generations received, `reason` as
        its summary's error (logged as a warning unless quiet)."""
        if self._remote is None or self._done.is_set():
            return
        self._killed = reason
        if not quiet:  # in the log of the subclass's module
            logging.getLogger(type(self).__module__).warning("run %s: %s", self.run_id, reason)
        self._end_now()


class TimeLimit:
    """A subscriber that stops a run once its run time (event.seconds: optimizer time, pauses and
    subscribers excluded) reaches `seconds`: runner.subscribe(TimeLimit(runner, 3.0)). The run
    then ends "stopped" after the generation that crossed the limit; how many generations that is
    depends on the machine's speed and load. A run's own time budget is TrainConfig.seconds (the
    same rule, checked by the runner itself, the run then "finished" and its defaults chosen for
    the budget); this subscriber stays for the claims experiment, whose equal-time runs keep the
    equal-budget runs' settings."""

    def __init__(self, runner: "RunBase", seconds: float):
        if not seconds > 0:
            raise ValueError(f"a time limit must be positive seconds, got {seconds!r}")
        self.runner, self.seconds = runner, float(seconds)

    def __call__(self, event: GenerationEvent) -> None:
        if event.seconds >= self.seconds:
            self.runner.stop(wait=False)


def speed_period(generations_per_second: float | None) -> float:
    """Seconds between generation starts for a speed cap (None or inf: no cap, 0.0); ValueError
    naming the value when it is not a positive number."""
    if generations_per_second is None:
        return 0.0
    try:
        gps = float(generations_per_second)
    except (TypeError, ValueError):
        raise ValueError(f"a speed must be generations per second (a positive number) or None, "
                         f"got {generations_per_second!r}") from None
    if not gps > 0:  # also NaN
        raise ValueError(f"a speed must be a positive number of generations per second, got {generations_per_second!r}")
    return 0.0 if gps == float("inf") else 1.0 / gps


class Runner(RunBase):
    def __init__(self, config: TrainConfig, problem: Problem | None = None, blas_threads: int | None = 1,
                 history_limit: int | None = None):
        super().__init__(config, problem, history_limit)
        self.backend: Backend = make_backend(self.problem, config)
        self.blas_threads = blas_threads
        self._wake = threading.Condition(self._lock)  # pause, resume, step, stop and speed changes
        self._steps = 0  # generations Step has asked for while paused, not yet run
        self._period = 0.0  # s between generation starts (set_speed); 0: no cap
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._population_sent = -float("inf")
        self._generations_done = 0
        self._ended_by: str | None = None  # "generations" or "seconds" once the run has run out of either
        self.on_hold = None  # callable(generations done), in the run's thread, each time it starts holding
        self._display = (self.problem.display_goals() if getattr(self.problem, "goal", "position") == "pose"
                         else display_goal(self.problem.arm)[None])

    # ------------------------------------------------------------------ control
    def start(self) -> "Runner":
        """Run in a background thread; returns at once."""
        self._claim()
        self._thread = threading.Thread(target=self._run, name=f"lab-runner-{self.run_id}", daemon=True)
        self._thread.start()
        return self

    def run(self) -> RunSummary:
        """Run in the calling thread until done; returns the summary."""
        self._claim()
        self._run()
        return self._summary

    def pause(self) -> None:
        """Hold the run after the generation in flight."""
        self._set_state("running", "paused")

    def resume(self) -> None:
        if self._set_state("paused", "running"):
            self.holding = None
            self._notify()

    def step(self) -> bool:
        """While paused: run exactly one more generation, then hold again (each call one more).
        False (nothing done) when the run is not paused."""
        with self._wake:
            if self._state != "paused":
                return False
            self._steps += 1
            self.holding = None
            self._wake.notify_all()
        return True

    def set_speed(self, generations_per_second: float | None) -> None:
        """Cap the run at this many generations a second (None: no cap); takes effect at once."""
        period = speed_period(generations_per_second)
        with self._wake:
            self._period = period
            self._wake.notify_all()

    def stop(self, wait: bool = True, timeout: float | None = None) -> None:
        """Ask the run to end after the generation in flight; with wait, block until it has."""
        self._stop.set()
        self._notify()
        if wait and self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        error = None
        try:
            limits = threadpool_limits(self.blas_threads, user_api="blas") if self.blas_threads else None
            try:
                self._loop()
            finally:
                if limits is not None:
                    limits.restore_original_limits()
        except Exception as e:  # a failed run reports, it never takes the process down
            log.exception("run %s failed", self.run_id)
            error = f"{type(e).__name__}: {e}"
        final = "failed" if error else ("stopped" if self._stop.is_set() else "finished")
        self._finish(final, error)

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify_all()

    def _go(self, last_start: float) -> bool:
        """Wait until the next generation may start: not paused (or a Step pending), and at least
        the speed cap's period after the last one started (a Step does not wait for it).
        False when the run is to stop."""
        announce = False
        while True:
            if announce:  # outside the lock: the worker's hook writes to a pipe
                self._held(self._generations_done)
                announce = False
            with self._wake:
                if self._stop.is_set():
                    return False
                if self._state == "paused":
                    if self._steps > 0:
                        self._steps -= 1
                        self.holding = None
                        return True
                    if self.holding is None:  # holding from now: said once
                        self.holding = self._generations_done
                        announce = True
                        continue
                    self._wake.wait()
                    continue
                self.holding = None
                left = last_start + self._period - time.perf_counter()
                if left <= 0:
                    return True
                self._wake.wait(left)

    def _held(self, generations: int) -> None:
        """The run holds (paused) after `generations` generations, every one of them published."""
        hook = self.on_hold
        if hook is not None:
            try:
                hook(generations)
            except Exception:
                log.exception("on_hold hook failed")

    def _loop(self) -> None:
        backend = self.backend
        budget = self.config.seconds
        t_run, last_start = 0.0, -float("inf")
        for index in range(self.config.generations):
            if not self._go(last_start):
                return
            t0 = last_start = time.perf_counter()
            backend.progress = max(index / self.config.generations, t_run / budget if budget else 0.0)
            before = backend.best_mse
            result = backend.step()
            t_run += time.perf_counter() - t0
            self._generations_done = index + 1
            f = result.fitness
            spent = budget is not None and t_run >= budget
            last = spent or index == self.config.generations - 1
            population = self._population(index, last) if self._subscribers else None
            self._publish(GenerationEvent(
                run_id=self.run_id, index=index, best=backend.best_mse, gen_best=float(np.min(f)),
                median=float(np.median(f)), worst=float(np.max(f)), evaluations=backend.evaluations,
                seconds=t_run, controller=backend.best, improved=backend.best_mse < before, extras=result.extras,
                population=population,
            ))
            if spent:
                self._ended_by = "seconds"
                return
        self._ended_by = "generations"

    def _population(self, index: int, last: bool) -> Population | None:
        """The population to send with this generation's event (see GenerationEvent.population):
        its controllers when the last went out POPULATION_PERIOD ago or the run holds after it (or
        ends: `last`)."""
        now = time.perf_counter()
        live = (now - self._population_sent >= POPULATION_PERIOD or self._state == "paused"
                or self._stop.is_set() or last)
        if not (live or population_logged(index)):
            return None
        population = self.backend.candidates(controllers=live)
        if population is None:
            return None
        points = self.backend.candidate_reach(self._display)[:, 0].astype(np.float32)
        if live:
            self._population_sent = now
        return dataclasses.replace(population, points=points)

    def _finish(self, state: str, error: str | None) -> None:
        self._conclude(self._summarize(state, self.backend.best, error, self._ended_by))
