"""lab: the paper's MLP and fitness, NEAT phenotypes equal neat-python's, runs are reproducible,
the runner obeys its controls, and bad input is refused before any work."""

import copy
import json
import logging
import os
import random
import subprocess
import sys
import threading
import time

import neat
import numpy as np
import pytest

import lab
from conftest import METHODS, wait_until as wait_for
import robots
from lab.methods.cmaes import CMAESBackend
from lab.methods.neat import NEATBackend, compile_genomes, genome_program, genome_to_controller, program_hidden
from lab.problem.controllers import GraphController, MLPController, compile_programs, controller_from_dict, mlp_size
from lab.problem.encoding import Encoding
from lab.problem import Problem, goal_errors
from lab.running.runner import build_problem

SMALL = dict(test_goals=200)


# ---------------------------------------------------------------- independent references
def np_mlp(x, weights, ni, nh, no):
    """The paper's MLP (section 4.3), written out with numpy: tanh(tanh([x, 1] w_i) w_o)."""
    w_i = weights[: (ni + 1) * nh].reshape(ni + 1, nh)
    w_o = weights[(ni + 1) * nh :].reshape(nh, no)
    xb = np.hstack([x, np.ones((len(x), 1))])
    return np.tanh(np.tanh(xb @ w_i) @ w_o)


def np_joints(arm, a, margin=0.0):
    """Outputs in [-1, 1] onto the joint range widened by margin (a fraction of the half range), clipped."""
    half = (arm.upper - arm.lower) / 2.0
    lo, hi = arm.lower - margin * half, arm.upper + margin * half
    return np.clip(lo + (a + 1.0) / 2.0 * (hi - lo), arm.lower, arm.upper)


def np_mse(arm, goals, q):
    reached = arm.fk(q)[:, list(arm.task_axes)]
    return float(np.mean(np.sum((goals - reached) ** 2, axis=1)))


def np_encode(arm, goals):
    """Cartesian encoding: each task coordinate scaled to [-1, 1] by the workspace bounds."""
    lo, hi = arm.workspace_bounds
    return 2.0 * (goals - lo) / (hi - lo) - 1.0


def far_goals(arm, n, seed):
    """Goals in and well outside the workspace (networks saturate there)."""
    lo, hi = arm.workspace_bounds
    rng = np.random.default_rng(seed)
    return lo + (hi - lo) * rng.uniform(-1.0, 2.0, (n, len(lo)))


# ---------------------------------------------------------------- 1. the MLP layout
@pytest.mark.parametrize("nh", [1, 5, 12])
def test_mlp_equals_the_papers_layout(nh):
    arm = robots.load("planar")
    enc = Encoding.for_arm(arm, "cartesian")
    ni, no = enc.n_inputs, enc.n_outputs
    assert (ni, no) == (2, 3)
    assert mlp_size(ni, nh, no) == (ni + 1) * nh + nh * no
    rng = np.random.default_rng(nh)
    goals = np.concatenate([arm.sample_goals(100, seed=5), far_goals(arm, 50, seed=6)])
    x = np_encode(arm, goals)
    np.testing.assert_allclose(enc.inputs(goals), x, rtol=0, atol=1e-12)
    for scale in (0.3, 1.0, 20.0):  # 20: saturated units
        w = rng.normal(0, scale, (ni + 1) * nh + nh * no)
        c = MLPController(enc, nh, w)
        np.testing.assert_allclose(c.w_i, w[: (ni + 1) * nh].reshape(ni + 1, nh), rtol=0, atol=0)
        np.testing.assert_allclose(c.w_o, w[(ni + 1) * nh :].reshape(nh, no), rtol=0, atol=0)
        a = np_mlp(x, w, ni, nh, no)
        np.testing.assert_allclose(c.outputs(goals), a, rtol=0, atol=1e-12)
        q = c(goals)
        assert q.shape == (len(goals), arm.nq)
        np.testing.assert_allclose(q, np_joints(arm, a), rtol=0, atol=1e-12)
        assert np.all((q >= arm.lower) & (q <= arm.upper))


def test_mlp_rejects_a_wrong_weight_count():
    enc = Encoding.for_arm(robots.load("planar"), "cartesian")
    with pytest.raises(ValueError, match="weights"):
        MLPController(enc, 4, np.zeros(mlp_size(2, 4, 3) + 1))


def test_polar_features_are_cartesian_plus_radius_and_bearing():
    arm = robots.load("scara")
    enc = Encoding.for_arm(arm, "polar")
    goals = arm.sample_goals(200, seed=2)
    x = enc.inputs(goals)
    assert x.shape == (200, 5)
    raw = np.column_stack([goals, np.hypot(goals[:, 0], goals[:, 1]), np.arctan2(goals[:, 1], goals[:, 0])])
    np.testing.assert_allclose(x, 2 * (raw - enc.in_lo) / (enc.in_hi - enc.in_lo) - 1, atol=1e-12)
    assert np.all(np.abs(x) <= 1.0 + 0.05)  # the workspace maps into about [-1, 1]


def test_reach_features_add_the_slack_of_reach_that_linearizes_the_scara_elbow():
    arm = robots.load("scara")
    enc = Encoding.for_arm(arm, "reach")
    assert enc.r_max == pytest.approx(40.0, abs=0.05) and enc.input_names == ["x", "y", "z", "r", "φ", "s"]
    q = np.random.default_rng(4).uniform(arm.lower, arm.upper, (300, 4))
    goals = arm.fk(q)
    x = enc.inputs(goals)
    s = np.sqrt(np.clip(1 - np.hypot(goals[:, 0], goals[:, 1]) / enc.r_max, 0, 1))
    np.testing.assert_allclose(x[:, :5], Encoding.for_arm(arm, "polar").inputs(goals), atol=1e-12)
    np.testing.assert_allclose(x[:, 5], 2 * (s - enc.in_lo[5]) / (enc.in_hi[5] - enc.in_lo[5]) - 1, atol=1e-12)
    # the elbow angle theta2 = 2 acos(r / 40) is close to linear in s (a line fits it to 0.05 rad),
    # and far from linear in r
    line_error = {name: np.abs(np.polyval(np.polyfit(v, q[:, 1], 1), v) - q[:, 1]).max()
                  for name, v in (("s", s), ("r", np.hypot(goals[:, 0], goals[:, 1])))}
    assert line_error["s"] < 0.05 and line_error["r"] > 5 * line_error["s"], line_error
    # beyond the workspace s stays 0, and the encoding survives a round trip through JSON
    far = np.array([[60.0, 0.0, -3.0]])
    assert enc.inputs(far)[0, 5] == pytest.approx(2 * (0 - enc.in_lo[5]) / (enc.in_hi[5] - enc.in_lo[5]) - 1)
    again = Encoding.from_dict(json.loads(json.dumps(enc.to_dict())))
    assert np.array_equal(again.inputs(goals), x) and again.r_max == enc.r_max


def test_sphere_features_centre_on_the_shoulder_and_follow_the_elbow_of_an_arm_in_space():
    arm = robots.load("ur5")
    enc = Encoding.for_arm(arm, "sphere")
    assert enc.input_names == ["x", "y", "z", "r", "φ", "s", "ρ", "ψ", "σ"]
    # the centre is the UR5's shoulder (d1 = 89.159 mm above the base), the radius the farthest goal from it
    assert enc.z_c == pytest.approx(0.089159, abs=0.003)
    q = np.random.default_rng(1).uniform(arm.lower, arm.upper, (3000, arm.nq))
    goals = arm.fk(q)
    rho = np.linalg.norm(goals - [0.0, 0.0, enc.z_c], axis=1)
    assert rho.max() <= enc.rho_max * (1 + 1e-3)
    x = enc.inputs(goals)
    np.testing.assert_allclose(x[:, :6], Encoding.for_arm(arm, "reach").inputs(goals), atol=1e-12)
    sigma = np.sqrt(np.clip(1 - rho / enc.rho_max, 0, 1))
    np.testing.assert_allclose(x[:, 8], 2 * (sigma - enc.in_lo[8]) / (enc.in_hi[8] - enc.in_lo[8]) - 1, atol=1e-12)
    # the elbow's bend |q3| follows the slack about the shoulder, not the slack about the base axis
    bend = np.abs(q[:, 2])
    assert np.corrcoef(bend, sigma)[0, 1] > 0.9 > 0.7 > np.corrcoef(bend, x[:, 5])[0, 1]
    again = Encoding.from_dict(json.loads(json.dumps(enc.to_dict())))
    assert np.array_equal(again.inputs(goals), x) and (again.z_c, again.rho_max) == (enc.z_c, enc.rho_max)
    # an arm in a plane has no sphere; a file without its centre is refused by name
    with pytest.raises(ValueError, match="sphere features need three task axes"):
        Encoding.for_arm(robots.load("planar"), "sphere")
    with pytest.raises(ValueError, match="sphere features need 3 task axes, a finite z_c and a positive rho_max"):
        Encoding.from_dict({k: v for k, v in enc.to_dict().items() if k != "rho_max"})


