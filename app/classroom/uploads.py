"""Uploads of recordings: checked as a transfer starts and as its parts arrive, before viser buffers them.

viser keeps an upload's parts in memory until the file is whole (app/viser_private.py,
guard_uploads, puts `UploadGuard.start` and `UploadGuard.part` in front of it). A transfer is
refused as it starts when it is too large, when it declares more parts than its size allows
(at most MAX_PARTS, a 200 MiB file in viser's 512 KiB parts, and never more parts than bytes),
when the tab may not upload (a viewer), when the tab has started too many lately, when the same
tab has another upload under way (one at a time per tab: a stalled transfer of one tab never
holds up another's), when the uploads under way would hold more than MAX_IN_FLIGHT in memory (the
tab is told how much and why), or when the upload folder would pass its cap; a transfer whose
parts add up to more than it declared, or that sends a part out of its declared range, or whose
bytes are all in but not its parts, is dropped as that part arrives; one that stalls is dropped
after IDLE_TIMEOUT (`sweep`). A file that passes is saved under a name that is never hidden,
never too long and never another file's (`save_upload`). Messages name the file as the user
named it, never a path of the server (`save_upload` puts the name in place of its temporary file).
"""

from __future__ import annotations

import errno
import os
import re
import tempfile
import threading
import time
from collections import deque

from app.classroom.files import kind_of, not_a_file
from app.classroom.limits import refused

MAX_UPLOAD = 200 * 2**20  # bytes, one file
MAX_URDF = 8 * 2**20  # bytes, an uploaded URDF (app/any_robot.py): one without meshes is tens of kB
PART = 512 * 2**10  # bytes: viser's browser client sends a file in parts of this size (UploadButton.tsx)
MAX_PARTS = -(-MAX_UPLOAD // PART)  # 400: the parts of the largest file allowed
MAX_IN_FLIGHT = 2 * MAX_UPLOAD  # bytes declared by every upload under way, all tabs together
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


def safe_name(name: str, suffix: str = ".rrd") -> str:
    """A file name for an upload: its base name, letters, digits and . _ - only (others become _),
    no leading dot (never hidden), at most MAX_STEM characters before the suffix ('.rrd'; a URDF's '.urdf')."""
    base = os.path.basename(name.replace("\\", "/"))
    stem = base[:-len(suffix)] if base.lower().endswith(suffix) else base
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".")[:MAX_STEM].rstrip(".")
    return (stem or "upload") + suffix


def not_a_recording_file(path: str) -> str | None:
    """Why a recording to open is not a regular file ("x.rrd is a named pipe (FIFO), not a file"),
    naming it by its base name (a tab is never told where the server keeps files); None when it is
    one. Reading a pipe with no writer would block for good, a device read without end."""
    why = not_a_file(path)
    return None if why is None else why.replace(path, os.path.basename(path), 1)


def hide_paths(text: str, path: str, name: str) -> str:
    """text with `path` (and any other absolute path in it, e.g. a salvage copy's) shown as the
    user's file name / a base name: a tab is never told where the server keeps files."""
    shown = os.path.basename(name.replace("\\", "/")) or "the upload"
    text = text.replace(os.path.abspath(path), shown).replace(path, shown)
    return re.sub(r"(?<![\w.])/(?:[^\s/:'\"()]+/)+([^\s/:'\"()]+)", r"\1", text)


class UploadRefused(ValueError):
    """An uploaded file failed its check (the message names it as the user did)."""


def save_upload(folder: str, name: str, content: bytes, check=None, suffix: str = ".rrd") -> str:
    """Write content under folder as safe_name(name), or name-2.rrd, name-3.rrd, ... when taken
    (never replacing a file); check(path), if given, is called on the written file before it gets
    its name (an exception leaves nothing behind; one from check comes back as UploadRefused, its
    message naming the file as `name` does, not the temporary path). Returns the path. A folder
    path that holds something else (a file, a pipe, a device) is an OSError saying what, never the
    path (the tab sees it)."""
    if os.path.lexists(folder) and not os.path.isdir(folder):
        what = kind_of(os.stat(folder).st_mode) if os.path.exists(folder) else "a broken link"
        raise OSError(errno.ENOTDIR, f"the server's upload folder is {what or 'a file'}, not a folder")
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".upload-", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(content)
        if check is not None:
            try:
                check(tmp)
            except Exception as e:  # noqa: BLE001 - said with the user's name, not the server's path
                raise UploadRefused(hide_paths(str(e), tmp, name)) from None
        stem = safe_name(name, suffix)[:-len(suffix)]
        for k in range(1, 10_000):
            path = os.path.join(folder, f"{stem}{suffix}" if k == 1 else f"{stem}-{k}{suffix}")
            try:
                os.link(tmp, path)  # atomic, and fails if the name is taken
            except FileExistsError:
                continue
            return path
        raise OSError(f"no free name for {stem}{suffix} in {folder}")
    finally:
        try:
            os.remove(tmp)
        except FileNotFoundError:
            pass


