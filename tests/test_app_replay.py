"""The runs list and replay panel: a run started in the app is listed, opened from its Rerun
recording, scrubbed generation by generation; bad uploads are refused and change nothing."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from lab.recording.replay import load_controller

from app.server import LabApp
from app.training.notebook import label

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    folder = tmp_path_factory.mktemp("replay")
    lab_app = LabApp(port=0, notebook=str(folder / "notebook.json"), recordings=str(folder / "rec"))
    lab_app.panel.generations.value, lab_app.panel.population.value = 40, 10
    assert lab_app.panel.start() is None
    lab_app.state.runner.join(60)
    yield lab_app
    lab_app.stop()


def test_a_finished_run_is_in_the_list_with_its_recording(app):
    entry = app.state.notebook.entries()[-1]
    assert entry["state"] == "finished" and entry["generations"] == 40
    assert entry["recording"] and os.path.exists(entry["recording"])
    app.runs.refresh(force=True)
    assert label(entry) in app.runs.choice.options


def test_scrubbing_shows_the_logged_controller_of_that_generation(app):
    entry = app.state.notebook.entries()[-1]
    app.runs.refresh(force=True)  # the list as the previous test leaves it, when run alone too
    assert app.runs.open(label(entry)) is None
    assert not app.runs.slider.disabled and app.state.replaying
    goals = app.state.arm.sample_goals(5, seed=9)
    for generation in (1, 10, 40):
        app.runs.slider.value = generation
        expected = load_controller(entry["recording"], generation - 1)
        assert np.allclose(app.state.shown.controller(goals), expected(goals))
        assert f"generation {generation}" in app.state.shown.source
    app.runs.live()
    assert not app.state.replaying and app.state.shown.source.startswith("run")


@pytest.mark.parametrize("name,content", [("notes.txt", b"hello"), ("fake.rrd", b"RRF not really a recording")])
def test_a_bad_upload_is_refused_and_nothing_changes(app, name, content):
    before = app.state.shown.version
    assert "refused" in app.runs.open_upload(name, content)
    assert "refused" in app.runs.message.content
    assert app.state.shown.version == before
    uploads = os.path.join(app.recordings, "uploads")
    assert not any(f.startswith(name[:4]) for f in (os.listdir(uploads) if os.path.isdir(uploads) else []))


def test_an_uploaded_recording_replays(app):
    entry = app.state.notebook.entries()[-1]
    with open(entry["recording"], "rb") as f:
        content = f.read()
    assert app.runs.open_upload("shared by a student.rrd", content) is None
    assert os.path.exists(os.path.join(app.recordings, "uploads", "shared_by_a_student.rrd"))
    assert app.state.replaying and "shared_by_a_student.rrd" in app.state.shown.source
    app.runs.live()


def test_an_entry_without_its_recording_replays_its_final_controller(app, tmp_path):
    entry = dict(app.state.notebook.entries()[-1], run_id="gone0000", recording=str(tmp_path / "missing.rrd"))
    app.state.notebook.add(entry)
    app.runs.refresh(force=True)
    assert app.runs.open(label(entry)) is None
    assert app.runs.slider.disabled and "final controller" in app.state.shown.source
    app.runs.live()


def test_replay_shows_the_recorded_population_of_that_generation(app):
    from lab.recording.replay import read_recording

    from app.probe import Probe

    entry = next(e for e in app.state.notebook.entries() if e["recording"] and os.path.exists(e["recording"]))
    rec = read_recording(entry["recording"])
    probe = Probe(app.url).start()
    try:
        owner = int(probe.owner("/tab/goal0/marker"))
        app.runs.refresh(force=True)
        assert app.runs.open(label(entry)) is None
        app.runs.slider.value = 25
        shown = app.state.replayed_population
        assert shown.generation == 24 and np.array_equal(shown.points, rec.population_at(24).points)
        deadline = time.monotonic() + 10
        while owner not in app.sessions and time.monotonic() < deadline:
            time.sleep(0.05)
        session = app.sessions[owner]
        while time.monotonic() < deadline:
            cloud = session.goals[0].cloud
            if cloud is not None and np.allclose(np.asarray(cloud.points), shown.points):
                break
            time.sleep(0.05)
        assert cloud is not None and np.allclose(np.asarray(cloud.points), shown.points)
        deadline = time.monotonic() + 5
        while "Replay" not in app.panel.legend.content and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "Replay" in app.panel.legend.content  # the render loop's next panel refresh
    finally:
        app.runs.live()
        probe.close()


def test_uploads_of_one_name_are_kept_side_by_side_and_odd_names_are_saved_visibly(app):
    entry = next(e for e in app.state.notebook.entries() if e.get("recording") and os.path.exists(e["recording"]))
    with open(entry["recording"], "rb") as f:
        content = f.read()
    uploads = os.path.join(app.recordings, "uploads")
    assert app.runs.open_upload("shared.rrd", content) is None
    assert app.runs.open_upload("shared.rrd", content) is None  # another tab's file of the same name
    assert "shared-2.rrd" in app.runs.message.content
    assert {"shared.rrd", "shared-2.rrd"} <= set(os.listdir(uploads))
    assert app.runs.open_upload(".rrd", content) is None  # was saved hidden, never listed
    assert app.runs.open_upload("x" * 300 + ".rrd", content) is None  # was 'File name too long'
    app.runs.refresh(force=True)
    listed = [o for o in app.runs.choice.options if o.startswith("file: uploads/")]
    assert "file: uploads/upload.rrd" in listed and f"file: uploads/{'x' * 100}.rrd" in listed
    assert not any(f.startswith(".") for f in os.listdir(uploads))
    app.runs.live()
