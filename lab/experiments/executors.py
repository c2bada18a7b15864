"""Where runs execute: local processes (one per core) or a Ray cluster.

Both give `submit(train, spec) -> concurrent.futures.Future` whose result is `runs.attempt`'s dict,
so one scheduler (reproduce.py) serves both. A worker process that dies (a crash, not an
exception) fails the futures in flight; the pool is rebuilt on the next submit, and the
scheduler retries those runs like any other failure.

Workers use one BLAS thread each: OPENBLAS_NUM_THREADS (and friends) are set in the environment
the workers start with, before they import numpy; lab's Runner also limits BLAS while it runs.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from lab.experiments.runs import attempt

PARENT_VAR = "LAB_EXPERIMENT_PARENT"
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
              "LAB_THREADS": "1"}


def _init_worker() -> None:
    _end_with_parent()
    os.environ.update(ONE_THREAD)  # for anything the worker starts later
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def _end_with_parent() -> None:
    """A worker ends with the process that started it, however that one ends (even SIGKILL): the
    kernel sends it SIGKILL then (Linux prctl PR_SET_PDEATHSIG), and a thread checks the parent too."""
    parent = int(os.environ.get(PARENT_VAR) or os.getppid())  # the executor's process, set before the spawn
    if os.getppid() != parent:  # it ended while this worker was starting
        os._exit(1)
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the thread below still ends it
        pass

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


class ProcessExecutor:
    """Runs in `workers` spawned processes (default: all cores)."""

    name = "processes"

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1
        self._pool: ProcessPoolExecutor | None = None
        self._saved_env: dict | None = None

    def __enter__(self) -> "ProcessExecutor":
        # spawned workers inherit this environment when they start, before importing numpy
        self._saved_env = {k: os.environ.get(k) for k in (*ONE_THREAD, PARENT_VAR)}
        os.environ.update(ONE_THREAD, **{PARENT_VAR: str(os.getpid())})
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if self._pool is not None:
            if exc_type is not None:  # Ctrl-C or an error: end the workers now, keep what is stored
                for proc in list(getattr(self._pool, "_processes", {}).values()):
                    proc.terminate()
            self._pool.shutdown(wait=exc_type is None, cancel_futures=True)
        for k, v in (self._saved_env or {}).items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"), initializer=_init_worker)

    def submit(self, train, spec) -> Future:
        if self._pool is None:
            self._pool = self._new_pool()
        try:
            return self._pool.submit(attempt, train, spec)
        except BrokenProcessPool:  # a worker died: start a fresh pool
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            return self._pool.submit(attempt, train, spec)

    def describe(self) -> str:
        return f"{self.workers} local processes (spawn, one BLAS thread each)"


class RayExecutor:
    """Runs as Ray tasks (one CPU each) on the cluster at `address`.

    address "local" starts a local instance; an already initialized Ray (ray.init in this process,
    as the tests do) is used as it is.
    """

    name = "ray"

    def __init__(self, address: str):
        try:
            import ray
        except ImportError as e:
            raise RuntimeError("--ray needs Ray: pip install -e '.[ray]'") from e
        self.ray = ray
        self.address = address
        self._started = False
        self._task = None

    def __enter__(self) -> "RayExecutor":
        ray = self.ray
        if not ray.is_initialized():
            kwargs = dict(runtime_env={"env_vars": ONE_THREAD}, log_to_driver=False)
            if self.address == "local":
                ray.init(address="local", include_dashboard=False, **kwargs)  # never a running cluster
            else:
                ray.init(address=self.address, **kwargs)
            self._started = True
        # max_retries=0: the scheduler retries (once) and reports, whatever the failure
        self._task = ray.remote(num_cpus=1, max_retries=0)(attempt)
        return self

    def __exit__(self, *exc) -> None:
        if self._started:
            self.ray.shutdown()

    def submit(self, train, spec) -> Future:
        return self._task.remote(train, spec).future()

    def describe(self) -> str:
        res = self.ray.cluster_resources()
        return f"Ray cluster at {self.address} ({int(res.get('CPU', 0))} CPUs, {len(self.ray.nodes())} node(s))"
