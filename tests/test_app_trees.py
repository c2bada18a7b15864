"""The app on trees (robots of several end effectors: talos-legs, g1), driven by headless tabs.

Checked: a goal has one marker per end effector (added and removed goals too); dragging one moves
only that effector's goal, the pose sent is Pinocchio's for q = controller(goal) and the errors
are each effector's ||reach(q) - goal|| (the label: the worst); the classical IK beside it reports
the worst effector of its own answers; training from the panel with every method, the population
drawn at every effector, a race and the replay of a recording work on a tree.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from viser import _messages

import lab
import robots
from app.tab.goals import fmt_len, marker_name
from app.training.notebook import label
from conftest import METHODS, last_pose, make_app, session_of, wait_until
from lab.recording.replay import load_controller

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")

TREES = ("talos-legs", "g1")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    lab_app = make_app(tmp_path_factory.mktemp("trees"), robot="talos-legs", record=True)
    yield lab_app
    lab_app.stop()


@pytest.fixture
def tab(tab, app):  # conftest's tab and this module's app
    yield tab
    app.state.reset()
    app.panel.race.enabled.value = False
    app.runs.live()


def on(app, tab, robot: str) -> None:
    """Show `robot` in every tab; returns once `tab`'s goals are rebuilt for it."""
    session = session_of(app, tab)
    assert app.switch_robot(robot) is None
    assert wait_until(lambda: session.arm.name == robot and session.goals, 30)


def set_field(probe, kind: str, label_: str, value) -> None:
    msg = probe.wait_for(lambda m: m["type"] == kind and m["props"]["label"] == label_)
    probe.send(_messages.GuiUpdateMessage(uuid=msg["uuid"], updates={"value": value}))


def pose_is_pinocchios(probe, arm, q, prefix: str) -> bool:
    """Every moving joint of the arm drawn under `prefix`, as last sent, where Pinocchio puts it for q."""
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, arm.to_pinocchio(q))
    for j in range(1, arm.model.njoints):
        try:
            pos, wxyz = last_pose(probe, f"{prefix}/j{j}")
        except StopIteration:
            return False
        R = pin.Quaternion(wxyz[0], *wxyz[1:]).toRotationMatrix()
        if not (np.allclose(pos, data.oMi[j].translation, atol=1e-6) and np.allclose(R, data.oMi[j].rotation, atol=1e-6)):
            return False
    return True


def test_the_trees_are_offered_and_a_bad_goal_is_refused(app, tab):
    assert set(TREES) <= set(app.panel.robot.options)
    assert set(robots.names()) <= set(app.panel.robot.options)
    assert app.panel.budget.value == 30.0  # a tree opens with the real arms' budget
    session = session_of(app, tab)
    arm = session.arm
    assert arm.is_tree and app.show_map.disabled and "No error map" in app.map_legend.content
    with pytest.raises(ValueError, match="one per end effector"):
        session.add_goal(np.zeros(3))  # one point for a robot of two effectors
    assert len(session.goals) == 1


@pytest.mark.parametrize("robot", TREES)
def test_a_goal_has_a_marker_per_effector_and_added_goals_too(app, tab, robot):
    on(app, tab, robot)
    session = session_of(app, tab)
    arm = session.arm
    assert arm.name == robot and arm.n_effectors >= 2
    assert wait_until(lambda: {marker_name(0, e) for e in range(arm.n_effectors)} <= {
        m["name"] for _t, m in list(tab.messages) if m["type"] == "TransformControlsMessage"}, 10)
    g = session.goals[0]
    assert g.goal.shape == (arm.n_effectors, 3)
    # the default goal: where its effectors are at rest (a humanoid stands), where the runs draw the population
    np.testing.assert_allclose(g.goal, arm.reach(arm.rest))
    assert session.add_goal() is None
    extra = session.goals[1]
    assert len(extra.markers) == arm.n_effectors and extra.goal.shape == (arm.n_effectors, 3)
    assert wait_until(lambda: {marker_name(1, e) for e in range(arm.n_effectors)}
                      <= {m["name"] for _t, m in list(tab.messages) if m["type"] == "TransformControlsMessage"})
    assert session.remove_goal() is None and len(session.goals) == 1
    assert wait_until(lambda: marker_name(1, arm.n_effectors - 1) in {
        m["name"] for _t, m in list(tab.messages) if m["type"] == "RemoveSceneNodeMessage"})
    on(app, tab, "talos-legs")


