"""Presenter and viewers (app/classroom/access.py), tried as a hostile student would: with headless tabs
(app/probe.py) on a server restricted by a presenter token, a viewer's Start, Stop, settings,
robot and uploads change nothing; the presenter's do. Real browser tabs: tests/test_app_browser.py."""

from __future__ import annotations

import sqlite3
import time

import pytest
from viser import _messages

from app.classroom.access import REFUSED, Access, is_loopback
from app.server import LabApp
from conftest import tab_of, wait_or_kill, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
TOKEN = "s3cret-Token_1"


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    folder = tmp_path_factory.mktemp("access")
    lab_app = LabApp(port=0, notebook=str(folder / "notebook.db"), recordings=str(folder / "rec"),
                     presenter_token=TOKEN)
    lab_app.panel.generations.value, lab_app.panel.population.value = 100_000, 10
    yield lab_app
    if lab_app.state.running:
        lab_app.state.reset()
    lab_app.stop()


@pytest.fixture
def presenter(app):
    ws = app.presenter_url.split("websocket=")[1]
    import urllib.parse

    probe = tab_of(urllib.parse.unquote(ws))
    yield probe
    probe.close()


@pytest.fixture
def viewer(app):
    probe = tab_of(app.url)
    yield probe
    probe.close()



def gui_uuid(probe, label):
    return probe.wait_for(lambda m: m["type"].startswith("Gui") and m.get("props", {}).get("label") == label)["uuid"]


def refused(probe, since=0):
    return probe.wait_for(lambda m: m["type"].startswith("Notification") and REFUSED in str(m), 10, since)


def test_who_is_restricted():
    assert not Access("127.0.0.1").restricted and Access("127.0.0.1").token is None
    assert Access("127.0.0.1", "tok").restricted
    a, b = Access("0.0.0.0"), Access("0.0.0.0")
    assert a.restricted and a.token and a.token != b.token and len(a.token) >= 20
    assert not Access("0.0.0.0", open=True).restricted
    assert is_loopback("::1") and is_loopback("localhost") and not is_loopback("192.168.1.5")
    assert TOKEN not in repr(Access("0.0.0.0", TOKEN))
    with pytest.raises(ValueError):
        Access("0.0.0.0", "a&b")


def test_a_viewer_cannot_start_stop_or_change_settings_and_the_presenter_can(app, presenter, viewer):
    assert wait_until(lambda: len(app.sessions) >= 2)
    # the viewer is told, and sees the shared controls disabled in its own tab only
    viewer.wait_for(lambda m: m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m))
    start_uuid = gui_uuid(viewer, "Start")
    viewer.wait_for(lambda m: m["type"] == "GuiUpdateMessage" and m["uuid"] == start_uuid
                    and m["updates"].get("disabled") is True)
    assert not any(m["type"] == "GuiUpdateMessage" and m["updates"].get("disabled") is True
                   for _t, m in presenter.messages)
    assert not any(m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m) for _t, m in presenter.messages)

    viewer.click("Start")
    refused(viewer)
    time.sleep(0.5)
    assert not app.state.running

    population = gui_uuid(viewer, "Population")
    n = len(viewer.messages)
    viewer.send(_messages.GuiUpdateMessage(uuid=population, updates={"value": 10_000.0}))
    refused(viewer, n)
    assert app.panel.population.value == 10  # never applied, never echoed
    viewer.wait_for(lambda m: m["type"] == "GuiUpdateMessage" and m["uuid"] == population
                    and m["updates"].get("value") == 10, 10, n)  # its widget is put back
    assert not any(m["type"] == "GuiUpdateMessage" and m.get("uuid") == population
                   and m["updates"].get("value") == 10_000.0 for _t, m in presenter.messages)

    robot = gui_uuid(viewer, "Robot")
    viewer.send(_messages.GuiUpdateMessage(uuid=robot, updates={"value": "ur5"}))
    time.sleep(0.5)
    assert app.state.arm.name == "planar"

    presenter.click("Start")
    assert wait_until(lambda: app.state.progress()["generation"] >= 3)
    for label in ("Pause", "Stop", "Reset"):
        viewer.click(label)
    time.sleep(1.0)
    assert app.state.running and app.state.runner.state == "running"
    presenter.click("Stop")
    assert wait_until(lambda: not app.state.running)


def test_a_viewer_cannot_upload(app, viewer):
    button = viewer.wait_for(lambda m: m["type"] == "GuiUploadButtonMessage")["uuid"]
    viewer.send(_messages.FileTransferStartUpload(source_component_uuid=button, transfer_uuid="v1", filename="x.rrd",
                                                  mime_type="x", part_count=1, size_bytes=10))
    refused(viewer)
    from app import viser_private

    assert viser_private.buffered_uploads(app.server) == {}


def test_a_wrong_or_missing_token_is_a_viewer(app):
    for url in (app.url + "/?token=wrong", app.url + "/?token=", app.url + f"/?token={TOKEN}x"):
        probe = tab_of(url)
        try:
            probe.wait_for(lambda m: m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m))
        finally:
            probe.close()


def test_the_token_is_never_written_to_the_notebook_or_recordings(app, presenter):
    presenter.click("Start")
    assert wait_until(lambda: app.state.running and app.state.progress()["generation"] >= 3)
    recording = app.state.recording
    presenter.click("Stop")
    assert wait_until(lambda: not app.state.running)
    time.sleep(1.0)
    con = sqlite3.connect(app.state.notebook.path)
    dump = "\n".join(con.iterdump())
    con.close()
    assert "run" in dump.lower() and TOKEN not in dump
    import os

    assert recording and wait_until(lambda: os.path.exists(recording), 30)
    assert TOKEN.encode() not in open(recording, "rb").read()


def test_on_loopback_without_a_token_every_tab_is_a_presenter(tmp_path):
    app = LabApp(port=0, notebook=str(tmp_path / "nb.db"), recordings=str(tmp_path / "rec"), record=False)
    try:
        assert not app.access.restricted and app.presenter_url == app.url
        probe = tab_of(app.url)
        try:
            assert app.access.is_presenter(int(probe.owner("/tab/goal0/marker")))
        finally:
            probe.close()
    finally:
        app.stop()


def test_python_m_app_beyond_loopback_prints_a_presenter_link_that_makes_a_presenter(tmp_path, capsys):
    import signal
    import subprocess
    import sys
    import urllib.parse

    from app.__main__ import main

    assert main(["--open", "--presenter-token", "x", "--port", "0"]) == 2
    assert "contradict" in capsys.readouterr().err
    assert main(["--presenter-token", "a b", "--port", "0"]) == 2
    assert "--presenter-token" in capsys.readouterr().err
    proc = subprocess.Popen([sys.executable, "-m", "app", "--host", "0.0.0.0", "--port", "0", "--no-record",
                             "--notebook", str(tmp_path / "nb.db")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        link = None
        for line in proc.stdout:
            if "presenter link on this machine:" in line:
                link = line.rsplit(" ", 1)[-1].strip()
                break
        assert link and "websocket=" in link
        ws = urllib.parse.unquote(link.split("websocket=")[1])
        token = ws.split("token=")[1]
        assert len(token) >= 20
        for url, role in ((ws, "presenter"), (ws.split("?")[0], "viewer")):
            probe = tab_of(url)
            try:
                time.sleep(1.5)
                viewer_line = any(m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m) for _t, m in probe.messages)
                assert viewer_line == (role == "viewer"), role
            finally:
                probe.close()
    finally:
        proc.send_signal(signal.SIGINT)
        wait_or_kill(proc, 30)


def test_a_viewer_replays_a_run_in_its_own_tab_only(app, presenter, viewer):
    import numpy as np

    from app.training.notebook import label
    from lab.recording.replay import load_controller

    if not any(e.get("recording") for e in app.state.notebook.entries()):  # a run with a recording
        presenter.click("Start")
        assert wait_until(lambda: app.state.running and app.state.progress()["generation"] >= 3)
        presenter.click("Stop")
        assert wait_until(lambda: not app.state.running)
    viewer.wait_for(lambda m: m["type"] == "GuiFolderMessage" and m["props"]["label"] == "Replay (this tab)")
    assert not any(m["type"] == "GuiFolderMessage" and m["props"]["label"] == "Replay (this tab)"
                   for _t, m in presenter.messages)
    entry = next(e for e in reversed(app.state.notebook.entries()) if e.get("recording"))
    assert wait_until(lambda: __import__("os").path.exists(entry["recording"]), 30)
    app.runs.refresh(force=True)
    vid, pid = int(viewer.owner("/tab/goal0/marker")), int(presenter.owner("/tab/goal0/marker"))
    assert wait_until(lambda: vid in app.sessions and pid in app.sessions)
    mine, theirs = app.sessions[vid], app.sessions[pid]
    shared = app.state.shown.version
    assert mine.replay.open(label(entry)) is None
    assert app.state.shown.version == shared and not app.state.replaying  # nobody else's view changed
    assert "this tab" in mine.shown.source and theirs.shown is app.state.shown
    goal = mine.goals[0].goal
    mine.replay.slider.value = 2  # scrub to generation 2 (as the viewer's slider would)
    expected = load_controller(entry["recording"], 1)
    assert np.allclose(mine.controller()(goal[None]), expected(goal[None]))
    mine.replay.live()
    assert mine.shown is app.state.shown


def test_a_viewer_cannot_open_a_public_share_tunnel(app, viewer, presenter, monkeypatch):
    """viser's titlebar 'share' button asks the server for a public URL (a tunnel through
    share.viser.studio): from a viewer, the request never reaches viser."""
    asked = []
    monkeypatch.setattr(app.server, "request_share_url", lambda *a, **k: asked.append(1))
    monkeypatch.setattr(app.server, "disconnect_share_url", lambda *a, **k: asked.append(0))
    viewer.send(_messages.ShareUrlRequest())
    viewer.send(_messages.ShareUrlDisconnect())
    time.sleep(1.0)
    assert asked == []
    presenter.send(_messages.ShareUrlRequest())  # the presenter may (the lab never asks by itself)
    assert wait_until(lambda: asked == [1], 10)



def test_invalid_values_to_any_control_are_dropped_and_logged_once_per_tab(app, presenter, viewer, caplog):
    """A tab (a viewer too) sending 500 invalid values to its own controls and to shared ones: each is
    dropped before viser applies it, one log line per tab, no "Task exception was never retrieved", and
    a good message still works afterwards."""
    import logging

    caplog.set_level(logging.WARNING)
    assert wait_until(lambda: len(app.sessions) >= 2)
    viewer_id = max(app.sessions)
    ghosts = gui_uuid(viewer, "Classical IK beside it")
    session = app.sessions[viewer_id]
    assert ghosts in session.client.gui._gui_input_handle_from_uuid  # a per-tab control
    slider = session.replay.slider._impl.uuid  # the viewer's own replay slider
    assert slider in session.client.gui._gui_input_handle_from_uuid
    population = gui_uuid(presenter, "Population")
    bads = [{"value": float("nan")}, {"value": "abc"}, {"color": "red"}, {"value": [1, 2]}, {"value": None},
            {"value": float("inf")}, {"bogus": 1, "value": True}]
    for k in range(500):
        viewer.send(_messages.GuiUpdateMessage(uuid=(ghosts, slider)[k % 2], updates=bads[k % len(bads)]))
        presenter.send(_messages.GuiUpdateMessage(uuid=population, updates=bads[k % len(bads)]))
    time.sleep(1.0)
    assert app.panel.population.value == 10 and session.show_ik.value is False
    assert session.replay.slider.value == 0
    # a good message still works, in both tabs
    viewer.send(_messages.GuiUpdateMessage(uuid=ghosts, updates={"value": True}))
    assert wait_until(lambda: session.show_ik.value is True, 10)
    presenter.send(_messages.GuiUpdateMessage(uuid=population, updates={"value": 12}))
    assert wait_until(lambda: app.panel.population.value == 12, 10)
    app.panel.population.value = 10
    text = caplog.text
    assert "Task exception was never retrieved" not in text and "Traceback" not in text, text[-3000:]
    lines = [r.getMessage() for r in caplog.records if "invalid message" in r.getMessage()]
    assert 1 <= len(lines) <= 2, lines  # one per tab (the viewer's and the presenter's)
    assert len(caplog.records) <= 4, [r.getMessage() for r in caplog.records][:10]


def test_wrong_tokens_are_logged_by_address_and_limited_per_address(app, caplog):
    """Every wrong try is logged with the tab's address (never the token): the first 5 from an address
    within a minute one line each, the others one line a minute with their count; the right token is
    always compared and always makes a presenter, however many wrong tries came before from its
    address (a class behind one NAT shares the teacher's address)."""
    import logging
    import urllib.parse

    from app.classroom import access as access_module

    caplog.set_level(logging.WARNING, logger="app.classroom.access")
    now = [1000.0]
    app.access.clock, app.access._wrong, app.access._quiet = (lambda: now[0]), {}, {}
    right = urllib.parse.unquote(app.presenter_url.split("websocket=")[1])

    def role(url):
        probe = tab_of(url)
        try:
            return app.access.is_presenter(int(probe.owner("/tab/goal0/marker")))
        finally:
            probe.close()

    try:
        assert not any(role(app.url + f"/?token=guess{k}") for k in range(access_module.MAX_WRONG + 3))
        assert role(right)  # compared, and right: a presenter
        lines = [r.getMessage() for r in caplog.records]
        wrong = [m for m in lines if "wrong token from 127.0.0.1" in m]
        assert len(wrong) == access_module.MAX_WRONG + 1, lines  # 5 one by one, then one line for the others
        assert "more than 5 wrong tries" in wrong[-1] and "more not logged" not in wrong[-1]
        assert not any(TOKEN in m or "guess" in m for m in lines)
        assert not role(app.url + "/?token=guess-again")  # within the minute: counted, not logged
        assert len(caplog.records) == len(lines)
        now[0] += access_module.WRONG_WINDOW / 2
        assert not role(app.url + "/?token=guess-later") and len(caplog.records) == len(lines)
        assert role(right)
        now[0] += access_module.WRONG_WINDOW / 2 + 1  # a minute after the last line: one line with the count
        assert not role(app.url + "/?token=guess-last")
        assert "4 more not logged" in caplog.records[-1].getMessage(), caplog.records[-1].getMessage()
    finally:
        app.access.clock, app.access._wrong, app.access._quiet = time.monotonic, {}, {}


def test_wrong_tokens_from_the_presenters_address_never_lock_the_presenter_out(tmp_path, caplog):
    """A token from a file; six tabs with wrong tokens from 127.0.0.1 (the
    presenter's own address); then the presenter link makes a presenter (no Viewer line) and its
    Start and Reset are accepted."""
    import logging
    import urllib.parse

    from app.__main__ import parse, presenter_token
    from conftest import make_app

    caplog.set_level(logging.WARNING, logger="app.classroom.access")
    good = "a-Long-Enough-Token_123456"
    (tmp_path / "TOK").write_text(good + "\n")
    token, _warning = presenter_token(parse(["--presenter-token-file", str(tmp_path / "TOK")]))
    lab_app = make_app(tmp_path, presenter_token=token)
    try:
        lab_app.panel.generations.value, lab_app.panel.population.value = 100_000, 10
        for i in range(6):
            probe = tab_of(lab_app.url + f"/?token=wrong-{i}-xxxxxxxxxxxxxxxxxxxxxx")
            probe.wait_for(lambda m: m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m))
            probe.close()
        assert sum("wrong token from 127.0.0.1" in r.getMessage() for r in caplog.records) == 6
        presenter = tab_of(urllib.parse.unquote(lab_app.presenter_url.split("websocket=")[1]))
        try:
            assert lab_app.access.is_presenter(int(presenter.owner("/tab/goal0/marker")))
            presenter.click("Start")
            assert wait_until(lambda: lab_app.state.running and lab_app.state.progress()["generation"] >= 2, 60)
            presenter.click("Reset")
            assert wait_until(lambda: not lab_app.state.running, 60)
            assert not any(m["type"] == "GuiMarkdownMessage" and "Viewer" in str(m) for _t, m in presenter.messages)
            assert not any(m["type"].startswith("Notification") and REFUSED in str(m) for _t, m in presenter.messages)
        finally:
            presenter.close()
    finally:
        if lab_app.state.running:
            lab_app.state.reset()
        lab_app.stop()


def test_tabs_sending_garbage_frames_are_closed_with_one_log_line_and_no_traceback(app, presenter, caplog):
    """A frame that is not a viser message (not msgpack, a text frame, msgpack of no known
    type) closes its tab, as before, but 20 such tabs give at most a couple of log lines (one a minute,
    with the count), no websockets "connection handler failed" traceback; the server forgets the
    closed tabs, and a good tab still works."""
    import asyncio
    import logging

    import msgspec

    caplog.set_level(logging.WARNING)  # websockets' traceback is an ERROR record
    garbage = [b"\xc1\xc1 not msgpack", "a text frame", msgspec.msgpack.encode({"type": "NoSuchMessage"}),
               msgspec.msgpack.encode([1, 2, 3]), b"\x91" * 10_000]
    tabs = [tab_of(app.url) for _ in range(20)]
    ids = {int(tab.owner("/tab/goal0/marker")) for tab in tabs}
    assert len(ids) == 20 and wait_until(lambda: ids <= set(app.sessions), 60)
    for k, tab in enumerate(tabs):
        asyncio.run_coroutine_threadsafe(tab._ws.send(garbage[k % len(garbage)]), tab._loop).result(10)
    try:
        assert wait_until(lambda: not ids & set(app.sessions), 60), ids & set(app.sessions)  # closed, forgotten
        for tab in tabs:
            assert wait_until(lambda: tab._ws.close_code is not None, 30)
            assert tab._ws.close_code in (1003, 1007), tab._ws.close_code
    finally:
        for tab in tabs:
            tab.close()
    text = caplog.text
    assert "connection handler failed" not in text and "Traceback" not in text, text[-3000:]
    lines = [r.getMessage() for r in caplog.records if "not a viser message" in r.getMessage()]
    assert 1 <= len(lines) <= 2, lines
    assert len(caplog.records) <= 5, [r.getMessage() for r in caplog.records][:10]
    population = gui_uuid(presenter, "Population")  # a good tab still works
    presenter.send(_messages.GuiUpdateMessage(uuid=population, updates={"value": 12}))
    assert wait_until(lambda: app.panel.population.value == 12, 10)
    app.panel.population.value = 10


def test_a_short_presenter_token_is_refused_and_one_can_come_from_a_file_or_the_environment(tmp_path, capsys,
                                                                                             monkeypatch):
    from app.__main__ import TOKEN_ENV, main, parse, presenter_token

    monkeypatch.delenv(TOKEN_ENV, raising=False)
    assert main(["--presenter-token", "a", "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "at least 16" in err and "ps" in err  # refused, and told it shows in ps
    good = "a-Long-Enough-Token_123"
    (tmp_path / "token").write_text(good + "\n")
    assert presenter_token(parse(["--presenter-token-file", str(tmp_path / "token")])) == (good, None)
    assert capsys.readouterr().err == ""  # no warning: nothing in ps
    (tmp_path / "short").write_text("abc\n")
    assert main(["--presenter-token-file", str(tmp_path / "short"), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--presenter-token-file" in err and "at least 16" in err
    assert main(["--presenter-token-file", str(tmp_path / "missing"), "--port", "0"]) == 2
    assert "missing" in capsys.readouterr().err
    monkeypatch.setenv(TOKEN_ENV, good)
    assert presenter_token(parse([])) == (good, None)
    monkeypatch.setenv(TOKEN_ENV, "short")
    assert main(["--port", "0"]) == 2
    assert TOKEN_ENV in capsys.readouterr().err
    assert presenter_token(parse(["--presenter-token", good])) == (good, None)  # still works, with a warning
    assert "ps" in capsys.readouterr().err
