"""What a presenter reads in the scene and the panel says what it measures, in the arm's units.

Checked: every length the app prints carries its unit (the paper's arms: "units"; metres as mm or µm);
the error map's legend in the scene and in the Views tab give the same yellow threshold in those units;
the About text of each robot gives the number of training goals and hidden units of the run its
panel would start, and the red goals drawn are that run's; a tree opens standing at rest on a floor at
its soles; goal labels run to the left of their markers, away from the panel; viser's page is served
with the lab's head (no viser tool panel while a tab connects).
"""

from __future__ import annotations

import socket
import urllib.request

import numpy as np
import pytest
import viser

import lab
import robots
from app import viser_private
from app.panels.views import MAP_SCALE, map_grid, map_key, map_legend, map_scale, yellow_words
from app.tab.goals import READY_ID, about, fmt_len
from app.tab.scene import body_bounds, frame_workspace
from conftest import NEEDS_CHROMIUM, session_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")


def test_every_length_the_app_prints_carries_its_unit():
    planar, ur5 = robots.load("planar"), robots.load("ur5")
    assert fmt_len(planar, 0.002) == "0.002 units" and fmt_len(planar, 4.6724) == "4.672 units"
    assert fmt_len(planar, 2e-5).endswith(" units")
    assert fmt_len(ur5, 0.0123) == "12.3 mm" and fmt_len(ur5, 2e-5) == "20 µm"


@pytest.mark.parametrize("robot", ["planar", "scara", "planar-10", "ur5", "so100"])
def test_the_error_maps_legends_give_the_same_yellow_in_the_arms_units(robot):
    arm = robots.load(robot)
    fmt = lambda d: fmt_len(arm, d)  # noqa: E731
    scale = map_scale(arm)
    assert scale == pytest.approx(MAP_SCALE * (arm.workspace_bounds[1] - arm.workspace_bounds[0]).max())
    key = map_key(arm, fmt)
    unit = "mm" if robots.in_metres(robot) else "units"
    top = " ".join(key.top[1].split())  # its lines as one
    assert f"≥ {fmt(scale)} (10 % of the workspace)" in top and fmt(scale).endswith(unit) and top.startswith("error map")
    assert "dark purple = on the goal" == key.bottom[1]
    text = map_legend(arm, np.array([0.0, 0.5 * scale, np.nan]), fmt)
    assert yellow_words(arm, fmt) in text and f"{fmt(scale)} or more" in text
    if robots.in_metres(robot):  # a real arm's also in % of its reach
        assert f"{100 * scale / arm.reach_radius:.0f} % of its reach" in text
    # the bar stands beside the reachable cells, to their left (away from the panel), its colours from
    # dark purple (the first row, drawn at -y) to yellow; each label starts at the bar's left edge and runs
    # to the right (a page whose scene begins near the bar: a lesson's column, a phone), the top one above
    # the bar's top end, the bottom one below its bottom end, in short lines
    grid = map_grid(arm)
    assert key.center[0] + 0.5 * key.width < grid.origin[0] + grid.cell * grid.cells[:, 0].min()
    assert key.top[0][0] == key.bottom[0][0] == pytest.approx(key.center[0] - 0.5 * key.width)
    assert key.top[0][1] == pytest.approx(key.center[1] + 0.5 * key.height) and key.top[2] == "bottom-left"
    assert key.bottom[0][1] == pytest.approx(key.center[1] - 0.5 * key.height) and key.bottom[2] == "top-left"
    assert max(len(line) for line in key.top[1].splitlines() + key.bottom[1].splitlines()) <= 36
    assert key.image[0].sum() < key.image[-1].sum()


@pytest.mark.parametrize("robot", robots.names())
def test_about_says_the_training_goals_and_network_of_the_run_the_panel_would_start(robot):
    arm = robots.load(robot)
    d = lab.TrainConfig.preset(robot=robot)
    text = about(arm, d)
    assert f"over {d.targets:,} fixed goals" in text and f"({d.hidden} hidden units)" in text
    assert f"{arm.nq} joint angles" in text and "never shown a right answer" in text
    assert ("Lengths in mm." if robots.in_metres(robot) else "Lengths in the paper's units.") in text
    if arm.is_tree:
        assert f"{arm.n_effectors} end effectors" in text
    assert {"planar": 70, "ur5": 300, "g1": 600}.get(robot, d.targets) == d.targets  # the figures the docs quote


