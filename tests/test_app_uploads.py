"""Uploads, tried as a hostile tab would (headless clients speaking viser's upload protocol):
refused before viser buffers a byte when too large, dropped when the parts outgrow the declared
size or stall, limited per tab and by the upload folder's cap; saved names never collide, are
never hidden and never too long; the last file does not stay in the button's value."""

from __future__ import annotations

import os
import time
import uuid

import pytest
from viser import _messages

from app import viser_private
from app.probe import Probe
from conftest import wait_until
from app.classroom.uploads import UploadGuard, safe_name, save_upload

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
MiB = 2**20


@pytest.fixture
def tab(tab, app):  # conftest's tab and app
    yield tab
    app.runs.uploads._starts.clear()  # each test starts with a fresh rate budget



def start(tab, name, size, parts):
    button = tab.wait_for(lambda m: m["type"] == "GuiUploadButtonMessage"  # the Runs panel's, not More robots…'
                          and m["props"]["label"].startswith("Upload a recording"))["uuid"]
    transfer = uuid.uuid4().hex
    tab.send(_messages.FileTransferStartUpload(source_component_uuid=button, transfer_uuid=transfer, filename=name,
                                               mime_type="application/octet-stream", part_count=parts, size_bytes=size))
    return button, transfer


def part(tab, button, transfer, index, content):
    tab.send(_messages.FileTransferPart(source_component_uuid=button, transfer_uuid=transfer, part_index=index,
                                        content=content))


def notified(tab, text, timeout=10.0):
    return tab.wait_for(lambda m: m["type"].startswith("Notification") and text in str(m), timeout)


def test_a_too_large_upload_is_refused_before_viser_buffers_a_byte(app, tab):
    button, transfer = start(tab, "big.rrd", 300 * MiB, 300)
    notified(tab, "at most 200 MiB")
    for k in range(3):
        part(tab, button, transfer, k, b"R" * MiB)
    time.sleep(0.3)
    assert viser_private.buffered_uploads(app.server) == {}
    assert app.runs.uploads.in_flight() == 0


