"""Training on trees (several end effectors): the fitness is the mean over goals of the summed squared
effector errors, the same through the compiled kernels as through arm.fk; every method trains on a
tree, reproducibly; tree controllers save and load; a serial arm's numbers are unchanged."""

import json

import numpy as np
import pytest

import lab
import robots
from lab.experiments import arms
from lab.problem import Encoding, Problem, encoding_for, encoding_from_dict, kernels
from lab.problem.controllers import MLPController, controller_from_dict, mlp_size
from lab.problem.fitness import tree_arrays
from lab.problem.tree_encoding import TreeEncoding

from conftest import METHODS

TREES = ("talos-legs", "solo12", "allegro", "g1")
FAST = dict(targets=30, test_goals=40)  # a run of a few generations in well under a second each


def reference_mse(arm, q, goals):
    """The tree fitness by numpy: mean over goals of sum over effectors of ||goal_e - fk_e(q)||^2."""
    return float(np.mean(np.sum((arm.fk(q)[..., list(arm.task_axes)] - goals) ** 2, axis=(-2, -1))))


@pytest.mark.parametrize("robot", TREES)
@pytest.mark.parametrize("features", ["cartesian", "sphere"])
def test_the_kernel_fitness_is_the_summed_effector_errors_through_fk(robot, features):
    arm = robots.load(robot)
    enc = encoding_for(arm, features, 0.3)
    assert isinstance(enc, TreeEncoding) and enc.n_outputs == arm.nq
    problem = Problem(arm, enc, targets=25, test_goals=10)
    rng = np.random.default_rng(1)
    W = rng.normal(0, 0.5, (4, mlp_size(enc.n_inputs, 6, enc.n_outputs)))
    f = problem.mlp_mse(W, 6)
    ref = [reference_mse(arm, MLPController(enc, 6, w)(problem.train_goals), problem.train_goals) for w in W]
    np.testing.assert_allclose(f, ref, rtol=1e-9, atol=0)
    A = rng.uniform(-1, 1, (3, len(problem.train_goals), arm.nq))  # outputs_mse: network outputs directly
    ref = [reference_mse(arm, enc.joints(a), problem.train_goals) for a in A]
    np.testing.assert_allclose(problem.outputs_mse(A), ref, rtol=1e-9, atol=0)
    assert problem.controller_mse(MLPController(enc, 6, W[0])) == pytest.approx(f[0], rel=1e-9)


def test_graph_fitness_on_a_tree_is_the_reference():
    """NEAT's compiled graphs go through the tree's graph kernel: the same numbers as arm.fk."""
    run = lab.evolve("solo12", "neat", generations=2, population=6, seed=0, **FAST)
    arm = robots.load("solo12")
    problem = Problem(arm, run.controller.encoding, **FAST)
    goals = problem.train_goals
    assert problem.graphs_mse([run.controller])[0] == pytest.approx(reference_mse(arm, run.controller(goals), goals),
                                                                    rel=1e-9)


@pytest.mark.parametrize("robot", ["planar", "scara", "ur5"])
def test_a_serial_arm_as_a_tree_of_one_effector_gives_the_same_bits(robot):
    """The tree kernel composes each effector's chain by the serial kernel: one effector on every joint
    is the serial arm's fitness bit for bit (and a serial arm's Problem keeps the serial kernels)."""
    arm = robots.load(robot)
    enc = encoding_for(arm, "reach", 0.5)
    problem = Problem(arm, enc, targets=30, test_goals=5)
    XT, goalsT = problem._train
    one = kernels.pack_tree([arm.chain.arrays], [np.arange(arm.nq)], arm.nq)
    W = np.random.default_rng(2).normal(0, 0.7, (5, mlp_size(enc.n_inputs, 5, enc.n_outputs)))
    serial, tree = np.empty(5), np.empty(5)
    kernels.mlp_mse(XT, goalsT, problem._axes, W, 5, problem._qmap, arm.chain.arrays, serial)
    kernels.tree_mlp_mse(XT, goalsT, problem._axes, W, 5, problem._qmap[:4] + (kernels.NO_TURN[None],), one, tree)
    assert np.array_equal(serial, tree)
    assert np.array_equal(problem.mlp_mse(W, 5), serial)
    if robot == "ur5":  # and the turn: a tree's limb is turned by the serial arm's turn, bit for bit
        turned = Problem(arm, encoding_for(arm, "reach", 0.5, turn=True), targets=30, test_goals=5)
        kernels.mlp_mse(XT, goalsT, problem._axes, W, 5, turned._qmap, arm.chain.arrays, serial)
        kernels.tree_mlp_mse(XT, goalsT, problem._axes, W, 5, turned._qmap[:4] + (turned.encoding.turn[None],), one,
                             tree)
        assert np.array_equal(serial, tree)


