"""`python -m app.classroom.lesson --url URL` prints links only for the lab's http(s) address: a
hostile or broken --url (javascript:, a space, a query, nothing) printed such a link and exited 0."""

import subprocess
import sys
from pathlib import Path

import pytest

from app.classroom.lesson import LESSONS, main, page_url_problem

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("url,why", [
    ("javascript:alert(1)", "is not an http:// or https:// address \\(it begins 'javascript'"),
    ("http://a b/", "holds a space or a control character"), ("http://a\tb/", "holds a space"),
    ("http://teacher-pc:8080/?robot=g1", "has a query"), ("http://teacher-pc:8080/#x", "has a fragment"),
    ("", "is empty"), ("teacher-pc:8080", "is not an http:// or https:// address"),
    ("ftp://teacher-pc/", "is not an http"), ("data:text/html,<script>", "is not an http"),
    ("HTTPS://teacher-pc", "in lower case"), ("http://", "has no host"), ("http:///lab", "has no host"),
    ("http://trusted.example@evil.example/", "has a user name before its host"),
    ("http://teacher-pc:99999", "has a port that is not a number in 1..65535"), ("http://teacher-pc:", "port"),
    ("http://x\"onmouseover=alert(1)", "has a host a link cannot carry"),
    ("http://teacher-pc/a\"><script>", "has a path with characters"), ("http://teacher-pc/é", "has a path")])
def test_a_url_that_is_not_the_labs_http_address_is_one_line_and_status_2(url, why, capsys):
    assert main(["--list", "--url", url]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("error: --url ")
    assert __import__("re").search(why, err), err


@pytest.mark.parametrize("url", ["http://teacher-pc:9000", "http://127.0.0.1:8080/", "https://school.example/lab/",
                                 "http://[::1]:8080", "http://192.168.1.5:8080", "https://lab.school-7.example"])
def test_an_http_address_with_a_host_prints_every_lessons_link(url, capsys):
    assert page_url_problem(url) is None
    assert main(["--url", url]) == 0
    out = capsys.readouterr().out
    assert all(lesson.link(url) in out for lesson in LESSONS.values())


def test_the_module_exits_with_status_2_on_a_hostile_url():
    done = subprocess.run([sys.executable, "-m", "app.classroom.lesson", "--url", "javascript:alert(1)"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == "" and len(done.stderr.strip().splitlines()) == 1


TOKEN = "lesson-Presenter_token1"


def _links(out: str, name: str) -> tuple[str, str]:
    block = out.split(f"{name}: ", 1)[1].split("\n")
    students = next(line.split("students: ", 1)[1] for line in block if "students: " in line)
    presenter = next(line.split("presenter: ", 1)[1] for line in block if "presenter: " in line)
    return students, presenter


def test_a_token_file_gives_each_lesson_a_presenter_link_and_the_students_link_stays_without(tmp_path, capsys):
    """Before, `--url` printed only viewer links; a teacher had to add `token=...;` by hand."""
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    assert main(["--url", "http://teacher-pc:8080", "--presenter-token-file", str(token_file)]) == 0
    out = capsys.readouterr().out
    for lesson in LESSONS.values():
        students, presenter = _links(out, lesson.name)
        assert students == lesson.link("http://teacher-pc:8080") and TOKEN not in students
        assert presenter == lesson.link("http://teacher-pc:8080", TOKEN) and f"token%3D{TOKEN}%3B" in presenter
    assert "keep it to yourself" in out
    # the presenter link the server printed gives the same token
    from app.viser_private import websocket_link

    assert main(["--url", "http://teacher-pc:8080", "--presenter-link",
                 websocket_link("http://teacher-pc:8080", token=TOKEN)]) == 0
    assert _links(capsys.readouterr().out, "class-as-a-search")[1] == LESSONS["class-as-a-search"].link(
        "http://teacher-pc:8080", TOKEN)


@pytest.mark.parametrize("args,why", [(["--presenter-token-file", "/nonexistent/token"], "--presenter-token-file"),
                                      (["--presenter-link", "http://teacher-pc:8080/"], "holds no presenter token")])
def test_a_token_that_cannot_be_read_is_one_line_and_status_2(args, why, capsys):
    assert main(["--url", "http://teacher-pc:8080", *args]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and why in err


def test_a_presenter_link_opens_a_presenter_tab_with_the_lesson_applied_and_a_students_link_a_viewer(tmp_path):
    import urllib.parse

    from conftest import make_app, wait_until
    from app.probe import Probe

    app = make_app(tmp_path, presenter_token=TOKEN, class_workers=1, startup=None)
    tabs = []
    try:
        lesson = LESSONS["fitness-without-targets"]
        for token in (TOKEN, None):
            url = urllib.parse.unquote(lesson.link(app.url, token).split("?websocket=", 1)[1]).replace("ws://", "http://")
            tabs.append(Probe(url).start(60))
            tabs[-1].wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
        owners = [int(t.owner("/tab/goal0/marker")) for t in tabs]
        assert wait_until(lambda: all(o in app.sessions for o in owners), 60)
        presenter, viewer = (app.sessions[o] for o in owners)
        assert presenter.presenter and presenter.my_run is None
        assert not viewer.presenter and viewer.my_run is not None
        # the tab is listed before its lesson is opened (app/server.py): both are waited for
        assert wait_until(lambda: int(app.panel.generations.value) == int(lesson.params["generations"]), 60)
        assert wait_until(lambda: viewer.my_run.lesson == lesson.name, 60)
    finally:
        for t in tabs:
            t.close()
        app.stop()
