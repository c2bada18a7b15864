"""The lab notebook: one entry per run started in the app, kept across restarts and shared safely.

Stored in SQLite (the standard library's sqlite3) at recordings/notebook.db by default, beside
the runs' Rerun recordings (`python -m app --notebook PATH`). WAL mode and one transaction per
change: two apps (or more) can share one notebook without losing an entry, and a crash never
leaves it half-written. A JSON notebook of earlier versions (notebook.json beside the database,
or a PATH ending in .json, whose database is then PATH with .db) is imported once, automatically,
and left in place. Each entry:

    run_id, started (ISO 8601, local time), robot, method, seed, settings (the TrainConfig),
    state (finished / stopped / failed), generations, evaluations, seconds,
    train_mse, test_mse (held-out), recording (path of the .rrd or null),
    controller (the final best controller's to_dict(), so an entry replays without its recording)

A path that holds something else (a folder, a file that is not a lab notebook) is refused with
NotebookError, and left as it is. An entry that is not a run (no text run_id, robot or method)
is kept as it is but not listed; `skipped()` names them.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sqlite3
import threading
import time

log = logging.getLogger(__name__)

DEFAULT_PATH = os.path.join("recordings", "notebook.db")
SQLITE_MAGIC = b"SQLite format 3\x00"
_SCHEMA = ("CREATE TABLE IF NOT EXISTS runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)",
           "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")


class NotebookError(ValueError):
    """The notebook's path holds something that is not a lab notebook (it is left untouched)."""


class Notebook:
    """The runs of a SQLite notebook; every call opens its own connection (threads and processes
    may share the file). path: the database, or a JSON notebook whose database sits beside it."""

    def __init__(self, path: str = DEFAULT_PATH):
        self.given = os.fspath(path)
        legacy = None
        if self.given.endswith(".json"):
            legacy, self.path = self.given, self.given[: -len(".json")] + ".db"
        else:
            self.path = self.given
            beside = os.path.join(os.path.dirname(self.path), "notebook.json")
            legacy = beside if os.path.basename(self.path) == "notebook.db" else None
        self._lock = threading.Lock()
        self._skipped: list[str] = []
        self._check(self.path, sqlite=True)
        entries = self._read_json(legacy) if legacy is not None and os.path.lexists(legacy) else None
        try:
            with self._connect() as db:
                for statement in _SCHEMA:
                    db.execute(statement)
                imported = db.execute("SELECT value FROM meta WHERE key = 'imported'").fetchone()
                if entries is not None and imported is None:
                    for e in entries:
                        db.execute("INSERT OR IGNORE INTO runs (run_id, entry) VALUES (?, ?)",
                                   (_run_id(e), json.dumps(e)))
                    db.execute("INSERT INTO meta VALUES ('imported', ?)", (legacy,))
        except sqlite3.DatabaseError as e:
            raise NotebookError(f"notebook {self.path} is not a lab notebook ({e}); it was left as it is: "
                                "move it away or give another path") from e

    def _connect(self) -> sqlite3.Connection:
        folder = os.path.dirname(self.path) or "."
        os.makedirs(folder, exist_ok=True)
        for attempt in range(5):
            db = sqlite3.connect(self.path, timeout=30, isolation_level=None)  # explicit transactions below
            try:
                db.execute("PRAGMA busy_timeout=30000")
                db.execute("PRAGMA journal_mode=WAL")  # switching a new file to WAL can meet another opener
                return _Transaction(db)
            except sqlite3.OperationalError as e:
                db.close()
                if "locked" not in str(e) or attempt == 4:
                    raise
                time.sleep(0.1 * (attempt + 1))

    def _check(self, path: str, sqlite: bool) -> None:
        if os.path.isdir(path):
            raise NotebookError(f"notebook {path} is a folder; give the path of a file")
        if sqlite and os.path.isfile(path) and os.path.getsize(path) > 0:
            with open(path, "rb") as f:
                head = f.read(len(SQLITE_MAGIC))
            if head != SQLITE_MAGIC:
                raise NotebookError(f"notebook {path} is not a lab notebook (not a SQLite database); it was "
                                    "left as it is: move it away or give another path")

    def _read_json(self, path: str) -> list[dict]:
        """The entries of a JSON notebook of earlier versions (NotebookError if it is not one)."""
        self._check(path, sqlite=False)
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
            data = json.loads(text) if text.strip() else []  # an empty file: an empty notebook
            entries = data.get("runs") if isinstance(data, dict) else data
            if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
                raise ValueError("no list of run entries in it")
        except (OSError, ValueError) as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
            raise NotebookError(f"notebook {path} is not a lab notebook ({e}); it was left as it is: "
                                "move it away or give another path") from e
        return entries

    def _rows(self) -> list[dict]:
        with self._connect() as db:
            return [json.loads(text) for (text,) in db.execute("SELECT entry FROM runs ORDER BY seq")]

    def entries(self) -> list[dict]:
        """The runs, oldest first; entries that are not runs are left out (see skipped())."""
        runs, skipped = [], []
        for e in self._rows():
            if _is_run(e):
                runs.append(e)
            elif "run_id" in e:
                skipped.append(repr(e.get("run_id")))
        if skipped != self._skipped:
            log.warning("notebook %s: entries skipped, not runs (run_id, robot and method must be text): %s",
                        self.path, ", ".join(skipped))
        self._skipped = skipped
        return runs

    def skipped(self) -> list[str]:
        """The run ids of the entries the last entries() left out."""
        return list(self._skipped)

    def get(self, run_id: str) -> dict | None:
        return next((e for e in self.entries() if e["run_id"] == run_id), None)

    def add(self, entry: dict) -> None:
        """Add a run (or replace the run of the same run_id), in one transaction."""
        if not _is_run(entry):
            raise ValueError(f"a notebook entry needs a text run_id, robot and method, got {entry!r:.200}")
        with self._lock, self._connect() as db:
            db.execute("INSERT INTO runs (run_id, entry) VALUES (?, ?) "
                       "ON CONFLICT (run_id) DO UPDATE SET entry = excluded.entry", (entry["run_id"], json.dumps(entry)))


