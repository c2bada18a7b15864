"""The app's teaching views and replay: DLS IK, the error map, the network drawing, recordings."""

from __future__ import annotations

import numpy as np
import pytest

import lab
import robots
from app.panels.views import error_map, map_grid, network_svg
from lab.problem.controllers import network_layout
from robots.ik import dls_ik, workspace_size


@pytest.mark.parametrize("name", ["planar", "scara", "ur5", "kinova"])
def test_dls_ik_reaches_reachable_goals_within_the_limits(name):
    arm = robots.load(name)
    goals = arm.sample_goals(12, seed=3)
    results = [dls_ik(arm, g) for g in goals]
    for g, r in zip(goals, results):
        assert np.all(r.q >= arm.lower - 1e-12) and np.all(r.q <= arm.upper + 1e-12)
        assert r.error == pytest.approx(np.linalg.norm(arm.reach(r.q) - g), abs=1e-9)  # the error it reports
    assert np.mean([r.converged for r in results]) >= 0.9
    assert all(r.error < 1e-4 * workspace_size(arm) for r in results if r.converged)


def test_dls_ik_on_an_unreachable_goal_stops_at_the_closest_pose():
    arm = robots.load("planar")
    r = dls_ik(arm, np.array([60.0, 0.0]))
    reach = 8.625 + 8.625 + 6.125
    assert not r.converged and r.error == pytest.approx(60.0 - reach, abs=0.05)  # stretched toward it


@pytest.fixture(scope="module")
def neat_run():
    return lab.evolve("planar", "neat", generations=15, population=30, seed=1, add_node=0.3, add_connection=0.3)


def test_error_map_colours_the_controllers_error_on_reachable_cells(neat_run):
    arm, controller = robots.load("planar"), neat_run.controller
    grid = map_grid(arm)
    image, err, scale = error_map(arm, controller)
    assert image.shape == (grid.n, grid.n, 4)
    assert (image[..., 3] > 0).sum() == len(grid.goals)  # one opaque pixel per reachable cell
    assert np.allclose(err, np.linalg.norm(arm.reach(controller(grid.goals)) - grid.goals, axis=1))
    # reachable cells hold end-effector positions: their centres are within a cell of the workspace
    assert np.all(np.linalg.norm(grid.goals, axis=1) <= 8.625 * 2 + 6.125 + grid.cell)
    worst, best = np.argmax(err), np.argmin(err)
    j, i = grid.cells[worst][1], grid.cells[worst][0]
    jb, ib = grid.cells[best][1], grid.cells[best][0]
    assert image[j, i, :3].astype(int).sum() > image[jb, ib, :3].astype(int).sum()  # yellow vs purple


def test_error_map_of_a_3d_arm_is_a_slice():
    arm = robots.load("ur5")
    grid = map_grid(arm)
    lo, hi = arm.workspace_bounds
    assert grid.goals.shape[1] == 3 and np.allclose(grid.goals[:, 2], 0.5 * (lo[2] + hi[2]))


def test_network_drawing_shows_enabled_connections_only(neat_run):
    c = neat_run.controller
    nodes, links = network_layout(c)
    enabled = [x for x in c.genome["connections"] if x[3]]
    assert len(links) == len(enabled)
    assert {n.key for n in nodes} >= set(c.input_keys) | set(c.output_keys)
    assert network_svg(c).count("<line") == len(enabled)
    mlp = lab.evolve("planar", "cmaes", generations=3, population=8, seed=0).controller
    assert network_svg(mlp).count("<line") == mlp.w_i[:-1].size + mlp.w_o.size  # bias row not drawn


def test_the_app_and_recordings_label_a_network_alike(neat_run):
    """One layout (lab.problem.controllers.network_layout) for the app's drawing and Rerun's graph:
    the same labels, inputs named by the encoding and joints q1 .. qn."""
    import rerun as rr  # noqa: F401

    from lab.recording.views import network

    c = neat_run.controller
    nodes, _links = network_layout(c)
    graph, _edges = network(c)
    labels = [str(x) for x in graph.labels.as_arrow_array().to_pylist()]
    assert labels == [n.label for n in nodes]
    assert [n.label for n in nodes if n.kind == "output"] == [f"q{k + 1}" for k in range(len(c.output_keys))]
    svg = network_svg(c)
    assert all(f">{n.label}<" in svg for n in nodes if n.label)


def test_the_private_viser_api_the_app_relies_on_is_still_there():
    """app/viser_private.py holds every reach into viser's internals; if viser changes one, this
    fails and names it (the app would fall back to slower public setters, silently)."""
    import viser

    from app import viser_private

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        frame = server.scene.add_frame("/probe", show_axes=False)
        assert viser_private.check(frame) == [], f"viser {viser.__version__} changed: {viser_private.check(frame)}"
        viser_private.set_pose(frame, np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0, 0.0]))
        assert np.allclose(frame.position, [1, 2, 3]) and np.allclose(frame.wxyz, [0, 1, 0, 0])
    finally:
        server.stop()