def test_the_tree_arrays_are_each_effectors_own_chain():
    arm = robots.load("g1")  # the hands share the waist's three joints
    rot, pos, kind, identity, ee_pos, joints, starts = tree_arrays(arm)
    assert len(starts) == arm.n_effectors + 1 and starts[-1] == len(joints) == len(rot)
    for e in range(arm.n_effectors):
        assert np.array_equal(joints[starts[e]:starts[e + 1]], arm.chain.path(e))
        for mine, theirs in zip((rot, pos, kind, identity), arm.chain.effector_arrays(e)[:4]):
            assert np.array_equal(mine[starts[e]:starts[e + 1]], theirs)
    with pytest.raises(ValueError, match=r"effector 0: its path must be joint indices in \[0, 29\)"):
        kernels.pack_tree([arm.chain.effector_arrays(0)], [np.arange(10) + 25], arm.nq)
    with pytest.raises(ValueError, match="chain must describe 3 joints"):
        kernels.pack_tree([arm.chain.effector_arrays(0)], [np.arange(3)], arm.nq)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("robot", ["talos-legs", "solo12"])
def test_every_method_improves_a_tree_and_repeats_its_run(method, robot):
    generations = 40 if method == "gradient" else 8
    runs = [lab.evolve(robot, method, generations=generations, population=12, seed=3, **FAST) for _ in range(2)]
    a, b = runs
    assert a.history[-1] < a.history[0]
    assert np.array_equal(a.history, b.history) and a.test_mse == b.test_mse
    goals = robots.load(robot).sample_goals(5, seed=9)
    assert np.array_equal(a.controller(goals), b.controller(goals))


@pytest.mark.parametrize("method", METHODS)
def test_a_tree_controller_saves_and_loads(method):
    run = lab.evolve("talos-legs", method, generations=3, population=6, seed=1, **FAST)
    doc = json.loads(json.dumps(run.controller.to_dict()))
    assert doc["encoding"]["effectors"] == 2
    back = controller_from_dict(doc)
    assert isinstance(back.encoding, TreeEncoding)
    goals = robots.load("talos-legs").sample_goals(20, seed=4)
    assert np.array_equal(back(goals), run.controller(goals))
    assert back(goals).shape == (20, 12)


def test_goals_of_the_wrong_shape_are_refused_by_name():
    arm = robots.load("solo12")
    run = lab.evolve("solo12", "cmaes", generations=1, population=6, seed=0, **FAST)
    for bad in (np.zeros((5, 3)), np.zeros((5, 2, 3)), np.zeros((5, 4, 2))):
        with pytest.raises(ValueError, match=r"4 end effectors must have shape \(n, 4, 3\)"):
            run.controller(bad)
    assert run.controller(arm.sample_goals(2, seed=0)).shape == (2, arm.nq)


def test_the_tree_encoding_round_trips_and_scales_each_effector_by_its_own_workspace():
    arm = robots.load("allegro")
    enc = encoding_for(arm, "cartesian")
    lo, hi = arm.workspace_bounds
    np.testing.assert_allclose(enc.in_lo, lo.reshape(-1))
    np.testing.assert_allclose(enc.in_hi, hi.reshape(-1))
    for features in ("sphere", "bearings", "polar"):
        enc = encoding_for(arm, features, 0.3)
        back = encoding_from_dict(json.loads(json.dumps(enc.to_dict())))
        goals = arm.sample_goals(50, seed=3)
        assert np.array_equal(back.inputs(goals), enc.inputs(goals))
        assert len(enc.input_names) == enc.n_inputs
        x = enc.inputs(arm.sample_goals(2000, seed=5))
        assert np.all(np.abs(x) <= 1.2)  # about [-1, 1] on other goals too


def test_the_gradient_on_a_tree_is_the_fitness_gradient():
    arm = robots.load("solo12")
    problem = Problem(arm, encoding_for(arm, "sphere", 0.3), targets=20, test_goals=5)
    enc = problem.encoding
    w = np.random.default_rng(4).normal(0, 0.3, mlp_size(enc.n_inputs, 3, enc.n_outputs))
    mse, g = problem.mlp_gradient(w, 3)
    assert mse == pytest.approx(problem.mlp_mse(w[None], 3)[0], rel=1e-12)
    h = 1e-6
    E = np.eye(w.size) * h
    fd = (problem.mlp_mse(w + E, 3) - problem.mlp_mse(w - E, 3)) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=0, atol=1e-6 * np.abs(g).max())


