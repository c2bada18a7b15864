"""app/viser_private.py: a tab's query through viser's `?websocket=` parameter.

If viser changes what these rely on (its server's private connection table, or its client's
`?websocket=` parameter), these fail and name it.
"""

from __future__ import annotations

import shutil
import threading
import time
import urllib.parse

import pytest
import viser

from app import viser_private
from app.probe import Probe

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")


@pytest.fixture
def server():
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    s.queries = {}
    s.seen = threading.Event()

    @s.on_client_connect
    def _(client):
        s.queries[client.client_id] = viser_private.client_query(client)
        s.seen.set()

    yield s
    s.stop()


def url_of(server) -> str:
    return f"http://127.0.0.1:{server.get_port()}"


def test_the_private_api_for_queries_is_still_there(server):
    assert viser_private.query_api_missing(server) == [], f"viser {viser.__version__} changed"


def test_a_tab_connecting_with_a_query_is_seen_with_it(server):
    probe = Probe(url_of(server) + "/?token=abc-1;lesson=x").start()
    try:
        assert server.seen.wait(20)
        assert list(server.queries.values()) == [{"token": "abc-1", "lesson": "x"}]
    finally:
        probe.close()


def test_a_tab_without_a_query_has_none(server):
    probe = Probe(url_of(server)).start()
    try:
        assert server.seen.wait(20)
        assert list(server.queries.values()) == [{}]
    finally:
        probe.close()


def test_a_link_carries_its_parameters_to_the_server(server):
    link = viser_private.websocket_link(url_of(server), token="T0k_en", lesson="l1")
    page = urllib.parse.urlsplit(link)
    assert page.path == "/" and f":{server.get_port()}" in page.netloc
    ws = urllib.parse.parse_qs(page.query)["websocket"][0]
    assert ws.startswith("ws://127.0.0.1:")
    probe = Probe(ws).start()
    try:
        assert server.seen.wait(20)
        assert list(server.queries.values()) == [{"token": "T0k_en", "lesson": "l1"}]
    finally:
        probe.close()


@pytest.mark.parametrize("bad", ["a&b", "a b", "x;y", "é", "a/b"])
def test_a_link_refuses_values_that_viser_would_mangle(bad):
    with pytest.raises(ValueError, match="only letters, digits"):
        viser_private.websocket_link("http://h:1", token=bad)


def test_parse_query_takes_both_separators_and_the_first_of_a_name():
    assert viser_private.parse_query("/?a=1;b=2&a=3&c") == {"a": "1", "b": "2", "c": ""}
    assert viser_private.parse_query("/") == {}


def test_client_query_names_what_is_missing_when_viser_changes():
    class Fake:
        client_id = 0
        _viser_server = object()

    with pytest.raises(viser_private.ViserChanged, match="_websock_server"):
        viser_private.client_query(Fake())


CHROMIUM = shutil.which("chromium")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (`make browser` installs it)")
def test_viser_s_own_client_honours_the_websocket_parameter_and_keeps_it_on_reload(server):
    """viser's built client (not ours) must connect to the `?websocket=` URL, query included;
    a reload of the rewritten page URL must connect with the same query."""
    sync_api = pytest.importorskip("playwright.sync_api")
    link = viser_private.websocket_link(url_of(server), token="abc", lesson="two")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True)
        try:
            page = browser.new_page()
            page.goto(link)
            assert server.seen.wait(30), "the page never connected"
            assert list(server.queries.values()) == [{"token": "abc", "lesson": "two"}]
            server.seen.clear()
            deadline = time.monotonic() + 10
            while "websocket=" not in page.url and time.monotonic() < deadline:
                time.sleep(0.1)
            page.reload()
            assert server.seen.wait(30), "the reloaded page never connected"
            assert list(server.queries.values())[-1] == {"token": "abc", "lesson": "two"}, page.url
        finally:
            browser.close()


