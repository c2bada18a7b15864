"""Files that are not files: a path given to the lab (a token file, the notebook, an upload's folder, a
recording to replay) is looked at with os.stat before it is opened, and anything but a regular file is
refused at once, named by what it is. Opening a named pipe with no writer blocks for good, and a
device such as /dev/zero gives bytes without end (issue #55: 5.7 GB read, then a MemoryError).

    what = kind_of(os.stat(path).st_mode)      # None for a regular file, else "a named pipe (FIFO)", ...
    text = read_small(path, 4096)               # a regular file of at most 4096 bytes, or FileRefused
"""

from __future__ import annotations

import os
import stat


class FileRefused(ValueError):
    """A path that is not a regular file, or a file larger than its purpose allows (the message
    names the path and what it is)."""


def kind_of(mode: int) -> str | None:
    """What a file of this st_mode is, in words, when it is not a regular file (None when it is)."""
    for test, words in ((stat.S_ISREG, None), (stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                        (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
                        (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return words
    return "not a regular file"


def size_words(n: int) -> str:
    return f"{n:,} bytes" if n < 2**10 else f"{n / 2**10:,.1f} KiB" if n < 2**20 else f"{n / 2**20:,.1f} MiB"


def not_a_file(path: str) -> str | None:
    """Why `path` is not a regular file ("PATH is a named pipe (FIFO), not a file"), None when it is
    one or does not exist (its opener says that)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    what = kind_of(mode)
    return None if what is None else f"{path} is {what}, not a file"


def read_small(path: str, limit: int) -> bytes:
    """The bytes of a regular file of at most `limit` bytes. FileRefused (naming the path and what
    it is) for a pipe, a device, a folder, a socket or a larger file, before anything blocks: the
    path is looked at first, opened with O_NONBLOCK (a pipe swapped in meanwhile never blocks) and
    looked at again, and at most limit + 1 bytes are read. OSError (missing, no permission) as open's."""
    if (why := not_a_file(path)) is not None:
        raise FileRefused(why)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if (what := kind_of(st.st_mode)) is not None:
            raise FileRefused(f"{path} is {what}, not a file")
        if st.st_size > limit:
            raise FileRefused(f"{path} is {size_words(st.st_size)}; at most {size_words(limit)} are read from it")
        chunks, total = [], 0
        while total <= limit:
            chunk = os.read(fd, limit + 1 - total)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > limit:  # grew since it was looked at
            raise FileRefused(f"{path} is over {size_words(limit)}; at most {size_words(limit)} are read from it")
        return b"".join(chunks)
    finally:
        os.close(fd)
