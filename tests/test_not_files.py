"""Files that are not files (issue #55): a token file, a notebook, an upload's folder or a recording to
open that is a device, a named pipe, a folder (or, for a token file, larger than a token needs) is
refused at once, naming the path and what it is; nothing blocks (a pipe with no writer did, for good)
and nothing is read without end (/dev/zero as a token file: 5.7 GB, then a MemoryError)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from types import SimpleNamespace

import pytest

from app.classroom.access import read_token_file
from app.classroom.files import FileRefused, read_small
from app.classroom.uploads import not_a_recording_file, save_upload
from app.training.notebook import Notebook, NotebookError

TOKEN = "files-Token_0123456789"


def promptly(fn, *args, timeout: float = 30.0):
    """fn(*args) in a thread: its result, or the exception it raised; a call still blocked after
    `timeout` s fails the test (it would otherwise hang it)."""
    out = {}

    def call():
        try:
            out["value"] = fn(*args)
        except BaseException as e:  # noqa: BLE001 - handed back to the test
            out["error"] = e

    t = threading.Thread(target=call, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), f"{fn.__name__}{args} blocked"
    return out.get("error", out.get("value"))


@pytest.fixture
def odd(tmp_path):
    """Paths that are not files: kind -> (path, what the message calls it)."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    folder = tmp_path / "folder"
    folder.mkdir()
    return {"device": ("/dev/zero", "a character device"), "fifo": (str(fifo), "a named pipe (FIFO)"),
            "folder": (str(folder), "a folder")}


def test_a_token_file_that_is_not_a_file_or_too_large_is_refused_by_name_without_reading_it(tmp_path, odd):
    for path, what in odd.values():
        e = promptly(read_token_file, path)
        assert isinstance(e, ValueError) and str(e) == f"{path} is {what}, not a file (a token file holds one line)"
    big = tmp_path / "big"
    big.write_text(TOKEN + "\n" + "x" * 5000)
    e = promptly(read_token_file, str(big))
    assert str(e) == f"{big} is 4.9 KiB; at most 4.0 KiB are read from it (a token file holds one line)"
    good = tmp_path / "token"
    good.write_text(f"  {TOKEN}  \nsecond line\n")
    assert read_token_file(str(good)) == TOKEN
    assert str(promptly(read_token_file, str(tmp_path / "none"))) == f"{tmp_path / 'none'}: No such file or directory"
    assert isinstance(promptly(read_small, "/dev/zero", 10), FileRefused)


def test_a_notebook_that_is_not_a_file_is_refused_by_name_at_once(odd):
    for kind, (path, what) in odd.items():
        e = promptly(Notebook, path)
        assert isinstance(e, NotebookError), (kind, e)
        if kind == "folder":
            assert str(e) == f"notebook {path} is a folder; give the path of a file"
        else:
            assert str(e).startswith(f"notebook {path} is {what}, not a file; it was left as it is")


def test_an_uploads_folder_or_a_recording_that_is_not_a_file_is_refused(tmp_path):
    from app.panels.runs import RunsPanel

    fifo = tmp_path / "stuck.rrd"
    os.mkfifo(fifo)
    assert not_a_recording_file(str(fifo)) == "stuck.rrd is a named pipe (FIFO), not a file"  # no server path
    said = promptly(RunsPanel.open_file, SimpleNamespace(refuse=lambda _client, text: text), str(fifo))
    assert said == "refused: stuck.rrd is a named pipe (FIFO), not a file"
    folder = tmp_path / "uploads"
    os.mkfifo(folder)
    e = promptly(save_upload, str(folder), "run.rrd", b"RRF2")
    assert isinstance(e, OSError) and e.strerror == "the server's upload folder is a named pipe (FIFO), not a folder"
    assert str(tmp_path) not in str(e)


def app_refuses(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", "--port", "0", "--no-record", *args], capture_output=True,
                          text=True, timeout=180)


@pytest.mark.parametrize("kind", ["device", "fifo", "folder", "large"])
def test_python_m_app_refuses_a_token_file_that_is_not_a_file_in_one_line(tmp_path, odd, kind):
    if kind == "large":
        path = tmp_path / "large"
        path.write_text(TOKEN + "\n" + "x" * 10_000)
        what = "is 9.8 KiB; at most 4.0 KiB are read from it"
    else:
        path, what = odd[kind]
        what = f"is {what}, not a file"
    done = app_refuses("--notebook", str(tmp_path / "nb.db"), "--presenter-token-file", str(path))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == f"error: --presenter-token-file {path} {what} (a token file holds one line)\n"
    assert not os.path.exists(tmp_path / "nb.db")  # refused before anything was opened


@pytest.mark.parametrize("kind", ["device", "fifo", "folder"])
def test_python_m_app_refuses_a_notebook_that_is_not_a_file_in_one_line(odd, kind):
    path, what = odd[kind]
    done = app_refuses("--notebook", path)
    assert done.returncode == 2 and done.stdout == "", done.stderr
    line = (f"error: notebook {path} is a folder; give the path of a file\n" if kind == "folder" else
            f"error: notebook {path} is {what}, not a file; it was left as it is: move it away or give another path\n")
    assert done.stderr == line
