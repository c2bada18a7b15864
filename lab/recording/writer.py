"""The recording's writer process: `python -m lab.recording.writer`, started by lab.recording.logger.RerunLogger.

It reads length-prefixed pickles from stdin, the pipe the training process writes into:
("start", header) first, then ("event", row) per generation, then ("end", summary) on a clean
close. It owns the Rerun RecordingStream, so none of Rerun's work (Arrow columns, chunking,
encoding, the file's writes) runs in the training process or holds its GIL. It writes and
flushes whatever the pipe holds, at most every WRITE_INTERVAL (20 ms), so the file trails the
run by about that much; what waits is in the kernel's pipe buffer, not in a process's memory.
The pipe outlives the training process: after a SIGKILL of that process, whatever it had handed
over is still written, and the file is closed with its footer (end of input without "end").

It writes "C" to stdout once the file is closed and complete (the training process's close()
waits for that), then compacts the file after a clean close, then exits. It ignores SIGINT
(Ctrl-C in a terminal reaches the whole process group; the training process then closes the
recording itself). The file's contents are described in lab/recording/logger.py. It inherits the
logger's lock on the file (lab/recording/busy.py: the file is being written) and lets it go once the
file is closed, before compacting it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import sys
import time

import numpy as np
import pyarrow as pa
import rerun as rr

import robots

from lab.problem import environment
from lab.recording import views
from lab.recording.population import mse_colors, species_colors
from lab.running.decimation import display_goal, long_run, population_logged
from lab.running.pipes import EventDecoder, claim_stdout, messages
from lab.recording.logger import APPLICATION_ID, FORMAT_VERSION
from lab.recording.rerun_tool import compact

WRITE_INTERVAL = 0.02  # seconds: at most this often a write and flush of what the pipe holds (each costs
# ~0.3 ms of CPU whatever it holds; the pipe keeps what waits, even if the training process is killed)
DISPLAY_INTERVAL = 0.1  # seconds between writes of the display-only series (log10 MSE, search state)


# a flush that has not reached the file in this long never will (Rerun's file sink thread died:
# a full disk); healthy ones take milliseconds
FLUSH_TIMEOUT = 15.0
DISK_CHECK_INTERVAL = 1.0  # seconds between looks at the free space of the recording's filesystem
RESERVE_MAX = 256 * 2**20  # bytes kept free: 2 % of the filesystem, at most this (LAB_RECORDING_RESERVE overrides)


def reserve(path: str) -> int:
    """Bytes the recording leaves free on its filesystem: when less is free, it stops, closed and readable."""
    given = environment.recording_reserve()  # SettingError naming LAB_RECORDING_RESERVE when not bytes
    if given is not None:
        return given
    total = shutil.disk_usage(os.path.dirname(os.path.abspath(path))).total
    return min(RESERVE_MAX, total // 50)


class NearlyFull(Exception):
    """The recording's filesystem has less free than its reserve: the file is closed and the recording stops."""