def test_parts_beyond_the_declared_size_drop_the_transfer(app, tab):
    button, transfer = start(tab, "liar.rrd", MiB, 4)
    part(tab, button, transfer, 0, b"R" * (MiB // 2))
    assert wait_until(lambda: viser_private.buffered_uploads(app.server).get(transfer) == MiB // 2)
    part(tab, button, transfer, 1, b"R" * MiB)  # more than the rest it declared
    notified(tab, "more than the 1 MiB it declared")
    assert wait_until(lambda: viser_private.buffered_uploads(app.server) == {})
    part(tab, button, transfer, 2, b"R" * 100)  # later parts are ignored
    time.sleep(0.2)
    assert viser_private.buffered_uploads(app.server) == {} and app.runs.uploads.in_flight() == 0


def test_a_stalled_upload_is_dropped_after_the_timeout(app, tab):
    app.runs.uploads.idle_timeout = 0.5
    try:
        button, transfer = start(tab, "slow.rrd", 4 * MiB, 4)
        part(tab, button, transfer, 0, b"R" * MiB)
        assert wait_until(lambda: transfer in viser_private.buffered_uploads(app.server))
        notified(tab, "stalled")  # the render loop sweeps once a second
        assert viser_private.buffered_uploads(app.server) == {}
        assert app.runs.uploads.in_flight() == 0
    finally:
        app.runs.uploads.idle_timeout = 30.0


def test_one_upload_at_a_time_and_the_last_file_is_not_kept(app, tab):
    button, first = start(tab, "a.rrd", 2 * MiB, 2)
    part(tab, button, first, 0, b"R" * MiB)
    assert wait_until(lambda: first in viser_private.buffered_uploads(app.server))
    start(tab, "b.rrd", MiB, 1)  # one at a time per tab (another tab's is not held up: see below)
    notified(tab, "another upload from this tab is under way")
    part(tab, button, first, 1, b"R" * MiB)  # complete: not a recording, refused by the app
    notified(tab, "not a Rerun recording")
    assert wait_until(lambda: app.runs.uploads.in_flight() == 0)
    assert app.runs.upload.value.content == b""  # viser's copy of the file is let go
    assert viser_private.buffered_uploads(app.server) == {}


def test_a_viewer_is_refused_before_anything_is_buffered(app, tab):
    guard = app.runs.uploads
    allowed = guard.allowed
    guard.allowed = lambda cid: "the presenter controls uploads"
    try:
        button, transfer = start(tab, "x.rrd", MiB, 1)
        notified(tab, "the presenter controls uploads")
        part(tab, button, transfer, 0, b"R" * MiB)
        time.sleep(0.2)
        assert viser_private.buffered_uploads(app.server) == {}
    finally:
        guard.allowed = allowed


def test_a_tab_may_start_only_so_many_uploads_a_minute(tmp_path):
    now = [0.0]
    guard = UploadGuard(str(tmp_path), rate=(4, 60.0), clock=lambda: now[0])
    for k in range(4):
        assert guard.start(1, f"t{k}", "r.rrd", 10)
        guard._active.clear()  # as if each had finished
    assert "too many uploads" in guard.refusal(1, "r.rrd", 10, "t4")
    assert guard.refusal(2, "r.rrd", 10, "u0") is None  # another tab has its own budget
    guard._active.clear()
    now[0] = 61.0
    assert guard.refusal(1, "r.rrd", 10, "t5") is None


def test_the_upload_folder_has_a_cap(tmp_path):
    (tmp_path / "old.rrd").write_bytes(b"R" * 900)
    guard = UploadGuard(str(tmp_path), folder_cap=1000)
    assert "the upload folder is full" in guard.refusal(1, "new.rrd", 200, "t")
    assert guard.refusal(1, "new.rrd", 100, "t") is None


def test_saved_names_never_collide_are_never_hidden_and_never_too_long(tmp_path):
    first = save_upload(str(tmp_path), "shared.rrd", b"one")
    second = save_upload(str(tmp_path), "shared.rrd", b"two")
    assert os.path.basename(first) == "shared.rrd" and os.path.basename(second) == "shared-2.rrd"
    assert open(first, "rb").read() == b"one" and open(second, "rb").read() == b"two"
    assert safe_name(".rrd") == "upload.rrd" and safe_name("..hidden.rrd") == "hidden.rrd"
    assert safe_name("../../etc/x y.rrd") == "x_y.rrd"
    long = save_upload(str(tmp_path), "a" * 300 + ".rrd", b"three")
    assert len(os.path.basename(long)) == 104 and open(long, "rb").read() == b"three"
    assert sorted(os.listdir(tmp_path)) == sorted(["shared.rrd", "shared-2.rrd", os.path.basename(long)])


def test_a_file_that_fails_its_check_leaves_nothing(tmp_path):
    def bad(path):
        raise ValueError("not a recording")

    with pytest.raises(ValueError):
        save_upload(str(tmp_path), "x.rrd", b"RRF", check=bad)
    assert os.listdir(tmp_path) == []


def test_an_upload_declaring_absurd_part_counts_is_refused_as_it_starts(app, tab):
    """A billion parts for 1 MiB, more parts than bytes, more than a 200 MiB file has: refused as the
    transfer starts, nothing held; a transfer whose bytes are all in but not its parts is dropped at once."""
    for name, size, parts, said in (("huge.rrd", MiB, 10**9, "1,000,000,000 parts"), ("tiny.rrd", 10, 11, "11 parts"),
                                    ("many.rrd", 100 * MiB, 401, "401 parts")):
        button, transfer = start(tab, name, size, parts)
        notified(tab, said)
        part(tab, button, transfer, 0, b"R" * 10)
        time.sleep(0.1)
        assert viser_private.buffered_uploads(app.server) == {} and app.runs.uploads.in_flight() == 0
        app.runs.uploads._starts.clear()
    button, transfer = start(tab, "short.rrd", MiB, 3)
    part(tab, button, transfer, 0, b"R" * MiB)  # every byte, in one of the 3 parts it declared
    notified(tab, "in 1 of the 3 parts it declared")
    assert wait_until(lambda: viser_private.buffered_uploads(app.server) == {} and app.runs.uploads.in_flight() == 0)


def test_a_stalled_upload_of_one_tab_does_not_hold_up_another_tabs(app, tab):
    button, stalled = start(tab, "stalled.rrd", 2 * MiB, 2)
    part(tab, button, stalled, 0, b"R" * MiB)  # and never the rest
    assert wait_until(lambda: stalled in viser_private.buffered_uploads(app.server))
    other = Probe(app.url).start()
    try:
        t0 = time.monotonic()
        other_button, transfer = start(other, "b.rrd", MiB, 1)
        part(other, other_button, transfer, 0, b"R" * MiB)
        notified(other, "not a Rerun recording")  # whole, and handled by the app: not held up
        assert time.monotonic() - t0 < 5.0
        assert not any("under way" in str(m) for _t, m in other.messages)
    finally:
        other.close()
    assert wait_until(lambda: list(viser_private.buffered_uploads(app.server)) == [stalled])
    viser_private.drop_upload(app.server, stalled)
    app.runs.uploads._active.clear()


def test_the_memory_held_by_uploads_under_way_is_capped_and_the_waiting_tab_told_why(tmp_path):
    guard = UploadGuard(str(tmp_path), max_in_flight=300)
    assert guard.start(1, "a", "a.rrd", 200, 1)
    assert "another upload from this tab" in guard.refusal(1, "c.rrd", 10, "c")
    why = guard.refusal(2, "b.rrd", 200, "b")
    assert "must wait" in why and "b.rrd" in why
    assert guard.refusal(2, "b.rrd", 100, "b") is None


def test_refusals_name_the_file_as_the_user_did_never_the_servers_paths(app, tab):
    content = b"RRF2" + b"\0" * 2000  # looks like a recording, is not one
    button, transfer = start(tab, "C:\\Users\\me\\mine.rrd", len(content), 1)
    part(tab, button, transfer, 0, content)
    m = notified(tab, "cannot be replayed")
    text = str(m)
    assert "mine.rrd" in text
    for hidden in (app.recordings, os.path.abspath(app.recordings), "uploads/", ".upload-", ".part", "/tmp"):
        assert hidden not in text, (hidden, text)
