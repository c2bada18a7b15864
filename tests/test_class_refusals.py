"""Small faults of a class, found by a hostile probe (docs/faults.md): every "Stop my run" while a
run is stopping started a thread (7 to 336 threads from 300 clicks); names that only look alike
("ＡＤＡ" beside "Ada") were both accepted; a viewer's upload was "refused: refused: ..."; refusals
named fields by the API's names ("targets", "seconds") where the student reads "Goals" and "Time
budget (s)"."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

import lab
from app.classroom.access import REFUSED
from app.classroom.class_runs import ClassRuns, name_key
from app.classroom.limits import CLASSROOM, in_labels, refused
from app.classroom.uploads import UploadGuard
from app.panels.my_run import MyRunPanel
from app.training.notebook import Notebook
from conftest import wait_until

SHORT = dict(robot="planar", method="cmaes", generations=20, population=10)


@pytest.fixture
def notebook(tmp_path):
    return Notebook(str(tmp_path / "notebook.db"))


class SlowStop:
    """A run's runner whose Stop takes a while (a worker finishing its generation in flight)."""

    made: list = []

    def __init__(self, config, history_limit=None):
        self.config, self.run_id, self.preparing = config, None, None
        self.release, self.stops = threading.Event(), 0
        SlowStop.made.append(self)

    def subscribe(self, subscriber):
        pass

    def start(self):
        pass

    def stop_or_kill(self, grace):
        self.stops += 1
        self.release.wait(60)

    def stop(self, wait=False):
        pass

    def join(self, timeout=None):
        pass


def stop_threads() -> int:
    return sum(t.name.startswith("class-stop-") for t in threading.enumerate())


def test_three_hundred_stops_of_a_stopping_run_start_one_thread(notebook):
    SlowStop.made.clear()
    runs = ClassRuns(notebook, CLASSROOM, workers=1, runner=SlowStop)
    assert runs.submit(1, lab.TrainConfig(**SHORT)) is None
    run, runner = runs.run_of(1), SlowStop.made[-1]
    assert run.state == "running" and not run.stopping
    before = stop_threads()
    try:
        answers = [runs.stop_tab(1) for _ in range(300)]  # a student's clicks while it stops
        answers.append(runs.stop(run.id, "stopped by the presenter"))
        assert answers == [None] * 301  # none refused: the run is stopping, as asked
        assert stop_threads() - before <= 1 and run.stopping
        assert wait_until(lambda: runner.stops == 1, 10)
        assert run.note == "stopped by its student"  # the first Stop's reason is kept
        runs.drop_tab(1)  # its tab closes while it stops: no thread more
        assert stop_threads() - before <= 1 and runner.stops == 1
    finally:
        runner.release.set()
    assert wait_until(lambda: stop_threads() == before, 10)


def test_names_are_compared_after_nfkc_and_case_folding(notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    assert runs.set_name(1, "Ada") is None
    for lookalike in ("ＡＤＡ", "ａｄａ", "ADA", "Ａda"):  # fullwidth letters: the same name on the board
        why = runs.set_name(2, lookalike)
        assert why is not None and "taken" in why, lookalike
    assert runs.set_name(3, "ﬁsh") is None  # a ligature
    assert "taken" in runs.set_name(4, "fish")
    assert runs.set_name(5, "Straße") is None
    assert "taken" in runs.set_name(6, "STRASSE")
    assert "taken" in runs.set_name(7, "ｓｔｕｄｅｎｔ " + runs.name_of(8).split()[-1])  # a generated name too
    assert name_key("ＡＤＡ") == name_key("ada") != name_key("Adam")
    runs.drop_tab(1)
    assert runs.set_name(2, "ＡＤＡ") is None  # free once its tab has closed


def test_a_viewers_upload_is_refused_once(tmp_path):
    told = []
    guard = UploadGuard(str(tmp_path), allowed=lambda cid: REFUSED, notify=lambda cid, text: told.append(text))
    assert guard.start(7, "t1", "run.rrd", 1000, 1) is False
    assert told == [REFUSED] and told[0].count("refused") == 1
    assert refused("the folder is full") == "refused: the folder is full"
    assert refused(REFUSED) == REFUSED


class _Fields:
    """My experiment's fields as config() reads them (the panel's own method, no browser)."""

    config = MyRunPanel.config
    _method_name = MyRunPanel._method_name

    def __init__(self, **values):
        label = dict(population="Population", hidden="Hidden units", goals="Goals", generations="Generations",
                     seed="Seed", budget="Time budget (s)")
        start = {**dict(population=10.0, hidden=8.0, goals=70.0, generations=20.0, seed=0.0, budget=0.0), **values}
        for key, text in label.items():
            setattr(self, key, SimpleNamespace(value=start[key], label=text))
        self.robot = SimpleNamespace(value="planar")
        self.method = SimpleNamespace(value=lab.methods.get("cmaes").label)


@pytest.mark.parametrize("values, label, api", [
    (dict(goals=0.0), "Goals", "targets"), (dict(goals=2.5), "Goals", "targets"),
    (dict(budget=-3.0), "Time budget (s)", "seconds"), (dict(budget=2e9), "Time budget (s)", "seconds"),
    (dict(hidden=0.0), "Hidden units", "hidden"), (dict(population=10**5), "Population", None),
    (dict(generations=0.0), "Generations", None)])
def test_my_experiments_refusals_name_the_fields_the_student_sees(values, label, api):
    with pytest.raises(ValueError) as e:
        _Fields(**values).config()
    text = str(e.value)
    assert text.startswith(label + " "), text
    if api is not None:
        assert not text.startswith(api), text


def test_the_servers_limits_name_the_fields_the_student_sees(notebook):
    runs = ClassRuns(notebook, CLASSROOM, workers=1)
    why = runs.submit(1, lab.TrainConfig(**{**SHORT, "targets": 5000}))
    assert why.startswith("refused: Goals must be at most 3,000") and "targets" not in why
    why = runs.submit(1, lab.TrainConfig(robot="planar", method="cmaes", population=10, seconds=700.0))
    assert why.startswith("refused: Time budget (s) must be at most 600") and "seconds (" not in why
    assert runs.run_of(1) is None


def test_the_python_api_keeps_its_own_names():
    with pytest.raises(ValueError, match="^targets must be"):
        lab.TrainConfig(robot="planar", targets=0)
    assert in_labels("targets must be an integer in 1..1,000,000, got 0") == \
        "Goals must be an integer in 1..1,000,000, got 0"
    assert in_labels("seconds must be a positive number") == "Time budget (s) must be a positive number"
    assert in_labels("unknown robot 'x'") == "unknown robot 'x'"
