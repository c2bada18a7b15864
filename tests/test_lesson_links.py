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
