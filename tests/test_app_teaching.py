"""The app for a class: Step, the speed control, the population view and a race, driven
as a browser drives them (app/probe.py sends the GUI's messages) and checked on the server."""

from __future__ import annotations

import time

import numpy as np
import pytest
from viser import _messages

from app.probe import Probe
from conftest import session_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")


@pytest.fixture
def tab(tab, app):  # conftest's tab and app
    yield tab
    app.state.reset()
    app.panel.speed.value = "unlimited"
    app.panel.race.enabled.value = False



def settled(count, quiet=0.5, timeout=15.0) -> int:
    """count() once it has not changed for `quiet` seconds."""
    last, since, t0 = count(), time.monotonic(), time.monotonic()
    while time.monotonic() - since < quiet and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
        if count() != last:
            last, since = count(), time.monotonic()
    return last


def set_field(probe, kind: str, label: str, value) -> None:
    """Change a GUI field as the browser does (a GuiUpdateMessage for its uuid)."""
    msg = probe.wait_for(lambda m: m["type"] == kind and m["props"]["label"] == label)
    probe.send(_messages.GuiUpdateMessage(uuid=msg["uuid"], updates={"value": value}))


def generations(app) -> int:
    return app.state.progress()["generation"]


def test_one_step_click_is_one_more_generation_on_the_server(app, tab):
    app.panel.generations.value = 100_000
    tab.click("Start")
    assert wait_until(lambda: generations(app) >= 5)
    tab.click("Step")  # refused while running, said in the panel
    assert wait_until(lambda: "Step works while the run is paused" in app.panel.message.content, 5)
    tab.click("Pause")
    runner = app.state.runner
    assert wait_until(lambda: runner.holding is not None)  # the worker holds, every event before it in
    held = runner.holding
    assert generations(app) == held
    for k in range(1, 4):
        tab.click("Step")
        assert wait_until(lambda: runner.holding == held + k)
        assert generations(app) == held + k
    assert settled(lambda: generations(app)) == held + 3 and runner.state == "paused"
    # the population shown is the stepped generation's own
    track = app.state.track
    assert wait_until(lambda: track.population is not None and track.population.generation == held + 2)
    tab.click("Resume")
    assert wait_until(lambda: generations(app) > held + 10)


def test_the_speed_control_caps_generations_per_second(app, tab):
    app.panel.generations.value = 100_000
    set_field(tab, "GuiDropdownMessage", "Speed", "5 generations/s")
    assert wait_until(lambda: app.state.speed == 5.0, 5)
    tab.click("Start")
    assert wait_until(lambda: generations(app) >= 2)
    g0, t0 = generations(app), time.monotonic()
    time.sleep(2.0)
    rate = (generations(app) - g0) / (time.monotonic() - t0)
    assert 3.0 <= rate <= 5.6, rate
    set_field(tab, "GuiDropdownMessage", "Speed", "unlimited")
    g1 = generations(app)
    time.sleep(1.0)
    assert generations(app) - g1 > 30


def test_the_population_is_drawn_at_each_tabs_own_goal(app, tab):
    app.panel.generations.value = 100_000
    session = session_of(app, tab)
    tab.click("Start")
    assert wait_until(lambda: generations(app) >= 20)
    tab.click("Pause")
    assert wait_until(lambda: app.state.runner.state == "paused")
    settled(lambda: generations(app))
    population = app.state.track.population
    arm = session.arm

    def drawn_at(goal) -> bool:
        cloud = session.goals[0].cloud
        if cloud is None or session.population_drawn is None:
            return False
        expected = population.reach(arm, goal[None])[:, 0]
        return np.allclose(np.asarray(cloud.points), expected, atol=1e-4)

    assert wait_until(lambda: drawn_at(session.goals[0].goal), 5)
    assert len(population) == app.state.runner.config.population
    # the marker moves: the cloud follows it (the candidates' reach for the new goal)
    goal = arm.sample_goals(3, seed=11)[2]
    tab.drag("/tab/goal0/marker", arm.to_3d(goal))
    assert wait_until(lambda: np.allclose(session.goals[0].goal, goal) and drawn_at(goal), 5)
    # faint arms on the toggle: one segment per link per candidate
    set_field(tab, "GuiCheckboxMessage", "Population as faint arms", True)
    assert wait_until(lambda: session.goals[0].faint is not None and session.goals[0].faint.visible, 5)
    assert np.asarray(session.goals[0].faint.points).shape == (len(population) * (arm.nq + 1), 2, 3)
    assert wait_until(lambda: "log scale" in app.panel.legend.content, 5)  # the legend changes at most once a second