class Writer:
    """The recording of one run (see lab/recording/logger.py for what goes where)."""

    def __init__(self, header: dict):
        config = self.config = header["config"]  # TrainConfig.to_dict()
        self.method = views.MethodView(**header["method"])
        self.path = header["path"]
        self.pose_every = header["pose_every"]
        arm = robots.load(header["robot"])
        self._geometry = views.Geometry(arm, header["train_goals"])
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=header["run_id"])
        self._rec.save(self.path, default_blueprint=views.blueprint(self.method, self._geometry))
        self._rec.send_recording_name(f"{config['robot']} {config['method']} seed {config['seed']}")
        self._log_static(header)
        self._rec.flush(timeout_sec=FLUSH_TIMEOUT)
        self._logged = None  # the last controller written
        self._posed = (None, -(10**9))  # (controller, generation) of the last pose written
        self._search_keys: list | None = None  # the backend's numeric extras, in a fixed order
        self._last_event = None
        self._last_written = None  # index of the last generation whose rows are written
        self._display: list = []  # events whose display-only series are not written yet
        self._display_sent = time.monotonic()

    def write(self, events: list) -> None:
        """Controllers first, then /mse: a file cut anywhere holds the controller of every generation
        whose /mse row it holds. The display-only series follow every DISPLAY_INTERVAL (fewer chunks:
        each costs ~0.3 ms of CPU). Generations are logged by the rule lab.running.decimation.long_run
        (every one below 10,000; beyond, fewer per tenfold), the run's last one always (end())."""
        if not events:
            return
        self._write_rows([e for e in events if long_run(e.index)])
        self._last_event = events[-1]
        for e in events:  # the rule at every generation: the first one is posed, whatever the batch holds
            self._write_pose(e)
        self._write_populations(events)

    def _write_rows(self, events: list) -> None:
        if not events:
            return
        self._write_controllers(events)
        self._send_rows("mse", events, [_mse_row(e) for e in events])
        self._display += events
        self._last_written = events[-1].index
        if time.monotonic() - self._display_sent >= DISPLAY_INTERVAL:
            self._write_display()

    def _write_populations(self, events: list) -> None:
        """/world/population: each candidate's end-effector point at the display goal, coloured by its
        training MSE (species ids as class ids); /population: the numbers (mse, species)."""
        for e in events:
            p = e.population
            if p is None or p.points is None or not population_logged(e.index):  # not the live views' extras
                continue
            self._set_time(e)
            points = np.asarray(p.points, np.float32).reshape(-1, 3)  # a tree's: each candidate's E points
            per = len(points) // max(len(p.mse), 1)
            colors = np.repeat(mse_colors(p.mse), per, axis=0)
            species = {} if p.species is None else {"class_ids": np.repeat(np.asarray(p.species, np.uint16), per)}
            self._rec.log("world/population", rr.Points3D(points, colors=colors,
                                                          radii=3 * self._geometry.radius, **species))
            values = {"mse": np.asarray(p.mse, np.float64)}
            if p.species is not None:
                values["species"] = np.asarray(p.species, np.int64)
                # the species' own colours, for the viewer (class ids get colours of its own otherwise)
                colors = np.repeat(species_colors(p.species), per, axis=0)
                self._rec.log("world/population_species", rr.Points3D(points, colors=colors,
                                                                      radii=3 * self._geometry.radius))
            self._rec.log("population", rr.AnyValues(**values))

    def end(self, summary: dict | None) -> None:
        """What is still pending (the last generation, display series, the last pose), and the summary
        of a clean close."""
        last = self._last_event
        if last is not None and self._last_written != last.index:
            self._write_rows([last])
        self._write_display()
        if last is not None:
            self._write_pose(last, final=True)
        if summary is not None:
            self._rec.log("summary", rr.TextDocument(json.dumps(summary, indent=1)), static=True)

    def flush(self) -> None:
        self._rec.flush(timeout_sec=FLUSH_TIMEOUT)

    def close(self) -> None:
        """Flush and close the file (with its footer)."""
        try:
            self._rec.flush(timeout_sec=FLUSH_TIMEOUT)
        finally:
            self._rec.disconnect()

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
        self._rec.send_columns(entity, indexes=_indexes(events), columns=[_Column(_Column.SCALARS, rows, pa.float64())])

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
            "controller", indexes=_indexes([e for e, _ in rows]),
            columns=[_Column(_Column.TEXT, [[t] for _, t in rows], pa.string())])
        if self.method.controller == "graph":  # the network in force at every logged generation
            for e, _ in rows:
                self._set_time(e)
                self._rec.log("network", *views.network(e.controller))

    def _write_pose(self, e, final: bool = False) -> None:
        """The pose of a new best controller, at most every max(pose_every, generation / 5)
        generations: frequent early, ~12 per tenfold of generations later (bounded files). Called
        for every generation (the first with a controller is posed), so which generations are
        posed does not depend on how many generations each read of the pipe brought."""
        posed, at = self._posed
        if e.controller is None or e.controller is posed:
            return
        if not final and e.index - at < max(self.pose_every, e.index // 5):
            return
        self._set_time(e)
        for entity, archetype in views.pose(self._geometry, e.controller).items():
            self._rec.log(entity, archetype)
        self._posed = (e.controller, e.index)

    def _set_time(self, e) -> None:
        self._rec.set_time("generation", sequence=e.index)
        self._rec.set_time("run_time", duration=e.seconds)
        self._rec.set_time("wall_time", timestamp=e.wall_time)

    def _log_static(self, header: dict) -> None:
        c, arm = self.config, self._geometry.arm
        protocol = {
            "format": FORMAT_VERSION, "run_id": header["run_id"], "robot": c["robot"], "method": c["method"],
            "urdf_sha256": getattr(arm, "urdf_sha256", None),  # the robot's identity: its string and its file's bytes
            "seed": c["seed"], "joint_names": list(arm.joint_names), "lower": arm.lower.tolist(),
            "upper": arm.upper.tolist(), "task_axes": list(arm.task_axes), "goal_seed": header["goal_seed"],
            "train_goals": np.asarray(header["train_goals"]).tolist(),
            "hyperparameters": header["hyperparameters"], "config": c, "versions": views.versions(),
        }
        rec = self._rec
        rec.log("protocol", rr.TextDocument(json.dumps(protocol, indent=1, default=_jsonable)), static=True)
        rec.log("about", rr.TextDocument(views.about(c, self.method), media_type=rr.MediaType.MARKDOWN), static=True)
        for entity, archetype in views.static_scene(self._geometry) + views.robot_meshes(arm):
            rec.log(entity, archetype, static=True)
        goal = arm.to_3d(display_goal(arm)).reshape(-1, 3)  # a tree's: one point per effector
        rec.log("world/display_goal", rr.Points3D(goal, colors=[[255, 255, 255]], radii=5 * self._geometry.radius,
                                                  labels=["population shown for this goal"]), static=True)


def main() -> int:
    # Ctrl-C and a closing terminal reach the whole process group: the writer ends when its
    # input does (the logger closes it), so that the file is always closed with its footer
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    os.nice(10)  # the optimizer (and the app) first when the two cores are busy; the pipe waits
    ack = claim_stdout()
    if sys.argv[1:2] == ["--serve"]:
        return serve(int(sys.argv[2]))
    code = _one(sys.stdin.fileno(), ack)
    if code is None:  # the stream is gone undropped: its flush could hang this process's exit
        os._exit(1)
    return code


def _one(fd: int, ack: int, busy_fd: int | None = None) -> int | None:
    """Write the recording whose messages come on fd, telling `ack` "C" once it is closed and complete
    (then compacting it after a clean close), or "E" and why. The exit code: 0, 1 (a nearly full
    disk: closed with its footer), 2 (no start message); None where writing failed, whose Rerun
    stream is left undropped: Rerun's RecordingStream flushes, with no time limit, when it is
    dropped, and a dead file sink never finishes that flush. busy_fd: the file's lock (serve(); a
    lone writer's is named in the start message), released once the file is closed, or on failure."""
    stream = messages(fd)
    first = next(stream, None)
    if not first or first[0][0] != "start":
        print("rerun writer: no start message on its input", file=sys.stderr)
        release(busy_fd)
        return 2
    header = first[0][1]
    if busy_fd is not None:
        header["busy_fd"] = busy_fd
    try:
        return _write(header, first, stream, ack)
    except NearlyFull as e:  # closed with its footer: readable; not compacted (that needs room)
        _tell(ack, b"E" + str(e).encode("utf-8", "replace"))
        return 1
    except Exception as e:  # a full disk, a vanished folder: one line to the logger, no traceback
        _tell(ack, b"E" + _why(e, header["path"]).encode("utf-8", "replace"))
        _undropped.append(sys.exc_info())  # the traceback holds the stream: never dropped (see above)
        return None
    finally:
        if busy_fd is not None:  # served: this process goes on, so the lock is let go here
            release(header.pop("busy_fd", None))


_undropped: list = []  # failed recordings' streams (in their tracebacks), never dropped


def serve(control: int) -> int:
    """One writer process for many recordings (lab/recording/service.py): each recording's message
    pipe, ack pipe and file lock arrive as descriptors on the `control` socket (SCM_RIGHTS), and a
    thread writes it as a writer process of its own would (_one), telling its ack pipe "C" (closed),
    then a zero byte once compacted, then closing it. Ends when the control socket does (the app has gone)
    and every recording it holds is closed: a recording's pipe outlives the app, as a lone writer's."""
    import socket
    import threading

    sock = socket.socket(fileno=control)
    threads = []
    while True:
        try:
            _, fds, _, _ = socket.recv_fds(sock, 16, 3)
        except OSError:
            break
        if len(fds) not in (2, 3):  # end of the control stream (the app has gone), or a message without its pipes
            for fd in fds:
                os.close(fd)
            if not fds:
                break
            continue
        threads = [t for t in threads if t.is_alive()]
        fd, ack, *busy = fds  # no lock where flock is missing
        t = threading.Thread(target=_served, args=(fd, ack, busy[0] if busy else None), name=f"recording-{fd}")
        t.start()
        threads.append(t)
    for t in threads:
        t.join()
    return 0


def _served(fd: int, ack: int, busy_fd: int | None) -> None:
    """One recording of serve(): its messages on fd; its lock's descriptor released once it is closed."""
    try:
        _one(fd, ack, busy_fd)
    except BaseException:  # noqa: BLE001 - one recording's failure is its own (said on its ack pipe)
        pass
    finally:
        os.close(fd)
        _tell(ack, b"\0")  # lab.recording.service.DONE: closed and compacted, as a lone writer's exit says
        os.close(ack)


def _write(header: dict, first: list, stream, ack: int) -> int:
    writer = Writer(header)
    decode, summary, clean, batch = EventDecoder(header["run_id"]), None, False, first[1:]
    t0 = time.monotonic()
    checked = -DISK_CHECK_INTERVAL  # the first batch is followed by a look at the free space
    keep = reserve(header["path"])
    try:
        while batch is not None:  # None: end of input without "end" (the training process was killed)
            events = []
            for kind, body in batch:
                if kind == "event":
                    events.append(decode(body))
                elif kind == "end":
                    summary, clean = body, True
            writer.write(events)
            if clean:
                break
            if time.monotonic() - checked >= DISK_CHECK_INTERVAL:
                checked = time.monotonic()
                free = shutil.disk_usage(os.path.dirname(os.path.abspath(header["path"]))).free
                if free < keep:
                    writer.end(None)
                    raise NearlyFull(f"the disk is nearly full ({free:,} bytes free on its filesystem, under the "
                                     f"{keep:,} a recording leaves free); the file is closed")
            writer.flush()
            time.sleep(max(0.0, WRITE_INTERVAL - (time.monotonic() - t0)))  # what arrives meanwhile waits in the pipe
            t0 = time.monotonic()
            batch = next(stream, None)
        writer.end(summary)
    finally:
        writer.close()
    release(header.pop("busy_fd", None))  # closed with its footer: no longer being written (lab/recording/busy.py)
    _tell(ack, b"C")
    if clean and header["compact"]:
        compact(writer.path)
    return 0


def release(fd: int | None) -> None:
    """Close the inherited descriptor that holds the file's lock (the logger has closed its copy)."""
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass


def _tell(ack: int, message: bytes) -> None:
    try:
        os.write(ack, message)
    except OSError:  # the logger no longer listens (its process has ended): the file is closed all the same
        pass


def _why(e: Exception, path: str) -> str:
    """Why writing failed, in words: a full disk is named as such (Rerun's file sink only says that
    its thread shut down)."""
    try:
        free = shutil.disk_usage(os.path.dirname(os.path.abspath(path))).free
    except OSError:
        free = None
    if free is not None and free < (1 << 20):
        return f"the disk is full ({free:,} bytes free on its filesystem)"
    return f"{type(e).__name__}: {e}"


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


def _indexes(events) -> list:
    return [rr.TimeColumn("generation", sequence=np.array([e.index for e in events], dtype=np.int64)),
            rr.TimeColumn("run_time", duration=np.array([e.seconds for e in events], dtype=np.float64)),
            rr.TimeColumn("wall_time", timestamp=np.array([e.wall_time for e in events], dtype=np.float64))]


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


if __name__ == "__main__":
    sys.exit(main())
