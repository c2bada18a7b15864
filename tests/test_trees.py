"""robots: trees of several end effectors (legs, feet, fingertips) on one kinematic tree, base fixed.

Every effector of every tree against Pinocchio (frame placements and frame Jacobians), the shapes
(a goal is one position per effector), the classical solvers on the stacked effector Jacobian, and
the refusals by name.
"""

import os

import numpy as np
import pinocchio as pin
import pytest

import robots
from conftest import fmt_xyz, random_joints
from robots.ik import _curvature, _data, _task_jacobian, _task_jacobian_axes, default_tolerance, dls_ik, refine, workspace_size

TREES = {  # name: (joints, effector frames)
    "talos-legs": (12, ("left_sole_link", "right_sole_link")),
    "solo12": (12, ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT")),
    "allegro": (16, ("link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip")),
    "g1": (29, ("left_rubber_hand", "right_rubber_hand", "left_ankle_roll_link", "right_ankle_roll_link")),
}


def pinocchio_effectors(arm, q):
    """(N, E, 3) positions and (N, E, 3, nq) positional frame Jacobians of every effector, with Pinocchio."""
    data = arm.model.createData()
    pos, jac = [], []
    for x in arm.to_pinocchio(q):
        pin.framesForwardKinematics(arm.model, data, x)
        pos.append([data.oMf[f].translation.copy() for f in arm.effector_ids])
        jac.append([pin.computeFrameJacobian(arm.model, data, x, f, pin.LOCAL_WORLD_ALIGNED)[:3].copy()
                    for f in arm.effector_ids])
    return np.array(pos), np.array(jac)


def random_tree_urdf(seed: int) -> str:
    """A tree of 9 joints (revolute, continuous, prismatic about random unaligned axes, at random
    placements), each joint's parent link drawn among the earlier links, a locked branch ("finger",
    no effector on it) and a fixed tip link behind each of three leaves."""
    rng = np.random.default_rng(seed)
    fmt = fmt_xyz
    parents = ["base", "base", "l0", "l1", "l2", "l2", "l3", "l4", "l5"]  # leaves: l6, l7, l8
    links, joints = random_joints(rng, parents)
    joints.append('<joint name="finger" type="revolute"><parent link="l3"/><child link="f"/>'
                  '<axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint>')
    links.append('<link name="f"/>')
    for leaf in (6, 7, 8):
        joints.append(f'<joint name="tool{leaf}" type="fixed"><parent link="l{leaf}"/><child link="tip{leaf}"/>'
                      f'<origin xyz="{fmt(rng.uniform(-1, 1, 3))}" rpy="{fmt(rng.uniform(-3, 3, 3))}"/></joint>')
        links.append(f'<link name="tip{leaf}"/>')
    return f'<robot name="tree{seed}">{"".join(links)}{"".join(joints)}</robot>'


# ---------------------------------------------------------------- the trees by name
def test_trees_load_by_name_and_are_listed_after_the_serial_arms():
    everything, serial = robots.names(), robots.names(trees=False)
    assert everything == serial + tuple(TREES) and not set(TREES) & set(serial)
    for name in TREES:
        assert robots.kind(name) == "tree" and robots.in_metres(name)
    with pytest.raises(ValueError, match="known robots: .*g1"):
        robots.load("g2")


@pytest.mark.parametrize("name", TREES)
def test_tree_joints_effectors_and_model(name):
    arm = robots.load(name)
    nq, effectors = TREES[name]
    assert arm.nq == nq and arm.model.nq == arm.model.nv == nq  # fixed base: no free-flyer
    assert arm.effectors == effectors and arm.n_effectors == len(effectors) and arm.is_tree
    assert [arm.model.frames[f].name for f in arm.effector_ids] == list(effectors)
    # the model's joints are the joints of q, in order; every one moves some effector
    assert arm.joint_names == tuple(arm.model.names[1:])
    assert arm.chain.on_path.any(axis=0).all()
    assert np.all((arm.rest >= arm.lower) & (arm.rest <= arm.upper)) and np.all(arm.lower < arm.upper)
    with pytest.raises(AttributeError, match="use arm.effectors"):
        arm.ee_frame
    with pytest.raises(AttributeError, match="use arm.effector_ids"):
        arm.ee_frame_id
    with pytest.raises(ValueError, match="not a serial chain"):
        arm.chain.arrays
    assert f"effectors={effectors!r}" in repr(arm)


def test_talos_legs_lock_the_rest_of_talos_at_half_sitting():
    arm = robots.load("talos-legs")
    assert all(j.startswith("leg_") for j in arm.joint_names)
    np.testing.assert_allclose(arm.rest[[3, 9]], 0.859395, atol=1e-6)  # knees bent: the SRDF's half_sitting
    g1 = robots.load("g1")
    assert g1.rest[g1.joint_names.index("left_knee_joint")] == 0.3  # Unitree's standing posture


# ---------------------------------------------------------------- kinematics against Pinocchio
@pytest.mark.parametrize("name", TREES)
def test_fk_and_jacobian_of_every_effector_equal_pinocchio(name):
    arm = robots.load(name)
    rng = np.random.default_rng(3)
    q = np.concatenate([arm.sample_q(150, seed=2), rng.uniform(-4, 4, (50, arm.nq))])
    pos, jac = pinocchio_effectors(arm, q)
    E = arm.n_effectors
    assert arm.fk(q).shape == (200, E, 3) and arm.jacobian(q).shape == (200, E, 3, arm.nq)
    np.testing.assert_allclose(arm.fk(q), pos, rtol=0, atol=1e-9)
    np.testing.assert_allclose(arm.jacobian(q), jac, rtol=0, atol=1e-9)
    # a joint that does not move an effector has a zero column in its Jacobian
    off = ~arm.chain.on_path  # (E, nq)
    assert off.any() and np.all(arm.jacobian(q)[:, off[:, None, :].repeat(3, 1)] == 0.0)


@pytest.mark.parametrize("seed", range(4))
def test_fk_and_jacobian_of_any_tree_equal_pinocchio_and_finite_differences(seed, tmp_path):
    """Branches at the root and further out, unaligned revolute, continuous and prismatic axes at
    random placements, a locked branch with no effector, effectors behind fixed joints."""
    path = tmp_path / "tree.urdf"
    path.write_text(random_tree_urdf(seed))
    arm = robots.from_urdf(path, ["tip6", "tip8", "tip7"])
    assert arm.nq == 9 and "finger" not in arm.joint_names and arm.effectors == ("tip6", "tip8", "tip7")
    q = np.concatenate([arm.sample_q(100, seed=seed), np.random.default_rng(seed).uniform(-4, 4, (30, 9))])
    pos, jac = pinocchio_effectors(arm, q)
    np.testing.assert_allclose(arm.fk(q), pos, rtol=0, atol=1e-9)
    np.testing.assert_allclose(arm.jacobian(q), jac, rtol=0, atol=1e-9)
    h, qs = 1e-6, q[:20]
    fd = np.stack([(arm.fk(qs + h * np.eye(9)[k]) - arm.fk(qs - h * np.eye(9)[k])) / (2 * h) for k in range(9)], -1)
    np.testing.assert_allclose(arm.jacobian(qs), fd, rtol=0, atol=1e-6)
    # each effector alone is the serial arm of its chain: the same positions
    for e, frame in enumerate(arm.effectors):
        alone = robots.from_urdf(path, frame)
        cols = [arm.joint_names.index(j) for j in alone.joint_names]
        assert arm.chain.on_path[e, cols].all() and arm.chain.on_path[e].sum() == len(cols)
        np.testing.assert_allclose(alone.fk(q[:, cols]), arm.fk(q)[:, e], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", TREES)
def test_each_effectors_own_chain_composes_to_its_position(name):
    """chain.effector_arrays(e): the serial chain (rot, pos, kind, identity, ee_pos) of effector e,
    as a serial arm's chain.arrays, composed here joint after joint on q[:, path(e)]."""
    arm = robots.load(name)
    q = arm.sample_q(50, seed=8)
    for e in range(arm.n_effectors):
        rot, pos, kind, identity, ee_pos = arm.chain.effector_arrays(e)
        path = arm.chain.path(e)
        assert list(path) == sorted(path) and len(rot) == len(path) == arm.chain.on_path[e].sum()
        R, p = np.broadcast_to(np.eye(3), (len(q), 3, 3)), np.zeros((len(q), 3))
        for k in range(len(path)):
            p = p + R @ pos[k]
            R = R if identity[k] else R @ rot[k]
            x = q[:, path[k], None]
            if kind[k] == 0:
                c, s = np.cos(x), np.sin(x)
                R = np.stack([c * R[:, :, 0] + s * R[:, :, 1], c * R[:, :, 1] - s * R[:, :, 0], R[:, :, 2]], axis=2)
            else:
                p = p + x * R[:, :, 2]
        np.testing.assert_allclose(p + R @ ee_pos, arm.fk(q)[:, e], rtol=0, atol=1e-12)


def test_one_frame_in_a_sequence_is_a_serial_arm(tmp_path):
    path = tmp_path / "tree.urdf"
    path.write_text(random_tree_urdf(0))
    one, listed = robots.from_urdf(path, "tip6"), robots.from_urdf(path, ["tip6"])
    q = one.sample_q(10, seed=1)
    assert not listed.is_tree and listed.ee_frame == "tip6" and listed.effectors == ("tip6",)
    assert listed.fk(q).shape == (10, 3) and listed.jacobian(q).shape == (10, 3, one.nq)
    np.testing.assert_array_equal(listed.fk(q), one.fk(q))
    assert listed.chain.arrays[4].shape == (3,)  # what the lab's kernels read, as before


@pytest.mark.parametrize("seed", range(4))
def test_refines_bend_is_the_second_derivative_along_the_step_on_any_tree(seed, tmp_path):
    """robots.ik._curvature, from the Jacobian's columns and the joints' axes: the effectors' second
    derivative along a joint direction v equals central finite differences of fk, with unaligned
    revolute, continuous and prismatic joints, and effectors on different branches."""
    path = tmp_path / "tree.urdf"
    path.write_text(random_tree_urdf(seed))
    arm = robots.from_urdf(path, ["tip6", "tip8", "tip7"])
    rng, h = np.random.default_rng(seed), 1e-4
    for x in arm.sample_q(10, seed=seed):
        v = rng.standard_normal(arm.nq)
        J, parts = _task_jacobian_axes(arm, _data(arm), arm.to_pinocchio(x), [0, 1, 2])
        np.testing.assert_allclose(J, arm.jacobian(x).reshape(-1, arm.nq), rtol=0, atol=1e-9)
        fd = (arm.fk(x + h * v) - 2 * arm.fk(x) + arm.fk(x - h * v)).reshape(-1) / h**2
        np.testing.assert_allclose(_curvature(parts, v, [0, 1, 2]), fd, rtol=0, atol=1e-5 * max(1.0, np.abs(fd).max()))


@pytest.mark.parametrize("name", TREES)
def test_joint_positions_hang_from_their_parents(name):
    arm = robots.load(name)
    q = arm.sample_q(10, seed=5)
    pts = arm.joint_positions(q)
    E = arm.n_effectors
    assert pts.shape == (10, 1 + arm.nq + E, 3) and arm.point_parents.shape == (1 + arm.nq + E,)
    np.testing.assert_array_equal(pts[:, 1 + arm.nq:], arm.fk(q))
    np.testing.assert_array_equal(pts[:, 0], 0.0)
    data = arm.model.createData()
    for x, p in zip(arm.to_pinocchio(q), pts):
        pin.forwardKinematics(arm.model, data, x)
        for k in range(arm.nq):
            j = k + 1  # the reduced model's joint k + 1 is the joint of q[k]
            origin = (data.oMi[int(arm.model.parents[j])] * arm.model.jointPlacements[j]).translation
            np.testing.assert_allclose(p[k + 1], origin, atol=1e-9)
            assert arm.point_parents[k + 1] == int(arm.model.parents[j])  # the parent's point (0: the root)
    assert list(robots.load("ur5").point_parents) == list(range(-1, robots.load("ur5").nq + 1))


# ---------------------------------------------------------------- goals, limits, reach
@pytest.mark.parametrize("name", TREES)
def test_goals_are_one_position_per_effector(name):
    arm = robots.load(name)
    E = arm.n_effectors
    goals = arm.sample_goals(30, seed=4)
    assert goals.shape == (30, E, 3)
    np.testing.assert_array_equal(goals, arm.reach(arm.sample_q(30, seed=4)))
    np.testing.assert_array_equal(goals, arm.sample_goals(30, seed=4))
    lo, hi = arm.workspace_bounds
    assert lo.shape == hi.shape == (E, 3) and np.all(goals >= lo) and np.all(goals <= hi)
    q = arm.sample_q(5, seed=1) + 7.0
    inside = arm.within_limits(q)
    assert inside.shape == q.shape and np.all((inside >= arm.lower) & (inside <= arm.upper))
    assert arm.to_3d(goals).shape == (30, E, 3)


@pytest.mark.parametrize("name", TREES)
def test_effector_reach_is_each_effectors_farthest_sampled_distance(name):
    arm = robots.load(name)
    reach = arm.effector_reach
    assert reach.shape == (arm.n_effectors,) and arm.reach_radius == reach.max()
    p = arm.fk(arm.sample_q(5000, seed=3))
    assert np.all(np.linalg.norm(p, axis=-1).max(axis=0) <= reach * 1.02)
    with pytest.raises(ValueError, match="read-only"):
        reach[0] = 0.0


def test_a_serial_arms_effector_reach_is_its_reach_radius():
    for name in ("planar", "ur5", "planar-20"):
        arm = robots.load(name)
        assert arm.effector_reach.shape == (1,) and arm.effector_reach[0] == arm.reach_radius


# ---------------------------------------------------------------- the classical solvers on trees
@pytest.mark.parametrize("name", TREES)
def test_the_solvers_use_the_stacked_effector_jacobian(name):
    arm = robots.load(name)
    q = arm.sample_q(5, seed=2)
    for x in q:
        J = _task_jacobian(arm, _data(arm), arm.to_pinocchio(x), [0, 1, 2])
        assert J.shape == (3 * arm.n_effectors, arm.nq)
        np.testing.assert_allclose(J, arm.jacobian(x).reshape(-1, arm.nq), rtol=0, atol=1e-9)


# dls_ik from the rest posture on 100 reachable goals (all effectors within 1e-4 x workspace size):
# measured 0.99, 0.88, 0.95, 0.80; from a straight-legged g1 (neutral) it was 0.39 (a singular start)
DLS_RATE = {"talos-legs": 0.95, "solo12": 0.8, "allegro": 0.9, "g1": 0.7}


@pytest.mark.parametrize("name", TREES)
def test_dls_ik_reaches_goals_of_every_effector(name):
    arm = robots.load(name)
    goals = arm.sample_goals(100, seed=11)
    results = [dls_ik(arm, g) for g in goals]
    tol = 1e-4 * workspace_size(arm)
    for r, g in zip(results, goals):
        assert r.q.shape == (arm.nq,) and np.all((r.q >= arm.lower) & (r.q <= arm.upper))
        assert r.error == pytest.approx(np.linalg.norm(arm.reach(r.q) - g), abs=1e-12)
        assert r.converged == (r.error < tol)
    rate = np.mean([r.converged for r in results])
    assert rate >= DLS_RATE[name], rate


@pytest.mark.parametrize("name", TREES)
def test_refine_makes_seeds_a_twentieth_of_a_radian_off_exact(name):
    """Seeds 0.05 rad off (every joint) of reachable goals: within refine's default tolerance (0.1 mm,
    every effector) in at most 5 steps on >= 95 % of goals,
    at most 3 steps on >= 90 %."""
    arm = robots.load(name)
    rng = np.random.default_rng(3)
    q_true = arm.sample_q(200, seed=11)
    goals = arm.reach(q_true)
    seeds = arm.within_limits(q_true + 0.05 * rng.standard_normal(q_true.shape))
    tol = default_tolerance(arm)
    assert tol == 1e-4
    five = refine(arm, goals, seeds, steps=5)
    assert five.q.shape == (200, arm.nq) and five.error.shape == (200,) and np.all(five.steps <= 5)
    worst = np.linalg.norm(arm.reach(five.q) - goals, axis=-1).max(axis=1)  # the effector farthest off
    np.testing.assert_allclose(five.error, worst, atol=1e-12)
    assert np.mean(five.error < tol) >= 0.95, np.mean(five.error < tol)
    three = refine(arm, goals, seeds, steps=3)
    assert np.mean(three.error < tol) >= 0.90, np.mean(three.error < tol)
    # several proposals per goal, as a multi-head network gives them
    both = refine(arm, goals[:20], np.stack([seeds[:20], q_true[:20] + 1.0]), steps=5)
    assert both.choice.shape == (20,) and np.mean(both.error < tol) >= 0.9


def test_the_solvers_refuse_goals_of_the_wrong_shape():
    arm = robots.load("solo12")
    with pytest.raises(ValueError, match=r"goal must have shape \(4, 3\) \(one position per effector: FL_FOOT"):
        dls_ik(arm, np.zeros(3))
    with pytest.raises(ValueError, match=r"goal must have shape \(4, 3\)"):
        dls_ik(arm, np.zeros(12))
    with pytest.raises(ValueError, match=r"goals must be \(n, 4, 3\)"):
        refine(arm, np.zeros((5, 3)), np.zeros((5, 12)))
    with pytest.raises(ValueError, match=r"goals must be \(n, 4, 3\)"):
        refine(arm, np.zeros((5, 4, 3)), np.zeros((4, 12)))
    r = refine(arm, arm.reach(arm.rest), arm.rest)  # one goal (E, 3), one seed
    assert r.q.shape == (1, 12) and r.error[0] < 1e-12


# ---------------------------------------------------------------- refusals, by name
def tree_file(tmp_path) -> str:
    path = tmp_path / "tree.urdf"
    path.write_text(random_tree_urdf(1))
    return str(path)


def test_a_frame_the_urdf_lacks_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"end-effector frame 'tip9' not found in .*tree.urdf"):
        robots.from_urdf(tree_file(tmp_path), ["tip6", "tip9"])


def test_the_same_frame_twice_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"end-effector frame 'tip7' is given twice"):
        robots.from_urdf(tree_file(tmp_path), ["tip7", "tip6", "tip7"])


