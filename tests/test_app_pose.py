"""The app in pose mode (app/tab/posegoal.py): goals that turn as well as move.

Checked: a pose-mode server's gizmos turn; a turned gizmo's goal is the 4 x 4 of its position and
orientation, and the arm shows the pose controller's answer for it; the refined ghost reaches a
reachable pose within refine's tolerances (position and angle) from the network's answer; the
label gives mm and degrees; a robot without poses refuses pose mode by name (the panel, LabApp,
`python -m app`); back in position mode the gizmo no longer turns and the label has no angle.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

import lab
import robots
from app.tab.posegoal import gizmo_pose, matrix_to_wxyz
from conftest import make_app, session_of, wait_until
from robots import pose

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")

ROBOT = "ur5"
LABEL = re.compile(r"net \d+(\.\d)? (mm|µm), \d+(\.\d+)?(e-\d+)?°")


APP_ARGS = dict(robot=ROBOT, goal="pose", record=True)  # conftest's app and tab fixtures


class NearAnswer:
    """A stand-in pose controller: for the poses it was given, their joints 0.05 rad off (a network's
    answer near a branch), else the rest pose."""

    goal = "pose"

    def __init__(self, arm, poses, q, seed=0):
        self.encoding = SimpleNamespace(q_lo=arm.lower, q_hi=arm.upper)
        noisy = q + np.random.default_rng(seed).normal(0.0, 0.05, q.shape)
        self.table = [(T, arm.within_limits(p)) for T, p in zip(poses, noisy)]
        self.rest = arm.rest

    def __call__(self, poses):
        return np.array([next((q for T, q in self.table if np.allclose(T, P, atol=1e-5)), self.rest)
                         for P in np.asarray(poses).reshape(-1, 4, 4)])


def marker_props(tab, since=0):
    return tab.wait_for(lambda m: m["type"] == "TransformControlsMessage" and m["name"] == "/tab/goal0/marker",
                        since=since)["props"]


def label_texts(tab):
    """Every text the tab was sent for goal 1's label."""
    return [str(m) for _t, m in list(tab.messages) if m.get("name") == "/tab/goal0/label"]


def test_the_app_serves_in_pose_mode_with_gizmos_that_turn(app, tab):
    session = session_of(app, tab)
    assert app.state.goal == "pose" and session.goal_kind == "pose"
    assert app.panel.goal.value == "Pose"
    props = marker_props(tab)
    assert not props["disable_rotations"]
    assert list(props["active_axes"]) == [True, True, True]
    # the first goal starts at a reachable pose whose position is the position mode's first goal
    g = session.goals[0]
    arm = session.arm
    assert np.allclose(g.pose[:3, 3], g.goal)
    assert g.pose[3].tolist() == [0, 0, 0, 1]


def test_a_turned_gizmo_gives_the_goals_rotation_and_the_arm_answers_that_pose(app, tab):
    session = session_of(app, tab)
    arm = session.arm
    T = pose.sample_poses(arm, 3, seed=11)[2]
    wxyz = matrix_to_wxyz(T[:3, :3])
    tab.drag("/tab/goal0/marker", T[:3, 3], wxyz=wxyz)
    g = session.goals[0]
    assert wait_until(lambda: np.allclose(g.pose, T, atol=1e-6))
    assert np.allclose(g.pose[:3, :3], T[:3, :3], atol=1e-6)
    controller = app.state.shown.controller
    assert controller.goal == "pose"
    q = controller(T[None])[0]
    assert wait_until(lambda: g.arm_view.q is not None and np.allclose(g.arm_view.q, q, atol=1e-9))
    # its errors are the pose's: position [m] and angle [rad] of the answer shown
    d, a = pose.pose_errors(arm, T[None], q[None])
    assert g.error == pytest.approx(d[0]) and g.angle == pytest.approx(a[0])
    # turning alone (the same position) changes the goal, hence the network's input
    R = gizmo_pose(T[:3, 3], (np.cos(0.4), np.sin(0.4), 0.0, 0.0))
    tab.drag("/tab/goal0/marker", T[:3, 3], wxyz=(np.cos(0.4), np.sin(0.4), 0.0, 0.0))
    assert wait_until(lambda: np.allclose(g.pose, R, atol=1e-6))
    assert pose.rotation_angle(g.pose[:3, :3], T[:3, :3]) > 1e-3