class UploadGuard:
    def __init__(self, folder: str, allowed=None, notify=None, *, max_upload: int = MAX_UPLOAD,
                 folder_cap: int = FOLDER_CAP, idle_timeout: float = IDLE_TIMEOUT, rate=RATE,
                 max_parts: int = MAX_PARTS, max_in_flight: int = MAX_IN_FLIGHT, clock=time.monotonic):
        """folder: where uploads are saved; allowed(client_id) -> None or the reason a tab may not
        upload; notify(client_id, text): tell a tab its upload was refused or dropped."""
        self.folder, self.allowed, self.notify = folder, allowed, notify
        self.max_upload, self.folder_cap, self.idle_timeout = max_upload, folder_cap, idle_timeout
        self.rate, self.clock = rate, clock
        self.max_parts, self.max_in_flight = max_parts, max_in_flight
        self._lock = threading.Lock()
        self._active: dict[str, dict] = {}  # transfer id -> client, name, size, received, last, complete
        self._starts: dict[int, deque] = {}  # client id -> times of its recent starts

    def _tell(self, client_id, text: str) -> None:
        if self.notify is not None:
            self.notify(client_id, text)

    # ------------------------------------------------------------------ called by viser's event loop
    def start(self, client_id: int, transfer_id: str, filename: str, size: int, parts: int | None = None) -> bool:
        """Whether viser may receive this upload of `parts` parts (a refusal is told to the tab)."""
        reason = self.refusal(client_id, filename, size, transfer_id, parts)
        if reason is not None:
            self._tell(client_id, refused(reason))  # once: an access refusal already says it
            return False
        return True

    def refusal(self, client_id: int, filename: str, size: int, transfer_id: str | None = None,
                parts: int | None = None) -> str | None:
        """Why this upload may not start (None: it may; with a transfer_id it is then under way).
        parts: the part count it declares (None: not known yet, not checked)."""
        filename = filename if isinstance(filename, str) else ""
        shown = (os.path.basename(filename.replace("\\", "/")) or "the upload")[:60]
        if self.allowed is not None and (reason := self.allowed(client_id)) is not None:
            return reason
        if not filename.lower().endswith((".rrd", ".urdf")):
            return f"{shown} is not a Rerun recording (.rrd) nor a robot's URDF (.urdf)"
        if filename.lower().endswith(".urdf") and size > MAX_URDF:  # app/any_robot.py: More robots…
            return f"{shown} is {mib(size)}; a URDF may be at most {mib(MAX_URDF)} (its meshes are not needed)"
        if size <= 0:
            return f"{shown} is empty"
        if size > self.max_upload:
            return f"{shown} is {mib(size)}; an upload may be at most {mib(self.max_upload)}"
        if parts is not None and not 1 <= parts <= min(size, self.max_parts):
            return (f"{shown} declares {parts:,} parts for {mib(size)}; an upload comes in 1 to "
                    f"{min(size, self.max_parts):,} parts")
        now = self.clock()
        with self._lock:
            starts = self._starts.setdefault(client_id, deque())
            while starts and now - starts[0] > self.rate[1]:
                starts.popleft()
            if len(starts) >= self.rate[0]:
                return f"too many uploads from this tab: at most {self.rate[0]} in {self.rate[1]:g} s"
            if any(t["client"] == client_id for t in self._active.values()):
                return "another upload from this tab is under way; try again when it has finished"
            held = sum(t["size"] for t in self._active.values())
            if held + size > self.max_in_flight:
                return (f"uploads under way from other tabs hold {mib(held)} of the {mib(self.max_in_flight)} "
                        f"the server keeps in memory; {shown} ({mib(size)}) must wait until they have finished "
                        f"(a stalled one is dropped after {self.idle_timeout:g} s)")
            used = folder_bytes(self.folder) + held
            if used + size > self.folder_cap:
                return (f"the upload folder is full ({mib(used)} of {mib(self.folder_cap)}); "
                        f"{shown} ({mib(size)}) does not fit")
            if transfer_id is None:
                return None
            starts.append(now)
            self._active[transfer_id] = dict(client=client_id, name=shown, size=size, received=0, last=now,
                                           complete=False, parts=parts, seen=set())
        return None

    def part(self, client_id: int, transfer_id: str, nbytes: int, index: int | None = None) -> bool:
        """Whether viser may buffer this part (number `index`, None: not checked); False drops the
        transfer (told to the tab)."""
        why = None
        with self._lock:
            t = self._active.get(transfer_id)
            if t is None or t["client"] != client_id or t["complete"]:
                return False
            parts = t.get("parts")
            t["received"] += nbytes
            t["last"] = self.clock()
            if index is not None and parts is not None and (not 0 <= index < parts or index in t["seen"]):
                why = f"sent part {index} of the {parts} it declared, or sent it twice"
            elif t["received"] > t["size"]:
                why = f"sent more than the {mib(t['size'])} it declared"
            else:
                if index is not None:
                    t["seen"].add(index)
                whole = t["received"] == t["size"]
                if whole and index is not None and parts is not None and len(t["seen"]) < parts:
                    why = f"sent its {mib(t['size'])} in {len(t['seen'])} of the {parts} parts it declared"
                t["complete"] = whole
            if why is not None:
                del self._active[transfer_id]
        if why is not None:
            self._tell(client_id, f"refused: {t['name']} {why}; dropped")
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