def test_two_effectors_on_one_link_are_refused_by_name(tmp_path):
    # tip6 hangs from l6 by a fixed joint: both move with joint j6, one rigid link
    with pytest.raises(ValueError, match=r"frames 'l6' and 'tip6' are on one link \('l6', moved by joint 'j6'\)"):
        robots.from_urdf(tree_file(tmp_path), ["l6", "tip6"])
    with pytest.raises(ValueError, match=r"frames 'tip8' and 'tool8' are on one link"):  # a link and its joint
        robots.from_urdf(tree_file(tmp_path), ["tip8", "tool8"])


def test_an_effector_on_the_root_link_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"frame 'base' in .* is not moved by any joint \(it is on the root link "
                                         r"'base'\)"):
        robots.from_urdf(tree_file(tmp_path), ["tip6", "base"])
    with pytest.raises(ValueError, match=r"frame 'base' .* is not moved by any joint"):
        robots.from_urdf(tree_file(tmp_path), "base")


@pytest.mark.parametrize("frames", [[], (), 3, ["tip6", 7], None])
def test_effectors_must_be_frame_names(tmp_path, frames):
    with pytest.raises(ValueError, match="a frame name or a non-empty sequence of frame names"):
        robots.from_urdf(tree_file(tmp_path), frames)


