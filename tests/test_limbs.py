"""robots.limbs: a tree's hip-and-knee limbs solved in closed form. The solutions are checked through
Pinocchio's own kinematics (arm.reach), never against the module's own formulas."""

import numpy as np
import pytest

import robots
from robots.limbs import hips, solve

N = 60


def test_the_hips_are_found_where_four_revolute_joints_have_two_axes_that_meet():
    g1 = {h.effector: h for h in hips(robots.load("g1"))}
    assert sorted(g1) == [0, 1, 2, 3]  # both hands, both feet
    for e in (0, 1):  # the shoulders: their roll and yaw axes pass 6.24 mm apart, under the waist
        assert g1[e].prefix == (12, 13, 14) and not g1[e].exact
        assert g1[e].gap == pytest.approx(6.24e-3, abs=1e-4)
    for e in (2, 3):  # the hips: roll and yaw meet, nothing shared
        assert g1[e].prefix == () and g1[e].exact
    assert [h.joints for h in hips(robots.load("talos-legs"))] == [(0, 1, 2, 3), (6, 7, 8, 9)]
    assert hips(robots.load("solo12")) == ()  # three joints a leg
    assert [h.effector for h in hips(robots.load("allegro"))] == [3]  # the thumb; the fingers' axes are parallel
    assert hips(robots.load("ur5")) == ()  # a serial arm


@pytest.mark.parametrize("robot", ["g1", "talos-legs", "allegro"])
def test_the_joints_that_reached_a_goal_are_among_the_solutions_for_their_first_joint(robot):
    arm = robots.load(robot)
    true = arm.sample_q(N, seed=0)
    goals = arm.reach(true)
    for hip in hips(arm):
        if not hip.exact:
            continue
        joints = list(hip.joints)
        values, found = hip.nearest(arm, goals[:, hip.effector], true, true[:, joints[:1]].copy())
        assert found.all()
        np.testing.assert_allclose(values, true[:, joints], atol=1e-9)


@pytest.mark.parametrize("robot", ["g1", "talos-legs"])
def test_a_solved_limb_lands_on_its_goal_from_a_seed_anywhere(robot):
    """Exact hips to rounding; g1's shoulders, whose axes miss each other, to micrometres in the median
    after the corrections (refine takes them the rest of the way)."""
    arm = robots.load(robot)
    goals = arm.reach(arm.sample_q(N, seed=1))
    q, solved = solve(arm, goals, arm.sample_q(N, seed=2))
    error = np.linalg.norm(arm.reach(q) - goals, axis=-1)
    for hip in hips(arm):
        e = hip.effector
        assert solved[:, e].mean() >= 0.8, (hip, solved[:, e].mean())
        if hip.exact:
            assert error[solved[:, e], e].max() < 1e-9
        else:
            assert np.median(error[solved[:, e], e]) < 1e-5


def test_solve_never_takes_a_limb_group_farther_from_its_goals():
    arm = robots.load("g1")
    true = arm.sample_q(N, seed=3)
    goals = arm.reach(true)
    q, _ = solve(arm, goals, true)  # already on every goal: nothing nearer, the same joints to rounding
    np.testing.assert_allclose(q, true, atol=1e-9)
    seed = arm.sample_q(N, seed=4)
    before = np.linalg.norm(arm.reach(seed) - goals, axis=-1)
    after = np.linalg.norm(arm.reach(solve(arm, goals, seed)[0]) - goals, axis=-1)
    for group in arm.chain.limb_groups:
        assert np.all(after[:, group].max(axis=1) <= before[:, group].max(axis=1))


def test_the_waist_turns_where_an_arm_cannot_reach_its_goal_under_the_seeds():
    """Seeds on the goals' own joints but for g1's waist, set elsewhere: where a hand's goal is out of
    its arm's reach under that waist, the waist moves and both hands are solved under the new one."""
    arm = robots.load("g1")
    true = arm.sample_q(N, seed=5)
    goals = arm.reach(true)
    waist = [12, 13, 14]
    seed = true.copy()
    seed[:, waist] = arm.sample_q(N, seed=6)[:, waist]
    q, solved = solve(arm, goals, seed)
    moved = np.any(q[:, waist] != seed[:, waist], axis=1)
    assert moved.sum() >= N // 4
    assert solved[moved][:, :2].all()
    hands = np.linalg.norm(arm.reach(q) - goals, axis=-1)[:, :2]
    assert np.median(hands[moved]) < 1e-5
    assert np.all((q[:, waist] >= arm.lower[waist]) & (q[:, waist] <= arm.upper[waist]))


def test_bad_shapes_are_refused_with_what_was_expected():
    arm = robots.load("g1")
    q = arm.sample_q(3, seed=7)
    with pytest.raises(ValueError, match=r"goals \(n, 4, 3\) and q \(n, 29\)"):
        solve(arm, arm.reach(q)[:, :2], q)
    with pytest.raises(ValueError, match="got"):
        solve(arm, arm.reach(q), q[:2])