@pytest.mark.parametrize("robot", TREES)
def test_dragging_an_effector_moves_the_pose_to_the_controllers_answer(app, tab, robot):
    on(app, tab, robot)
    session = session_of(app, tab)
    arm, g = session.arm, session.goals[0]
    controller = app.state.shown.controller
    assert controller is not None
    goal = g.goal.copy()
    target = arm.sample_goals(4, seed=21)[3]
    for e in (0, arm.n_effectors - 1):  # a hand, a foot; the other effectors' goals stay
        tab.drag(marker_name(0, e), arm.to_3d(target[e]))
        goal[e] = target[e]
        assert wait_until(lambda: np.allclose(g.goal, goal), 10)
    q = controller(goal[None])[0]
    assert wait_until(lambda: pose_is_pinocchios(tab, arm, q, "/tab/goal0/arm"), 10)
    errors = np.linalg.norm(arm.reach(q) - goal, axis=-1)
    np.testing.assert_allclose(g.errors, errors)
    assert g.error == pytest.approx(errors.max())
    text = f"net {fmt_len(arm, errors.max())} (worst of {arm.n_effectors})"
    assert wait_until(lambda: g.label.text == text)
    # the label stands beside the marker dragged last
    pos, _ = last_pose(tab, "/tab/goal0/label")
    np.testing.assert_allclose(pos, arm.to_3d(goal[arm.n_effectors - 1]) + session.ws["label_offset"], atol=1e-6)
    session.write_table()
    assert all(fmt_len(arm, x) in session.details.content for x in errors)
    on(app, tab, "talos-legs")


def test_classical_ik_beside_it_on_a_tree(app, tab):
    session = session_of(app, tab)
    arm, g = session.arm, session.goals[0]
    set_field(tab, "GuiCheckboxMessage", "Classical IK beside it", True)
    assert wait_until(lambda: g.ik is not None and g.seeded is not None, 20)
    goal = g.goal
    dls = np.linalg.norm(arm.reach(g.ik.q) - goal, axis=-1).max()
    assert g.ik_error == pytest.approx(dls)
    assert g.ik_error < 0.01  # from the rest pose, on a reachable goal
    seeded_q = g.refined.q
    assert g.seeded[0] == pytest.approx(np.linalg.norm(arm.reach(seeded_q) - goal, axis=-1).max())
    assert g.seeded[0] < g.error  # the refinement improves on the network
    assert wait_until(lambda: pose_is_pinocchios(tab, arm, g.ik.q, "/tab/goal0/ik"), 10)
    assert wait_until(lambda: fmt_len(arm, g.ik_error) in session.details.content, 10)


@pytest.mark.parametrize("method", METHODS)
def test_training_from_the_panel_on_a_tree_draws_every_effectors_population(app, tab, method):
    panel, state = app.panel, app.state
    session = session_of(app, tab)
    arm = session.arm
    panel.method.value = lab.methods.get(method).label
    panel.budget.value = 0
    panel.generations.value = 12
    panel.population.value = float(lab.TrainConfig.preset(robot=arm.name, method=method).population if method == "neat"
                                   else 10)
    panel.reset()  # the untrained network of the run Start makes
    assert wait_until(lambda: state.shown.source.startswith("untrained"), 30)
    assert panel.start() is None, panel.message.content
    runner = state.runner
    runner.join(120)
    assert runner.state == "finished" and state.progress()["generation"] == 12
    population = state.track.population
    assert population is not None and population.points.shape == (len(population), arm.n_effectors, 3)
    g = session.goals[0]

    def drawn() -> bool:
        if g.cloud is None or population.controllers is None:
            return False
        expected = population.reach(arm, g.goal[None])[:, 0].reshape(-1, 3)
        return np.asarray(g.cloud.points).shape == expected.shape and np.allclose(g.cloud.points, expected, atol=1e-4)

    assert wait_until(drawn, 10)
    parents = arm.point_parents
    assert wait_until(lambda: g.faint is not None and np.asarray(g.faint.points).shape
                      == (len(population) * int((parents >= 0).sum()), 2, 3), 10)
    entry = state.notebook.entries()[-1]
    assert entry["robot"] == arm.name and entry["method"] == method


