"""Training on a Ray cluster: RayRunner, a runner whose generations run in a Ray actor.

    from lab.running import ray_runner
    ray_runner.connect("local")                  # or "HOST:6379"; ray_runner.RayMissing without Ray
    runner = ray_runner.RayRunner(TrainConfig(robot="planar", method="cmaes"))
    runner.subscribe(callback)                   # called here, in a reader thread, once per generation
    runner.start(); runner.pause(); runner.step(); runner.resume(); runner.stop(); summary = runner.join()

The same interface and events as lab.running.worker.ProcessRunner (both are RunBase), so subscribers
(the class's runs, the app) cannot tell them apart. The run trains in an actor (one CPU of the
cluster, one BLAS thread, a lab Runner inside it) on whichever node Ray picks (spread over the
nodes). The actor keeps each generation's event, encoded as the worker's pipe does (lab/running/pipes.py:
its numbers, the best controller only when it changed); a reader thread here takes what has
accumulated every READ_PERIOD s with one remote call and hands it to the subscribers, so a curve and an
arm move live as for a local run. At the end it takes the actor's summary and ends the actor.

stop() ends the run after its generation in flight; stop_or_kill() kills the actor when it has not
ended `grace` s later (the run then ends "stopped" with the generations received). An actor that dies
on its own (its process killed, its node gone) fails the run: "its Ray worker was lost: ...". So does
one that has not answered for LOST_AFTER s once started. A run whose actor has not been placed
START_WAIT s after Start (no node had a CPU for it) fails, naming the cluster, and its actor is
cancelled; so does one waiting when the cluster is found lost (lab/running/ray_watch.py: its GCS or this
process's raylet not answering, no live node with a CPU), at once, and a run started while it is lost
(`RayRunner.unavailable()` says why before one is made). Ray is imported only here and only when used:
the lab and the app run without it.
"""

from __future__ import annotations

import logging
import os
import threading
import time

from lab.running import pipes
from lab.running.config import TrainConfig
from lab.running.ray_watch import WATCH
from lab.running.runner import RemoteRunBase, RunSummary

log = logging.getLogger(__name__)

READ_PERIOD = 0.05  # s between the reader's takes of the actor's events
STOP_GRACE = 5.0  # s: how long stop_or_kill waits after Stop before it kills the actor
LOST_AFTER = 60.0  # s: a started actor that has not answered a take this long is taken for lost
START_WAIT = 60.0  # s: a run whose actor no node has taken (a CPU) this long after Start gives up
WAIT_STEP = 1.0  # s between a waiting run's looks at the cluster's health (lab/running/ray_watch.py)
OBJECT_STORE_BYTES = 100 * 1024 * 1024  # a local instance's object store: events and summaries are small
INSTALL = 'pip install -e ".[ray]"'
# every process of the cluster's workers: one BLAS thread, one fitness thread (as lab/experiments/executors.py)
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
              "LAB_THREADS": "1"}


class RayMissing(RuntimeError):
    """Ray is not installed here."""


def _ray():
    try:
        import ray
    except ImportError as e:
        raise RayMissing(f"Ray is not installed; install it with {INSTALL}") from e
    return ray


def connect(address: str) -> str:
    """Join the Ray cluster at `address` ("local": start a local instance, a small object store and no
    dashboard); nothing when this process has joined one already. Returns where runs go, in words.
    RayMissing without Ray; ConnectionError (naming the address) when the cluster cannot be reached."""
    ray = _ray()
    _answers(address)
    WATCH.joined(address)
    if not ray.is_initialized():
        kwargs = dict(runtime_env={"env_vars": ONE_THREAD}, log_to_driver=False, logging_level=logging.WARNING)
        try:
            if address == "local":
                ray.init(address="local", include_dashboard=False, object_store_memory=OBJECT_STORE_BYTES, **kwargs)
            else:
                ray.init(address=address, **kwargs)
        except Exception as e:  # noqa: BLE001 - ray raises ConnectionError, ValueError, RuntimeError, ...
            hint = ("" if address == "local" or os.environ.get("RAY_AUTH_MODE") == "token" else
                    "; a cluster with token authentication (`ray start`'s default) also needs RAY_AUTH_MODE=token "
                    "here and its token (~/.ray/auth_token or RAY_AUTH_TOKEN)")
            raise ConnectionError(f"cannot join the Ray cluster at {address}: {_first_line(e)}{hint}") from e
    return describe(address)