def test_the_label_gives_mm_and_degrees(app, tab):
    session = session_of(app, tab)
    tab.drag("/tab/goal0/marker", session.goals[0].pose[:3, 3] + 0.01, wxyz=(1.0, 0.0, 0.0, 0.0))
    g = session.goals[0]
    assert wait_until(lambda: LABEL.fullmatch(g.label.text) is not None, timeout=30), g.label.text
    assert wait_until(lambda: any(LABEL.search(t) for t in label_texts(tab)), timeout=30)
    assert wait_until(lambda: "°" in session.table.content)


def test_the_refined_ghost_reaches_a_reachable_pose_from_the_networks_answer(app, tab):
    session = session_of(app, tab)
    arm = session.arm
    T = pose.sample_poses(arm, 5, seed=21)
    q_true = np.array([pose_ik(arm, t) for t in T])
    stand_in = NearAnswer(arm, T, q_true)
    assert app.state.show(stand_in, "a stand-in pose network") is None
    try:
        session.show_ik.value = True
        for k in range(len(T)):
            wxyz = matrix_to_wxyz(T[k][:3, :3])
            tab.drag("/tab/goal0/marker", T[k][:3, 3], wxyz=wxyz)
            g = session.goals[0]
            assert wait_until(lambda: g.seeded is not None and g.refined.q is not None
                              and np.allclose(g.pose, T[k], atol=1e-6)
                              and pose.pose_errors(arm, T[k][None], g.refined.q[None])[0][0] < 1e-4, timeout=30)
            d, a = pose.pose_errors(arm, T[k][None], g.refined.q[None])
            assert d[0] < 1e-4 and a[0] < np.radians(0.1)  # refine's default tolerances
    finally:
        session.show_ik.value = False
        app.state.live()


def pose_ik(arm, T):
    """Joints with the tool frame T (the dls_pose_ik baseline, converged)."""
    from robots.ik import dls_pose_ik

    r = dls_pose_ik(arm, T, restarts=50)
    assert r.converged
    return r.q


def test_a_robot_without_poses_refuses_pose_mode_by_name(app, tmp_path):
    from app.__main__ import main

    with pytest.raises(ValueError, match="real arms"):
        make_app(tmp_path, robot="planar", goal="pose")
    assert main(["--robot", "g1", "--goal", "pose", "--port", "0", "--no-record"]) == 2
    panel = app.panel
    assert panel.set_goal("position") is None
    assert app.switch_robot("planar") is None
    try:
        msg = panel.set_goal("pose")
        assert msg is not None and "real arms" in msg and "planar" in msg
        assert app.state.goal == "position"
    finally:
        assert app.switch_robot(ROBOT) is None
        assert panel.set_goal("pose") is None


def test_position_mode_is_unchanged(app, tab):
    session = session_of(app, tab)
    try:
        n = len(tab.messages)
        assert app.panel.set_goal("position") is None
        assert wait_until(lambda: session.goal_kind == "position", timeout=30)
        props = marker_props(tab, since=n)
        assert props["disable_rotations"]
        goal = session.goals[0].goal
        assert goal.shape == (3,)
        tab.drag("/tab/goal0/marker", goal + 0.01)
        g = session.goals[0]
        q = app.state.shown.controller((goal + 0.01)[None])[0]
        assert wait_until(lambda: g.arm_view.q is not None and np.allclose(g.arm_view.q, q, atol=1e-9))
        assert np.isnan(g.angle)
        assert "°" not in session.table.content
    finally:
        assert app.panel.set_goal("pose") is None