class _Transaction:
    """A connection as a context manager: BEGIN IMMEDIATE ... COMMIT (ROLLBACK on error), then closed."""

    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self) -> sqlite3.Connection:
        self.db.execute("BEGIN IMMEDIATE")
        return self.db

    def __exit__(self, kind, *_exc) -> None:
        try:
            self.db.execute("ROLLBACK" if kind else "COMMIT")
        finally:
            self.db.close()


def _run_id(entry: dict):
    run_id = entry.get("run_id")
    return run_id if isinstance(run_id, str) else None


def _is_run(entry) -> bool:
    return isinstance(entry, dict) and all(isinstance(entry.get(k), str) for k in ("run_id", "robot", "method"))


def entry_from_summary(summary, started: float, recording: str | None) -> dict:
    """A notebook entry from a lab.RunSummary."""
    cfg = summary.config
    finite = lambda x: float(x) if x is not None and math.isfinite(x) else None  # noqa: E731
    numbers = summary.numbers()
    return {
        "run_id": summary.run_id,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(started)),
        "robot": cfg.robot, "method": cfg.method, "seed": cfg.seed, "settings": cfg.to_dict(),
        **numbers, "seconds": round(float(numbers["seconds"]), 3),
        "train_mse": finite(numbers["train_mse"]), "test_mse": finite(numbers["test_mse"]),
        "recording": str(recording) if recording else None,
        "controller": summary.controller.to_dict() if summary.controller is not None else None,
    }


def label(entry: dict) -> str:
    """One line for the runs list."""
    mse = entry.get("test_mse")
    mse_s = f"{mse:.3g}" if isinstance(mse, (int, float)) else "-"
    started = entry.get("started")
    when = started[5:16].replace("T", " ") if isinstance(started, str) else "?"
    return (f"{when} {entry['robot']} {entry['method']} s{entry.get('seed', '?')} {entry.get('generations', '?')}g "
            f"held-out {mse_s} [{entry['run_id'][:6]}]")
