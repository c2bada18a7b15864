"""The Class board and the lesson links as each tab gets them, with headless tabs (app/probe.py) on a
server restricted by a presenter token: a phone's tab (a canvas 390 x 844) gets its own table of the
columns a phone holds (name, state, held-out MSE) and a style hiding the wide table, a desktop tab
only the wide one, a phone turned wide loses it, a closed phone tab leaves no entry; a presenter's
Share this lesson holds the students' link and, labelled not to be shared, its own presenter link
with the token; a viewer's tab is never sent the token."""

from __future__ import annotations

import os
import re
import shutil
import urllib.parse

import pytest
from viser import _messages

import lab
from app.probe import Probe
from conftest import make_app, tab_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
TOKEN = "s3cret-Token_phone"


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    lab_app = make_app(tmp_path_factory.mktemp("phone-board"), presenter_token=TOKEN, startup=None)
    yield lab_app
    lab_app.stop()


def phone_tab(url, width=390, height=844):
    probe = Probe(url, width, height).start(60)
    probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
    return probe


def contents(probe, marker: str) -> list[tuple[str, str]]:
    """(uuid, html) of each GUI element whose html (as created or updated) holds `marker`."""
    out = []
    for _t, m in list(probe.messages):
        text = m.get("props", {}).get("content") if m["type"] == "GuiHtmlMessage" else \
            (m.get("updates", {}).get("content") if m["type"] == "GuiUpdateMessage" else None)
        if isinstance(text, str) and marker in text:
            out.append((m["uuid"], text))
    return out


def headers(table: str) -> list[str]:
    return re.findall(r"<th>([^<]*)</th>", table)


def session_of(app, probe):
    owner = int(probe.owner("/tab/goal0/marker"))
    assert wait_until(lambda: owner in app.sessions, 60)
    return app.sessions[owner]


def test_a_phone_tab_gets_the_boards_three_columns_and_a_desktop_tab_the_whole_table(app):
    phone, desk = phone_tab(app.url), tab_of(app.url)
    try:
        assert wait_until(lambda: contents(phone, "lab-board-narrow"), 30)
        uuid, narrow = contents(phone, "lab-board-narrow")[-1]
        assert "No student run yet" in narrow  # no run yet: the board says so, in the phone's own element
        assert "<style>.lab-board-wide{display:none}</style>" in narrow  # the wide table hidden in this tab
        # a run: the phone's table has the three columns, its row the same three cells
        assert app.class_runs.set_name(10_000, "Ana") is None
        assert app.class_runs.submit(10_000, lab.TrainConfig(robot="planar", generations=5, population=10)) is None
        assert wait_until(lambda: any("<b>Ana</b>" in t for _u, t in contents(phone, "lab-board-narrow")), 60)
        row = [t for u, t in contents(phone, "lab-board-narrow") if "<b>Ana</b>" in t][-1]
        assert headers(row) == ["name", "state", "held-out MSE"]
        cells = re.search(r"<tr><td><b>Ana</b></td>(.*?)</tr>", row).group(1)
        assert cells.count("<td>") == 2
        assert {u for u, _t in contents(phone, "lab-board-narrow")} == {uuid}  # one element, updated
        assert wait_until(lambda: any("<b>Ana</b>" in t for _u, t in contents(desk, "lab-board-wide")), 60)
        wide = [t for _u, t in contents(desk, "lab-board-wide") if "<b>Ana</b>" in t][-1]
        assert len(headers(wide)) == 7  # the desktop's: every column
        assert not contents(desk, "lab-board-narrow") and not contents(desk, "display:none}</style>")
        # turned wide (landscape): the narrow table goes, the wide one shows again
        phone.send(_messages.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -3.0, 2.0), fov=1.0, near=0.01, far=1000.0,
            image_height=390, image_width=844, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0)))
        assert wait_until(lambda: any(m["type"] == "GuiRemoveMessage" and m["uuid"] == uuid
                                      for _t, m in list(phone.messages)), 30)
        assert not app.board._phones
    finally:
        app.class_runs.stop_tab(10_000, "test over")
        desk.close()
        phone.close()


def test_a_closed_phone_tab_leaves_no_narrow_table_entry(app):
    phone = phone_tab(app.url)
    assert wait_until(lambda: len(app.board._phones) == 1, 30)
    phone.close()
    assert wait_until(lambda: not app.board._phones, 30)


