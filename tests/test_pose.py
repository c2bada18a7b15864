"""robots.pose and pose refinement: the tool frame's pose and 6-row Jacobian equal Pinocchio's and
finite differences on real arms; angles are exact where arccos is not; bad poses are refused by name;
refine and dls_pose_ik bring reachable poses within 0.1 mm and 0.1 degree."""

import math

import numpy as np
import pinocchio as pin
import pytest

import robots
from robots import pose
from robots.ik import dls_pose_ik, refine, refine_pose

ARMS = ["ur5", "panda", "so100"]  # 6 joints, 7 joints, 5 joints with an approach axis
EVERY_SERIAL = ["ur5", "ur10", "panda", "so100", "so101", "z1", "xarm7", "kinova"]


def pinocchio_pose(arm, q):
    """The tool frame (4, 4) and its LOCAL_WORLD_ALIGNED Jacobian (6, nq), one q at a time, by Pinocchio."""
    data = arm.model.createData()
    T, J = [], []
    for x in arm.to_pinocchio(q):
        pin.framesForwardKinematics(arm.model, data, x)
        T.append(data.oMf[arm.ee_frame_id].homogeneous.copy())
        J.append(pin.computeFrameJacobian(arm.model, data, x, arm.ee_frame_id, pin.LOCAL_WORLD_ALIGNED))
    return np.array(T), np.array(J)


def random_rotations(n, seed):
    rng = np.random.default_rng(seed)
    return np.array([pin.exp3(v) for v in rng.normal(size=(n, 3))])


