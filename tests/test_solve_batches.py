"""lab.solve on batches of any size: an empty batch gives an empty answer of the right
shapes (it blamed "q0 must be (0, 6)", a q0 never given); a large one is solved CHUNK goals at a time,
each goal's answer the one it gets in a smaller batch, with a progress line once the call has run a
few seconds (a million poses grew memory without bound and said nothing)."""

import inspect
import json
import os

import numpy as np
import pytest

import lab
import lab.solver as solver
import robots
from robots import pose

PRETRAINED = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "app", "pretrained")


def shipped(name):
    with open(os.path.join(PRETRAINED, f"{name}-cmaes.json"), encoding="utf-8") as f:
        return lab.controller_from_dict(json.load(f)["controller"])


class FakePoseController:
    goal = "pose"

    def __init__(self, arm, seed=0):
        self.arm, self.seed = arm, seed

    def proposals(self, poses):  # two answers a goal, a function of the goal alone
        base = np.tile(self.arm.rest, (len(poses), 1)) + 0.1 * poses[:, :3, 3].sum(axis=1, keepdims=True)
        return np.stack([self.arm.within_limits(base), self.arm.within_limits(base - 0.2)])

    def __call__(self, poses):
        return self.proposals(poses)[0]


def _fields_equal(a, b):
    for name in ("q", "error", "angle", "converged", "steps", "choice", "network_error", "network_angle"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.tol == b.tol and a.angle_tol == b.angle_tol


# ---------------------------------------------------------------- an empty batch
@pytest.mark.parametrize("name", ["ur5", "talos-legs", "planar"])
def test_an_empty_batch_of_positions_gives_an_empty_answer(name):
    arm = robots.load(name)
    empty = np.zeros((0, *((arm.n_effectors,) if arm.is_tree else ()), len(arm.task_axes)))
    for controller in (None, shipped(name)):
        s = lab.solve(controller, arm, empty)
        assert s.q.shape == (0, arm.nq) and s.error.shape == s.converged.shape == s.steps.shape == (0,)
        assert s.angle is None and s.angle_tol is None and s.tol > 0 and np.isnan(s.success)
        assert (s.network_error is None) == (controller is None)
        if controller is not None:
            assert s.network_error.shape == (0,)
    s = lab.solve(None, arm, empty, q0=np.zeros((0, arm.nq)))
    assert s.q.shape == (0, arm.nq)


def test_an_empty_batch_of_poses_gives_an_empty_answer():
    arm = robots.load("ur5")
    for controller in (None, FakePoseController(arm)):
        for kw in ({}, {"q0": np.zeros((0, 6))}, {"seconds": 0.01}, {"steps": 0}):
            s = lab.solve(controller, arm, np.zeros((0, 4, 4)), **kw)
            assert s.q.shape == (0, 6) and s.error.shape == s.angle.shape == s.converged.shape == (0,)
            assert s.tol > 0 and s.angle_tol > 0  # the tolerances the goals would be held to
            assert (s.network_angle is None) == (controller is None)
    r = robots.ik.refine(arm, np.zeros((0, 4, 4)), np.zeros((0, 6)))  # refine itself too
    assert r.q.shape == (0, 6) and r.angle.shape == (0,)
    r = robots.ik.refine(arm, np.zeros((0, 3)), np.zeros((0, 6)))
    assert r.q.shape == (0, 6) and r.error.shape == (0,)


def test_an_empty_batch_still_refuses_what_is_wrong():
    arm = robots.load("ur5")
    with pytest.raises(ValueError, match=r"q0 must be \(0, 6\)"):  # a q0 that was given, and is wrong
        lab.solve(None, arm, np.zeros((0, 4, 4)), q0=np.zeros((2, 6)))
    with pytest.raises(ValueError, match="answers 7 joints, the arm has 6"):
        lab.solve(shipped("panda"), arm, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="seconds .* applies to pose goals"):
        lab.solve(None, arm, np.zeros((0, 3)), seconds=1.0)


# ---------------------------------------------------------------- chunks
def test_chunks_give_the_answers_of_one_batch(monkeypatch):
    so100 = robots.load("so100")
    goals = so100.sample_goals(40, seed=3)
    whole = lab.solve(shipped("so100"), so100, goals)
    ur5 = robots.load("ur5")
    poses = pose.sample_poses(ur5, 30, seed=2)
    q0 = ur5.sample_q(30, seed=8)
    whole_pose = lab.solve(FakePoseController(ur5), ur5, poses, q0=q0, steps=4)
    tree = robots.load("talos-legs")
    tree_goals = tree.sample_goals(25, seed=4)
    whole_tree = lab.solve(shipped("talos-legs"), tree, tree_goals)
    monkeypatch.setattr(solver, "CHUNK", 7)
    _fields_equal(lab.solve(shipped("so100"), so100, goals), whole)
    _fields_equal(lab.solve(FakePoseController(ur5), ur5, poses, q0=q0, steps=4), whole_pose)
    _fields_equal(lab.solve(shipped("talos-legs"), tree, tree_goals), whole_tree)


def test_no_chunk_holds_more_than_chunk_goals(monkeypatch):
    """What bounds the memory: the network's proposals and refinement see CHUNK goals at a time."""
    seen, inner = [], solver._chunk

    def counted(*args):
        seen.append(len(inspect.signature(inner).bind(*args).arguments["goals"]))
        return inner(*args)

    monkeypatch.setattr(solver, "CHUNK", 16)
    monkeypatch.setattr(solver, "_chunk", counted)
    arm = robots.load("panda")
    s = lab.solve(shipped("panda"), arm, arm.sample_goals(100, seed=1), steps=1)
    assert max(seen) <= 16 and sum(seen) == 100 and s.q.shape == (100, 7)
    seen.clear()
    poses = pose.sample_poses(arm, 37, seed=1)
    s = lab.solve(None, arm, poses, steps=0)
    assert max(seen) <= 16 and sum(seen) == 37
    np.testing.assert_array_equal(s.q, np.tile(arm.rest, (37, 1)))


def test_a_budgeted_chunk_keeps_each_goals_own_generator(monkeypatch):
    """seconds: goal i draws its restarts from seed + i whichever chunk it is in."""
    calls = []
    monkeypatch.setattr(solver.pose_solve.PoseSolver, "solve",
                        lambda self, goal, seeds, **kw: calls.append(kw["seed"]) or _fake_result(seeds[0]))
    monkeypatch.setattr(solver, "CHUNK", 4)
    arm = robots.load("ur5")
    lab.solve(None, arm, pose.sample_poses(arm, 10, seed=0), seconds=0.001, seed=100)
    assert calls == list(range(100, 110))


def _fake_result(q):
    class R:
        pass

    r = R()
    r.q, r.error, r.angle, r.converged, r.iterations = q, 1.0, 1.0, False, 0
    return r


def test_a_long_call_says_how_far_it_has_come(monkeypatch, capsys):
    arm = robots.load("planar")
    goals = arm.sample_goals(50, seed=0)
    monkeypatch.setattr(solver, "CHUNK", 10)
    lab.solve(None, arm, goals, steps=1)  # quick: nothing said
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(solver, "PROGRESS_AFTER", 0.0)  # as if each chunk took seconds
    lab.solve(None, arm, goals, steps=1)
    err = capsys.readouterr().err
    assert "lab.solve planar" in err and "50/50" in err
    lab.solve(None, arm, goals, steps=1, progress=False)
    assert capsys.readouterr().err == ""