def test_a_presenters_phone_is_told_the_large_chart_is_for_a_wide_screen(app):
    """A phone's bottom sheet folds a panel into a closed section: there, Show the chart large showed
    nothing. It says why in the board's folder instead."""
    phone = phone_tab(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    try:
        client = session_of(app, phone).client
        assert wait_until(lambda: client.client_id in app.board._phones, 30)
        why = app.board.show_big(client)
        assert why.startswith("refused: the large chart is for a wide screen")
        assert app.board.board_message.content == why and client.client_id not in app.board._big
    finally:
        phone.close()


def test_the_presenters_share_this_lesson_holds_its_own_link_with_the_token_and_a_viewer_never_sees_it(app):
    presenter = tab_of(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]))
    viewer = tab_of(app.url)
    try:
        mine = session_of(app, presenter)
        assert wait_until(lambda: "do not share" in mine.lesson.content, 30)
        text = mine.lesson.content
        students, own = text.split("do not share", 1)
        assert "For the students" in students and "Open this lesson" in students
        assert TOKEN not in students  # the students' link carries no token
        assert "For you (presenter)" in text and f"token={TOKEN};" in urllib.parse.unquote(own)
        links = [urllib.parse.unquote(u) for u in re.findall(r"\]\(([^)]+)\)", text)]
        assert len(links) == 2 and TOKEN not in links[0] and TOKEN in links[1]
        assert links[1].replace(f"token={TOKEN};", "") == links[0]  # the same lesson, the token in front
        theirs = session_of(app, viewer)
        assert wait_until(lambda: "Open this lesson" in theirs.lesson.content, 30)
        assert "For you (presenter)" not in theirs.lesson.content and TOKEN not in theirs.lesson.content
        assert not any(TOKEN in repr(m) for _t, m in list(viewer.messages))  # nothing sent to it holds it
    finally:
        viewer.close()
        presenter.close()


@pytest.mark.skipif(shutil.which("chromium") is None, reason="Debian's chromium is not installed (`make browser`)")
def test_in_a_real_browser_a_phone_shows_the_three_columns_unwrapped_and_a_laptop_the_whole_table(tmp_path):
    """Chromium at 390 x 844 (a phone) and 1366 x 768: the phone's Class tab shows the narrow table
    (3 columns, each row on a line or two, within the page's width), not the wide one; the laptop's
    the wide one. APP_SCREENSHOT_DIR keeps the screenshots."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    app = make_app(tmp_path, startup=None)
    try:
        for tab, name in ((10_001, "Ana on a phone"), (10_002, "Bartholomew")):
            assert app.class_runs.set_name(tab, name) is None
            assert app.class_runs.submit(tab, lab.TrainConfig(robot="planar", generations=5, population=10)) is None
        folder = os.environ.get("APP_SCREENSHOT_DIR") or str(tmp_path)
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=shutil.which("chromium"), headless=True)
            try:
                page = browser.new_page(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
                page.goto(app.url)
                bar = page.get_by_text("Neuro-IK Lab", exact=True)
                sync_api.expect(bar).to_be_visible(timeout=30_000)
                page.wait_for_timeout(1000)  # folded on load
                bar.tap()
                page.get_by_text("Class", exact=True).first.tap()
                narrow = page.locator(".lab-board-narrow table")
                sync_api.expect(narrow).to_be_visible(timeout=15_000)
                narrow.scroll_into_view_if_needed()  # the sheet scrolls: the board below its tabs
                page.wait_for_timeout(500)
                page.screenshot(path=os.path.join(folder, "class-board-phone-390x844.png"))
                assert narrow.locator("th").all_inner_texts() == ["name", "state", "held-out MSE"]
                assert not page.locator(".lab-board-wide").first.is_visible()
                box = narrow.bounding_box()
                assert box["x"] >= 0 and box["x"] + box["width"] <= 390, box
                heights = [r.bounding_box()["height"] for r in narrow.locator("tr").all()[1:]]
                assert heights and max(heights) < 3 * 17, heights  # a row on a line or two, not 5-6
                page.close()
                page = browser.new_page(viewport={"width": 1366, "height": 768})
                page.goto(app.url)
                page.get_by_text("Class", exact=True).first.click(timeout=30_000)
                wide = page.locator(".lab-board-wide table")
                sync_api.expect(wide).to_be_visible(timeout=15_000)
                page.screenshot(path=os.path.join(folder, "class-board-1366x768.png"))
                assert len(wide.locator("th").all_inner_texts()) == 7 and page.locator(".lab-board-narrow").count() == 0
                page.close()
            finally:
                browser.close()
    finally:
        for tab in (10_001, 10_002):
            app.class_runs.stop_tab(tab, "test over")
        app.stop()
