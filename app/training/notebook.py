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
marker) is recognised by its schema (each table's CREATE statement as SQLite keeps it: its types,
key and UNIQUE, not only its column names) and gets the marker. A missing or 0-byte file, or a SQLite
database with no tables, becomes a new notebook: there is nothing in it to lose, and it is what a
second app sees while the first one creates the notebook. Anything else (another program's SQLite
database, another `runs` table, even one of the notebook's column names, a newer notebook, a
database that fails PRAGMA quick_check, a file that is not SQLite, a folder) is refused with
NotebookError naming the path and what it holds, and left byte for byte as it was: it is read through SQLite's immutable=1 URI, which writes nothing
(no -wal or -shm file) beside it.

A notebook that cannot be written (the file or its folder is read-only, by os.access, or SQLite
says so) is opened read-only: its runs are listed, the runs added since it was opened are listed
too but not written, and that is said once (a warning; `read_only` names why). An entry that is not a run (not
JSON, not a JSON object, no text run_id, robot or method) is kept as it is but not listed;
`skipped()` names them (by run_id, else by its row: "seq N") and one log line says why; so is a
row whose JSON raises anything else (nested too deeply: a RecursionError).

A write that fails while the app runs (another program holds the file locked past the busy
timeout, `timeout`; a full disk; an I/O error) loses nothing: the entry is kept in memory and
listed, `not_saved()` says how many wait and why (the Runs panel shows it), a thread writes
them once it can, trying again after 0.5 s, 1 s, 2 s, ... 30 s, and meanwhile the entry is in the
journal beside the notebook (`<notebook>.journal`, app/training/journal.py), so that a process
killed (or stopped) before they are written loses nothing. At the app's stop `close()` tries once
more for CLOSE_WAIT s and leaves what is still not written in the journal; the log names the journal
and the runs in it (or, should the journal not be writable either, a full disk, the runs lost). The
next opening of the notebook imports the journal's entries, and removes them from the journal only
once they are committed. Reads take no lock: in WAL mode they go on while another program writes.

A notebook path (or its journal) that is not a regular file (a folder, a named pipe, a device, a
socket) is refused at once, naming what it is, before anything opens it: a pipe with no writer would
block an open forever, a device give bytes without end.
"""

from __future__ import annotations

import atexit
import json
import logging
import math
import os
import sqlite3
import stat
import threading
import time
import weakref
from pathlib import Path

from app.classroom.files import kind_of
from app.training.journal import Journal

log = logging.getLogger(__name__)

DEFAULT_PATH = os.path.join("recordings", "notebook.db")
SQLITE_MAGIC = b"SQLite format 3\x00"
APPLICATION_ID = 0x4E494B4C  # "NIKL": PRAGMA application_id of a lab notebook (offset 68 of the header)
SCHEMA_VERSION = 1  # PRAGMA user_version (offset 60): the notebook's schema, newer ones are refused
_SCHEMA = ("CREATE TABLE IF NOT EXISTS runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)",
           "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
_COLUMNS = {"runs": ["seq", "run_id", "entry"], "meta": ["key", "value"]}  # the tables of every version so far
# each table as SQLite keeps it (sqlite_master.sql: the CREATE statement without IF NOT EXISTS), the
# same in every version so far: a table of these names with other types, key or constraints is not ours
_TABLES = {statement.split()[5]: statement.replace(" IF NOT EXISTS", "") for statement in _SCHEMA}
_LEAVE = "it was left as it is: move it away or give another path"
BUSY_TIMEOUT = 30.0  # s a write waits for another program's lock on the file (SQLite's busy timeout)
READ_TIMEOUT = 5.0  # s a read waits at most (a WAL notebook's readers wait only for a checkpoint or recovery)
RETRY_FIRST, RETRY_MAX = 0.5, 30.0  # s between tries of a failed write: doubled after each failure, up to the max
CLOSE_WAIT = 1.0  # s close() (the app's stop) waits for a lock before the entries not written go to the journal


class NotebookError(ValueError):
    """The notebook's path holds something that is not a lab notebook (it is left untouched)."""