def test_a_race_runs_two_processes_on_the_same_goals_and_both_enter_the_notebook(app, tab):
    panel, state = app.panel, app.state
    panel.generations.value = 100_000
    set_field(tab, "GuiCheckboxMessage", "Race a second run", True)
    set_field(tab, "GuiDropdownMessage", "Partner method", "NEAT")
    assert wait_until(lambda: panel.race.method.value == "NEAT" and panel.race.population.value == 50, 5)
    entries = len(state.notebook.entries())
    tab.click("Start")
    assert wait_until(lambda: state.partner is not None and len(state.partner.track) >= 5 and generations(app) >= 5)
    main, partner = state.runner, state.partner.runner
    assert main.pid != partner.pid
    assert np.array_equal(main.problem.train_goals, partner.problem.train_goals)
    assert (main.config.method, partner.config.method) == ("cmaes", "neat")
    panel.refresh(force=True)
    assert "leads" in panel.status.content
    assert len(panel.plot.series) == 5  # best and median of each run on one plot
    session = session_of(app, tab)
    assert wait_until(lambda: session.goals[0].partner_view is not None and session.goals[0].partner_view.visible)
    # pause, step and stop apply to both
    tab.click("Pause")
    assert wait_until(lambda: main.holding is not None and partner.holding is not None)
    a, b = main.holding, partner.holding
    tab.click("Step")
    assert wait_until(lambda: (main.holding, partner.holding) == (a + 1, b + 1))
    assert (generations(app), len(state.partner.track)) == (a + 1, b + 1)
    tab.click("Stop")
    assert wait_until(lambda: main.state == partner.state == "stopped")
    assert wait_until(lambda: len(state.notebook.entries()) == entries + 2)
    assert {e["method"] for e in state.notebook.entries()[-2:]} == {"cmaes", "neat"}


def test_a_lesson_link_opens_a_tab_with_its_settings(app, tab):
    from app.classroom.lesson import lesson_params

    panel = app.panel
    session = session_of(app, tab)
    panel.method.value = "NEAT"
    panel.seed.value = 4
    panel.race.enabled.value = True
    panel.race.method.value = "CMA-ES"
    panel.race.seed.value = 9
    params = lesson_params(panel)
    assert wait_until(lambda: "Open this lesson" in session.lesson.content and "seed 4" in session.lesson.content, 5)
    link = session.lesson.content.split("](", 1)[1].split(")", 1)[0]
    # back to other settings, then another browser opens the link
    panel.race.enabled.value = False
    panel.robot.value = "scara"
    panel.method.value = "CMA-ES"
    assert app.state.arm.name == "scara"
    from urllib.parse import unquote

    ws = unquote(link.split("?websocket=", 1)[1])
    other = Probe(ws.replace("ws://", "http://")).start()
    try:
        other.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
        assert wait_until(lambda: lesson_params(panel) == params, 10), (lesson_params(panel), params)
        assert app.state.arm.name == "planar" and panel.race.enabled.value and panel.race.seed.value == 9
        # a lesson that makes no run is refused by name and changes nothing
        bad = Probe(ws.replace("ws://", "http://").replace("method=neat", "method=nope")).start()
        bad.wait_for(lambda m: m["type"] == "NotificationShowMessage" and "nope" in str(m))
        bad.close()
        assert lesson_params(panel) == params
    finally:
        other.close()
        panel.race.enabled.value = False
        panel.method.value = "CMA-ES"


