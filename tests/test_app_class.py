"""A class experimenting together, with headless tabs (app/probe.py) on a server restricted by a presenter
token: a viewer's tab has "My experiment" and its run trains in a process of its own, the shared run
going on beside it; the Class board lists it with the name escaped; a markup or taken name is refused;
a closed tab's run stops; the server's stop ends the students' runs, stopped in the notebook. The
scheduler alone: tests/test_class_runs.py."""

from __future__ import annotations

import time
import urllib.parse

import pytest
from viser import _messages

import lab
from conftest import make_app, tab_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
TOKEN = "s3cret-Token_class"


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    lab_app = make_app(tmp_path_factory.mktemp("class"), presenter_token=TOKEN, class_workers=1, startup=None,
                       limits={"population": 200})
    yield lab_app
    if lab_app.state.running:
        lab_app.state.reset()
    lab_app.stop()


def session_of(app, probe):
    owner = int(probe.owner("/tab/goal0/marker"))
    assert wait_until(lambda: owner in app.sessions, 60)
    return app.sessions[owner]


def gui_uuid(probe, label, timeout=30.0):
    return probe.wait_for(lambda m: m["type"].startswith("Gui") and m.get("props", {}).get("label") == label,
                          timeout)["uuid"]


def has_gui(probe, label) -> bool:
    return any(m["type"].startswith("Gui") and m.get("props", {}).get("label") == label for _t, m in list(probe.messages))


def wait_for_options(app, run):
    """The board's Stop choices, once they offer `run` (the render loop refreshes the board)."""
    assert wait_until(lambda: run.id in app.board._ids.values(), 30)
    return list(app.board._ids.items())


def small(panel, generations=20):
    assert panel.robot.value == "planar"
    panel.population.value, panel.generations.value, panel.budget.value = 10.0, float(generations), 0.0


