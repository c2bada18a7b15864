"""robots.seeds: an arm's table of sampled joint vectors gives each goal the entries that reach nearest
it; lab.solve tries them on the goals its proposals leave outside tolerance, and only there."""

import numpy as np
import pytest

import lab
import robots
from robots import seeds


def test_the_nearest_entries_are_the_nearest_and_within_the_limits():
    arm = robots.load("ur5")
    table = seeds.table(arm)
    assert seeds.table(arm) is table and len(table) == seeds.SIZE + 1  # built once; the rest pose and SIZE draws
    goals = arm.sample_goals(50, seed=3)
    q = table.nearest(goals, 5)
    assert q.shape == (5, 50, arm.nq)
    assert np.all(q >= arm.lower) and np.all(q <= arm.upper)
    d = np.linalg.norm(arm.reach(q) - goals, axis=-1)  # (5, 50)
    assert np.all(np.diff(d, axis=0) >= -1e-12)  # nearest first
    brute = np.linalg.norm(arm.reach(table.q)[:, None] - goals[None], axis=-1).min(axis=0)
    np.testing.assert_allclose(d[0], brute, rtol=0, atol=1e-12)


def test_a_tree_is_matched_on_all_its_effectors():
    arm = robots.load("talos-legs")
    goals = arm.sample_goals(10, seed=4)
    q = seeds.table(arm).nearest(goals, 2)
    assert q.shape == (2, 10, arm.nq)
    stacked = np.linalg.norm((arm.reach(q) - goals).reshape(2, 10, -1), axis=-1)
    assert np.all(stacked[0] <= stacked[1] + 1e-12)


def test_the_same_table_on_every_build():
    arm = robots.load("so100")
    np.testing.assert_array_equal(seeds.SeedTable(arm).q, seeds.SeedTable(arm).q)
    with pytest.raises(ValueError, match="whole number of entries"):
        seeds.SeedTable(arm, size=0)
    with pytest.raises(ValueError, match="coordinates"):
        seeds.table(arm).nearest(np.zeros((3, 2)), 1)


def test_solve_tries_the_table_only_where_the_proposals_miss():
    """From the rest pose alone, a 20-link snake's goals are mostly out of 3 steps' range; the table's
    entries bring them within tolerance, and the goals the rest pose met keep its answer."""
    arm = robots.load("planar-20")
    goals = arm.sample_goals(200, seed=11)
    plain = lab.solve(None, arm, goals, table=0)
    s = lab.solve(None, arm, goals)
    assert s.success > plain.success + 0.2 and s.success >= 0.95, (plain.success, s.success)
    met = plain.converged
    np.testing.assert_array_equal(s.q[met], plain.q[met])
    assert np.all(s.error <= plain.error) and np.all(s.steps <= 3)
    assert np.all(s.choice[~met & s.converged] >= 1)  # the rest pose is proposal 0; the table's come after
    np.testing.assert_allclose(s.error, np.linalg.norm(arm.reach(s.q) - goals, axis=-1), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="table must be an integer"):
        lab.solve(None, arm, goals, table=-1)
