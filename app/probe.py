"""A headless viser client for tests and benchmarks: speaks the websocket protocol, draws nothing.

    probe = Probe(app.url).start()     # connects and sends a camera, so the server sees a tab
    probe.wait_for(lambda m: m["type"] == "TransformControlsMessage")
    seconds = probe.drag("/tab/goal0/marker", (10.0, 5.0, 0.0))   # until the arm's new pose arrives
    probe.close()

Server -> client frames are [8 B msgpack size][8 B zstd size][zstd msgpack][binary buffers]
(viser/infra/_infra.py); client -> server messages are plain msgpack (`encode`).
"""

from __future__ import annotations

import asyncio
import threading
import time

import msgspec
import viser
import zstandard
from viser import _messages
from websockets.asyncio.client import connect


def decode(raw: bytes) -> list[dict]:
    """The messages of one server frame (binary arrays left as placeholders)."""
    n_inner = int.from_bytes(raw[:8], "little")
    n_comp = int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + n_comp], max_output_size=n_inner)
    return msgspec.msgpack.decode(inner)["messages"]


def encode(message) -> bytes:
    """A client -> server message (msgpack of its serializable dict, as the browser sends)."""
    return msgspec.msgpack.encode(message.as_serializable_dict())


class Probe:
    def __init__(self, url: str, width: int = 1280, height: int = 800, loop: asyncio.AbstractEventLoop | None = None):
        """loop: an event loop running in another thread, shared by many probes (benchmarks: one
        thread for a hall of tabs); by default the probe runs its own loop in its own thread."""
        self.url = url.replace("http://", "ws://").replace("https://", "wss://")
        self.size = (width, height)
        self.messages: list[tuple[float, dict]] = []  # (arrival time, message)
        self.frames = 0  # frames received
        self.decoding = True  # False (`drain`): frames are read and counted, not decoded nor kept
        self._cond = threading.Condition()
        self._own = loop is None
        self._loop = asyncio.new_event_loop() if loop is None else loop
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="viser-probe")
        self._ws = None
        self._closed = False

    def start(self, timeout: float = 20.0) -> "Probe":
        if self._own:
            self._thread.start()
        asyncio.run_coroutine_threadsafe(self._connect(), self._loop).result(timeout)
        return self

    async def _connect(self) -> None:
        self._ws = await connect(self.url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None,
                                 compression=None)
        w, h = self.size
        await self._ws.send(encode(_messages.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -3.0, 2.0), fov=1.0, near=0.01, far=1000.0,
            image_height=h, image_width=w, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0))))
        self._loop.create_task(self._read())

    async def _read(self) -> None:
        try:
            async for raw in self._ws:
                t = time.perf_counter()
                self.frames += 1
                if not self.decoding:
                    continue
                msgs = decode(raw)
                with self._cond:
                    self.messages.extend((t, m) for m in msgs)
                    self._cond.notify_all()
        except Exception:  # closed
            pass

    def drain(self) -> "Probe":
        """From now on read the server's frames without decoding or keeping them: a tab that only
        watches, as a browser on another machine would cost this one nothing (benchmarks)."""
        self.decoding = False
        with self._cond:
            self.messages.clear()
        return self

    def send(self, message) -> None:
        asyncio.run_coroutine_threadsafe(self._ws.send(encode(message)), self._loop).result(10)

    def wait_for(self, predicate, timeout: float = 20.0, since: int = 0) -> dict:
        """The first message (from index `since`) for which predicate(message) holds."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for _t, m in self.messages[since:]:
                    if predicate(m):
                        return m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError("no such message from the server")
                self._cond.wait(left)

    def owner(self, name: str) -> str:
        """The owner stamp of a scene node this tab has (its client id for per-tab nodes)."""
        return self.wait_for(lambda m: m.get("name") == name and "owner" in m).get("owner", "")

    def drag(self, name: str, position, timeout: float = 10.0, pose_prefix: str | None = None,
             wxyz=(1.0, 0.0, 0.0, 0.0)) -> float:
        """Move (and turn, by the quaternion wxyz) a transform gizmo; seconds until the server's first
        pose message under pose_prefix."""
        prefix = pose_prefix or name.rsplit("/", 1)[0] + "/arm/"
        owner = self.owner(name)
        with self._cond:
            since = len(self.messages)
        t0 = time.perf_counter()
        self.send(_messages.TransformControlsUpdateMessage(
            name=name, wxyz=tuple(float(v) for v in wxyz), position=tuple(float(v) for v in position), owner=owner))
        self.wait_for(lambda m: m["type"] in ("SetPositionMessage", "SetOrientationMessage")
                      and m["name"].startswith(prefix), timeout, since)
        with self._cond:
            arrived = next(t for t, m in self.messages[since:] if m.get("name", "").startswith(prefix))
        return arrived - t0

    def click(self, label: str, timeout: float = 20.0) -> None:
        """Press the GUI button with this label, as a browser does (its value set to True)."""
        msg = self.wait_for(lambda m: m["type"] == "GuiButtonMessage" and m["props"]["label"] == label, timeout)
        self.send(_messages.GuiUpdateMessage(uuid=msg["uuid"], updates={"value": True}))

    def close(self) -> None:
        """Close the socket (the server sees the tab go) and stop the client's loop; idempotent."""
        if self._closed or not self._loop.is_running():
            return
        self._closed = True
        if self._ws is not None:
            asyncio.run_coroutine_threadsafe(self._ws.close(), self._loop).result(10)
        if self._own:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5)
