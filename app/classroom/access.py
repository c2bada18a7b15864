"""Presenter and viewers: who may change what every tab shares.

viser has no authentication, so the lab makes its own. The server makes a random token at start
and prints a presenter link holding it (as Jupyter does); the token travels in the query of the
websocket URL (viser's own `?websocket=` page parameter, app/viser_private.py: websocket_link,
connection_query). A tab that connected with it is a presenter; every other tab is a viewer.

The one gate: every element of the shared GUI (server.gui: the training panel, its Start,
Pause, Resume, Stop, Reset, the robot, method and settings, the runs list and replay, uploads, and
any control added there later) is a shared control. A viewer's change of one is dropped before viser
applies it (viser_private.guard_shared_gui; uploads are refused as they start, app/classroom/uploads.py);
programmatic calls on the server are not affected. Viewers see the shared controls disabled
(`sync_viewers`, per tab) and a line saying the presenter controls the run; their own goal markers
and IK ghosts (client.gui, per tab) stay theirs. A new shared control needs nothing more than being
created in server.gui; a per-tab control belongs in client.gui.

Who is restricted: beyond loopback (any --host that is not 127.0.0.1, ::1, localhost) only
presenters; on loopback every tab is a presenter unless a presenter token is given; `open=True`
(`--open`) lifts the restriction on purpose. Tokens are compared in constant time
(hmac.compare_digest), never logged, never written to the notebook or recordings.

Wrong tries (as Jupyter, whose login handler logs each failed login with the client's address and
never the token; Jupyter has no lockout, the lab adds one): every tab that connects with a wrong
token is logged with its address; after MAX_WRONG (5) wrong tries from one address within
WRONG_WINDOW (60 s) further tabs from that address are viewers without their token being compared
(logged once per lockout) until the window has passed. A token given by the user must be at least
MIN_TOKEN (16) characters (`token_problem`, checked by `python -m app` at startup; a random one is
24 bytes, 32 characters, as Jupyter's is 24 random bytes).
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import secrets
import threading
import time

from app import viser_private

log = logging.getLogger(__name__)
MIN_TOKEN = 16  # characters of a presenter token the user gives
MAX_WRONG, WRONG_WINDOW = 5, 60.0  # wrong tries per address in this many seconds, then no comparison

VIEWER_LINE = ("**Viewer.** The presenter controls the run and the shared settings; your goal markers, "
               "IK ghosts and camera are your own.")
REFUSED = "refused: the presenter controls the run (this tab is a viewer)"
RESEND = (0.5, 2.0, 5.0)  # s after a viewer connects: its disabled controls are sent again (viser may
# deliver our per-tab update before the shared element's creation, which the browser then drops)


def is_loopback(host: str) -> bool:
    if host in ("localhost", "ip6-localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def token_problem(token: str) -> str | None:
    """Why a presenter token the user gave is not accepted (None: it is)."""
    if not token or not viser_private.SAFE_VALUE.fullmatch(token):
        return "the presenter token must be letters, digits and . _ ~ - only"
    if len(token) < MIN_TOKEN:
        return (f"the presenter token is {len(token)} characters; at least {MIN_TOKEN} are needed "
                f"(a short one is guessed in seconds); leave it out for a random one")
    return None


class Access:
    def __init__(self, host: str, token: str | None = None, open: bool = False,  # noqa: A002
                 clock=time.monotonic):
        """token: the presenter token (None: a random one where one is needed). Any length is
        accepted here (tests); `python -m app` refuses a short one (token_problem)."""
        if token is not None and (not token or not viser_private.SAFE_VALUE.fullmatch(token)):
            raise ValueError("the presenter token must be letters, digits and . _ ~ - only")
        self.restricted = not open and (token is not None or not is_loopback(host))
        self.token = (token or secrets.token_urlsafe(24)) if self.restricted else None
        self._roles: dict[int, bool] = {}  # client id -> presenter?
        self._viewers: dict[int, dict] = {}  # client id -> {client, since, applied}
        self._wrong: dict[str, list] = {}  # address -> times of its recent wrong tries
        self._locked_told: dict[str, float] = {}  # address -> when its lockout was logged
        self.clock = clock
        self._lock = threading.Lock()
        self.server = None

    def __repr__(self) -> str:  # never shows the token
        return f"Access(restricted={self.restricted})"

    def link(self, page_url: str) -> str:
        """The presenter link for page_url (the plain URL when nothing is restricted)."""
        if not self.restricted:
            return page_url
        return viser_private.websocket_link(page_url, token=self.token)

    # ------------------------------------------------------------------ roles
    def is_presenter(self, client_id: int) -> bool:
        if not self.restricted:
            return True
        with self._lock:
            role = self._roles.get(client_id)
        if role is None:
            try:
                query = viser_private.connection_query(self.server, client_id)
                address = viser_private.connection_address(self.server, client_id)
            except viser_private.ViserChanged:  # fail closed: a viewer
                query, address = {}, None
            role = self._try(client_id, address, (query or {}).get("token", "")) if query is not None else False
            if query is not None:  # a tab that has gone is not remembered
                with self._lock:
                    self._roles[client_id] = role
        return role

    def _try(self, client_id: int, address: str | None, given: str) -> bool:
        """Whether `given` is the token, for a tab from `address`: a wrong one is logged (address,
        never the token) and counted; an address with MAX_WRONG wrong tries in WRONG_WINDOW is not
        compared at all (its tabs are viewers; logged once per lockout)."""
        if not given:  # no token: an ordinary viewer, not a try
            return False
        where = address or "unknown address"
        now = self.clock()
        with self._lock:
            tries = self._wrong.setdefault(where, [])
            tries[:] = [t for t in tries if now - t < WRONG_WINDOW]
            locked = len(tries) >= MAX_WRONG
            tell = locked and now - self._locked_told.get(where, -WRONG_WINDOW) >= WRONG_WINDOW
            if tell:
                self._locked_told[where] = now
        if locked:
            if tell:
                log.warning("presenter token: %d wrong tries from %s within %g s; its tabs are viewers without "
                            "their token being compared until %g s after the last wrong try", MAX_WRONG, where,
                            WRONG_WINDOW, WRONG_WINDOW)
            return False
        if hmac.compare_digest(given.encode(), self.token.encode()):
            return True
        with self._lock:
            tries.append(now)
            n = len(tries)
        log.warning("presenter token: wrong token from %s (tab %s; %d of %d wrong tries allowed in %g s)",
                    where, client_id, n, MAX_WRONG, WRONG_WINDOW)
        return False

    def refusal(self, client_id: int) -> str | None:
        """None when this tab may change shared state, else the reason."""
        return None if self.is_presenter(client_id) else REFUSED

    # ------------------------------------------------------------------ the gate
    def install(self, server, notify=None) -> None:
        """Guard server's shared GUI: a viewer's change is dropped, its tab told (notify(client_id,
        text)) and its widget put back to the server's value."""
        self.server = server

        def refused(client_id: int, uuid: str) -> None:
            handle = viser_private.shared_inputs(server).get(uuid)
            client = server.get_clients().get(client_id)
            if client is not None and handle is not None and not getattr(handle._impl, "is_button", False):
                viser_private.send_gui_props(client, uuid, value=handle.value)
            if notify is not None:
                notify(client_id, REFUSED)

        viser_private.guard_shared_gui(server, self.is_presenter, refused)

    def connected(self, client) -> bool:
        """A tab connected: a viewer gets its line and its shared controls disabled. Returns whether it
        is a presenter."""
        if self.is_presenter(client.client_id):
            return True
        client.gui.add_markdown(VIEWER_LINE, order=-1)
        with self._lock:
            self._viewers[client.client_id] = dict(client=client, since=time.monotonic(), applied=None, sent=0)
        self._apply(client.client_id)
        return False

    def disconnected(self, client_id: int) -> None:
        with self._lock:
            self._roles.pop(client_id, None)
            self._viewers.pop(client_id, None)

    def sync_viewers(self) -> None:
        """Viewers' shared controls shown disabled: sent again when the shared GUI changed (an element
        added, or its disabled flag changed for everyone) and a few times after a viewer connected
        (called by the render loop)."""
        if self.server is None:
            return
        with self._lock:
            ids = list(self._viewers)
        if ids:
            state = self._shared_state()
            for cid in ids:
                self._apply(cid, state)

    def _shared_state(self):
        return frozenset((u, bool(getattr(h, "disabled", False))) for u, h in viser_private.shared_inputs(self.server).items())

    def _apply(self, client_id: int, state=None) -> None:
        state = self._shared_state() if state is None else state
        with self._lock:
            v = self._viewers.get(client_id)
            if v is None:
                return
            age = time.monotonic() - v["since"]
            due = v["sent"] < len(RESEND) and age >= RESEND[v["sent"]]
            if v["applied"] == state and not due:
                return
            v["applied"] = state
            if due:
                v["sent"] += 1
            client = v["client"]
        try:
            with client.atomic():
                for uuid, _disabled in state:
                    viser_private.send_gui_props(client, uuid, disabled=True)
        except Exception:  # noqa: BLE001 - the tab has just gone
            pass
