"""Every reach into viser's private API, in one place (tests/test_app_views.py checks each is still there).

viser 1.1 has no public way to do these; each has a measured reason, and a fallback to the
public API where one exists. When viser changes, `check()` names what is gone.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import math
import re
import threading
import time
import urllib.parse

import numpy as np

try:  # private: the scene's position and orientation messages
    from viser._messages import SetOrientationMessage, SetPositionMessage
except ImportError:  # pragma: no cover - another viser: set_pose falls back to the setters
    SetOrientationMessage = SetPositionMessage = None


def set_pose(handle, position: np.ndarray, wxyz: np.ndarray) -> None:
    """handle.position, handle.wxyz = position, wxyz, without the setters' cost.

    Why: viser 1.1's pose setters (casts, np.allclose, property machinery) made arm updates the
    server's main cost while dragging (docs/results/app-speed.md). This queues the same two
    messages through the scene's own (private) queue and keeps the handle's state (`handle._impl`)
    in step; if that API is not there (another viser), it falls back to the setters."""
    impl = getattr(handle, "_impl", None)
    queue = getattr(getattr(impl, "api", None), "_queue_scene_message", None)
    if queue is None or SetPositionMessage is None or not hasattr(impl, "removed"):
        handle.position, handle.wxyz = position, wxyz
        return
    if impl.removed:  # a message for a removed node would bring it back in the browser
        return
    impl.position[:] = position
    impl.wxyz[:] = wxyz
    queue(SetPositionMessage(impl.name, (float(position[0]), float(position[1]), float(position[2]))))
    queue(SetOrientationMessage(impl.name, (float(wxyz[0]), float(wxyz[1]), float(wxyz[2]), float(wxyz[3]))))


# ---------------------------------------------------------------------- a tab's query
# viser's client drops the page's query string before it opens its websocket, so the server never
# sees `?token=...` of the page URL. The client's own `?websocket=<ws URL>` parameter makes it
# connect to that URL instead, query included (viser/client/src/App.tsx: `searchParams.getAll
# ("websocket")`; WebsocketClientWorker.ts: `new WebSocket(server, [protocol])`), and the server
# sees it in the handshake's request path. After connecting, the client rewrites the page URL
# with that parameter unescaped (SearchParamsUtils.ts: syncSearchParamServer), so a reload keeps
# the query only up to its first '&': parameters are joined with ';' here, and values are kept to
# URL-safe characters, which survive that rewriting unchanged.
SAFE_VALUE = re.compile(r"[A-Za-z0-9._~-]*")


def websocket_link(page_url: str, **params: str) -> str:
    """A link to the app at page_url (http://host:port) whose tab connects with `params` in its
    websocket URL's query, where `client_query` reads them back. Names and values must be URL-safe
    ([A-Za-z0-9._~-]; ValueError otherwise): viser rewrites the page URL unescaped."""
    for name, value in params.items():
        if not name or not SAFE_VALUE.fullmatch(name) or not SAFE_VALUE.fullmatch(str(value)):
            raise ValueError(f"link parameter {name}={value!r}: only letters, digits and . _ ~ - are kept by viser's client")
    base = page_url.rstrip("/")
    ws = ("wss://" + base[len("https://"):]) if base.startswith("https://") else "ws://" + base.split("://", 1)[-1]
    query = ";".join(f"{k}={v}" for k, v in params.items())
    return f"{base}/?websocket={urllib.parse.quote(f'{ws}/?{query}', safe='')}"


def parse_query(path: str) -> dict[str, str]:
    """The parameters of a request path's query ('&' or ';' between them; the first of a name wins)."""
    query = urllib.parse.urlsplit(path).query
    out: dict[str, str] = {}
    for part in re.split(r"[&;]", query):
        if part:
            name, _, value = part.partition("=")
            out.setdefault(urllib.parse.unquote_plus(name), urllib.parse.unquote_plus(value))
    return out


class ViserChanged(RuntimeError):
    """viser no longer has a private attribute this module relies on (the message names it)."""


def client_query(client) -> dict[str, str]:
    """The query of the websocket URL a tab (viser.ClientHandle) connected with, as a dict ({} when the
    tab has already gone). ViserChanged, naming what is missing, when viser's internals changed.

    Reach: `client._viser_server._websock_server._live_connections[client_id]` is the tab's
    websockets ServerConnection (set before any connect callback runs), whose public `.request.path`
    is the handshake's path with its query."""
    return connection_query(getattr(client, "_viser_server", None), client.client_id) or {}


def connection_query(server, client_id: int) -> dict[str, str] | None:
    """client_query by the tab's id (its connection is known before viser's connect callbacks run,
    from the websocket handshake on): None when there is no such connection (any more)."""
    missing = query_api_missing(server)
    if missing:
        raise ViserChanged(f"viser changed: {', '.join(missing)} missing; a tab's query cannot be read")
    connection = server._websock_server._live_connections.get(client_id)
    if connection is None:
        return None
    request = getattr(connection, "request", None)
    return parse_query(getattr(request, "path", "") or "")


def connection_address(server, client_id: int) -> str | None:
    """The remote IP address of a tab's connection (None when it has gone). Same reach as
    connection_query, then websockets' public ServerConnection.remote_address."""
    missing = query_api_missing(server)
    if missing:
        raise ViserChanged(f"viser changed: {', '.join(missing)} missing; a tab's address cannot be read")
    connection = server._websock_server._live_connections.get(client_id)
    address = getattr(connection, "remote_address", None)
    return str(address[0]) if isinstance(address, tuple) and address else None


def query_api_missing(server) -> list[str]:
    """What of the private API client_query uses this viser server lacks (empty: all there)."""
    websock = getattr(server, "_websock_server", None)
    if websock is None:
        return ["ViserServer._websock_server"]
    if not isinstance(getattr(websock, "_live_connections", None), dict):
        return ["WebsockServer._live_connections"]
    return []


# ---------------------------------------------------------------------- updates from other threads
# viser is meant to be driven from any thread (its examples update handles from the main thread;
# sync callbacks run in its thread pool; AsyncMessageBuffer.push takes a threading.Lock "to prevent
# race conditions when pushing messages from different threads" and wakes the loop with
# call_soon_threadsafe). But push() also calls `self.message_event.set()` directly, in the pushing
# thread: asyncio.Event.set() iterates the event's waiters (one future per tab's sender waiting
# on that buffer) while the loop's thread appends and removes them, which raises
# `RuntimeError: deque mutated during iteration` in the pushing thread (the message is buffered,
# but the caller's update stops half-way) and resolves futures off the loop (a wake-up can be
# lost). tests/test_viser_private.py reproduces it with viser's class alone: 100 waiting senders
# on one buffer, pushes from another thread every 20 ms: 85 errors in 954 pushes (viser 1.1.1).
# The fix: each buffer's message event hands a set() from another thread to its loop
# (call_soon_threadsafe), so only the loop's thread touches its waiters. Nothing reads the flag
# synchronously (viser 1.1.1: only window_loop awaits and clears it).
class LoopSafeEvent(asyncio.Event):
    """An asyncio.Event of `loop` whose set() may be called from any thread."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        super().__init__()
        self._owner = loop
        self._pending = False  # a set() is on its way to the loop

    def set(self) -> None:
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:  # a thread with no running loop
            here = None
        if here is self._owner:
            super().set()
            return
        # Already set, or a set on its way: nothing more to wake (a sender reads the buffer's message
        # counter, which push() raised before calling this, after it clears the event). This keeps a
        # burst of pushes inside atomic() to one wake-up of the loop instead of one per message.
        if self._value or self._pending:
            return
        self._pending = True
        try:
            self._owner.call_soon_threadsafe(self._set_here)
        except RuntimeError:  # the loop is closed (the server stopped): nothing to wake
            self._pending = False

    def _set_here(self) -> None:
        self._pending = False
        super().set()


def install_loop_safe_wakeups() -> None:
    """Make every viser message buffer created from now on wake its loop safely from any thread
    (viser.infra AsyncMessageBuffer.message_event becomes a LoopSafeEvent). Call it before
    creating the ViserServer; idempotent; it changes viser's class for the whole process.
    ViserChanged, naming it, when the class is not there any more."""
    cls = _message_buffer_class()
    if getattr(cls, "_loop_safe", False):
        return
    original = cls.__init__

    def __init__(self, *args, **kwargs):
        original(self, *args, **kwargs)
        self.message_event = LoopSafeEvent(self.event_loop)

    cls.__init__ = __init__
    cls._loop_safe = True


def _message_buffer_class():
    try:
        from viser.infra._async_message_buffer import AsyncMessageBuffer
    except ImportError as e:
        raise ViserChanged(f"viser changed: viser.infra._async_message_buffer.AsyncMessageBuffer missing ({e})") from e
    fields = getattr(AsyncMessageBuffer, "__dataclass_fields__", {})
    missing = [f for f in ("event_loop", "message_event") if f not in fields]
    if missing:
        raise ViserChanged(f"viser changed: AsyncMessageBuffer has no {', '.join(missing)}")
    return AsyncMessageBuffer


# ---------------------------------------------------------------------- bad messages from a tab
# viser 1.1.1 applies a tab's GuiUpdateMessage by casting its value to the element's type
# (GuiApi._handle_gui_updates: `type(current)(value)`, `assert hasattr(state, prop)`) in a task of its
# event loop that nobody awaits: a slider sent "abc", a checkbox sent an unknown property, raises,
# and asyncio prints an 8-line "Task exception was never retrieved" per message; NaN, a string to a
# checkbox (bool("abc") is True) or an out-of-list dropdown value are even applied (the last raised
# in the lab's callbacks: StopIteration, KeyError, a render loop failing on every pass, issue #55).
# A gizmo's TransformControlsUpdateMessage is applied as it comes (SceneApi._handle_transform_controls_
# updates): an orientation (NaN, 0, 0, 0) or (0, 0, 0, 0) became the goal's and raised in every redraw.
# The gate checks every value a tab sends against its element before viser applies it (a GUI value:
# its type, a dropdown's options, a slider's or number's min and max, an RGB's 0..255; a gizmo: a
# finite nonzero quaternion, normalised, and a finite position; a camera: finite numbers), drops a bad
# one before any callback, and catches whatever a tab's message still raises in any handler: one log
# line per tab per BAD_LOG_PERIOD seconds, the count of the others in the next line, never a
# traceback, and the same line to the tab as a notification (at most one a BAD_LOG_PERIOD).
# A frame that is not a viser message at all (not msgpack, no known type, a text frame) ends the tab's
# connection in viser's reader (viser.infra._infra._message_consumer), which is right, but the error
# escapes viser's connection handler and websockets logs a 13-line "connection handler failed"
# traceback per tab: a viewer could fill the teacher's terminal. The gate's reader closes such a tab
# itself (close code 1003/1007) and logs one line, at most one per BAD_LOG_PERIOD for all such tabs
# of a server with the count of the others, never a traceback.
BAD_LOG_PERIOD = 60.0  # s: at most one log line per tab in this while
MAX_TEXT = 10_000  # characters of a text value a tab may send
MAX_COORD = 1e6  # a gizmo's or camera's coordinate beyond this is no place in any workspace here
_bad_log: dict = {}  # (event loop id, client id) -> [time of the last line, messages dropped since]
_bad_lock = threading.Lock()
_option_sets: dict = {}  # id(options tuple) -> (that tuple, its frozenset): a dropdown's check is O(1)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _in_options(value: str, options) -> bool:
    """value in options, by a set made once per options tuple (a runs list can be long)."""
    entry = _option_sets.get(id(options))
    if entry is None or entry[0] is not options:
        if len(_option_sets) > 1000:  # options replaced over a long day: forget the old ones
            _option_sets.clear()
        entry = _option_sets[id(options)] = (options, frozenset(options))  # keeps the tuple: its id stays its own
    return value in entry[1]


def _bound(limit, k: int):
    """The k-th entry of a min or max (a number for every entry, a tuple of one each, or None)."""
    if isinstance(limit, (tuple, list)):
        return limit[k] if k < len(limit) else None
    return limit


def _within(v, lo, hi) -> bool:
    span = (hi - lo) if _number(lo) and _number(hi) else 1.0
    eps = 1e-9 * max(1.0, abs(span))  # a slider's steps as floats
    return (not _number(lo) or v >= lo - eps) and (not _number(hi) or v <= hi + eps)


def gui_update_problem(state, updates) -> str | None:
    """Why a tab's GuiUpdateMessage `updates` may not be applied to an element whose state is `state`
    (viser's _GuiHandleState: value, props), or None. A browser only ever sends {"value": ...} of the
    element's type: one of a dropdown's (or button group's) options, a number within the element's min
    and max (where it has them), an RGB colour's 0..255."""
    if not isinstance(updates, dict) or set(updates) != {"value"}:
        return f"properties {sorted(map(str, updates))[:5] if isinstance(updates, dict) else updates!r:.40} (only value may be sent)"
    value, current = updates["value"], getattr(state, "value", None)
    props = getattr(state, "props", state)
    lo, hi = getattr(props, "min", None), getattr(props, "max", None)
    if lo is None and hi is None and "Rgb" in type(props).__name__:
        lo, hi = 0, 255
    why = "for a {} element"
    if getattr(state, "is_button", False) and isinstance(current, bool):
        ok = value is True
    elif isinstance(current, bool):
        ok = isinstance(value, bool)
    elif isinstance(current, (int, float)):
        ok = _number(value)
        if ok and not _within(value, lo, hi):
            ok, why = False, f"outside {lo}..{hi} of its {{}} element"
    elif isinstance(current, str):
        ok = isinstance(value, str) and len(value) <= MAX_TEXT
        options = getattr(props, "options", None)
        if ok and isinstance(options, tuple) and options and not _in_options(value, options):
            ok, why = False, "not one of its {} element's options"
    elif isinstance(current, tuple):
        ok = (isinstance(value, (list, tuple)) and len(value) == len(current)
              and all(_number(v) if isinstance(c, (int, float)) and not isinstance(c, bool) else type(v) is type(c)
                      for v, c in zip(value, current)))
        if ok and not all(_within(v, _bound(lo, k), _bound(hi, k)) for k, v in enumerate(value) if _number(v)):
            ok, why = False, f"outside {lo}..{hi} of its {{}} element"
    else:  # an upload's file, a value the browser never sends
        ok = False
    return None if ok else f"value {value!r:.40} " + why.format(type(current).__name__)


_NUMBER_TYPES = frozenset((int, float))  # bool is neither


def _finite(values, n: int) -> bool:
    """values: n numbers (not bools), each finite and within MAX_COORD."""
    return (type(values) in (tuple, list) and len(values) == n and {type(v) for v in values} <= _NUMBER_TYPES
            and all(map(math.isfinite, values)) and max(map(abs, values)) <= MAX_COORD)


def transform_problem(message) -> str | None:
    """Why a tab's TransformControlsUpdateMessage may not move its gizmo, or None: its orientation must
    be a finite nonzero quaternion (w, x, y, z) and its position finite. A good one's quaternion is
    normalised in place (a browser's float32 one is off by ~1e-7; the goal is a rotation)."""
    q, p = getattr(message, "wxyz", None), getattr(message, "position", None)
    if not _finite(q, 4):
        return f"gizmo orientation {q!r:.60} (not a finite quaternion)"
    w, x, y, z = q
    norm2 = w * w + x * x + y * y + z * z
    if norm2 < 1e-12:
        return f"gizmo orientation {tuple(q)!r:.60} (a zero quaternion is no rotation)"
    if not _finite(p, 3):
        return f"gizmo position {p!r:.60} (not a finite point)"
    if abs(norm2 - 1.0) > 1e-12:
        norm = math.sqrt(norm2)
        message.wxyz = (w / norm, x / norm, y / norm, z / norm)
    return None


def camera_problem(message) -> str | None:
    """Why a tab's ViewerCameraMessage may not be applied (a number that is not finite), or None."""
    for name, n in (("wxyz", 4), ("position", 3), ("look_at", 3), ("up_direction", 3)):
        if not _finite(getattr(message, name, None), n):
            return f"camera {name} {getattr(message, name, None)!r:.60} (not finite)"
    for name in ("fov", "near", "far", "image_height", "image_width"):
        if not _number(getattr(message, name, None)):
            return f"camera {name} {getattr(message, name, None)!r:.40} (not a finite number)"
    return None


def _quiet_since(key) -> int | None:
    """None when a line for `key` was logged less than BAD_LOG_PERIOD ago (this one is counted
    instead), else the count of those not logged since the last line (a line is due now)."""
    now = time.monotonic()
    with _bad_lock:
        if len(_bad_log) > 10_000:  # tabs come and go: forget those quiet for a while
            for k in [k for k, (t, _n) in _bad_log.items() if t is None or now - t >= BAD_LOG_PERIOD]:
                del _bad_log[k]
        entry = _bad_log.setdefault(key, [None, 0])
        if entry[0] is not None and now - entry[0] < BAD_LOG_PERIOD:
            entry[1] += 1
            return None
        dropped, entry[0], entry[1] = entry[1], now, 0
    return dropped


def _loop_id():
    try:
        return id(asyncio.get_running_loop())
    except RuntimeError:
        return None


def report_bad_message(client_id, what: str, tell=None) -> None:
    """Log a tab's dropped message: one line per tab per BAD_LOG_PERIOD (per server: its event loop);
    tell(text), when given, says the same to the tab (a notification) when the line is logged."""
    dropped = _quiet_since((_loop_id(), client_id))
    if dropped is None:
        return
    more = f" ({dropped} more dropped in the last {BAD_LOG_PERIOD:g} s)" if dropped else ""
    logging.getLogger("app.viser").warning(
        "tab %s sent an invalid message, dropped: %s%s; further ones are logged at most once a minute",
        client_id, what, more)
    if tell is not None:
        try:
            tell(f"Not applied: {what}. Further invalid values from this tab are dropped without a word "
                 f"for a minute.")
        except Exception:  # noqa: BLE001 - the tab has gone: nobody to tell
            pass


def _teller(owner, client_id):
    """tell(text): a notification in tab client_id, for a GuiApi's or SceneApi's owner (a ViserServer or
    the tab's ClientHandle)."""
    def tell(text: str) -> None:
        client = owner.get_clients().get(client_id) if hasattr(owner, "get_clients") else owner
        if client is not None:
            client.add_notification("Not applied", text, auto_close_seconds=8.0, color="red")
    return tell


def _tell_connection(connection, text: str) -> None:
    """A notification in the tab of a viser WebsockClientConnection (what ClientHandle.add_notification queues)."""
    from viser import _messages

    props = _messages.NotificationProps(title="Not applied", body=text, loading=False, with_close_button=True,
                                        auto_close_seconds=8.0, color="red")
    connection.queue_message(_messages.NotificationShowMessage(uuid=f"lab-gate-{time.monotonic_ns()}", props=props))


def report_unreadable_frame(address, what: str) -> None:
    """Log a tab closed for a frame that is not a viser message: one line per BAD_LOG_PERIOD for all
    such tabs of a server (its event loop), with the count of the others."""
    dropped = _quiet_since((_loop_id(), "unreadable frames"))
    if dropped is None:
        return
    more = f" ({dropped} more such tabs closed in the last {BAD_LOG_PERIOD:g} s)" if dropped else ""
    logging.getLogger("app.viser").warning(
        "a tab from %s sent a frame that is not a viser message (%s) and was closed%s; further ones are logged at "
        "most once a minute", address or "an unknown address", what, more)


async def _read_messages(websocket, handle_message, message_class) -> None:
    """viser's per-tab reader (viser.infra._infra._message_consumer, viser 1.1.1), except that a frame
    that is not a viser message closes the tab with one rate-limited log line instead of raising out
    of the connection handler (websockets' traceback). The next recv() then raises ConnectionClosed,
    which viser's handler expects: its teardown and disconnect callbacks run as for any closed tab."""
    while True:
        raw = await websocket.recv()
        try:
            if not isinstance(raw, bytes):
                raise TypeError(f"a text frame of {len(raw)} characters")
            message = message_class.deserialize(raw)
        except Exception as e:  # noqa: BLE001 - anything a tab sends: the tab is closed, told once a minute
            address = getattr(websocket, "remote_address", None)
            report_unreadable_frame(address[0] if isinstance(address, tuple) and address else None,
                                    f"{type(e).__name__}: {e!s:.80}")
            await websocket.close(1003 if isinstance(raw, str) else 1007, "not a viser message")
            continue
        handle_message(message)


def install_message_gate() -> None:
    """Check every tab's GUI update against its element before viser applies it, and catch what any
    tab's message raises in viser's handlers (report_bad_message, no traceback); a frame that is not a
    viser message closes its tab with one line (report_unreadable_frame, no traceback). Process-wide,
    for every ViserServer and tab created from now on (call it before creating the server); idempotent.
    ViserChanged, naming it, when what it wraps is gone."""
    try:
        from viser import _messages
        from viser._gui_api import GuiApi
        from viser._scene_api import SceneApi
        from viser.infra import _infra
        from viser.infra._infra import WebsockMessageHandler
    except ImportError as e:
        raise ViserChanged(f"viser changed: {e}; bad messages cannot be dropped") from e
    if not inspect.iscoroutinefunction(getattr(_infra, "_message_consumer", None)):
        raise ViserChanged("viser changed: viser.infra._infra._message_consumer is not a coroutine function any more")
    for cls, name in ((GuiApi, "_handle_gui_updates"), (WebsockMessageHandler, "_handle_incoming_message"),
                      (SceneApi, "_handle_transform_controls_updates")):
        if not inspect.iscoroutinefunction(getattr(cls, name, None)):
            raise ViserChanged(f"viser changed: {cls.__name__}.{name} is not a coroutine function any more")
    if getattr(GuiApi, "_lab_gated", False):
        return
    apply_update, dispatch = GuiApi._handle_gui_updates, WebsockMessageHandler._handle_incoming_message
    move_gizmo = SceneApi._handle_transform_controls_updates

    async def _handle_gui_updates(self, client_id, message):
        handle = self._gui_input_handle_from_uuid.get(message.uuid)
        if handle is not None and not handle._impl.removed:
            problem = gui_update_problem(handle._impl, message.updates)
            if problem is not None:
                label = getattr(getattr(handle._impl, "props", None), "label", None)  # viser 1.1: props.label
                report_bad_message(client_id, f"{label if isinstance(label, str) else '?'!r:.40}: {problem}",
                                   _teller(self._owner, client_id))
                return
        await apply_update(self, client_id, message)

    async def _handle_transform_controls_updates(self, client_id, message):
        # runs only in the scope (server or tab) whose owner the message names: one report per message
        problem = transform_problem(message)
        if problem is not None:
            report_bad_message(client_id, problem, _teller(self._owner, client_id))
            return
        await move_gizmo(self, client_id, message)

    async def _handle_incoming_message(self, client_id, message):
        if type(message) is camera and type(message) in self._incoming_handlers:  # the tab's connection
            problem = camera_problem(message)
            if problem is not None:
                report_bad_message(client_id, problem, lambda text: _tell_connection(self, text))
                return
        try:
            await dispatch(self, client_id, message)
        except Exception as e:  # noqa: BLE001 - a tab's message: dropped, told once a minute
            report_bad_message(client_id, f"{type(message).__name__} raised {type(e).__name__}: {e!s:.80}")

    camera = _messages.ViewerCameraMessage
    GuiApi._handle_gui_updates = _handle_gui_updates
    SceneApi._handle_transform_controls_updates = _handle_transform_controls_updates
    WebsockMessageHandler._handle_incoming_message = _handle_incoming_message
    _infra._message_consumer = _read_messages  # looked up by name in viser's connection handler, per tab
    GuiApi._lab_gated = True


# ---------------------------------------------------------------------- shared GUI: who may change it
# Elements of server.gui are shared by every tab. guard_shared_gui drops a tab's change of one of them
# (a value typed, a button pressed or held) before viser applies it, unless allow(client_id) says the
# tab may: viser never sets the value, never calls the callbacks, never echoes it to other tabs.
def guard_shared_gui(server, allow, refused=None) -> None:
    """allow(client_id) -> bool; refused(client_id, uuid): called for each dropped change (in
    viser's event loop). Covers every element of server.gui, present and future. Idempotent."""
    from viser import _messages

    missing = shared_gui_api_missing(server)
    if missing:
        raise ViserChanged(f"viser changed: {', '.join(missing)} missing; shared controls cannot be guarded")
    if getattr(server, "_lab_gui_guarded", False):
        return
    shared = server.gui._gui_input_handle_from_uuid

    def check(client_id, message) -> bool:
        if message.uuid not in shared or allow(client_id):
            return True
        if refused is not None:
            refused(client_id, message.uuid)
        return False

    handlers = server._websock_server._incoming_handlers
    for cls in (_messages.GuiUpdateMessage, _messages.GuiButtonHoldMessage):
        if handlers.get(cls):
            _guard(handlers, cls, check)
    # Server-wide requests any tab may send: viser's titlebar "share" button opens (and closes) a
    # public tunnel to the server through share.viser.studio; forms' submit and dirty marks and
    # command-palette triggers reach every tab. Only tabs allowed to change shared state may.
    for name in SERVER_WIDE_REQUESTS:
        cls = getattr(_messages, name, None)
        if cls is not None and handlers.get(cls):
            _guard(handlers, cls, lambda client_id, message: allow(client_id))
    server._lab_gui_guarded = True


SERVER_WIDE_REQUESTS = ("ShareUrlRequest", "ShareUrlDisconnect", "GuiFormSubmitMessage", "GuiFormDirtyMessage",
                        "CommandTriggerMessage")


def shared_gui_api_missing(server) -> list[str]:
    missing = []
    try:
        from viser import _messages

        _messages.GuiUpdateMessage  # noqa: B018
    except (ImportError, AttributeError):
        return ["viser._messages.GuiUpdateMessage"]
    handlers = getattr(getattr(server, "_websock_server", None), "_incoming_handlers", None)
    if not isinstance(handlers, dict):
        missing.append("WebsockServer._incoming_handlers")
    elif not handlers.get(_messages.GuiUpdateMessage):
        missing.append("a handler of GuiUpdateMessage")
    if not isinstance(getattr(getattr(server, "gui", None), "_gui_input_handle_from_uuid", None), dict):
        missing.append("GuiApi._gui_input_handle_from_uuid")
    return missing


def shared_inputs(server) -> dict:
    """uuid -> handle of every input element (buttons included) of server.gui."""
    return dict(server.gui._gui_input_handle_from_uuid)


def send_gui_props(client, uuid: str, **props) -> None:
    """Set props (e.g. disabled=True, value=...) of a GUI element in one tab only: the other tabs and
    the server's own state are untouched (a shared element looks disabled to a viewer)."""
    from viser import _messages

    client._websock_connection.queue_message(_messages.GuiUpdateMessage(uuid, props))


# ---------------------------------------------------------------------- uploads
# viser 1.1.1 buffers an upload's parts in memory (GuiApi._current_file_upload_states) as they come
# and only then hands the whole file to the button's callbacks: a size cap checked there comes after
# the memory is spent, an unfinished transfer is held until its tab closes, and the last file stays
# in the button's value. guard_uploads puts our checks in front of viser's own handlers.
def guard_uploads(server, on_start, on_part) -> None:
    """In front of viser's upload handlers of `server` (shared GUI): on_start(client_id, transfer_id,
    filename, size_bytes, part_count) and on_part(client_id, transfer_id, nbytes, part_index) return True to let viser
    have the message. A refused start is never seen by viser (its parts are then ignored: viser
    drops parts of unknown transfers); a refused part drops the transfer and what viser buffered
    of it. Both run in viser's event loop: keep them short. Idempotent per server."""
    from viser import _messages

    handlers = _upload_handlers(server)
    if getattr(server, "_lab_uploads_guarded", False):
        return
    _guard(handlers, _messages.FileTransferStartUpload,
           lambda cid, m: on_start(cid, m.transfer_uuid, m.filename, int(m.size_bytes), int(m.part_count)))

    def allow_part(cid, m):
        if on_part(cid, m.transfer_uuid, len(m.content), int(m.part_index)):
            return True
        drop_upload(server, m.transfer_uuid)
        return False

    _guard(handlers, _messages.FileTransferPart, allow_part)
    server._lab_uploads_guarded = True


def _guard(handlers: dict, message_cls, allow) -> None:
    """Replace viser's handlers of message_cls with one that calls them only when
    allow(client_id, message) is true."""
    originals = tuple(handlers[message_cls])
    if any(inspect.iscoroutinefunction(cb) for cb in originals):
        async def handler(client_id, message):
            if allow(client_id, message):
                for cb in originals:
                    out = cb(client_id, message)
                    if inspect.isawaitable(out):
                        await out
    else:
        def handler(client_id, message):
            if allow(client_id, message):
                for cb in originals:
                    cb(client_id, message)
    handlers[message_cls] = [handler]


def _upload_handlers(server) -> dict:
    missing = upload_api_missing(server)
    if missing:
        raise ViserChanged(f"viser changed: {', '.join(missing)} missing; uploads cannot be guarded")
    return server._websock_server._incoming_handlers


def upload_api_missing(server) -> list[str]:
    """What of the private API the upload guard uses this viser server lacks (empty: all there)."""
    missing = []
    try:
        from viser import _messages

        _messages.FileTransferStartUpload, _messages.FileTransferPart  # noqa: B018
    except (ImportError, AttributeError):
        return ["viser._messages.FileTransferStartUpload / FileTransferPart"]
    handlers = getattr(getattr(server, "_websock_server", None), "_incoming_handlers", None)
    if not isinstance(handlers, dict):
        missing.append("WebsockServer._incoming_handlers")
    elif not getattr(server, "_lab_uploads_guarded", False):
        for cls in (_messages.FileTransferStartUpload, _messages.FileTransferPart):
            if not handlers.get(cls):
                missing.append(f"a handler of {cls.__name__}")
    if not isinstance(getattr(getattr(server, "gui", None), "_current_file_upload_states", None), dict):
        missing.append("GuiApi._current_file_upload_states")
    return missing


def drop_upload(server, transfer_id: str) -> None:
    """Forget an unfinished upload and the parts viser has buffered of it (later parts are ignored)."""
    server.gui._current_file_upload_states.pop(transfer_id, None)


def buffered_uploads(server) -> dict[str, int]:
    """transfer id -> bytes viser holds in memory, of every unfinished upload."""
    states = dict(server.gui._current_file_upload_states)
    return {k: sum(len(p) for p in dict(v.get("parts", {})).values()) for k, v in states.items()}


def forget_upload_value(handle) -> None:
    """Let go of the last uploaded file, which viser keeps in the upload button's value."""
    impl = handle._impl
    impl.value = type(impl.value)(name="", content=b"")


def check(handle) -> list[str]:
    """What of the private API used here this viser lacks (empty: all there), for a scene handle."""
    missing = []
    if SetPositionMessage is None or SetOrientationMessage is None:
        missing.append("viser._messages.SetPositionMessage / SetOrientationMessage")
    impl = getattr(handle, "_impl", None)
    if impl is None:
        missing.append("SceneNodeHandle._impl")
    else:
        for name in ("removed", "name", "position", "wxyz"):
            if not hasattr(impl, name):
                missing.append(f"SceneNodeHandle._impl.{name}")
        if getattr(getattr(impl, "api", None), "_queue_scene_message", None) is None:
            missing.append("SceneApi._queue_scene_message")
    return missing


def client_host(client) -> str | None:
    """The Host header a tab (viser.ClientHandle) connected with: the address its browser reached this
    server at (None when the tab has gone). Same reach as client_query (ViserChanged when it is gone)."""
    server = getattr(client, "_viser_server", None)
    missing = query_api_missing(server)
    if missing:
        raise ViserChanged(f"viser changed: {', '.join(missing)} missing; a tab's address cannot be read")
    connection = server._websock_server._live_connections.get(client.client_id)
    headers = getattr(getattr(connection, "request", None), "headers", None)
    return headers.get("Host") if headers is not None else None


# ---------------------------------------------------------------------- the page
# viser 1.1.1 serves its client as one file, viser/client/build/index.html, from the folder that
# ViserServer passes to viser.infra.WebsockServer.__init__ as `http_server_root` (its serving thread
# reads `self._http_server_root` once, as it starts). Until a tab's websocket is open and the server's
# GUI has arrived, that page shows viser's own tool panel ("Inactive", the websocket's URL, Save
# Canvas, Reset View, the scene tree): 1-2 s on a 2-core machine, before the lab's panel replaces it.
# There is no public way to add to the page: install_page_head makes every WebsockServer created from
# then on serve a copy of that folder whose index.html has `head` first in its <head>.
_page = {"head": None, "dirs": {}}


def install_page_head(head: str) -> None:
    """Serve viser's page with `head` (HTML: a <style>, a <script>) at the start of its <head>, from every
    viser server created from now on (call it before creating the ViserServer; a later call replaces
    the head for servers created after it). ViserChanged, naming it, when WebsockServer is not there."""
    try:
        from viser.infra import WebsockServer
    except ImportError as e:
        raise ViserChanged(f"viser changed: viser.infra.WebsockServer missing ({e})") from e
    if getattr(WebsockServer, "_lab_page_head", False):  # installed (its __init__ is ours: no signature)
        _page["head"] = head
        return
    if "http_server_root" not in inspect.signature(WebsockServer.__init__).parameters:
        raise ViserChanged("viser changed: WebsockServer.__init__ takes no http_server_root")
    _page["head"] = head
    original = WebsockServer.__init__

    def __init__(self, *args, **kwargs):
        original(self, *args, **kwargs)
        root = getattr(self, "_http_server_root", None)
        if root is not None and _page["head"]:
            self._http_server_root = page_folder(root, _page["head"])

    WebsockServer.__init__ = __init__
    WebsockServer._lab_page_head = True


def page_folder(root, head: str):
    """A folder (made once per root and head, removed at exit) that serves what `root` serves, its
    index.html with `head` just after "<head>"; `root` itself when its index.html has no <head>."""
    import atexit
    import shutil
    import tempfile
    from pathlib import Path

    root = Path(root)
    key = (str(root), head)
    if key in _page["dirs"]:
        return _page["dirs"][key]
    page = root / "index.html"
    text = page.read_text(encoding="utf-8") if page.is_file() else ""
    if "<head>" not in text:
        logging.getLogger("app.viser").warning("viser's page %s has no <head>: served as it is", page)
        _page["dirs"][key] = root
        return root
    folder = Path(tempfile.mkdtemp(prefix="lab-page-"))
    atexit.register(shutil.rmtree, folder, True)
    for entry in root.iterdir():
        if entry.name != "index.html":
            (folder / entry.name).symlink_to(entry.resolve())
    (folder / "index.html").write_text(text.replace("<head>", "<head>" + head, 1), encoding="utf-8")
    _page["dirs"][key] = folder
    return folder
