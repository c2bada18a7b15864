"""Training on pose goals: the pose fitness, pose controllers, TrainConfig.goal, the methods' pose runs."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

import lab
import robots
from lab import methods
from lab.problem.controllers import MLPController, mlp_size
from lab.problem.pose_encoding import PoseEncoding
from lab.problem.pose_fitness import PoseProblem
from robots import pose


def _direct_fitness(arm, enc, q, goals) -> float:
    """The mean of ||p - p_g||^2 + (L angle)^2 by Pinocchio's frame placement and log3 (an approach
    axis: the angle between the axes)."""
    data = arm.model.createData()
    total = 0.0
    for qi, T in zip(q, goals):
        pin.framesForwardKinematics(arm.model, data, arm.to_pinocchio(qi))
        M = data.oMf[arm.ee_frame_id]
        d = M.translation - T[:3, 3]
        if enc.axis is None:
            angle = np.linalg.norm(pin.log3(T[:3, :3].T @ M.rotation))
        else:
            a, g = M.rotation @ enc.axis, T[:3, :3] @ enc.axis
            angle = np.arctan2(np.linalg.norm(np.cross(a, g)), a @ g)
        total += d @ d + (enc.weight * angle) ** 2
    return total / len(goals)


@pytest.mark.parametrize("name, turn, heads, wrist, reach", [
    ("ur5", False, 1, False, 0), ("ur5", True, 2, False, 0), ("panda", True, 1, False, 0), ("so100", True, 3, False, 0),
    ("kinova", False, 1, False, 0), ("ur5", True, 2, True, 0), ("panda", True, 1, True, 0), ("kinova", False, 1, True, 0),
    ("ur5", True, 2, True, 3), ("panda", True, 1, True, 2), ("kinova", True, 1, True, 2), ("so101", True, 2, False, 3)])
def test_pose_fitness_equals_pinocchio_frame_placement_and_log3(name, turn, heads, wrist, reach):
    """With and without the closed-form wrist and reach (lab.problem.pose_encoding): the compiled
    fitness equals the controller's answers measured through Pinocchio."""
    arm = robots.load(name)
    problem = PoseProblem(arm, PoseEncoding.for_arm(arm, "sphere", 0.3, turn, wrist=wrist, reach=reach), targets=40,
                          test_goals=5, goal_seed=3)
    enc = problem.encoding
    rng = np.random.default_rng(1)
    W = rng.normal(0.0, 0.4, (3, mlp_size(enc.n_inputs, 6, enc.n_outputs * heads)))
    controllers = [MLPController(enc, 6, w, heads, None, arm.chain.arrays if heads > 1 else None) for w in W]
    fitness = problem.mlp_mse(W, 6, offsets=None if heads == 1 else controllers[0].offsets)
    # the fitness turns the frame rigidly about the first joint's axis (arm.base_axis) where the
    # controller recomputes the chain: on the SO arms the two agree to about 1e-9
    for c, f in zip(controllers, fitness):
        direct = _direct_fitness(arm, enc, c(problem.train_goals), problem.train_goals)
        assert f == pytest.approx(direct, rel=1e-7)
        assert problem.controller_mse(c) == pytest.approx(direct, rel=1e-7)
    if not enc.exact_pass:  # three different networks, three different figures (an exact pass: the
        assert len(set(np.round(fitness, 12))) == 3  # networks only pick branches, and may pick the same)


def test_pose_controller_round_trips_with_identical_answers():
    arm = robots.load("ur5")
    run = lab.evolve("ur5", goal="pose", generations=5, population=8, targets=20, test_goals=10, seed=2, heads=2)
    c = run.controller
    assert c.goal == "pose" and isinstance(c.encoding, PoseEncoding)
    back = lab.controller_from_dict(json.loads(json.dumps(c.to_dict())))
    T = pose.sample_poses(arm, 50, seed=11)
    assert back.goal == "pose" and np.array_equal(back(T), c(T))
    assert np.array_equal(back.proposals(T), c.proposals(T))
    s = lab.solve(back, arm, T, steps=0)  # lab.solve takes it as a pose controller
    assert s.angle is not None and s.q.shape == (50, arm.nq)


