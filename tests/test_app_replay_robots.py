"""A recording of one arm replayed in a lab that shows another: a planar recording uploaded into a g1
lab. The presenter's upload switches the lab to the planar arm and replays the recording's controller
there, and says so; while a g1 run is going it is refused by name and nothing changes; a file whose
controller is not of the arm it names is refused before anything switches; a viewer's own replay,
which cannot switch the shared scene, names both arms."""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest
import rerun as rr

import lab
from app.training.notebook import label
from conftest import make_app, wait_until
from lab.recording.replay import load_controller, read_recording

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
PLANAR = "planar-cmaes-s0.rrd"
TOKEN = "presenter-token-of-this-test-0123456789"


@pytest.fixture(scope="module")
def root():
    from pathlib import Path

    return Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def app(tmp_path_factory, root):
    folder = tmp_path_factory.mktemp("replay-robots")
    (folder / "rec").mkdir()
    shutil.copy(root / "recordings" / "examples" / PLANAR, folder / "rec" / PLANAR)  # in the runs list
    lab_app = make_app(folder, robot="g1", presenter_token=TOKEN)
    yield lab_app
    lab_app.stop()


@pytest.fixture
def g1(app):
    if app.state.running:
        app.state.reset()
    app.runs.live()
    assert app.switch_robot("g1") is None
    return app


def test_a_viewers_own_replay_of_a_planar_run_in_a_g1_lab_names_both_arms(g1):
    from app.probe import Probe

    app = g1
    viewer = Probe(app.url).start(60)  # no token: a viewer, with its own "Replay (this tab)"
    try:
        viewer.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
        assert wait_until(lambda: any(not s.presenter for s in list(app.sessions.values())), 60)
        session = next(s for s in list(app.sessions.values()) if not s.presenter)
        app.runs.refresh(force=True)
        said = session.replay.open(f"file: {PLANAR}")
        assert said == ("refused: this run is of the planar arm and the presenter shows the g1 arm: it replays "
                        "in this tab once the presenter shows the planar arm")
        assert session.own is None and session.replay.message.content == said and app.state.arm.name == "g1"
    finally:
        viewer.close()


def _recording_naming(path, robot: str, source) -> None:
    """A recording whose /protocol names `robot` and whose controllers are those of `source`."""
    rec = read_recording(source)
    stream = rr.RecordingStream("neuro-ik-lab")
    stream.save(str(path))
    stream.log("protocol", rr.TextDocument(json.dumps({**rec.protocol, "robot": robot,
                                                       "config": {**rec.protocol["config"], "robot": robot}})),
               static=True)
    for g, doc in rec.controllers[-2:]:
        stream.set_time("generation", sequence=g)
        stream.log("controller", rr.TextDocument(json.dumps(doc)))
        stream.log("mse", rr.Scalars([doc["best_mse"], doc["best_mse"]]))
    stream.flush()
    rr.disconnect(stream)


def test_a_recording_whose_controller_is_not_of_the_arm_it_names_is_refused_before_anything_switches(g1, tmp_path, root):
    app = g1
    path = tmp_path / "says-ur5.rrd"
    _recording_naming(path, "ur5", root / "recordings" / "examples" / PLANAR)
    assert read_recording(path).protocol["robot"] == "ur5"
    version = app.state.shown.version
    said = app.runs.open_upload("says-ur5.rrd", path.read_bytes())
    assert said.startswith("refused: this run names the ur5 arm, but its controller was not made for it")
    assert "nothing was changed" in said
    assert app.state.arm.name == "g1" and app.state.shown.version == version and not app.state.replaying


def test_a_planar_upload_while_a_g1_run_goes_is_refused_by_name_and_the_run_goes_on(g1, root):
    app = g1
    config = lab.TrainConfig(robot="g1", generations=10**6, population=10, targets=10, test_goals=10)
    assert app.state.start(config) is None
    try:
        assert wait_until(lambda: app.state.running, 120)
        said = app.runs.open_upload(PLANAR, (root / "recordings" / "examples" / PLANAR).read_bytes())
        assert said.startswith("refused: this run is of the planar arm and the lab shows the g1 arm, which it "
                               "cannot leave now: a g1 run is going; stop it before changing the robot"), said
        assert app.state.arm.name == "g1" and app.state.running and not app.state.replaying
        assert "refused" in app.runs.message.content
    finally:
        app.state.reset()
        assert wait_until(lambda: not app.state.running, 120)


def test_a_planar_upload_into_a_g1_lab_switches_to_the_planar_arm_and_replays_the_recording(g1, root):
    from app.probe import Probe

    app = g1
    presenter = Probe(app.url + f"/?token={TOKEN}").start(60)
    try:
        presenter.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
        assert wait_until(lambda: any(s.presenter for s in list(app.sessions.values())), 60)
        session = next(s for s in list(app.sessions.values()) if s.presenter)
        path = root / "recordings" / "examples" / PLANAR
        assert app.runs.open_upload("from a student.rrd", path.read_bytes(), session.client) is None
        assert app.state.arm.name == "planar" and app.state.replaying
        said = "This run is of the planar arm: the lab now shows the planar arm (it showed the g1)."
        assert app.runs.message.content.startswith(said)
        presenter.wait_for(lambda m: m["type"].startswith("Notification") and said in str(m), 30)
        goals = app.state.arm.sample_goals(20, seed=5)
        assert np.array_equal(app.state.shown.controller(goals), load_controller(path)(goals))
        # the tab's scene follows: the planar arm, its goal reached by the replayed controller (not garbage)
        assert wait_until(lambda: session.arm is app.state.arm and session.version == app.state.shown.version
                          and session.goals and np.isfinite(session.goals[0].error), 60)
        assert session.goals[0].error < 0.05 * app.state.arm.reach_radius
        app.runs.refresh(force=True)
        rec_label = next(k for k in app.runs._items if "from_a_student" in k)
        assert app.runs.open(rec_label) is None  # again from the list, on the planar arm now: no switch said
        assert app.runs.message.content == ""
    finally:
        presenter.close()
        app.runs.live()