@pytest.mark.parametrize("name", ["so100", "so101"])
def test_r_and_phi_are_about_the_base_axis_so_the_base_joint_turns_phi_alone(name):
    """An arm whose base axis stands beside its URDF's origin (the SO arms, 4-5 cm): turning the base
    joint changes the input phi by just that turn, and r and the slacks not at all."""
    arm = robots.load(name)
    enc = Encoding.for_arm(arm, "sphere")
    assert np.allclose(enc.axis_xy, arm.base_axis[0][:2]) and np.linalg.norm(enc.axis_xy) > 0.03
    q = arm.sample_q(50, seed=3)
    q2 = q.copy()
    q2[:, 0] = np.clip(q[:, 0] + 0.3, arm.lower[0], arm.upper[0])
    turn = (q2[:, 0] - q[:, 0]) * np.sign(arm.base_axis[1][2])
    lo = enc.in_lo
    raw = [lo + (enc.inputs(arm.fk(a)) + 1) / 2 * (enc.in_hi - enc.in_lo) for a in (q, q2)]
    names = enc.input_names
    dphi = np.angle(np.exp(1j * (raw[1][:, names.index("φ")] - raw[0][:, names.index("φ")])))
    np.testing.assert_allclose(dphi, turn, atol=1e-4)  # SO101's pan axis leans 1e-4 off the vertical
    for k in ("r", "s", "ρ", "ψ", "σ", "z"):
        np.testing.assert_allclose(raw[1][:, names.index(k)], raw[0][:, names.index(k)], atol=1e-4)
    again = Encoding.from_dict(json.loads(json.dumps(enc.to_dict())))
    assert np.array_equal(again.axis_xy, enc.axis_xy)


def test_r_and_phi_are_about_a_base_axis_a_urdf_tilts_by_its_rounding():
    """example-robot-data's Bravo 7 on the BlueVolta vehicle: its base axis, meant to be vertical, leans
    0.09 degrees, 0.89 m from the URDF's origin; r and phi are taken about it all the same (about the
    origin, its inputs trained a network 7 times worse), so a turn of the base joint leaves r nearly
    as it is."""
    arm = robots.load("erd:bluevolta_bravo7_gripper")
    assert 1e-9 < 1 - abs(arm.base_axis[1][2]) < 1e-4 and np.linalg.norm(arm.base_axis[0][:2]) > 0.8
    enc = Encoding.for_arm(arm, "sphere")
    np.testing.assert_array_equal(enc.axis_xy, arm.base_axis[0][:2])
    q = arm.sample_q(50, seed=3)
    q2 = q.copy()
    q2[:, 0] += 0.5
    r = [np.hypot(*(arm.fk(a)[:, :2] - enc.axis_xy).T) for a in (q, q2)]
    np.testing.assert_allclose(r[1], r[0], atol=2e-3 * arm.reach_radius)


@pytest.mark.parametrize("name", [n for n in robots.names() if robots.kind(n) == "real"])
def test_a_real_arm_whose_limits_bind_reaches_them_without_saturating_its_outputs(name):
    """CMA-ES's real-arm margin (lab.methods.cmaes.margin_of): an arm whose every limited joint turns
    less than a turn (SO100, SO101, Z1, Panda, Kinova) gets one, so that its outputs reach each limit
    at |a| <= 0.8, in tanh's working range (atanh 1.1), not only at a saturated +-1; an arm with
    joints of +-2 pi keeps 0, whose limits lie two turns apart (UR5, UR10, xArm7)."""
    from lab.methods.cmaes import LIMITED_MARGIN, defaults

    arm = robots.load(name)
    margin = defaults(arm)["margin"]
    limited = ~np.asarray(arm.chain.continuous, bool)
    binds = bool(np.all((arm.upper - arm.lower)[limited] < 2 * np.pi))
    assert margin == (LIMITED_MARGIN if binds else 0.0)
    assert binds == (name in ("so100", "so101", "z1", "panda", "kinova"))
    enc = Encoding.for_arm(arm, defaults(arm)["features"], margin)
    a = (np.stack([arm.lower, arm.upper]) - enc.q_offset) / enc.q_scale - 1.0  # the outputs that land on the limits
    if binds:
        assert np.all(np.abs(a[:, limited]) <= 0.8)
        np.testing.assert_allclose(enc.joints(np.clip(a, -1, 1))[:, limited], np.stack([arm.lower, arm.upper])[:, limited], atol=1e-12)
        assert np.all(enc.joints(np.full((1, arm.nq), 1.0))[0] <= arm.upper)  # beyond: clipped to the limits
    else:
        np.testing.assert_allclose(np.abs(a[:, limited]), 1.0)


@pytest.mark.parametrize("name", ["so100", "so101"])
def test_bearings_put_phis_seam_behind_the_arm_and_phi_primes_in_front(name):
    """"bearings": "sphere" with phi measured from the bearing the arm faces (its goals' circular
    mean bearing: SO100 faces -y, SO101 +x) and phi' from the opposite one. phi's seam (+-pi) then lies
    among the fewest goals, behind the arm, and phi' has its seam in front, among the most."""
    arm = robots.load(name)
    enc, sphere = Encoding.for_arm(arm, "bearings"), Encoding.for_arm(arm, "sphere")
    assert enc.input_names == sphere.input_names + ["φ′"]
    assert np.degrees(enc.facing) == pytest.approx({"so100": -90.0, "so101": 0.0}[name], abs=3.0)
    goals = arm.sample_goals(4000, seed=8)
    raw = enc.in_lo + (enc.inputs(goals) + 1) / 2 * (enc.in_hi - enc.in_lo)
    raw_sphere = sphere.in_lo + (sphere.inputs(goals) + 1) / 2 * (sphere.in_hi - sphere.in_lo)
    phi = raw_sphere[:, 4]
    np.testing.assert_allclose(np.delete(raw[:, :9], 4, axis=1), np.delete(raw_sphere, 4, axis=1), atol=1e-9)
    np.testing.assert_allclose(np.exp(1j * raw[:, 4]), np.exp(1j * (phi - enc.facing)), atol=1e-9)
    np.testing.assert_allclose(np.exp(1j * raw[:, 9]), -np.exp(1j * raw[:, 4]), atol=1e-9)
    behind = np.sum(np.abs(raw[:, 4]) > np.radians(150))  # within 30 degrees of phi's seam
    in_front = np.sum(np.abs(raw[:, 9]) > np.radians(150))  # of phi''s seam
    assert behind < 0.5 * in_front, (behind, in_front)
    again = Encoding.from_dict(json.loads(json.dumps(enc.to_dict())))
    assert again.facing == enc.facing and np.array_equal(again.inputs(goals), enc.inputs(goals))
    with pytest.raises(ValueError, match="facing must be a bearing"):
        Encoding.from_dict({**enc.to_dict(), "facing": 7.0})


# ---------------------------------------------------------------- 2. the fitness
@pytest.mark.parametrize("robot,features,margin", [("planar", "cartesian", 0.0), ("scara", "cartesian", 0.0),
                                                    ("scara", "polar", 0.5), ("planar", "cylindrical", 1.0),
                                                    ("scara", "reach", 2.0), ("ur5", "sphere", 0.0),
                                                    ("so101", "bearings", 0.0)])
