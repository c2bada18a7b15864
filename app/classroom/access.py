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
never the token, and has no lockout): the token a tab gives is always compared, and the right one
always makes a presenter, however many wrong ones came before from its address. A class behind one
NAT, or students on the teacher's own machine, share the teacher's address: a lockout by address
(which the lab had) let any of them keep the teacher from the controls by a few wrong tries a
minute. Only failures are counted, per address: the first MAX_WRONG (5) within WRONG_WINDOW (60 s)
are logged one line each with the address; beyond that, one line per address per WRONG_WINDOW with
the count of the others, so guessing cannot fill the log. A wrong try gives a viewer, nothing more.
What makes guessing hopeless is the token's length, not a limit: a token given by the user must be
at least MIN_TOKEN (16) characters (`token_problem`, checked by `python -m app` at startup; 16 of
the 66 allowed characters are about 96 bits: 10^15 years at a million tries a second), a random one
is 24 bytes, 32 characters, as Jupyter's is 24 random bytes.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import secrets
import threading
import time

from app import viser_private
from app.classroom.files import FileRefused, read_small

log = logging.getLogger(__name__)
MIN_TOKEN = 16  # characters of a presenter token the user gives
MAX_TOKEN_FILE = 4096  # bytes of a token file read at most (a larger file is refused, not read)
MAX_WRONG, WRONG_WINDOW = 5, 60.0  # wrong tries per address logged one by one in this many seconds, then summed

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


def read_token_file(path: str) -> str:
    """The presenter token in a token file: its first line, stripped. The file is read for at most
    MAX_TOKEN_FILE bytes; ValueError, its message naming the path and why (a pipe, a device, a
    folder, a larger file: refused before anything blocks, app/classroom/files.py; missing, no
    permission, not UTF-8)."""
    try:
        data = read_small(path, MAX_TOKEN_FILE)
    except FileRefused as e:
        raise ValueError(f"{e} (a token file holds one line)") from None
    except OSError as e:
        raise ValueError(f"{path}: {e.strerror or e}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    return text.split("\n", 1)[0].strip()


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
        self._quiet: dict[str, list] = {}  # address -> [when its last summary line was logged, tries not logged since]
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
        """Whether `given` is the token (compared in constant time, always: the right one is never
        refused), for a tab from `address`. A wrong one is counted and logged by address, never the
        token: one line each for the first MAX_WRONG in WRONG_WINDOW, then one line per WRONG_WINDOW
        with the count of the others."""
        if not given:  # no token: an ordinary viewer, not a try
            return False
        if hmac.compare_digest(given.encode(), self.token.encode()):
            return True
        where = address or "unknown address"
        now = self.clock()
        with self._lock:
            if len(self._wrong) > 10_000:  # addresses come and go: forget those quiet for a window
                for key in [k for k, t in self._wrong.items() if not t or now - t[-1] >= WRONG_WINDOW]:
                    self._wrong.pop(key, None)
                    self._quiet.pop(key, None)
            tries = self._wrong.setdefault(where, [])
            tries[:] = [t for t in tries if now - t < WRONG_WINDOW][-MAX_WRONG:]
            tries.append(now)
            n = len(tries)
            told = self._quiet.setdefault(where, [None, 0])  # [time of its last summary line, tries not logged]
            if n > MAX_WRONG and told[0] is not None and now - told[0] < WRONG_WINDOW:
                told[1] += 1
                return False
            quiet, told[1] = told[1], 0
            if n > MAX_WRONG:
                told[0] = now
        more = f"; {quiet} more not logged since the last line" if quiet else ""
        if n <= MAX_WRONG:
            log.warning("presenter token: wrong token from %s (tab %s; wrong try %d in %g s from there%s)",
                        where, client_id, n, WRONG_WINDOW, more)
        else:
            log.warning("presenter token: wrong token from %s (tab %s): more than %d wrong tries in %g s from there%s; "
                        "further ones are logged at most once a minute with their count (the right token still "
                        "makes a presenter)", where, client_id, MAX_WRONG, WRONG_WINDOW, more)
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