def _answers(address: str, timeout: float = 5.0) -> None:
    """ConnectionError unless something listens at a HOST:PORT address (ray.init would retry for
    minutes); ValueError for an address that is none. "local", "auto" and ray:// addresses pass."""
    if address in ("local", "auto") or "://" in address:
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"a Ray address is HOST:PORT (as `ray start --head` prints) or local, got {address!r}")
    import socket

    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as e:
        raise ConnectionError(f"cannot join the Ray cluster at {address}: nothing answers there "
                              f"({e.strerror or e})") from None


def cpus() -> int:
    """The cluster's CPUs (at least 1)."""
    return max(1, int(_ray().cluster_resources().get("CPU", 1)))


def describe(address: str = "") -> str:
    ray = _ray()
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    where = "a local Ray instance" if address == "local" else f"the Ray cluster at {address}"
    return f"{where} ({cpus()} CPUs on {len(nodes)} node{'s' if len(nodes) != 1 else ''})"


def _first_line(e: BaseException, most: int = 300) -> str:
    text = " ".join(str(e).strip().splitlines()[:1]) or type(e).__name__
    return text if len(text) <= most else text[:most - 3] + "..."


def _actor_state(actor) -> str | None:
    """The actor's state in the GCS ("PENDING_CREATION" until a node has taken it and its __init__
    has returned, "ALIVE", "DEAD"), or None when it cannot be read (ray._private.state: no public
    call reads it without the dashboard)."""
    try:
        from ray._private import state

        return state.actors(actor._actor_id.hex()).get("State")
    except Exception:  # noqa: BLE001 - an API of Ray's that moved: the plain bound applies
        return None


class _NotStarted(Exception):
    """The run's actor will not start: why (naming the cluster)."""


def _why_lost(e: BaseException) -> str:
    """A dead actor's error in a few words: "the actor died (it was killed by `ray.kill`)"."""
    text = str(e)
    because = text.find("The actor is dead because ")
    if because < 0:
        return _first_line(e)
    reason = text[because + len("The actor is dead because "):].split(". ")[0].strip().rstrip(".")
    return f"the actor died ({reason})"


class RunActor:
    """In a Ray worker: a lab Runner and the events it has published, encoded, not yet taken. Its
    __init__ only keeps the arguments (the actor is "ALIVE" once a node has taken it: the server tells
    a run that waits for a CPU from one whose worker is loading the lab); start() makes the Runner."""

    def __init__(self, config: TrainConfig, run_id: str, blas_threads: int | None, history_limit: int | None):
        self._args = (config, run_id, blas_threads, history_limit)
        self._lock = threading.Lock()
        self._events: list = []
        self._held: int | None = None
        self._encode = pipes.EventEncoder()
        self.runner = self.error = None

    def _make(self) -> None:
        config, run_id, blas_threads, history_limit = self._args
        os.environ.update(ONE_THREAD)  # before the lab's kernels load in this worker
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, user_api="blas")
        from lab.running.runner import Runner

        try:
            self.runner = Runner(config, blas_threads=blas_threads, history_limit=history_limit)
        except Exception as e:  # noqa: BLE001 - told to the server as the run's failure
            self.runner, self.error = None, f"{type(e).__name__}: {e}"
            return
        self.runner.run_id = run_id
        self.runner.subscribe(self._forward)
        self.runner.on_hold = self._on_hold

    def _forward(self, event) -> None:
        encoded = self._encode(event)
        with self._lock:
            self._events.append(encoded)

    def _on_hold(self, generations: int) -> None:
        with self._lock:
            self._held = generations

    def start(self) -> dict:
        """Start the run (unless it could not be made); where it runs."""
        import ray

        self._make()
        if self.runner is not None:
            self.runner.start()
        context = ray.get_runtime_context()
        return {"node": context.get_node_id(), "pid": os.getpid(), "error": self.error}

    def take(self) -> tuple[list, int | None, RunSummary | None, str | None]:
        """(the events published since the last take, the generations held at (paused) or None, the
        summary once the run has ended and every event is taken, the error of a run that could not start)."""
        if self.runner is None:
            return [], None, None, self.error
        done = self.runner.done  # read before the events: the last event is taken with the summary
        with self._lock:
            events, self._events = self._events, []
            held, self._held = self._held, None
        return events, held, (self.runner.join() if done else None), None

    def pause(self) -> None:
        if self.runner is not None:
            self.runner.pause()

    def resume(self) -> None:
        if self.runner is not None:
            self.runner.resume()

    def step(self) -> None:
        if self.runner is not None:
            self.runner.step()

    def set_speed(self, generations_per_second) -> None:
        if self.runner is not None:
            self.runner.set_speed(generations_per_second)

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop(wait=False)


