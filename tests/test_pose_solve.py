"""robots.pose_solve: the compiled pose solver's residual equals robots.pose.residual (Pinocchio's
frame, log3 and Jlog3), its descents reach reachable poses within 1e-5, the same seed gives the same
answer, and bad calls are refused by name; lab.solve(..., seconds=) runs it from a network's proposals.
Success is what holds on any machine; the exact bits of an answer may differ with the CPU's vector
width (numba compiles for the CPU it runs on), so answers are compared within 1e-12, not bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import lab
import robots
from robots import pose, pose_solve

ROOT = Path(__file__).resolve().parents[1]
TIGHT = 1e-5  # TRAC-IK's tolerance, in metres and radians


def _compiled_residual(arm, q, goal, length, want_j=True):
    chain, tool, axis = pose_solve._setup(arm)
    n = arm.nq
    e, Je = np.empty(6), np.zeros((6, n))
    scratch = (np.empty((n, 12)), np.empty((1, 1, 3)), np.empty((1, n + 1, 3)), np.empty((n, 3)), np.empty((3, 3)),
               np.empty((3, 3)), np.empty(3), np.empty((3, 3)))
    norm, err_p, err_a = pose_solve._residual(q[None].copy(), np.ascontiguousarray(goal[:3, :3]),
                                              np.ascontiguousarray(goal[:3, 3]), chain, tool, axis, length, e, Je,
                                              want_j, scratch)
    return e, Je, norm, err_p, err_a


@pytest.mark.parametrize("theta", [0.0, 1e-9, 0.3, 2.0, 3.0, np.pi - 1e-5])
def test_log3_and_its_jacobian_equal_pinocchios(theta):
    rng = np.random.default_rng(3)
    for _ in range(5):
        axis = rng.normal(size=3)
        E = pin.exp3(theta * axis / np.linalg.norm(axis))
        w, M = np.empty(3), np.empty((3, 3))
        angle = pose_solve._log3(E, w)
        assert angle == pytest.approx(theta, abs=1e-7)
        np.testing.assert_allclose(pin.exp3(w), E, atol=1e-7)  # near a half turn: either sign of the axis
        if theta < 3.0:
            np.testing.assert_allclose(w, pin.log3(E), atol=1e-9)
            pose_solve._jr_inv(w, angle, M)
            np.testing.assert_allclose(M, pin.Jlog3(E), atol=1e-7)


@pytest.mark.parametrize("name", ["ur5", "panda", "so100", "so101"])
def test_the_compiled_residual_equals_pinocchios(name):
    """e, Je and both errors of the compiled kernel against robots.pose.residual on Pinocchio's frame
    and Jacobian, far from the goal: the full pose (log3, Jlog3) and the approach axis alike."""
    arm = robots.load(name)
    axis = pose.approach_axis(arm)
    data = arm.model.createData()
    for goal, q in zip(pose.sample_poses(arm, 4, seed=11), arm.sample_q(4, seed=12)):
        x = arm.to_pinocchio(q)
        J6 = pin.computeFrameJacobian(arm.model, data, x, arm.ee_frame_id, pin.LOCAL_WORLD_ALIGNED)
        e_ref, Je_ref, p_ref, a_ref = pose.residual(goal, data.oMf[arm.ee_frame_id], J6, axis, 0.3)
        e, Je, norm, err_p, err_a = _compiled_residual(arm, q, goal, 0.3)
        np.testing.assert_allclose(e, e_ref, atol=1e-10)
        np.testing.assert_allclose(Je, Je_ref, atol=1e-9)
        assert norm == pytest.approx(np.linalg.norm(e_ref), abs=1e-10)
        assert (err_p, err_a) == pytest.approx((p_ref, a_ref), abs=1e-9)


@pytest.mark.parametrize("name", ["ur5", "panda", "xarm7", "so100"])
def test_reachable_poses_are_solved_within_1e5_and_checked_by_pinocchio(name):
    arm = robots.load(name)
    goals = pose.sample_poses(arm, 40, seed=21)
    data = arm.model.createData()
    for i, goal in enumerate(goals):
        r = pose_solve.solve_pose(arm, goal, restarts=200, seconds=None, tol=TIGHT, angle_tol=TIGHT, seed=i)
        assert r.converged, (i, r)
        assert np.all(r.q >= arm.lower) and np.all(r.q <= arm.upper)
        pin.framesForwardKinematics(arm.model, data, arm.to_pinocchio(r.q))
        M = data.oMf[arm.ee_frame_id]
        assert np.linalg.norm(M.translation - goal[:3, 3]) == pytest.approx(r.error, abs=1e-12)
        assert r.error < TIGHT and r.angle < TIGHT
        p, a = pose.pose_errors(arm, goal[None], r.q[None])
        assert a[0] == pytest.approx(r.angle, abs=1e-9)


def test_a_good_start_needs_no_restart_and_the_same_seed_gives_the_same_answer():
    arm = robots.load("panda")
    q_true = arm.sample_q(10, seed=31)
    goals = pose.fk_pose(arm, q_true)
    near = arm.within_limits(q_true + 0.02)
    for i, goal in enumerate(goals):
        r = pose_solve.solve_pose(arm, goal, near[i], seconds=None)
        assert r.converged and r.restarts == 0 and r.iterations <= 10
    far = pose.sample_poses(arm, 5, seed=32)
    for goal in far:
        a = pose_solve.solve_pose(arm, goal, restarts=30, seconds=None, seed=7)
        b = pose_solve.solve_pose(arm, goal, restarts=30, seconds=None, seed=7)
        np.testing.assert_allclose(a.q, b.q, atol=1e-12)
        assert (a.restarts, a.iterations, a.converged) == (b.restarts, b.iterations, b.converged)


def test_no_restarts_without_a_budget_and_the_budget_is_kept():
    arm = robots.load("ur5")
    goal = pose.sample_poses(arm, 1, seed=41)[0]
    r = pose_solve.solve_pose(arm, goal, arm.rest, seconds=None, iterations=1)
    assert r.restarts == 0 and r.iterations == 1
    # an unreachable pose: past full reach, every start stalls; the budget ends the restarts
    out = goal.copy()
    out[:3, 3] = [5.0, 0.0, 0.0]
    r = pose_solve.solve_pose(arm, out, seconds=0.05)
    assert not r.converged and r.restarts > 0 and r.seconds < 1.0


@pytest.mark.parametrize("call, message", [
    (lambda arm, g: pose_solve.solve_pose(arm, np.eye(3)), "4, 4"),
    (lambda arm, g: pose_solve.solve_pose(arm, np.stack([g, g])), "solves one pose"),
    (lambda arm, g: pose_solve.solve_pose(arm, g, np.zeros(5)), "starts must be"),
    (lambda arm, g: pose_solve.solve_pose(arm, g, np.full(6, np.nan)), "starts must be"),
    (lambda arm, g: pose_solve.solve_pose(arm, g, iterations=0), "iterations"),
    (lambda arm, g: pose_solve.solve_pose(arm, g, tol=-1.0), "tol"),
    (lambda arm, g: lab.solve(None, arm, g[None], seconds=0.0), "seconds"),
    (lambda arm, g: lab.solve(None, arm, g[None, :3, 3], seconds=0.005), "applies to pose goals"),
])
def test_bad_calls_are_refused_by_name(call, message):
    arm = robots.load("ur5")
    goal = pose.sample_poses(arm, 1, seed=51)[0]
    with pytest.raises(ValueError, match=message):
        call(arm, goal)


def test_lab_solve_with_a_budget_runs_the_compiled_solver_from_the_networks_proposals():
    arm = robots.load("ur5")
    with open(ROOT / "app" / "pretrained" / "ur5-pose-cmaes.json") as f:
        controller = lab.controller_from_dict(json.load(f)["controller"])
    goals = pose.sample_poses(arm, 20, seed=61)
    s = lab.solve(controller, arm, goals, seconds=0.05, tol=TIGHT, angle_tol=TIGHT)
    assert s.converged.all()
    p, a = pose.pose_errors(arm, goals, s.q)
    np.testing.assert_allclose(s.error, p, atol=1e-12)
    np.testing.assert_allclose(s.angle, a, atol=1e-9)
    np.testing.assert_allclose(s.network_error, pose.pose_errors(arm, goals, controller(goals))[0], atol=1e-12)
    starts = np.asarray(controller.proposals(goals))
    for i in (0, 7):
        r = pose_solve.solve_pose(arm, goals[i], starts[:, i], seconds=0.05, tol=TIGHT, angle_tol=TIGHT, seed=i)
        np.testing.assert_allclose(s.q[i], r.q, atol=1e-12)