def test_a_viewers_own_run_trains_beside_the_shared_run_and_the_board_lists_it(app):
    presenter = tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    viewer = tab_of(app.url)
    try:
        gui_uuid(viewer, "Start my run")
        gui_uuid(presenter, "Stop this run")  # the Class tab, in every tab
        assert not has_gui(presenter, "Start my run")  # a presenter has the shared Train panel instead
        mine = session_of(app, viewer).my_run
        # the shared run goes on for good while the student's runs
        assert app.state.start(lab.TrainConfig(robot="planar", generations=100_000, population=10)) is None
        shared = app.state.runner
        # a name with markup is refused, in the tab, and the name stays
        before = mine.name.value
        viewer.send(_messages.GuiUpdateMessage(uuid=gui_uuid(viewer, "Your name"), updates={"value": "<b>x</b>"}))
        assert wait_until(lambda: "refused" in mine.message.content, 30) and "'<'" in mine.message.content
        assert app.class_runs.name_of(mine.tab) == before
        viewer.send(_messages.GuiUpdateMessage(uuid=gui_uuid(viewer, "Your name"), updates={"value": "Ada & co"}))
        assert wait_until(lambda: "'&'" in mine.message.content, 30)
        viewer.send(_messages.GuiUpdateMessage(uuid=gui_uuid(viewer, "Your name"), updates={"value": " Ada  L "}))
        assert wait_until(lambda: app.class_runs.name_of(mine.tab) == "Ada L", 30)
        # beyond the server's limits: refused with the reason
        small(mine)
        mine.population.value = 10_000.0
        why = mine.start()
        assert why.startswith("refused:") and "population" in why and "at most 200" in why
        small(mine)
        viewer.click("Start my run")
        assert wait_until(lambda: app.class_runs.run_of(mine.tab) is not None, 30)
        run = app.class_runs.run_of(mine.tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        assert run.state == "finished" and run.generation == 20
        assert run.runner.pid != shared.pid
        entry = app.state.notebook.get(run.id)
        assert entry["state"] == "finished" and entry["student"] == "Ada L" and entry["generations"] == 20
        # the shared run went on throughout, untouched
        assert app.state.runner is shared and shared.state == "running"
        assert wait_until(lambda: "Finished" in mine.status.content, 30)
        assert wait_until(lambda: "Ada L" in app.board.table.content, 30)
        assert run.id[:6] not in app.board.choice.options  # an ended run is not offered to Stop
        # the tab's own arms showed its run (the shared arm); the others' did not
        assert session_of(app, viewer).shown.source.startswith("my run (Ada L)")
        assert not session_of(app, presenter).shown.source.startswith("my run")
        # the class chart has its point; the presenter shows it to the whole class
        assert wait_until(lambda: "1 finished run" in app.board.chart.content, 30)
        app.board.axis.value = "method"
        assert wait_until(lambda: "against method" in app.board.chart.content, 30)
        assert wait_until(lambda: any(run.id[:6] in o for o in app.board.show_choice.options), 30)
        app.board.show_choice.value = next(o for o in app.board.show_choice.options if run.id[:6] in o)
        assert app.board.show_chosen() is None
        assert app.state.shown.controller is run.controller and "Ada L" in app.state.shown.source
    finally:
        app.state.reset()
        viewer.close()
        presenter.close()


def test_a_taken_name_is_refused_and_a_closed_tabs_run_stops(app, wait_ended):
    one, two = tab_of(app.url), tab_of(app.url)
    try:
        a, b = session_of(app, one).my_run, session_of(app, two).my_run
        assert app.class_runs.set_name(a.tab, "Grace") is None
        two.send(_messages.GuiUpdateMessage(uuid=gui_uuid(two, "Your name"), updates={"value": "grace"}))
        assert wait_until(lambda: "taken" in b.message.content, 30)
        small(b, generations=100_000)
        assert b.start() is None
        run = app.class_runs.run_of(b.tab)
        assert "one run at a time" in b.start()
        assert wait_until(lambda: run.generation > 0, 300), run.status()
        # tab one's run waits behind it (one worker); a viewer cannot stop another's run from the board
        small(a, generations=100_000)
        assert a.start() is None
        waiting = app.class_runs.run_of(a.tab)
        assert waiting.state == "queued"
        # its tab says who is ahead and the wait (or that none can be told yet), above Start my run
        assert wait_until(lambda: "1 run ahead of yours" in a.status.content, 30), a.status.content
        assert "to wait" in a.status.content or "no estimate" in a.status.content
        label = next(k for k, v in wait_for_options(app, waiting) if v == waiting.id)
        app.board.choice.value = label
        two.click("Stop this run")
        assert wait_until(lambda: any("Notification" in m["type"] and "presenter" in str(m)
                                      for _t, m in list(two.messages)), 30)
        assert not run.ended and waiting.state == "queued"
        # the presenter can
        assert app.board.stop_chosen() is None
        assert waiting.state == "stopped" and waiting.note == "stopped by the presenter" and not run.ended
        pid = run.runner.pid
        two.close()
        assert wait_until(lambda: run.ended, 60) and run.state == "stopped"
        wait_ended(pid)
        assert app.state.notebook.get(run.id)["error"] == "its tab closed"
    finally:
        one.close()
        two.close()


def test_the_servers_stop_ends_the_students_runs_as_stopped(tmp_path, wait_ended):
    lab_app = make_app(tmp_path, presenter_token=TOKEN, class_workers=1, startup=None,
                       limits={"population": 200})
    tabs = [tab_of(lab_app.url), tab_of(lab_app.url)]
    try:
        panels = [session_of(lab_app, t).my_run for t in tabs]
        for p in panels:
            small(p, generations=100_000)
            assert p.start() is None
        running, queued = (lab_app.class_runs.run_of(p.tab) for p in panels)
        assert queued.state == "queued" and queued.status() == "queued, place 1 of 1"
        assert wait_until(lambda: running.generation > 0, 300), running.status()
        pid = running.runner.pid
        lab_app.stop()
        assert running.state == "stopped" and queued.state == "stopped"
        wait_ended(pid)
        for run in (running, queued):
            assert lab_app.state.notebook.get(run.id)["state"] == "stopped"
    finally:
        for t in tabs:
            t.close()
        lab_app.stop() if not lab_app._stop.is_set() else None


def test_the_class_chart_escapes_names_and_plots_only_finished_runs():
    from types import SimpleNamespace

    from app.panels.class_board import chart_svg

    def run(name, hidden, mse, state="finished"):
        config = lab.TrainConfig(robot="planar", generations=20, population=10, hidden=hidden)
        return SimpleNamespace(name=name, config=config, state=state, held_out=lambda: mse)

    runs = [run("<i>a</i>", 8, 0.1), run("b", 16, 0.01), run("c", 32, 0.02, state="stopped"), run("d", 64, None)]
    svg = chart_svg(runs, "hidden units")
    assert "2 finished runs" in svg and svg.count("<circle") == 2
    assert "<i>" not in svg and "&lt;i&gt;a&lt;/i&gt;" in svg
    assert "no finished run" in chart_svg(runs[2:], "population")


def test_python_m_app_takes_the_number_of_class_workers():
    from app.__main__ import parse

    assert parse([]).class_workers is None and parse(["--class-workers", "3"]).class_workers == 3
    for bad in ("0", "-1", "two", "1.5"):
        with pytest.raises(SystemExit):
            parse(["--class-workers", bad])


def test_a_run_on_another_robot_is_drawn_in_its_own_tab_reaching_for_the_goal_its_student_drags(app):
    """The class sees the planar arm; a viewer's so100 run is drawn in that tab's own scene (beside the
    class's arm), posed at its best network's answer for the goal the student drags; another tab has
    none of it, and the shared scene is unchanged."""
    import numpy as np
    import pinocchio as pin

    import robots
    from conftest import last_pose
    from robots.visual import se3_pose

    presenter = tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    viewer, other = tab_of(app.url), tab_of(app.url)
    try:
        mine = session_of(app, viewer).my_run
        assert app.state.arm.name == "planar"
        mine.robot.value = "so100"
        mine.population.value, mine.generations.value, mine.budget.value = 10.0, 5.0, 0.0
        assert mine.start() is None
        run = app.class_runs.run_of(mine.tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        assert run.state == "finished"
        assert wait_until(lambda: mine.view is not None and mine.view.controller is run.controller, 60)
        viewer.wait_for(lambda m: m.get("name") == "/tab/myrun/goal0", 30)
        viewer.wait_for(lambda m: m.get("name") == "/tab/myrun/title" and "so100" in str(m), 30)
        arm = robots.load("so100")
        goal = arm.sample_goals(1, seed=3)[0]
        view = mine.view
        assert view.scale > 1.0  # drawn at the planar arm's size, beside it
        viewer.drag("/tab/myrun/goal0", view.to_world(goal)[0] if arm.is_tree else view.to_world(goal),
                    pose_prefix="/tab/myrun/arm/", timeout=30)
        assert wait_until(lambda: np.allclose(mine.view.goal, goal), 30)
        q = run.controller(goal[None])[0]
        data = arm.model.createData()
        pin.forwardKinematics(arm.model, data, arm.to_pinocchio(q))

        def posed() -> bool:
            for j in range(1, arm.model.njoints):
                position, wxyz = last_pose(viewer, f"/tab/myrun/arm/j{j}")
                want_p, want_q = se3_pose(data.oMi[j])
                want_p = view.offset + view.scale * want_p  # where it stands in the tab's scene
                if not (np.allclose(position, want_p, atol=1e-5) and
                        (np.allclose(wxyz, want_q, atol=1e-6) or np.allclose(wxyz, -want_q, atol=1e-6))):
                    return False
            return True

        assert wait_until(posed, 30)
        assert np.isfinite(mine.view.error) and "net " in mine.view.label.text
        # only that tab: no other tab, presenter or viewer, got any of it; the class's arm is the planar one
        for tab in (presenter, other):
            assert not any(str(m.get("name", "")).startswith("/tab/myrun") for _t, m in list(tab.messages))
        assert app.state.arm.name == "planar"
        # Show off: the robot leaves the tab's scene
        mine.show_on_arm.value = False
        assert wait_until(lambda: mine.view is None, 30)
        viewer.wait_for(lambda m: m["type"] == "RemoveSceneNodeMessage" and m["name"] == "/tab/myrun/goal0", 30)
    finally:
        viewer.close()
        other.close()
        presenter.close()


def test_the_class_chart_draws_the_class_curve_through_each_values_median():
    from types import SimpleNamespace

    import numpy as np

    from app.panels.class_board import chart_svg

    def run(hidden, mse):
        config = lab.TrainConfig(robot="planar", generations=20, population=10, hidden=hidden)
        return SimpleNamespace(name="s", config=config, state="finished", held_out=lambda: mse)

    runs = [run(2, 0.1), run(2, 0.4), run(2, 1.6), run(8, 0.01), run(64, 1.0)]
    svg = chart_svg(runs, "hidden units")
    assert svg.count("<circle") == 5 and svg.count("<polyline") == 1 and "class median" in svg
    line = svg.split('<polyline points="')[1].split('"')[0]
    ys = [float(p.split(",")[1]) for p in line.split()]
    xs = [float(p.split(",")[0]) for p in line.split()]
    # three points, left to right; the median of 2's three runs (0.4) lies between 8's (0.01) and 64's (1.0)
    assert len(ys) == 3 and xs == sorted(xs) and ys[1] > ys[0] > ys[2]
    # hidden units 2..64 on a log axis: 8 is as far from 2 as 64 from 16 would be, so halfway less than linear
    assert np.isclose((xs[1] - xs[0]) / (xs[2] - xs[0]), np.log(4) / np.log(32))
    assert "<polyline" not in chart_svg(runs, "method")  # a method is no curve


def test_the_class_as_a_search_gives_each_student_tab_its_part(app):
    """The lesson's link: the N-th viewer tab to open it gets the N-th number of hidden units of the link's
    class_hidden= list as its My experiment's (seed 0; the next round of the list seed 1), and the
    lesson's other settings; a tab's seat stays its own; a presenter's tab has no My experiment to set."""
    from app.classroom.lesson import LESSONS
    from app.probe import Probe

    lesson = LESSONS["class-as-a-search"]
    values = [int(v) for v in lesson.params["class_hidden"].split(".")]
    url = urllib.parse.unquote(lesson.link(app.url).split("?websocket=", 1)[1]).replace("ws://", "http://")
    tabs = []
    try:
        for k in range(2):
            tabs.append(Probe(url).start(60))
            tabs[-1].wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
        panels = [session_of(app, t).my_run for t in tabs]
        for k, panel in enumerate(panels):
            assert wait_until(lambda: "part of the class" in panel.part.content, 30)
            config = panel.config()
            assert (config.hidden, config.seed, config.generations, config.population) == \
                (values[k], 0, int(lesson.params["generations"]), int(lesson.params["population"]))
            assert config.robot == lesson.params["robot"] and config.seconds is None
        seat = app.class_runs.lesson_seat(lesson.name, panels[1].tab)
        assert seat == 1 and app.class_runs.lesson_seat(lesson.name, panels[0].tab) == 0
        assert app.class_runs.lesson_seat(lesson.name, -5) == 2  # the next tab's seat
        assert panels[0].take_part({**lesson.params, "lesson": lesson.name}) is None
        assert panels[0].config().hidden == values[0]  # its own seat again
        assert panels[0].take_part({"class_hidden": "2.x"}).startswith("refused")
    finally:
        for t in tabs:
            t.close()


def test_the_presenter_shows_a_finished_students_recording_and_scrubs_its_generations(tmp_path):
    """On a server that records, a student's finished run has its recording; the board's show opens it
    in the Runs tab for the whole class: the slider spans its generations and scrubbing one shows the
    controller logged then."""
    import os

    import numpy as np

    lab_app = make_app(tmp_path, presenter_token=TOKEN, class_workers=1, startup=None, record=True,
                       limits={"population": 200})
    viewer = tab_of(lab_app.url)
    try:
        mine = session_of(lab_app, viewer).my_run
        small(mine, generations=20)
        assert mine.start() is None
        run = lab_app.class_runs.run_of(mine.tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        assert run.recording and os.path.isfile(run.recording)
        assert lab_app.state.notebook.get(run.id)["recording"] == run.recording
        board = lab_app.board
        assert wait_until(lambda: any(run.id[:6] in o for o in board.show_choice.options), 30)
        board.show_choice.value = next(o for o in board.show_choice.options if run.id[:6] in o)
        assert board.show_chosen() is None and "recording" in board.show_message.content
        runs = lab_app.runs
        assert runs.recording is not None and str(runs.recording.path) == run.recording
        last = int(runs.recording.controller_doc()["generation"]) + 1  # its last new best, of 20 generations
        assert not runs.slider.disabled and runs.slider.min == 1 and runs.slider.max == runs.slider.value == last > 1
        goals = lab_app.state.arm.sample_goals(5, seed=1)
        assert np.array_equal(lab_app.state.shown.controller(goals), run.controller(goals))  # its last: the final
        assert runs.scrub(1) is None
        first = lab.controller_from_dict(runs.recording.controller_doc(0)["controller"])
        assert "generation 1" in lab_app.state.shown.source and lab_app.state.replaying
        assert np.array_equal(lab_app.state.shown.controller(goals), first(goals))
        runs.live()
        assert not lab_app.state.replaying
    finally:
        viewer.close()
        lab_app.stop()


def folder_and_first_line(probe, label):
    """(the folder's creation message, the content of the first markdown inside it)."""
    folder = probe.wait_for(lambda m: m["type"] == "GuiFolderMessage" and m["props"].get("label") == label, 30)
    first = probe.wait_for(lambda m: m["type"] == "GuiMarkdownMessage" and m.get("container_uuid") == folder["uuid"], 30)
    content = first["props"]["_markdown"]
    for _t, m in list(probe.messages):  # its later content (take_part writes it after the tab connects)
        if m["type"] == "GuiUpdateMessage" and m.get("uuid") == first["uuid"] and "_markdown" in m.get("updates", {}):
            content = m["updates"]["_markdown"]
    return folder, content


def red_notifications(probe) -> list:
    return [m for _t, m in list(probe.messages)
            if "Notification" in m["type"] and m.get("props", {}).get("color") == "red"]


@pytest.mark.parametrize("name", ["class-as-a-search", "position-or-pose"])
def test_a_lesson_link_opens_my_experiment_unfolded_with_the_students_part_first_and_no_failure(app, name):
    """A viewer's lesson link did what the lesson meant (the shared settings stay the
    presenter's), yet its tab read "this lesson link's settings were not applied" and the student's part
    sat in a folded folder. Now the folder opens, its first line is the student's part, nothing is red;
    the tab's runs are grouped under the lesson."""
    from app.classroom.lesson import LESSONS
    from app.probe import Probe

    url = urllib.parse.unquote(LESSONS[name].link(app.url).split("?websocket=", 1)[1]).replace("ws://", "http://")
    tab = Probe(url).start(60)
    plain = tab_of(app.url)
    try:
        tab.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
        panel = session_of(app, tab).my_run
        assert wait_until(lambda: "Press **Start my run**" in panel.part.content, 30)
        assert wait_until(lambda: "Start my run" in folder_and_first_line(tab, "My experiment (this tab)")[1], 30)
        folder, first = folder_and_first_line(tab, "My experiment (this tab)")
        assert folder["props"]["expand_by_default"] is True
        assert ("Your part of the class's search" if name == "class-as-a-search" else "Your run in this lesson") in first
        assert panel.lesson == name and panel.config().robot == LESSONS[name].params["robot"]
        plain_folder, plain_first = folder_and_first_line(plain, "My experiment (this tab)")
        assert plain_folder["props"]["expand_by_default"] is False and plain_first == ""  # no lesson: folded
        time.sleep(1.0)  # any notification the connect sends has arrived by now
        assert red_notifications(tab) == [], red_notifications(tab)
        assert not any("not applied" in str(m) for _t, m in list(tab.messages))
    finally:
        tab.close()
        plain.close()


def test_a_viewers_hint_names_start_my_run_and_a_refused_name_is_said_in_the_folder(app):
    """Before, "Ana (phone)" silently became "student 6"; the viewer's hint named the presenter's Start."""
    presenter = tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    viewer = tab_of(app.url)
    try:
        s_viewer, s_presenter = session_of(app, viewer), session_of(app, presenter)
        assert "**Start my run**" in s_viewer.intro.content and "**Start** trains" not in s_viewer.intro.content
        assert "**Start** trains a new one" in s_presenter.intro.content
        mine = s_viewer.my_run
        viewer.send(_messages.GuiUpdateMessage(uuid=gui_uuid(viewer, "Your name"), updates={"value": "Ana (phone)"}))
        given = app.class_runs.name_of(mine.tab)
        assert wait_until(lambda: "refused" in mine.name_note.content, 30)
        assert "'Ana (phone)'" in mine.name_note.content and f"**{given}**" in mine.name_note.content
        assert "'('" in mine.name_note.content
        small(mine, generations=3)
        assert mine.start() is None
        assert "refused" in mine.message.content and given in mine.message.content  # still said after Start
        run = app.class_runs.run_of(mine.tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        viewer.send(_messages.GuiUpdateMessage(uuid=gui_uuid(viewer, "Your name"), updates={"value": "Ana phone"}))
        assert wait_until(lambda: mine.name_note.content == "", 30)
    finally:
        viewer.close()
        presenter.close()


def test_the_presenters_board_controls_new_board_large_chart_and_grade_book(app):
    """New board, Show the chart large and Download the class's runs: the presenter's alone (a viewer's
    click does nothing); the CSV goes to the presenter's tab; the large chart to its own tab; a new
    board leaves the earlier runs out of the table and the chart, the notebook keeps them."""
    from app.classroom.gradebook import class_csv

    presenter = tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    viewer = tab_of(app.url)
    try:
        mine = session_of(app, viewer).my_run
        assert app.class_runs.set_name(mine.tab, "Board Ada") is None
        small(mine, generations=3)
        assert mine.start() is None
        run = app.class_runs.run_of(mine.tab)
        assert wait_until(lambda: run.ended, 300), run.status()
        assert wait_until(lambda: "Board Ada" in app.board.table.content, 30)
        boards = app.class_runs.boards
        for label in ("Download the class's runs (CSV)", "New board", "Show the chart large"):
            viewer.click(label)
        assert wait_until(lambda: sum("Notification" in m["type"] and "presenter" in str(m)
                                      for _t, m in list(viewer.messages)) >= 3, 30)
        time.sleep(0.5)
        assert not any(m["type"] == "FileTransferStartDownload" for _t, m in list(viewer.messages))
        assert app.class_runs.boards == boards and not any("1200 600" in str(m) for _t, m in list(viewer.messages))
        # the grade book, to the presenter's tab
        presenter.click("Download the class's runs (CSV)")
        sent = presenter.wait_for(lambda m: m["type"] == "FileTransferStartDownload", 30)
        assert sent["filename"].endswith(".csv") and sent["size_bytes"] == len(class_csv(app.class_runs.rows()))
        # the large chart, in the presenter's own tab
        presenter.click("Show the chart large")
        presenter.wait_for(lambda m: 'viewBox="0 0 1200 600"' in str(m) and "Board Ada" in str(m), 30)
        assert not any("1200 600" in str(m) for _t, m in list(viewer.messages))
        # a new board: the run leaves the table and the chart (the large one too); the notebook keeps it
        presenter.click("New board")
        assert wait_until(lambda: app.class_runs.boards == boards + 1, 30)
        assert wait_until(lambda: "Board Ada" not in app.board.table.content, 30)
        assert "no finished run yet" in app.board.chart.content
        assert wait_until(lambda: "no finished run yet" in app.board._big[presenter_id(app, presenter)][1].content, 30)
        assert app.state.notebook.get(run.id)["student"] == "Board Ada"
    finally:
        viewer.close()
        presenter.close()


def presenter_id(app, probe) -> int:
    return session_of(app, probe).client.client_id


def test_a_lesson_link_that_makes_no_run_is_refused_in_the_students_folder(app):
    """A refusal is said where the student looks (the folder's first line, above Start), not only as a toast."""
    from app.probe import Probe
    from app.viser_private import websocket_link

    link = websocket_link(app.url, lesson="class-as-a-search", robot="nosuchrobot", class_hidden="2.3")
    tab = Probe(urllib.parse.unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")).start(60)
    try:
        tab.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
        panel = session_of(app, tab).my_run
        assert wait_until(lambda: panel.part.content.startswith("refused: this lesson link does not make a run"), 30)
        assert "nosuchrobot" in panel.part.content
        assert wait_until(lambda: panel.message.content == panel.part.content, 30)  # said above Start just after
        assert wait_until(lambda: "refused" in folder_and_first_line(tab, "My experiment (this tab)")[1], 30)
        assert folder_and_first_line(tab, "My experiment (this tab)")[0]["props"]["expand_by_default"] is True
    finally:
        tab.close()