def test_held_out_stats_per_effector_and_refinement_on_a_tree():
    arm = robots.load("talos-legs")
    run = lab.evolve("talos-legs", "cmaes", generations=5, population=8, seed=0, **FAST)
    stats = arms.held_out(arm, run.controller, n=200)
    assert [e["effector"] for e in stats["effectors"]] == list(arm.effectors)
    errors = arms.position_errors(arm, run.controller, arms.held_out_goals(arm, 200))
    for e, row in enumerate(stats["effectors"]):
        assert row["median"] == pytest.approx(1000 * np.median(errors[:, e]))
        assert row["median_pct"] == pytest.approx(100 * np.median(errors[:, e]) / arm.effector_reach[e])
        assert row["median"] <= row["p90"] <= row["p99"]
    assert stats["median"] == pytest.approx(1000 * np.median(errors))
    goals = arms.held_out_goals(arm, 4)
    r = arms.refined(arm, run.controller, goals, steps=2, most=3)
    assert len(r["errors"]) == 4 and 0 <= r["success"] <= 1
    d = arms.dls_from_rest(arm, goals, max_iter=50)
    assert 0 <= d["success"] <= 1


def test_a_tree_run_records_and_reloads(tmp_path):
    from lab.recording.logger import RerunLogger
    from lab.recording.replay import load_controller, read_recording

    config = lab.TrainConfig(robot="solo12", method="cmaes", generations=4, population=8, **FAST)
    runner = lab.Runner(config)
    logger = RerunLogger(runner, path=tmp_path / "tree.rrd", pose_every=1)
    runner.subscribe(logger)
    summary = runner.run()
    logger.wait(60)
    assert summary.state == "finished"
    goals = runner.problem.test_goals[:10]
    assert np.array_equal(load_controller(tmp_path / "tree.rrd")(goals), summary.controller(goals))
    rec = read_recording(tmp_path / "tree.rrd")
    assert rec.population_at(3).points.shape == (8, 4, 3)


@pytest.mark.parametrize("robot", TREES)
def test_a_wired_genome_is_an_mlp_zero_off_its_limbs_with_the_dense_fitness(robot):
    """lab.problem.wiring: the groups share no joint (g1's arms and waist one group, each leg its own);
    the expanded weights are zero off the wiring, each joint hears only its group's effectors' inputs,
    and the groups' shares of the error add up to the dense kernel's fitness of the same weights."""
    from lab.problem.wiring import Wiring, limb_groups

    arm = robots.load(robot)
    groups = limb_groups(arm)
    assert sorted(e for g in groups for e in g) == list(range(arm.n_effectors))
    for a in range(len(groups)):
        for b in range(a + 1, len(groups)):
            ja = {int(j) for e in groups[a] for j in arm.chain.path(e)}
            assert not ja & {int(j) for e in groups[b] for j in arm.chain.path(e)}
    if robot == "g1":
        assert groups == [[0, 1], [2], [3]]
    enc = encoding_for(arm, "reach", 0.3)
    problem = Problem(arm, enc, targets=25, test_goals=10)
    wiring = Wiring.for_arm(arm, enc.n_inputs, 9)
    assert sum(len(u) for u in wiring.units) == 9 and wiring.dim < wiring.size
    rng = np.random.default_rng(2)
    G = rng.normal(0, 0.5, (5, wiring.dim))
    W = wiring.expand(G)
    assert np.all(W[:, ~wiring.mask] == 0) and np.array_equal(wiring.genome(W), G)
    np.testing.assert_allclose(problem.wired_mse(G, wiring).sum(axis=1), problem.mlp_mse(W, 9), rtol=1e-12)
    # the candidates sliced over threads: the same numbers, bit for bit
    many = Problem(arm, enc, targets=400, test_goals=10, threads=1)
    G = rng.normal(0, 0.5, (24, wiring.dim))
    one = many.wired_mse(G, wiring)
    many.threads = 3
    assert np.array_equal(many.wired_mse(G, wiring), one)
    # a goal of one group's effectors moves only that group's joints
    net = MLPController(enc, 9, W[0])
    goals = arm.sample_goals(2, seed=5)
    moved = goals.copy()
    moved[:, groups[-1]] = goals[::-1][:, groups[-1]]
    changed = np.any(net(goals) != net(moved), axis=0)
    assert set(np.flatnonzero(changed)) <= set(wiring.joints[-1].tolist())


