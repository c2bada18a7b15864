"""The viser app, server side: tabs are headless websocket clients (app/probe.py).

Checked: the pose sent for a dragged marker is the controller's output (through the arm's
kinematics) and its printed error is ||goal - fk||; markers are constrained to the task axes;
tabs have their own goals; the training panel drives the lab Runner (generations advance,
pause holds them, refusals are shown); the notebook keeps runs across restarts.
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
import urllib.request

import numpy as np
import pinocchio as pin
import pytest

from app.probe import Probe
from app.server import LabApp
from app.startup import made_for
from app.tab.goals import fmt_len
from app.training.notebook import Notebook, NotebookError
from conftest import last_pose, session_of, wait_or_kill, wait_until

import lab
import robots

# the render loop may redraw a tab in the instant between its socket closing and its session ending
pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")



def test_url_is_the_port_served(app):
    assert app.url == f"http://127.0.0.1:{app.server.get_port()}"
    with urllib.request.urlopen(app.url, timeout=10) as r:
        assert r.status == 200


def test_marker_is_constrained_to_the_task_plane(app, tab):
    msg = tab.wait_for(lambda m: m["type"] == "TransformControlsMessage" and m["name"] == "/tab/goal0/marker")
    props = msg["props"]
    assert list(props["active_axes"]) == [True, True, False]  # planar arm: the plane z = 0
    assert list(props["translation_limits"][2]) == [0.0, 0.0]
    assert props["disable_rotations"]


@pytest.mark.parametrize("goal", [(14.0, 6.0), (60.0, -40.0)], ids=["reachable", "unreachable"])
def test_pose_sent_is_the_controller_output(app, tab, goal):
    session = session_of(app, tab)
    tab.drag("/tab/goal0/marker", (*goal, 0.0))
    assert wait_until(lambda: np.allclose(session.goals[0].goal, goal))
    arm, controller = session.arm, app.state.shown.controller
    q = controller(np.array([goal]))[0]
    # the last joint's frame, as sent to the browser, is where Pinocchio puts it for q
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, arm.to_pinocchio(q))
    j = arm.model.njoints - 1

    def sent_pose_is_pinocchios() -> bool:  # once the drag's messages have all arrived
        pos, wxyz = last_pose(tab, f"/tab/goal0/arm/j{j}")
        R = pin.Quaternion(wxyz[0], *wxyz[1:]).toRotationMatrix()
        return np.allclose(pos, data.oMi[j].translation, atol=1e-6) and np.allclose(R, data.oMi[j].rotation, atol=1e-6)

    assert wait_until(sent_pose_is_pinocchios, timeout=10)
    # the printed error is ||goal - fk(q)||, also for a goal out of reach
    error = float(np.linalg.norm(arm.fk(q)[:2] - goal))
    assert session.goals[0].error == pytest.approx(error)
    assert wait_until(lambda: any(m["type"] == "GuiUpdateMessage" and fmt_len(arm, error) in str(m["updates"])
                                  for _t, m in list(tab.messages)))
    assert np.all(q >= arm.lower - 1e-12) and np.all(q <= arm.upper + 1e-12)
    if goal[0] > 50:
        assert error > 10  # out of reach: the pose and a large error, no crash


def test_tabs_have_their_own_goals_and_a_tab_closing_mid_run_harms_nothing(app, tab):
    other = Probe(app.url).start()
    app.panel.generations.value = 100_000
    try:
        a, b = session_of(app, tab), session_of(app, other)
        assert a is not b
        assert a.add_goal() is None
        assert len(a.goals) == 2 and len(b.goals) == 1
        assert "refused" in b.remove_goal()  # the last goal stays
        assert a.remove_goal() is None and len(a.goals) == 1
        assert app.panel.start() is None
        assert wait_until(lambda: app.state.progress()["generation"] >= 3)
        other.close()  # mid-run
        assert wait_until(lambda: len(app.sessions) == 1)
        n = app.state.progress()["generation"]
        assert wait_until(lambda: app.state.progress()["generation"] > n + 3)  # training goes on
        tab.drag("/tab/goal0/marker", (10.0, 10.0, 0.0))  # the remaining tab still answers
    finally:
        other.close()
        app.state.reset()
        app.panel.generations.value = 1000


def test_training_panel_runs_pauses_refuses_and_keeps_a_notebook(app, tab):
    panel, state = app.panel, app.state
    session = session_of(app, tab)
    panel.generations.value = 100_000
    panel.population.value = 20
    try:
        panel.buttons["Start"].value = True
        assert wait_until(lambda: state.progress()["generation"] >= 5)
        panel.buttons["Start"].value = True  # a second start is refused, with a message
        assert "refused" in panel.message.content.lower() and "run is going" in panel.message.content
        panel.buttons["Pause"].value = True
        assert wait_until(lambda: state.runner.state == "paused")
        assert wait_until(lambda: state.runner.holding is not None)  # the worker holds; every event is in
        held = state.progress()["generation"]
        # the arms follow training: once redrawn, the pose is the run's best controller's
        assert wait_until(lambda: session.version == state.shown.version)
        assert state.shown.source.startswith("run")
        goal = session.goals[0].goal
        assert np.allclose(session.goals[0].arm_view.q, state.shown.controller(goal[None])[0], rtol=0, atol=1e-4)
        printed = fmt_len(session.arm, session.goals[0].error)  # the label and the tab's table agree
        assert printed in session.goals[0].label.text and printed in session.table.content
        time.sleep(0.3)
        assert state.progress()["generation"] == held
        panel.buttons["Resume"].value = True
        assert wait_until(lambda: state.progress()["generation"] > held + 2)
        panel.refresh(force=True)
        assert "Running" in panel.status.content and "evaluations/s" in panel.status.content
        panel.buttons["Stop"].value = True
        assert state.runner.state == "stopped"
        entry = state.notebook.entries()[-1]
        assert entry["run_id"] == state.runner.run_id and entry["state"] == "stopped"
        assert entry["robot"] == "planar" and entry["settings"]["population"] == 20 and entry["test_mse"] > 0
        assert Notebook(state.notebook.path).entries()[-1]["run_id"] == entry["run_id"]  # kept on disk
        panel.buttons["Reset"].value = True  # an untrained network: the first generation of the next run
        assert state.progress()["generation"] == 0 and state.shown.source.startswith("untrained")
        panel.buttons["Trained network"].value = True  # one click brings the shipped one back
        assert state.progress()["generation"] == 0 and state.shown.source.startswith("shipped")
    finally:
        state.reset()
        panel.generations.value, panel.population.value = 1000, 50


@pytest.mark.parametrize("field,bad,reason", [("population", 0, "population"), ("generations", -5, "generations"),
                                              ("seed", 2.5, "whole number"), ("population", 3, "CMA-ES")])
def test_invalid_numbers_are_refused_with_a_message(app, field, bad, reason):
    handle = getattr(app.panel, field)
    before = handle.value
    handle.value = bad
    assert handle.value == before  # put back
    assert "refused" in app.panel.message.content.lower() and reason in app.panel.message.content


def test_robot_change_is_refused_while_training(app):
    panel, state = app.panel, app.state
    panel.generations.value = 100_000
    assert panel.start() is None
    try:
        panel.robot.value = "scara"
        assert panel.robot.value == "planar" and state.arm.name == "planar"
        assert "stop it before changing the robot" in panel.message.content
    finally:
        panel.stop()
        panel.reset()
        panel.generations.value = 1000


def test_notebook_survives_a_restart_and_a_bad_file(tmp_path):
    path = tmp_path / "nb.db"
    nb = Notebook(str(path))
    nb.add({"run_id": "abc", "robot": "planar", "method": "cmaes", "seed": 0, "generations": 3})
    assert Notebook(str(path)).get("abc")["generations"] == 3
    for content in (b"{ not json", b"[1, 2, 3]", b"RRF2\x00\xff binary"):  # refused, left as it is
        bad = tmp_path / "bad.db"
        bad.write_bytes(content)
        with pytest.raises(NotebookError, match=f"notebook {re.escape(str(bad))} is not a lab notebook"):
            Notebook(str(bad))
        assert bad.read_bytes() == content
    with pytest.raises(NotebookError, match="is a folder"):
        Notebook(str(tmp_path))
    empty = tmp_path / "empty.db"
    empty.write_bytes(b"")
    assert Notebook(str(empty)).entries() == []


def test_a_json_notebook_is_imported_once_and_left_in_place(tmp_path):
    old = tmp_path / "notebook.json"
    text = json.dumps({"comment": "my notes", "runs": [{"run_id": "a1", "robot": "planar", "method": "cmaes"},
                                                       {"runid_typo": "b2"}]})
    old.write_text(text)
    nb = Notebook(str(tmp_path / "notebook.db"))
    assert [e["run_id"] for e in nb.entries()] == ["a1"]
    nb.add({"run_id": "c3", "robot": "planar", "method": "cmaes"})
    old.write_text(json.dumps({"runs": [{"run_id": "zz", "robot": "planar", "method": "cmaes"}]}))
    again = Notebook(str(tmp_path / "notebook.db"))  # imported once: a later change of the JSON is not
    assert [e["run_id"] for e in again.entries()] == ["a1", "c3"]
    assert Notebook(str(old)).path == str(tmp_path / "notebook.db")  # a .json path: its database beside it
    bad = tmp_path / "other.json"
    bad.write_bytes(b"[1, 2, 3]")
    with pytest.raises(NotebookError, match="is not a lab notebook"):
        Notebook(str(bad))
    assert bad.read_bytes() == b"[1, 2, 3]" and not (tmp_path / "other.db").exists()


def test_malformed_entries_are_skipped_by_name_and_the_others_stay_listed(tmp_path):
    old = tmp_path / "notebook.json"
    old.write_text(json.dumps({"runs": [{"run_id": "good1", "robot": "planar", "method": "cmaes"},
                                        {"run_id": "norobot", "method": "cmaes"},
                                        {"run_id": 42, "robot": "planar", "method": "cmaes"},
                                        {"run_id": "good2", "robot": "scara", "method": "neat"}]}))
    nb = Notebook(str(tmp_path / "notebook.db"))
    assert [e["run_id"] for e in nb.entries()] == ["good1", "good2"]
    assert nb.skipped() == ["'norobot'", "42"]
    with pytest.raises(ValueError, match="needs a text run_id"):
        nb.add({"run_id": 7, "robot": "planar", "method": "cmaes"})


def _sha(path) -> str:
    import hashlib

    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def _old_notebook(path, entries) -> None:
    """A notebook.db as earlier versions made it (no application_id, no user_version)."""
    import sqlite3

    db = sqlite3.connect(path, isolation_level=None)
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)")
    db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
    for e in entries:
        db.execute("INSERT INTO runs (run_id, entry) VALUES (?, ?)", (e["run_id"], json.dumps(e)))
    db.close()


def test_a_notebook_of_earlier_versions_opens_with_its_entries_and_gets_the_marker(tmp_path):
    import sqlite3

    from app.training.notebook import APPLICATION_ID, SCHEMA_VERSION

    path = tmp_path / "notebook.db"
    _old_notebook(path, [{"run_id": "old1", "robot": "planar", "method": "cmaes", "generations": 7}])
    (tmp_path / "notebook.json").write_text(json.dumps([{"run_id": "js1", "robot": "planar", "method": "neat"}]))
    nb = Notebook(str(path))
    assert [e["run_id"] for e in nb.entries()] == ["old1", "js1"]  # the JSON of before: imported once
    assert nb.read_only is None
    nb.add({"run_id": "new1", "robot": "planar", "method": "cmaes"})
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    db.close()
    assert [e["run_id"] for e in Notebook(str(path)).entries()] == ["old1", "js1", "new1"]
    fresh = tmp_path / "fresh.db"
    Notebook(str(fresh))
    with open(fresh, "rb") as f:
        head = f.read(100)
    assert int.from_bytes(head[68:72], "big") == APPLICATION_ID and int.from_bytes(head[60:64], "big") == SCHEMA_VERSION


def test_another_programs_database_is_refused_by_name_and_left_byte_for_byte(tmp_path):
    """A SQLite file of another program (other tables, another `runs`, another application_id, a
    newer notebook, a damaged one) is refused, and nothing is written into it or beside it."""
    import sqlite3

    from app.training.notebook import APPLICATION_ID

    def database(name, *statements, wal=False):
        path = tmp_path / name
        db = sqlite3.connect(path, isolation_level=None)
        if wal:
            db.execute("PRAGMA journal_mode=WAL")
        for statement in statements:
            db.execute(statement)
        db.close()
        return path

    cases = [
        (database("users.db", "CREATE TABLE users (id INTEGER, pw TEXT)", "INSERT INTO users VALUES (1, 'x')"),
         "a SQLite database with table users"),
        (database("users-wal.db", "CREATE TABLE users (id INTEGER, pw TEXT)", wal=True),
         "a SQLite database with table users"),
        (database("runs.db", "CREATE TABLE runs (id INTEGER PRIMARY KEY, name TEXT)", "INSERT INTO runs VALUES (1, 'a')"),
         "its table runs has the columns id, name"),
        (database("both.db", "CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)",
                  "CREATE TABLE users (id INTEGER)"), "a SQLite database with table users"),
        (database("gpkg.db", "PRAGMA application_id = 1196444487", "CREATE TABLE runs (seq, run_id, entry)"),
         "another program: application_id 0x47504b47"),
        (database("newer.db", f"PRAGMA application_id = {APPLICATION_ID}", "PRAGMA user_version = 9"),
         "a lab notebook of a newer version"),
        (database("versioned.db", "PRAGMA user_version = 3"), "no tables, user_version 3"),
        # the notebook's column names, not its table: no key, no UNIQUE on run_id, other types
        (database("names.db", "CREATE TABLE runs (seq TEXT, run_id BLOB, entry INTEGER)",
                  "INSERT INTO runs VALUES ('1', X'00', 5)"),
         re.escape("its table runs is `CREATE TABLE runs (seq TEXT, run_id BLOB, entry INTEGER)`, a notebook's is "
                   "`CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)`")),
        (database("names-wal.db", "CREATE TABLE runs (seq, run_id, entry)", wal=True), "its table runs is `CREATE TABLE runs \\(seq, run_id, entry\\)`"),
        (database("nounique.db", f"PRAGMA application_id = {APPLICATION_ID}", "PRAGMA user_version = 1",
                  "CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT, entry TEXT NOT NULL)",
                  "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)"), "its table runs is `CREATE TABLE runs \\(seq "
                  "INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT, entry"),
        (database("meta.db", "CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, entry TEXT NOT NULL)",
                  "CREATE TABLE meta (key, value)"), "its table meta is `CREATE TABLE meta \\(key, value\\)`"),
        (database("check.db", "CREATE TABLE runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, run_id TEXT UNIQUE, "
                  "entry TEXT NOT NULL CHECK (length(entry) < 9))"), "its types, key or constraints differ"),
    ]
    damaged = tmp_path / "damaged.db"
    _old_notebook(damaged, [{"run_id": f"r{k}", "robot": "planar", "method": "cmaes", "pad": "x" * 3000} for k in range(40)])
    data = bytearray(damaged.read_bytes())
    data[4096 * 3: 4096 * 3 + 64] = b"\xff" * 64  # a page of the runs table overwritten
    damaged.write_bytes(bytes(data))
    cases.append((damaged, "damaged or not a lab notebook \\(SQLite: database disk image is malformed"))
    for path, what in cases:
        before, listing = _sha(path), sorted(os.listdir(tmp_path))
        with pytest.raises(NotebookError, match=f"notebook {re.escape(str(path))} is .*{what}"):
            Notebook(str(path))
        assert _sha(path) == before, path
        assert sorted(os.listdir(tmp_path)) == listing, path  # no -wal, -shm or -journal beside it


def test_a_bad_row_is_skipped_by_name_and_the_others_are_listed(tmp_path, caplog):
    import sqlite3

    path = tmp_path / "nb.db"
    nb = Notebook(str(path))
    nb.add({"run_id": "good1", "robot": "planar", "method": "cmaes"})
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('cut', '{\"run_id\": \"cut\", \"rob')")
    db.execute("INSERT INTO runs (run_id, entry) VALUES (NULL, '[1, 2]')")
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('num', '42')")
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('bytes', X'FFFE00')")
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('deep', ?)", ("[" * 100_000,))  # a RecursionError in json
    db.execute("INSERT INTO runs (run_id, entry) VALUES (NULL, ?)", ('{"run_id": ' + "[" * 100_000,))
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('rec', ?)",  # a run whose recording is not a path
               (json.dumps({"run_id": "rec", "robot": "planar", "method": "cmaes", "recording": [1]}),))
    db.close()
    nb.add({"run_id": "good2", "robot": "scara", "method": "neat"})
    with caplog.at_level("WARNING", logger="app.training.notebook"):
        assert [e["run_id"] for e in nb.entries()] == ["good1", "good2"]
        assert [e["run_id"] for e in nb.entries()] == ["good1", "good2"]
    assert nb.skipped() == ["'cut'", "seq 3", "'num'", "'bytes'", "'deep'", "seq 7", "'rec'"]
    [line] = [r.getMessage() for r in caplog.records]  # one line, not one per refresh
    assert "'cut' (not JSON" in line and "seq 3 (not a JSON object)" in line and "'num' (not a JSON object)" in line
    assert "'deep' (not readable: its JSON is nested too deeply)" in line and "seq 7 (not readable" in line
    assert "'rec' (its recording must be a path" in line


def test_a_notebook_that_cannot_be_read_lists_the_runs_read_last(tmp_path, monkeypatch, caplog):
    import sqlite3

    nb = Notebook(str(tmp_path / "nb.db"))
    nb.add({"run_id": "r1", "robot": "planar", "method": "cmaes"})
    assert [e["run_id"] for e in nb.entries()] == ["r1"]

    def locked(self):
        raise sqlite3.OperationalError("database is locked")

    monkeypatch.setattr(Notebook, "_rows", locked)
    with caplog.at_level("WARNING", logger="app.training.notebook"):
        assert [e["run_id"] for e in nb.entries()] == ["r1"]  # the render loop goes on
        assert [e["run_id"] for e in nb.entries()] == ["r1"]
    [line] = [r.getMessage() for r in caplog.records]
    assert "cannot be read (database is locked)" in line


def test_a_bad_row_leaves_the_runs_list_working(app):
    """The render loop's Runs list (and the lesson links and replay lists after it) goes on."""
    import sqlite3

    from app.training.notebook import label

    entry = {"run_id": "listed01", "robot": "planar", "method": "cmaes", "seed": 0}
    app.state.notebook.add(entry)
    db = sqlite3.connect(app.state.notebook.path, isolation_level=None)
    db.execute("INSERT INTO runs (run_id, entry) VALUES ('badrow01', 'not json')")
    try:
        app.runs.refresh(force=True)
        assert label(entry) in app.runs.choice.options
        assert "'badrow01'" in app.runs.message.content
    finally:
        db.execute("DELETE FROM runs WHERE run_id IN ('badrow01', 'listed01')")
        db.close()


