"""One Rerun writer process for many recordings: what a classroom server records with.

    service = WriterService()                 # its process starts now (imports done before the first run)
    logger = RerunLogger(runner, path="recordings/class/", service=service)
    ...
    service.close()                           # no more recordings; its process ends once theirs are closed

A lone RerunLogger starts a writer process of its own (`python -m lab.recording.writer`), which costs
each run the process's start (the imports of rerun and pyarrow, about 1.3 s of CPU) and its exit: on
a 2-core laptop serving a class, CPU taken from the students' training. Here one process
(`python -m lab.recording.writer --serve FD`) writes them all, each in a thread of its own, exactly as
a lone writer would (lab/recording/writer.py): the logger hands it, over a Unix socket (SCM_RIGHTS),
the read end of the recording's message pipe, the write end of its ack pipe and the file's lock.
What a lone writer promises holds: the pipe outlives the app (the file gets its footer after a
SIGKILL of the app), the lock is held until the file is closed, "C" says closed and complete, "E"
why it failed. The recording's compaction (`rerun rrd optimize`) is still a short process of
Rerun's own binary a run. A process that has died is started again on the next recording.
"""

from __future__ import annotations

import os
import socket
import subprocess
import threading

from lab.running import pipes

DONE = b"\0"  # the last byte on a served recording's ack pipe: closed and compacted (or failed), as a lone writer's exit


class WriterService:
    """A writer process serving recordings (see the module docstring); start=False: started on the first."""

    def __init__(self, start: bool = True):
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._sock: socket.socket | None = None
        self._closed = False
        if start:
            with self._lock:
                self._started()

    @property
    def pid(self) -> int | None:
        """The serving process's id (None before it starts)."""
        return None if self._proc is None else self._proc.pid

    def _started(self) -> socket.socket:
        if self._proc is None or self._proc.poll() is not None:
            if self._sock is not None:
                self._sock.close()
            parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self._proc = pipes.start("lab.recording.writer", "--serve", str(child.fileno()),
                                         env={"RUST_LOG": "off"}, pass_fds=(child.fileno(),))
            finally:
                child.close()
            self._proc.stdin.close()  # its recordings come on the socket, its acks go on theirs
            self._proc.stdout.close()
            threading.Thread(target=self._proc.wait, name="rerun-writer-service", daemon=True).start()
            self._sock = parent
        return self._sock

    def open(self, busy_fd: int | None) -> "Served":
        """A recording's pipes, handed to the serving process with the file's lock (busy_fd, this
        process's copy stays open: the caller closes it)."""
        msg_r, msg_w = os.pipe()
        ack_r, ack_w = os.pipe()
        fds = [msg_r, ack_w] + ([busy_fd] if busy_fd is not None else [])
        try:
            with self._lock:
                if self._closed:
                    raise RuntimeError("the writer service is closed")
                for attempt in (1, 2):  # a process that has died is started again, once
                    try:
                        socket.send_fds(self._started(), [b"R"], fds)
                        break
                    except OSError:
                        if attempt == 2:
                            raise
                        self._proc = None
                pid = self._proc.pid
        except BaseException:
            for fd in (msg_w, ack_r):
                os.close(fd)
            raise
        finally:
            os.close(msg_r)
            os.close(ack_w)
        return Served(msg_w, ack_r, pid)

    def close(self) -> None:
        """No more recordings: the process ends once those it writes are closed (not waited for)."""
        with self._lock:
            self._closed = True
            if self._sock is not None:
                self._sock.close()
                self._sock = None


class Served:
    """A served recording's end of its pipes, as RerunLogger uses a lone writer's Popen: stdin (the
    messages), stdout (its acks: "C" or "E..." then DONE), wait() until compacted, pid and returncode."""

    def __init__(self, msg_w: int, ack_r: int, pid: int):
        self.pid = pid
        self.stdin = os.fdopen(msg_w, "wb", buffering=0)
        self.stdout = _Acks(ack_r)
        self.returncode: int | None = None

    def wait(self, timeout: float | None = None) -> int:
        if not self.stdout.ended.wait(timeout):
            raise subprocess.TimeoutExpired(f"recording writer {self.pid}", timeout)
        self.returncode = 0
        return 0

    def poll(self) -> int | None:
        return 0 if self.stdout.ended.is_set() else None


class _Acks:
    """The ack pipe, read to its end by a thread of its own: read(1) the first byte, read() the rest
    until the pipe ends (DONE left out); ended: the recording is closed and compacted (or failed)."""

    def __init__(self, fd: int):
        self._fd, self._buf, self._cond = fd, bytearray(), threading.Condition()
        self.ended, self.closed = threading.Event(), False
        threading.Thread(target=self._pump, name=f"recording-acks-{fd}", daemon=True).start()

    def _pump(self) -> None:
        try:
            while True:
                data = os.read(self._fd, 4096)
                if not data:
                    break
                with self._cond:
                    self._buf += data
                    self._cond.notify_all()
        except OSError:
            pass
        finally:
            os.close(self._fd)
            with self._cond:
                if self._buf.endswith(DONE):
                    del self._buf[-1:]
                self.ended.set()
                self._cond.notify_all()

    def read(self, n: int = -1) -> bytes:
        with self._cond:
            if n < 0:
                self._cond.wait_for(self.ended.is_set)
                out = bytes(self._buf)
                self._buf.clear()
                return out
            self._cond.wait_for(lambda: len(self._buf) >= n or self.ended.is_set())
            out = bytes(self._buf[:n])
            del self._buf[:n]
            return out

    def close(self) -> None:
        self.closed = True