class Notebook:
    """The runs of a SQLite notebook; every call opens its own connection (threads and processes
    may share the file). path: the database, or a JSON notebook whose database sits beside it.
    read_only: None, or why the notebook is not written (its runs are listed all the same)."""

    def __init__(self, path: str = DEFAULT_PATH, timeout: float = BUSY_TIMEOUT):
        """timeout: s a write waits for another program's lock on the file (SQLite's busy timeout)."""
        self.given = os.fspath(path)
        self.timeout = float(timeout)
        legacy = None
        if self.given.endswith(".json"):
            legacy, self.path = self.given, self.given[: -len(".json")] + ".db"
        else:
            self.path = self.given
            beside = os.path.join(os.path.dirname(self.path), "notebook.json")
            legacy = beside if os.path.basename(self.path) == "notebook.db" else None
        self._lock = threading.Lock()  # guards _unsaved, _texts, _failure, _retrier
        self._writing = threading.Lock()  # one write at a time from this notebook (add and its retries)
        self._texts: dict[str, str] = {}  # run_id -> the JSON of an unsaved entry (a writable notebook's)
        self._failure: str | None = None  # why the last write failed (None once it succeeds)
        self._retrier: threading.Thread | None = None  # writes the unsaved entries, with a backoff
        self.retry_max = RETRY_MAX  # s between the retrier's tries at most
        self._skipped: list[str] = []
        self._listed: list[dict] = []  # what entries() read last
        self._unreadable: str | None = None  # why the last entries() could not read the file
        # the runs listed but not in the file: a read-only notebook's (added since it was opened), or a
        # writable one's whose write failed (locked past the timeout, a full disk), retried until written
        self._unsaved: dict[str, dict] = {}
        self.journal = Journal(self.path + ".journal")  # the entries not written yet, beside the notebook
        self._journal_lock = threading.Lock()  # one change of the journal at a time from this notebook
        self._journaled: dict[str, str] = {}  # run_id -> the JSON this notebook put in the journal
        self._said_lost: set[str] = set()  # run ids the log has said the journal could not take
        self.closed = False
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
        if self.read_only is None:
            self.journal.keep_reserve()  # room for the journal, kept while the disk has it
            self._import_journal()
        else:
            self._list_journal()
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
                tables = dict(db.execute("SELECT name, sql FROM sqlite_master WHERE type = 'table'").fetchall())
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
            if " ".join(tables[name].split()) != _TABLES[name]:  # the names alone: another program's table
                raise NotebookError(f"notebook {self.path} is not a lab notebook (its table {name} is "
                                    f"`{' '.join(tables[name].split())}`, a notebook's is `{_TABLES[name]}`: "
                                    f"its types, key or constraints differ); {_LEAVE}")
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

    def _connect(self, timeout: float | None = None) -> sqlite3.Connection:
        """A write transaction; a lock held by another program is waited for `timeout` s (default: the
        notebook's), then "database is locked"."""
        timeout = self.timeout if timeout is None else timeout
        folder = os.path.dirname(self.path) or "."
        os.makedirs(folder, exist_ok=True)
        for attempt in range(5):
            db = sqlite3.connect(self.path, timeout=timeout, isolation_level=None)  # explicit transactions below
            try:
                db.execute(f"PRAGMA busy_timeout={int(timeout * 1000)}")
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
        return _Closing(sqlite3.connect(f"{Path(os.path.abspath(self.path)).as_uri()}?{mode}", uri=True,
                                        timeout=self.timeout))

    def _check(self, path: str, sqlite: bool) -> None:
        """Refuse a path that is not a regular file (a folder, a pipe, a device) or, for the database,
        a file that is not SQLite; a missing file passes (a new notebook)."""
        try:
            mode = os.stat(path).st_mode
        except FileNotFoundError:
            return
        except OSError as e:
            raise NotebookError(f"notebook {path} cannot be read ({e.strerror or e}); {_LEAVE}") from e
        if stat.S_ISDIR(mode):
            raise NotebookError(f"notebook {path} is a folder; give the path of a file")
        if (what := kind_of(mode)) is not None:  # opening a pipe with no writer would block for good
            raise NotebookError(f"notebook {path} is {what}, not a file; {_LEAVE}")
        if sqlite and os.path.getsize(path) > 0:
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
        if self.read_only is None:  # a read takes no write lock: it goes on while another program writes (WAL)
            uri = f"{Path(os.path.abspath(self.path)).as_uri()}?mode=rw"  # a file gone is not made again here
            with _Closing(sqlite3.connect(uri, uri=True, timeout=min(self.timeout, READ_TIMEOUT))) as db:
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
        file cannot be read (locked past the timeout, gone, damaged since), the runs read last, said
        once. The runs not in the file (a read-only notebook's, or those whose write is retried) are
        listed after the file's."""
        with self._lock:
            unsaved = dict(self._unsaved)  # before the file is read: the retrier may write (and drop) some meanwhile
        try:
            rows = self._rows()
        except sqlite3.Error as e:
            if str(e) != self._unreadable:
                log.warning("notebook %s cannot be read (%s): the runs read last are listed", self.path, e)
            self._unreadable = str(e)
            return [e for e in self._listed if e["run_id"] not in unsaved] + list(unsaved.values())
        self._unreadable = None
        runs, skipped, why = [], [], []
        for seq, run_id, text in rows:
            e, reason = _parse(text)
            if _is_run(e) and not isinstance(e.get("recording"), (str, type(None))):
                e, reason = None, "its recording must be a path (text) or null"
            if _is_run(e):
                runs.append(e)
                continue
            inner = e.get("run_id") if isinstance(e, dict) else None
            name = repr(inner) if isinstance(inner, (str, int, float)) and len(repr(inner)) <= 80 else \
                repr(run_id) if isinstance(run_id, str) and len(run_id) <= 80 else f"seq {seq}"
            skipped.append(name)
            why.append(f"{name} ({reason})")
        if skipped != self._skipped:
            log.warning("notebook %s: entries skipped, not runs: %s", self.path, ", ".join(why))
        self._skipped, self._listed = skipped, runs
        return [e for e in runs if e["run_id"] not in unsaved] + list(unsaved.values())

    def skipped(self) -> list[str]:
        """The names of the entries the last entries() left out: repr(run_id), or "seq N"."""
        return list(self._skipped)

    def get(self, run_id: str) -> dict | None:
        return next((e for e in self.entries() if e["run_id"] == run_id), None)

    def add(self, entry: dict, timeout: float | None = None) -> None:
        """Add a run (or replace the run of the same run_id), in one transaction. It is listed at once.
        A read-only notebook keeps it in memory (listed until the app stops; said once, when opened).
        A write that fails (the file locked by another program past `timeout` s, default the
        notebook's; a full disk; an I/O error) loses nothing: the entry is kept in memory, listed,
        put in the journal, and written by a thread that tries again (after 0.5 s, 1 s, 2 s, ...
        RETRY_MAX s) while the process runs; not_saved() says how many wait and why, and the log says
        it once. While an earlier write is failing, a new entry does not wait for the lock: it goes
        to the retrier and the journal at once."""
        if not _is_run(entry):
            raise ValueError(f"a notebook entry needs a text run_id, robot and method, got {entry!r:.200}")
        text = json.dumps(entry)  # an entry that is not JSON is refused here, not retried
        with self._lock:
            self._unsaved.pop(entry["run_id"], None)
            self._unsaved[entry["run_id"]] = entry
            if self.read_only is None:
                self._texts[entry["run_id"]] = text
            failing = self._failure is not None
        if self.read_only is None:
            if not self._save(0.0 if failing else self.timeout if timeout is None else timeout):
                with self._lock:  # another write under way held it past the wait: the retrier writes it
                    if entry["run_id"] in self._unsaved:
                        self._start_retrier()
                kept, lost, error = self._journal_unsaved()  # and the journal has it meanwhile
                if entry["run_id"] in lost and entry["run_id"] not in self._said_lost:  # (the first failure's
                    self._said_lost.add(entry["run_id"])  # line, or an earlier one, may have named it)
                    log.error("notebook %s: run %s not saved yet (%s): listed and tried again while the app runs; "
                              "the journal %s could not take it (%s): lost if the app stops before it is written",
                              self.path, entry["run_id"], self._failure, self.journal.path, error)

    def not_saved(self) -> tuple[int, str | None]:
        """How many runs of a writable notebook are listed but not written yet, and why (the last
        write's error, e.g. "database is locked"): (0, None) when every run is in the file. (A
        read-only notebook's runs are never written: read_only says why.)"""
        with self._lock:
            if self.read_only is not None or not self._unsaved or self._failure is None:
                return 0, None  # (an entry being written, no write failed yet: not said)
            return len(self._unsaved), self._failure

    def flush(self, timeout: float | None = None) -> int:
        """Write the runs not saved yet, now (waiting `timeout` s at most for a lock); returns how
        many are still not saved."""
        if self.read_only is None and self._unsaved:
            self._save(self.timeout if timeout is None else timeout)
        return self.not_saved()[0]

    def _save(self, timeout: float) -> bool:
        """Write every unsaved entry in one transaction; False (the entries kept, the retrier
        started) when that fails. Waits `timeout` s at most for the retrier's write under way: the
        retrier writes what this one would have."""
        if not self._writing.acquire(timeout=max(timeout, 0.0)):
            return False
        try:
            with self._lock:
                batch = [(run_id, e, self._texts[run_id]) for run_id, e in self._unsaved.items()]
            if not batch:
                return True
            try:
                with self._connect(timeout) as db:
                    for run_id, _e, text in batch:
                        db.execute("INSERT INTO runs (run_id, entry) VALUES (?, ?) "
                                   "ON CONFLICT (run_id) DO UPDATE SET entry = excluded.entry", (run_id, text))
            except (sqlite3.Error, OSError) as err:  # locked, full, I/O error, the folder gone
                why = str(err) or type(err).__name__
                with self._lock:
                    said, self._failure = self._failure, why
                    self._start_retrier()
                kept, lost, error = self._journal_unsaved()
                if said is None:
                    self._said_lost.update(lost)
                    n = len(kept) + len(lost)
                    where = self._where(kept, lost, error, "lost if the app stops before they are written")
                    (log.error if lost else log.warning)(
                        "notebook %s: %d run%s not saved yet (%s): listed and tried again while the app runs; %s",
                        self.path, n, "" if n == 1 else "s", why, where)
                return False
            self._unjournal({run_id: text for run_id, _e, text in batch})  # committed: out of the journal
            with self._lock:
                for run_id, e, _text in batch:
                    if self._unsaved.get(run_id) is e:  # not replaced by a later add meanwhile
                        del self._unsaved[run_id]
                        del self._texts[run_id]
                said = self._failure if not self._unsaved else None
                if said is not None:
                    self._failure = None
            if said is not None:
                log.warning("notebook %s: the runs not saved (%s) are saved now", self.path, said)
            return True
        finally:
            self._writing.release()

    def _start_retrier(self) -> None:
        """(self._lock held) The retrier, unless it runs."""
        if self._retrier is None:
            self._retrier = threading.Thread(target=self._retry, name="notebook-retry", daemon=True)
            self._retrier.start()
            _waiting.add(self)

    # ------------------------------------------------------------------ the journal
    def _journal_unsaved(self) -> tuple[list[str], list[str], str | None]:
        """Put every entry not written yet in the journal (those already there as they are: nothing
        to do): all in one rewrite, else (a full disk) one by one, so that what fits is kept. Returns
        (the run ids the journal holds, those it could not take, why)."""
        error = None
        with self._journal_lock:
            with self._lock:
                pending = {run_id: self._texts[run_id] for run_id in self._unsaved if run_id in self._texts}
            new = {run_id: text for run_id, text in pending.items() if self._journaled.get(run_id) != text}
            for batch in [] if not new else [new] if len(new) == 1 else [new, *({k: v} for k, v in new.items())]:
                try:
                    self.journal.change(add=batch)
                except OSError as e:  # a full disk (ENOSPC, EFBIG), a read-only folder, a pipe at its path
                    error = e.strerror or str(e) or type(e).__name__
                    continue
                self._journaled.update(batch)
                if batch is new:
                    break
            kept = [run_id for run_id, text in pending.items() if self._journaled.get(run_id) == text]
            return kept, [run_id for run_id in pending if run_id not in kept], error

    def _where(self, kept: list[str], lost: list[str], error: str | None, fate: str) -> str:
        """Where the runs not written are, in words: the journal (by run id), and those it could not take."""
        said = []
        if kept:
            said.append(f"in the journal {self.journal.path} ({', '.join(kept)}), which the next opening of the "
                        "notebook imports")
        if lost:
            said.append(f"{'the journal ' + self.journal.path if not kept else 'it'} could not take "
                        f"{', '.join(lost)} ({error}): {fate}")
        return "; ".join(said)

    def _unjournal(self, committed: dict[str, str]) -> None:
        """Drop from the journal the entries this notebook put there that are now committed."""
        with self._journal_lock:
            done = {run_id: text for run_id, text in committed.items() if self._journaled.get(run_id) == text}
            if not done:
                return
            try:
                self.journal.change(drop=done)
            except OSError as e:  # they stay in it: imported again, the same, at the next opening
                log.warning("notebook %s: runs written, but the journal %s could not be rewritten (%s): its copies "
                            "of them (%s) are imported again, unchanged, at the next opening", self.path,
                            self.journal.path, e.strerror or e, ", ".join(done))
            for run_id in done:
                del self._journaled[run_id]

    def _import_journal(self) -> None:
        """At opening: the journal's entries written into the notebook (one transaction), then removed
        from the journal; its lines that are not entries set aside (<journal>.unreadable). Entries that
        cannot be written now stay in the journal, listed and retried."""
        try:
            entries, bad = self.journal.read()
        except OSError as e:
            log.warning("notebook %s: its journal cannot be read (%s); it was left as it is", self.path, e.strerror or e)
            return
        left = entries
        if entries:
            ids = ", ".join(entries)
            try:
                with self._connect() as db:
                    for run_id, text in entries.items():
                        db.execute("INSERT INTO runs (run_id, entry) VALUES (?, ?) "
                                   "ON CONFLICT (run_id) DO UPDATE SET entry = excluded.entry", (run_id, text))
            except (sqlite3.Error, OSError) as err:
                why = str(err) or type(err).__name__
                with self._lock:
                    for run_id, text in entries.items():
                        self._unsaved[run_id], self._texts[run_id] = json.loads(text), text
                    self._journaled.update(entries)
                    self._failure = why
                    self._start_retrier()
                log.warning("notebook %s: the %d run%s of its journal %s could not be written into it (%s): listed, "
                            "tried again while the app runs, kept in the journal until written (%s)", self.path,
                            len(entries), "" if len(entries) == 1 else "s", self.journal.path, why, ids)
                return
            try:
                with self._journal_lock:
                    left = self.journal.change(drop=entries)
                gone = "the journal removed" if not left and not bad else "removed from the journal"
            except OSError as e:
                gone = f"left in it, as the journal could not be rewritten ({e.strerror or e}): imported again next time"
            log.warning("notebook %s: %d run%s imported from its journal %s (%s) and %s", self.path, len(entries),
                        "" if len(entries) == 1 else "s", self.journal.path, ids, gone)
        if bad and not left:
            try:
                aside = self.journal.set_aside()
            except OSError as e:
                aside = f"{self.journal.path} ({e.strerror or e})"
            log.warning("notebook %s: its journal had %d line%s that %s not a run (%s): kept in %s", self.path,
                        len(bad), "" if len(bad) == 1 else "s", "is" if len(bad) == 1 else "are",
                        "; ".join(line[:60] for line in bad[:5]), aside)

    def _list_journal(self) -> None:
        """A read-only notebook: the journal's entries listed (not written; imported when it is writable)."""
        try:
            entries, _bad = self.journal.read()
        except OSError:
            return
        if entries:
            self._unsaved.update({run_id: json.loads(text) for run_id, text in entries.items()})
            log.warning("notebook %s: its journal %s holds %d run%s not in it (%s): listed; imported once the "
                        "notebook can be written", self.path, self.journal.path, len(entries),
                        "" if len(entries) == 1 else "s", ", ".join(entries))

    def close(self, wait: float = CLOSE_WAIT) -> list[str]:
        """At the app's stop: write the entries not written yet, waiting `wait` s at most for a lock;
        those still not written stay in the journal, and the log names it and them (or, when the
        journal cannot be written either, says they are lost and names them). Returns the run ids
        not written into the notebook."""
        self.closed = True
        with self._lock:
            ids = list(self._unsaved)
        if not ids:
            return []
        if self.read_only is not None:
            log.warning("notebook %s is read-only (%s): the %d run%s added since it was opened are not written: %s",
                        self.path, self.read_only, len(ids), "" if len(ids) == 1 else "s", ", ".join(ids))
            return ids
        self._save(wait)
        with self._lock:
            why = self._failure or "another write of them still under way"
        kept, lost, error = self._journal_unsaved()
        if not kept and not lost:
            return []
        n = len(kept) + len(lost)
        (log.error if lost else log.warning)(
            "notebook %s: %d run%s could not be written before the app stopped (%s): %s", self.path, n,
            "" if n == 1 else "s", why, self._where(kept, lost, error, "lost"))
        return kept + lost

    def _retry(self) -> None:
        """The retrier: writes the unsaved entries, waiting longer after each failure, until none is
        left or the notebook is closed (add and flush write them too, at once)."""
        delay = RETRY_FIRST
        while True:
            time.sleep(delay)
            if not self.closed:  # after close() the journal holds them, or the log said they are lost
                self._save(self.timeout)
            with self._lock:
                if not self._unsaved or self.closed:
                    self._retrier = None
                    _waiting.discard(self)
                    return
            delay = min(delay * 2, self.retry_max)


_waiting: "weakref.WeakSet[Notebook]" = weakref.WeakSet()  # notebooks with runs not saved yet


@atexit.register
def _last_try() -> None:
    """At an interpreter's exit (a program using the notebook without closing it; `python -m app`
    closes its own): close() each notebook with runs not written yet."""
    for nb in list(_waiting):
        if not nb.closed:
            try:
                nb.close()
            except Exception:  # noqa: BLE001 - the exit goes on; the journal holds what it could
                log.exception("notebook %s: closing it failed", nb.path)


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


def _parse(text) -> tuple[object, str]:
    """A row's entry, read from its JSON, and why it is not a run should it not be one (any error
    in one row is that row's: it is skipped by name, the others are listed)."""
    try:
        e = json.loads(text)
    except (TypeError, ValueError) as err:  # not text, not JSON (UnicodeDecodeError is a ValueError)
        return None, f"not JSON: {err}"
    except RecursionError:  # nested deeper than Python's stack: "[" * 100_000
        return None, "not readable: its JSON is nested too deeply"
    except Exception as err:  # noqa: BLE001 - whatever one row raises (MemoryError is not an Exception)
        return None, f"not readable: {type(err).__name__}: {err}"
    return e, "not a JSON object" if not isinstance(e, dict) else "run_id, robot and method must be text"


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
        # the robot's identity is its string and its URDF's bytes (a replay says when the file changed or went)
        "urdf_sha256": _urdf_sha256(cfg.robot),
        **numbers, "seconds": round(float(numbers["seconds"]), 3),
        "train_mse": finite(numbers["train_mse"]), "test_mse": finite(numbers["test_mse"]),
        "recording": str(recording) if recording else None,
        "controller": summary.controller.to_dict() if summary.controller is not None else None,
    }


def _urdf_sha256(robot: str) -> str | None:
    import robots

    try:
        return robots.load(robot).urdf_sha256
    except Exception:  # noqa: BLE001 - the entry is kept whatever its robot
        return None


def label(entry: dict) -> str:
    """One line for the runs list."""
    mse = entry.get("test_mse")
    mse_s = f"{mse:.3g}" if isinstance(mse, (int, float)) else "-"
    started = entry.get("started")
    when = started[5:16].replace("T", " ") if isinstance(started, str) else "?"
    return (f"{when} {entry['robot']} {entry['method']} s{entry.get('seed', '?')} {entry.get('generations', '?')}g "
            f"held-out {mse_s} [{entry['run_id'][:6]}]")
