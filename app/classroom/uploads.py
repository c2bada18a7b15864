"""Uploads of recordings: checked as a transfer starts and as its parts arrive, before viser buffers them.

viser keeps an upload's parts in memory until the file is whole (app/viser_private.py,
guard_uploads, puts `UploadGuard.start` and `UploadGuard.part` in front of it). A transfer is
refused as it starts when it is too large, when the tab may not upload (a viewer), when the tab
has started too many lately, when another upload is under way, or when the upload folder would
pass its cap; a transfer whose parts add up to more than it declared is dropped as the extra
part arrives; one that stalls is dropped after IDLE_TIMEOUT (`sweep`). A file that passes is
saved under a name that is never hidden, never too long and never another file's
(`save_upload`).
"""

from __future__ import annotations

import os
import re
import tempfile
import threading
import time
from collections import deque

MAX_UPLOAD = 200 * 2**20  # bytes, one file
FOLDER_CAP = 1024 * 2**20  # bytes, the upload folder in all
IDLE_TIMEOUT = 30.0  # s without a part: the transfer is dropped
RATE = (4, 60.0)  # at most 4 uploads started per tab in 60 s
MAX_STEM = 100  # characters of a saved file's name, before ".rrd"


def mib(n: int) -> str:
    return f"{n / 2**20:,.0f} MiB" if n >= 2**20 else f"{n / 2**10:,.0f} KiB"


def folder_bytes(folder: str) -> int:
    """Bytes of the regular files directly in folder (0 if it does not exist)."""
    total = 0
    try:
        with os.scandir(folder) as it:
            for e in it:
                if e.is_file(follow_symlinks=False):
                    total += e.stat(follow_symlinks=False).st_size
    except FileNotFoundError:
        pass
    return total


def safe_name(name: str) -> str:
    """A file name for an upload: its base name, letters, digits and . _ - only (others become _),
    no leading dot (never hidden), at most MAX_STEM characters before '.rrd'."""
    base = os.path.basename(name.replace("\\", "/"))
    stem = base[:-4] if base.lower().endswith(".rrd") else base
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".")[:MAX_STEM].rstrip(".")
    return (stem or "upload") + ".rrd"


def save_upload(folder: str, name: str, content: bytes, check=None) -> str:
    """Write content under folder as safe_name(name), or name-2.rrd, name-3.rrd, ... when taken
    (never replacing a file); check(path), if given, is called on the written file before it gets
    its name (an exception leaves nothing behind). Returns the path."""
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".upload-", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(content)
        if check is not None:
            check(tmp)
        stem = safe_name(name)[:-4]
        for k in range(1, 10_000):
            path = os.path.join(folder, f"{stem}.rrd" if k == 1 else f"{stem}-{k}.rrd")
            try:
                os.link(tmp, path)  # atomic, and fails if the name is taken
            except FileExistsError:
                continue
            return path
        raise OSError(f"no free name for {stem}.rrd in {folder}")
    finally:
        try:
            os.remove(tmp)
        except FileNotFoundError:
            pass


class UploadGuard:
    def __init__(self, folder: str, allowed=None, notify=None, *, max_upload: int = MAX_UPLOAD,
                 folder_cap: int = FOLDER_CAP, idle_timeout: float = IDLE_TIMEOUT, rate=RATE,
                 clock=time.monotonic):
        """folder: where uploads are saved; allowed(client_id) -> None or the reason a tab may not
        upload; notify(client_id, text): tell a tab its upload was refused or dropped."""
        self.folder, self.allowed, self.notify = folder, allowed, notify
        self.max_upload, self.folder_cap, self.idle_timeout = max_upload, folder_cap, idle_timeout
        self.rate, self.clock = rate, clock
        self._lock = threading.Lock()
        self._active: dict[str, dict] = {}  # transfer id -> client, name, size, received, last, complete
        self._starts: dict[int, deque] = {}  # client id -> times of its recent starts

    def _tell(self, client_id, text: str) -> None:
        if self.notify is not None:
            self.notify(client_id, text)

    # ------------------------------------------------------------------ called by viser's event loop
    def start(self, client_id: int, transfer_id: str, filename: str, size: int) -> bool:
        """Whether viser may receive this upload (a refusal is told to the tab)."""
        reason = self.refusal(client_id, filename, size, transfer_id)
        if reason is not None:
            self._tell(client_id, f"refused: {reason}")
            return False
        return True

    def refusal(self, client_id: int, filename: str, size: int, transfer_id: str | None = None) -> str | None:
        """Why this upload may not start (None: it may; with a transfer_id it is then under way)."""
        shown = (filename or "the upload")[:60]
        if self.allowed is not None and (reason := self.allowed(client_id)) is not None:
            return reason
        if not filename.lower().endswith(".rrd"):
            return f"{shown} is not a Rerun recording (.rrd)"
        if size <= 0:
            return f"{shown} is empty"
        if size > self.max_upload:
            return f"{shown} is {mib(size)}; an upload may be at most {mib(self.max_upload)}"
        now = self.clock()
        with self._lock:
            starts = self._starts.setdefault(client_id, deque())
            while starts and now - starts[0] > self.rate[1]:
                starts.popleft()
            if len(starts) >= self.rate[0]:
                return f"too many uploads from this tab: at most {self.rate[0]} in {self.rate[1]:g} s"
            if self._active:
                return "another upload is under way; try again when it has finished"
            used = folder_bytes(self.folder)
            if used + size > self.folder_cap:
                return (f"the upload folder is full ({mib(used)} of {mib(self.folder_cap)}); "
                        f"{shown} ({mib(size)}) does not fit")
            if transfer_id is None:
                return None
            starts.append(now)
            self._active[transfer_id] = dict(client=client_id, name=shown, size=size, received=0, last=now,
                                           complete=False)
        return None

    def part(self, client_id: int, transfer_id: str, nbytes: int) -> bool:
        """Whether viser may buffer this part; False drops the transfer (told to the tab)."""
        with self._lock:
            t = self._active.get(transfer_id)
            if t is None or t["client"] != client_id or t["complete"]:
                return False
            t["received"] += nbytes
            t["last"] = self.clock()
            if t["received"] > t["size"]:
                del self._active[transfer_id]
                over = True
            else:
                t["complete"] = t["received"] == t["size"]
                over = False
        if over:
            self._tell(client_id, f"refused: {t['name']} sent more than the {mib(t['size'])} it declared; dropped")
            return False
        return True

    # ------------------------------------------------------------------ called by the app
    def done(self) -> None:
        """The app has handled the finished upload (saved or refused it): the next may start."""
        with self._lock:
            for k in [k for k, t in self._active.items() if t["complete"]]:
                del self._active[k]

    def sweep(self) -> list[str]:
        """Drop transfers without a part for idle_timeout (told to their tabs); their ids, for viser
        to forget what it buffered."""
        now = self.clock()
        with self._lock:
            stale = {k: t for k, t in self._active.items() if now - t["last"] > self.idle_timeout}
            for k in stale:
                del self._active[k]
        for t in stale.values():
            if not t["complete"]:
                self._tell(t["client"], f"dropped: {t['name']} stalled ({mib(t['received'])} of "
                                        f"{mib(t['size'])} in {self.idle_timeout:g} s without progress)")
        return list(stale)

    def in_flight(self) -> int:
        with self._lock:
            return len(self._active)
