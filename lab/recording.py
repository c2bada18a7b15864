"""The Rerun logger: one .rrd recording per training run, written off the optimizer's thread.

    runner = Runner(TrainConfig(robot="planar", method="cmaes"))
    logger = RerunLogger(runner)              # or RerunLogger(config, problem, path="run.rrd")
    runner.subscribe(logger)                  # logger(event) per generation; on_end closes the file
    runner.run(); print(logger.path)

Contract of the file (lab/replay.py reads it back):
- timelines: `generation` (sequence) and `run_time` (duration: optimizer time, pauses excluded);
  rows logged one by one (poses, network) also get Rerun's wall-clock `log_time`;
- every generation: /mse, three series [best so far, median, worst] (worst only when finite), the
  same as /log10_mse (the viewer has no log axis in 0.41), /search: the backend's numeric extras
  (CMA-ES sigma and restarts; NEAT species, nodes, connections, hidden), names in its SeriesLines;
- /controller: a JSON TextDocument {"generation", "best_mse", "controller": to_dict()} whenever the
  best controller changes (so at the first generation too); floats are written with repr, so the
  controller rebuilds bit for bit;
- decimated: /world/{arm,reached,errors} (the best controller's pose for every training goal, on
  improvement, at most every max(pose_every, generation / 5) generations, and at the end) and, for
  NEAT, /network (GraphNodes and GraphEdges of the best genome, inputs left, outputs right);
- static: /protocol (JSON: robot, limits, goals, seed, hyperparameters, config, versions),
  /world/goals, /about (what the views show), /summary (written when the run ends).

Cost: __call__ only queues the event. The logger's own thread drains the queue at most every
`flush_interval` seconds (20 ms): the new controllers and the /mse rows of all queued generations,
each as one column batch (rr.send_columns), then a flush; the display-only series (/log10_mse,
/search) go out every 0.1 s the same way. A process killed with SIGKILL therefore loses at most
the last 20 ms of generations (0.1 s of the display series). Every chunk and flush costs ~0.3 ms
of CPU whatever it holds: with 2 ms generations the logger uses ~35% of a core when it flushes
after every generation (flush_interval=0), ~11% at 20 ms (benchmarks/bench_recording.py). The
closed file is compacted in a background thread (`rerun rrd optimize`: about 2.5x smaller).
"""

from __future__ import annotations

import atexit
import json
import logging
import math
import os
import queue
import subprocess
import tempfile
import threading
import time
import uuid
import weakref
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr

from . import recording_views as views
from .config import TrainConfig
from .problem import Problem

log = logging.getLogger(__name__)

APPLICATION_ID = "neuro-ik-lab"
FORMAT_VERSION = 1
DISPLAY_INTERVAL = 0.1  # seconds between writes of the display-only series (log10 MSE, search state)


@dataclass(frozen=True)
class _End:
    """Queued by close(): write the summary and end the logger's thread."""

    summary: object = None


def default_path(config: TrainConfig, folder: str | os.PathLike = "recordings", now: datetime | None = None) -> Path:
    """recordings/<robot>-<method>-s<seed>-<YYYYmmdd-HHMMSS>.rrd (a -2, -3 ... suffix if taken)."""
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    stem = Path(folder) / f"{config.robot}-{config.method}-s{config.seed}-{stamp}"
    path, k = stem.with_suffix(".rrd"), 1
    while path.exists():
        k += 1
        path = Path(f"{stem}-{k}.rrd")
    return path


def prepare_path(path: str | os.PathLike | None, config: TrainConfig) -> Path:
    """The file to write (a folder gets a default name); raises OSError/ValueError, naming the
    path, when it cannot be written. Creates missing folders."""
    if path is None:
        p = default_path(config)
    elif Path(path).is_dir() or str(path).endswith(("/", os.sep)):
        p = default_path(config, folder=path)
    else:
        p = Path(path)
    if p.exists() and not p.is_file():
        raise ValueError(f"recording path {p} exists and is not a file")
    blocker = next((a for a in p.parents if a.exists()), None)
    if blocker is not None and not blocker.is_dir():
        raise OSError(f"cannot write the recording {p}: {blocker} is not a folder")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=p.parent, prefix=".write-test-")
        os.close(fd)
        os.unlink(probe)
        if p.exists() and not os.access(p, os.W_OK):
            raise PermissionError("file is read-only")
    except OSError as e:
        raise OSError(f"cannot write the recording {p}: {e.strerror or e}") from e
    return p


