"""A class in a real browser (Debian's headless chromium, Playwright) at 1366 x 768: a student's lesson
link opens *My experiment* with its part in view, **Start my run** answers in view; the presenter's
**Show the chart large** draws the chart across most of the page, its type large, the lab's panel folded
beside it until it closes. APP_SCREENSHOT_DIR
keeps the screenshots."""

from __future__ import annotations

import os
import random
import re

import pytest
from conftest import CHROMIUM, NEEDS_CHROMIUM, make_app, wait_until
from test_class_board import HandRunner

import lab

pytestmark = [NEEDS_CHROMIUM, pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")]
sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
TOKEN = "browser-class-token-1"


def shot(page, tmp_path, name: str) -> None:
    page.screenshot(path=os.path.join(os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path), f"{name}.png"))


def in_view(box, width: int = 1366, height: int = 768) -> bool:
    return box is not None and box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= width \
        and box["y"] + box["height"] <= height


def test_a_students_lesson_and_the_presenters_large_chart_at_1366x768(tmp_path):
    from app.classroom.lesson import LESSONS

    app = make_app(tmp_path, presenter_token=TOKEN, class_workers=1, startup=None)
    lesson = LESSONS["class-as-a-search"]
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
            student = browser.new_page(viewport={"width": 1366, "height": 768})
            student.goto(lesson.link(app.url))
            part = student.get_by_test_id("floating-panel").get_by_text("Your part of the class's search", exact=False)
            sync_api.expect(part).to_be_visible(timeout=120_000)  # the folder opened, its first line
            start = student.get_by_role("button", name="Start my run")
            start.scroll_into_view_if_needed(timeout=120_000)
            start.click(timeout=120_000)
            panel = student.get_by_test_id("floating-panel")
            status = panel.get_by_text("Running", exact=False).or_(panel.get_by_text("Queued", exact=False))
            sync_api.expect(status.first).to_be_visible(timeout=120_000)
            shot(student, tmp_path, "class-student-started-1366x768")
            assert in_view(status.first.bounding_box()) and in_view(start.bounding_box())
            # a class's finished runs, ended by hand (no process): 12 of the lesson, 2 of other settings
            app.class_runs.make_runner = HandRunner
            rng = random.Random(1)
            for k in range(14):
                hidden = (2, 3, 4, 5, 6, 8, 12, 16, 32, 64)[k % 10]
                generations = 300 if k < 12 else 3000
                app.class_runs.submit(1000 + k, lab.TrainConfig(robot="planar", generations=generations, population=50,
                                                                hidden=hidden, seed=k // 10), lesson=lesson.name)

            def finish_all() -> bool:
                for r in app.class_runs.rows():
                    if not r.ended and isinstance(r.runner, HandRunner):
                        r.runner.finish(rng.uniform(0.05, 50.0))
                return sum(r.state == "finished" and isinstance(r.runner, HandRunner) for r in app.class_runs.rows()) == 14

            assert wait_until(finish_all, 300)
            presenter = browser.new_page(viewport={"width": 1366, "height": 768})
            presenter.goto(lesson.link(app.url, TOKEN))
            sync_api.expect(presenter.get_by_role("button", name="Start", exact=True)).to_be_visible(timeout=120_000)
            presenter.get_by_test_id("floating-panel").get_by_text("Class", exact=True).click(timeout=120_000)
            presenter.get_by_role("button", name="Show the chart large").click(timeout=120_000)
            # the 12 lesson runs ended by hand, and the student's own when it has ended (the same settings)
            title = presenter.get_by_text(re.compile(r"^Held-out MSE against hidden units: 1[23] finished runs$"))
            sync_api.expect(title).to_be_visible(timeout=120_000)
            presenter.wait_for_timeout(1000)
            shot(presenter, tmp_path, "class-chart-large-1366x768")
            chart = presenter.locator('svg[viewBox="0 0 1200 600"]')
            box = chart.bounding_box()
            assert box["width"] >= 800 and in_view(box), box  # most of the page's width, all of it in view
            assert float(title.evaluate("e => parseFloat(getComputedStyle(e).fontSize)")) >= 24
            assert chart.locator("circle title").count() in (12, 13)  # each point's student, on hover
            assert presenter.get_by_text("2 finished runs left out", exact=False).count() >= 1
            # the lab's panel folded to its rail under the chart (docked beside the lesson's column, it
            # was under the chart's right third), and back when the chart closes
            show = presenter.get_by_role("button", name="Show the chart large")
            sync_api.expect(show).to_be_hidden(timeout=30_000)
            presenter.get_by_role("button", name="Close the chart").click(timeout=30_000)
            sync_api.expect(show).to_be_visible(timeout=30_000)
            browser.close()
    finally:
        app.stop()
