"""The Rerun logger: one .rrd recording per training run, written by a process of its own.

    runner = Runner(TrainConfig(robot="planar", method="cmaes"))
    logger = RerunLogger(runner)              # or RerunLogger(config, problem, path="run.rrd")
    runner.subscribe(logger)                  # logger(event) per generation; on_end closes the file
    runner.run(); print(logger.path)

Contract of the file (lab/recording/replay.py reads it back; docs/recordings.md):
- timelines: `generation` (sequence), `run_time` (duration: optimizer time, pauses excluded) and
  `wall_time` (timestamp: when the generation ended in the training process, pauses included);
  rows logged one by one (poses, network) also get Rerun's `log_time` (when the writer logged them);
- every generation: /mse, three series [best so far, median, worst] (worst only when finite), the
  same as /log10_mse (the viewer has no log axis in 0.41), /search: the backend's numeric extras
  (CMA-ES sigma and restarts; NEAT species, nodes, connections, hidden), names in its SeriesLines;
- /controller: a JSON TextDocument {"generation", "best_mse", "controller": to_dict()} whenever the
  best controller changes (so at the first generation too); floats are written with repr, so the
  controller rebuilds bit for bit;
- decimated: /world/{arm,reached,errors} and /world/robot (the best controller's pose for every
  training goal: at the first generation, then on improvement at most every
  max(pose_every, generation / 5) generations, and at the end);
- for a graph method (NEAT), /network: GraphNodes and GraphEdges of the best genome (inputs left,
  outputs right) at every /controller row, so from the first generation; an MLP method has no
  network panel (its shape never changes, and the viewer's graph edges carry no weights): its view
  shows /controller;
- populations (lab.running.decimation.population_logged: every generation up to 100, then every
  10th): /world/population (each candidate's point at the display goal, coloured by training MSE;
  /world/population_species by species) and /population (AnyValues mse, species);
- static: /protocol (JSON: robot, limits, goals, seed, hyperparameters, config, versions),
  /world/goals, /about (what the views show), /summary (written when the run ends cleanly).

Cost and durability: __call__ pickles the generation's numbers (and the best controller when it
changed) and writes them into a pipe, ~20 us in the optimizer's thread; the writer process
(lab/recording/writer.py) does all of Rerun's work on the other core and writes and flushes
what the pipe holds every 20 ms. Once __call__ has returned, the generation is in the kernel's
pipe buffer: a training process killed with SIGKILL loses at most the generation in flight,
and the writer then closes the file with its footer. The pipe holds about a thousand
generations (1 MiB), so training never waits for the writer's start (~1 s). After a clean close
the writer compacts the file (`rerun rrd optimize`: about 2.5x smaller) and exits.
"""

from __future__ import annotations

import atexit
import logging
import os
import subprocess
import tempfile
import threading
import uuid
import weakref
from datetime import datetime
from pathlib import Path

import numpy as np

from lab.recording import busy
from lab.running import pipes
from lab import methods
from lab.running.config import TrainConfig
from lab.problem import Problem
from lab.problem.robot import robot_slug

log = logging.getLogger(__name__)

APPLICATION_ID = "neuro-ik-lab"
# what the writer process is told of the method (lab/recording/views.MethodView): plain data, so
# that it needs no method's code (a method registered in a script exists in that script only)
METHOD_VIEW = ("name", "label", "controller", "search_title", "search_series")
FORMAT_VERSION = 1


