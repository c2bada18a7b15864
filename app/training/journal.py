"""The notebook's journal: entries that could not be written into the notebook, kept in a file beside it.

`<notebook>.journal` holds one entry a line (its JSON, as the notebook would store it). A write into
the notebook that fails (another program holds it locked, a full disk) puts the entry here at once,
and the app's stop puts there whatever is still not written after a bounded wait; the next opening of
the notebook imports the journal's entries and removes them from it only once they are committed
(app/training/notebook.py). A process killed at any point loses nothing the journal holds.

Every change rewrites the whole journal: a temporary file beside it, written and fsync'd, then renamed
over it (atomic), then the folder fsync'd; a write that fails (ENOSPC, EFBIG) leaves the journal as it
was. Processes that share a notebook take an flock on its folder around a change (read, merge, write),
waited for LOCK_WAIT s at most. A line that is not an entry is kept as it is, never dropped silently.
Only a regular file is read: a pipe or a device at the journal's path is refused (`JournalError`).

A full disk: the notebook keeps `<notebook>.journal-reserve`, RESERVE bytes allocated on the disk
while there was room (`keep_reserve`, at each opening). A journal write that fails for want of space
(ENOSPC, EDQUOT) removes the reserve, which frees its blocks, and writes again; the next opening
allocates it anew once there is room.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import threading
import time
from contextlib import contextmanager

from app.classroom.files import kind_of

LOCK_WAIT = 2.0  # s a change waits for another process's change of the same journal, then goes on
RESERVE = 4 * 2**20  # bytes kept allocated beside the journal, given up for it when the disk is full
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


class JournalError(OSError):
    """The journal's path holds something that is not a journal file (a pipe, a device, a folder)."""


class Journal:
    def __init__(self, path: str):
        self.path = path
        self.reserve_path = path + "-reserve"

    def keep_reserve(self, size: int | None = None) -> bool:
        """Allocate the reserve (`size` bytes on the disk, default RESERVE) if it is missing or short;
        False when the disk has no room for it now (then nothing is left behind). Never raises OSError."""
        size = RESERVE if size is None else size
        try:
            st = os.stat(self.reserve_path)
            if kind_of(st.st_mode) is None and st.st_size >= size and st.st_blocks * 512 >= size:
                return True
        except OSError:
            pass
        tmp = f"{self.reserve_path}.{os.getpid()}-{threading.get_ident()}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                os.posix_fallocate(fd, 0, size)
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.reserve_path)
            return True
        except OSError:
            try:
                os.remove(tmp)
            except OSError:
                pass
            return False

    def _free_reserve(self) -> bool:
        """Give the reserve's blocks back to the disk; True if there was one."""
        try:
            if kind_of(os.lstat(self.reserve_path).st_mode) is not None:
                return False
            os.remove(self.reserve_path)
        except OSError:
            return False
        _sync_folder(self.reserve_path)
        return True

    def exists(self) -> bool:
        return os.path.lexists(self.path)

    def read(self) -> tuple[dict[str, str], list[str]]:
        """(run_id -> the entry's JSON, in the journal's order; the lines that are not entries)."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return {}, []
        if (what := kind_of(st.st_mode)) is not None:
            raise JournalError(f"the journal {self.path} is {what}, not a file")
        fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK)  # a pipe swapped in meanwhile never blocks
        try:
            if (what := kind_of(os.fstat(fd).st_mode)) is not None:
                raise JournalError(f"the journal {self.path} is {what}, not a file")
            with os.fdopen(fd, "rb", closefd=False) as f:
                data = f.read()
        finally:
            os.close(fd)
        entries, bad = {}, []
        for line in data.decode("utf-8", "replace").splitlines():
            if not line.strip():
                continue
            try:
                e = json.loads(line)
            except (ValueError, RecursionError):
                e = None
            if isinstance(e, dict) and all(isinstance(e.get(k), str) for k in ("run_id", "robot", "method")):
                entries.pop(e["run_id"], None)
                entries[e["run_id"]] = line
            else:
                bad.append(line)
        return entries, bad

    def change(self, add: dict[str, str] | None = None, drop: dict[str, str] | None = None) -> dict[str, str]:
        """Add entries (run_id -> JSON) and drop those committed (run_id -> the JSON committed: an
        entry replaced since is kept), in one atomic rewrite; the file is removed when nothing is left.
        Returns the entries it holds now. OSError (ENOSPC, EFBIG, ...) leaves the journal as it was."""
        with self._locked():
            entries, bad = self.read()
            for run_id, text in (drop or {}).items():
                if entries.get(run_id) == text:
                    del entries[run_id]
            for run_id, text in (add or {}).items():
                entries.pop(run_id, None)
                entries[run_id] = text
            lines = list(entries.values()) + bad
            if not lines:
                if os.path.lexists(self.path):
                    os.remove(self.path)
                    _sync_folder(self.path)
                return entries
            self._write("".join(line + "\n" for line in lines).encode("utf-8"))
            return entries

    def set_aside(self) -> str:
        """Rename the journal (its lines that are not entries, once the others are imported) out of
        the way: <journal>.unreadable, -2, -3 ...; returns the new path."""
        for k in range(1, 1000):
            target = f"{self.path}.unreadable" + ("" if k == 1 else f"-{k}")
            if not os.path.lexists(target):
                os.rename(self.path, target)
                _sync_folder(self.path)
                return target
        raise OSError(f"no free name beside {self.path}")

    def _write(self, data: bytes) -> None:
        try:
            self._write_once(data)
        except OSError as e:
            if e.errno not in _NO_SPACE or not self._free_reserve():
                raise
            self._write_once(data)  # the reserve's room, given up for it

    def _write_once(self, data: bytes) -> None:
        tmp = f"{self.path}.{os.getpid()}-{threading.get_ident()}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.path)
        except BaseException:
            try:
                os.remove(tmp)
            except OSError:
                pass
            raise
        _sync_folder(self.path)

    @contextmanager
    def _locked(self):
        """An flock on the journal's folder (another process's change waits LOCK_WAIT s at most)."""
        try:
            fd = os.open(os.path.dirname(os.path.abspath(self.path)), os.O_RDONLY)
        except OSError:
            yield
            return
        try:
            deadline = time.monotonic() + LOCK_WAIT
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        break  # went on without it: a rewrite is still atomic
                    time.sleep(0.02)
            yield
        finally:
            os.close(fd)  # the flock goes with it


def _sync_folder(path: str) -> None:
    try:
        fd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
