"""Presenter and viewer in two real browser tabs (Debian's headless chromium through Playwright):
the tab opened with the presenter link starts a run; the plain tab sees Start disabled and the
line saying the presenter controls the run, and its click changes nothing. APP_SCREENSHOT_DIR=dir
keeps both tabs' screenshots."""

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



def test_two_browser_tabs_a_presenter_and_a_viewer(tmp_path):
    from app.server import LabApp

    app = LabApp(port=0, notebook=str(tmp_path / "notebook.db"), recordings=str(tmp_path / "rec"), record=False,
                 presenter_token="classroom-42")
    app.panel.generations.value = 100_000
    shots = os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            viewer = browser.new_page(viewport={"width": 1400, "height": 1000})
            viewer.goto(app.url)
            sync_api.expect(viewer.get_by_text("The presenter controls the run", exact=False)).to_be_visible(timeout=30_000)
            start = viewer.get_by_role("button", name="Start", exact=True)
            sync_api.expect(start).to_be_disabled(timeout=15_000)
            start.click(force=True)  # even a forced click changes nothing
            viewer.wait_for_timeout(1000)
            assert not app.state.running

            presenter = browser.new_page(viewport={"width": 1400, "height": 1000})
            presenter.goto(app.presenter_url)
            assert "classroom-42" in app.presenter_url
            start_p = presenter.get_by_role("button", name="Start", exact=True)
            sync_api.expect(start_p).to_be_enabled(timeout=30_000)
            assert presenter.get_by_text("The presenter controls the run", exact=False).count() == 0
            start_p.click(force=True)  # enabled (checked above); the panel's layout may still be moving under load
            assert wait_until(lambda: app.state.progress()["generation"] >= 5), "no generation after the presenter's Start"
            # the viewer watches the same run
            sync_api.expect(viewer.get_by_text("Running", exact=False).first).to_be_visible(timeout=10_000)
            # the viewer's panel follows a refresh or two later (under load, seconds): wait as for Start
            sync_api.expect(viewer.get_by_role("button", name="Stop", exact=True)).to_be_disabled(timeout=15_000)
            presenter.wait_for_timeout(1000)
            viewer.screenshot(path=os.path.join(shots, "viewer.png"))
            presenter.screenshot(path=os.path.join(shots, "presenter.png"))
            browser.close()
    finally:
        app.stop()
