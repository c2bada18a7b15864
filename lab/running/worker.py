"""Training in a process of its own: ProcessRunner, a Runner whose generations run elsewhere.

    runner = ProcessRunner(TrainConfig(robot="planar", method="cmaes"))
    runner.subscribe(callback)       # called here, in a reader thread, once per generation
    runner.start(); runner.pause(); runner.step(); runner.resume(); runner.stop(); summary = runner.join()
    runner.set_speed(5)              # at most 5 generations a second (None: no cap)

The same interface and events as lab.running.runner.Runner (both are RunBase), so subscribers (the
Rerun logger, the app) cannot tell them apart. What differs is where the optimizer runs: in
`python -m lab.running.worker`, with an interpreter and a GIL of its own, so a busy process beside it
(the app's server, its tabs, its redraws) no longer slows it down, and it cannot slow them.
The worker sends each generation through a pipe (lab/running/pipes.py: its numbers, and the best
controller when it changed); pause, step, speed, resume and stop go the other way. A Step
is exact: the parent counts it as asked only while it knows the run paused, and the worker's
Runner runs one generation per Step it receives while paused. A worker whose parent
goes away stops its run and exits.

prestart() keeps one worker started and warmed up (modules imported, numba kernels loaded)
for the next start(), so a click on Start trains at once instead of after ~2 s. A worker warms up
before its run (lab/running/warmup.py: on a cold cache about a minute of compiling, the opened
robot's kernels for the method the page opens with first; a spare does every step, a worker with its
run waiting only the steps that run needs) and tells each step through a pipe of its own:
`warmup_status()`, `ProcessRunner.preparing` and `on_warmup(callback)` say what a run waits for. A
spare that is compiling a step the run does not need when Start comes is ended, and the run goes to a
fresh worker (it loads what the spare finished from numba's cache): a run never waits for kernels it
does not call. A warming worker whose parent goes away exits at once.
"""

from __future__ import annotations

import json
import logging
import os
import select
import signal
import subprocess
import sys
import threading
import time
from itertools import chain


from lab.running import pipes
from lab.running.config import TrainConfig
from lab.running.runner import RemoteRunBase

# s: how long stop_or_kill waits for a worker to end its run after Stop before killing it (a worker
# that does not answer: stopped with SIGSTOP, hung in a native call, swapped out)
STOP_GRACE = 5.0
# s: the reader takes the worker's events in batches this far apart (hundreds of generations a second
# would otherwise wake it, and take the GIL from the app's threads, hundreds of times a second)
ANSWERED_WAIT = 10.0  # s Stop waits for a worker that answered (its pipe holds unread data) to end its run
READ_PERIOD = 0.02

log = logging.getLogger(__name__)

_spare: subprocess.Popen | None = None  # a started worker waiting for its run (see prestart)
_keep_spare = False
_spare_lock = threading.Lock()
_first_robot = "planar"  # the robot whose kernels a spare compiles first (prestart)
_first_config: dict | None = None  # the run a spare compiles for first (TrainConfig.to_dict(); None: the robot's defaults)


class Warmup:
    """What a worker's warm-up is doing, as its progress pipe tells it (lab/running/warmup.py)."""

    def __init__(self, pid: int):
        self.pid = pid
        self.index = self.steps = 0
        self.label = ""
        self.key = ""  # the step's kernels (lab.running.warmup.Step.key)
        self.expected: float | None = 0.0  # s the step in progress is expected to take (None: no estimate yet)
        self.since = time.monotonic()  # when it began
        self.started = time.monotonic()
        self.done = False
        self.seconds = 0.0  # s the whole warm-up took (when done)
        self.compiling = False  # numba compiles (a kernel missed the cache): the warm-up is worth telling
        self.abandoned = False  # a spare ended by the parent (other kernels came first): its end is not told

    def describe(self) -> str | None:
        """"step 2 of 7 (CMA-ES for serial arms), about 12 s" while it compiles (past the
        estimate: "25 s so far (about 11 s expected)"); None when done or while every
        kernel so far has loaded from the cache (milliseconds each)."""
        if self.done or not self.compiling or not self.steps:
            return None
        spent = time.monotonic() - self.since
        if self.expected is None:  # nothing measured on this machine yet
            when = f"{spent:.0f} s so far (the first on this machine: no estimate yet)"
        elif spent < self.expected - 0.5:
            when = f"about {self.expected - spent:.0f} s"
        else:
            when = f"{spent:.0f} s so far (about {self.expected:.0f} s expected)"
        return f"step {self.index} of {self.steps} ({self.label}), {when}"


_listeners: list = []  # on_warmup's callbacks