def test_a_posture_is_refused_for_a_joint_the_urdf_lacks(tmp_path):
    with pytest.raises(ValueError, match=r"posture for 'knee', which is not a joint of the URDF"):
        robots.from_urdf(tree_file(tmp_path), ["tip6", "tip7"], posture={"knee": 0.3})
    arm = robots.from_urdf(tree_file(tmp_path), ["tip6", "tip7"], posture={"j0": 0.25, "j1": 1.0})
    rest = dict(zip(arm.joint_names, arm.rest))
    assert rest["j0"] == 0.25 and rest["j1"] == pytest.approx(1.0)  # j1 is continuous: cos, sin and back


def test_tree_visuals_follow_the_tree():
    from robots.visual import joint_poses, visual_geometry

    arm = robots.load("solo12")
    geoms = visual_geometry(arm)
    assert geoms and {g.joint for g in geoms} <= set(range(arm.model.njoints))
    assert len(joint_poses(arm, arm.rest)) == arm.nq


def test_effector_names_are_checked_before_anything_is_built():
    urdf = os.path.join(os.path.dirname(robots.__file__), "urdf", "planar.urdf")
    with pytest.raises(ValueError, match="end-effector frame 'ee' is given twice"):
        robots.from_urdf(urdf, ("ee", "ee"))
