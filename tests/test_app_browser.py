"""The app in a real browser: Debian's headless chromium (software WebGL) driven by Playwright.

Loads the page, finds the training panel, clicks Start, and checks on the server that
generations advance and that the page shows the run. `make test` installs chromium where it
is missing (`make browser`); no browser is downloaded. APP_SCREENSHOT=path.png keeps a
screenshot of the page after the run has started.
"""

from __future__ import annotations

import os
import time

import pytest
from conftest import CHROMIUM, NEEDS_CHROMIUM, wait_until

pytestmark = [
    NEEDS_CHROMIUM,
    pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection"),
]
sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")



def test_browser_finds_the_training_panel_and_starts_a_run(tmp_path):
    from app.server import LabApp

    app = LabApp(port=0, notebook=str(tmp_path / "notebook.json"), recordings=str(tmp_path / "rec"), record=False)
    app.panel.generations.value = 100_000  # long enough to watch it advance
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.goto(app.url)
            sync_api.expect(page.get_by_role("tab", name="Train")).to_be_visible(timeout=30_000)
            start = page.get_by_role("button", name="Start")
            sync_api.expect(start).to_be_visible()
            assert wait_until(lambda: len(app.sessions) == 1)  # the page is a tab with its own goals
            assert app.state.progress()["generation"] == 0
            start.click()
            assert wait_until(lambda: app.state.progress()["generation"] >= 5), "no generation after Start"
            first = app.state.progress()["generation"]
            assert wait_until(lambda: app.state.progress()["generation"] > first + 5)
            # the page shows the run: the status line and the generation count move
            sync_api.expect(page.get_by_text("Running", exact=False).first).to_be_visible(timeout=10_000)
            page.wait_for_timeout(1500)
            shot = os.environ.get("APP_SCREENSHOT") or str(tmp_path / "app.png")
            page.screenshot(path=shot)
            assert os.path.getsize(shot) > 10_000
            browser.close()
    finally:
        app.stop()


def settled(count, quiet=0.6, timeout=15.0) -> int:
    """count() once it has not changed for `quiet` seconds."""
    last, since, t0 = count(), time.monotonic(), time.monotonic()
    while time.monotonic() - since < quiet and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
        if count() != last:
            last, since = count(), time.monotonic()
    return last


def test_browser_steps_one_generation_sets_the_speed_and_races_two_runs(tmp_path):
    """The app for a class in a real browser: one click on Step = one generation more on the server; the Speed
    menu caps the rate; a race draws two curves (APP_SCREENSHOT_DIR keeps the screenshots)."""
    from app.server import LabApp

    shots = os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path)
    app = LabApp(port=0, notebook=str(tmp_path / "notebook.db"), recordings=str(tmp_path / "rec"), record=False)
    app.panel.generations.value = 100_000
    generations = lambda: app.state.progress()["generation"]  # noqa: E731
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            page = browser.new_page(viewport={"width": 1400, "height": 1400})
            page.goto(app.url)
            button = lambda name: page.get_by_role("button", name=name, exact=True)  # noqa: E731
            sync_api.expect(button("Start")).to_be_visible(timeout=30_000)
            assert wait_until(lambda: len(app.sessions) == 1)
            button("Start").click()
            assert wait_until(lambda: generations() >= 10), "no generation after Start"
            button("Pause").click()
            assert wait_until(lambda: app.state.runner.state == "paused")
            runner = app.state.runner
            assert wait_until(lambda: runner.holding is not None)  # the worker holds; every event is in
            held = runner.holding
            assert generations() == held
            button("Step").click()
            assert wait_until(lambda: runner.holding == held + 1)
            assert settled(generations) == held + 1, "one click on Step is one generation"
            button("Step").click()
            assert wait_until(lambda: runner.holding == held + 2)
            assert settled(generations) == held + 2
            page.screenshot(path=os.path.join(shots, "step.png"))
            # the speed menu: 5 generations a second
            page.get_by_label("Speed").click()
            page.get_by_role("option", name="5 generations/s").click()
            assert wait_until(lambda: app.state.speed == 5.0, 10)
            button("Resume").click()
            assert wait_until(lambda: generations() >= held + 4)
            g0, t0 = generations(), time.monotonic()
            time.sleep(2.0)
            rate = (generations() - g0) / (time.monotonic() - t0)
            assert 3.0 <= rate <= 5.6, rate
            button("Stop").click()
            assert wait_until(lambda: app.state.runner.state == "stopped")
            # a race: CMA-ES against NEAT, two curves on one plot
            page.get_by_label("Speed").click()
            page.get_by_role("option", name="unlimited").click()
            page.get_by_text("Race", exact=True).click()
            page.get_by_label("Race a second run").check()
            page.get_by_label("Partner method").click()
            page.get_by_role("option", name="NEAT", exact=True).click()
            assert wait_until(lambda: app.panel.race.enabled.value and app.panel.race.method.value == "NEAT", 10)
            button("Start").click()
            assert wait_until(lambda: app.state.partner is not None and len(app.state.partner.track) >= 20
                              and generations() >= 20, 60)
            sync_api.expect(page.get_by_text("best MSE, partner").first).to_be_visible(timeout=10_000)
            sync_api.expect(page.get_by_text("leads", exact=False).first).to_be_visible(timeout=10_000)
            page.wait_for_timeout(1500)
            page.screenshot(path=os.path.join(shots, "race.png"))
            page.get_by_text("best MSE, partner").first.scroll_into_view_if_needed()
            page.wait_for_timeout(2500)  # uPlot redraws after the scroll (software WebGL, a loaded box)
            page.screenshot(path=os.path.join(shots, "race-curves.png"))
            button("Stop").click()
            assert wait_until(lambda: app.state.partner.runner.state == "stopped")
            browser.close()
    finally:
        app.stop()