def on_warmup(callback) -> None:
    """callback(warmup: Warmup) is called, in a reader thread, as each worker's warm-up begins a
    step and as it ends (warmup.done)."""
    _listeners.append(callback)


def warmup_status() -> str | None:
    """What the spare worker's warm-up is doing ("step 2 of 7 (...), about 12 s"), None when no
    warm-up is going."""
    with _spare_lock:
        w = getattr(_spare, "warmup", None)
    return w.describe() if w is not None else None


def _tell(warmup: Warmup) -> None:
    for callback in list(_listeners):
        try:
            callback(warmup)
        except Exception:  # noqa: BLE001 - a listener's fault is not the worker's
            log.exception("warm-up listener failed")


def _follow(fd: int, warmup: Warmup) -> None:
    """Read a worker's progress pipe: "step INDEX STEPS EXPECTED_S KEY LABEL" lines (EXPECTED_S "-":
    no estimate), "compiling" (numba missed its cache), "done SECONDS"."""
    with os.fdopen(fd, "r", encoding="utf-8", errors="replace") as f:
        for line in f:
            kind, _, rest = line.rstrip("\n").partition(" ")
            if kind == "compiling":
                warmup.compiling = True
                _tell(warmup)
            elif kind == "step":
                index, steps, expected, key, label = rest.split(" ", 4)
                warmup.index, warmup.steps, warmup.key, warmup.label = int(index), int(steps), key, label
                warmup.expected = None if expected == "-" else float(expected)
                warmup.since = time.monotonic()
                _tell(warmup)
            elif kind == "done":
                warmup.seconds = float(rest)
                break
    warmup.seconds = warmup.seconds or time.monotonic() - warmup.started
    warmup.done = True  # also when the worker ended without saying so (killed)
    if not warmup.abandoned:  # ended by us for another: no "training kernels ready" of kernels it never finished
        _tell(warmup)