@pytest.mark.parametrize("method", lab.methods.names())
def test_about_names_where_a_growing_network_starts_and_the_runs_own_goals(method):
    arm = robots.load("ur5")
    d = lab.TrainConfig.preset(robot="ur5", method=method)
    text = about(arm, d)
    assert f"over {d.targets:,} fixed goals" in text
    if lab.methods.get(method).controller == "mlp":
        assert f"({d.hidden} hidden units)" in text and "grows" not in text
    else:  # NEAT's kind: no fixed size to quote, where it starts
        assert f"{lab.methods.get(method).label} grows (from {d.hidden} hidden units)" in text


def test_the_tab_shows_each_robots_about_and_its_runs_goals_and_the_scene_its_map_key(app, tab):
    session = session_of(app, tab)
    for robot in ("planar", "ur5", "planar"):
        assert app.switch_robot(robot) is None
        assert wait_until(lambda: session.arm.name == robot, 20)
        arm, d = session.arm, lab.TrainConfig.preset(robot=robot)
        # the tab writes About after it takes the arm (its scene built between): on a busy machine later
        assert wait_until(lambda: session.about.content == about(arm, d), 20), session.about.content
        assert len(app.training_goals()) == d.targets  # the red points: the goals that run trains on
        assert READY_ID in session.intro.content
    # a run of another method on other goals: About says that run's goals, the red points' number
    config = lab.TrainConfig.preset(robot=robot, method=lab.methods.names()[-1], targets=25, generations=3,
                                    population=6, seed=0)
    assert app.state.start(config) is None
    assert wait_until(lambda: session.about.content == about(session.arm, config), 30)
    assert "over 25 fixed goals" in session.about.content and len(app.training_goals()) == 25
    assert wait_until(lambda: app.state.runner.state == "finished", 60)
    # the map's key in the scene, shown with the map: its label's text is the legend's
    arm = app.state.arm
    top = map_key(arm, lambda v: fmt_len(arm, v)).top[1]
    assert wait_until(lambda: any(m["type"] == "LabelMessage" and m["name"] == f"{app._map_key.name}/top"
                                  and m["props"]["text"] == top for _t, m in list(tab.messages)))
    app.show_map.value = True
    assert wait_until(lambda: app._map_key.visible and app._map.visible)
    app.show_map.value = False
    assert wait_until(lambda: not app._map_key.visible and not app._map.visible)
    # the goal's label: the network's error with its unit, up and to the left of the marker
    g = session.goals[0]
    assert wait_until(lambda: g.label.text.startswith("net ") and g.label.text.endswith(" units"))
    assert session.ws["label_offset"][0] < 0


@pytest.mark.parametrize("robot", ["g1", "talos-legs", "solo12"])
def test_a_legged_tree_opens_standing_at_rest_on_a_floor_at_its_soles(robot):
    arm = robots.load(robot)
    ws = frame_workspace(arm)
    lo, _hi = body_bounds(arm)
    assert ws["floor_z"] == pytest.approx(lo[2])  # the lowest point of its body at rest: its soles
    feet = [k for k, name in enumerate(arm.effectors) if "hand" not in name]
    rest = arm.fk(arm.rest)
    # the feet at rest are on the floor (ankle or sole frames, within 6 cm of it), above it
    assert np.all(rest[feet, 2] >= ws["floor_z"] - 1e-9) and np.all(rest[feet, 2] - ws["floor_z"] < 0.06)
    from lab.running.decimation import display_goal

    np.testing.assert_allclose(display_goal(arm), arm.reach(arm.rest))  # the first goal: standing at rest


def test_viser_serves_its_page_with_the_labs_head_and_nothing_else_changed():
    head = "<style>/* lab-head-test */</style>"
    viser_private.install_page_head(head)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.get_port()}/", timeout=30) as r:
            page = r.read().decode("utf-8")
    finally:
        server.stop()
        from app.server import PAGE_HEAD

        viser_private.install_page_head(PAGE_HEAD)  # the app's, for the servers created after this test
    from pathlib import Path

    original = (Path(viser.__file__).parent / "client" / "build" / "index.html").read_text(encoding="utf-8")
    assert page.startswith(original[:original.index("<head>") + 6] + head)
    assert page.replace(head, "", 1) == original