def test_start_in_pose_mode_trains_a_pose_network_drawn_recorded_and_noted(app, tab):
    panel, state = app.panel, app.state
    session = session_of(app, tab)
    panel.budget.value = 0.0
    panel.generations.value = 100_000
    panel.population.value = 10
    try:
        assert panel.start() is None, panel.message.content
        assert state.runner.config.goal == "pose"
        assert wait_until(lambda: state.progress()["generation"] >= 3, timeout=120)
        assert wait_until(lambda: state.shown.source.startswith("run"), timeout=60)
        assert state.shown.controller.goal == "pose"
        # the tab's arm answers its pose goal with the run's network; the population is drawn at it
        assert wait_until(lambda: session.version == state.shown.version, timeout=30)
        g = session.goals[0]
        assert wait_until(lambda: g.cloud is not None and g.cloud.visible, timeout=30)
        assert np.asarray(g.cloud.points).shape[0] == 10
        assert state.recording is not None  # the Rerun recording of a pose run
        assert app.training_goals().shape == (state.runner.config.targets, 3)  # the red points: their positions
        # the views are redrawn by the render loop once a second after the shown network changes
        assert wait_until(lambda: "No error map for pose goals" in app.map_legend.content, timeout=15)
        run_id = state.runner.run_id
    finally:
        state.reset()
        panel.generations.value = 1000
    # the run's notebook entry replays in pose mode; in position mode, replaying it brings pose goals back
    entry = next(e for e in state.notebook.entries() if e["run_id"] == run_id)
    assert entry["settings"]["goal"] == "pose"
    assert panel.set_goal("position") is None
    try:
        controller = lab.controller_from_dict(entry["controller"])
        assert app.runs._show(entry["robot"], controller, "a pose run", None) is None
        assert state.goal == "pose" and state.shown.controller.goal == "pose"
        assert wait_until(lambda: session.goal_kind == "pose", timeout=30)
    finally:
        state.live()
        assert panel.set_goal("pose") is None


def test_a_lesson_link_carries_the_goal_kind(app):
    from app.classroom.lesson import check_lesson, lesson_params

    params = lesson_params(app.panel)
    assert params["goal"] == "pose" and params["robot"] == ROBOT
    main, _partner, _views, _text = check_lesson(params)
    assert main.goal == "pose"
    with pytest.raises(ValueError, match="real arms"):
        check_lesson({**params, "robot": "planar"})


def test_the_pose_lesson_link_opens_pose_mode_and_position_lessons_go_back(app):
    from app.classroom.lesson import LESSONS, apply_lesson

    panel = app.panel
    assert panel.set_goal("position") is None
    try:
        assert apply_lesson(app, {"lesson": "1", **LESSONS["position-or-pose"].params}) is None
        assert app.state.goal == "pose" and app.state.arm.name == ROBOT and panel.goal.value == "Pose"
        assert panel.config().goal == "pose"
        # a lesson without goal= is a position lesson: it puts the goals back to positions
        assert apply_lesson(app, {"lesson": "1", "robot": ROBOT, "method": panel._method_name()}) is None
        assert app.state.goal == "position" and panel.goal.value == "Position"
    finally:
        assert panel.set_goal("pose") is None


def test_the_panel_quotes_the_pose_networks_figures_in_pose_mode():
    """In pose mode the panel quotes the shipped pose network's held-out figures (mm and degrees), not
    the position runs' budget figures; nothing where the method shipped no pose network."""
    import json

    from app.panels.train import expectation
    from app.startup import pretrained_path

    held = json.loads(open(pretrained_path("panda", "cmaes", goal="pose"), encoding="utf-8").read())["held_out"]
    said = expectation("panda", "cmaes", 30.0, "pose")
    assert f"{held['median_mm']:.1f} mm, {held['median_deg']:.1f}° median on held-out poses" in said
    assert "wrist, elbow and shoulder solved in closed form" in said and "of its reach" not in said
    for robot in ("so101", "ur5", "z1"):  # a pass solves every joint (PoseEncoding.exact_pass)
        assert "every joint solved in closed form" in expectation(robot, "cmaes", 30.0, "pose")
    assert expectation("panda", "neat", 30.0, "pose") == ""
    assert "of its reach" in expectation("panda", "cmaes", 30.0)  # position goals: the budgets' figure