_actor_class = None
_actor_lock = threading.Lock()


def _remote_actor():
    global _actor_class
    with _actor_lock:
        if _actor_class is None:
            # one CPU each; never restarted or retried: a lost actor fails its run, which the class can rerun
            _actor_class = _ray().remote(num_cpus=1, max_restarts=0, max_task_retries=0)(RunActor)
        return _actor_class


class RayRunner(RemoteRunBase):
    """A runner (see lab.running.runner) that trains in a Ray actor. `backend` is None here: the
    backend lives in the actor. Needs a joined cluster (connect, or ray.init)."""

    SPEED_COMMAND = "set_speed"

    def __init__(self, config: TrainConfig, blas_threads: int | None = 1, history_limit: int | None = None,
                 spare: bool = False):
        """spare: ignored (no prestarted actor; the argument is ProcessRunner's)."""
        super().__init__(config, blas_threads=blas_threads, history_limit=history_limit)
        self.ray = _ray()
        self._actor = None
        self._started = False  # the actor has started its run
        self.stop_grace = STOP_GRACE
        self.start_wait = START_WAIT  # s: how long it waits for a node to take its actor (a CPU)
        self.node_id: str | None = None  # the Ray node it trains on, once started
        self.pid: int | None = None  # the actor's process there

    @property
    def _remote(self):
        return self._actor

    @staticmethod
    def unavailable() -> str | None:
        """None while the cluster answers, else why a new run would fail at once, naming the cluster
        (lab/running/ray_watch.py; never blocks, probes at most every few seconds)."""
        return WATCH.lost()

    @property
    def preparing(self) -> str | None:
        """"waiting for a CPU on the Ray cluster" until its actor has started the run; else None."""
        if self._actor is None or self._started or self._done.is_set():
            return None
        return "waiting for a CPU on the Ray cluster"

    # ------------------------------------------------------------------ control
    def start(self) -> "RayRunner":
        """Hand the run to a new actor; returns at once (the actor starts when the cluster has a CPU)."""
        self._claim()
        actor = _remote_actor().options(scheduling_strategy="SPREAD")
        self._actor = actor.remote(self.config, self.run_id, self.blas_threads, self.history_limit)
        started = self._actor.start.remote()
        self._sent_at_start()
        threading.Thread(target=self._read, args=(started,), name=f"lab-ray-{self.run_id}", daemon=True).start()
        return self

    def _stop_early(self) -> str | None:
        # still waiting for a CPU: nothing to keep
        return None if self._started or self._done.is_set() else "stopped before its Ray worker started"

    def stop_or_kill(self, grace: float | None = None) -> bool:
        """Stop; an actor that has not ended the run `grace` s later (default: stop_grace) is killed,
        and the run ends "stopped" with the generations received. Returns whether it had to be killed."""
        grace = self.stop_grace if grace is None else grace
        self.stop(wait=True, timeout=grace)
        if self._actor is None or self._done.is_set():
            return False
        self.kill(f"its Ray worker did not answer Stop within {grace:g} s and was killed")
        self._done.wait(max(grace, 5.0))
        return True

    def _end_now(self) -> None:
        try:
            self.ray.kill(self._actor, no_restart=True)
        except Exception:  # noqa: BLE001 - already gone
            pass

    def _command(self, method: str, *args) -> None:
        with self._send_lock:
            try:
                getattr(self._actor, method).remote(*args)
            except Exception:  # noqa: BLE001 - the actor is gone: the reader reports how
                pass

    # ------------------------------------------------------------------ the reader thread
    def _read(self, started) -> None:
        ray = self.ray
        decode, summary, error, lost = pipes.EventDecoder(self.run_id), None, None, None
        try:
            where = self._wait_started(started)  # a kill ends the wait (ray.get raises)
            self.node_id, self.pid, error = where["node"], where["pid"], where["error"]
            self._started = True
            while summary is None and error is None:
                try:
                    events, held, summary, error = ray.get(self._actor.take.remote(), timeout=LOST_AFTER)
                except ray.exceptions.GetTimeoutError:
                    lost = f"it has not answered for {LOST_AFTER:g} s"
                    self.kill(f"its Ray worker was lost: {lost}", quiet=True)
                    self._killed = None
                    break
                for body in events:
                    self._publish(decode(body))
                if held is not None:
                    with self._lock:
                        self.holding = held if self._state == "paused" else None
                if summary is None and error is None:
                    time.sleep(READ_PERIOD)  # a batch of generations per take, not a call per generation
        except _NotStarted as e:  # no CPU for it in time, or the cluster lost
            lost = e
        except Exception as e:  # noqa: BLE001 - the actor died (killed, its process or node gone)
            lost = _why_lost(e)
        if summary is not None:
            self._conclude(summary)
        elif self._killed is not None:
            self._conclude(self._summarize("stopped", decode.controller, self._killed))
        elif error is not None:
            self._conclude(self._summarize("failed", decode.controller, error))
        else:
            why = (f"its Ray worker never started: {lost}" if isinstance(lost, _NotStarted) else
                   f"its Ray worker was lost: {lost}")
            log.warning("run %s: %s", self.run_id, why)
            self._conclude(self._summarize("failed", decode.controller, why))
        if self._actor is not None:
            try:  # the run has ended: its CPU goes back to the cluster (a pending actor is cancelled)
                ray.kill(self._actor, no_restart=True)
            except Exception:  # noqa: BLE001
                pass

    def _wait_started(self, started) -> dict:
        """The actor's answer to start(); _NotStarted, naming the cluster, when the cluster is found
        lost meanwhile (looked at every WAIT_STEP s), when no node has taken the actor start_wait s
        after Start, or when one has and start() has not answered LOST_AFTER s later."""
        ray, t0, taken = self.ray, time.monotonic(), None
        while True:
            try:
                return ray.get(started, timeout=WAIT_STEP)
            except ray.exceptions.GetTimeoutError:
                pass
            if (lost := WATCH.lost()) is not None:
                raise _NotStarted(lost)
            now = time.monotonic()
            if taken is None and now - t0 > self.start_wait:
                if _actor_state(self._actor) != "ALIVE":
                    raise _NotStarted(f"no node of {WATCH.where()} took it within {self.start_wait:g} s "
                                      "(every CPU busy, or the cluster lost)")
                taken = now  # it has its CPU: its worker is loading the lab
            if taken is not None and now - taken > LOST_AFTER:
                raise _NotStarted(f"its worker on {WATCH.where()} has not started the run {LOST_AFTER:g} s after "
                                  "it took it")
