"""robots: kinematics equal Pinocchio and the paper's equations; bad input is refused clearly."""

import os
import re

import numpy as np
import pinocchio as pin
import pytest

import robots
from conftest import fmt_xyz, random_joints

ALL = robots.names(trees=False)  # the serial arms (the trees: tests/test_trees.py)


def pinocchio_fk(arm, q):
    """End-effector positions and rotations, one configuration at a time, with Pinocchio itself."""
    data = arm.model.createData()
    pos, rot = [], []
    for x in arm.to_pinocchio(q):
        pin.forwardKinematics(arm.model, data, x)
        pin.updateFramePlacements(arm.model, data)
        pos.append(data.oMf[arm.ee_frame_id].translation.copy())
        rot.append(data.oMf[arm.ee_frame_id].rotation.copy())
    return np.array(pos), np.array(rot)


def test_names_include_the_paper_arms_and_example_robot_data_arms():
    for name in ("planar", "scara", "ur5", "panda", "so100", "z1", "xarm7", "kinova"):
        assert name in ALL


@pytest.mark.parametrize("name", ALL)
def test_fk_equals_pinocchio(name):
    arm = robots.load(name)
    rng = np.random.default_rng(7)
    # within the limits, and well outside them (fk is plain kinematics, no clipping)
    q = np.concatenate([arm.sample_q(300, seed=1), rng.uniform(-4, 4, (100, arm.nq))])
    expected, _ = pinocchio_fk(arm, q)
    np.testing.assert_allclose(arm.fk(q), expected, rtol=0, atol=1e-9)


def random_chain_urdf(seed: int) -> str:
    """A serial chain of 7 joints, each revolute, continuous or prismatic about a random
    (unaligned) axis, at a random origin and rpy, with a side branch (a locked "finger")
    and the end-effector frame behind a fixed joint."""
    rng = np.random.default_rng(seed)
    fmt = fmt_xyz
    links, joints = random_joints(rng, ["base"] + [f"l{k}" for k in range(6)])
    joints.append('<joint name="finger" type="revolute"><parent link="l3"/><child link="f"/>'
                  '<axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint>')
    joints.append(f'<joint name="tool" type="fixed"><parent link="l6"/><child link="tip"/>'
                  f'<origin xyz="{fmt(rng.uniform(-1, 1, 3))}" rpy="{fmt(rng.uniform(-3, 3, 3))}"/></joint>')
    links += ['<link name="f"/>', '<link name="tip"/>']
    return f'<robot name="random{seed}">{"".join(links)}{"".join(joints)}</robot>'