# ---------------------------------------------------------------- kinematics
@pytest.mark.parametrize("name", EVERY_SERIAL)
def test_pose_and_jacobian_equal_pinocchio(name):
    arm = robots.load(name)
    rng = np.random.default_rng(3)
    # within the limits and outside them (kinematics do not clip); kinova has continuous joints
    q = np.concatenate([arm.sample_q(40, seed=1), rng.uniform(-4, 4, (10, arm.nq))])
    T_pin, J_pin = pinocchio_pose(arm, q)
    T, J = pose.fk_pose_and_jacobian(arm, q)
    np.testing.assert_allclose(T, T_pin, rtol=0, atol=1e-12)
    np.testing.assert_allclose(J, J_pin, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(pose.fk_pose(arm, q), T)
    np.testing.assert_array_equal(pose.pose_jacobian(arm, q), J)
    np.testing.assert_allclose(T[:, :3, 3], arm.fk(q), rtol=0, atol=1e-12)  # the position fk's


@pytest.mark.parametrize("name", ARMS)
def test_jacobian_equals_finite_differences_of_the_pose(name):
    """Linear rows: d p / d q_k; angular rows: the turn log3(R(q + h e_k) R(q - h e_k)^T) / 2h, in
    the base frame's axes (LOCAL_WORLD_ALIGNED)."""
    arm = robots.load(name)
    q = arm.sample_q(5, seed=2)
    J = pose.pose_jacobian(arm, q)
    h = 1e-6
    for i in range(len(q)):
        for k in range(arm.nq):
            step = np.zeros(arm.nq)
            step[k] = h
            Tp, Tm = pose.fk_pose(arm, q[i] + step), pose.fk_pose(arm, q[i] - step)
            v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            w = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
            np.testing.assert_allclose(J[i, :3, k], v, rtol=0, atol=1e-7)
            np.testing.assert_allclose(J[i, 3:, k], w, rtol=0, atol=1e-7)


def test_batch_shapes_follow_q():
    arm = robots.load("ur5")
    assert pose.fk_pose(arm, arm.rest).shape == (4, 4)
    assert pose.fk_pose(arm, np.zeros((2, 3, 6))).shape == (2, 3, 4, 4)
    assert pose.pose_jacobian(arm, np.zeros((2, 3, 6))).shape == (2, 3, 6, 6)
    with pytest.raises(ValueError, match="shape"):
        pose.fk_pose(arm, np.zeros(5))


@pytest.mark.parametrize("name", ARMS)
def test_sampled_poses_are_rotations_at_the_sampled_goals(name):
    arm = robots.load(name)
    T = pose.sample_poses(arm, 200, seed=4)
    assert T.shape == (200, 4, 4)
    np.testing.assert_array_equal(pose.check_poses(T), T)
    np.testing.assert_allclose(T[:, :3, 3], arm.sample_goals(200, seed=4), rtol=0, atol=1e-12)  # same joint vectors
    np.testing.assert_array_equal(T, pose.sample_poses(arm, 200, seed=4))
    assert not np.array_equal(T, pose.sample_poses(arm, 200, seed=5))


# ---------------------------------------------------------------- what a pose holds
def test_full_pose_on_six_and_seven_joints_and_an_approach_axis_on_the_so_arms():
    for name in ("ur5", "ur10", "panda", "z1", "xarm7", "kinova"):
        assert pose.approach_axis(robots.load(name)) is None and pose.pose_dims(robots.load(name)) == 6
    np.testing.assert_allclose(pose.approach_axis(robots.load("so100")), [0.0, -1.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(pose.approach_axis(robots.load("so101")), [0.0, 0.0, 1.0], rtol=0, atol=1e-5)
    assert pose.pose_dims(robots.load("so100")) == 5


@pytest.mark.parametrize("name", ["so100", "so101"])
def test_the_approach_axis_is_the_roll_axis_and_points_away_from_the_wrist(name):
    """Turning the last joint (the wrist roll) leaves the approach direction where it is (the roll
    is what a 5-joint pose leaves free), and the axis points from the wrist-flex joint out toward
    the tool (the fingers), not back into the arm."""
    arm = robots.load(name)
    axis = pose.approach_axis(arm)
    q = arm.sample_q(50, seed=6)
    rolled = q.copy()
    rolled[:, -1] = arm.lower[-1] + (arm.upper[-1] - arm.lower[-1]) * np.random.default_rng(0).random(len(q))
    a, a_rolled = pose.fk_pose(arm, q)[:, :3, :3] @ axis, pose.fk_pose(arm, rolled)[:, :3, :3] @ axis
    np.testing.assert_allclose(a, a_rolled, rtol=0, atol=1e-12)
    wrist_flex = arm.joint_positions(q)[:, arm.nq - 1]  # origins: base, then each joint in order
    tool = pose.fk_pose(arm, q)[:, :3, 3]
    ahead = np.einsum("ij,ij->i", tool + 0.05 * a - wrist_flex, a)
    assert np.all(ahead > 0.04)


def test_arms_that_take_no_pose_are_refused_with_the_reason():
    with pytest.raises(ValueError, match=r"task axes \(0, 1\)"):
        pose.approach_axis(robots.load("planar"))
    with pytest.raises(ValueError, match="4 joints: a full pose needs 6"):
        pose.approach_axis(robots.load("scara"))
    with pytest.raises(ValueError, match="4 end effectors"):
        pose.sample_poses(robots.load("solo12"), 3, seed=0)


# ---------------------------------------------------------------- validation
def test_check_poses_accepts_rotations_and_one_pose():
    T = pose.sample_poses(robots.load("panda"), 5, seed=0)
    assert pose.check_poses(T[0]).shape == (1, 4, 4)
    assert pose.check_poses(T.astype(np.float32)).dtype == np.float64  # float32 rounding is within atol
    nudged = T.copy()
    nudged[:, :3, :3] *= 1 + 1e-9
    pose.check_poses(nudged)


@pytest.mark.parametrize("bad, message", [
    (np.zeros((5, 3, 3)), r"shape \(n, 4, 4\).*got shape \(5, 3, 3\)"),
    (np.zeros((5, 3)), r"shape \(n, 4, 4\)"),
    (np.zeros((2, 2, 4, 4)), r"shape \(n, 4, 4\)"),
    (np.array([["a"] * 4] * 4), "real numbers"),
    ("nan", "real numbers"),
])
def test_check_poses_refuses_a_wrong_shape_or_type(bad, message):
    with pytest.raises(ValueError, match=message):
        pose.check_poses(bad)


def _bad(kind):
    T = pose.sample_poses(robots.load("ur5"), 6, seed=1)
    if kind == "nan":
        T[3, 0, 3] = np.nan
    elif kind == "inf":
        T[3, 1, 1] = np.inf
    elif kind == "bottom":
        T[3, 3, 0] = 0.5
    elif kind == "scaled":
        T[3, :3, :3] *= 1.01
    elif kind == "sheared":
        T[3, 0, 1] += 1e-3
    elif kind == "reflection":
        T[3, :3, 2] *= -1
    return T


@pytest.mark.parametrize("kind, message", [
    ("nan", "NaN or infinity.*pose 3"),
    ("inf", "NaN or infinity.*pose 3"),
    ("bottom", r"last row other than \(0, 0, 0, 1\).*pose 3"),
    ("scaled", "not orthonormal.*pose 3"),
    ("sheared", "not orthonormal.*pose 3"),
    ("reflection", "det -1.*reflection, not a rotation.*pose 3"),
])
def test_check_poses_names_the_problem_and_the_pose(kind, message):
    with pytest.raises(ValueError, match=message):
        pose.check_poses(_bad(kind))


@pytest.mark.parametrize("kind", ["nan", "scaled", "reflection"])
def test_refine_and_features_refuse_a_bad_pose_before_any_work(kind):
    arm = robots.load("ur5")
    T = _bad(kind)
    with pytest.raises(ValueError, match="pose 3"):
        refine(arm, T, np.tile(arm.rest, (len(T), 1)))
    with pytest.raises(ValueError, match="pose 3"):
        pose.pose_features(arm, T)
    with pytest.raises(ValueError, match="pose 3"):
        pose.pose_errors(arm, T, np.tile(arm.rest, (len(T), 1)))


# ---------------------------------------------------------------- angles and features
def test_rotation_angle_is_the_norm_of_log3_and_exact_near_zero_and_half_a_turn():
    Ra, Rb = random_rotations(100, 0), random_rotations(100, 1)
    expected = [np.linalg.norm(pin.log3(a.T @ b)) for a, b in zip(Ra, Rb)]
    # (1e-10: near half a turn log3's own rounding is 1e-12)
    np.testing.assert_allclose(pose.rotation_angle(Ra, Rb), expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(pose.rotation_angle(Rb, Ra), expected, rtol=0, atol=1e-10)
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    for angle in (1e-9, 1e-6, 0.3, math.pi - 1e-7, math.pi - 1e-9):
        R = pin.exp3(angle * axis)
        assert abs(pose.rotation_angle(Ra[0], Ra[0] @ R) - angle) < 1e-14 + 1e-12 * angle
    # where arccos((trace - 1) / 2) loses half the digits
    small = pin.exp3(1e-9 * axis)
    assert abs(np.arccos(min(1.0, (np.trace(small) - 1) / 2)) - 1e-9) > 1e-9 / 10
    assert pose.axis_angle_between([1.0, 0, 0], [math.cos(1e-9), math.sin(1e-9), 0]) == pytest.approx(1e-9, rel=1e-12)
    assert pose.axis_angle_between([1.0, 0, 0], [-1.0, 1e-9, 0]) == pytest.approx(math.pi - 1e-9, abs=1e-15)


def test_the_6d_feature_is_continuous_and_gives_the_rotation_back():
    R = random_rotations(50, 2)
    x = pose.rotation_6d(R)
    assert x.shape == (50, 6)
    np.testing.assert_allclose(pose.rotation_from_6d(x), R, rtol=0, atol=1e-12)
    # near rotations have near features (a quaternion's sign can jump; this cannot)
    turned = R @ np.array([pin.exp3(v) for v in np.full((50, 3), 1e-6)])
    assert np.abs(pose.rotation_6d(turned) - x).max() < 1e-5
    noisy = pose.rotation_from_6d(x + np.random.default_rng(0).normal(0, 0.1, x.shape))
    np.testing.assert_allclose(np.swapaxes(noisy, 1, 2) @ noisy, np.broadcast_to(np.eye(3), noisy.shape), atol=1e-12)
    assert np.all(np.linalg.det(noisy) > 0)


def test_pose_features_are_position_and_6d_or_position_and_approach_axis():
    ur5, so100 = robots.load("ur5"), robots.load("so100")
    T = pose.sample_poses(ur5, 10, seed=0)
    f = pose.pose_features(ur5, T)
    np.testing.assert_array_equal(f, np.concatenate([T[:, :3, 3], T[:, :3, 0], T[:, :3, 1]], axis=1))
    T = pose.sample_poses(so100, 10, seed=0)
    f = pose.pose_features(so100, T)
    np.testing.assert_allclose(f, np.concatenate([T[:, :3, 3], -T[:, :3, 1]], axis=1), rtol=0, atol=1e-12)


def test_pose_errors_are_zero_at_the_answer_and_the_so100_roll_is_free():
    for name in ARMS:
        arm = robots.load(name)
        q = arm.sample_q(20, seed=8)
        p, a = pose.pose_errors(arm, pose.fk_pose(arm, q), q)
        assert np.all(p < 1e-12) and np.all(a < 1e-7)
    arm = robots.load("so100")
    q = arm.sample_q(20, seed=8)
    rolled = q.copy()
    rolled[:, -1] = 0.0
    p, a = pose.pose_errors(arm, pose.fk_pose(arm, q), rolled)
    assert np.all(p < 1e-12) and np.all(a < 1e-7)  # its tool frame sits on the roll axis
    ur5 = robots.load("ur5")
    q = ur5.sample_q(20, seed=8)
    turned = q.copy()
    turned[:, -1] += 0.5
    assert np.allclose(pose.pose_errors(ur5, pose.fk_pose(ur5, q), turned)[1], 0.5)


@pytest.mark.parametrize("name", ["ur5", "so100", "so101"])
def test_the_residual_jacobian_is_minus_the_derivative_of_the_residual(name):
    """e(q + dq) = e(q) - Je dq to first order, for the full pose (log3 with Jlog3) and the approach
    axis (the chord g - a), far from the goal as well as near it."""
    arm = robots.load(name)
    axis = pose.approach_axis(arm)
    goals = pose.sample_poses(arm, 3, seed=1)
    data = arm.model.createData()

    def res(q, goal):
        x = arm.to_pinocchio(q)
        J6 = pin.computeFrameJacobian(arm.model, data, x, arm.ee_frame_id, pin.LOCAL_WORLD_ALIGNED)
        return pose.residual(goal, data.oMf[arm.ee_frame_id], J6, axis, 0.1)

    h = 1e-6
    for goal, q in zip(goals, arm.sample_q(3, seed=2)):
        _, Je, *_ = res(q, goal)
        fd = np.stack([(res(q + h * np.eye(arm.nq)[k], goal)[0] - res(q - h * np.eye(arm.nq)[k], goal)[0]) / (2 * h)
                       for k in range(arm.nq)], axis=1)
        np.testing.assert_allclose(-Je, fd, rtol=0, atol=1e-7)


# ---------------------------------------------------------------- refinement
def _near(arm, n, seed, noise=0.05):
    q_true = arm.sample_q(n, seed=seed)
    rng = np.random.default_rng(seed + 100)
    return q_true, pose.fk_pose(arm, q_true), arm.within_limits(q_true + rng.normal(0, noise, q_true.shape))


@pytest.mark.parametrize("name", ARMS)
def test_refine_brings_reachable_poses_within_a_tenth_of_a_millimetre_and_degree(name):
    arm = robots.load(name)
    _, T, q0 = _near(arm, 60, seed=11)
    r = refine(arm, T, q0, steps=10)
    assert r.tol == 1e-4 and r.angle_tol == pytest.approx(math.radians(0.1))
    assert r.converged.all(), (r.error.max(), np.degrees(r.angle.max()))
    p, a = pose.pose_errors(arm, T, r.q)  # the errors it reports are the pose's
    np.testing.assert_allclose(r.error, p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.angle, a, rtol=0, atol=1e-9)
    assert np.all((r.q >= arm.lower) & (r.q <= arm.upper))
    assert r.choice is None and np.all(r.steps <= 10)
    three = refine(arm, T, q0)  # the default: at most 3 steps
    assert np.all(three.steps <= 3) and three.converged.mean() >= 0.9


def test_refine_holds_its_tolerances_and_a_tighter_one_costs_steps():
    arm = robots.load("panda")
    _, T, q0 = _near(arm, 30, seed=12)
    loose = refine(arm, T, q0, steps=20, tol=1e-3, angle_tol=math.radians(1))
    tight = refine(arm, T, q0, steps=20, tol=1e-5, angle_tol=1e-5)  # TRAC-IK's criterion
    assert loose.converged.all() and tight.converged.all()
    assert np.all(tight.error < 1e-5) and np.all(tight.angle < 1e-5)
    assert tight.steps.sum() > loose.steps.sum()


def test_refine_takes_proposals_and_keeps_the_one_that_reaches():
    arm = robots.load("ur5")
    q_true, T, q0 = _near(arm, 20, seed=13, noise=0.02)
    far = arm.sample_q(20, seed=99)
    r = refine(arm, T, np.stack([far, q0]), steps=3)
    assert r.choice is not None and r.choice.shape == (20,)
    assert r.converged.mean() >= 0.9
    assert np.mean(r.choice == 1) >= 0.9  # the nearby proposal wins where the far one does not reach
    one = refine(arm, T[0], q0[0], steps=5)  # one pose (4, 4) and one seed (nq,)
    assert one.q.shape == (1, arm.nq) and one.converged.all()


def test_refine_refuses_bad_pose_calls_by_name():
    arm = robots.load("ur5")
    T = pose.sample_poses(arm, 4, seed=0)
    with pytest.raises(ValueError, match=r"q0 must be \(4, 6\) or \(k, 4, 6\)"):
        refine(arm, T, np.zeros((3, 6)))
    with pytest.raises(ValueError, match="angle_tol applies to pose goals"):
        refine(arm, arm.sample_goals(4, seed=0), np.zeros((4, 6)), angle_tol=0.01)
    with pytest.raises(ValueError, match="tol and angle_tol must be finite and > 0"):
        refine(arm, T, np.zeros((4, 6)), angle_tol=0.0)
    with pytest.raises(ValueError, match=r"task axes \(0, 1\)"):
        planar = robots.load("planar")
        refine(planar, T, np.zeros((4, planar.nq)))


def test_position_goals_still_take_the_position_path():
    arm = robots.load("ur5")
    goals = arm.sample_goals(20, seed=3)
    q0 = arm.within_limits(arm.sample_q(20, seed=3) + 0.01)
    r = refine(arm, goals, q0)
    assert r.angle is None and r.tol == 1e-4
    np.testing.assert_array_equal(r.converged, r.error < 1e-4)
    np.testing.assert_allclose(r.error, np.linalg.norm(arm.fk(r.q) - goals, axis=1), atol=1e-12)


@pytest.mark.parametrize("name", ["ur5", "so100"])
def test_dls_with_restarts_reaches_poses_from_the_rest_pose(name):
    arm = robots.load(name)
    T = pose.sample_poses(arm, 8, seed=21)
    results = [dls_pose_ik(arm, g, restarts=30, seed=0) for g in T]
    assert all(r.converged for r in results)
    for g, r in zip(T, results):
        p, a = pose.pose_errors(arm, g[None], r.q[None])
        assert p[0] == pytest.approx(r.error, abs=1e-12) and a[0] == pytest.approx(r.angle, abs=1e-9)
        assert r.error < 1e-4 and r.angle < math.radians(0.1)
    again = dls_pose_ik(arm, T[0], restarts=30, seed=0)
    np.testing.assert_array_equal(again.q, results[0].q)  # a seed makes it repeatable
    with pytest.raises(ValueError, match="one pose"):
        dls_pose_ik(arm, T, restarts=1)


def test_refine_pose_is_refine_on_poses():
    arm = robots.load("so100")
    _, T, q0 = _near(arm, 10, seed=14)
    a, b = refine(arm, T, q0), refine_pose(arm, T, q0)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.angle, b.angle)


def test_a_five_joint_arm_of_your_own_holds_its_last_joints_axis_toward_the_tool():
    """Any 5-joint chain takes pose goals held to an approach axis: its last joint's axis in the tool
    frame (turning that joint leaves the direction where it is), pointing from that joint toward the
    tool; the SO-100 loaded by its example-robot-data name gets the registered arm's axis."""
    import os

    arm = robots.load(os.path.join(os.path.dirname(__file__), "data", "own_arm.urdf"), ee="tool0")
    assert arm.nq == 5 and robots.kind(arm.name) == "custom"
    axis = pose.approach_axis(arm)
    assert pose.pose_dims(arm) == 5 and abs(np.linalg.norm(axis) - 1) < 1e-12
    q = arm.sample_q(50, seed=6)
    rolled = q.copy()
    rolled[:, -1] = arm.lower[-1] + (arm.upper[-1] - arm.lower[-1]) * np.random.default_rng(0).random(len(q))
    a, a_rolled = pose.fk_pose(arm, q)[:, :3, :3] @ axis, pose.fk_pose(arm, rolled)[:, :3, :3] @ axis
    np.testing.assert_allclose(a, a_rolled, rtol=0, atol=1e-12)
    last = arm.joint_positions(q)[:, arm.nq]  # origins: base, then each joint in order
    tool = pose.fk_pose(arm, q)[:, :3, 3]
    assert np.all(np.einsum("ij,ij->i", tool - last, a) > 0)  # toward the tool, not back into the arm
    np.testing.assert_allclose(pose.approach_axis(robots.load("erd:so100")), pose.approach_axis(robots.load("so100")),
                               rtol=0, atol=1e-12)