def in_view(page, locator) -> bool:
    """The element is on screen without scrolling: its box lies within the viewport."""
    box = locator.bounding_box()
    size = page.viewport_size
    return box is not None and box["y"] >= 0 and box["y"] + box["height"] <= size["height"] and \
        box["x"] >= 0 and box["x"] + box["width"] <= size["width"]


def test_a_first_visit_on_a_projector_sees_what_the_lab_is_and_an_untrained_network_learn(tmp_path):
    """1366 x 768, as a classroom projector shows it, with the app's own defaults (`python -m app`):
    the title, the about text, the drag hint, the run controls, the speed, the generation counter and
    the convergence plot are all in view without scrolling; Reset shows an untrained network visibly
    off the goal, Start trains it toward the goal (APP_SCREENSHOT_DIR keeps the screenshots)."""
    from app.__main__ import WATCHING_SPEED
    from app.server import LabApp

    shots = os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path)
    app = LabApp(port=0, notebook=str(tmp_path / "notebook.db"), recordings=str(tmp_path / "rec"), record=False,
                 speed=WATCHING_SPEED)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            page = browser.new_page(viewport={"width": 1366, "height": 768})
            page.goto(app.url)
            sync_api.expect(page.get_by_role("tab", name="Train")).to_be_visible(timeout=30_000)
            assert wait_until(lambda: len(app.sessions) == 1)
            session = next(iter(app.sessions.values()))
            title = page.get_by_text("Neuro-IK Lab", exact=True).first
            about = page.get_by_text("never shown a right answer", exact=False).first
            hint = page.get_by_text("Drag the arrows", exact=False).first
            for what in (title, about, hint, page.get_by_role("button", name="Start", exact=True),
                         page.get_by_role("button", name="Reset", exact=True),
                         page.get_by_role("button", name="Trained network"),
                         page.get_by_text("Speed", exact=True).first, page.get_by_text("generation 0", exact=False).first,
                         page.get_by_text("Convergence", exact=False).first):
                sync_api.expect(what).to_be_visible(timeout=10_000)
                assert in_view(page, what), f"{what} is below the fold at 1366 x 768"
            page.screenshot(path=os.path.join(shots, "first-visit.png"))
            trained_error = session.goals[0].error
            page.get_by_role("button", name="Reset", exact=True).click()
            assert wait_until(lambda: app.state.shown.source.startswith("untrained"))
            assert wait_until(lambda: session.version == app.state.shown.version)
            off = session.goals[0].error
            assert off > 0.05 * app.state.arm.reach_radius and off > 20 * trained_error  # visibly off the goal
            page.wait_for_timeout(800)
            page.screenshot(path=os.path.join(shots, "first-visit-reset.png"))
            page.get_by_role("button", name="Start", exact=True).click()
            assert wait_until(lambda: app.state.progress()["generation"] >= 60, timeout=20)
            # the speed a class can follow: about 20 generations a second, not the machine's pace
            assert app.state.progress()["generation"] < 200
            # the controls of a running run, and the plot, stay in view
            for name in ("Pause", "Stop", "Reset"):
                button = page.get_by_role("button", name=name, exact=True)
                sync_api.expect(button).to_be_visible(timeout=5_000)
                assert in_view(page, button)
            assert wait_until(lambda: session.version == app.state.shown.version and session.goals[0].error < off)
            page.wait_for_timeout(800)
            page.screenshot(path=os.path.join(shots, "first-visit-learning.png"))
            browser.close()
    finally:
        app.stop()