def test_mlp_mse_equals_numpy_fitness(robot, features, margin):
    arm = robots.load(robot)
    enc = Encoding.for_arm(arm, features, margin)
    prob = Problem(arm, enc, targets=40, test_goals=60, goal_seed=3)
    nh = 6
    D = mlp_size(enc.n_inputs, nh, enc.n_outputs)
    W = np.random.default_rng(0).normal(0, 1.0, (7, D))
    for test, goals in ((False, prob.train_goals), (True, prob.test_goals)):
        got = prob.mlp_mse(W, nh, test=test)
        assert got.shape == (7,)
        x = np_encode(arm, goals) if features == "cartesian" else enc.inputs(goals)
        for p, w in enumerate(W):
            q = np_joints(arm, np_mlp(x, w, enc.n_inputs, nh, enc.n_outputs), margin)
            expected = np_mse(arm, goals, q)
            assert got[p] == pytest.approx(expected, rel=0, abs=1e-9)
            c = MLPController(enc, nh, w)
            assert prob.controller_mse(c, goals) == pytest.approx(expected, rel=0, abs=1e-9)


def test_nan_and_overflowing_weights_get_inf_and_never_crash():
    arm = robots.load("scara")
    enc = Encoding.for_arm(arm, "cartesian")
    prob = Problem(arm, enc, targets=30, test_goals=30)
    nh = 4
    D = mlp_size(enc.n_inputs, nh, enc.n_outputs)
    W = np.random.default_rng(1).normal(0, 1, (6, D))
    W[0, 3] = np.nan
    W[1, :] = np.nan
    W[2, -1] = np.nan  # an output weight only
    W[3, 0] = np.inf  # tanh(inf) = 1: finite
    W[4, :] = np.where(np.arange(D) % 2, 1e308, -1e308)  # inf - inf inside the sums: NaN
    mse = prob.mlp_mse(W, nh)
    assert not np.any(np.isnan(mse))
    assert np.all(np.isinf(mse[[0, 1, 2]]))
    assert np.all((mse >= 0) & ((mse == np.inf) | np.isfinite(mse)))
    assert np.isfinite(mse[5])
    for w, m in zip(W, mse):  # the controller path agrees, inf included
        assert prob.controller_mse(MLPController(enc, nh, w)) == pytest.approx(m, rel=0, abs=1e-9) or m == np.inf
    # NaN network outputs and NaN goals: +inf, no exception
    A = np.zeros((2, len(prob.train_goals), arm.nq))
    A[0, 5, 1] = np.nan
    out = prob.outputs_mse(A)
    assert out[0] == np.inf and np.isfinite(out[1])
    bad_goals = prob.train_goals.copy()
    bad_goals[0, 0] = np.nan
    errs = goal_errors(arm, MLPController(enc, nh, W[5]), bad_goals)
    assert errs[0] == np.inf and np.all(np.isfinite(errs[1:]))


def test_resampled_goals_with_sep_cmaes_on_a_real_arm_are_warned_of(caplog):
    """sep-CMA-ES above pycma's TPA_dimension weights (a real arm's defaults) collapses its step size on
    resampled goals (docs/log.md): such a run says so; fixed goals, or the paper's arms, do not."""
    import logging

    def warned(**settings):
        caplog.clear()
        cfg = lab.TrainConfig(**{"generations": 1, "population": 4, "targets": 10, "test_goals": 10, **settings})
        with caplog.at_level(logging.WARNING, logger="lab.methods.cmaes"):
            CMAESBackend(build_problem(cfg), cfg)
        return [r.getMessage() for r in caplog.records if "two-point" in r.getMessage()]

    assert warned(robot="so100", resample=True) and "collapses" in warned(robot="so100", resample=True)[0]
    assert not warned(robot="so100")
    assert not warned(robot="planar", resample=True)
    assert not warned(robot="so100", resample=True, separable=False, hidden=4)


def test_a_nan_weight_vector_never_becomes_the_cmaes_best():
    cfg = lab.TrainConfig(population=10, generations=10, targets=20, test_goals=20)
    prob = build_problem(cfg)
    b = CMAESBackend(prob, cfg)
    real = prob.mlp_mse
    seen = []

    def poisoned(W, hidden, test=False, offsets=None):  # row 0 is evaluated as if its weights were NaN
        W = np.array(W)
        W[0, 0] = np.nan
        seen.append(W[0].copy())
        return real(W, hidden, test, offsets)

    prob.mlp_mse = poisoned
    for _ in range(10):
        f = b.step().fitness
        assert f[0] == np.inf
    assert b.best is not None and np.all(np.isfinite(b.best.weights))
    assert np.isfinite(b.best_mse)
    assert prob.controller_mse(b.best) == pytest.approx(b.best_mse, rel=0, abs=1e-9)

    # all rows NaN: no best at all, and the run goes on
    prob.mlp_mse = lambda W, hidden, test=False, offsets=None: real(np.full_like(np.asarray(W), np.nan), hidden, test, offsets)
    b2 = CMAESBackend(prob, cfg)
    for _ in range(3):
        assert np.all(b2.step().fitness == np.inf)
    assert b2.best is None and b2.best_mse == np.inf


def test_a_nan_genome_never_becomes_the_neat_best():
    cfg = lab.TrainConfig(method="neat", population=20, generations=5, targets=20, test_goals=20)
    b = NEATBackend(build_problem(cfg), cfg)
    for g in b.population.population.values():
        for c in g.connections.values():
            c.weight = np.nan
        break
    f = b.step().fitness
    assert f[0] == np.inf and np.isfinite(f[1:]).all()
    for _ in range(4):
        b.step()
    assert b.best is not None and np.isfinite(b.best_mse)
    assert all(np.isfinite(w) for _, _, _, links in b.best.nodes for _, w in links)
    assert b.problem.controller_mse(b.best) == pytest.approx(b.best_mse, rel=0, abs=1e-9)


# ---------------------------------------------------------------- 3. NEAT phenotypes
def structured_genomes(backend):
    """The backend's population, plus mutated copies with hidden nodes and added connections,
    an output cut off from the inputs, and a hidden node fed by nothing (neat-python 2.0
    evaluates such nodes as tanh(bias))."""
    gc = backend.neat_config.genome_config
    genomes = [copy.deepcopy(g) for g in backend.population.population.values()]
    state = random.getstate()
    random.seed(42)
    try:
        extra = []
        for k, g in enumerate(genomes[:12]):
            g = copy.deepcopy(g)
            for _ in range(1 + k % 3):
                g.mutate_add_node(gc)
            for _ in range(k % 4):
                g.mutate_add_connection(gc)
            extra.append(g)
        cut = copy.deepcopy(extra[0])
        out0 = gc.output_keys[0]
        for (i, o), c in cut.connections.items():
            if o == out0:
                c.enabled = False
        extra.append(cut)
        orphan = copy.deepcopy(extra[1])
        hidden = [k for k in orphan.nodes if k not in gc.output_keys]
        for (i, o), c in orphan.connections.items():
            if o == hidden[0]:
                c.enabled = False
        extra.append(orphan)
    finally:
        random.setstate(state)
    return genomes + extra