def test_the_runs_list_says_the_notebook_is_read_only(app, monkeypatch):
    monkeypatch.setattr(app.state.notebook, "read_only", "the file is read-only")
    app.runs.refresh(force=True)
    assert app.runs.message.content.startswith("Notebook read-only (the file is read-only): new runs are listed")
    monkeypatch.undo()
    app.runs.refresh(force=True)
    assert "read-only" not in app.runs.message.content


def test_the_runs_list_says_which_runs_are_not_saved_yet_and_why(app):
    """A run whose entry could not be written (another program locks the notebook): listed, and the
    Runs panel says it is not saved yet and why, until the retry writes it."""
    import sqlite3

    from app.training.notebook import label

    nb = app.state.notebook
    entry = {"run_id": "unsaved01", "robot": "planar", "method": "cmaes", "seed": 0}
    other = sqlite3.connect(nb.path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        nb.add(entry, timeout=0.1)
        app.runs.refresh(force=True)
        assert label(entry) in app.runs.choice.options
        assert app.runs.message.content.startswith("1 run not saved yet: database is locked; retrying.")
    finally:
        other.execute("ROLLBACK")
    try:
        assert wait_until(lambda: nb.not_saved() == (0, None), 120)  # the retrier waits for the lock's end
        app.runs.refresh(force=True)
        assert label(entry) in app.runs.choice.options and "not saved" not in app.runs.message.content
    finally:
        other.execute("DELETE FROM runs WHERE run_id = 'unsaved01'")
        other.close()


def test_a_read_only_notebook_is_listed_and_not_written(tmp_path, monkeypatch, caplog):
    """Tests run as root, whom chmod does not stop: os.access is made to say what it says to a user
    for a 0444 file (or a read-only folder), and SQLite's own "readonly database" is raised where
    os.access cannot tell (a read-only mount seen through another user's permissions)."""
    import sqlite3

    path = tmp_path / "nb.db"
    Notebook(str(path)).add({"run_id": "kept1", "robot": "planar", "method": "cmaes"})
    before, files = _sha(path), sorted(os.listdir(tmp_path))  # the notebook (and its journal's reserve)
    real = os.access
    for locked, why in ((str(path), "the file is read-only"), (str(tmp_path), f"the folder {tmp_path} is read-only")):
        caplog.clear()
        monkeypatch.setattr(os, "access", lambda p, mode, **k: False if (os.fspath(p) == locked and mode & os.W_OK)
                            else real(p, mode, **k))
        with caplog.at_level("WARNING", logger="app.training.notebook"):
            nb = Notebook(str(path))
            assert nb.read_only == why
            nb.add({"run_id": "session1", "robot": "planar", "method": "neat"})
            assert [e["run_id"] for e in nb.entries()] == ["kept1", "session1"]  # a run added while read-only: listed
        [line] = [r.getMessage() for r in caplog.records]  # said once, clearly
        assert f"notebook {path} is read-only ({why})" in line and "new runs are not written" in line
        assert _sha(path) == before and sorted(os.listdir(tmp_path)) == files == ["nb.db", "nb.db.journal-reserve"]
    monkeypatch.setattr(os, "access", real)

    def readonly(self):
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(Notebook, "_connect", readonly)
    nb = Notebook(str(path))
    assert nb.read_only == "SQLite: attempt to write a readonly database"
    assert [e["run_id"] for e in nb.entries()] == ["kept1"]


def test_two_apps_sharing_a_notebook_lose_no_entry(tmp_path):
    """Two processes add runs to one notebook at once (as two `make app` do): every entry stays."""
    import subprocess
    import sys

    path = tmp_path / "notebook.db"
    code = ("import sys; from app.training.notebook import Notebook\n"
            "nb = Notebook(sys.argv[1])\n"
            "for k in range(40): nb.add({'run_id': f'{sys.argv[2]}{k}', 'robot': 'planar', 'method': 'cmaes'})\n")
    procs = [subprocess.Popen([sys.executable, "-c", code, str(path), who], stderr=subprocess.PIPE, text=True)
             for who in ("a", "b")]
    errors = [p.communicate(timeout=60)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errors
    ids = {e["run_id"] for e in Notebook(str(path)).entries()}
    assert ids == {f"{w}{k}" for w in "ab" for k in range(40)}


def test_a_run_that_ends_while_another_program_locks_the_notebook_is_kept_and_saved_later(tmp_path, caplog):
    """Another program holds BEGIN EXCLUSIVE across a run's end (past the busy timeout: "database is
    locked"): the entry is listed as not saved, then written once the lock goes; no traceback."""
    import sqlite3

    from app.training.state import LabState

    path = tmp_path / "notebook.db"
    nb = Notebook(str(path), timeout=0.2)  # SQLite's busy timeout, 30 s in the app
    nb.add({"run_id": "before1", "robot": "planar", "method": "cmaes"})
    state = LabState("planar", nb)
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        with caplog.at_level("WARNING"):
            assert state.start(lab.TrainConfig(robot="planar", method="cmaes", seed=0, generations=5, population=8,
                                               targets=10, test_goals=10)) is None
            run_id = state.runner.run_id
            assert state.runner.join(120).state == "finished"
            assert [e["run_id"] for e in nb.entries()] == ["before1", run_id]  # listed at once
            assert nb.not_saved() == (1, "database is locked")
            assert [r[0] for r in other.execute("SELECT run_id FROM runs")] == ["before1"]  # not in the file
            time.sleep(1.0)  # the retrier tries (and fails) again meanwhile: nothing changes, nothing is said
            assert nb.not_saved() == (1, "database is locked") and nb.get(run_id)["run_id"] == run_id
            other.execute("ROLLBACK")  # the lock goes
            assert wait_until(lambda: nb.not_saved() == (0, None), 120)
    finally:
        other.close()
    assert [e["run_id"] for e in Notebook(str(path)).entries()] == ["before1", run_id]
    assert Notebook(str(path)).get(run_id)["generations"] == 5
    assert not [r for r in caplog.records if r.exc_info or r.levelname == "ERROR"]  # no traceback
    said = [r.getMessage() for r in caplog.records if r.name == "app.training.notebook"]
    assert said == [f"notebook {path}: 1 run not saved yet (database is locked): listed and tried again while the app "
                    f"runs; in the journal {path}.journal ({run_id}), which the next opening of the notebook imports",
                    f"notebook {path}: the runs not saved (database is locked) are saved now"]
    assert not os.path.exists(f"{path}.journal")  # written: out of the journal


def test_a_run_that_ends_on_a_full_disk_is_kept_and_saved_when_space_returns(tmp_path):
    """The disk is full when the entry is written (RLIMIT_FSIZE in a child process: a write past it
    fails as on a full disk, "disk I/O error"): the entry is listed as not saved and written once
    there is space again; nothing else in the notebook changes."""
    import subprocess
    import sys

    code = """if True:
        import json, os, resource, signal, sys, time
        from app.training.notebook import Notebook
        path = sys.argv[1]
        nb = Notebook(path, timeout=1.0)
        nb.add({"run_id": "small1", "robot": "planar", "method": "cmaes"})
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) as on a full disk
        soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (65536, hard))  # the notebook's WAL cannot grow past 64 KiB
        nb.add({"run_id": "big1", "robot": "planar", "method": "cmaes", "controller": {"w": "x" * 300_000}})
        full = (nb.not_saved(), [e["run_id"] for e in nb.entries()], [e["run_id"] for e in Notebook(path).entries()])
        time.sleep(1.0)  # the retrier fails again meanwhile
        still = nb.not_saved()
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))  # space again
        deadline = time.monotonic() + 120
        while nb.not_saved()[0] and time.monotonic() < deadline:
            time.sleep(0.05)
        saved = Notebook(path).get("big1")
        print(json.dumps({"full": full, "still": still, "later": nb.not_saved(), "saved": len(saved["controller"]["w"])}))
    """
    path = tmp_path / "notebook.db"
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["full"] == [[1, "disk I/O error"], ["small1", "big1"], ["small1"]]  # listed, not in the file
    assert out["still"] == [1, "disk I/O error"]
    assert out["later"] == [0, None] and out["saved"] == 300_000
    assert "Traceback" not in done.stderr and "1 run not saved yet (disk I/O error)" in done.stderr
    assert "the runs not saved (disk I/O error) are saved now" in done.stderr


def test_a_g1_gradient_run_after_cmaes_and_neat_leaves_its_entry(tmp_path, caplog):
    """On g1, a gradient run started after a CMA-ES and a NEAT run (each stopped,
    as the app's Stop does, and recorded) leaves its entry, as every run before it; then one that
    ends on its own. Every entry is in the file, whole, pointing at its own whole recording."""
    from app.server import rerun_recorder
    from app.training.state import LabState
    from lab.recording.replay import read_recording

    path = tmp_path / "notebook.db"
    state = LabState("g1", Notebook(str(path)), recorder=rerun_recorder(str(tmp_path / "rec")))
    small = dict(robot="g1", seed=0, population=6, targets=20, test_goals=20)
    runs = []
    with caplog.at_level("WARNING"):
        for method, stop in (("cmaes", True), ("neat", True), ("gradient", True), ("gradient", False)):
            config = lab.TrainConfig.preset(method=method, generations=100_000 if stop else 4, **small)
            assert state.start(config) is None
            runner = state.runner
            if stop:
                assert wait_until(lambda: state.progress()["generation"] >= 2, 300)
                assert state.stop() is None
            assert runner.join(300) is not None and runner.done
            runs.append((runner.run_id, method, "stopped" if stop else "finished"))
            assert [(e["run_id"], e["method"], e["state"]) for e in state.notebook.entries()] == runs
    entries = Notebook(str(path)).entries()  # in the file
    assert [(e["run_id"], e["method"], e["state"]) for e in entries] == runs
    assert state.notebook.not_saved() == (0, None)
    for e in entries:
        assert e["controller"] is not None and e["robot"] == "g1"
        assert read_recording(e["recording"]).protocol["run_id"] == e["run_id"]
    assert not [r for r in caplog.records if r.exc_info]  # no traceback


def test_a_race_of_one_method_and_seed_records_two_files(tmp_path, monkeypatch):
    """Both runs of a race start in the same second; with the same method and seed they still get a
    recording each, whole, and each notebook entry points at its own."""
    from datetime import datetime

    import lab.recording.logger as logger_module
    from app.server import rerun_recorder

    class Frozen(datetime):  # one second for both, however slow the machine
        @classmethod
        def now(cls, tz=None):
            return cls(2026, 12, 4, 11, 5, 0)

    monkeypatch.setattr(logger_module, "datetime", Frozen)
    from app.training.state import LabState
    from lab.recording.replay import read_recording

    state = LabState("planar", Notebook(str(tmp_path / "notebook.db")), recorder=rerun_recorder(str(tmp_path / "rec")))
    config = lab.TrainConfig(robot="planar", method="cmaes", seed=0, generations=15, population=8, targets=10,
                             test_goals=10)
    assert state.start(config, partner=config) is None
    assert state.recording != state.partner.recording
    assert wait_until(lambda: len(state.notebook.entries()) == 2, 120)
    entries = state.notebook.entries()
    assert len({e["recording"] for e in entries}) == 2
    for e in entries:
        rec = read_recording(e["recording"])
        assert (rec.salvaged, rec.last_generation, rec.protocol["run_id"]) == (False, 14, e["run_id"])


def test_python_m_app_refuses_bad_paths_and_hosts_before_starting(tmp_path, capsys):
    from app.__main__ import main

    recording = tmp_path / "run.rrd"
    recording.write_bytes(b"RRF2\x00\x88 a recording given by mistake")
    for path, why in ((recording, "is not a lab notebook"), (tmp_path, "is a folder")):
        assert main(["--notebook", str(path), "--port", "0"]) == 2
        assert f"error: notebook {path} {why}" in capsys.readouterr().err
    assert main(["--recordings", str(recording / "sub"), "--port", "0"]) == 2
    assert f"error: --recordings must be a folder, but {recording} is a file" in capsys.readouterr().err
    assert main(["--host", "no.such.host.invalid", "--port", "0"]) == 2  # viser would wait forever
    assert "error: cannot serve on --host no.such.host.invalid" in capsys.readouterr().err
    assert recording.read_bytes() == b"RRF2\x00\x88 a recording given by mistake"
    assert sorted(os.listdir(tmp_path)) == ["run.rrd"]


def start_app_process(*args: str):
    """`python -m app ARGS` in a child process: (the process, the URL it prints as ready)."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "app", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    url = None
    for line in proc.stdout:
        if "Neuro-IK Lab ready" in line:
            url = line.rsplit(" ", 1)[-1].strip()
            break
    return proc, url


def test_python_m_app_prints_the_url_it_really_serves(tmp_path):
    import signal
    import socket

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    port = taken.getsockname()[1]
    proc, url = start_app_process("--port", str(port), "--no-record", "--notebook", str(tmp_path / "nb.json"))
    try:
        assert url is not None and url.startswith("http://127.0.0.1:")
        served = int(url.rsplit(":", 1)[1])
        assert served != port  # the taken port was skipped, and the URL says which one is used
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        wait_or_kill(proc, 20)
        taken.close()


def test_changing_the_robot_rebuilds_every_tab_with_that_arms_controller(app, tab):
    session = session_of(app, tab)
    app.panel.robot.value = "scara"
    try:
        shown = app.state.shown
        assert app.state.arm.name == "scara" and made_for(shown.controller, shown.arm)  # its own, at once
        assert shown.source.startswith(("shipped", "trained at startup"))
        assert app.panel.generations.value == lab.TrainConfig(robot="scara").generations  # the arm's defaults
        assert wait_until(lambda: session.arm.name == "scara")
        msg = tab.wait_for(lambda m: m["type"] == "TransformControlsMessage" and m["name"] == "/tab/goal0/marker"
                           and list(m["props"]["active_axes"]) == [True, True, True])
        assert msg["props"]["disable_rotations"]
        assert wait_until(lambda: session.goals and "net " in session.goals[0].label.text)
    finally:
        app.panel.robot.value = "planar"
    assert wait_until(lambda: session.arm.name == "planar") and app.state.shown.source.startswith("shipped")


def test_a_controller_never_meets_an_arm_it_was_not_made_for(app):
    """A controller of another arm is refused with a message (the render loop never sees it)."""
    planar = app.state.shown.controller
    scara = robots.load("scara")
    before = app.state.shown
    msg = app.state.show(planar, "a test", arm=scara)
    assert msg and "not made for the scara arm" in msg and app.state.shown is before
    assert app.state.show_replay(planar, "a test") is None  # the planar arm's own is shown
    app.state.live()


@pytest.mark.parametrize("robot", robots.names())
def test_every_shipped_controller_fits_its_arm_and_has_the_error_its_file_records(robot):
    """app/pretrained/<robot>-<method>.json: made for that arm, the arm's default method, and its
    held-out error (lab.experiments.arms, 2,000 goals) is the one the file records."""
    from app.startup import load_pretrained, pretrained_path
    from lab.experiments import arms

    controller, _ = load_pretrained(robot)
    with open(pretrained_path(robot), encoding="utf-8") as f:
        doc = json.load(f)
    arm = robots.load(robot)
    assert doc["settings"]["robot"] == robot and made_for(controller, arm)
    if doc.get("held_out"):
        again, stored = arms.held_out(arm, controller), doc["held_out"]
        rows = list(zip(again.get("effectors", [again]), stored.get("effectors", [stored])))  # a tree: each effector
        assert rows and len(again.get("effectors", [])) == len(stored.get("effectors", []))
        for now, then in [(again, stored), *rows]:
            for key in ("median", "p90", "p99"):
                if key in now or key in then:
                    assert now[key] == pytest.approx(then[key], rel=1e-9), key


@pytest.mark.parametrize("robot", [n for n in robots.names() if robots.kind(n) == "real"])
def test_every_shipped_real_arm_controller_seeds_a_refinement_to_a_tenth_of_a_millimetre(robot):
    """The practical use of a learned IK (docs/results/real-arms.md): the shipped network's answer
    (every head's proposal) and at most 3 damped Gauss-Newton steps reach 0.1 mm on at least 99 %
    of the 2,000 held-out goals, and of 2,000 goals of another seed (arms.OTHER_GOALS) that no
    setting was tuned on."""
    from app.startup import load_pretrained
    from lab.experiments import arms
    from lab.problem.controllers import proposals
    from robots.ik import refine

    controller, _ = load_pretrained(robot)
    arm = robots.load(robot)
    tol = arms.tolerance(arm)
    assert tol == 1e-4
    for goal_seed in (0, arms.OTHER_GOALS):
        goals = arms.held_out_goals(arm, goal_seed=goal_seed)
        r = refine(arm, goals, proposals(controller, goals), steps=3)  # refine's default tolerance: 0.1 mm
        assert np.all(r.steps <= 3)
        assert np.mean(r.error < tol) >= 0.99, (goal_seed, np.mean(r.error < tol))


# a tree's shipped controller: (most held-out median over goals and effectors, % of each effector's reach;
# least share of held-out goals with every effector within 0.1 mm after at most 3 steps). The aim is 2 % and
# 99 % on every tree (the team's aim: 1 %); g1 reaches 99 % refined with its limbs solved in closed form
# first (robots.limbs; docs/results/trees.md), and is held to 1.8 % and 99.8 % (measured 1.75 %, 99.90 %).
TREE_FIGURES = {"talos-legs": (1.0, 0.99), "allegro": (1.0, 0.99), "solo12": (1.0, 0.99), "g1": (1.8, 0.998)}


@pytest.mark.parametrize("robot", [n for n in robots.names() if robots.kind(n) == "tree"])
def test_every_shipped_tree_controller_keeps_its_measured_error_and_refinement(robot):
    """On 2,000 held-out goals: each effector's error as a share of its own reach, the median over goals
    and effectors, and the refined answer's worst effector within refine's 0.1 mm."""
    from app.startup import load_pretrained
    from lab.experiments import arms
    from lab.problem.controllers import proposals
    from robots.ik import refine

    most, least = TREE_FIGURES[robot]
    controller, _ = load_pretrained(robot)
    arm = robots.load(robot)
    goals = arms.held_out_goals(arm)
    errors = np.linalg.norm(arm.reach(controller(goals)) - goals, axis=-1)  # (n, E)
    assert errors.shape == (len(goals), arm.n_effectors)
    assert np.median(100 * errors / np.asarray(arm.effector_reach)) <= most
    r = refine(arm, goals, proposals(controller, goals), steps=3)
    worst = np.linalg.norm(arm.reach(r.q) - goals, axis=-1).max(axis=1)
    assert arms.tolerance(arm) == 1e-4 and np.all(r.steps <= 3)
    assert np.mean(worst < 1e-4) >= least, np.mean(worst < 1e-4)


@pytest.mark.parametrize("robot", ["ur5", "panda", "so100"])
def test_a_real_arm_opens_with_its_own_controller_and_a_sensible_pose(robot, tmp_path):
    """python -m app --robot NAME: that arm's shipped controller (never the planar one), and the
    first goal's pose is close: its error is a few % of the arm's reach at most."""
    lab_app = LabApp(port=0, robot=robot, notebook=str(tmp_path / "nb.json"), recordings=str(tmp_path / "rec"),
                     record=False)
    probe = Probe(lab_app.url).start()
    try:
        shown = lab_app.state.shown
        assert shown.arm.name == robot and made_for(shown.controller, shown.arm)
        probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
        session = session_of(lab_app, probe)
        assert wait_until(lambda: np.isfinite(session.goals[0].error))
        if shown.source.startswith("shipped"):
            assert session.goals[0].error < 0.05 * shown.arm.reach_radius
        session.show_ik.value = True  # the classical IK beside it (off on a first visit)
        session._toggle_ik()
        assert wait_until(lambda: session.goals[0].seeded is not None, timeout=30)  # the refined ghost
        assert session.goals[0].seeded[0] <= session.goals[0].error
    finally:
        probe.close()
        lab_app.stop()


def test_robot_switches_from_several_threads_at_once_rebuild_the_scene_cleanly(app):
    """Panel callbacks (viser's thread pool) and the render loop rebuild the shared scene; at the
    same time they must not meet inside viser (a node added twice at once loses its handle)."""
    errors = []

    def switch(names):
        for name in names:
            try:
                app.switch_robot(name)
                app._draw_views()
            except Exception as e:  # noqa: BLE001 - collected and reported below
                errors.append(e)

    threads = [threading.Thread(target=switch, args=(["scara", "planar"] * 6,)) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    app.switch_robot("planar")
    assert not errors, errors[:3]
    assert app.state.arm.name == "planar" and wait_until(lambda: app._drawn[1] is app.state.arm)


def test_neat_from_the_panel_draws_the_growing_network(app):
    panel, state = app.panel, app.state
    panel.method.value = "NEAT"
    assert panel.hidden.value == 0  # NEAT's own default: start without hidden nodes
    panel.generations.value, panel.population.value = 30, 30
    try:
        assert panel.start() is None
        state.runner.join(60)
        assert state.runner.state == "finished" and state.shown.controller.kind == "graph"
        app._draw_views()
        enabled = sum(1 for c in state.shown.controller.genome["connections"] if c[3])
        assert app.network.content.count("<line") == enabled
    finally:
        state.reset()
        panel.method.value = "CMA-ES"
        panel.generations.value, panel.population.value = 1000, 50


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP", "SIGINT"])
def test_every_way_of_stopping_the_app_notes_the_run_and_closes_its_recording(tmp_path, sig):
    """python -m app stopped by a signal during training: the run is in the notebook as stopped,
    its recording reads back with its summary, no traceback, within a few seconds."""
    import signal

    from lab.recording.replay import read_recording

    nb, rec = tmp_path / "nb.db", tmp_path / "rec"
    proc, url = start_app_process("--port", "0", "--notebook", str(nb), "--recordings", str(rec))
    try:
        assert url is not None
        probe = Probe(url).start()
        probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
        probe.click("Start")  # the default planar run: 1000 generations, long enough
        # the writer has started (a name is claimed, empty, at Start; the writer fills it)
        assert wait_until(lambda: any(f.stat().st_size > 0 for f in rec.glob("*.rrd")), timeout=30)
        time.sleep(2.0)  # generations go by
        probe.close()
    finally:
        proc.send_signal(getattr(signal, sig))
        t0 = time.monotonic()
        out, _ = wait_or_kill(proc, 30)
    assert proc.returncode == 0 and time.monotonic() - t0 < 30, out[-3000:]  # a hang guard; the time is measured apart
    assert "Traceback" not in out, out[-3000:]
    entries = Notebook(str(nb)).entries()
    assert len(entries) == 1 and entries[0]["state"] in ("stopped", "finished") and entries[0]["generations"] > 0
    # the writer process finishes the file on its own after the app has gone (it may be behind)
    assert wait_until(lambda: read_recording(entries[0]["recording"]).summary is not None, timeout=30)
    assert read_recording(entries[0]["recording"]).summary["state"] == entries[0]["state"]


def test_reset_shows_an_untrained_network_off_the_goals_and_one_click_the_trained_one(app, tab):
    """The demo's flow: Reset shows the network a new run starts from (its first generation's best,
    far from the goals), Start trains from there, Trained network shows the shipped one again."""
    panel, state = app.panel, app.state
    try:
        trained = state.shown.controller
        panel.buttons["Reset"].value = True
        untrained = state.shown.controller
        assert state.shown.source.startswith("untrained") and untrained is not trained
        config = panel.config()
        problem = lab.Runner(config).problem
        goals = problem.train_goals
        mse = lambda c: float(np.mean(np.sum((state.arm.fk(c(goals))[:, list(state.arm.task_axes)] - goals) ** 2, 1)))  # noqa: E731
        # the same network a run of these settings starts from, and far worse than the trained one
        first = lab.Runner(lab.TrainConfig.from_dict({**config.to_dict(), "generations": 1})).run().controller
        assert untrained.to_dict() == first.to_dict()
        assert mse(untrained) > 100 * mse(trained)
        session = session_of(app, tab)
        assert wait_until(lambda: session.version == state.shown.version)
        reach = state.arm.reach_radius
        assert session.goals[0].error > 0.05 * reach  # visibly off the goal
        panel.buttons["Trained network"].value = True
        assert state.shown.source.startswith("shipped") and state.shown.controller is trained
    finally:
        state.reset()
