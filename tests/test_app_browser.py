"""The app in a real browser: Debian's headless chromium (software WebGL) driven by Playwright.

Loads the page, finds the training panel, clicks Start, and checks on the server that
generations advance and that the page shows the run. `make test` installs chromium where it
is missing (`make browser`); no browser is downloaded. APP_SCREENSHOT=path.png keeps a
screenshot of the page after the run has started.
"""

from __future__ import annotations

import os
import shutil
import time

import pytest

CHROMIUM = shutil.which("chromium")
pytestmark = [
    pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (`make browser` installs it)"),
    pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection"),
]
sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")


def wait_until(predicate, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return False


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