def lesson_ws(link: str) -> str:
    from urllib.parse import unquote

    return unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")


def markdown_of(probe, uuid: str) -> str:
    """The last text a markdown element of the probe's tab was given."""
    return probe.wait_for(lambda m: m["type"] == "GuiUpdateMessage" and m["uuid"] == uuid
                          and "_markdown" in m["updates"])["updates"]["_markdown"]


def lesson_column(probe) -> dict:
    """The lesson's column in a tab: its panel, tab, texts (in order) and the answers' folder."""
    panel = probe.wait_for(lambda m: m["type"] == "GuiPanelMessage")
    tab = probe.wait_for(lambda m: m["type"] == "GuiUpdateMessage" and m["uuid"] == panel["uuid"]
                         and "_tab_container_ids" in m["updates"])["updates"]["_tab_container_ids"][0]
    folder = probe.wait_for(lambda m: m["type"] == "GuiFolderMessage" and m["container_uuid"] == tab)
    answers = probe.wait_for(lambda m: m["type"] == "GuiMarkdownMessage" and m["container_uuid"] == folder["uuid"])
    texts = [m for _t, m in probe.messages if m["type"] == "GuiMarkdownMessage" and m["container_uuid"] == tab]
    return dict(panel=panel, tab=tab, folder=folder, texts=[markdown_of(probe, m["uuid"]) for m in texts],
                answers=markdown_of(probe, answers["uuid"]))


@pytest.mark.parametrize("name", ["fitness-without-targets", "cmaes-vs-neat", "hidden-units", "real-arm-and-snake",
                                  "gradient-vs-evolution"])
def test_each_lesson_link_opens_its_state_and_its_text_in_that_tab(app, tab, name):
    from app.classroom.lesson import LESSONS, TAB_VIEWS, lesson_params, lesson_sections, lesson_text, lesson_views

    lesson = LESSONS[name]
    params = {"lesson": "1", **{k: v for k, v in lesson.params.items() if k != "views"}}
    title, text = lesson_text(name)
    sections = dict(lesson_sections(text))
    other = Probe(lesson_ws(lesson.link(app.url))).start()
    try:
        column = lesson_column(other)
        shown = "\n".join(column["texts"])
        # the goal, what to set, what to watch and the questions are open; the answers folded
        assert title in column["texts"][0]
        for part in ("", "What to set", "What to watch", "Questions for students"):
            assert sections[part].splitlines()[-1] in shown, part
        assert "What the class should see" not in shown and "## Figures" not in shown and "```" not in shown
        assert column["folder"]["props"]["label"].startswith("Answers")
        assert column["folder"]["props"]["expand_by_default"] is False
        for part in ("What the class should see", "Figures"):
            assert f"#### {part}" in column["answers"] and sections[part].splitlines()[0] in column["answers"]
        assert "lab.evolve(" in column["answers"]
        # no link to the lesson itself (the tab shows it), at any address; nor a link into the lab's server
        assert "Open the lesson" not in shown and "?websocket=" not in shown + column["answers"]
        assert "](../" not in shown + column["answers"]
        # the lesson's column is docked at the left, the lab's panel at the right: Start stays in view
        other.wait_for(lambda m: m["type"] == "GuiSetPanelPositionMessage" and m["uuid"] == column["panel"]["uuid"]
                       and m["position"] == {"kind": "edge", "edge": "left"})
        other.wait_for(lambda m: m["type"] == "GuiSetPanelPositionMessage" and m["uuid"] == "viser-control-panel"
                       and m["position"] == {"kind": "edge", "edge": "right"})
        # the panel is in the lesson's state: robot, method, settings, race partner, views
        panel = app.panel
        assert wait_until(lambda: lesson_params(panel) == params, 10), (lesson_params(panel), params)
        assert app.state.arm.name == lesson.params["robot"]
        views = lesson_views(lesson.params)
        session = session_of(app, other)
        assert {v: getattr(session, attr).value for v, attr in TAB_VIEWS.items()} == \
            {v: views[v] for v in TAB_VIEWS}
        assert app.show_map.value == views["map"]
        # the text is that tab's own: the first tab has no lesson
        assert not any(m["type"] == "GuiPanelMessage" for _t, m in tab.messages)
        other.click("Close the lesson")
        other.wait_for(lambda m: m["type"] == "GuiPanelRemoveMessage" and m["uuid"] == column["panel"]["uuid"])
        assert wait_until(lambda: session.lesson_view is None, 5)
    finally:
        other.close()
        app.show_map.value = True
        app.panel.race.enabled.value = False
        app.switch_robot("planar")
        app.panel.method.value = "CMA-ES"


