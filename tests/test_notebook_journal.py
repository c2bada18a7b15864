"""No notebook entry lost at exit (issue #55): an entry that cannot be written (another program holds
the notebook locked, a full disk) goes to the journal beside it, the log names the journal and the
runs in it, and the next opening of the notebook imports them; what the journal cannot take either is
named as lost, never said to be "retried until written" by a process about to exit."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.parse

from viser import _messages

from app.training.notebook import Notebook
from conftest import tab_of, wait_until

TOKEN = "journal-Token_0123456789"


def run(run_id: str, **more) -> dict:
    return {"run_id": run_id, "robot": "planar", "method": "cmaes", **more}


class App:
    """`python -m app ARGS` in a child process, its output read by a thread (lines kept)."""

    def __init__(self, *args: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "app", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    def line(self, text: str, timeout: float = 300.0) -> str | None:
        assert wait_until(lambda: any(text in s for s in self.lines) or self.proc.poll() is not None, timeout)
        return next((s for s in self.lines if text in s), None)

    def wait(self, timeout: float) -> int:
        """The app's exit code; killed past `timeout` s. Not proc.communicate(): that reads the pipe too,
        and under load took the app's last lines (the journal's) from the reader thread."""
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise

    def output(self) -> str:
        self.reader.join(30)
        return "".join(self.lines)


def my_number(probe, label: str) -> str:
    """The uuid of a number field of the tab's own My experiment folder (the shared panel has one of the
    same label)."""
    folder = probe.wait_for(lambda m: m["type"] == "GuiFolderMessage"
                            and m["props"]["label"].startswith("My experiment"), 60)["uuid"]
    return probe.wait_for(lambda m: m["type"] == "GuiNumberMessage" and m["props"]["label"] == label
                          and m["container_uuid"] == folder, 60)["uuid"]


def said(probe, text: str) -> bool:
    return any(text in str(m) for _t, m in list(probe.messages))


def test_the_app_stopped_while_another_program_locks_the_notebook_keeps_every_entry_in_its_journal(tmp_path):
    """The shared run going, one student's run going and another's queued, another program holding the
    notebook locked: SIGTERM. The log names the journal and the three runs in it (nothing says
    "retried until written"); the lock goes; the next opening of the notebook has the three entries,
    as stopped, and the journal is gone. (Before: the runs were said to be "kept in memory and retried
    until written", and the app's os._exit lost them: 0 of them in the notebook.)"""
    nb = tmp_path / "nb.db"
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    app = App("--port", "0", "--notebook", str(nb), "--no-record", "--presenter-token-file", str(token_file),
              "--class-workers", "1")
    tabs = []
    other = None
    try:
        ready = app.line("Neuro-IK Lab ready")
        assert ready is not None, app.output()[-3000:]
        url = ready.rsplit(" ", 1)[-1].strip()
        link = app.line("presenter link")
        presenter = tab_of(urllib.parse.unquote(link.split("websocket=")[1].strip()))
        tabs.append(presenter)
        presenter.click("Start")  # the shared run: 1,000 generations at 20 a second, going on at the stop
        students = [tab_of(url), tab_of(url)]
        tabs.extend(students)
        for k, tab in enumerate(students):  # one runs, one waits in the queue (one class worker)
            tab.send(_messages.GuiUpdateMessage(uuid=my_number(tab, "Generations"), updates={"value": 100_000.0}))
            tab.send(_messages.GuiUpdateMessage(uuid=my_number(tab, "Population"), updates={"value": 10.0}))
            time.sleep(1.0)  # the values are in before the click
            tab.click("Start my run")
            assert wait_until(lambda: said(tab, "**Queued" if k else "**Running"), 300), app.output()[-3000:]
        assert wait_until(lambda: said(students[0], "**Running, generation"), 300), app.output()[-3000:]
        other = sqlite3.connect(nb, isolation_level=None)
        other.execute("BEGIN EXCLUSIVE")  # another program holds the notebook past every wait of the stop
    finally:  # the tabs stay open: a closed tab would stop its own run (and drop a queued one) first
        app.proc.send_signal(signal.SIGTERM)
        try:
            app.wait(120)
        finally:
            for tab in tabs:
                tab.close()
    out = app.output()
    try:
        assert app.proc.returncode == 0, out[-3000:]
        assert "Traceback" not in out and "retried until written" not in out, out[-3000:]
        assert [r[0] for r in other.execute("SELECT run_id FROM runs")] == []  # none written: the lock held
        journal = f"{nb}.journal"
        lines = [s for s in out.splitlines() if "before the app stopped" in s]
        assert len(lines) == 1, out[-6000:]
        [line] = lines
        assert f"in the journal {journal} (" in line and "which the next opening of the notebook imports" in line
        ids = re.search(r"in the journal \S+ \(([^)]*)\)", line).group(1).split(", ")
        assert len(ids) == 3 and "3 runs could not be written before the app stopped (database is locked)" in line
        kept = [json.loads(s)["run_id"] for s in open(journal, encoding="utf-8")]
        assert sorted(kept) == sorted(ids)
    finally:
        other.execute("ROLLBACK")  # the lock goes
        other.close()
    entries = {e["run_id"]: e for e in Notebook(str(nb)).entries()}  # the next start opens it
    assert sorted(entries) == sorted(ids) and not os.path.exists(journal)
    assert all(e["state"] == "stopped" for e in entries.values())
    errors = [e.get("error") or "" for e in entries.values() if "student" in e]
    queued = "the server stopped before it started"
    assert len(errors) == 2 and errors.count(queued) == 1, errors  # the queued one
    [running] = [e for e in errors if e != queued]
    assert running, errors  # the running one: "the server stopped" (or its worker killed)
    assert sum("student" not in e and e["generations"] > 0 for e in entries.values()) == 1  # the shared run
    assert [e["run_id"] for e in Notebook(str(nb)).entries()] == list(entries)  # imported once, and no more


def test_a_locked_notebook_at_close_keeps_its_entries_in_the_journal_until_the_next_opening(tmp_path, caplog):
    """In process: entries added while another program holds the lock go to the journal at once (a
    process killed meanwhile loses nothing), close() names the journal and them, the next opening
    imports them and removes the journal; a journal line that is not a run is set aside, not lost."""
    path = tmp_path / "nb.db"
    nb = Notebook(str(path), timeout=0.2)
    nb.add(run("before1"))
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        with caplog.at_level("WARNING"):
            nb.add(run("late1"), timeout=0.2)
            nb.add(run("late2", generations=7), timeout=0.2)
            journal = tmp_path / "nb.db.journal"
            assert [json.loads(s)["run_id"] for s in journal.read_text().splitlines()] == ["late1", "late2"]
            assert nb.close(wait=0.2) == ["late1", "late2"]
    finally:
        other.execute("ROLLBACK")
        other.close()
    lines = [r.getMessage() for r in caplog.records if r.name == "app.training.notebook"]
    assert lines == [
        f"notebook {path}: 1 run not saved yet (database is locked): listed and tried again while the app runs; "
        f"in the journal {journal} (late1), which the next opening of the notebook imports",
        f"notebook {path}: 2 runs could not be written before the app stopped (database is locked): in the journal "
        f"{journal} (late1, late2), which the next opening of the notebook imports"]
    with open(journal, "a", encoding="utf-8") as f:
        f.write("not a run\n")
    caplog.clear()
    with caplog.at_level("WARNING"):
        again = Notebook(str(path))
    assert [e["run_id"] for e in again.entries()] == ["before1", "late1", "late2"]
    assert again.get("late2")["generations"] == 7
    assert not journal.exists() and (tmp_path / "nb.db.journal.unreadable").read_text() == "not a run\n"
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"notebook {path}: 2 runs imported from its journal {journal} (late1, late2) and removed from "
                    "the journal", f"notebook {path}: its journal had 1 line that is not a run (not a run): kept in "
                    f"{journal}.unreadable"]


