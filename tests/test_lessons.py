"""docs/lessons/: every shipped lesson has its page with the sections a class needs, its page carries
the link that opens it (built by lesson_link for the default address), and the index lists them all.
That each link opens its state and its text in a tab: tests/test_app_teaching.py."""

from __future__ import annotations

import os
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
            # told, not as a failure, that the shared run is the presenter's and the lesson's run is its own to start
            told = viewer.wait_for(lambda m: m["type"] == "NotificationShowMessage" and "presenter runs it" in str(m))
            assert told["props"]["color"] == "green" and "Start my run" in str(told)
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


class _Enough(Exception):
    """The snippet has printed the rows the test compares."""


def figures_of(name: str) -> tuple[list[str], str]:
    """(the data rows of the table under a lesson's ## Figures, its python snippet)."""
    text = (LESSONS_DIR / f"{name}.md").read_text()
    figures = text[text.index("## Figures"):]
    table = [line for line in figures.splitlines() if line.startswith("|")]
    assert table[0].rstrip(" |").endswith("seconds"), f"{name}: the table's last column is not its seconds"
    return table[2:], re.search(r"```python\n(.*?)```", figures, re.S).group(1)


def cells(row: str) -> list[str]:
    """A table row's cells but its last (the seconds, which differ from machine to machine)."""
    return [c.strip() for c in row.strip().strip("|").split("|")][:-1]


@pytest.mark.parametrize("name", sorted(LESSONS))
def test_the_figures_a_lesson_quotes_are_the_ones_its_snippet_prints(name, monkeypatch):
    """Each lesson's snippet prints the rows of its table of figures: run as a student would copy it, its
    first row is the table's first row, digit for digit (the seconds aside). LESSON_FIGURES=all
    compares every row (minutes: what re-measuring a lesson's figures takes)."""
    monkeypatch.setenv("LAB_THREADS", "1")  # as the figures were measured (the fitness is the same bit for bit)
    table, code = figures_of(name)
    wanted = len(table) if os.environ.get("LESSON_FIGURES") == "all" else 1
    printed: list[str] = []

    def capture(*args, **_kw) -> None:
        line = " ".join(map(str, args))
        if line.startswith("|"):
            printed.append(line)
            if len(printed) == wanted:
                raise _Enough

    try:
        exec(compile(code, f"docs/lessons/{name}.md", "exec"), {"print": capture, "__name__": "lesson"})
    except _Enough:
        pass
    assert len(printed) == wanted, f"{name}: the snippet printed {len(printed)} rows of {wanted}"
    for got, quoted in zip(printed, table):
        assert cells(got) == cells(quoted), f"{name}: the snippet prints\n{got}\nthe lesson quotes\n{quoted}"


def test_lesson_one_reads_the_error_map_as_its_legend_does():
    """Lesson 1 says what yellow means on the error map in the legend's own words and units."""
    import robots
    from robots.ik import workspace_size

    from app.panels.views import error_map
    from app.tab.goals import fmt_len

    arm = robots.load("planar")
    _image, _err, scale = error_map(arm, None)
    text = " ".join((LESSONS_DIR / "fitness-without-targets.md").read_text().split())
    assert f"yellow where it misses by {fmt_len(arm, scale)} or more" in text
    assert f"({100 * scale / workspace_size(arm):.0f} % of the workspace's width" in text