class ProcessRunner(RemoteRunBase):
    """A Runner (see lab.running.runner) that trains in a worker process. `backend` is None here: the
    backend lives in the worker."""

    def __init__(self, config: TrainConfig, blas_threads: int | None = 1, history_limit: int | None = None,
                 spare: "bool | WarmWorkers" = True):
        """spare: take the prestarted worker when there is one (False: always a worker of its own, so
        that runs beside the app's own, a class's students', leave the spare to the app's next Start;
        a WarmWorkers: one of its warm workers, which leaves the app's spare alone too)."""
        super().__init__(config, blas_threads=blas_threads, history_limit=history_limit)
        self.use_spare = spare
        self._proc: subprocess.Popen | None = None
        self.stop_grace = STOP_GRACE  # s, see stop_or_kill

    @property
    def _remote(self):
        return self._proc

    @property
    def pid(self) -> int | None:
        """The worker's process id (None before start)."""
        return self._proc.pid if self._proc is not None else None

    @property
    def preparing(self) -> str | None:
        """While the worker still compiles what this run needs: "step 2 of 7 (...), about 12 s";
        else None."""
        w = getattr(self._proc, "warmup", None)
        return w.describe() if w is not None and not self._done.is_set() else None

    # ------------------------------------------------------------------ control
    def start(self) -> "ProcessRunner":
        """Hand the run to a worker process; returns at once."""
        self._claim()
        if isinstance(self.use_spare, WarmWorkers):
            self._proc = self.use_spare.take(self.config)
        else:
            self._proc = _take_worker(self.config) if self.use_spare else _spawn(spare=False)
        self._command("run", self.config, self.run_id, self.blas_threads, self.history_limit)
        self._sent_at_start()
        threading.Thread(target=self._read, name=f"lab-worker-{self.run_id}", daemon=True).start()
        return self

    def _stop_early(self) -> str | None:
        # no generation yet, and none before its kernels are compiled
        return None if self.preparing is None else "stopped while the training kernels were being prepared"

    def stop_or_kill(self, grace: float | None = None) -> bool:
        """Stop; a worker that has not ended its run `grace` s later (default: stop_grace) is killed
        (SIGKILL: a process stopped by SIGSTOP cannot act on SIGTERM). The run then ends "stopped"
        with the generations the worker had sent (its summary's error says it was killed). Returns
        whether the worker had to be killed."""
        grace = self.stop_grace if grace is None else grace
        self.stop(wait=True, timeout=grace)
        if self._proc is None or self._done.is_set():
            return False
        # a worker that answered (it has ended, or sent what the reader, slowed by a busy machine, has
        # not read yet) is not killed: its reader concludes with what it sent. It may take longer than
        # the grace to end its run and exit on a loaded machine (1.7-2.3 s at load 6), so it is given
        # ANSWERED_WAIT while its pipe holds what the reader has not read; a silent worker is killed now
        deadline = time.monotonic() + max(grace, ANSWERED_WAIT)
        while self._answered() and not self._done.is_set() and time.monotonic() < deadline:
            self._done.wait(0.05)
        if self._done.is_set() or self._proc.poll() is not None:
            self._done.wait(max(grace, 5.0))
            return False
        self.kill(f"the training process did not answer Stop within {grace:g} s and was killed")
        self._done.wait(max(grace, 5.0))  # the reader sees the end of the pipe and concludes
        return True

    def _answered(self) -> bool:
        """The worker has ended, or has written to its pipe what the reader has not read yet."""
        if self._proc.poll() is not None:
            return True
        try:
            readable, _, _ = select.select([self._proc.stdout], [], [], 0)
        except (OSError, ValueError):  # closed by the reader: it has read the end
            return True
        return bool(readable)

    def _end_now(self) -> None:
        try:
            self._proc.kill()
        except OSError:  # already gone
            pass

    def _command(self, *message) -> None:
        with self._send_lock:
            try:
                pipes.send(self._proc.stdin.fileno(), message)
            except (OSError, ValueError):  # the worker is gone: the reader reports how
                pass

    # ------------------------------------------------------------------ the reader thread
    def _read(self) -> None:
        decode, summary, error = pipes.EventDecoder(self.run_id), None, None
        for batch in pipes.messages(self._proc.stdout.fileno()):
            for kind, body in batch:
                if kind == "event":
                    self._publish(decode(body))
                elif kind == "held":  # after every event it had sent: the count is final until a step
                    with self._lock:
                        self.holding = body if self._state == "paused" else None
                elif kind == "end":
                    summary = body
                elif kind == "failed":
                    error = body
            if summary is not None:  # its last message: the run ends now, not after its interpreter's teardown (~0.5-1 s)
                break
            time.sleep(READ_PERIOD)  # the next read takes this while's events at once: not a wake-up per generation
        self._proc.stdin.close()
        self._proc.stdout.close()
        if summary is not None:  # it exits on its own; reaped aside
            threading.Thread(target=self._proc.wait, name=f"lab-worker-exit-{self.run_id}", daemon=True).start()
            code = None
        else:
            code = self._proc.wait()
        if summary is None and self._killed is not None:  # killed by stop_or_kill: what it had sent counts
            self._conclude(self._summarize("stopped", decode.controller, self._killed))
        elif summary is None:
            self._conclude(self._summarize("failed", decode.controller,
                                           error or f"the training process exited with code {code}"))
        else:
            self._conclude(summary)
        if _keep_spare:
            prestart()

def prestart(robot: str | None = None, first: TrainConfig | None = None) -> None:
    """Keep a warmed-up worker ready for the next start(), now and after every run. robot: the one the
    next run is likely on (the app's first), whose kernels its warm-up compiles first; first: that
    run's settings, when they are not the robot's defaults (the app's Start has a time budget on a
    real arm, and a budget can change the heads: its kernels)."""
    global _spare, _keep_spare, _first_robot, _first_config
    with _spare_lock:
        _keep_spare = True
        if first is not None:
            before = _first_key()
            _first_robot, _first_config = first.robot, first.to_dict()
            if _spare is not None and _spare.poll() is None and _first_key() != before:
                _spare.warmup.abandoned = True
                _spare.kill()  # started a moment ago for other kernels (python -m app's, before the page's settings)
                threading.Thread(target=_spare.wait, daemon=True).start()
                _spare = None
        elif robot is not None and robot != _first_robot:
            _first_robot, _first_config = robot, None
        if _spare is None or _spare.poll() is not None:
            _spare = _spawn(spare=True)