def test_a_full_disk_at_exit_keeps_what_the_journal_can_take_and_names_what_is_lost(tmp_path):
    """The disk is full (RLIMIT_FSIZE 64 KiB in a child process: the notebook's WAL cannot grow): an
    entry of 60 kB does not fit the WAL but fits the journal, one of 300 kB fits neither. The process
    closes the notebook and ends with os._exit, as `python -m app` does: the log says the first is in
    the journal and the second is lost, each by name; the next opening imports the first, whole."""
    code = """if True:
        import logging, os, resource, signal, sys
        logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
        from app.training.notebook import Notebook
        nb = Notebook(sys.argv[1], timeout=1.0)
        nb.add({"run_id": "small1", "robot": "planar", "method": "cmaes"})
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) as on a full disk
        soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (65536, hard))
        nb.add({"run_id": "fits1", "robot": "planar", "method": "cmaes", "controller": {"w": "x" * 60_000}})
        nb.add({"run_id": "huge1", "robot": "planar", "method": "cmaes", "controller": {"w": "y" * 300_000}})
        print(nb.close(), flush=True)
        os._exit(0)
    """
    path = tmp_path / "nb.db"
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "['fits1', 'huge1']", done.stderr
    journal = f"{path}.journal"
    assert "Traceback" not in done.stderr and "until written" not in done.stderr
    [line] = [s for s in done.stderr.splitlines() if "before the app stopped" in s]
    assert line == (f"ERROR app.training.notebook: notebook {path}: 2 runs could not be written before the app "
                    f"stopped (disk I/O error): in the journal {journal} (fits1), which the next opening of the "
                    "notebook imports; it could not take huge1 (File too large): lost")
    assert (f"notebook {path}: run huge1 not saved yet (disk I/O error): listed and tried again while the app runs; "
            f"the journal {journal} could not take it (File too large): lost if the app stops before it is written"
            in done.stderr)  # said as it happens, too: a process killed before its stop
    entries = {e["run_id"]: e for e in Notebook(str(path)).entries()}
    assert sorted(entries) == ["fits1", "small1"] and len(entries["fits1"]["controller"]["w"]) == 60_000
    assert not os.path.exists(journal)


