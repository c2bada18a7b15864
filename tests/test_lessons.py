"""docs/lessons/: every shipped lesson has its page with the sections a class needs, its page carries
the link that opens it (built by lesson_link for the default address), and the index lists them all.
That each link opens its state and its text in a tab: tests/test_app_teaching.py."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from app.classroom.lesson import LESSONS, LESSONS_DIR, lesson_names, lesson_text, lesson_views, main

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ("## Open the lesson", "## What to set", "## What to watch", "## Questions for students",
            "## What the class should see", "## Figures")


def test_the_app_reads_the_lessons_of_this_tree():
    assert LESSONS_DIR == ROOT / "docs" / "lessons"
    assert len(LESSONS) >= 4 and sorted(LESSONS) == lesson_names()


@pytest.mark.parametrize("name", sorted(LESSONS))
def test_each_lesson_page_has_its_sections_link_and_measured_figures(name):
    text = (LESSONS_DIR / f"{name}.md").read_text()
    where = [text.find(s) for s in SECTIONS]
    assert all(w >= 0 for w in where) and where == sorted(where), f"{name}: sections missing or out of order"
    assert LESSONS[name].link() in text and LESSONS[name].link().startswith("http://127.0.0.1:8080/?websocket=")
    figures = text[text.index("## Figures"):]
    assert re.search(r"^\|.*\d", figures, re.M), f"{name}: no table of measured figures"
    assert "```python" in figures and "lab.evolve(" in figures, f"{name}: no snippet that produced the figures"
    assert re.search(r"Measured 20\d\d-\d\d-\d\d", figures), f"{name}: figures without their date"
    questions = text[text.index("## Questions for students"):text.index("## What the class should see")]
    assert len(re.findall(r"^\d+\. ", questions, re.M)) >= 3
    title, body = lesson_text(name)
    assert text.startswith(f"# {title}\n") and "## Open the lesson" in body
    assert lesson_views(LESSONS[name].params) is not None


def test_the_index_lists_every_lesson_with_its_link():
    index = (LESSONS_DIR / "index.md").read_text()
    for name, lesson in LESSONS.items():
        assert f"]({name}.md)" in index and lesson.link() in index


def test_unknown_names_and_views_are_refused_by_name():
    with pytest.raises(ValueError, match="no lesson named 'nope'.*fitness-without-targets"):
        lesson_text("nope")
    with pytest.raises(ValueError, match="no lesson named 'index'"):
        lesson_text("index")
    with pytest.raises(ValueError, match="no lesson named '../index'"):
        lesson_text("../index")
    with pytest.raises(ValueError, match="unknown view 'xray'"):
        lesson_views({"views": "ik.xray"})
    assert lesson_views({"views": "none"}) == dict.fromkeys(("ik", "population", "faint", "species", "map"), False)


def test_the_command_line_prints_each_lessons_link_for_a_host(capsys):
    main(["--list", "--url", "http://teacher-pc:9000"])
    out = capsys.readouterr().out
    for name, lesson in LESSONS.items():
        assert f"{name}: {lesson_text(name)[0]}" in out and lesson.link("http://teacher-pc:9000") in out
    assert "127.0.0.1" not in out


@pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
def test_a_viewer_gets_the_lessons_text_and_views_but_not_its_settings(tmp_path):
    from urllib.parse import unquote

    from app.classroom.lesson import lesson_params
    from app.probe import Probe
    from conftest import make_app, wait_until

    app = make_app(tmp_path, presenter_token="t0ken", startup=None)  # tabs without the token are viewers
    try:
        before = lesson_params(app.panel)
        lesson = LESSONS["real-arm-and-snake"]
        viewer = Probe(unquote(lesson.link(app.url).split("?websocket=", 1)[1]).replace("ws://", "http://")).start()
        try:
            viewer.wait_for(lambda m: m["type"] == "GuiPanelMessage")  # the lesson's column
            viewer.wait_for(lambda m: m["type"] == "GuiMarkdownMessage"
                            and m["props"]["_markdown"] == f"### {lesson_text(lesson.name)[0]}")
            viewer.wait_for(lambda m: m["type"] == "NotificationShowMessage" and "presenter controls" in str(m))
            assert wait_until(lambda: any(s.faint_arms.value for s in app.sessions.values()), 5)  # its own views
            time.sleep(0.3)
            assert lesson_params(app.panel) == before and app.state.arm.name == "planar"
        finally:
            viewer.close()
    finally:
        app.stop()


def test_the_panel_shows_headings_smaller_and_code_as_written():
    from app.classroom.lesson import panel_headings

    text = "## What to set\ntext\n```python\n# a comment, not a heading\n```\n### More\n"
    assert panel_headings(text) == "#### What to set\ntext\n```python\n# a comment, not a heading\n```\n##### More\n"


@pytest.mark.parametrize("name", sorted(LESSONS))
def test_the_panel_shows_the_questions_open_and_the_answers_folded_without_a_self_link(name):
    """What a tab's lesson column shows open (the goal, what to set, what to watch, the questions) and
    what it folds (what the class should see, the figures, the code); no link to the lesson itself,
    nor relative links that would point into the lab's server."""
    from app.classroom.lesson import lesson_sections, panel_parts

    _title, body = lesson_text(name)
    sections = dict(lesson_sections(body))
    shown, answers = panel_parts(body)
    for part in ("", "What to set", "What to watch", "Questions for students"):
        assert sections[part].splitlines()[0] in shown and sections[part].splitlines()[-1] in shown
    for part in ("What the class should see", "Figures"):
        assert f"## {part}" not in shown and f"#### {part}" in answers
    assert "```" not in shown and "```python" in answers and "lab.evolve(" in answers
    assert "Open the lesson" not in shown + answers and "?websocket=" not in shown + answers
    assert "](" not in (shown + answers).replace("](http", "")  # links to other pages are their paths