def stress(seconds: float, safe: bool, senders: int = 100, period: float = 0.02, stop_at_error: bool = False) -> dict:
    """viser's message buffer with `senders` waiting consumers (one per tab, as on the broadcast
    buffer) in an event loop's thread, and pushes from this thread every `period` s: the errors
    the pushes raised, and whether every consumer got the last message (no lost wake-up)."""
    import asyncio
    import sys

    from viser import _messages
    from viser.infra._async_message_buffer import AsyncMessageBuffer

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # thread switches as often as possible: the race shows in seconds
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    async def make():
        b = AsyncMessageBuffer(loop, persistent_messages=True)
        b.message_event = viser_private.LoopSafeEvent(loop) if safe else asyncio.Event()
        return b

    buf = asyncio.run_coroutine_threadsafe(make(), loop).result()
    last: dict[int, float] = {}

    async def consumer(k):
        async for window in buf.window_generator(k):
            last[k] = window[-1].position[2]

    async def busy():  # the loop's thread is never idle (as with tabs dragging)
        while True:
            await asyncio.sleep(0)

    tasks = [asyncio.run_coroutine_threadsafe(consumer(k), loop) for k in range(senders)]
    tasks.append(asyncio.run_coroutine_threadsafe(busy(), loop))
    errors, n = [], 0
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (stop_at_error and errors):
            try:
                buf.push(_messages.SetPositionMessage("/n", (0.0, 0.0, float(n))))
            except RuntimeError as e:
                errors.append(str(e))
            n += 1
            time.sleep(period)
        sys.setswitchinterval(interval)
        time.sleep(0.5)
        got_last = sum(v == float(n - 1) for v in last.values())
    finally:
        sys.setswitchinterval(interval)
        buf.set_done()  # the consumers end
        for t in tasks[:-1]:
            try:
                t.result(5)
            except Exception:  # noqa: BLE001 - a consumer that failed still ends
                pass
        tasks[-1].cancel()
        time.sleep(0.05)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.close()
    return dict(pushes=n, errors=errors, got_last=got_last, senders=senders)


def test_viser_alone_raises_when_a_thread_pushes_while_tabs_wait():
    """The fault, with viser's own buffer and event (viser 1.1.1): if this fails, viser has fixed
    it, and install_loop_safe_wakeups can go. A race: on a busy machine (fewer pushes, rarer thread
    switches) 20 s may pass without it, so up to three tries of 20 s; on an idle one the first hits it.
    With viser 1.1.1 three misses are a busy machine (skipped, saying so); with another version they
    fail: that version may have fixed it."""
    tries = []
    for _ in range(3):
        r = stress(20.0, safe=False, stop_at_error=True)
        tries.append(r)
        if r["errors"]:
            break
    if not r["errors"] and viser.__version__ == "1.1.1":  # the version the fault was seen in, on an idle machine
        pytest.skip(f"the race did not show in three tries of 20 s on this busy machine: {tries}")
    assert r["errors"] and "deque mutated during iteration" in r["errors"][0], tries


def test_with_loop_safe_wakeups_no_push_raises_and_every_tab_gets_the_last_message():
    r = stress(6.0, safe=True)
    assert r["errors"] == [], r
    assert r["got_last"] == r["senders"], r


def test_install_makes_every_new_buffer_loop_safe():
    viser_private.install_loop_safe_wakeups()
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        assert isinstance(s._websock_server._broadcast_buffer.message_event, viser_private.LoopSafeEvent)
    finally:
        s.stop()


def test_the_private_api_for_guarding_uploads_is_still_there(server):
    assert viser_private.upload_api_missing(server) == [], f"viser {viser.__version__} changed"
    viser_private.guard_uploads(server, lambda *a: True, lambda *a: True)
    assert viser_private.upload_api_missing(server) == [] and viser_private.buffered_uploads(server) == {}