def test_a_race_on_a_tree(app, tab):
    panel, state = app.panel, app.state
    session = session_of(app, tab)
    panel.budget.value = 0
    panel.generations.value, panel.population.value = 100_000, 10
    set_field(tab, "GuiCheckboxMessage", "Race a second run", True)
    set_field(tab, "GuiDropdownMessage", "Partner method", "Gradient (Adam)")
    assert wait_until(lambda: panel.race.enabled.value and panel.race.method.value == "Gradient (Adam)", 5)
    assert panel.start() is None, panel.message.content
    assert wait_until(lambda: state.partner is not None and len(state.partner.track) >= 3
                      and state.progress()["generation"] >= 3, 60)
    g = session.goals[0]
    assert wait_until(lambda: g.partner_view is not None and g.partner_view.visible, 10)
    state.pause()
    assert wait_until(lambda: all(r.holding is not None for r in state.runners()), 20)
    partner = state.partner.controller
    assert wait_until(lambda: state.partner.controller is partner and g.partner_view.q is not None
                      and np.allclose(g.partner_view.q, partner(g.goal[None])[0]), 10)
    q = partner(g.goal[None])[0]
    assert g.partner_error == pytest.approx(np.linalg.norm(session.arm.reach(q) - g.goal, axis=-1).max())
    state.stop()


def test_a_recorded_tree_run_replays(app, tab):
    panel, state = app.panel, app.state
    session = session_of(app, tab)
    arm = session.arm
    panel.method.value = lab.methods.get("cmaes").label
    panel.budget.value = 0
    panel.generations.value, panel.population.value = 20, 10
    assert panel.start() is None, panel.message.content
    state.runner.join(120)
    entry = state.notebook.entries()[-1]
    assert entry["robot"] == arm.name and entry["recording"]
    app.runs.refresh(force=True)
    assert app.runs.open(label(entry)) is None, app.runs.message.content
    goal = session.goals[0].goal
    for generation in (1, 20):
        app.runs.slider.value = generation
        expected = load_controller(entry["recording"], generation - 1)
        assert np.allclose(state.shown.controller(goal[None]), expected(goal[None]))
        q = expected(goal[None])[0]
        g = session.goals[0]
        assert wait_until(lambda: np.allclose(g.errors, np.linalg.norm(arm.reach(q) - goal, axis=-1)), 10)
    # the population the recording logged at that generation: every effector's point of each candidate
    recorded = state.replayed_population
    assert recorded is not None and recorded.points.shape == (len(recorded), arm.n_effectors, 3)
    assert wait_until(lambda: g.cloud is not None and np.allclose(g.cloud.points, recorded.points.reshape(-1, 3)), 10)
    app.runs.live()


def test_a_shipped_tree_controller_is_picked_up_and_a_missing_one_is_trained(tmp_path, monkeypatch):
    """app/pretrained/<tree>-<method>.json, in the serial arms' format, opens the tree; without one
    a quick run is trained instead (as for an arm)."""
    import app.startup as startup
    from lab.experiments import arms

    monkeypatch.setattr(startup, "PRETRAINED_DIR", str(tmp_path))
    controller, note = startup.startup_controller("talos-legs")  # no file: a quick run
    assert note.startswith("trained at startup") and startup.made_for(controller, robots.load("talos-legs"))
    run = lab.evolve("talos-legs", generations=5, population=10, seed=0)
    path = startup.write_pretrained(run, arms.held_out(robots.load("talos-legs"), run.controller))
    assert path == str(tmp_path / "talos-legs-cmaes.json")
    controller, note = startup.startup_controller("talos-legs")
    assert note.startswith("shipped (5 generations, median error")
    goals = robots.load("talos-legs").sample_goals(3, seed=1)
    np.testing.assert_allclose(controller(goals), run.controller(goals))


def test_a_lesson_link_on_a_tree_opens_it_in_another_tab(app, tab):
    from urllib.parse import unquote

    from app.classroom.lesson import lesson_params
    from app.probe import Probe

    panel = app.panel
    session = session_of(app, tab)
    on(app, tab, "g1")
    panel.seed.value = 3
    params = lesson_params(panel)
    assert params["robot"] == "g1"
    assert wait_until(lambda: "Open this lesson" in session.lesson.content and "g1" in session.lesson.content
                      and "seed 3" in session.lesson.content, 5)
    link = session.lesson.content.split("](", 1)[1].split(")", 1)[0]
    on(app, tab, "talos-legs")
    other = Probe(unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")).start()
    try:
        other.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
        assert wait_until(lambda: lesson_params(panel) == params, 10), (lesson_params(panel), params)
        assert app.state.arm.name == "g1"
        assert wait_until(lambda: marker_name(0, 3) in {m["name"] for _t, m in list(other.messages)
                                                         if m["type"] == "TransformControlsMessage"}, 10)
    finally:
        other.close()
        panel.seed.value = 0
        on(app, tab, "talos-legs")