def test_a_notebook_that_cannot_take_an_entry_nor_its_journal_says_they_are_lost(tmp_path, caplog, monkeypatch):
    """The journal cannot be written either (here: a named pipe at its path): the log says the runs are
    lost if the app stops first, and close() that they are lost, naming them; nothing blocks."""
    path = tmp_path / "nb.db"
    nb = Notebook(str(path), timeout=0.2)
    os.mkfifo(tmp_path / "nb.db.journal")
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        with caplog.at_level("WARNING"):
            nb.add(run("gone1"), timeout=0.2)
            assert nb.close(wait=0.2) == ["gone1"]
    finally:
        other.execute("ROLLBACK")
        other.close()
    journal = f"{path}.journal"
    lines = [r.getMessage() for r in caplog.records if r.name == "app.training.notebook"]
    why = f"the journal {journal} is a named pipe (FIFO), not a file"
    assert lines == [
        f"notebook {path}: 1 run not saved yet (database is locked): listed and tried again while the app runs; "
        f"the journal {journal} could not take gone1 ({why}): lost if the app stops before they are written",
        f"notebook {path}: 1 run could not be written before the app stopped (database is locked): the journal "
        f"{journal} could not take gone1 ({why}): lost"]
    assert [r.levelname for r in caplog.records if r.name == "app.training.notebook"] == ["ERROR", "ERROR"]


def test_a_truly_full_disk_gives_the_journal_the_room_kept_for_it(tmp_path, monkeypatch, caplog):
    """The notebook's filesystem is full (a 1 MiB tmpfs filled to the last block): neither the
    notebook's WAL nor a journal beside it could grow, so the journal keeps room allocated while the
    disk has it (`<notebook>.journal-reserve`), and gives it up to be written. The entry is in the
    journal at close and in the notebook at the next opening, once there is room again (needs root to
    mount the tmpfs; skipped elsewhere)."""
    from app.training import journal as journal_module

    tiny = tmp_path / "tiny"
    tiny.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(tiny)], capture_output=True).returncode:
        import pytest

        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        monkeypatch.setattr(journal_module, "RESERVE", 256 * 1024)
        path = tiny / "nb.db"
        nb = Notebook(str(path), timeout=0.2)
        nb.add(run("before1"))
        assert os.path.getsize(f"{path}.journal-reserve") == 256 * 1024
        fd = os.open(tiny / "filler", os.O_WRONLY | os.O_CREAT)  # the disk filled by another program
        try:
            while os.write(fd, b"\0" * 4096):
                pass
        except OSError:
            pass  # ENOSPC: not one block left
        finally:
            os.close(fd)
        entry = run("full1", controller={"w": "x" * 100_000})
        with caplog.at_level("WARNING"):
            nb.add(entry, timeout=0.2)
            not_written = nb.close(wait=0.2)  # [] when the retrier wrote it in the room given up
        assert not_written in ([], ["full1"])
        said = [r.getMessage() for r in caplog.records if r.name == "app.training.notebook"]
        assert any(f"in the journal {path}.journal (full1)" in line for line in said), said
        assert not any("lost" in line or "could not take" in line for line in said), said
        assert not os.path.exists(f"{path}.journal-reserve")  # given up for the journal
        os.remove(tiny / "filler")
        again = Notebook(str(path))
        assert [e["run_id"] for e in again.entries()] == ["before1", "full1"]
        assert again.get("full1") == entry
        assert not (tiny / "nb.db.journal").exists()
        assert os.path.getsize(f"{path}.journal-reserve") == 256 * 1024  # kept again, now there is room
    finally:
        subprocess.run(["umount", "-l", str(tiny)], capture_output=True)