def test_the_message_gate_checks_each_value_against_its_element():
    """install_message_gate's check (app/viser_private.py: gui_update_problem): a browser sends only
    {"value": ...} of the element's type; anything else is dropped before viser casts it."""
    from types import SimpleNamespace as S

    problem = viser_private.gui_update_problem
    number, box, text = S(value=1.0), S(value=True), S(value="planar", options=("planar", "ur5"))
    assert problem(number, {"value": 2}) is None and problem(number, {"value": 2.5}) is None
    for bad in (float("nan"), float("inf"), "abc", True, None, [1]):
        assert problem(number, {"value": bad}) is not None, bad
    assert problem(box, {"value": False}) is None and problem(box, {"value": "abc"}) is not None
    assert problem(box, {"color": "red"}) is not None and problem(box, {"value": True, "x": 1}) is not None
    assert problem(text, {"value": "ur5"}) is None and problem(text, {"value": "kuka"}) is not None
    assert problem(S(value=(1.0, 2.0)), {"value": [3, 4.5]}) is None
    assert problem(S(value=(1.0, 2.0)), {"value": [3, float("nan")]}) is not None
    assert problem(S(value=False, is_button=True), {"value": True}) is None
    assert problem(S(value=False, is_button=True), {"value": False}) is not None
    assert problem(number, "not a dict") is not None
    # viser keeps an element's options, min and max in its props: a dropdown's value must be one of its
    # options, a slider's (a number's, a vector's) within min..max, a colour's 0..255 (issue #55)
    dropdown = S(value="CMA-ES", props=S(options=("CMA-ES", "NEAT")))
    assert problem(dropdown, {"value": "NEAT"}) is None
    for bad in ("No such", "warp", "", 5, None):
        assert problem(dropdown, {"value": bad}) is not None, bad
    assert "options" in problem(dropdown, {"value": "No such"})
    slider = S(value=0.0, props=S(min=0, max=10, step=1))
    assert problem(slider, {"value": 10}) is None and problem(slider, {"value": 0}) is None
    for bad in (-1, 10.5, 1e300, -1e300, float("nan")):
        assert problem(slider, {"value": bad}) is not None, bad
    vector = S(value=(0.0, 0.0), props=S(min=(0.0, -1.0), max=(1.0, 1.0)))
    assert problem(vector, {"value": [1, -1]}) is None and problem(vector, {"value": [1, -2]}) is not None
    rgb = S(value=(10, 20, 30), props=type("GuiRgbProps", (), {})())
    assert problem(rgb, {"value": [0, 255, 9]}) is None and problem(rgb, {"value": [0, 256, 9]}) is not None
    free = S(value=50.0, props=S(min=None, max=None))  # a number without bounds: any finite one
    assert problem(free, {"value": 1e9}) is None and problem(free, {"value": float("inf")}) is not None
    viser_private.install_message_gate()
    viser_private.install_message_gate()  # idempotent


def test_the_gate_takes_a_gizmo_s_pose_only_as_a_finite_rotation_and_point():
    """transform_problem: a gizmo's orientation must be a finite nonzero quaternion (normalised in place,
    as the goal is a rotation), its position a finite point (issue #55: (NaN, 0, 0, 0) broke the render
    loop); camera_problem: a camera's numbers finite."""
    from types import SimpleNamespace as S

    nan, inf = float("nan"), float("inf")
    for wxyz in ((nan, 0, 0, 0), (1, nan, 0, 0), (0, 0, 0, nan), (0, 0, 0, 0), (inf, 0, 0, 0), (1, -inf, 0, 0), (1, 0, 0),
                 (1e300, 1e300, 0, 0), ("a", 0, 0, 0), None):
        assert viser_private.transform_problem(S(wxyz=wxyz, position=(0.0, 0.0, 0.0))) is not None, wxyz
    for position in ((nan, 0, 0), (0, nan, 0), (0, 0, nan), (0, inf, 0), (0, 0), (1e300, 0, 0), None, (True, 0, 0)):
        assert viser_private.transform_problem(S(wxyz=(1.0, 0, 0, 0), position=position)) is not None, position
    good = S(wxyz=(2.0, 0.0, 0.0, 2.0), position=(0.1, -0.2, 0.3))
    assert viser_private.transform_problem(good) is None
    assert good.wxyz == pytest.approx((2 ** -0.5, 0.0, 0.0, 2 ** -0.5), abs=1e-15)
    camera = dict(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -3.0, 2.0), fov=1.0, near=0.01, far=1000.0,
                  image_height=800, image_width=1280, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0))
    assert viser_private.camera_problem(S(**camera)) is None
    for name, bad in (("wxyz", (nan, 0, 0, 0)), ("position", (0, inf, 0)), ("fov", nan), ("image_width", None)):
        assert viser_private.camera_problem(S(**{**camera, name: bad})) is not None, name