@pytest.mark.parametrize("robot", ["planar", "scara"])
def test_genome_to_controller_equals_neat_feed_forward_network(robot):
    cfg = lab.TrainConfig(robot=robot, method="neat", population=30, generations=15, targets=25, **SMALL)
    prob = build_problem(cfg)
    b = NEATBackend(prob, cfg)
    for _ in range(15):
        b.step()
    genomes = structured_genomes(b)
    enc, arm = prob.encoding, prob.arm
    goals = np.concatenate([prob.train_goals, far_goals(arm, 20, seed=9)])
    X = enc.inputs(goals)
    graphs = []
    for g in genomes:
        ctrl = genome_to_controller(g, b.neat_config, enc)
        net = neat.nn.FeedForwardNetwork.create(g, b.neat_config)
        expected = np.array([net.activate(list(x)) for x in X])
        np.testing.assert_allclose(ctrl.outputs(goals), expected, rtol=0, atol=1e-9)
        q = ctrl(goals)
        np.testing.assert_allclose(q, np_joints(arm, expected, ctrl.encoding.margin), rtol=0, atol=1e-9)
        assert np.all((q >= arm.lower) & (q <= arm.upper))
        graphs.append(ctrl)
    assert sum(c.n_hidden > 0 for c in graphs) >= 10  # the structure was exercised
    cut = graphs[-2].outputs(goals)[:, 0]  # an output cut off from the inputs: constant, as in neat
    assert np.all(cut == cut[0])
    # the backend's own path compiles genomes straight to compile_programs' arrays, bit for bit
    programs = [genome_program(g, b.neat_config) for g in genomes]
    for got, expected in zip(compile_genomes(programs), compile_programs(graphs)):
        assert type(got) is type(expected)
        if isinstance(got, np.ndarray):
            assert got.dtype == expected.dtype and got.shape == expected.shape and np.array_equal(got, expected)
        else:
            assert got == expected
    assert [program_hidden(p) for p in programs] == [c.n_hidden for c in graphs]

    for test, goals in ((False, prob.train_goals), (True, prob.test_goals)):
        got = prob.graphs_mse(graphs, test=test)
        for g, m in zip(genomes, got):
            net = neat.nn.FeedForwardNetwork.create(g, b.neat_config)
            a = np.array([net.activate(list(x)) for x in enc.inputs(goals)])
            assert m == pytest.approx(np_mse(arm, goals, np_joints(arm, a, enc.margin)), rel=0, abs=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_logged_hyperparameters_are_the_ones_the_optimizer_runs_with(method):
    """Backend.settings(problem, config) builds no backend (a recording of a run in a worker
    process logs it from the app's side), so check it against the optimizer a backend builds."""
    own = {"neat": dict(mutation_power=0.7), "neat_cma": dict(mutation_power=0.7, tune_evaluations=50)}.get(method, {})
    config = lab.TrainConfig(robot="scara", method=method, population=20, hidden=4, **own, **SMALL)
    problem = build_problem(config)
    backend = lab.methods.make_backend(problem, config)
    settings = type(backend).settings(problem, config)
    assert settings == backend.hyperparameters()
    if method == "cmaes":
        es = backend.es
        assert (settings["dim"], settings["popsize"], settings["sigma0"]) == (es.N, es.popsize, es.sigma0)
    elif method == "gradient":
        assert settings["dim"] == backend.w.size and settings["learning_rate"] == backend.options.learning_rate
        assert settings["evaluations_per_step"] == 1 + problem.arm.nq
    else:
        genome, pop = backend.neat_config.genome_config, backend.neat_config
        assert settings["pop_size"] == pop.pop_size == len(backend.population.population)
        assert settings["weight_mutate_power"] == genome.weight_mutate_power == 0.7
        assert (settings["node_add_prob"], settings["conn_add_prob"]) == (genome.node_add_prob, genome.conn_add_prob)
        assert settings["initial_hidden"] == genome.num_hidden == 4
        if method == "neat_cma":  # and the CMA-ES searches' (50 evaluations: 4 generations of 15)
            assert (settings["tune_batches"], settings["tune_population"]) == (4, 15)


# ---------------------------------------------------------------- 4. determinism
# diagonal=10: CMA-ES switches from its diagonal to its full sampler mid-run (pycma's new sampler
# would draw from numpy's global generator if the backend did not hand it the run's own)
# (a graph method gets a larger population: NEAT's species need room)
RUN = {m.name: dict(generations=30, population=12 if m.controller == "mlp" else 30, targets=30, **SMALL,
                    **({"diagonal": 10} if "diagonal" in m.options.names() else {}))
       for m in lab.methods.all_methods()}


def _scramble_global_random(k):
    np.random.seed(k)
    random.seed(k)


@pytest.mark.parametrize("method", METHODS)
def test_same_seed_same_run_different_seed_different_run(method):
    _scramble_global_random(1)
    a = lab.evolve("planar", method, seed=3, **RUN[method])
    _scramble_global_random(2)  # runs depend on their seed alone, not on global random state
    b = lab.evolve("planar", method, seed=3, **RUN[method])
    c = lab.evolve("planar", method, seed=4, **RUN[method])
    assert len(a.history) == RUN[method]["generations"]
    assert np.array_equal(a.history, b.history)
    assert np.array_equal(a.median_history, b.median_history)
    assert a.train_mse == b.train_mse and a.test_mse == b.test_mse
    goals = robots.load("planar").sample_goals(50, seed=8)
    assert np.array_equal(a.controller(goals), b.controller(goals))
    assert not np.array_equal(a.history, c.history)
    assert np.all(np.diff(a.history) <= 0)
    assert a.train_mse == pytest.approx(a.history[-1], rel=0, abs=1e-9)


def test_same_seed_same_history_in_another_process():
    code = (
        "import json, lab\n"
        f"runs = {RUN!r}\n"
        "print(json.dumps({m: [float(x) for x in lab.evolve('planar', m, seed=5, **kw).history]"
        " for m, kw in runs.items()}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    other = json.loads(proc.stdout.strip().splitlines()[-1])
    for method, kw in RUN.items():
        here = [float(x) for x in lab.evolve("planar", method, seed=5, **kw).history]
        assert other[method] == here, method


def test_fitness_in_threads_equals_one_thread_bit_for_bit(monkeypatch):
    """Problem.mlp_mse splits a population over `threads` slices; every candidate's MSE is the same
    number whatever slice it lands in, and a run is the same run with LAB_THREADS 1 or 3."""
    arm = robots.load("ur5")
    enc = Encoding.for_arm(arm, "reach", 0.0)
    W = np.random.default_rng(3).normal(0, 0.3, (50, mlp_size(enc.n_inputs, 16, enc.n_outputs)))
    one = Problem(arm, enc, targets=400, threads=1).mlp_mse(W, 16)
    for threads in (2, 3, 4):
        assert np.array_equal(Problem(arm, enc, targets=400, threads=threads).mlp_mse(W, 16), one)
    runs = []
    for threads in ("1", "3"):
        monkeypatch.setenv("LAB_THREADS", threads)
        runs.append(lab.evolve(robot="ur5", generations=30, population=24, seed=4, targets=400))
    assert np.array_equal(runs[0].history, runs[1].history) and runs[0].test_mse == runs[1].test_mse


def test_a_bad_thread_count_is_refused_by_name(monkeypatch):
    from lab.problem.fitness import default_threads

    monkeypatch.setenv("LAB_THREADS", "two")
    with pytest.raises(ValueError, match="LAB_THREADS must be an integer >= 1, got 'two'"):
        default_threads()
    monkeypatch.setenv("LAB_THREADS", "2")
    assert default_threads() == 2
    monkeypatch.delenv("LAB_THREADS")
    assert 1 <= default_threads() <= 4


def test_processes_that_work_beside_others_get_one_fitness_thread():
    from lab.experiments.executors import ONE_THREAD
    from lab.running import pipes

    assert ONE_THREAD["LAB_THREADS"] == "1"
    proc = pipes.start("lab.running.worker")  # it waits for its run on stdin: only its environment is read
    try:
        deadline, env = time.monotonic() + 10, []
        while b"PYTHONPATH" not in b"".join(env) and time.monotonic() < deadline:  # empty until exec is done
            env = open(f"/proc/{proc.pid}/environ", "rb").read().split(b"\0")
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    if "LAB_THREADS" not in os.environ:
        assert b"LAB_THREADS=1" in env


@pytest.mark.parametrize("method", METHODS)
def test_runners_in_threads_equal_sequential_runs(method):
    cfgs = [lab.TrainConfig(method=method, seed=s, **RUN[method]) for s in (0, 1)]
    sequential = [lab.Runner(c).run().history for c in cfgs]
    runners = [lab.Runner(c) for c in cfgs]
    for r in runners:
        r.start()
    concurrent = [r.join(60).history for r in runners]
    for s, c in zip(sequential, concurrent):
        assert np.array_equal(s, c)
    assert not np.array_equal(*sequential)


# ---------------------------------------------------------------- 5. the runner
def long_runner(method="cmaes"):
    return lab.Runner(lab.TrainConfig(method=method, generations=100_000, population=20, targets=20, test_goals=20))



def resume_then_stop(r, g0: int):
    """Resume a paused run, see it pass generation g0 + 3, stop it (within 2 s); its summary."""
    r.resume()
    assert r.state == "running" and wait_for(lambda: r.snapshot().generation > g0 + 3, timeout=2.0)
    t0 = time.monotonic()
    r.stop()
    assert time.monotonic() - t0 < 2.0
    summary = r.join(2.0)
    assert summary is not None and summary.state == "stopped" and r.state == "stopped"
    return summary


def test_pause_resume_stop():
    r = long_runner()
    events = []

    def pause_at_3(e):  # pause between two generations, from the runner's own thread
        events.append(e.index)
        if e.index == 3:
            r.pause()

    r.subscribe(pause_at_3)
    r.start()
    try:
        assert wait_for(lambda: r.state == "paused")
        time.sleep(0.3)
        s = r.snapshot()
        assert s.state == "paused" and s.generation == 4 and events == [0, 1, 2, 3]
        r.resume()
        assert r.state == "running"
        assert wait_for(lambda: r.snapshot().generation > 8, timeout=2.0)
        # paused from another thread: at most the generation in flight completes
        r.pause()
        assert r.state == "paused"
        g0 = r.snapshot().generation
        t = time.monotonic()
        while time.monotonic() - t < 0.4:
            assert r.snapshot().generation <= g0 + 1
            time.sleep(0.01)
        summary = resume_then_stop(r, g0)
    finally:
        r.stop(timeout=5)
    assert r.done
    assert g0 + 3 < summary.generations < 100_000
    assert events == list(range(summary.generations))
    assert len(summary.history) == summary.generations
    assert summary.evaluations == summary.generations * 20
    assert summary.train_mse == pytest.approx(summary.history[-1], rel=0, abs=1e-9)


def test_stop_while_paused_returns_at_once():
    r = long_runner("neat").start()
    assert wait_for(lambda: r.snapshot().generation >= 2)
    r.pause()
    time.sleep(0.05)
    t0 = time.monotonic()
    r.stop()
    assert time.monotonic() - t0 < 2.0
    assert r.join(2.0).state == "stopped"
    with pytest.raises(RuntimeError):
        r.start()


class Recorder:
    def __init__(self):
        self.events, self.ends = [], []

    def __call__(self, event):
        self.events.append(event)

    def on_end(self, summary):
        self.ends.append(summary)


@pytest.mark.parametrize("method", METHODS)
def test_subscribers_get_every_generation_in_order(method, caplog):
    G, P = 15, 12
    cfg = lab.TrainConfig(method=method, generations=G, population=P, targets=25, test_goals=20)
    r = lab.Runner(cfg)
    a, b = Recorder(), Recorder()
    calls = []

    def broken(event):
        calls.append(event.index)
        raise RuntimeError("subscriber bug")

    r.subscribe(a)
    r.subscribe(broken)
    r.subscribe(b)
    with caplog.at_level(logging.CRITICAL, logger="lab.running.runner"):
        summary = r.run()
    assert summary.state == "finished" and summary.generations == G
    assert calls == [0]  # called once, then unsubscribed; the run went on
    for rec in (a, b):
        assert [e.index for e in rec.events] == list(range(G))
        assert rec.ends == [summary]
    best = [e.best for e in a.events]
    assert all(x >= y for x, y in zip(best, best[1:]))
    assert np.array_equal(summary.history, best)
    for i, e in enumerate(a.events):
        assert e is b.events[i]
        # a population method counts its population per generation; the gradient method 1 + nq per step
        # (NEAT-CMA its population and its tuning's evaluations: Method.evaluations_per_step)
        per_step = lab.methods.get(method).evaluations_per_step(r.problem.arm, cfg)
        assert e.evaluations == (e.index + 1) * per_step
        assert r.problem.controller_mse(e.controller) == pytest.approx(e.best, rel=0, abs=1e-9)
        assert e.best <= e.gen_best <= e.median <= e.worst
        assert e.improved == (i == 0 or e.best < a.events[i - 1].best)
        assert e.run_id == summary.run_id
    assert summary.train_mse == pytest.approx(best[-1], rel=0, abs=1e-9)


def test_on_end_once_for_a_stopped_run():
    r = long_runner()
    rec = Recorder()
    unsubscribe_other = r.subscribe(lambda e: None)
    r.subscribe(rec)
    unsubscribe_other()
    r.start()
    assert wait_for(lambda: len(rec.events) >= 2)
    r.stop()
    summary = r.join(2.0)
    assert rec.ends == [summary] and summary.state == "stopped"
    assert [e.index for e in rec.events] == list(range(summary.generations))


def test_snapshot_after_the_run_is_consistent():
    r = lab.Runner(lab.TrainConfig(method="neat", generations=10, population=20, targets=20, test_goals=20))
    summary = r.run()
    s = r.snapshot()
    assert s.state == "finished" and s.generation == 10
    assert s.best == summary.history[-1] == s.history[-1]
    assert r.problem.controller_mse(s.controller) == pytest.approx(s.best, rel=0, abs=1e-9)




@pytest.mark.parametrize("method", METHODS)
def test_snapshot_during_an_improvement_is_consistent(method, monkeypatch):
    """Deterministic: take the snapshot at the instant another thread could, while _offer
    builds the new best controller."""
    r = lab.Runner(lab.TrainConfig(method=method, generations=15, population=10, targets=20, test_goals=20))
    snaps = []
    if lab.methods.get(method).controller == "mlp":  # cmaes, gradient
        import importlib

        mod = importlib.import_module(f"lab.methods.{method}")
        real, name = mod.MLPController, "MLPController"
    else:
        import lab.methods.neat as mod

        real, name = mod.genome_to_controller, "genome_to_controller"

    def spy(*args, **kwargs):
        if threading.current_thread() is r._thread or r.state == "running":
            snaps.append(r.snapshot())
        return real(*args, **kwargs)

    monkeypatch.setattr(mod, name, spy)
    r.run()
    snaps = [s for s in snaps if s.controller is not None]
    assert snaps
    for s in snaps:
        assert r.problem.controller_mse(s.controller) == pytest.approx(s.best, rel=0, abs=1e-9)


def test_snapshot_from_another_thread_while_running():
    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads often, as a busy GUI would
    r = long_runner("neat").start()
    bad = []
    try:
        t = time.monotonic()
        n = 0
        while time.monotonic() - t < 1.5:
            s = r.snapshot()
            if s.controller is None:
                continue
            n += 1
            m = r.problem.controller_mse(s.controller)
            if abs(m - s.best) > 1e-9:
                bad.append((s.generation, s.best, m))
    finally:
        sys.setswitchinterval(old)
        r.stop()
    assert n > 100
    assert not bad, f"{len(bad)} of {n} snapshots: controller MSE != snapshot.best, e.g. {bad[:2]}"


# neat-python 2.0's DefaultReproduction._adjust_spawn_exact gives up when it must remove more than
# one genome (spawn [2, 2, 2, 2, 4] for pop_size 10): NEATBackend re-speciates and retries.
def test_a_small_population_neat_run_finishes(caplog):
    cfg = lab.TrainConfig(method="neat", population=10, generations=200, seed=0, targets=20, test_goals=20)
    with caplog.at_level(logging.CRITICAL, logger="lab.running.runner"):
        summary = lab.Runner(cfg).run()
    assert summary.state == "finished", summary.error
    assert summary.generations == 200


# ---------------------------------------------------------------- 6. a 6-DoF arm learns
def test_ur5_error_falls_and_joints_stay_within_limits():
    run = lab.evolve("ur5", "cmaes", generations=60, seed=0, test_goals=200)
    arm = robots.load("ur5")
    assert run.history[-1] < run.history[0]
    assert np.all(np.diff(run.history) <= 0)
    assert run.train_mse == pytest.approx(run.history[-1], rel=0, abs=1e-9)
    assert np.isfinite(run.test_mse)
    assert run.evaluations == 60 * 50
    goals = np.concatenate([arm.sample_goals(300, seed=1), far_goals(arm, 100, seed=2)])
    q = run.controller(goals)
    assert q.shape == (400, 6)
    assert np.all((q >= arm.lower) & (q <= arm.upper))


# ---------------------------------------------------------------- 7. bad input
@pytest.fixture
def no_work(monkeypatch):
    """Fail if a run, a problem or an arm is built."""
    def boom(*a, **k):
        raise AssertionError("work started before the input was validated")

    monkeypatch.setattr(sys.modules["lab.running.evolve"], "Runner", boom)
    monkeypatch.setattr(sys.modules["lab.running.runner"], "build_problem", boom)
    monkeypatch.setattr(robots, "load", boom)


@pytest.mark.parametrize("field", ["generations", "population", "targets", "test_goals"])
@pytest.mark.parametrize("value", [0, -1, 2.5, True])
@pytest.mark.parametrize("method", METHODS)
def test_bad_counts_are_refused_before_any_work(field, value, method, no_work):
    t = time.monotonic()
    with pytest.raises(ValueError, match=field):
        lab.evolve("planar", method, **{field: value})
    with pytest.raises(ValueError, match=field):
        lab.TrainConfig(method=method, **{field: value})
    assert time.monotonic() - t < 0.5


@pytest.mark.parametrize("field,value,why", [
    ("paper", "no", "paper must be True or False"), ("restarts", "no", "restarts must be True or False"),
    ("margin", -5, "margin must be a number in \\[0, 10\\)"), ("margin", float("nan"), "margin must be"),
    ("goal_seed", 1.5, "goal_seed must be an integer in 0.."), ("sigma0", "x", "sigma0 must be a positive number"),
    ("sigma0", True, "sigma0 must be a positive number"), ("add_node", None, "add_node must be a probability"),
    ("hidden", True, "hidden must be an integer in 1..256"), ("population", 10**9, "population must be an integer in 1..10,000"),
    ("targets", 10**10, "targets must be an integer in 1..1,000,000")])
def test_bad_settings_are_refused_by_field_name(field, value, why, no_work):
    owner = next((m.name for m in lab.methods.all_methods() if field in m.options.names()), "cmaes")
    with pytest.raises(ValueError, match=why):
        lab.TrainConfig(method=owner, **{field: value})


HUGE = 10**400  # float(HUGE) overflows; repr(10**5000) is refused by Python itself (over 4,300 digits)


@pytest.mark.parametrize("field,value,why", [
    ("seconds", HUGE, "seconds must be a positive finite number of seconds .* up to 1,000,000,000, or None, "
                      "got an integer near 10\\*\\*400$"),
    ("seconds", -HUGE, "seconds must be .* got an integer near -10\\*\\*400$"),
    ("seconds", 1e300, "seconds must be .* up to 1,000,000,000"), ("seconds", float("nan"), "seconds must be"),
    ("seconds", "5" * 10_000, "seconds must be .* got '5{59}\\.\\.\\.$"),
    ("generations", 10**5000, "generations must be an integer in 1..1,000,000,000, got an integer near 10\\*\\*5000$"),
    ("population", HUGE, "population must be an integer in 1..10,000"), ("targets", -HUGE, "targets must be an integer in 1.."),
    ("hidden", float("inf"), "hidden must be an integer in 1..256, got inf"), ("heads", HUGE, "heads must be an integer"),
    ("seed", HUGE, "seed must be an integer in 0..9,223,372,036,854,775,807, got an integer near 10\\*\\*400$"),
    ("goal_seed", 2**63, "goal_seed must be an integer in 0..9,223,372,036,854,775,807"),
    ("seed", True, "seed must be an integer"), ("test_goals", "1000", "test_goals must be an integer"),
    ("margin", HUGE, "margin must be a number in \\[0, 10\\), got an integer near"),
    ("sigma0", HUGE, "sigma0 must be a positive number up to 1,000,000, got an integer near"),
    ("mutation_power", HUGE, "mutation_power must be a positive number up to 1,000,000"),
    ("learning_rate", -HUGE, "learning_rate must be a positive number up to 10"),
    ("diagonal", HUGE, "diagonal must be an integer in 0..1,000,000,000"), ("resample", HUGE, "resample must be True or False"),
    ("features", "x" * 10_000, "features must be one of .*, got 'x{59}\\.\\.\\.$"),
    ("method", 10**5000, "unknown method an integer near 10\\*\\*5000; known methods: cmaes"),
    ("robot", 10**5000, "unknown robot an integer near 10\\*\\*5000; known robots: planar")],
    ids=lambda v: v if isinstance(v, str) and len(v) < 20 else type(v).__name__)
def test_out_of_range_arguments_of_evolve_are_one_line_naming_the_argument_and_its_range(field, value, why, no_work):
    """lab.evolve("planar", seconds=10**400) raised a bare OverflowError that did not name seconds;
    a seed of 10**400 was accepted and then named a recording past 255 bytes. Each numeric argument
    is refused by name with the range it accepts, the value shown in short, before any work."""
    owner = next((m.name for m in lab.methods.all_methods() if field in m.options.names()), "cmaes")
    args = {"method": owner, field: value} if field != "method" else {field: value}
    with pytest.raises(ValueError, match=why) as refused:
        lab.evolve(**args)
    assert type(refused.value) is ValueError and "\n" not in str(refused.value) and len(str(refused.value)) < 300
    with pytest.raises(ValueError, match=why):
        lab.TrainConfig.preset(**args)


@pytest.mark.parametrize("argv,why", [
    (["--seconds", "1e400"], "seconds must be .* up to 1,000,000,000, or None, got inf"),
    (["--seconds", "-5"], "seconds must be"), (["--seed", "9" * 30], "seed must be an integer in 0..9,223,372"),
    (["--hidden", "9" * 30], "hidden must be an integer in 1..256"),
    (["--sigma0", "1e400"], "sigma0 must be a positive number up to 1,000,000, got inf")])
def test_out_of_range_arguments_of_lab_train_are_one_line_and_status_2(argv, why, no_work, capsys):
    from lab.__main__ import main

    assert main(["train", "--no-recording", "--quiet", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and __import__("re").search(why, err), err


def test_the_largest_seeds_still_train_and_record(tmp_path):
    """The seed's bound, 2**63 - 1, is a seed numpy, the notebook and a recording's name take."""
    from lab.recording.logger import RerunLogger

    config = lab.TrainConfig(robot="planar", generations=2, population=8, seed=2**63 - 1, goal_seed=2**63 - 1)
    runner = lab.Runner(config)
    logger = RerunLogger(runner, path=tmp_path)
    runner.subscribe(logger)
    summary = runner.run()
    logger.close(wait=True)
    assert summary.state == "finished" and logger.failure() is None and logger.path.stat().st_size > 0
    assert json.loads(json.dumps(config.to_dict()))["seed"] == 2**63 - 1


def test_numpy_integers_are_whole_numbers_and_stored_as_int():
    c = lab.TrainConfig(generations=np.int64(5), seed=np.int64(3), hidden=np.int32(4))
    assert (c.generations, c.seed, c.hidden) == (5, 3, 4) and type(c.generations) is int
    json.dumps(c.to_dict())  # what a recording stores


@pytest.mark.parametrize("paper", [False, True])
def test_unknown_robot_is_refused_before_any_work(paper, no_work):
    with pytest.raises(ValueError, match="robot.*'nope'.*planar"):
        lab.evolve("nope", "cmaes", paper=paper)


def test_unknown_method_is_refused_before_any_work(no_work):
    with pytest.raises(ValueError, match="method.*'ga'.*cmaes"):
        lab.evolve("planar", "ga")
    with pytest.raises(ValueError, match="method"):
        lab.TrainConfig(method="ga")


def test_unknown_method_with_the_paper_preset_is_a_value_error(no_work):
    with pytest.raises(ValueError, match="method"):
        lab.evolve("planar", "ga", paper=True)


def test_population_too_small_for_the_method(no_work):
    with pytest.raises(ValueError, match="population"):
        lab.evolve("planar", "cmaes", population=3)
    with pytest.raises(ValueError, match="population"):
        lab.evolve("planar", "neat", population=1)


# ---------------------------------------------------------------- 8. serialisation
def test_a_malformed_controller_dict_is_a_value_error_naming_the_problem():
    c = MLPController(Encoding.for_arm(robots.load("planar")), 2, np.zeros(mlp_size(2, 2, 3))).to_dict()
    cases = [({}, "its field 'encoding' is missing"), ({**c, "kind": "svm"}, "unknown controller kind 'svm'"),
             ({k: v for k, v in c.items() if k != "weights"}, "its field 'weights' is missing"),
             ({**c, "weights": c["weights"][:-1]}, "MLP with 2 hidden units needs 12 weights, got shape \\(11,\\)"),
             ({**c, "hidden": "five"}, ".*'five'"),
             ([c], "expected a dict, got list"),
             ({**c, "heads": 2}, "MLP with 2 hidden units and 2 heads needs 18 weights, got shape \\(12,\\)"),
             ({**c, "heads": 0}, "heads must be an integer in \\[1, 9\\], got 0")]
    arm = robots.load("so101")
    two = MLPController(Encoding.for_arm(arm), 2, np.zeros(mlp_size(3, 2, 10)), 2, None, arm.chain.arrays).to_dict()
    cases += [({k: v for k, v in two.items() if k != "chain"}, "an MLP with several heads needs the arm's kinematic chain to pick a head"),
              ({**two, "chain": {**two["chain"], "pos": two["chain"]["pos"][:-1]}}, "chain must describe 5 joints"),
              ({**two, "anchors": two["anchors"][:1]}, "anchors must be 2 x 5 finite joint values"),
              ({**two, "weights": two["weights"][:-1]}, "MLP with 2 hidden units and 2 heads needs 28 weights")]
    for d, why in cases:
        with pytest.raises(ValueError, match="not a controller: " + why):
            controller_from_dict(d)


def test_a_graph_or_encoding_the_kernels_cannot_run_is_refused_when_loaded():
    """Keys are checked before a graph reaches the compiled kernel (which does not bounds-check)."""
    enc = Encoding.for_arm(robots.load("planar"), "cartesian")
    nodes = [[0, 0.1, 1.0, [[-1, 0.5], [-2, -0.3]]], [1, 0.0, 1.0, [[0, 0.7]]], [2, 0.0, 1.0, [[-2, 0.2]]]]
    g = {"kind": "graph", "encoding": enc.to_dict(), "nodes": nodes, "input_keys": [-1, -2],
         "output_keys": [0, 1, 2], "genome": {}}
    goals = robots.load("planar").sample_goals(5, seed=0)
    assert controller_from_dict(g)(goals).shape == (5, 3)
    e = enc.to_dict()
    cases = [({**g, "input_keys": [-1, -2, -3]}, "graph: 3 input_keys, but the encoding has 2 distinct inputs"),
             ({**g, "output_keys": [0]}, "graph: 1 output_keys, but the arm has 3 joints"),
             ({**g, "nodes": [[0, 0, 1, [[999, 1.0]]]]}, "graph: node 0 reads key 999, which is not an input or an earlier node"),
             ({**g, "nodes": nodes[1:] + nodes[:1]}, "graph: node 1 reads key 0"),  # not in evaluation order
             ({**g, "encoding": {**e, "in_hi": e["in_lo"]}}, "input ranges .* must be 2 finite \\(lo < hi\\) pairs"),
             ({**g, "encoding": {**e, "q_lo": e["q_hi"], "q_hi": e["q_lo"]}}, "joint ranges must be 3 finite"),
             ({**g, "encoding": {**e, "features": "reach"}}, "reach features need a positive r_max"),
             ({**g, "encoding": {**e, "task_axes": [0, 5]}}, "task_axes must be distinct axes among 0, 1, 2")]
    for d, why in cases:
        with pytest.raises(ValueError, match="not a controller: " + why):
            controller_from_dict(d)


def test_controllers_rebuild_from_dict_with_identical_outputs():
    mlp = lab.evolve("scara", "cmaes", generations=5, population=8, targets=20, seed=1, **SMALL).controller
    cfg = lab.TrainConfig(robot="scara", method="neat", population=20, generations=5, targets=20, **SMALL)
    b = NEATBackend(build_problem(cfg), cfg)
    for _ in range(5):
        b.step()
    genome = structured_genomes(b)[-3]
    graph = genome_to_controller(genome, b.neat_config, b.problem.encoding)
    assert isinstance(mlp, MLPController) and isinstance(graph, GraphController) and graph.n_hidden > 0
    arm = robots.load("scara")
    goals = np.concatenate([arm.sample_goals(100, seed=3), far_goals(arm, 20, seed=4)])
    for c in (mlp, graph):
        d = c.to_dict()
        again = controller_from_dict(json.loads(json.dumps(d)))  # as stored in a recording
        assert type(again) is type(c) and again.kind == c.kind and again.n_params == c.n_params
        assert np.array_equal(again(goals), c(goals))
        assert np.array_equal(again.outputs(goals), c.outputs(goals))
        assert again.to_dict() == d
    with pytest.raises(ValueError, match="kind"):
        controller_from_dict({**mlp.to_dict(), "kind": "svm"})


# ---------------------------------------------------------------- 5b. training in a worker process
def process_runner(method="cmaes", **changes):
    from lab.running.worker import ProcessRunner

    config = dict(method=method, generations=100_000, population=20, targets=20, test_goals=20)
    return ProcessRunner(lab.TrainConfig(**{**config, **changes}))


@pytest.mark.parametrize("method", METHODS)
def test_a_run_in_a_worker_process_is_the_same_run(method):
    """Same seed, same generations, same controllers: only where the optimizer runs differs."""
    cfg = dict(generations=25, population=12)
    here, there = Recorder(), Recorder()
    r = lab.Runner(lab.TrainConfig(method=method, targets=20, test_goals=20, **cfg))
    r.subscribe(here)
    local = r.run()
    p = process_runner(method, **cfg)
    p.subscribe(there)
    remote = p.run()
    assert remote.state == "finished" and p.state == "finished" and there.ends == [remote]
    assert remote.run_id == p.run_id and remote.generations == 25 and remote.evaluations == local.evaluations
    np.testing.assert_array_equal(remote.history, local.history)
    np.testing.assert_array_equal(remote.median_history, local.median_history)
    assert (remote.train_mse, remote.test_mse) == (local.train_mse, local.test_mse)
    for a, b in zip(here.events, there.events, strict=True):
        assert (a.index, a.best, a.median, a.worst, a.evaluations, a.improved) == \
               (b.index, b.best, b.median, b.worst, b.evaluations, b.improved)
        assert b.run_id == p.run_id and a.controller.to_dict() == b.controller.to_dict()
        assert p.problem.controller_mse(b.controller) == pytest.approx(b.best, rel=0, abs=1e-9)
    # a controller crosses the pipe only when it changes: the same objects repeat as in the local run
    same = lambda events: [x.controller is y.controller for x, y in zip(events, events[1:])]  # noqa: E731
    assert same(there.events) == same(here.events)
    s = p.snapshot()
    assert s.generation == 25 and s.best == remote.history[-1]


def test_a_worker_process_pauses_resumes_and_stops():
    r = process_runner("neat").start()
    rec = Recorder()
    r.subscribe(rec)
    try:
        assert wait_for(lambda: r.snapshot().generation >= 5, timeout=30)
        r.pause()
        assert r.state == "paused"
        time.sleep(0.3)  # the generation in flight, and the pipe, drain
        g0 = r.snapshot().generation
        time.sleep(0.4)
        assert r.snapshot().generation == g0
        summary = resume_then_stop(r, g0)
    finally:
        r.stop(timeout=5)
    assert rec.ends == [summary]
    assert summary.generations == r.snapshot().generation and len(summary.history) == summary.generations
    assert [e.index for e in rec.events] == list(range(rec.events[0].index, summary.generations))
    with pytest.raises(RuntimeError):
        r.start()


def test_a_killed_worker_process_fails_the_run_with_its_exit_code():
    import signal

    r = process_runner()
    rec = Recorder()
    r.subscribe(rec)
    r.start()
    assert wait_for(lambda: len(rec.events) >= 3, timeout=30)
    os.kill(r.pid, signal.SIGKILL)
    summary = r.join(10)
    assert summary is not None and summary.state == "failed" and r.state == "failed"
    assert "exited with code -9" in summary.error and rec.ends == [summary]
    assert summary.generations == len(rec.events) and summary.train_mse == pytest.approx(rec.events[-1].best, abs=1e-9)


def test_a_worker_process_ends_with_its_parent(wait_ended):
    """The parent killed outright: its worker stops training and exits (no orphan keeps a core)."""
    script = ("import time, lab\nfrom lab.running.worker import ProcessRunner\n"
              "r = ProcessRunner(lab.TrainConfig(generations=10**6, population=10, targets=10, test_goals=10))\n"
              "r.start()\nwhile r.snapshot().generation < 3: time.sleep(0.01)\n"
              "print(r.pid, flush=True)\ntime.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    worker = int(parent.stdout.readline())
    parent.kill()
    parent.wait()
    wait_ended(worker, timeout=10)


def test_a_prestarted_worker_takes_the_next_run():
    import lab.running.worker

    lab.running.worker.prestart()
    spare = lab.running.worker._spare.pid
    r = process_runner(generations=5).start()
    assert r.pid == spare and r.join(30).state == "finished"


def test_chatter_on_a_workers_stdout_cannot_corrupt_its_messages():
    """print() in a process started by lab.running.pipes.start goes to stderr; the pipe carries only messages."""
    from lab.running import pipes

    script = ("from lab.running import pipes\nfd = pipes.claim_stdout()\nprint('some library talking', flush=True)\n"
              "pipes.send(fd, ('event', [1.5, None]))\nprint('more talk')\n")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    got = [m for batch in pipes.messages(proc.stdout.fileno()) for m in batch]
    assert got == [("event", [1.5, None])]
    assert proc.wait() == 0 and b"some library talking" in proc.stderr.read()


def test_continuous_joints_span_two_turns_and_the_fitness_equals_the_controllers_error():
    """A continuous joint's output maps onto two turns and is turned into its range: the controller's
    q stays within the limits, and the compiled fitness (on the unturned angle) equals the MSE of
    the controller's own q through arm.fk (forward kinematics takes an angle modulo a turn)."""
    arm = robots.load("kinova")
    enc = Encoding.for_arm(arm, "reach", 0.0)
    assert enc.wrap.tolist() == np.asarray(arm.chain.continuous, bool).tolist() and enc.wrap.any()
    assert np.allclose(enc.q_scale[enc.wrap], 2 * np.pi)
    prob = Problem(arm, enc, targets=40, test_goals=10)
    W = np.random.default_rng(3).normal(0, 1.0, (5, mlp_size(enc.n_inputs, 6, enc.n_outputs)))
    fit = prob.mlp_mse(W, 6)
    for w, f in zip(W, fit):
        c = MLPController(enc, 6, w)
        q = c(prob.train_goals)
        assert np.all((q >= arm.lower) & (q <= arm.upper))
        assert f == pytest.approx(prob.controller_mse(c), rel=1e-9, abs=1e-12)
    again = Encoding.from_dict(json.loads(json.dumps(enc.to_dict())))
    assert again.wrap.tolist() == enc.wrap.tolist()


# ---------------------------------------------------------------- environment variables
BAD_ENVIRONMENT = [("LAB_THREADS", "0", "an integer >= 1"), ("LAB_THREADS", "-1", "an integer >= 1"),
                   ("LAB_THREADS", "abc", "an integer >= 1"),
                   ("LAB_METHODS", "no.such.module", "importable modules"),
                   ("LAB_METHODS", "not a module", "module names separated by commas"),
                   ("LAB_RECORDING_RESERVE", "lots", "an integer >= 0")]


def _env_run(args, var, value, cwd, timeout=60):
    env = {k: v for k, v in os.environ.items() if not k.startswith("LAB_")}
    env.update({var: value, "PYTHONPATH": os.pathsep.join(filter(None, [os.path.dirname(os.path.dirname(
        os.path.abspath(lab.__file__))), os.environ.get("PYTHONPATH")]))})
    try:
        return subprocess.run([sys.executable, *args], env=env, cwd=cwd, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{' '.join(args)} with {var}={value} did not stop within {timeout} s (it went on to work)")


@pytest.mark.parametrize("var, value, accepted", BAD_ENVIRONMENT)
def test_a_bad_environment_variable_is_one_line_and_status_2_in_lab_train(tmp_path, var, value, accepted):
    """LAB_THREADS=0/-1/abc, LAB_METHODS naming no module, LAB_RECORDING_RESERVE not bytes: `python -m
    lab train` says so in one line naming the variable, the value and what is accepted, and exits 2
    before any work (it ended in a traceback, status 1)."""
    proc = _env_run(["-m", "lab", "train", "--generations", "2", "--population", "8", "--quiet"], var, value,
                    tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: {var} must be") and proc.stderr.count("\n") == 1, proc.stderr
    assert repr(value) in proc.stderr and accepted in proc.stderr
    assert not (tmp_path / "recordings").exists()  # nothing was started


@pytest.mark.parametrize("args", [["replay", "missing.rrd"], ["reproduce", "--runs", "1", "--generations", "2"],
                                  ["claims", "--runs", "1", "--generations", "2"]])
def test_every_lab_command_refuses_a_bad_environment_variable(tmp_path, args):
    for var, value, _ in (BAD_ENVIRONMENT[2], BAD_ENVIRONMENT[3]):
        proc = _env_run(["-m", "lab", *args], var, value, tmp_path)
        assert proc.returncode == 2 and proc.stderr.startswith(f"error: {var} must be"), proc.stderr
        assert "Traceback" not in proc.stderr
    assert not (tmp_path / "results").exists()


@pytest.mark.parametrize("var, value, accepted", [BAD_ENVIRONMENT[2], BAD_ENVIRONMENT[3], BAD_ENVIRONMENT[5]])
def test_the_app_refuses_a_bad_environment_variable_before_serving(tmp_path, var, value, accepted):
    """`python -m app`: LAB_THREADS=abc started the server (and failed in a thread), LAB_METHODS
    naming no module ended in a traceback; now one line and status 2, and no server."""
    proc = _env_run(["-m", "app", "--port", "0", "--no-record", "--notebook", str(tmp_path / "nb.db")], var, value,
                    tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and "ready" not in proc.stdout
    assert proc.stderr.startswith(f"error: {var} must be") and accepted in proc.stderr, proc.stderr


def test_methods_named_in_lab_methods_are_loaded_when_the_registry_is_first_asked(tmp_path):
    """A module of LAB_METHODS registers its method (and may ask the registry while it is imported)."""
    (tmp_path / "my_methods.py").write_text(
        "from lab import methods\n"
        "from lab.methods import cmaes\n"
        "import dataclasses\n"
        "assert 'cmaes' in methods.names()  # the registry asked while this module is imported\n"
        "methods.register(dataclasses.replace(methods.get('cmaes'), name='mine', label='Mine'))\n")
    proc = _env_run(["-c", "from lab import methods; print(','.join(methods.names()))"], "LAB_METHODS",
                    "my_methods", tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-1].split(",")[-1] == "mine"


@pytest.mark.parametrize("name", ["scara", "planar", "ur5", "so101", "panda"])
def test_the_compiled_polar_inputs_equal_the_numpy_features(name):
    """Encoding.compiled_inputs (the pose networks') computes the reach, sphere and bearings features
    compiled; Encoding.inputs (numpy, the position networks') is their reference: the same inputs
    within rounding, one goal at a time as in a batch."""
    from lab.problem.encoding import _REACH, _SPHERE

    arm = robots.load(name)
    goals = arm.sample_goals(500, seed=31)
    for features in _REACH:
        if features in _SPHERE and len(arm.task_axes) != 3:
            continue
        enc = Encoding.for_arm(arm, features)
        x = enc.compiled_inputs(goals)
        np.testing.assert_allclose(x, enc.inputs(goals), rtol=0, atol=1e-12)
        assert np.array_equal(np.concatenate([enc.compiled_inputs(g[None]) for g in goals[:20]]), x[:20])