def test_goal_kinds_and_robots_refused_by_name():
    with pytest.raises(ValueError, match="goal must be one of position, pose, got 'orientation'"):
        lab.TrainConfig(robot="ur5", goal="orientation")
    for robot, what in (("planar", "paper's arms"), ("planar-10", "snake"), ("solo12", "tree")):
        with pytest.raises(ValueError, match=f"goal='pose' is for a real arm.*{robot} is .*{what}"):
            lab.TrainConfig(robot=robot, goal="pose")
    with pytest.raises(ValueError, match="orientation"):
        lab.evolve("ur5", goal="orientation", generations=1)


def test_goal_is_left_out_of_to_dict_for_positions_and_kept_for_poses():
    position = lab.TrainConfig(robot="ur5")
    assert "goal" not in position.to_dict() and position.goal == "position"
    posed = lab.TrainConfig(robot="so100", goal="pose")
    assert posed.to_dict()["goal"] == "pose"
    assert lab.TrainConfig.from_dict(posed.to_dict()) == posed
    assert posed.turn is True  # the pose defaults of the default method turn the first joint


def test_a_short_cmaes_pose_run_improves_and_the_same_seed_gives_the_same_run():
    # without the closed-form reach, whose first generation is already near its best (docs/pose.md)
    kw = dict(goal="pose", generations=40, population=10, targets=30, test_goals=20, hidden=8, seed=4, reach=0)
    a = lab.evolve("so100", **kw)
    b = lab.evolve("so100", **kw)
    assert a.history[-1] < 0.8 * a.history[0]
    assert np.allclose(a.history, b.history, rtol=1e-9, atol=0)
    T = pose.sample_poses(robots.load("so100"), 20, seed=1)
    assert np.allclose(a.controller(T), b.controller(T), rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", [m for m in methods.names() if m != methods.DEFAULT_METHOD])
def test_every_method_trains_a_pose_controller(method):
    run = lab.evolve("ur5", method, goal="pose", generations=3, population=None, targets=20, test_goals=10, seed=0)
    assert run.controller.goal == "pose" and np.isfinite(run.test_mse)
    back = lab.controller_from_dict(run.controller.to_dict())
    T = pose.sample_poses(robots.load("ur5"), 5, seed=2)
    assert np.array_equal(back(T), run.controller(T))


@pytest.mark.parametrize("name", ["ur5", "so101"])
def test_pose_gradient_equals_finite_differences(name):
    """Without the closed-form wrist (with it the gradient holds the wrist's joints, so it is not the
    whole derivative: the wrist's solution moves with the joints before it)."""
    arm = robots.load(name)
    problem = PoseProblem(arm, PoseEncoding.for_arm(arm, "sphere", 0.0, False, wrist=False), targets=15,
                          test_goals=5, goal_seed=1)
    enc = problem.encoding
    w = np.random.default_rng(2).normal(0.0, 0.3, mlp_size(enc.n_inputs, 4, enc.n_outputs))
    f, g = problem.mlp_gradient(w, 4)
    assert f == pytest.approx(problem.mlp_mse(w[None], 4)[0], rel=1e-9)
    h = 1e-6
    for i in np.random.default_rng(3).choice(len(w), 8, replace=False):
        e = np.zeros_like(w)
        e[i] = h
        fd = (problem.mlp_mse((w + e)[None], 4)[0] - problem.mlp_mse((w - e)[None], 4)[0]) / (2 * h)
        assert g[i] == pytest.approx(fd, rel=1e-4, abs=1e-8)


SHIPPED = sorted((__import__("pathlib").Path(__file__).resolve().parents[1] / "app" / "pretrained").glob("*-pose-*.json"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_pose_controller_answers_poses_with_the_error_its_file_records(path):
    doc = json.loads(path.read_text())
    robot = doc["settings"]["robot"]
    assert path.name.startswith(f"{robot}-pose-") and doc["settings"]["goal"] == "pose"
    arm = robots.load(robot)
    c = lab.controller_from_dict(doc["controller"])
    assert c.goal == "pose" and np.allclose(c.encoding.q_lo, arm.lower) and np.allclose(c.encoding.q_hi, arm.upper)
    held = doc["held_out"]
    T = pose.sample_poses(arm, held["goals"], seed=held["seed"])
    s = lab.solve(c, arm, T, steps=0)  # the network alone
    # within a nanometre and a microdegree: where the closed form is exact the median is the passes'
    # last rounding, which the CPU's vector width (numba) and the inputs' last bit move
    assert 1000 * np.median(s.error) == pytest.approx(held["median_mm"], rel=1e-6, abs=1e-6)
    assert np.degrees(np.median(s.angle)) == pytest.approx(held["median_deg"], rel=1e-6, abs=1e-6)
