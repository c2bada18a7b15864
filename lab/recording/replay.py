"""Reading recordings back, and showing them in the Rerun viewer.

    controller = load_controller("recordings/planar-cmaes-s0-....rrd")        # the last generation's
    controller = load_controller(path, generation=250)                        # in force at generation 250
    rec = read_recording(path)  # protocol, per-generation best/median MSE, every logged controller
    replay(path)                # the viewer (or, with no display, the web viewer on localhost)

Only the file is needed (lab/recording/logger.py describes its contents; docs/recordings.md). A file without its footer
(a killed writer) reads through RrdReader.stream(); a file cut inside a frame is salvaged with
`rerun rrd merge --continue-on-error` into a temporary copy and read from there (`salvaged`).
A file still being written (lab/recording/busy.py) reads as far as it is written (`live`); one that
holds nothing of its run yet (its writer is starting) raises RecordingInProgress, which says so,
and `replay` waits for its first generation a while (START_WAIT) before it says so.
"""

from __future__ import annotations

import dataclasses
import http.server
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import numpy as np

from lab.problem.controllers import Controller, controller_from_dict
from lab.recording import busy
from lab.recording.rerun_tool import rerun_binary

MAGIC = b"RRF"  # the first bytes of every .rrd file
START_WAIT = 30.0  # seconds `replay` waits for a recording being written to hold its run's first generation


class RecordingError(ValueError):
    """A file that is not a readable lab recording (the message names the file)."""


class RecordingInProgress(RecordingError):
    """A recording being written that holds nothing of its run yet (its writer is starting)."""


@dataclass(frozen=True)
class Recording:
    """What a recording holds. generations, best, median: one row per logged generation (sorted);
    controllers: (generation, document) with document = {"generation", "best_mse", "controller"}."""

    path: Path
    protocol: dict
    generations: np.ndarray
    best: np.ndarray
    median: np.ndarray
    controllers: list = field(repr=False)
    summary: dict | None = None
    salvaged: bool = False
    populations: list = field(default_factory=list, repr=False)  # (generation, Population), sorted
    live: bool = False  # being written when it was read: what it held then (lab/recording/busy.py)

    def population_at(self, generation: int):
        """The population logged at or before `generation` (lab.methods.Population, without its
        controllers: each candidate's MSE, species and point at the display goal), or None."""
        generation = _generation(generation)
        found = [p for g, p in self.populations if g <= generation]
        return found[-1] if found else None

    @property
    def last_generation(self) -> int | None:
        """The last generation whose scalars were written completely."""
        return int(self.generations[-1]) if len(self.generations) else None

    def best_at(self, generation: int) -> float:
        generation = _generation(generation)
        i = np.searchsorted(self.generations, generation, side="right") - 1
        if i < 0:
            raise RecordingError(f"{self.path}: no generation <= {generation} in the recording")
        return float(self.best[i])

    def controller_doc(self, generation: int | None = None) -> dict:
        """The document of the controller in force at `generation` (default: the last complete one)."""
        if not self.controllers:
            if self.live:
                raise RecordingInProgress(f"{self.path} is being written and holds no controller yet: "
                                          "its run has not logged its first generation; try again in a few seconds")
            raise RecordingError(f"{self.path}: the recording holds no controller")
        generation = None if generation is None else _generation(generation)
        if generation is None:
            generation = self.last_generation if self.last_generation is not None else self.controllers[-1][0]
        docs = [d for g, d in self.controllers if g <= generation]
        if not docs:
            raise RecordingError(f"{self.path}: no controller was logged at or before generation {generation} "
                             f"(the first is at generation {self.controllers[0][0]})")
        return docs[-1]


def _generation(generation) -> int:
    """A generation index: a whole number (ValueError naming the value otherwise)."""
    if isinstance(generation, (bool, np.bool_)) or not isinstance(generation, (int, np.integer)):
        raise ValueError(f"generation must be a whole number, got {generation!r}")
    return int(generation)