def test_the_apps_page_waits_for_the_tabs_marker():
    from app.server import PAGE_HEAD

    assert f"getElementById('{READY_ID}')" in PAGE_HEAD and "#root{visibility:hidden}" in PAGE_HEAD


def in_view(page, box) -> bool:
    size = page.viewport_size
    return box is not None and box["y"] >= 0 and box["y"] + box["height"] <= size["height"] and \
        box["x"] >= 0 and box["x"] + box["width"] <= size["width"]


@NEEDS_CHROMIUM
def test_browser_no_viser_tool_panel_and_the_whole_plot_in_view_during_a_run(tmp_path):
    """1366 x 768 in a real browser: a tab whose websocket never reaches the server shows no viser tool
    panel; the lab's tab, during a run, has Pause, Stop and the whole convergence plot (its axis and
    key) in view; the g1's About says its 600 goals (APP_SCREENSHOT_DIR keeps the screenshots: the scene's
    labels are drawn in WebGL, not in the page, so that they stand clear of the panel is seen there)."""
    import os

    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    from app.__main__ import WATCHING_SPEED
    from conftest import CHROMIUM, make_app

    shots = os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path)
    app = make_app(tmp_path, speed=WATCHING_SPEED)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            page = browser.new_page(viewport={"width": 1366, "height": 768})
            # the app's page, its websocket sent to a port where nothing answers (viser's ?websocket=): it
            # stays as a tab is before the lab's panel arrives
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                nowhere = s.getsockname()[1]
            page.goto(f"{app.url}/?websocket=ws://127.0.0.1:{nowhere}")
            tools = page.get_by_text("Save Canvas")
            tools.wait_for(state="attached", timeout=30_000)  # viser's tool panel is on the page ...
            page.wait_for_timeout(1000)
            assert page.get_by_text("Inactive").count() + page.get_by_text("Connecting").count() >= 1
            for text in ("Save Canvas", "Reset View", "Inactive", "Connecting"):  # ... and hidden
                assert not any(e.is_visible() for e in page.get_by_text(text).all()), text
            page.screenshot(path=os.path.join(shots, "connecting.png"))
            page.close()

            page = browser.new_page(viewport={"width": 1366, "height": 768})
            page.goto(app.url)
            button = lambda name: page.get_by_role("button", name=name, exact=True)  # noqa: E731
            sync_api.expect(button("Start")).to_be_visible(timeout=30_000)
            assert not page.get_by_text("Save Canvas").is_visible()
            assert wait_until(lambda: len(app.sessions) == 1)
            session = next(iter(app.sessions.values()))
            button("Reset").click()
            assert wait_until(lambda: app.state.shown.source.startswith("untrained"))
            button("Start").click()
            assert wait_until(lambda: app.state.progress()["generation"] >= 40, timeout=60)
            panel = page.locator("[data-testid=floating-panel]").bounding_box()
            plot = page.locator(".uplot").first
            sync_api.expect(plot).to_be_visible()
            for what in (button("Pause"), button("Stop"), plot):
                assert in_view(page, what.bounding_box()), f"{what} is not in view at 1366 x 768 during a run"
            page.wait_for_timeout(1000)
            page.screenshot(path=os.path.join(shots, "legends-planar-run.png"))  # before the check: it shows a failure
            assert plot.bounding_box()["y"] + plot.bounding_box()["height"] <= panel["y"] + panel["height"]
            button("Stop").click()
            assert wait_until(lambda: not app.state.running, 20)
            assert app.switch_robot("g1") is None
            assert wait_until(lambda: session.arm.name == "g1" and session.goals
                              and session.goals[0].label.text.startswith("net "), 60)
            sync_api.expect(page.get_by_text("600 fixed goals", exact=False)).to_be_visible(timeout=20_000)
            page.wait_for_timeout(3000)  # the meshes (software WebGL)
            page.screenshot(path=os.path.join(shots, "legends-g1.png"))
            browser.close()
    finally:
        app.stop()
