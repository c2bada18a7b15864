"""Whether the Ray cluster that runs go to still answers: a cheap probe, never in the caller's way.

    from lab.running.ray_watch import WATCH
    WATCH.lost()      # None while the cluster answers, else why not, naming it (never blocks)
    WATCH.check()     # the same, probed now (blocks up to PROBE_TIMEOUT s)
    WATCH.where()     # "the Ray cluster at HOST:PORT" / "the local Ray instance at HOST:PORT (its GCS)"

A Ray node can go while this process lives on: its raylet killed (the OOM killer's usual victim),
its machine gone. Ray then keeps a new actor pending for good, waiting for a CPU no node offers, and
says nothing. The probe asks the cluster's GCS for its nodes (`ray.nodes()`, under a
millisecond) and knocks on the port of the raylet this process joined through (a TCP connect: a
killed raylet refuses at once, where the GCS takes ~15 s of missed heartbeats to mark its node
dead). The cluster is lost when the GCS does not answer within PROBE_TIMEOUT s, when this process's
own node is dead or its raylet refuses, or when no live node has a CPU. lost() runs the probe in a
thread of its own, at most every PROBE_PERIOD s however often it is asked (a render loop may ask
every pass), and returns the last answer; a change is logged once (a warning when lost, when it
answers again). Ray is imported only when a probe runs; nothing here starts or ends Ray.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

log = logging.getLogger(__name__)

PROBE_PERIOD = 5.0  # s: at most one probe this often
PROBE_TIMEOUT = 10.0  # s: a probe (the GCS's answer) not back by then: the cluster is lost
KNOCK_TIMEOUT = 2.0  # s: the TCP connect to this process's raylet


def _first_line(e: BaseException, most: int = 200) -> str:
    text = " ".join(str(e).strip().splitlines()[:1]) or type(e).__name__
    return text if len(text) <= most else text[:most - 3] + "..."


class ClusterWatch:
    def __init__(self, address: str | None = None, period: float = PROBE_PERIOD, timeout: float = PROBE_TIMEOUT):
        """address: as given to ray_runner.connect ("local", "HOST:PORT"; None: whatever ray.init joined)."""
        self.address, self.period, self.timeout = address, period, timeout
        self._lock = threading.Lock()
        self._lost: str | None = None
        self._gcs: str | None = None  # the GCS address the answer is about (a new ray.init: a new cluster)
        self._last = -float("inf")  # monotonic time of the last probe's start
        self._probing: threading.Thread | None = None

    def joined(self, address: str | None) -> None:
        """This process has joined a cluster (ray_runner.connect): forget what was said of any other."""
        with self._lock:
            self.address, self._lost, self._gcs, self._last = address, None, None, -float("inf")

    def where(self) -> str:
        """The cluster in words, with its address."""
        gcs = self._gcs_address()
        if self.address not in (None, "local", "auto"):
            return f"the Ray cluster at {self.address}"
        if self.address == "local":
            return f"the local Ray instance at {gcs or '?'}"
        return f"the Ray cluster at {gcs or '?'}"

    @staticmethod
    def _gcs_address() -> str | None:
        try:
            import ray

            return ray.get_runtime_context().gcs_address if ray.is_initialized() else None
        except Exception:  # noqa: BLE001 - not joined, or gone
            return None

    def lost(self) -> str | None:
        """None while the cluster answers (as last probed), else why not, naming it. Never blocks: a
        probe starts in a thread of its own when the last began PROBE_PERIOD s ago or more; one not
        back after PROBE_TIMEOUT s counts as an answer "lost"."""
        now = time.monotonic()
        with self._lock:
            probing = self._probing is not None and self._probing.is_alive()
            if probing and now - self._last > self.timeout:
                self._set(f"{self.where()} is lost: its GCS has not answered for {self.timeout:g} s")
            elif not probing and now - self._last >= self.period:
                self._last = now
                self._probing = threading.Thread(target=self._probe_and_set, name="lab-ray-watch", daemon=True)
                self._probing.start()
            return self._lost if self._gcs in (None, self._gcs_address()) else None

    def check(self) -> str | None:
        """Probe now (blocks while the GCS answers); the answer as lost()'s."""
        with self._lock:
            self._last = time.monotonic()
        self._probe_and_set()
        with self._lock:
            return self._lost

    def _probe_and_set(self) -> None:
        gcs = self._gcs_address()
        why = self._probe()
        with self._lock:
            self._gcs = gcs
            self._set(why)

    def _set(self, why: str | None) -> None:
        """The answer (under the lock), logged when it changes."""
        if why == self._lost:
            return
        if why is not None:
            log.warning("%s; runs waiting for a CPU there give up, new ones fail at once, until it answers again", why)
        else:
            log.warning("%s answers again: runs go to it again", self.where())
        self._lost = why

    def _probe(self) -> str | None:
        try:
            import ray

            if not ray.is_initialized():
                return f"{self.where()} is lost: this process is not joined to it (ray.shutdown?)"
            nodes = ray.nodes()
            mine = ray.get_runtime_context().get_node_id()
        except Exception as e:  # noqa: BLE001 - the GCS gone, Ray shut down under us
            return f"{self.where()} is lost: its GCS does not answer ({_first_line(e)})"
        alive = [n for n in nodes if n.get("Alive")]
        node = next((n for n in nodes if n.get("NodeID") == mine), None)
        if node is not None and not node.get("Alive"):
            reason = node.get("DeathReasonMessage") or "marked dead"
            return (f"{self.where()} is lost: the Ray node this server joined through ({mine[:8]}) is dead: "
                    f"{_first_line(Exception(reason), 160)}")
        if node is not None:
            host, port = node.get("NodeManagerAddress"), node.get("NodeManagerPort")
            if host and port:
                try:
                    socket.create_connection((host, int(port)), timeout=KNOCK_TIMEOUT).close()
                except OSError as e:
                    return (f"{self.where()} is lost: the raylet of the node this server joined through "
                            f"({host}:{port}) does not answer ({e.strerror or e}): killed, the OOM killer's usual "
                            "victim, or its machine gone")
        if not any(n.get("Resources", {}).get("CPU", 0) > 0 for n in alive):
            return f"{self.where()} is lost: no live node has a CPU ({len(nodes)} known, {len(alive)} alive)"
        return None


WATCH = ClusterWatch()  # the cluster this process's runs go to (ray_runner.connect names it)
