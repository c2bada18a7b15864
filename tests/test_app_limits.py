"""Settings a shared server accepts (app/classroom/limits.py): bounded by what one machine can serve a class
with; every arm's and method's defaults fit; `--limit NAME=N` raises one at start."""

from __future__ import annotations

import pytest

import lab
import robots
from app.classroom.limits import CLASSROOM, limits_for, parse_limit, refusal
from app.server import LabApp


@pytest.mark.parametrize("method", lab.methods.names())
def test_every_arms_defaults_fit_the_classroom_bounds(method):
    for robot in robots.names():
        config = lab.TrainConfig.preset(robot=robot, method=method)
        assert refusal(config, CLASSROOM) is None, (robot, method)


def test_the_largest_lab_settings_are_refused_by_a_shared_server():
    big = lab.TrainConfig.preset(robot="planar", population=10_000, hidden=256)
    why = refusal(big, limits_for(False))
    assert "Population must be at most 200" in why and "--limit population=N" in why
    assert refusal(big, limits_for(True)) is None  # loopback: the lab's own bounds
    assert refusal(big, limits_for(False, {"population": 10_000, "hidden": 256})) is None
    assert "Goals must be at most 3,000" in refusal(lab.TrainConfig.preset(robot="planar", targets=5000), CLASSROOM)
    assert "Generations" in refusal(lab.TrainConfig.preset(robot="planar", generations=10**6), CLASSROOM)


@pytest.mark.parametrize("text,why", [("population", "NAME=N"), ("speed=3", "NAME=N"), ("hidden=x", "whole number"),
                                      ("hidden=1000", "1..256"), ("population=0", "1..10,000")])
def test_bad_limits_are_refused_by_name(text, why):
    with pytest.raises(ValueError, match=why):
        parse_limit(text)
    from app.__main__ import main

    assert main(["--limit", text, "--port", "0"]) == 2


def test_a_shared_server_refuses_settings_beyond_its_bounds_in_the_panel_and_at_start(tmp_path):
    app = LabApp(port=0, notebook=str(tmp_path / "nb.db"), recordings=str(tmp_path / "rec"), record=False,
                 limits={"population": 100})
    try:
        assert app.state.limits == {**CLASSROOM, "population": 100}
        app.panel.population.value = 300.0  # as typed in a tab
        assert app.panel.population.value == 50 and "at most 100" in app.panel.message.content
        app.panel.hidden.value = 65.0
        assert app.panel.hidden.value == 5 and "at most 64" in app.panel.message.content
        msg = app.state.start(lab.TrainConfig.preset(robot="planar", population=101, generations=5))
        assert msg and "Population must be at most 100" in msg and not app.state.running
    finally:
        app.stop()


@pytest.mark.parametrize("value,why", [("nan", "whole number"), ("inf", "whole number"), ("-5", "1..1,000,000,000"),
                                       ("0", "1..1,000,000,000"), ("1000000001", "1..1,000,000,000"),
                                       ("1e400", "whole number"), ("10**400", "whole number"),
                                       ("9" * 400, "a number of 400 digits"), ("9" * 5000, "a number of 5,000 digits"),
                                       ("-" + "9" * 5000, "a negative number of 5,000 digits"),
                                       ("abc", "whole number"), ("600.5", "whole number"), ("", "whole number")])
def test_limit_seconds_beyond_its_bound_or_not_a_number_is_refused_by_name_in_one_short_line(value, why, capsys):
    """`--limit seconds=...` with NaN, inf, negative, a number of 5,000 digits (beyond Python's int()), a
    string: refused naming --limit seconds and why, in one line of at most a couple of hundred characters
    (never the whole value given), rc 2."""
    with pytest.raises(ValueError, match=why) as e:
        parse_limit(f"seconds={value}")
    assert str(e.value).startswith("--limit seconds: ") and len(str(e.value)) < 200
    from app.__main__ import main

    assert main(["--limit", f"seconds={value}", "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "--limit seconds" in err and err.count("\n") == 1 and len(err) < 300, err[:500]
    assert parse_limit("seconds=1200") == ("seconds", 1200)


def test_the_time_budget_field_cannot_be_pushed_past_the_servers_limit_over_the_wire(tmp_path, caplog):
    """A shared server (a presenter token, the classroom's bounds: a time budget of at most 600 s): a viewer's
    budget is refused whatever it is; a presenter's beyond 600 s, negative, 2^63, 1e308 is refused by name
    ("Time budget (s)") and the field put back; NaN, inf, strings, None, true never reach the field (the
    message gate drops them, naming the field in the log); a fair one is taken, and a run started with it
    has that budget. No traceback."""
    import logging
    import urllib.parse

    from viser import _messages

    from app.classroom.access import REFUSED
    from app.probe import Probe
    from conftest import make_app, wait_until

    caplog.set_level(logging.WARNING)
    token = "a-Long-Enough-Token_123456"
    app = make_app(tmp_path, presenter_token=token, limits={"seconds": 600})
    tabs = []
    try:
        assert app.state.limits["seconds"] == 600
        app.panel.population.value = 10

        def tab(url):
            probe = Probe(url).start(60)
            tabs.append(probe)
            probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
            return probe

        presenter = tab(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
        viewer = tab(app.url)
        budget = presenter.wait_for(lambda m: m["type"] == "GuiNumberMessage"
                                    and m["props"]["label"] == "Time budget (s)", 60)["uuid"]
        before = app.panel.budget.value

        def told(probe, since, *words):
            return probe.wait_for(lambda m: m["type"].startswith("Notification")
                                  and all(w in str(m) for w in words), 60, since)

        for value in (30, 601, -5, float("nan"), 10**18):
            n = len(viewer.messages)
            viewer.send(_messages.GuiUpdateMessage(uuid=budget, updates={"value": value}))
            told(viewer, n, REFUSED)  # a viewer's change of a shared control: refused before anything else
            assert app.panel.budget.value == before
        for value in (601, 600.001, -5, -1e-9, 2**63 - 1, 1e308):
            n = len(presenter.messages)
            presenter.send(_messages.GuiUpdateMessage(uuid=budget, updates={"value": value}))
            told(presenter, n, "Time budget (s)")
            assert wait_until(lambda: app.panel.budget.value == before, 10), (value, app.panel.budget.value)
        for value in (float("nan"), float("inf"), float("-inf"), "abc", "1e400", None, True, [600]):
            presenter.send(_messages.GuiUpdateMessage(uuid=budget, updates={"value": value}))
        assert app.panel.seconds() in (None, before)
        with pytest.raises((OverflowError, TypeError, ValueError)):  # 10**400 cannot even be sent: msgpack
            presenter.send(_messages.GuiUpdateMessage(uuid=budget, updates={"value": 10**400}))
        presenter.send(_messages.GuiUpdateMessage(uuid=budget, updates={"value": 45}))  # a fair one
        assert wait_until(lambda: app.panel.budget.value == 45, 20)
        assert app.panel.budget.value == 45 and app.panel.seconds() == 45.0
        assert any("Time budget (s)" in r.getMessage() and "invalid message" in r.getMessage()
                   for r in caplog.records)
        presenter.click("Start")
        assert wait_until(lambda: app.state.running, 60)
        assert app.state.runner.config.seconds == 45.0
        app.state.stop()
        assert wait_until(lambda: not app.state.running, 60)
        # the start path checks it too (a budget the field never showed)
        msg = app.state.start(lab.TrainConfig.preset(robot="planar", seconds=601.0))
        assert msg and "Time budget (s) must be at most 600" in msg and not app.state.running
        assert "Traceback" not in caplog.text, caplog.text[-3000:]
    finally:
        for probe in tabs:
            probe.close()
        if app.state.running:
            app.state.reset()
        app.stop()