class WarmWorkers:
    """Workers kept started and warmed up for runs beside the app's own (a class's students'), apart
    from the app's spare: `take` hands one to a run and starts its replacement at once, so the next
    run's worker has imported the lab and loaded its kernels while this one trained (~2 s a run saved
    on a 2-core machine: docs/results/class.md). Each warms up only the kernels of the run taken last
    (the class's next is most likely alike), not every method as the app's spare does: a worker a run
    costs no more CPU than a fresh one; one compiling kernels the run does not call is ended and the
    run gets a fresh worker (one of other settings loads its own kernels once it has it). Nothing is
    started before the first take (a server nobody runs a student run on starts no process for it)."""

    def __init__(self, size: int):
        self.size = max(1, int(size))
        self._ready: list[subprocess.Popen] = []  # started, oldest first
        self._lock = threading.Lock()
        self.closed = False
        self.started = 0  # worker processes started by this pool, fresh ones for a run included

    def pids(self) -> list[int]:
        """The waiting workers' process ids."""
        with self._lock:
            return [p.pid for p in self._ready if p.poll() is None]

    def take(self, config: TrainConfig | None = None) -> subprocess.Popen:
        """A warm worker for a run of `config` (a fresh one when none is ready), its replacement started."""
        with self._lock:
            proc = None
            while self._ready and proc is None:
                candidate = self._ready.pop(0)
                if candidate.poll() is None:
                    proc = candidate
            if proc is not None and config is not None and _busy_elsewhere(proc.warmup, config):
                proc.warmup.abandoned = True
                proc.kill()  # its finished steps stay in numba's cache
                threading.Thread(target=proc.wait, daemon=True).start()
                proc = None
            if proc is None:
                proc = _spawn(spare=False)
                self.started += 1
            self._fill(config)
            return proc

    def _fill(self, config: TrainConfig | None) -> None:
        self._ready = [p for p in self._ready if p.poll() is None]
        while not self.closed and len(self._ready) < self.size:
            self._ready.append(_spawn(spare=True, only=config))
            self.started += 1

    def close(self) -> None:
        """End the waiting workers (the runs they gave away go on); take() then starts fresh ones, unkept."""
        with self._lock:
            self.closed, ready, self._ready = True, self._ready, []
        for proc in ready:
            proc.warmup.abandoned = True
            proc.kill()
            threading.Thread(target=proc.wait, daemon=True).start()


def _first_key() -> str | None:
    """The kernels a spare compiles first (lab.running.warmup.run_key); None when they cannot be told."""
    from lab.running import warmup

    try:
        config = TrainConfig.from_dict(_first_config) if _first_config else warmup.default_config(_first_robot)
        return warmup.run_key(config)
    except ValueError:
        return None


def _take_worker(config: TrainConfig | None = None) -> subprocess.Popen:
    """The spare for a run of `config`; a fresh worker when there is none, or when the spare is
    compiling kernels that run does not call (it is ended: the run would wait for its step)."""
    global _spare
    with _spare_lock:
        proc, _spare = _spare, None
    if proc is not None and proc.poll() is None:
        if config is None or not _busy_elsewhere(proc.warmup, config):
            return proc
        log.info("the spare worker compiles %s, which this run does not call: a fresh worker instead",
                 proc.warmup.label)
        proc.warmup.abandoned = True
        proc.kill()  # its finished steps stay in numba's cache; the next spare compiles the rest
        threading.Thread(target=proc.wait, daemon=True).start()
    return _spawn(spare=False)


def _busy_elsewhere(warmup: Warmup, config: TrainConfig) -> bool:
    """Whether a warm-up is compiling (not loading) a step a run of `config` does not need."""
    if warmup.done or not warmup.compiling or not warmup.key:
        return False
    from lab.running.warmup import Step, run_key

    return not Step(0, 0, "", warmup.key, lambda: None).needed_by(run_key(config))


def _spawn(spare: bool, only: TrainConfig | None = None) -> subprocess.Popen:
    """A worker; only: a spare that warms up only the kernels a run of these settings needs, then waits."""
    read, write = os.pipe()  # the warm-up's progress (Warmup)
    robot, config = (only.robot, only.to_dict()) if only is not None else (_first_robot, _first_config)
    try:
        first = ["--first-config", json.dumps(config)] if config is not None else []
        proc = pipes.start("lab.running.worker", "--progress", str(write), "--first-robot", robot, *first,
                           *(["--spare"] if spare else []), *(["--only-first"] if only is not None else []),
                           pass_fds=(write,))
    except BaseException:
        os.close(read)
        raise
    finally:
        os.close(write)
    pipes.grow(proc.stdout.fileno())
    proc.warmup = Warmup(proc.pid)
    threading.Thread(target=_follow, args=(read, proc.warmup), name=f"lab-warmup-{proc.pid}", daemon=True).start()
    return proc