@pytest.mark.parametrize("seed", range(5))
def test_fk_of_any_serial_chain_equals_pinocchio(seed, tmp_path):
    """No code of its own per arm: unaligned revolute, continuous and prismatic axes at random
    placements, a locked side branch, a fixed end-effector frame."""
    path = tmp_path / "chain.urdf"
    path.write_text(random_chain_urdf(seed))
    arm = robots.from_urdf(path, "tip")
    assert arm.nq == 7 and "finger" not in arm.joint_names
    assert list(arm.is_prismatic) == [k % 3 == 2 for k in range(7)]
    q = np.concatenate([arm.sample_q(200, seed=seed), np.random.default_rng(seed).uniform(-4, 4, (50, 7))])
    expected, _ = pinocchio_fk(arm, q)
    np.testing.assert_allclose(arm.fk(q), expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(arm.joint_positions(q)[:, -1], expected, rtol=0, atol=1e-9)


# ---------------------------------------------------------------- the positional Jacobian
def pinocchio_jacobian(arm, q):
    """Pinocchio's frame Jacobian of the end effector, translational rows, one configuration at a time."""
    data = arm.model.createData()
    out = []
    for x in arm.to_pinocchio(q):
        out.append(pin.computeFrameJacobian(arm.model, data, x, arm.ee_frame_id, pin.LOCAL_WORLD_ALIGNED)[:3].copy())
    return np.array(out)


@pytest.mark.parametrize("name", ALL)
def test_jacobian_equals_pinocchio(name):
    """Continuous joints (kinova) included: Pinocchio's velocity of a continuous joint is the
    derivative with respect to its angle, our coordinate, so both have nq columns."""
    arm = robots.load(name)
    q = np.concatenate([arm.sample_q(100, seed=4), np.random.default_rng(8).uniform(-4, 4, (30, arm.nq))])
    J = arm.jacobian(q)
    assert J.shape == (130, 3, arm.nq) and arm.model.nv == arm.nq
    np.testing.assert_allclose(J, pinocchio_jacobian(arm, q), rtol=0, atol=1e-9)


def central_differences(arm, q, h=1e-6):
    cols = []
    for k in range(arm.nq):
        dq = np.zeros(arm.nq)
        dq[k] = h
        cols.append((arm.fk(q + dq) - arm.fk(q - dq)) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("seed", range(3))
def test_jacobian_of_any_serial_chain_equals_pinocchio_and_finite_differences(seed, tmp_path):
    """Unaligned revolute, continuous and prismatic axes at random placements."""
    path = tmp_path / "chain.urdf"
    path.write_text(random_chain_urdf(seed))
    arm = robots.from_urdf(path, "tip")
    q = arm.sample_q(40, seed=seed)
    J = arm.jacobian(q)
    np.testing.assert_allclose(J, pinocchio_jacobian(arm, q), rtol=0, atol=1e-9)
    np.testing.assert_allclose(J, central_differences(arm, q), rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["planar", "scara", "planar-20", "ur5", "kinova"])
def test_jacobian_equals_finite_differences_and_keeps_batch_shapes(name):
    arm = robots.load(name)
    q = arm.sample_q(50, seed=6)
    scale = max(1.0, arm.reach_radius)  # central differences: error ~ h^2 x (third derivative ~ length)
    np.testing.assert_allclose(arm.jacobian(q), central_differences(arm, q), rtol=0, atol=1e-6 * scale)
    assert arm.jacobian(q[0]).shape == (3, arm.nq)
    assert arm.jacobian(q.reshape(5, 10, arm.nq)).shape == (5, 10, 3, arm.nq)
    np.testing.assert_array_equal(arm.jacobian(q.reshape(5, 10, arm.nq)).reshape(50, 3, arm.nq), arm.jacobian(q))


def test_snake_jacobian_is_the_closed_form():
    """dp/dq_k = sum_{i>=k} l (-sin phi_i, cos phi_i), phi_i = q_1 + ... + q_i."""
    arm = robots.load("planar-10")
    q = arm.sample_q(30, seed=1)
    phi = np.cumsum(q, axis=1)
    l = 23.375 / 10
    tail_x = np.cumsum((-l * np.sin(phi))[:, ::-1], axis=1)[:, ::-1]
    tail_y = np.cumsum((l * np.cos(phi))[:, ::-1], axis=1)[:, ::-1]
    J = arm.jacobian(q)
    np.testing.assert_allclose(J[:, 0], tail_x, atol=1e-9)
    np.testing.assert_allclose(J[:, 1], tail_y, atol=1e-9)
    np.testing.assert_array_equal(J[:, 2], 0)


@pytest.mark.parametrize("name", ALL)
def test_chain_model_is_fixed_base_and_arm_only(name):
    arm = robots.load(name)
    assert arm.lower.shape == arm.upper.shape == (arm.nq,)
    assert np.all(arm.lower < arm.upper)
    assert arm.model.nv == arm.nq  # one velocity per joint: no free flyer, no locked-out gripper left
    assert len(arm.joint_names) == arm.nq
    assert np.all((arm.rest >= arm.lower) & (arm.rest <= arm.upper))
    assert robots.load(name) is arm  # built once and shared, so its arrays are read-only
    for a in (arm.lower, arm.upper, arm.rest):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 0.0


@pytest.mark.parametrize("name", ALL)
def test_joint_positions_are_the_joint_origins(name):
    arm = robots.load(name)
    q = arm.sample_q(20, seed=3)
    chain = arm.joint_positions(q)
    assert chain.shape == (20, arm.nq + 2, 3)
    np.testing.assert_allclose(chain[:, -1], arm.fk(q), atol=1e-12)
    data = arm.model.createData()
    for x, pts in zip(arm.to_pinocchio(q), chain):
        pin.forwardKinematics(arm.model, data, x)
        for k, j in enumerate(arm.chain.joint_ids):
            # a joint's origin before its own motion = oMi of its parent composed with its placement
            parent = data.oMi[int(arm.model.parents[int(j)])]
            origin = (parent * arm.model.jointPlacements[int(j)]).translation
            np.testing.assert_allclose(pts[k + 1], origin, atol=1e-9)


def eq3_planar(q):
    """Translation column of the paper's eq. (3)."""
    a1, a2, a3 = 8.625, 8.625, 6.125
    t1, t2, t3 = q[:, 0], q[:, 1], q[:, 2]
    x = a1 * np.cos(t1) + a2 * np.cos(t1 + t2) + a3 * np.cos(t1 + t2 + t3)
    y = a1 * np.sin(t1) + a2 * np.sin(t1 + t2) + a3 * np.sin(t1 + t2 + t3)
    return np.column_stack([x, y, np.zeros_like(x)])


def eq4_scara(q):
    """Translation column of the paper's eq. (4) and its rotation block.

    As printed, eq. (4)'s rotation block [[C, -S, 0], [S, C, 0], [0, 0, -1]] has determinant -1:
    no rotation has it. Table 2's D-H product (alpha2 = pi) gives [[C, S, 0], [S, -C, 0], [0, 0, -1]],
    which agrees with the print in its first and third columns; the test checks those.
    """
    a1, a2 = 20.0, 20.0
    t1, t2, t3, d4 = q.T
    p = np.column_stack([a1 * np.cos(t1) + a2 * np.cos(t1 + t2), a1 * np.sin(t1) + a2 * np.sin(t1 + t2), -d4])
    c, s = np.cos(t1 + t2 - t3), np.sin(t1 + t2 - t3)
    R = np.zeros((len(q), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, -1.0
    return p, R


@pytest.mark.parametrize("name", ["so100", "so101", "ur5", "planar"])
def test_the_base_axis_is_what_the_first_joint_turns_the_end_effector_about(name):
    """Turning only the first joint moves the end effector on a circle about arm.base_axis: its
    distance to that line stays the same (the SO arms' axis stands 4-5 cm beside the URDF's origin)."""
    arm = robots.load(name)
    point, direction = arm.base_axis
    assert np.linalg.norm(direction) == pytest.approx(1.0)
    q = np.repeat(arm.sample_q(5, seed=7), 9, axis=0)
    q[:, 0] = np.tile(np.linspace(arm.lower[0], arm.upper[0], 9), 5)
    p = arm.fk(q) - point
    d = np.linalg.norm(p - np.outer(p @ direction, direction), axis=1).reshape(5, 9)
    np.testing.assert_allclose(d - d[:, :1], 0.0, atol=1e-9)
    assert (np.linalg.norm(point[:2]) > 0.03) == name.startswith("so")


def test_planar_equals_eq3():
    arm = robots.load("planar")
    q = np.concatenate([arm.sample_q(500, seed=0), np.random.default_rng(1).uniform(-7, 7, (200, 3))])
    np.testing.assert_allclose(arm.fk(q), eq3_planar(q), rtol=0, atol=1e-9)
    # eq. (3)'s rotation block is a rotation of theta1 + theta2 + theta3 about z
    _, rot = pinocchio_fk(arm, q[:50])
    ang = q[:50].sum(axis=1)
    np.testing.assert_allclose(rot[:, 0, 0], np.cos(ang), atol=1e-9)
    np.testing.assert_allclose(rot[:, 1, 0], np.sin(ang), atol=1e-9)


def test_scara_equals_eq4():
    arm = robots.load("scara")
    q = np.concatenate([arm.sample_q(500, seed=0), np.random.default_rng(1).uniform(-7, 12, (200, 4))])
    p, R = eq4_scara(q)
    np.testing.assert_allclose(arm.fk(q), p, rtol=0, atol=1e-9)
    _, rot = pinocchio_fk(arm, q)
    np.testing.assert_allclose(rot[:, :, [0, 2]], R[:, :, [0, 2]], atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-9)


def test_paper_arms_protocol_limits_and_axes():
    planar, scara = robots.load("planar"), robots.load("scara")
    pi = np.pi
    np.testing.assert_allclose(planar.lower, [-pi / 2, 0, 0])
    np.testing.assert_allclose(planar.upper, [pi / 2, pi / 2, pi / 2])
    np.testing.assert_allclose(scara.lower, [-pi / 2, 0, -pi, 0])
    np.testing.assert_allclose(scara.upper, [pi / 2, 3 * pi / 4, pi, 10])
    assert planar.task_axes == (0, 1) and scara.task_axes == (0, 1, 2)
    assert planar.joint_names == ("theta1", "theta2", "theta3")
    assert scara.joint_names == ("theta1", "theta2", "theta3", "d4")


@pytest.mark.parametrize("name", ALL)
def test_sample_goals_are_reached_positions_and_reproducible(name):
    arm = robots.load(name)
    g = arm.sample_goals(70, seed=5)
    assert g.shape == (70, len(arm.task_axes))
    np.testing.assert_array_equal(g, arm.sample_goals(70, seed=5))
    assert not np.array_equal(g, arm.sample_goals(70, seed=6))
    q = arm.sample_q(70, seed=5)
    assert np.all((q >= arm.lower) & (q <= arm.upper))
    np.testing.assert_array_equal(g, arm.fk(q)[:, list(arm.task_axes)])
    lo, hi = arm.workspace_bounds
    # the bounds come from a larger sample of the same distribution: they contain nearly all goals
    assert np.mean(np.all((g >= lo) & (g <= hi), axis=1)) > 0.9


def test_batch_shapes_are_kept():
    arm = robots.load("ur5")
    q = arm.sample_q(24, seed=0).reshape(2, 3, 4, 6)
    p = arm.fk(q)
    assert p.shape == (2, 3, 4, 3)
    np.testing.assert_array_equal(p.reshape(-1, 3), arm.fk(q.reshape(-1, 6)))
    assert arm.fk(q[0, 0, 0]).shape == (3,)


def test_continuous_joints_are_single_angles():
    arm = robots.load("kinova")
    assert arm.nq == 6 and arm.model.nq == 9
    q = arm.sample_q(50, seed=2)
    np.testing.assert_allclose(arm.from_pinocchio(arm.to_pinocchio(q)), q, atol=1e-12)
    np.testing.assert_allclose(arm.fk(q), arm.fk(q + 2 * np.pi * arm.chain.continuous), atol=1e-9)


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(ValueError) as e:
        robots.load("iiwa")
    assert "iiwa" in str(e.value)
    for name in ALL:
        assert name in str(e.value)


@pytest.mark.parametrize("shape", [(5, 2), (4,), (), (3, 7)])
def test_q_of_wrong_shape_names_the_expected_shape(shape):
    arm = robots.load("planar")
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        arm.fk(np.zeros(shape))


@pytest.mark.parametrize("q", [np.zeros((2, 3), complex), np.array([["a", "b", "c"]]), np.array([[1, "x", 2]], object)])
def test_q_that_is_not_real_numbers_is_refused_by_dtype(q):
    with pytest.raises(ValueError, match=f"planar: q must hold real numbers, got dtype {re.escape(str(q.dtype))}"):
        robots.load("planar").fk(q)


@pytest.mark.parametrize("n", [-1, 2.5, "3", True])
def test_goal_counts_that_are_not_whole_numbers_are_refused(n):
    with pytest.raises(ValueError, match="n must be an integer >= 0"):
        robots.load("planar").sample_goals(n, seed=0)


def test_unknown_name_of_any_type_lists_the_known_ones():
    for name in (None, ["planar"], 3):
        with pytest.raises(ValueError, match="known robots: planar, scara"):
            robots.load(name)


def test_nan_in_q_gives_nan_out():
    arm = robots.load("scara")
    q = arm.sample_q(4, seed=0)
    q[1, 2] = np.nan
    q[3, 3] = np.inf
    p = arm.fk(q)
    assert np.all(np.isfinite(p[[0, 2]]))
    assert np.isnan(p[1, :2]).all()  # theta3 turns the wrist only; x, y of the tool follow it
    assert not np.all(np.isfinite(p[3]))


def test_missing_end_effector_frame_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"end-effector frame 'tool9' not found"):
        robots.from_urdf(os.path.join(os.path.dirname(robots.__file__), "urdf", "planar.urdf"), "tool9")


def test_unreadable_or_invalid_urdf_is_a_clear_error(tmp_path):
    with pytest.raises(OSError, match="cannot read URDF"):
        robots.from_urdf(tmp_path / "missing.urdf", "ee")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(ValueError, match="not a valid URDF"):
        robots.from_urdf(bad, "a")


def test_a_joint_of_more_than_one_axis_is_a_clear_error(tmp_path):
    urdf = tmp_path / "floating.urdf"
    urdf.write_text('<robot name="f"><link name="a"/><link name="b"/><joint name="free" type="floating">'
                    '<parent link="a"/><child link="b"/></joint></robot>')
    with pytest.raises(ValueError, match="JointModelFreeFlyer is not supported"):
        robots.from_urdf(urdf, "b")


# ---------------------------------------------------------------- from_urdf options, IK
PLANAR_URDF = os.path.join(os.path.dirname(robots.__file__), "urdf", "planar.urdf")
SCARA_URDF = os.path.join(os.path.dirname(robots.__file__), "urdf", "scara.urdf")


def test_limit_overrides_must_name_a_chain_joint_and_be_a_finite_range():
    arm = robots.from_urdf(PLANAR_URDF, "ee", limits={"theta1": (-1.0, 1.0)})
    assert (arm.lower[0], arm.upper[0]) == (-1.0, 1.0)
    for limits, why in (({"theta_1": (-1, 1)}, "'theta_1', which is not a joint of the chain"),
                        ({"theta1": (1, -1)}, "limits of 'theta1' must be finite with lower < upper"),
                        ({"theta2": (0, np.inf)}, "limits of 'theta2' must be finite")):
        with pytest.raises(ValueError, match=re.escape(why)):
            robots.from_urdf(PLANAR_URDF, "ee", limits=limits)


def test_reference_postures_are_checked():
    from robots.registry import _erd_paths

    path, share, (srdf, _) = _erd_paths("panda")
    with pytest.raises(ValueError, match="posture 'no_such' is not in .* \\(postures: default\\)"):
        robots.from_urdf(path, "panda_hand_tcp", package_dirs=(share,), srdf=(srdf, "no_such"))
    with pytest.raises(ValueError, match="reference must be a Pinocchio configuration of shape \\(9,\\)"):
        robots.from_urdf(path, "panda_hand_tcp", package_dirs=(share,), reference=np.zeros(7))


def test_from_pinocchio_checks_the_configuration_size():
    arm = robots.load("kinova")
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 9\), got shape \(6,\)"):
        arm.from_pinocchio(np.zeros(6))


def test_a_mimic_joint_on_the_chain_is_refused(tmp_path):
    urdf = tmp_path / "mimic.urdf"
    urdf.write_text('''<robot name="m"><link name="base"/><link name="a"/><link name="b"/><link name="tip"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="1 0 0"/><axis xyz="0 0 1"/>
        <limit lower="-2" upper="2" effort="1" velocity="1"/><mimic joint="j1" multiplier="2"/></joint>
      <joint name="t" type="fixed"><parent link="b"/><child link="tip"/><origin xyz="1 0 0"/></joint></robot>''')
    with pytest.raises(ValueError, match="joint\\(s\\) j2 on the chain to 'tip' mimic another joint"):
        robots.from_urdf(urdf, "tip")
    assert robots.from_urdf(urdf, "a").nq == 1  # off the chain it is locked, as a gripper's fingers are


def test_continuous_joints_turn_by_whole_turns_into_their_limits():
    kinova = robots.load("kinova")
    joint = kinova.joint_names[0]  # continuous, [-pi, pi] by default
    arm = robots.from_urdf(kinova.urdf_path, kinova.ee_frame, package_dirs=kinova.package_dirs,
                           limits={joint: (-5.0, -1.0)})
    q = np.array([[np.pi / 2, 3, 3, 0, 3, 0], [-4.0, 3, 3, 0, 3, 0], [0.5, 3, 3, 0, 3, 0]])
    moved = arm.within_limits(q)
    np.testing.assert_allclose(moved[:, 0], [np.pi / 2 - 2 * np.pi, -4.0, -1.0])  # -4.0 is kept as it is
    assert moved[1, 0] == -4.0
    np.testing.assert_allclose(arm.fk(moved[:2]), arm.fk(q[:2]), atol=1e-9)  # the same pose


def test_ik_starts_within_the_limits():
    from robots.ik import dls_ik

    planar = robots.load("planar")
    q0 = np.array([0.3, -0.5, 2.5])  # theta2 and theta3 are in [0, pi/2]
    r = dls_ik(planar, planar.reach(q0), q0=q0)
    assert np.all((r.q >= planar.lower) & (r.q <= planar.upper))
    assert r.error == pytest.approx(np.linalg.norm(planar.reach(q0) - planar.reach(r.q)), abs=1e-12)
    kinova = robots.load("kinova")
    r = dls_ik(kinova, kinova.reach(kinova.rest), q0=kinova.rest + 2 * np.pi * kinova.chain.continuous)
    assert np.all((r.q >= kinova.lower) & (r.q <= kinova.upper)) and r.converged


def test_ik_gives_each_arm_its_own_pinocchio_data():
    """Arms built and dropped in turn (an id may then be reused) never share a pin.Data."""
    import gc

    from robots.ik import dls_ik

    for i in range(60):
        arm = robots.from_urdf(SCARA_URDF if i % 3 == 0 else PLANAR_URDF, "ee")
        goal = arm.sample_goals(1, seed=i)[0]
        r = dls_ik(arm, goal, max_iter=3)
        assert r.error == pytest.approx(np.linalg.norm(goal - arm.reach(r.q)), abs=1e-12)
        del arm
        gc.collect()


# ---------------------------------------------------------------- real arms: reach, refinement, visuals
def test_paper_arms_snakes_and_real_arms_are_told_apart():
    assert [robots.kind(n) for n in ("planar", "scara")] == ["paper", "paper"]
    assert [robots.kind(n) for n in ("planar-10", "planar-20")] == ["snake", "snake"]
    others = set(robots.names(trees=False)) - {"planar", "scara", "planar-10", "planar-20"}
    assert others and all(robots.kind(n) == "real" for n in others)
    assert robots.kind("my-own-urdf") == "custom"
    # lengths: the paper's units for its arms and the snakes, metres for the rest
    assert [robots.in_metres(n) for n in ("planar", "scara", "planar-10", "planar-20")] == [False] * 4
    assert all(robots.in_metres(n) for n in others) and robots.in_metres("my-own-urdf")


@pytest.mark.parametrize("name", ["planar", "ur5"])
def test_reach_radius_is_the_farthest_sampled_end_effector(name):
    arm = robots.load(name)
    p = arm.fk(arm.sample_q(5000, seed=3))
    assert np.linalg.norm(p, axis=1).max() <= arm.reach_radius * 1.02
    if name == "planar":  # 8.625 + 8.625 + 6.125 when stretched
        assert arm.reach_radius == pytest.approx(23.375, rel=1e-3)


# ---------------------------------------------------------------- hyper-redundant planar snakes
SNAKES = {"planar-10": 10, "planar-20": 20}


def snake_closed_form(q, length):
    """p = sum_i l (cos(sum_{k<=i} q_k), sin(sum_{k<=i} q_k)), z = 0."""
    phi = np.cumsum(q, axis=-1)
    return np.stack([length * np.cos(phi).sum(-1), length * np.sin(phi).sum(-1), np.zeros(q.shape[:-1])], -1)


@pytest.mark.parametrize("name", SNAKES)
def test_snake_fk_is_the_closed_form(name):
    arm = robots.load(name)
    n = SNAKES[name]
    assert arm.nq == n and arm.task_axes == (0, 1) and arm.ee_frame == "ee"
    assert arm.joint_names == tuple(f"theta{i}" for i in range(1, n + 1))
    rng = np.random.default_rng(5)
    q = np.concatenate([arm.sample_q(500, seed=2), rng.uniform(-4, 4, (200, n))])  # also beyond the limits
    np.testing.assert_allclose(arm.fk(q), snake_closed_form(q, 23.375 / n), rtol=0, atol=1e-9)
    np.testing.assert_allclose(arm.fk(np.zeros(n)), [23.375, 0, 0], atol=1e-12)  # straight along x
    # the base frame is at the first joint, as the planar arm's: joint 1 at the origin, joint k at
    # the tip of link k - 1
    chain = arm.joint_positions(q[:20])
    np.testing.assert_allclose(chain[:, 1], 0, atol=1e-12)
    for k in range(2, n + 1):
        np.testing.assert_allclose(chain[:, k], snake_closed_form(q[:20, :k - 1], 23.375 / n), atol=1e-9)


@pytest.mark.parametrize("name", SNAKES)
def test_snake_limits_units_and_reach(name):
    arm = robots.load(name)
    np.testing.assert_array_equal(arm.lower, -np.pi / 2)
    np.testing.assert_array_equal(arm.upper, np.pi / 2)
    assert not arm.is_prismatic.any() and not arm.chain.continuous.any()
    assert arm.reach_radius == pytest.approx(23.375, rel=1e-12)  # its rest posture is straight
    p = arm.fk(arm.sample_q(5000, seed=9))
    assert np.all(np.linalg.norm(p, axis=1) <= 23.375 + 1e-9) and np.all(p[:, 2] == 0)
    geoms = arm.visual_model().geometryObjects
    assert len(geoms) == 2 * arm.nq + 2  # base, a joint cylinder and a link box per link, the tip


def test_snake_urdfs_are_the_generators_output():
    """robots/urdf/planar-10.urdf and planar-20.urdf are robots.snake's text, not hand edits."""
    from robots import snake

    for name, n in snake.SNAKES.items():
        with open(snake.urdf_path(name), encoding="utf-8") as f:
            assert f.read() == snake.snake_urdf(n, name=name), "regenerate with python -m robots.snake"
    with pytest.raises(ValueError, match="whole number of links"):
        snake.snake_urdf(0)


@pytest.mark.parametrize("name", ["ur5", "panda", "kinova"])
def test_refine_makes_a_close_seed_exact_within_three_steps(name):
    """robots.ik.refine: damped Gauss-Newton on Pinocchio's Jacobian from seeds ~2 cm off
    reaches 0.1 mm on (nearly) every goal; each goal keeps its best iterate; q stays within limits."""
    from robots.ik import refine

    arm = robots.load(name)
    q_true = arm.sample_q(200, seed=11)
    goals = arm.reach(q_true)
    seeds = arm.within_limits(q_true + np.random.default_rng(0).normal(0, 0.02, q_true.shape))
    start = np.linalg.norm(arm.reach(seeds) - goals, axis=1)
    r = refine(arm, goals, seeds, steps=3, tol=1e-4)
    assert np.mean(r.error < 1e-4) >= 0.97, (np.median(start), np.percentile(r.error, 95))
    assert np.allclose(np.linalg.norm(arm.reach(r.q) - goals, axis=1), r.error)
    assert np.all(r.error <= start + 1e-12) and np.all(r.steps <= 3)
    assert np.all((r.q >= arm.lower - 1e-12) & (r.q <= arm.upper + 1e-12))


@pytest.mark.parametrize("name", ["z1", "panda"])
def test_refine_holds_a_joint_at_its_limit_instead_of_clipping_the_step(name):
    """Goals whose solution has a joint 0.02 rad from a limit, seeds ~3 cm off: a full step pushes
    that joint past the limit. Holding the joint and solving with the others, plus halving a step
    that does not lower the error, converges on nearly all of them (clipping the step instead, the
    first version, did not: docs/log.md)."""
    from robots.ik import refine

    arm = robots.load(name)
    n = 300
    rng = np.random.default_rng(1)
    q_true = arm.sample_q(n, seed=5)
    j = rng.integers(0, arm.nq, n)
    near = np.where(rng.random(n) < 0.5, arm.lower[j] + 0.02, arm.upper[j] - 0.02)
    q_true[np.arange(n), j] = np.where(arm.chain.continuous[j].astype(bool), q_true[np.arange(n), j], near)
    goals = arm.reach(q_true)
    seeds = arm.within_limits(q_true + rng.normal(0, 0.05, q_true.shape))
    r = refine(arm, goals, seeds, steps=3, tol=1e-4)
    assert np.mean(r.error < 1e-4) >= 0.98
    assert np.all((r.q >= arm.lower - 1e-12) & (r.q <= arm.upper + 1e-12))
    assert np.allclose(np.linalg.norm(arm.reach(r.q) - goals, axis=1), r.error)


@pytest.mark.parametrize("name", ["so100", "so101", "ur5", "kinova", "planar"])
def test_refine_turns_the_first_joint_to_the_goals_bearing_in_closed_form(name):
    """A seed wrong in the first joint alone (by up to 1.5 rad) is made exact by the turn, before any
    Gauss-Newton step (steps=0): about the SO arms' offset axis, a continuous joint (Kinova, turning
    about -z) and the planar arm's x-y plane alike. turn=False leaves it as it was."""
    from robots.ik import refine

    arm = robots.load(name)
    q_true = arm.sample_q(300, seed=3)
    goals = arm.reach(q_true)
    seeds = q_true.copy()
    seeds[:, 0] += np.random.default_rng(2).uniform(-1.5, 1.5, len(seeds))
    inside = (seeds[:, 0] >= arm.lower[0]) & (seeds[:, 0] <= arm.upper[0]) | bool(arm.chain.continuous[0])
    seeds, goals = arm.within_limits(seeds[inside]), goals[inside]
    start = np.linalg.norm(arm.reach(seeds) - goals, axis=1)
    r = refine(arm, goals, seeds, steps=0, tol=1e-12 * arm.reach_radius)
    assert len(goals) > 150 and np.max(r.error) < 1e-8 * arm.reach_radius  # the axis is rounded to 1e-9
    assert np.allclose(r.q[:, 1:], seeds[:, 1:]) and np.all(r.steps == 0)
    assert np.allclose(refine(arm, goals, seeds, steps=0, turn=False).error, start, rtol=1e-9, atol=0)


def test_refine_turns_the_first_joint_no_further_than_its_limit():
    """Goals whose bearing lies beyond the first joint's range (SO100's pan: [-2, 2] rad; the goals of
    a pan angle of 2.5): the turn stops at the limit nearer in angle to go (+2, not -2), and the
    error never grows."""
    from robots.ik import refine

    arm = robots.load("so100")
    q = arm.sample_q(200, seed=4)
    q[:, 0] = 2.5  # reach() computes the pose beyond the limit
    goals = arm.reach(q)
    seeds = q.copy()
    seeds[:, 0] = 0.0  # the goals' bearing: 2.5 rad ahead (0.5 past +2) or 3.78 behind (1.78 past -2)
    start = np.linalg.norm(arm.reach(seeds) - goals, axis=1)
    r = refine(arm, goals, seeds, steps=0, tol=1e-12)
    assert np.all(r.error <= start) and np.all(r.q[:, 0] == arm.upper[0])


def test_refine_with_several_proposals_keeps_the_one_on_the_right_branch():
    """q0 (k, n, nq): k proposals per goal (a multi-head network's). Each takes the turn and one
    step, the nearest goes on: with one proposal 2 cm off and the others on far branches (another
    goal's joints), every goal ends where the close one alone takes it, whatever the proposals'
    order, and never after more than `steps` steps. One proposal as (1, n, nq) is the (n, nq) call."""
    from robots.ik import refine

    arm = robots.load("so101")
    n, rng = 120, np.random.default_rng(3)
    q_true = arm.sample_q(n, seed=21)
    goals = arm.reach(q_true)
    close = arm.within_limits(q_true + rng.normal(0, 0.02, q_true.shape))
    far = arm.sample_q(2 * n, seed=22).reshape(2, n, arm.nq)
    alone = refine(arm, goals, close, steps=3, tol=1e-4)
    assert np.mean(alone.error < 1e-4) >= 0.95
    assert refine(arm, goals, close, steps=3, tol=1e-4, flips=False).choice is None  # one proposal, no half turns
    where = rng.integers(0, 3, n)  # the close proposal's place among the three
    P = np.empty((3, n, arm.nq))
    P[where, np.arange(n)] = close
    others = np.array([[j for j in range(3) if j != w] for w in where]).T
    P[others[0], np.arange(n)], P[others[1], np.arange(n)] = far[0], far[1]
    r = refine(arm, goals, P, steps=3, tol=1e-4)
    assert np.all(r.steps <= 3)
    assert np.allclose(np.linalg.norm(arm.reach(r.q) - goals, axis=1), r.error)
    ok = alone.error < 1e-4
    assert np.mean(r.error[ok] < 1e-4) >= 0.97  # a far proposal wins only where it refines as well
    assert np.mean(r.choice[ok] == where[ok]) >= 0.9
    one = refine(arm, goals, close[None], steps=3, tol=1e-4)
    assert np.array_equal(one.q, alone.q) and np.array_equal(one.steps, alone.steps)


def test_refine_stops_at_a_tenth_of_a_millimetre_on_a_real_arm_by_default():
    """refine's default tolerance (robots.ik.default_tolerance): 1e-4 m on a real arm, the figure the
    docs promise (not 1e-4 x its workspace size, 0.19 mm on the UR5); 1e-4 x the workspace size on
    the paper's arms and the snakes (their units); 1e-4 m on a tree (each effector within it)."""
    from robots.ik import default_tolerance, refine, workspace_size

    for name in ("ur5", "so100", "kinova", "solo12", "allegro"):
        assert default_tolerance(robots.load(name)) == 1e-4
    for name in ("planar", "scara", "planar-10"):
        arm = robots.load(name)
        assert default_tolerance(arm) == 1e-4 * workspace_size(arm)
    arm = robots.load("ur5")
    assert 1e-4 * workspace_size(arm) > 1.5e-4
    # seeds 0.15 mm off (the wrist 1 joint alone): within 1e-4 x workspace size, not within 0.1 mm
    q_true = arm.sample_q(60, seed=7)
    goals = arm.reach(q_true)
    lever = np.linalg.norm(arm.jacobian(q_true)[:, :, 3], axis=1)  # m per rad of joint 3
    seeds = q_true.copy()
    seeds[:, 3] += 1.5e-4 / lever
    start = np.linalg.norm(arm.reach(seeds) - goals, axis=1)
    assert np.all((start > 1e-4) & (start < 1e-4 * workspace_size(arm)))
    r = refine(arm, goals, seeds, steps=1, turn=False)
    assert np.all(r.steps == 1) and np.all(r.error < 1e-4)
    same = refine(arm, goals, seeds, steps=1, tol=1e-4, turn=False)
    assert np.array_equal(r.q, same.q) and np.array_equal(r.error, same.error)
    looser = refine(arm, goals, seeds, steps=1, tol=1e-4 * workspace_size(arm), turn=False)
    assert np.all(looser.steps == 0)


@pytest.mark.parametrize("name", ["ur5", "scara", "kinova", "planar"])
def test_refines_bend_is_the_second_derivative_along_the_step(name):
    """robots.ik._curvature: d2p/dt2 along q + t v from the Jacobian's columns and the joints' axes
    equals central finite differences of the arm's reach (revolute, prismatic and continuous joints;
    the planar arm's two task axes)."""
    from robots.ik import _curvature, _data, _task_jacobian_axes

    arm = robots.load(name)
    axes, rng, h = list(arm.task_axes), np.random.default_rng(8), 1e-4
    for x in arm.sample_q(10, seed=8):
        v = rng.standard_normal(arm.nq)
        J, parts = _task_jacobian_axes(arm, _data(arm), arm.to_pinocchio(x), axes)
        np.testing.assert_allclose(J, arm.jacobian(x)[axes], rtol=0, atol=1e-9)
        fd = (arm.reach(x + h * v) - 2 * arm.reach(x) + arm.reach(x - h * v)) / h**2
        np.testing.assert_allclose(_curvature(parts, v, axes), fd, rtol=0, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_refine_bends_its_steps_and_turns_a_wrist_by_half_a_turn_near_full_reach():
    """UR5 goals near full reach (the elbow within 0.15 rad of straight), seeds 0.02 rad off the
    solution with wrist 2 turned by half a turn (its offset pointing away): straight steps solve
    few, bent steps more, and the half-turn proposals (tried when the first step takes less than
    90 % of the error off) nearly all, the wrist's (choice k + j - 1 = 4) on most, within 3 steps."""
    from robots.ik import refine

    arm = robots.load("ur5")
    rng = np.random.default_rng(5)
    q_true = arm.sample_q(200, seed=9)
    q_true[:, 2] = rng.uniform(-0.15, 0.15, len(q_true))
    goals = arm.reach(q_true)
    seeds = q_true + rng.normal(0, 0.02, q_true.shape)
    seeds[:, 4] += np.where(seeds[:, 4] + np.pi <= arm.upper[4], np.pi, -np.pi)
    seeds = arm.within_limits(seeds)
    straight = refine(arm, goals, seeds, steps=3, tol=1e-4, curved=False, flips=False)
    bent = refine(arm, goals, seeds, steps=3, tol=1e-4, flips=False)
    both = refine(arm, goals, seeds, steps=3, tol=1e-4)
    ok = [np.mean(r.error < 1e-4) for r in (straight, bent, both)]
    assert ok[0] < 0.75 and ok[1] > ok[0] + 0.15 and ok[2] >= 0.98, ok
    assert np.mean(both.choice == 4) >= 0.5 and np.all(both.steps <= 3)
    assert np.allclose(np.linalg.norm(arm.reach(both.q) - goals, axis=1), both.error)
    assert np.all((both.q >= arm.lower - 1e-12) & (both.q <= arm.upper + 1e-12))


def test_refine_refuses_mismatched_shapes():
    from robots.ik import refine

    arm = robots.load("ur5")
    with pytest.raises(ValueError, match="goals must be"):
        refine(arm, np.zeros((2, 2)), np.zeros((2, 6)))
    with pytest.raises(ValueError, match="goals must be"):
        refine(arm, np.zeros((2, 3)), np.zeros((4, 3, 6)))  # proposals for 3 goals, not 2


def test_joint_poses_place_the_visual_geometry_where_pinocchio_does():
    from robots.visual import joint_poses, visual_geometry

    arm = robots.load("ur5")
    q = arm.sample_q(1, seed=2)[0]
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, arm.to_pinocchio(q))
    poses = joint_poses(arm, q)
    for j, (p, wxyz) in poses.items():
        assert np.allclose(p, data.oMi[j].translation)
        R = pin.Quaternion(wxyz[0], wxyz[1], wxyz[2], wxyz[3]).toRotationMatrix()
        assert np.allclose(R, data.oMi[j].rotation)
    geoms = visual_geometry(arm)
    assert geoms and all(g.kind == "Mesh" and g.params[0].shape[1] == 3 for g in geoms)


def test_inverted_limits_bad_task_axes_and_non_utf8_files_are_refused_by_name(tmp_path):
    text = open(os.path.join(os.path.dirname(robots.__file__), "urdf", "planar.urdf"), encoding="utf-8").read()
    inverted = re.sub(r'lower="([^"]+)" upper="([^"]+)"', r'lower="\2" upper="\1"', text, count=1)
    assert inverted != text
    path = tmp_path / "inverted.urdf"
    path.write_text(inverted)
    with pytest.raises(ValueError, match="inverted limits"):
        robots.from_urdf(path, "ee", task_axes=(0, 1))
    good = tmp_path / "good.urdf"
    good.write_text(text)
    for axes in ((0, 0), (0, 3), (), (0, 1, 2, 0)):
        with pytest.raises(ValueError, match="task_axes must be distinct axes"):
            robots.from_urdf(good, "ee", task_axes=axes)
    latin = tmp_path / "latin.urdf"
    latin.write_bytes(text.replace("planar", "plan\xe4r").encode("latin-1"))
    with pytest.raises(ValueError, match="not UTF-8"):
        robots.from_urdf(latin, "ee", task_axes=(0, 1))


@pytest.mark.parametrize("lower, upper", [("-1e308", "1e308"), ("-1e4", "0.5"), ("0", "1001")])
def test_absurd_joint_limits_are_refused_by_joint_name(tmp_path, lower, upper):
    """A revolute joint's limits beyond +-1e3 rad (a prismatic one's beyond +-1e3 m), from the URDF or
    from limits=, are refused naming the joint: +-1e308 once loaded and sampled all-NaN goals."""
    text = open(PLANAR_URDF, encoding="utf-8").read()
    absurd = re.sub(r'lower="([^"]+)" upper="([^"]+)"', f'lower="{lower}" upper="{upper}"', text, count=1)
    assert absurd != text
    path = tmp_path / "absurd.urdf"
    path.write_text(absurd)
    with pytest.raises(ValueError, match=r"revolute joint 'theta1' has absurd limits in the URDF .*within \+-1000 rad"):
        robots.from_urdf(path, "ee", task_axes=(0, 1))
    assert robots.from_urdf(path, "ee", task_axes=(0, 1), limits={"theta1": (-1.0, 1.0)}).lower[0] == -1.0
    with pytest.raises(ValueError, match=r"revolute joint 'theta2' has absurd limits given in limits="):
        robots.from_urdf(PLANAR_URDF, "ee", task_axes=(0, 1), limits={"theta2": (float(lower), float(upper))})
    with pytest.raises(ValueError, match=r"prismatic joint 'd4' has absurd limits given in limits=.*within \+-1000 m"):
        robots.from_urdf(os.path.join(os.path.dirname(robots.__file__), "urdf", "scara.urdf"), "ee",
                         limits={"d4": (float(lower), float(upper))})


def test_sample_goals_never_returns_nan_silently():
    import dataclasses

    arm = robots.load("planar")
    broken = dataclasses.replace(arm, upper=np.array([1e308, 1.0, 1.0]), lower=np.array([-1e308, 0.0, 0.0]))
    with np.errstate(over="ignore", invalid="ignore"), pytest.raises(ValueError, match="sampled goals are not finite"):
        broken.sample_goals(5, seed=0)
    assert np.isfinite(arm.sample_goals(5, seed=0)).all()