def test_wiring_is_refused_where_it_means_nothing():
    from lab.problem.wiring import Wiring

    with pytest.raises(ValueError, match="wiring is for trees"):
        lab.TrainConfig(robot="ur5", method="cmaes", wiring=True)
    with pytest.raises(ValueError, match="wiring is for MLP networks"):
        lab.TrainConfig(robot="g1", method="neat", wiring=True)
    with pytest.raises(ValueError, match="at least one hidden unit for each of its 4 limb groups"):
        lab.TrainConfig(robot="solo12", method="cmaes", hidden=3)
    assert lab.TrainConfig(robot="solo12", method="cmaes").wiring is True  # CMA-ES's tree default
    assert lab.TrainConfig(robot="solo12", method="cmaes").replace(method="neat").wiring is False
    arm = robots.load("solo12")
    with pytest.raises(ValueError, match="at least one hidden unit for each of its 4 limb groups"):
        Wiring.for_arm(arm, 24, 3)
    with pytest.raises(ValueError, match="one equal input block per effector"):
        Wiring.for_arm(arm, 23, 8)


@pytest.mark.parametrize("method", ["cmaes", "gradient"])
def test_a_wired_run_repeats_its_run_keeps_its_zeros_and_its_config_round_trips(method):
    from lab.problem.wiring import Wiring

    kw = dict(generations=40 if method == "gradient" else 8, population=12, seed=3, wiring=True, hidden=8, **FAST)
    a, b = (lab.evolve("g1", method, **kw) for _ in range(2))
    assert a.history[-1] < a.history[0]
    assert np.array_equal(a.history, b.history) and a.test_mse == b.test_mse
    mask = Wiring.for_arm(robots.load("g1"), a.controller.encoding.n_inputs, 8).mask
    assert np.all(a.controller.weights[~mask] == 0) and np.any(a.controller.weights[mask] != 0)
    d = a.config.to_dict()
    assert d["wiring"] is True and lab.TrainConfig.from_dict(d) == a.config
    assert "wiring" not in lab.TrainConfig(robot="g1", method=method, wiring=False).to_dict()
    assert a.train_mse == pytest.approx(float(np.mean(np.sum(
        (robots.load("g1").fk(a.controller(a_goals := robots.load("g1").sample_goals(30, seed=0)))
         - a_goals) ** 2, axis=(-2, -1)))), rel=1e-9)


def test_a_tree_joint_of_more_than_a_turn_is_mapped_over_two_turns_within_its_limits():
    """solo12's joints turn +-10 rad: each is mapped as a continuous joint (two turns about its middle,
    wrapped into its range); the other trees' joints keep the plain mapping."""
    arm = robots.load("solo12")
    enc = encoding_for(arm, "reach", 0.0)
    assert enc.wrap.all() and np.allclose(enc.q_scale, 2 * np.pi)
    a = np.linspace(-1, 1, 7)[:, None] * np.ones(arm.nq)
    q = enc.joints(a)
    assert np.all(np.abs(q) <= np.pi)  # the turn about the middle (0), away from the limits
    raw = enc.q_offset + (a + 1.0) * enc.q_scale  # what the kernels compose: the same poses
    np.testing.assert_allclose(arm.fk(q), arm.fk(raw), atol=1e-12)
    assert not encoding_for(robots.load("g1"), "reach", 0.3).wrap.any()


@pytest.mark.parametrize("robot", TREES)
def test_every_shipped_tree_controller_fits_its_tree_and_has_the_error_its_file_records(robot):
    """app/pretrained/<tree>-cmaes.json (benchmarks/bench_trees.py --write-pretrained): a wired MLP made
    with CMA-ES's tree defaults, whose held-out errors per effector (2,000 goals) are the file's."""
    from app.startup import pretrained_path
    from lab.problem.wiring import Wiring

    with open(pretrained_path(robot, "cmaes"), encoding="utf-8") as f:
        doc = json.load(f)
    arm = robots.load(robot)
    controller = controller_from_dict(doc["controller"])
    config = lab.TrainConfig.from_dict(doc["settings"])
    assert config.robot == robot and config.wiring and isinstance(controller.encoding, TreeEncoding)
    mask = Wiring.for_arm(arm, controller.encoding.n_inputs, controller.hidden).mask
    assert np.all(controller.weights[~mask] == 0)
    again = arms.held_out(arm, controller)
    assert again["median_pct"] == pytest.approx(doc["held_out"]["median_pct"], rel=1e-9)
    for mine, theirs in zip(again["effectors"], doc["held_out"]["effectors"]):
        for key in ("median", "p90", "p99"):
            assert mine[key] == pytest.approx(theirs[key], rel=1e-9), (mine["effector"], key)
