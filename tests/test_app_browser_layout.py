"""The app's layout in a real browser (Debian's headless chromium, Playwright): a lesson on a
projector (1366 x 768) and a phone (390 x 844). APP_SCREENSHOT_DIR keeps the screenshots.

- A lesson link: the lesson in its own column at the left, the lab's panel at the right with Start
  in view; the answers folded until opened; the scene between the two.
- A phone: the panel folded to its bar at the bottom, the scene (the arm) in view, the camera drawn
  back to take in the workspace across the narrow page; a tap on the bar opens the panel, with Start.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import CHROMIUM, NEEDS_CHROMIUM, make_app, wait_until

pytestmark = [
    NEEDS_CHROMIUM,
    pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection"),
]
sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")


@pytest.fixture(scope="module")
def lab_app(tmp_path_factory):
    app = make_app(tmp_path_factory.mktemp("layout"), startup=None)
    yield app
    app.stop()


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True)
        yield b
        b.close()


def shot(page, tmp_path, name: str) -> None:
    page.screenshot(path=os.path.join(os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path), f"{name}.png"))


def in_view(box, width: int, height: int) -> bool:
    return box is not None and box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= width \
        and box["y"] + box["height"] <= height


def test_a_lesson_on_a_projector_keeps_start_in_view_and_the_answers_folded(lab_app, browser, tmp_path):
    from app.classroom.lesson import LESSONS, lesson_text

    name = "cmaes-vs-neat"
    title, _text = lesson_text(name)
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    try:
        page.goto(LESSONS[name].link(lab_app.url))
        start = page.get_by_role("button", name="Start", exact=True)
        sync_api.expect(start).to_be_visible(timeout=30_000)
        heading = page.get_by_text(title, exact=True)
        sync_api.expect(heading).to_be_visible(timeout=15_000)
        assert wait_until(lambda: lab_app.panel.race.enabled.value, 10)  # the lesson's state is set
        page.wait_for_timeout(1000)  # the columns settle
        shot(page, tmp_path, "lesson-1366x768")
        start_box, lesson_box = start.bounding_box(), heading.bounding_box()
        assert in_view(start_box, 1366, 768), start_box  # the lab's controls in view, the lesson open beside them
        assert in_view(lesson_box, 1366, 768) and lesson_box["x"] + lesson_box["width"] < start_box["x"]
        # the goal, what to set and the questions are there; the answers are folded until opened
        for text in ("What to set", "Questions for students"):
            assert page.get_by_text(text, exact=True).count() == 1
        sync_api.expect(page.get_by_text("What to set", exact=True)).to_be_visible()
        answers = page.get_by_text("What the class should see", exact=True)
        assert answers.count() == 0 or not answers.first.is_visible()
        assert page.get_by_text("Open the lesson", exact=False).count() == 0  # no link to itself
        page.get_by_text("Answers: what the class should see", exact=False).click()
        sync_api.expect(page.get_by_text("What the class should see", exact=True)).to_be_visible(timeout=10_000)
        # the scene between the two: the middle of the page is the canvas, not a panel
        middle = page.evaluate("document.elementFromPoint(683, 400).tagName")
        assert middle == "CANVAS", middle
    finally:
        page.close()


def test_a_phone_shows_the_arm_with_the_panel_folded_to_a_bar_that_opens(lab_app, browser, tmp_path):
    page = browser.new_page(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
    try:
        page.goto(lab_app.url)
        bar = page.get_by_text("Neuro-IK Lab", exact=True)
        sync_api.expect(bar).to_be_visible(timeout=30_000)
        assert wait_until(lambda: len(lab_app.sessions) >= 1, 30)
        start = page.get_by_role("button", name="Start", exact=True)
        sync_api.expect(start).to_have_count(0, timeout=15_000)  # folded: the panel's contents are gone
        page.wait_for_timeout(1000)
        shot(page, tmp_path, "phone-390x844-folded")
        box = bar.bounding_box()
        assert box["y"] > 844 - 80, box  # a bar at the bottom
        # held upright, the page sees less across: the camera is drawn back from the arm's framing
        session = max(lab_app.sessions.values(), key=lambda t: t.client.client_id)
        framed = np.linalg.norm(np.asarray(session.ws["camera"]) - session.ws["center"])
        assert wait_until(lambda: np.linalg.norm(np.asarray(session.client.camera.position) - session.ws["center"])
                          > 1.5 * framed, 10)
        # the scene is uncovered: the canvas at the middle and near the bottom of the page
        for x, y in ((195, 300), (195, 422), (60, 700)):
            assert page.evaluate(f"document.elementFromPoint({x}, {y}).tagName") == "CANVAS", (x, y)
        bar.tap()
        sync_api.expect(start).to_be_visible(timeout=10_000)
        page.wait_for_timeout(500)  # the sheet's height settles
        shot(page, tmp_path, "phone-390x844-open")
        # the opened sheet stops short of the arm, which the camera frames above it (app/tab/phone.py)
        from app.tab.phone import SHEET

        sheet_top = bar.bounding_box()["y"]
        assert sheet_top >= (1 - SHEET) * 844 - 2, sheet_top
        cam = session.client.camera
        x, y = _pixel(cam, session.ws["center"], 390, 844)
        assert 0 < x < 390 and 0 < y < sheet_top - 40, (x, y, sheet_top)  # the arm's base well above the sheet
        assert page.evaluate(f"document.elementFromPoint({x}, {y}).tagName") == "CANVAS", (x, y)
    finally:
        page.close()


def _pixel(camera, point, width: int, height: int) -> tuple[int, int]:
    """Where a world point is drawn on a page of this size, through a tab's camera."""
    position, look_at = np.asarray(camera.position), np.asarray(camera.look_at)
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    right = np.cross(forward, camera.up_direction)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel, t = np.asarray(point) - position, np.tan(0.5 * camera.fov)
    depth = rel @ forward
    nx, ny = (rel @ right) / (depth * t * width / height), (rel @ up) / (depth * t)
    return int((nx + 1) / 2 * width), int((1 - ny) / 2 * height)


def test_a_wide_page_keeps_its_panel_open_and_its_camera(lab_app, browser):
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    try:
        page.goto(lab_app.url)
        sync_api.expect(page.get_by_role("button", name="Start", exact=True)).to_be_visible(timeout=30_000)
        page.wait_for_timeout(1000)
        sync_api.expect(page.get_by_role("button", name="Start", exact=True)).to_be_visible()
        session = max(lab_app.sessions.values(), key=lambda t: t.client.client_id)
        assert np.allclose(session.client.camera.position, session.ws["camera"], atol=1e-3 * session.ws["size"])
    finally:
        page.close()