def test_opening_a_lesson_after_a_run_shows_that_lessons_fresh_state(app, tab):
    """Lesson 2 opened after lesson 1's run has ended: no finished run's curve, status or network
    is left (as if the lab had just opened on the lesson's arm), until Start."""
    from app.classroom.lesson import LESSONS

    app.panel.generations.value = 20
    tab.click("Start")
    assert wait_until(lambda: app.state.runner is not None and app.state.runner.state == "finished", 60)
    assert app.state.shown.source.startswith("run ")
    other = Probe(lesson_ws(LESSONS["cmaes-vs-neat"].link(app.url))).start()
    try:
        assert wait_until(lambda: app.panel.race.enabled.value and app.panel.method.value == "NEAT", 10)
        assert app.state.runner is None and app.state.partner is None
        assert app.state.progress()["generation"] == 0 and app.state.progress()["state"] == "idle"
        assert not app.state.shown.source.startswith("run ")  # the arm's own network, not the old run's
        assert wait_until(lambda: app.panel.status.content.startswith("**Idle**"), 5)
    finally:
        other.close()
        app.panel.race.enabled.value = False
        app.panel.method.value = "CMA-ES"


def test_an_unknown_lesson_is_refused_by_name_and_changes_nothing(app, tab):
    from app.classroom.lesson import LESSONS, lesson_params

    before = lesson_params(app.panel)
    link = LESSONS["cmaes-vs-neat"].link(app.url).replace("cmaes-vs-neat", "no-such-lesson")
    bad = Probe(lesson_ws(link)).start()
    try:
        bad.wait_for(lambda m: m["type"] == "NotificationShowMessage" and "no-such-lesson" in str(m)
                     and "cmaes-vs-neat" in str(m))  # it names the lesson and the lessons there are
        time.sleep(0.3)
        assert lesson_params(app.panel) == before
        assert not any(m["type"] == "GuiPanelMessage" for _t, m in bad.messages)
    finally:
        bad.close()


def test_a_budgeted_run_goes_at_full_speed_and_a_real_arm_brings_its_budget(app, tab):
    """The Speed menu caps runs without a budget only; picking a real arm fills its live budget."""
    from app.panels.train import REAL_ARM_BUDGET

    set_field(tab, "GuiDropdownMessage", "Speed", "1 generation/s")
    assert wait_until(lambda: app.state.speed == 1.0, 5)
    app.panel.budget.value = 3.0
    tab.click("Start")
    assert wait_until(lambda: generations(app) >= 30, 10)  # far beyond 1 a second
    assert wait_until(lambda: app.state.runner.state == "finished", 15)
    app.panel.budget.value = 0.0
    set_field(tab, "GuiDropdownMessage", "Robot", "ur5")
    assert wait_until(lambda: app.panel.budget.value == REAL_ARM_BUDGET, 10)
    config = app.panel.config()
    assert config.seconds == REAL_ARM_BUDGET and config.turn
    set_field(tab, "GuiDropdownMessage", "Robot", "planar")
    assert wait_until(lambda: app.panel.budget.value == 0.0, 10)
