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

What is opened (SQLite's own means of telling files apart): a notebook carries PRAGMA
application_id = APPLICATION_ID and PRAGMA user_version = SCHEMA_VERSION in its header, set when it is
created. A notebook of earlier versions (tables runs(seq, run_id, entry) and meta(key, value), no
marker) is recognised by its schema and gets the marker. A missing or 0-byte file, or a SQLite
database with no tables, becomes a new notebook: there is nothing in it to lose, and it is what a
second app sees while the first one creates the notebook. Anything else (another program's SQLite
database, another `runs` table, a newer notebook, a database that fails PRAGMA quick_check, a file
that is not SQLite, a folder) is refused with NotebookError naming the path and what it holds, and
left byte for byte as it was: it is read through SQLite's immutable=1 URI, which writes nothing
(no -wal or -shm file) beside it.

A notebook that cannot be written (the file or its folder is read-only, by os.access, or SQLite
says so) is opened read-only: its runs are listed, the runs added since it was opened are listed
too but not written, and that is said once (a warning; `read_only` names why). An entry that is not a run (not
JSON, not a JSON object, no text run_id, robot or method) is kept as it is but not listed;
`skipped()` names them (by run_id, else by its row: "seq N") and one log line says why.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sqlite3
import threading
import time
from pathlib import Path

log = logging.getLogger(__name__)

DEFAULT_PATH = os.path.join("recordings", "notebook.db")
SQLITE_MAGIC = b"SQLite format 3\x00"
APPLICATION_ID = 0x4E494B4C  # "NIKL": PRAGMA application_id of a lab notebook (offset 68 of the header)
SCHEMA_VERSION = 1  # PRAGMA user_version (offset 60): the notebook's schema, newer ones are refused
_SCHEMA = ("CREATE TABLE IF NOT EXISTS runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)",
           "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
_COLUMNS = {"runs": ["seq", "run_id", "entry"], "meta": ["key", "value"]}  # the tables of every version so far
_LEAVE = "it was left as it is: move it away or give another path"


class NotebookError(ValueError):
    """The notebook's path holds something that is not a lab notebook (it is left untouched)."""


class Notebook:
    """The runs of a SQLite notebook; every call opens its own connection (threads and processes
    may share the file). path: the database, or a JSON notebook whose database sits beside it.
    read_only: None, or why the notebook is not written (its runs are listed all the same)."""

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
        self._listed: list[dict] = []  # what entries() read last
        self._unreadable: str | None = None  # why the last entries() could not read the file
        self._unsaved: dict[str, dict] = {}  # a read-only notebook: the runs added since it was opened, listed only
        self.read_only: str | None = None
        self._check(self.path, sqlite=True)
        self._inspect()  # refuses what is not a lab notebook, writing nothing
        entries = self._read_json(legacy) if legacy is not None and os.path.lexists(legacy) else None
        self.read_only = self._not_writable()
        if self.read_only is None:
            try:
                self._open(entries, legacy)
            except sqlite3.OperationalError as e:
                if "readonly" not in str(e) and "read-only" not in str(e):
                    raise NotebookError(f"notebook {self.path} cannot be opened ({e}); {_LEAVE}") from e
                self.read_only = f"SQLite: {e}"
            except sqlite3.DatabaseError as e:
                raise NotebookError(f"notebook {self.path} is not a lab notebook ({e}); {_LEAVE}") from e
        if self.read_only is not None:
            if entries is not None and self._select("SELECT value FROM meta WHERE key = 'imported'") == []:
                self._unsaved = {e["run_id"]: e for e in entries if _is_run(e)}  # listed, not imported
            log.warning("notebook %s is read-only (%s): its runs are listed, new runs are not written into it "
                        "(they are listed until the app stops)", self.path, self.read_only)

    # ------------------------------------------------------------------ opening
    def _inspect(self) -> None:
        """Raise NotebookError unless self.path is missing or empty, or a lab notebook (of any version
        so far), reading it through SQLite's immutable=1 (nothing is written, no -wal/-shm is made)."""
        try:
            with open(self.path, "rb") as f:
                head = f.read(100)
        except FileNotFoundError:
            return
        except OSError as e:
            raise NotebookError(f"notebook {self.path} cannot be read ({e.strerror or e}); {_LEAVE}") from e
        if not head:
            return  # 0 bytes: SQLite's new database, nothing to lose (see the module's docstring)
        if len(head) < 100:
            raise NotebookError(f"notebook {self.path} is not a lab notebook (a SQLite header cut short); {_LEAVE}")
        app_id, version = int.from_bytes(head[68:72], "big"), int.from_bytes(head[60:64], "big")
        if app_id not in (0, APPLICATION_ID):
            raise NotebookError(f"notebook {self.path} is not a lab notebook (a SQLite database of another "
                                f"program: application_id {app_id:#010x}); {_LEAVE}")
        if app_id == APPLICATION_ID and version > SCHEMA_VERSION:
            raise NotebookError(f"notebook {self.path} is a lab notebook of a newer version (schema {version}; this "
                                f"version reads {SCHEMA_VERSION}); {_LEAVE}, or update the lab")
        try:
            with self._reader() as db:
                objects = db.execute("SELECT type, name FROM sqlite_master WHERE name NOT LIKE 'sqlite_%'").fetchall()
                columns = {name: [c[1] for c in db.execute(f"PRAGMA table_info({_quote(name)})")]
                           for kind, name in objects if kind == "table"}
                check = [r[0] for r in db.execute("PRAGMA quick_check(5)")] if objects else ["ok"]
        except sqlite3.DatabaseError as e:  # "database disk image is malformed", "file is not a database"
            what = "is damaged" if app_id == APPLICATION_ID else "is damaged or not a lab notebook"
            raise NotebookError(f"notebook {self.path} {what} (SQLite: {e}); {_LEAVE}") from e
        if check != ["ok"]:
            raise NotebookError(f"notebook {self.path} is damaged (PRAGMA quick_check: {'; '.join(check)}); {_LEAVE}")
        if not objects and (app_id, version) in ((0, 0), (APPLICATION_ID, SCHEMA_VERSION)):
            return  # an empty database: a notebook being created
        other = sorted(f"{kind} {name}" for kind, name in objects if kind != "table" or name not in _COLUMNS)
        if other:
            raise NotebookError(f"notebook {self.path} is not a lab notebook (a SQLite database with "
                                f"{', '.join(other)}); {_LEAVE}")
        for name, cols in columns.items():
            if cols != _COLUMNS[name]:
                raise NotebookError(f"notebook {self.path} is not a lab notebook (its table {name} has the "
                                    f"columns {', '.join(cols)}, a notebook's has {', '.join(_COLUMNS[name])}); {_LEAVE}")
        if "runs" not in columns or (app_id == 0 and version != 0):
            tables = ", ".join(f"table {t}" for t in sorted(columns)) or "no tables"
            raise NotebookError(f"notebook {self.path} is not a lab notebook (a SQLite database with {tables}, "
                                f"user_version {version}); {_LEAVE}")

    def _not_writable(self) -> str | None:
        """Why the notebook cannot be written (None if it can): a notebook in WAL mode writes its
        file and, beside it, its -wal and -shm files."""
        folder = os.path.dirname(os.path.abspath(self.path))
        existing = next((a for a in (folder, *Path(folder).parents) if os.path.exists(a)), folder)
        if os.path.exists(self.path) and not os.access(self.path, os.W_OK):
            return "the file is read-only"
        if not os.access(existing, os.W_OK | os.X_OK):
            return f"the folder {existing} is read-only"
        return None

    def _open(self, entries: list[dict] | None, legacy: str | None) -> None:
        """Create the tables and the marker (or add the marker to a notebook of earlier versions),
        and import a JSON notebook once, in one transaction."""
        with self._connect() as db:
            for statement in _SCHEMA:
                db.execute(statement)
            if db.execute("PRAGMA application_id").fetchone()[0] != APPLICATION_ID:
                db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            if db.execute("PRAGMA user_version").fetchone()[0] < SCHEMA_VERSION:
                db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            imported = db.execute("SELECT value FROM meta WHERE key = 'imported'").fetchone()
            if entries is not None and imported is None:
                for e in entries:
                    db.execute("INSERT OR IGNORE INTO runs (run_id, entry) VALUES (?, ?)",
                               (_run_id(e), json.dumps(e)))
                db.execute("INSERT INTO meta VALUES ('imported', ?)", (legacy,))

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

    def _reader(self) -> "_Closing":
        """A connection that writes nothing: immutable=1 (no lock, no -wal/-shm made) when no -wal
        file is beside the database (its content is all in it), else mode=ro (a writer may be at work)."""
        mode = "mode=ro" if os.path.exists(self.path + "-wal") else "immutable=1"
        return _Closing(sqlite3.connect(f"{Path(os.path.abspath(self.path)).as_uri()}?{mode}", uri=True, timeout=30))

    def _check(self, path: str, sqlite: bool) -> None:
        if os.path.isdir(path):
            raise NotebookError(f"notebook {path} is a folder; give the path of a file")
        if sqlite and os.path.isfile(path) and os.path.getsize(path) > 0:
            with open(path, "rb") as f:
                head = f.read(len(SQLITE_MAGIC))
            if head != SQLITE_MAGIC:
                raise NotebookError(f"notebook {path} is not a lab notebook (not a SQLite database); {_LEAVE}")

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
            raise NotebookError(f"notebook {path} is not a lab notebook ({e}); {_LEAVE}") from e
        return entries

    # ------------------------------------------------------------------ reading and writing
    def _select(self, query: str) -> list[tuple]:
        if self.read_only is None:
            with self._connect() as db:
                return db.execute(query).fetchall()
        if not os.path.exists(self.path) or os.path.getsize(self.path) == 0:
            return []
        try:
            with self._reader() as db:
                return db.execute(query).fetchall()
        except sqlite3.OperationalError as e:  # a read-only notebook that was never made: no tables
            if "no such table" in str(e):
                return []
            raise

    def _rows(self) -> list[tuple]:
        return self._select("SELECT seq, run_id, entry FROM runs ORDER BY seq")

    def entries(self) -> list[dict]:
        """The runs, oldest first; entries that are not runs are left out (see skipped()). When the
        file cannot be read (locked past the timeout, gone, damaged since), the last list, said once."""
        try:
            rows = self._rows()
        except sqlite3.Error as e:
            if str(e) != self._unreadable:
                log.warning("notebook %s cannot be read (%s): the runs read last are listed", self.path, e)
            self._unreadable = str(e)
            return list(self._listed)
        self._unreadable = None
        runs, skipped, why = [], [], []
        for seq, run_id, text in rows:
            try:
                e = json.loads(text)
            except (TypeError, ValueError) as err:  # not text, not JSON (UnicodeDecodeError is a ValueError)
                e, reason = None, f"not JSON: {err}"
            else:
                reason = "not a JSON object" if not isinstance(e, dict) else "run_id, robot and method must be text"
            if _is_run(e):
                if e["run_id"] not in self._unsaved:
                    runs.append(e)
                continue
            name = repr(e["run_id"]) if isinstance(e, dict) and "run_id" in e else \
                repr(run_id) if isinstance(run_id, str) else f"seq {seq}"
            skipped.append(name)
            why.append(f"{name} ({reason})")
        runs += self._unsaved.values()
        if skipped != self._skipped:
            log.warning("notebook %s: entries skipped, not runs: %s", self.path, ", ".join(why))
        self._skipped, self._listed = skipped, runs
        return list(runs)

    def skipped(self) -> list[str]:
        """The names of the entries the last entries() left out: repr(run_id), or "seq N"."""
        return list(self._skipped)

    def get(self, run_id: str) -> dict | None:
        return next((e for e in self.entries() if e["run_id"] == run_id), None)

    def add(self, entry: dict) -> None:
        """Add a run (or replace the run of the same run_id), in one transaction. A read-only
        notebook keeps it in memory (listed until the app stops; said once, when opened)."""
        if not _is_run(entry):
            raise ValueError(f"a notebook entry needs a text run_id, robot and method, got {entry!r:.200}")
        if self.read_only is not None:
            with self._lock:
                self._unsaved.pop(entry["run_id"], None)
                self._unsaved[entry["run_id"]] = entry
            return
        with self._lock, self._connect() as db:
            db.execute("INSERT INTO runs (run_id, entry) VALUES (?, ?) "
                       "ON CONFLICT (run_id) DO UPDATE SET entry = excluded.entry", (entry["run_id"], json.dumps(entry)))


class _Closing:
    """A read connection as a context manager: closed on leaving (sqlite3's own only commits)."""

    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self) -> sqlite3.Connection:
        return self.db

    def __exit__(self, *_exc) -> None:
        self.db.close()


def _quote(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


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