def _warm_up(stream, progress_fd: int | None, spare: bool, first_robot: str = "planar", first_config=None,
             only_first: bool = False):
    """In the worker: compile the kernels (lab/running/warmup.py) before the run, each step told on
    progress_fd. A spare compiles every step, `first_robot`'s for the default method (or the run of
    `first_config`, a TrainConfig.to_dict()) first, until its
    run arrives (only_first: `first_config`'s steps, then it waits); from then on (and in a worker
    started with its run) only the steps that run needs: the kinematics and its own kernels. Returns the first batch of messages (None: the parent went
    away)."""
    from lab.running import warmup

    fd = sys.stdin.fileno()
    warmed = threading.Event()

    def watch() -> None:  # the parent gone (Ctrl-C, a crash): no minute of compiling for nobody
        poll = select.poll()
        poll.register(fd, 0)  # only POLLHUP / POLLERR: the run command is left for the stream
        while not warmed.is_set():
            if poll.poll(200):
                os._exit(0)

    def pending() -> bool:
        poll = select.poll()
        poll.register(fd, select.POLLIN)
        return bool(poll.poll(0))

    def say(text: str) -> None:
        if progress_fd is not None:
            try:
                os.write(progress_fd, (text + "\n").encode())
            except OSError:
                pass

    threading.Thread(target=watch, name="lab-worker-parent", daemon=True).start()
    compiles = warmup.CompileWatch(lambda: say("compiling"))
    t = time.perf_counter()
    first, done = None, set()  # the run's first messages; the keys of the steps done
    estimate = warmup.Estimate()
    try:
        try:
            steps = warmup.plan(TrainConfig.from_dict(first_config) if first_config else None, robot=first_robot)
            if only_first and first_config:
                steps = warmup.for_run(steps, set(), TrainConfig.from_dict(first_config))
        except Exception:  # noqa: BLE001 - an unknown robot: the run itself says so
            log.exception("cannot plan the warm-up for %s", first_robot)
            steps = []
        while steps:
            if first is None and (not spare or pending()):
                first = next(stream, None)
                if first is None:
                    return None
                try:
                    steps = warmup.for_run(steps, done, first[0][1])
                except Exception:  # noqa: BLE001 - a config that cannot run: the run itself says so
                    log.exception("cannot plan the warm-up for this run")
                    break
                continue
            step, steps = steps[0], steps[1:]
            expected = estimate.seconds(step)
            say(f"step {step.index} {step.steps} {'-' if expected is None else f'{expected:.1f}'} {step.key} "
                f"{step.label}")
            count, t_step = compiles.count, time.perf_counter()
            try:
                step.work()
            except Exception:  # noqa: BLE001 - the run itself reports what fails
                log.exception("warm-up step %s failed", step.label)
            estimate.finished(step, time.perf_counter() - t_step, compiles.count > count)
            done.add(step.key)
    finally:
        say(f"done {time.perf_counter() - t:.1f}")
        warmed.set()
        if progress_fd is not None:
            os.close(progress_fd)
    return first if first is not None else next(stream, None)


# ---------------------------------------------------------------------- the worker process
def main(argv: list[str]) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which stops the run
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # so does a closing terminal
    out = pipes.claim_stdout()
    progress_fd = int(argv[argv.index("--progress") + 1]) if "--progress" in argv else None
    from lab.running.runner import Runner

    stream = pipes.messages(sys.stdin.fileno())
    first_robot = argv[argv.index("--first-robot") + 1] if "--first-robot" in argv else "planar"
    first_config = json.loads(argv[argv.index("--first-config") + 1]) if "--first-config" in argv else None
    first = _warm_up(stream, progress_fd, spare="--spare" in argv, first_robot=first_robot, first_config=first_config,
                     only_first="--only-first" in argv)
    if not first:
        return 0  # a spare whose parent ended without using it
    (_, config, run_id, blas_threads, *more), pending = first[0], first[1:]
    try:  # the worker keeps the history its parent keeps (a bounded one: memory flat over long runs)
        runner = Runner(config, blas_threads=blas_threads, history_limit=more[0] if more else None)
    except Exception as e:
        pipes.send(out, ("failed", f"{type(e).__name__}: {e}"))
        return 1
    runner.run_id = run_id
    rows = pipes.EventEncoder()

    def forward(event) -> None:
        try:
            pipes.send(out, ("event", rows(event)))
        except OSError:  # the parent is gone
            runner.stop(wait=False)

    def commands() -> None:
        actions = {"pause": runner.pause, "resume": runner.resume, "step": runner.step,
                   "speed": runner.set_speed, "stop": lambda: runner.stop(wait=False)}
        for batch in chain([pending], stream):
            for message in batch:
                actions[message[0]](*message[1:])
        runner.stop(wait=False)  # end of input: the parent is gone

    def held(generations: int) -> None:
        try:
            pipes.send(out, ("held", generations))
        except OSError:
            runner.stop(wait=False)

    runner.subscribe(forward)
    runner.on_hold = held
    threading.Thread(target=commands, name="lab-worker-commands", daemon=True).start()
    summary = runner.run()
    try:
        pipes.send(out, ("end", summary))
    except OSError:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
