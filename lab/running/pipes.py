"""Messages between lab's processes: length-prefixed pickles over a pipe (no heavy imports).

Used by the Rerun writer process (lab/recording/writer.py) and the training process
(lab/running/worker.py). A message written with `send` is in the kernel's pipe buffer when it returns,
so it outlives the sender: a process killed right after still has it delivered.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import dataclasses
import sys
from pathlib import Path

HEADER = struct.Struct("<I")  # the length of each pickled message
PIPE_BYTES = 1 << 20  # F_SETPIPE_SZ: Linux's default limit for unprivileged processes
_F_SETPIPE_SZ = 1031


def start(module: str, *args: str, env: dict | None = None, pass_fds: tuple = ()) -> subprocess.Popen:
    """`python -m module args` with pipes on stdin and stdout (unbuffered), this checkout first on
    its path, one BLAS thread and one fitness thread (LAB_THREADS) unless set: a process that works
    beside this one. env: variables
    to set there, unless they are set here already. pass_fds: descriptors it inherits (subprocess's)."""
    root = str(Path(__file__).resolve().parents[2])  # the checkout: lab/running/pipes.py -> ../..
    extra = {k: v for k, v in (env or {}).items() if k not in os.environ}
    env = dict(os.environ, **extra,
               PYTHONPATH=os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "LAB_THREADS"):
        env.setdefault(var, "1")
    return subprocess.Popen([sys.executable, "-m", module, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            bufsize=0, env=env, pass_fds=tuple(pass_fds))


def claim_stdout() -> int:
    """In a process started by start(): a descriptor for its stdout pipe, with fd 1 (and so print,
    and any library's chatter) sent to stderr instead, where it cannot corrupt the messages."""
    fd = os.dup(sys.stdout.fileno())
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    return fd


def encode(message) -> bytes:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return HEADER.pack(len(data)) + data


def send(fd: int, message) -> None:
    """Write one message to fd, all of it (raises OSError, e.g. BrokenPipeError, when the reader is gone)."""
    data = memoryview(encode(message))
    while data:
        data = data[os.write(fd, data):]


def messages(fd: int):
    """Yield lists of the messages available on fd, one list per read, until end of input."""
    buf = bytearray()
    while True:
        data = os.read(fd, 1 << 20)
        if not data:
            return
        buf += data
        batch, at = [], 0
        while len(buf) - at >= HEADER.size:
            (n,) = HEADER.unpack_from(buf, at)
            if len(buf) - at - HEADER.size < n:
                break
            batch.append(pickle.loads(memoryview(buf)[at + HEADER.size:at + HEADER.size + n]))
            at += HEADER.size + n
        del buf[:at]
        if batch:
            yield batch


def grow(fd: int) -> None:
    """Let the pipe hold PIPE_BYTES (about a thousand generations), where the system allows it."""
    try:
        import fcntl

        fcntl.fcntl(fd, _F_SETPIPE_SZ, PIPE_BYTES)
    except (ImportError, OSError):  # a smaller pipe only means the writer waits sooner
        pass


class EventDecoder:
    """Events off the pipe back into the run's GenerationEvents: its run id, and the last controller
    sent where an event came without one."""

    def __init__(self, run_id: str = ""):
        self.run_id, self.controller = run_id, None

    def __call__(self, sent):
        if sent.controller is not None:
            self.controller = sent.controller
        return dataclasses.replace(sent, run_id=self.run_id, controller=self.controller)


class EventEncoder:
    """GenerationEvents for the pipe: the same named fields, the run id left out and the controller
    sent once (when it changes; None: the last one sent)."""

    def __init__(self):
        self.sent = None

    def __call__(self, event):
        controller = event.controller if event.controller is not self.sent else None
        self.sent = event.controller
        return dataclasses.replace(event, run_id="", controller=controller)