def default_path(config: TrainConfig, folder: str | os.PathLike = "recordings", now: datetime | None = None) -> Path:
    """recordings/<robot>-<method>-s<seed>-<YYYYmmdd-HHMMSS>.rrd (a -2, -3 ... suffix if taken), claimed:
    the file is created empty (O_CREAT|O_EXCL) as its name is chosen, so that two loggers started in
    the same second (two apps on one folder, a race of one method and seed) never share a file.
    Creates the folder; raises OSError when nothing can be created there."""
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    stem = Path(folder) / f"{robot_slug(config.robot)}-{config.method}-s{config.seed}-{stamp}"
    Path(folder).mkdir(parents=True, exist_ok=True)
    for k in range(1, 10_000):
        path = stem.with_suffix(".rrd") if k == 1 else Path(f"{stem}-{k}.rrd")
        if claim(path):
            return path
    raise OSError(f"no free name for {stem}.rrd in {folder}")


def claim(path: str | os.PathLike) -> bool:
    """Create `path` empty if nothing is there, atomically (O_CREAT|O_EXCL): True if this call made
    it (the name is then this caller's), False if something was there already."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def not_a_folder(folder: str | os.PathLike) -> Path | None:
    """The file that keeps `folder` from being (or becoming) a folder: itself or the first
    existing path above it, when that is not a folder; None when the folder can be there."""
    folder = Path(folder)
    existing = next((a for a in (folder, *folder.parents) if a.exists()), None)
    return existing if existing is not None and not existing.is_dir() else None


def _is_recording(path: Path) -> bool:
    """Whether a file starts as a Rerun recording does (an empty file counts: nothing to lose)."""
    try:
        with open(path, "rb") as f:
            head = f.read(3)
    except OSError:
        return False
    return head in (b"RRF", b"")


def prepare_path(path: str | os.PathLike | None, config: TrainConfig, overwrite: bool = False) -> Path:
    """The file to write, claimed (see default_path; a folder gets a default name); raises
    OSError/ValueError, naming the path, when it cannot be written, and FileExistsError when it names
    a file that is already there (unless overwrite). Creates missing folders. Unless overwrite, the
    file is created empty here, atomically: a second logger given the same path is refused."""
    if path is not None and not str(path).strip():
        raise ValueError("recording path is empty; give a .rrd file or a folder (or leave it out for the default)")
    if path is None or Path(path).is_dir() or str(path).endswith(("/", os.sep)):
        folder = Path("recordings" if path is None else path)
        blocker = not_a_folder(folder)
        if blocker is not None:
            raise OSError(f"cannot write the recording in {folder}: {blocker} is not a folder")
        try:
            return default_path(config, folder=folder)
        except OSError as e:
            raise OSError(f"cannot write the recording in {folder}: {e.strerror or e}") from e
    p = Path(path)
    if p.exists() and not p.is_file():
        raise ValueError(f"recording path {p} exists and is not a file")
    if p.exists() and not overwrite:
        raise FileExistsError(_exists(p))
    if p.exists() and not _is_recording(p):
        raise FileExistsError(f"{p} is not a Rerun recording and was left as it is: only a recording is "
                              "overwritten; give another path")
    blocker = not_a_folder(p.parent)
    if blocker is not None:
        raise OSError(f"cannot write the recording {p}: {blocker} is not a folder")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=p.parent, prefix=".write-test-")
        os.close(fd)
        os.unlink(probe)
        if p.exists() and not os.access(p, os.W_OK):
            raise PermissionError("file is read-only")
        if not overwrite and not claim(p):  # taken since the look above: by another logger
            raise FileExistsError(_exists(p))
    except FileExistsError:
        raise
    except OSError as e:
        raise OSError(f"cannot write the recording {p}: {e.strerror or e}") from e
    return p


def _exists(p: Path) -> str:
    return (f"recording {p} already exists and was left as it is; give another path "
            "(or overwrite it: --overwrite, RerunLogger(..., overwrite=True))")


class RerunLogger:
    """A Runner subscriber that writes one Rerun recording (see the module docstring).

    source: a Runner, or a TrainConfig with `problem`, or a (config, problem) pair.
    pose_every: at least this many generations between 3D poses, and generation / 5 later on
        (scalars and controllers: all).
    compact: compact the file after closing it (the writer process does, after close() returns).
    overwrite: replace a file already at `path` (by default such a path is refused, FileExistsError).
    service: a lab.recording.service.WriterService that writes this recording in its process (many
        recordings, one process: a classroom server's), instead of a writer process of its own.
    """

    def __init__(self, source, problem: Problem | None = None, path: str | os.PathLike | None = None, *,
                 pose_every: int = 10, compact: bool = True, hyperparameters: dict | None = None,
                 overwrite: bool = False, block_on_end: bool = True, service=None):
        config, problem, run_id = _resolve_source(source, problem)
        if not (isinstance(pose_every, int) and pose_every >= 1):
            raise ValueError(f"pose_every must be an integer >= 1, got {pose_every!r}")
        replaced = path is not None and overwrite and os.path.isfile(path)  # a file of before, not ours to remove
        self.path = prepare_path(path, config, overwrite)
        # the file's lock while it is written (lab/recording/busy.py): taken here, as the file is still
        # empty, and handed to the writer process, which holds it until it exits
        held = busy.hold(self.path)
        try:
            self.config, self.problem, self.pose_every, self.compact = config, problem, pose_every, compact
            self.block_on_end = block_on_end
            method = methods.get(config.method)
            if hyperparameters is None:
                hyperparameters = method.backend.settings(problem, config)  # builds no backend
            self._rows = pipes.EventEncoder()
            self._lock = threading.Lock()
            self._closed = False
            self._error: str | None = None
            self._failure: str | None = None  # failure()'s line, once made
            self._said = False
            # Rerun's own log lines off (unless RUST_LOG says otherwise): a failure is one line of ours (failure())
            if service is not None:  # its process, already started, gets the pipes and the lock's descriptor
                self._proc = service.open(held)
                held_by_writer = None
            else:
                self._proc = pipes.start("lab.recording.writer", env={"RUST_LOG": "off"},
                                         pass_fds=() if held is None else (held,))
                held_by_writer = held
            self._fd = self._proc.stdin.fileno()
            pipes.grow(self._fd)
            self._send(("start", {
                "path": str(self.path), "config": config.to_dict(), "method": {k: getattr(method, k) for k in METHOD_VIEW}, "run_id": run_id, "robot": problem.arm.name,
                "train_goals": np.asarray(problem.train_goals), "goal_seed": problem.goal_seed,
                "hyperparameters": hyperparameters, "pose_every": pose_every, "compact": compact,
                "busy_fd": held_by_writer}))
        except BaseException:  # nothing started: the claimed name is given back
            if not replaced and self.path.is_file() and self.path.stat().st_size == 0:
                self.path.unlink(missing_ok=True)
            raise
        finally:
            if held is not None:  # the writer's copy holds the lock from here
                os.close(held)
        atexit.register(_close_at_exit, weakref.ref(self))

    @property
    def pid(self) -> int:
        """The writer process's id (a service's: the process that writes this recording and others)."""
        return self._proc.pid

    # ------------------------------------------------------------------ subscriber API
    def __call__(self, event) -> None:
        if self._closed:
            raise RuntimeError(f"the recording {self.path} is closed")
        if self._error is not None:  # the writer has stopped: said once, the run goes on
            return
        try:
            self._send(("event", self._rows(event)))
        except RuntimeError:
            log.warning("%s", self.failure())

    def on_end(self, summary) -> None:
        try:
            self.close(summary, block=self.block_on_end)
        except RuntimeError:
            if not self._said:
                log.warning("%s", self.failure())

    def failure(self) -> str | None:
        """One line on a writer that stopped (None while it works): the file, why (its own words: a
        full disk is named), and what of the file is readable."""
        if self._error is None:
            return None
        if self._failure is None:
            try:
                self._proc.wait(10)
                said = self._proc.stdout.read() if not self._proc.stdout.closed else b""
            except (OSError, ValueError, subprocess.TimeoutExpired):
                said = b""
            why = said[1:].decode("utf-8", "replace").strip() if said.startswith(b"E") else \
                f"its writer process exited (code {self._proc.returncode})"
            self._failure = f"recording {self.path} stopped: {why}; {_readable(self.path)}"
            self._said = True
        return self._failure

    def close(self, summary=None, wait: bool = False, block: bool = True) -> None:
        """Write the summary, then wait until the writer has closed the file (with its footer).
        Idempotent. The file is complete and readable when this returns; the writer then
        compacts it (compact=True), replacing it atomically with the same data in fewer chunks.
        wait=True (or wait()) waits for that too. block=False returns once the summary is sent:
        the writer process finishes the file on its own, even after this process has exited
        (the app stops within a second or two, however far the writer is behind)."""
        with self._lock:
            if self._closed:
                if self._failure is not None:
                    raise RuntimeError(self._failure)
                if wait:
                    self.wait()
                return
            self._closed = True
        doc = None if summary is None else summary.numbers()
        try:
            self._send(("end", doc))  # "end" even without a summary: a clean close, which is compacted
        except RuntimeError:
            pass  # the writer is gone: reported below
        self._proc.stdin.close()
        if not block:
            threading.Thread(target=self._finish_quietly, name=f"rerun-writer-{self.path.name}", daemon=True).start()
            return
        self._finish(wait)

    def _finish_quietly(self) -> None:
        try:
            self._finish()
        except RuntimeError:
            if not self._said:
                log.warning("%s", self.failure())

    def _finish(self, wait: bool = False) -> None:
        first = self._proc.stdout.read(1)
        if first != b"C":
            self._error = self._error or "the writer failed"
            rest = self._proc.stdout.read() if first else b""
            self._proc.stdout.close()
            self._proc.wait()
            if first == b"E":  # its reason, for failure()
                why = rest.decode("utf-8", "replace").strip()
                self._failure = f"recording {self.path} stopped: {why}; {_readable(self.path)}"
            raise RuntimeError(self.failure())
        self._proc.stdout.close()
        if wait:
            self.wait()
        else:  # reaps the writer when it is done compacting
            threading.Thread(target=self._proc.wait, name=f"rerun-writer-{self.path.name}", daemon=True).start()

    def wait(self, timeout: float | None = None) -> None:
        """Wait until the closed recording has been compacted (the writer has exited)."""
        try:
            self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _send(self, message) -> None:
        with self._lock:
            if self._error is not None:
                raise RuntimeError(self._error)
            try:
                pipes.send(self._fd, message)
            except OSError as e:  # BrokenPipeError: the writer is gone
                self._error = f"the Rerun writer of {self.path} stopped ({e.strerror or e}; any error it printed is on stderr)"
                raise RuntimeError(self._error) from e


def _resolve_source(source, problem):
    """(config, problem, recording id) from a Runner, a config or a pair."""
    if isinstance(source, tuple) and len(source) == 2 and problem is None:
        source, problem = source
    if isinstance(source, TrainConfig):
        if problem is None:
            from lab.running.runner import build_problem

            problem = build_problem(source)
        return source, problem, uuid.uuid4().hex[:12]
    if hasattr(source, "config") and hasattr(source, "problem") and hasattr(source, "run_id"):
        return source.config, source.problem, source.run_id
    raise TypeError(f"RerunLogger needs a Runner, a TrainConfig or (config, problem), got {type(source).__name__}")


def _readable(path: Path) -> str:
    """What of a recording can be read back, in words."""
    try:
        from lab.recording.replay import read_recording

        last = read_recording(path).last_generation
    except Exception:  # noqa: BLE001 - nothing usable
        return "nothing in it can be read back"
    return "nothing in it can be read back" if last is None else \
        f"generations 0..{last} can be read back (python -m lab replay {path})"


def _close_at_exit(ref) -> None:
    logger = ref()
    if logger is not None:
        try:
            logger.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass
