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
    assert "population must be at most 200" in why and "--limit population=N" in why
    assert refusal(big, limits_for(True)) is None  # loopback: the lab's own bounds
    assert refusal(big, limits_for(False, {"population": 10_000, "hidden": 256})) is None
    assert "training goals" in refusal(lab.TrainConfig.preset(robot="planar", targets=5000), CLASSROOM)
    assert "generations" in refusal(lab.TrainConfig.preset(robot="planar", generations=10**6), CLASSROOM)


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
        assert msg and "population must be at most 100" in msg and not app.state.running
    finally:
        app.stop()
