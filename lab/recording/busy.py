"""Whether a recording is being written: an advisory lock (flock) held on the file while it is.

    fd = hold(path)        # the logger, once the file is claimed: an exclusive lock on it
    being_written(path)    # a reader: True while some logger or its writer process holds that lock

The logger takes the lock as soon as it has claimed the file (still empty) and hands the locked
descriptor to its writer process, which keeps it until it exits; the kernel drops the lock when
the last of the two holding processes ends, however it ends. So a file that cannot be read yet
(empty: the writer is starting; a header and no run yet) is told from one that never will be (a
run that never began, a writer killed before it wrote). Where flock is missing, nothing is ever
said to be written (readers say what they find in the file).
"""

from __future__ import annotations

import os

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None


def hold(path: str | os.PathLike) -> int | None:
    """A descriptor of `path` holding an exclusive lock on it, or None where that cannot be had
    (no flock; another logger holds it: a file overwritten while another writes it)."""
    if fcntl is None:
        return None
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def being_written(path: str | os.PathLike) -> bool:
    """Whether a logger or its writer process holds `path` (see the module docstring). A shared
    lock is tried: readers asking at the same time do not see each other as writers."""
    if fcntl is None:
        return False
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a filesystem without locks
        return False
    finally:
        os.close(fd)  # closing drops our shared lock
    return False