class RerunLogger:
    """A Runner subscriber that writes one Rerun recording (see the module docstring).

    source: a Runner, or a TrainConfig with `problem`, or a (config, problem) pair.
    pose_every: at least this many generations between 3D poses, and generation / 5 later on
        (scalars and controllers: all).
    flush_interval: seconds between writes to the file (0: after every generation; see Cost above).
    compact: compact the file after closing it (in a background thread; see close()).
    """

    def __init__(self, source, problem: Problem | None = None, path: str | os.PathLike | None = None, *,
                 pose_every: int = 10, flush_interval: float = 0.02, compact: bool = True,
                 hyperparameters: dict | None = None):
        config, problem, backend, run_id = _resolve_source(source, problem)
        if not (isinstance(pose_every, int) and pose_every >= 1):
            raise ValueError(f"pose_every must be an integer >= 1, got {pose_every!r}")
        if not flush_interval >= 0:
            raise ValueError(f"flush_interval must be >= 0 seconds, got {flush_interval!r}")
        self.path = prepare_path(path, config)
        self.config, self.problem = config, problem
        self.pose_every, self.flush_interval, self.compact = pose_every, float(flush_interval), compact
        if hyperparameters is None:
            hyperparameters = _hyperparameters(backend, problem, config)
        self._geometry = views.Geometry(problem.arm, problem.train_goals)
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=run_id)
        self._rec.save(str(self.path), default_blueprint=views.blueprint(config.method, self._geometry))
        self._rec.send_recording_name(f"{config.robot} {config.method} seed {config.seed}")
        self._log_static(run_id, hyperparameters)
        self._rec.flush()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._error: BaseException | None = None
        self._closed = False
        self._close_lock = threading.Lock()
        self._logged = None  # the last controller written
        self._posed = (None, -(10**9))  # (controller, generation) of the last pose written
        self._search_keys: list | None = None  # the backend's numeric extras, in a fixed order
        self._last_event = None
        self._display: list = []  # events whose display-only series are not written yet
        self._display_sent = time.monotonic()
        self._compactor: threading.Thread | None = None
        self._thread = threading.Thread(target=self._drain, name=f"rerun-logger-{run_id}", daemon=True)
        self._thread.start()
        atexit.register(_close_at_exit, weakref.ref(self))

    # ------------------------------------------------------------------ subscriber API
    def __call__(self, event) -> None:
        if self._error is not None:
            raise RuntimeError(f"the Rerun logger of {self.path} failed: {self._error}") from self._error
        if self._closed:
            raise RuntimeError(f"the recording {self.path} is closed")
        self._queue.put(event)

    def on_end(self, summary) -> None:
        self.close(summary)

    def close(self, summary=None, wait: bool = False) -> None:
        """Write what is queued (and the summary), then close the file (with its footer). Idempotent.

        The file is complete and readable when this returns; compaction (compact=True) then goes
        on in a background thread, off the optimizer's path, and replaces the file atomically
        with the same data in fewer chunks. wait=True (or wait()) waits for it; so does the
        interpreter before it exits."""
        with self._close_lock:
            if self._closed:
                if wait:
                    self.wait()
                return
            self._closed = True
        self._queue.put(_End(summary))
        self._thread.join()
        try:
            self._rec.flush()
        finally:
            self._rec.disconnect()
        if self.compact:
            self._compactor = threading.Thread(target=compact, args=(self.path,), name=f"rerun-compact-{self.path.name}")
            self._compactor.start()  # not a daemon: the interpreter waits for it at exit
        if wait:
            self.wait()

    def wait(self, timeout: float | None = None) -> None:
        """Wait until the closed recording has been compacted."""
        if self._compactor is not None:
            self._compactor.join(timeout)

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ the logger's thread
    def _drain(self) -> None:
        while True:
            items = [self._queue.get()]
            t0 = time.monotonic()
            while True:
                try:
                    items.append(self._queue.get_nowait())
                except queue.Empty:
                    break
            end = next((item for item in items if isinstance(item, _End)), None)
            events = [item for item in items if not isinstance(item, _End)]
            try:
                if events and self._error is None:
                    self._write(events)
                if end is not None and self._error is None:
                    self._write_end(end.summary)
                self._rec.flush()
            except Exception as e:  # never take the run down; __call__ reports it (and is unsubscribed)
                log.exception("Rerun logger of %s failed", self.path)
                self._error = e
            if end is not None:
                return
            wait = self.flush_interval - (time.monotonic() - t0)
            if wait > 0:
                time.sleep(wait)

    def _write(self, events: list) -> None:
        """Controllers first, then /mse: a file cut anywhere holds the controller of every generation
        whose /mse row it holds. The display-only series follow every DISPLAY_INTERVAL (fewer chunks:
        each costs ~0.3 ms of CPU); no row of any series is ever dropped."""
        self._write_controllers(events)
        self._send_rows("mse", events, [_mse_row(e) for e in events])
        self._display += events
        if time.monotonic() - self._display_sent >= DISPLAY_INTERVAL:
            self._write_display()
        self._last_event = events[-1]
        self._write_pose(events[-1])

    def _write_display(self) -> None:
        events, self._display, self._display_sent = self._display, [], time.monotonic()
        if not events:
            return
        self._send_rows("log10_mse", events, [[_log10(v) for v in _mse_row(e)] for e in events])
        if self._search_keys is None:
            self._search_keys = sorted(k for k, v in events[0].extras.items() if _is_number(v))
            self._rec.log("search", rr.SeriesLines(names=self._search_keys, widths=2,
                                                   colors=views.palette(len(self._search_keys))), static=True)
        if self._search_keys:
            self._send_rows("search", events, [[_number(e.extras.get(k)) for k in self._search_keys] for e in events])

    def _send_rows(self, entity: str, events: list, rows: list) -> None:
        index = _indexes([e.index for e in events], [e.seconds for e in events])
        self._rec.send_columns(entity, indexes=index, columns=[_Column(_Column.SCALARS, rows, pa.float64())])

    def _write_controllers(self, events: list) -> None:
        rows = []
        for e in events:
            if e.controller is not None and e.controller is not self._logged:
                doc = {"generation": e.index, "best_mse": e.best, "controller": e.controller.to_dict()}
                rows.append((e, json.dumps(doc, separators=(",", ":"))))
                self._logged = e.controller
        if not rows:
            return
        self._rec.send_columns(
            "controller", indexes=_indexes([e.index for e, _ in rows], [e.seconds for e, _ in rows]),
            columns=[_Column(_Column.TEXT, [[t] for _, t in rows], pa.string())])
        e = rows[-1][0]
        if getattr(e.controller, "genome", None):
            self._set_time(e)
            self._rec.log("network", *views.network(e.controller))

    def _write_pose(self, e, final: bool = False) -> None:
        """The pose of a new best controller, at most every max(pose_every, generation / 5)
        generations: frequent early, ~12 per tenfold of generations later (bounded files)."""
        posed, at = self._posed
        if e.controller is None or e.controller is posed:
            return
        if not final and e.index - at < max(self.pose_every, e.index // 5):
            return
        self._set_time(e)
        for entity, archetype in views.pose(self._geometry, e.controller).items():
            self._rec.log(entity, archetype)
        self._posed = (e.controller, e.index)

    def _write_end(self, summary) -> None:
        self._write_display()
        if self._last_event is not None:
            self._write_pose(self._last_event, final=True)
        if summary is None:
            return
        doc = {"state": summary.state, "generations": summary.generations, "evaluations": summary.evaluations,
               "seconds": summary.seconds, "train_mse": summary.train_mse, "test_mse": summary.test_mse,
               "error": summary.error}
        self._rec.log("summary", rr.TextDocument(json.dumps(doc, indent=1)), static=True)

    def _set_time(self, e) -> None:
        self._rec.set_time("generation", sequence=e.index)
        self._rec.set_time("run_time", duration=e.seconds)

    # ------------------------------------------------------------------ static data
    def _log_static(self, run_id: str, hyperparameters: dict) -> None:
        c, arm = self.config, self.problem.arm
        protocol = {
            "format": FORMAT_VERSION, "run_id": run_id, "robot": c.robot, "method": c.method, "seed": c.seed,
            "joint_names": list(arm.joint_names), "lower": arm.lower.tolist(), "upper": arm.upper.tolist(),
            "task_axes": list(arm.task_axes), "goal_seed": self.problem.goal_seed,
            "train_goals": np.asarray(self.problem.train_goals).tolist(),
            "hyperparameters": hyperparameters, "config": c.to_dict(), "versions": views.versions(),
        }
        rec = self._rec
        rec.log("protocol", rr.TextDocument(json.dumps(protocol, indent=1, default=_jsonable)), static=True)
        rec.log("about", rr.TextDocument(views.about(c), media_type=rr.MediaType.MARKDOWN), static=True)
        for entity, archetype in views.static_scene(self._geometry, c.method):
            rec.log(entity, archetype, static=True)


def rerun_binary() -> str:
    """The real `rerun` executable (the venv's bin/rerun is a Python wrapper around it)."""
    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    import rerun_cli

    return str(Path(rerun_cli.__file__).with_name("rerun"))


def compact(path: str | os.PathLike, timeout: float = 60.0) -> bool:
    """Merge a closed recording's many small chunks (`rerun rrd optimize`), in place: about ten
    times smaller, same data. Leaves the file as it was (and returns False) if that fails."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.compacting.rrd")
    try:
        done = subprocess.run([rerun_binary(), "rrd", "optimize", str(path), "-o", str(tmp)],
                              capture_output=True, text=True, timeout=timeout)
        if done.returncode == 0 and tmp.is_file() and tmp.stat().st_size > 0:
            os.replace(tmp, path)
            return True
        log.warning("could not compact %s: %s", path, done.stderr.strip()[-500:])
    except (OSError, subprocess.SubprocessError) as e:
        log.warning("could not compact %s: %s", path, e)
    tmp.unlink(missing_ok=True)
    return False


def _resolve_source(source, problem):
    """(config, problem, backend or None, recording id) from a Runner, a config or a pair."""
    if isinstance(source, tuple) and len(source) == 2 and problem is None:
        source, problem = source
    if isinstance(source, TrainConfig):
        if problem is None:
            from .runner import build_problem

            problem = build_problem(source)
        return source, problem, None, uuid.uuid4().hex[:12]
    if hasattr(source, "config") and hasattr(source, "problem") and hasattr(source, "backend"):
        return source.config, source.problem, source.backend, source.run_id
    raise TypeError(f"RerunLogger needs a Runner, a TrainConfig or (config, problem), got {type(source).__name__}")


def _hyperparameters(backend, problem, config) -> dict:
    if backend is None:
        from .backends import make_backend

        backend = make_backend(problem, config)
    return backend.hyperparameters()


class _Column:
    """A component column built straight in Arrow, one list of values per row: the ComponentBatchLike
    protocol that send_columns takes (rr.Scalars.columns(...).partition(...) costs ~45 us a call)."""

    SCALARS = next(iter(rr.Scalars.columns(scalars=[0.0]))).component_descriptor()
    TEXT = next(iter(rr.TextDocument.columns(text=[""]))).component_descriptor()

    def __init__(self, descriptor, rows: list, kind: pa.DataType):
        self.descriptor = descriptor
        self.offsets = np.cumsum([0] + [len(row) for row in rows], dtype=np.int32)
        self.values = pa.array([v for row in rows for v in row], kind)

    def component_descriptor(self):
        return self.descriptor

    def as_arrow_array(self) -> pa.Array:
        return pa.ListArray.from_arrays(pa.array(self.offsets, pa.int32()), self.values)


def _indexes(gens, secs) -> list:
    return [rr.TimeColumn("generation", sequence=np.asarray(gens, dtype=np.int64)),
            rr.TimeColumn("run_time", duration=np.asarray(secs, dtype=np.float64))]


def _mse_row(e) -> list:
    """[best so far, median, worst]; worst only when finite."""
    return [e.best, e.median] + ([e.worst] if math.isfinite(e.worst) else [])


def _log10(v: float) -> float:
    return math.log10(v) if v > 0 and math.isfinite(v) else (-300.0 if v == 0 else math.nan)


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating))


def _number(v) -> float:
    return float(v) if _is_number(v) else math.nan


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.integer, np.floating, np.bool_)):
        return x.item()
    return repr(x)


def _close_at_exit(ref) -> None:
    logger = ref()
    if logger is not None:
        try:
            logger.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass
