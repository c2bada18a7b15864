"""One gate for every value a tab sends (app/viser_private.py install_message_gate; issue #55, 3 and 4).

A headless tab (app/probe.py) sends every GUI element it was given a value outside that element's
domain (a dropdown's value not among its options, NaN, infinities and numbers beyond a slider's
range, a string to a checkbox, a button released, a property that is not a value), and every one
of its goal gizmos an orientation that is no rotation ((NaN, 0, 0, 0), (0, 0, 0, 0), (inf, 0, 0, 0))
or a position that is not a point, and a camera that is not finite; from a presenter tab and from a
viewer tab, in position mode and in pose mode. Nothing may reach a callback or the render loop: no
traceback anywhere (log, stdout, stderr), the shared settings unchanged, each tab told in one line,
and the render loop still serving a good drag afterwards. Before the gate a dropdown's value was checked for its type
only and a gizmo's not at all: StopIteration and KeyError tracebacks from the callbacks, and one
gizmo message made the render loop log a traceback 30 times a second.
"""

from __future__ import annotations

import logging
import math
import urllib.parse

import numpy as np
import pytest
from viser import _messages

from conftest import make_app, session_of, tab_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
TOKEN = "s3cret-Token_1"
NAN, INF = float("nan"), float("inf")
# the last one of each list stays in a gizmo unless the gate drops it: (NaN, 0, 0, 0), as a probe sent
BAD_WXYZ = [(0.0, 0.0, 0.0, 0.0), (INF, 0.0, 0.0, 0.0), (1.0, NAN, 0.0, 0.0), (-INF, INF, 0.0, 0.0),
            (1e300, 1e300, 0.0, 0.0), (NAN, 0.0, 0.0, 0.0)]
CAMERA = dict(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -3.0, 2.0), fov=1.0, near=0.01, far=1000.0,
              image_height=800, image_width=1280, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0))
BAD_POSITIONS = [(NAN, 0.0, 0.0), (0.0, INF, 0.0), (0.0, 0.0, -INF), (1e300, 0.0, 0.0)]


@pytest.fixture(scope="module", params=["position", "pose"])
def app(request, tmp_path_factory):
    robot = "planar" if request.param == "position" else "ur5"  # pose goals: a real arm
    lab_app = make_app(tmp_path_factory.mktemp(f"gate-{request.param}"), presenter_token=TOKEN, robot=robot,
                       goal=request.param)
    yield lab_app
    if lab_app.state.running:
        lab_app.state.reset()
    lab_app.stop()


def presenter_of(app):
    return tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))


def elements(probe) -> dict[str, dict]:
    """uuid -> the message that made it, of every GUI input element (a value, or a button) the tab has."""
    return {m["uuid"]: m for _t, m in list(probe.messages)
            if m["type"].startswith("Gui") and m["type"] != "GuiUpdateMessage" and "props" in m
            and ("value" in m or m["type"] in ("GuiButtonMessage", "GuiUploadButtonMessage"))}


def bad_updates(m: dict) -> list[dict]:
    """Updates outside the domain of the element `m` made (whatever its kind)."""
    props, value = m["props"], m.get("value")
    bads = [{"bogus": 1}, {"value": None}, {"value": [1, "x"]}, {"value": {"a": 1}}]
    if props.get("options"):
        bads += [{"value": "No such"}, {"value": "warp"}, {"value": 5}, {"value": ""}]
    if isinstance(value, bool):
        bads += [{"value": "abc"}, {"value": 1}]
    elif isinstance(value, (int, float)):
        bads += [{"value": v} for v in (NAN, INF, -INF, "abc", True)]
        lo, hi = props.get("min"), props.get("max")
        bads += [{"value": lo - 1e6}] if isinstance(lo, (int, float)) else []
        bads += [{"value": hi + 1e6}] if isinstance(hi, (int, float)) else []
    elif isinstance(value, str):
        bads += [{"value": 5}, {"value": "x" * 20_001}]
    elif isinstance(value, list):
        n = len(value)
        bads += [{"value": [NAN] * n}, {"value": [INF] * n}, {"value": [1e9] * n}, {"value": [-1e9] * n},
                 {"value": [0] * (n + 1)}]
    if m["type"] == "GuiButtonMessage":
        bads += [{"value": False}, {"value": "abc"}]
    return bads


def gizmos(probe) -> dict[str, dict]:
    """name -> the TransformControlsMessage of each gizmo of the tab (its own goals)."""
    return {m["name"]: m for _t, m in list(probe.messages) if m["type"] == "TransformControlsMessage"}


def shared_settings(app) -> dict:
    panel = app.panel
    return {name: getattr(panel, name).value for name in ("robot", "goal", "method", "population", "generations")}


def test_no_value_outside_its_domain_reaches_a_callback_or_breaks_the_render_loop(app, caplog, capfd):
    caplog.set_level(logging.WARNING)
    presenter, viewer = presenter_of(app), tab_of(app.url)
    try:
        assert wait_until(lambda: len(app.sessions) >= 2, 60)
        sessions = {name: session_of(app, probe) for name, probe in (("presenter", presenter), ("viewer", viewer))}
        assert sessions["presenter"].presenter and not sessions["viewer"].presenter
        before = shared_settings(app)
        sent = 0
        for probe in (presenter, viewer):
            found = elements(probe)
            kinds = {m["type"] for m in found.values()}
            assert {"GuiDropdownMessage", "GuiNumberMessage", "GuiCheckboxMessage", "GuiButtonMessage"} <= kinds, kinds
            for uuid, m in found.items():
                for updates in bad_updates(m):
                    probe.send(_messages.GuiUpdateMessage(uuid=uuid, updates=updates))
                    sent += 1
            marks = gizmos(probe)
            assert "/tab/goal0/marker" in marks
            for name, m in marks.items():
                owner = m.get("owner", "")
                good_wxyz, good_position = (1.0, 0.0, 0.0, 0.0), (0.1, 0.1, 0.0)
                for position in BAD_POSITIONS:
                    probe.send(_messages.TransformControlsUpdateMessage(name=name, wxyz=good_wxyz, position=position,
                                                                        owner=owner))
                for wxyz in BAD_WXYZ:
                    probe.send(_messages.TransformControlsUpdateMessage(name=name, wxyz=wxyz, position=good_position,
                                                                        owner=owner))
                sent += len(BAD_WXYZ) + len(BAD_POSITIONS)
            for bad in (dict(fov=NAN), dict(position=(INF, 0.0, 0.0)), dict(wxyz=(NAN, 0.0, 0.0, 0.0))):
                probe.send(_messages.ViewerCameraMessage(**{**CAMERA, **bad}))
        assert sent > 300, sent
        passes = app.passes
        assert wait_until(lambda: app.passes >= passes + 60, 60)  # two seconds of the render loop, at least
        # nothing was applied: the shared settings are as they were, every goal a pose, every camera finite
        assert shared_settings(app) == before
        for s in sessions.values():
            assert np.all(np.isfinite(s.client.camera.position)) and np.isfinite(s.client.camera.fov)
            for g in s.goals:
                assert np.all(np.isfinite(g.query)), g.query
                for marker in g.markers:
                    assert abs(np.linalg.norm(marker.wxyz) - 1.0) < 1e-6, marker.wxyz
        # each tab was told, in one line (the gate says it at most once a minute per tab)
        for probe in (presenter, viewer):
            told = [m for _t, m in list(probe.messages)
                    if m["type"] == "NotificationShowMessage" and "Not applied" in str(m)]
            assert len(told) == 1, told
        # the render loop and the drags still serve both tabs
        for probe, s in ((presenter, sessions["presenter"]), (viewer, sessions["viewer"])):
            marker = s.goals[0].marker
            to = np.asarray(marker.position, float) + 0.01 * np.eye(3)[s.arm.task_axes[0]]
            probe.drag("/tab/goal0/marker", tuple(to), wxyz=tuple(np.asarray(marker.wxyz, float)), timeout=20)
            assert wait_until(lambda: np.allclose(marker.position, to), 10)
        passes = app.passes
        assert wait_until(lambda: app.passes >= passes + 10, 30)
        out = capfd.readouterr()
        text = caplog.text + out.out + out.err
        assert "Traceback" not in text and "Task exception was never retrieved" not in text, text[-4000:]
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text[-3000:]
        dropped = [r.getMessage() for r in caplog.records if "invalid message" in r.getMessage()]
        assert 1 <= len(dropped) <= 2, dropped  # one line per tab in a minute, the rest counted
    finally:
        presenter.close()
        viewer.close()


def test_a_tab_that_fails_in_the_render_loop_is_logged_once_and_reset_and_the_others_are_served(app, caplog):
    """Whatever one tab holds, the render loop's pass goes on for the others: that tab's failure is
    logged with its traceback once (then counted, not once a pass), and the tab is reset (its goals
    rebuilt at their defaults) and told."""
    caplog.set_level(logging.WARNING)
    bad_tab, good_tab = tab_of(app.url), tab_of(app.url)
    try:
        bad, good = session_of(app, bad_tab), session_of(app, good_tab)
        calls = {"bad": 0, "good": 0, "build": 0}
        good_refresh, bad_build = good.refresh, bad.build

        def broken():
            calls["bad"] += 1
            raise FloatingPointError("a goal that is no pose")

        def counted():
            calls["good"] += 1
            return good_refresh()

        def rebuilt():
            calls["build"] += 1
            bad_build()

        bad.refresh, good.refresh, bad.build = broken, counted, rebuilt  # this tab's redraw fails on every pass
        goals = list(bad.goals)
        assert wait_until(lambda: calls["bad"] >= 60 and calls["good"] >= 60, 60), calls
        bad.refresh, good.refresh = good_refresh, good_refresh
        failed = [r for r in caplog.records if r.name == "app.server"]
        assert len(failed) == 1 and failed[0].exc_info is not None, [r.getMessage() for r in failed]
        assert f"tab {bad.client.client_id}" in failed[0].getMessage()
        assert "Traceback" in caplog.text and caplog.text.count("Traceback") == 1
        assert 1 <= calls["build"] <= math.ceil(calls["bad"] / 30 / 5) + 1, calls  # reset, at most every 5 s
        assert bad.goals and all(g not in goals for g in bad.goals)  # rebuilt: new goals at their defaults
        bad_tab.wait_for(lambda m: m["type"] == "NotificationShowMessage" and "Reset" in str(m), 10)
        assert not any(m["type"] == "NotificationShowMessage" and "Reset" in str(m) for _t, m in good_tab.messages)
    finally:
        bad_tab.close()
        good_tab.close()