def load_controller(path: str | os.PathLike, generation: int | None = None) -> Controller:
    """Rebuild the controller logged at or before `generation` (default: the last complete generation)."""
    return controller_from_dict(read_recording(path).controller_doc(generation)["controller"])


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a recording written by lab.recording.logger.RerunLogger (raises OSError/ValueError naming
    the file; RecordingInProgress for one being written that holds nothing of its run yet). A
    recording being written is read as far as it is (Recording.live)."""
    live = busy.being_written(path)  # asked first: a writer that ends meanwhile has written more
    try:
        return dataclasses.replace(_read_file(path), live=live) if live else _read_file(path)
    except RecordingError as e:
        if live or busy.being_written(path):
            raise RecordingInProgress(
                f"{path} is being written: its run has started and has not logged its first generation yet "
                f"(the file holds {_size(path)}); try again in a few seconds") from e
        raise


def _read_file(path) -> Recording:
    path = check_file(path)
    try:
        return _read(path, path, salvaged=False)
    except RecordingError:
        raise
    except Exception as first:  # RuntimeError from a file cut inside a frame
        with tempfile.TemporaryDirectory(prefix="lab-salvage-") as tmp:
            copy = salvage(path, Path(tmp) / "salvaged.rrd", first)
            try:
                return _read(copy, path, salvaged=True)
            except RecordingError:
                raise
            except Exception as e:
                raise RecordingError(f"{path} cannot be read ({first}), even salvaged ({e})") from e


def _size(path) -> str:
    try:
        n = os.path.getsize(path)
    except OSError:
        return "nothing"
    return "nothing yet" if n == 0 else f"{n:,} bytes"


def check_file(path: str | os.PathLike) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such recording: {path}")
    if not path.is_file():
        raise RecordingError(f"{path} is not a file (expected a Rerun .rrd recording)")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    if not head:
        raise RecordingError(f"{path} is empty: a recording whose run never wrote to it (nothing is writing it now)")
    if head != MAGIC:
        raise RecordingError(f"{path} is not a Rerun recording (it does not start with {MAGIC!r})")
    return path


def salvage(path: Path, out: Path, reason: Exception | None = None) -> Path:
    """Copy every complete frame of a damaged .rrd to `out` (rerun rrd merge --continue-on-error)."""
    try:
        done = subprocess.run([rerun_binary(), "rrd", "merge", "--continue-on-error", str(path), "-o", str(out)],
                              capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as e:
        raise RecordingError(f"{path} cannot be read ({reason}) nor salvaged ({e})") from e
    if done.returncode != 0 or not out.is_file():
        raise RecordingError(f"{path} cannot be read ({reason}) nor salvaged: {done.stderr.strip()[-300:]}")
    return out


def _read(path: Path, name: Path, salvaged: bool) -> Recording:
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "RRD file has no footer": expected after a crash
        chunks = list(RrdReader(path).stream())
    protocol, summary, rows, docs, pops = None, None, [], [], {}
    for ch in chunks:
        entity = ch.entity_path
        if entity not in ("/protocol", "/summary", "/mse", "/controller", "/population", "/world/population"):
            continue
        rb = ch.to_record_batch()
        if entity in ("/population", "/world/population"):
            if "generation" in rb.schema.names:
                _population_rows(rb, entity, pops)
            continue
        if entity in ("/protocol", "/summary"):
            text = rb.column("TextDocument:text").to_pylist()[-1][0]
            protocol, summary = (json.loads(text), summary) if entity == "/protocol" else (protocol, json.loads(text))
        elif entity == "/mse" and "generation" in rb.schema.names:
            rows += zip(rb.column("generation").to_pylist(), rb.column("Scalars:scalars").to_pylist())
        elif entity == "/controller" and "generation" in rb.schema.names:
            for g, cell in zip(rb.column("generation").to_pylist(), rb.column("TextDocument:text").to_pylist()):
                if cell:
                    docs.append((int(g), json.loads(cell[0])))
    if protocol is None:
        raise RecordingError(f"{name} is a Rerun recording but not one of a lab training run (no /protocol)")
    rows.sort(key=lambda r: r[0])
    docs.sort(key=lambda d: d[0])
    gens = np.array([g for g, _ in rows], dtype=np.int64)
    best = np.array([v[0] for _, v in rows], dtype=np.float64)
    median = np.array([v[1] for _, v in rows], dtype=np.float64)
    return Recording(name, protocol, gens, best, median, docs, summary, salvaged, _populations(pops))


def _population_rows(rb, entity: str, pops: dict) -> None:
    """Collect /population's numbers and /world/population's points by generation."""
    gens = rb.column("generation").to_pylist()
    if entity == "/population":
        columns = {k: rb.column(k).to_pylist() for k in ("mse", "species") if k in rb.schema.names}
        for i, g in enumerate(gens):
            row = pops.setdefault(int(g), {})
            for k, values in columns.items():
                if values[i] is not None:
                    row[k] = values[i]
    elif "Points3D:positions" in rb.schema.names:
        for g, cell in zip(gens, rb.column("Points3D:positions").to_pylist()):
            if cell is not None:
                pops.setdefault(int(g), {})["points"] = cell


def _populations(pops: dict) -> list:
    from lab.methods import Population

    out = []
    for g in sorted(pops):
        row = pops[g]
        if "mse" not in row or "points" not in row:
            continue
        species = np.asarray(row["species"], np.int64) if row.get("species") is not None else None
        mse, points = np.asarray(row["mse"], float), np.asarray(row["points"], np.float32).reshape(-1, 3)
        if len(mse) and len(points) != len(mse) and len(points) % len(mse) == 0:  # a tree's: E points each
            points = points.reshape(len(mse), -1, 3)
        out.append((g, Population(g, mse, None, species, points)))
    return out


# ---------------------------------------------------------------------- the viewer
def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def web_url(web_port: int, data_url: str) -> str:
    return f"http://127.0.0.1:{web_port}/?url=" + quote(data_url, safe="")


class _OneFile(http.server.BaseHTTPRequestHandler):
    """Serves one file (the recording) to the web viewer, with the CORS header its page needs."""

    path_served: Path
    name: str

    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        self._serve(body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._serve(body=False)

    def _serve(self, body: bool) -> None:
        if self.path.split("?")[0] != f"/{self.name}":
            self.send_error(404)
            return
        data = self.path_served.read_bytes()
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Access-Control-Allow-Origin", "*")
        self.end_headers()
        if body:
            self.wfile.write(data)

    def log_message(self, *args) -> None:  # quiet
        pass


def serve_file(path: Path, port: int) -> tuple[http.server.ThreadingHTTPServer, str]:
    """An HTTP server on 127.0.0.1:port (0: a free one) serving `path`, in a thread; (server, its URL)."""
    handler = type("Handler", (_OneFile,), {"path_served": Path(path), "name": quote(Path(path).name)})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
    threading.Thread(target=server.serve_forever, name="replay-file-server", daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}/{handler.name}"


def replay(path: str | os.PathLike, web: bool | None = None, timeout: float | None = None,
           web_port: int | None = None, grpc_port: int | None = None, out=None) -> int:
    """Show a recording: the native viewer, or (web=True, or no display) the web viewer served on
    127.0.0.1, its URL printed. Returns when the viewer exits, after `timeout` seconds, or on
    Ctrl-C / SIGTERM; the viewer's whole process group is ended then, so nothing is left behind."""
    out = out or sys.stdout
    path = Path(path)
    rec = _first_generation(path, out)  # refuses what is not a lab recording; salvages a cut file
    with tempfile.TemporaryDirectory(prefix="lab-replay-") as tmp:
        shown = salvage(path, Path(tmp) / path.name) if rec.salvaged else path
        web = (not has_display()) if web is None else web
        cmd, files = [rerun_binary(), str(shown)], None
        if web:
            # the web viewer alone (no gRPC proxy: `--serve-web FILE` kept a whole core busy with no
            # browser attached), loading the recording over HTTP from a file server of ours: idle
            # when nobody watches
            files, data_url = serve_file(shown, grpc_port or 0)
            web_port = web_port or free_port()
            cmd = [rerun_binary(), "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port), data_url]
        try:
            proc = subprocess.Popen(cmd, start_new_session=True, stdin=subprocess.DEVNULL)
        except BaseException:
            if files is not None:
                files.shutdown()
            raise
        print(f"replaying {path} ({len(rec.generations)} generations{', salvaged' if rec.salvaged else ''}"
              f"{', those written so far: its run is still being recorded' if rec.live else ''}); "
              f"viewer process {proc.pid}", file=out, flush=True)
        if web:
            print(f"web viewer: {web_url(web_port, data_url)}", file=out, flush=True)
        try:
            return _wait_and_end(proc, timeout)
        finally:
            if files is not None:
                files.shutdown()


def _first_generation(path: Path, out, wait: float | None = None) -> Recording:
    """read_recording(path); a recording being written that holds nothing of its run yet is waited
    for, up to START_WAIT seconds (said once), then RecordingInProgress."""
    deadline, said = time.monotonic() + (START_WAIT if wait is None else wait), False
    while True:
        try:
            rec = read_recording(path)
            if rec.last_generation is not None or not rec.live:
                return rec
            error = RecordingInProgress(f"{path} is being written: its run has not logged its first "
                                        "generation yet; try again in a few seconds")
        except RecordingInProgress as e:
            error = e
        if time.monotonic() >= deadline:
            raise error
        if not said:
            print(f"{path} is being written; waiting for its first generation ...", file=out, flush=True)
            said = True
        time.sleep(0.2)


def _wait_and_end(proc: subprocess.Popen, timeout: float | None) -> int:
    previous = signal.signal(signal.SIGTERM, _raise_interrupt) if _main_thread() else None
    try:
        proc.wait(timeout)
        return 0
    except subprocess.TimeoutExpired:
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        end_group(proc)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def end_group(proc: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGTERM the process group of `proc` (started with start_new_session), then SIGKILL it."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, grace)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and _group_alive(proc.pid):
            proc.poll()
            time.sleep(0.05)
        if not _group_alive(proc.pid):
            break
    proc.poll()


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


__all__ = ["Recording", "RecordingError", "RecordingInProgress", "check_file", "load_controller", "read_recording", "replay", "salvage"]
