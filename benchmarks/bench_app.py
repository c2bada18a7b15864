"""Responsiveness of the app while it trains (issue 6, point 9).

    python benchmarks/bench_app.py                  # 10 tabs, one dragging; 2 rounds of 8 s each
    python benchmarks/bench_app.py --clients 10 --dragging 10 --hz 10   # every tab drags

Two numbers, measured side by side in alternating rounds (headless, app, headless, app, ...):

1. Marker update -> pose sent, with `--clients` tabs connected while a run trains. Every tab
   is a headless websocket client (app/probe.py) in a separate process; `--dragging` of them
   drag their own goal marker `--hz` times a second; for each drag it times from sending the update to receiving
   the arm's new pose (loopback round trip: an upper bound of the server-side time), and the
   server records, in the marker callback, the time from its start to the pose being flushed
   to the socket (a lower bound). Target: p95 <= 5 ms.
2. Training throughput (evaluations per second over the same window) with the app serving
   those tabs, over headless training (the same lab Runner, nothing else running; each with
   the GIL switch interval it runs with: Python's default 5 ms headless, the app's 1 ms).
   Target: >= 80 %.

The clients share the machine's cores with the server (a classroom's browsers would not), so
both numbers are pessimistic. No Rerun recording in either case.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import lab  # noqa: E402

CONFIG = dict(robot="planar", method="cmaes", generations=10**7, population=50, seed=0)


class Meter:
    """Runner subscriber: (time, evaluations) of each generation."""

    def __init__(self):
        self.points = []

    def __call__(self, event):
        self.points.append((time.perf_counter(), event.evaluations))

    def rate(self, t0: float, t1: float) -> float:
        pts = [(t, e) for t, e in self.points if t0 <= t <= t1]
        return (pts[-1][1] - pts[0][1]) / (pts[-1][0] - pts[0][0]) if len(pts) > 1 else float("nan")


def headless(seconds: float) -> float:
    sys.setswitchinterval(0.005)
    runner, meter = lab.Runner(lab.TrainConfig.preset(**CONFIG)), Meter()
    runner.subscribe(meter)
    runner.start()
    time.sleep(1.0)  # warm-up
    t0 = time.perf_counter()
    time.sleep(seconds)
    t1 = time.perf_counter()
    runner.stop()
    return meter.rate(t0, t1)


def with_app(app, clients: int, dragging: int, seconds: float, hz: float) -> dict:
    from app.server import SWITCH_INTERVAL

    sys.setswitchinterval(SWITCH_INTERVAL)
    meter = Meter()
    proc = subprocess.Popen([sys.executable, __file__, "--serve-clients", app.url, str(clients), str(dragging),
                             str(seconds), str(hz)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "connected"
    deadline = time.monotonic() + 30
    while len(app.sessions) < clients and time.monotonic() < deadline:
        time.sleep(0.05)
    assert app.state.start(lab.TrainConfig.preset(**CONFIG)) is None
    app.state.runner.subscribe(meter)
    time.sleep(1.0)  # warm-up: training and the redraws it causes
    app.latency.clear()
    t0 = time.perf_counter()
    out = json.loads(proc.communicate(timeout=seconds + 60)[0].strip().splitlines()[-1])
    t1 = time.perf_counter()
    server = list(app.latency)
    app.state.stop()
    app.state.reset()
    return dict(rate=meter.rate(t0, t1), rtt=out["rtt"], server=server)


def serve_clients(url: str, clients: int, dragging: int, seconds: float, hz: float) -> None:
    """The client process: `clients` tabs, the first `dragging` of them dragging their marker `hz`
    times a second (the others only receive what the server sends)."""
    from app.probe import Probe

    probes = [Probe(url).start() for _ in range(clients)]
    for p in probes:
        p.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
    print("connected", flush=True)
    time.sleep(1.0)  # the server's warm-up
    rtts: list[float] = []
    lock = threading.Lock()

    def drag(k: int, probe) -> None:
        rng = np.random.default_rng(k)
        end, period = time.perf_counter() + seconds, 1.0 / hz
        while time.perf_counter() < end:
            t = time.perf_counter()
            goal = (rng.uniform(-5, 20), rng.uniform(-15, 20), 0.0)
            dt = probe.drag("/tab/goal0/marker", goal)
            with lock:
                rtts.append(dt)
            time.sleep(max(0.0, period - (time.perf_counter() - t)))

    threads = [threading.Thread(target=drag, args=(k, p)) for k, p in enumerate(probes[:dragging])]
    for t in threads:
        t.start()
    time.sleep(seconds)
    for t in threads:
        t.join()
    for p in probes:
        p.close()
    print(json.dumps({"rtt": rtts}), flush=True)


def pct(x, q) -> float:
    return 1e3 * float(np.percentile(x, q)) if len(x) else float("nan")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--serve-clients":
        serve_clients(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6]))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--dragging", type=int, default=1, help="how many of the tabs drag their marker")
    ap.add_argument("--hz", type=float, default=30.0, help="marker updates per second per dragging tab")
    args = ap.parse_args()
    from app.server import LabApp

    folder = tempfile.mkdtemp(prefix="bench-app-")
    app = LabApp(port=0, notebook=os.path.join(folder, "notebook.json"), recordings=folder, record=False)
    heads, apps = [], []
    load = os.getloadavg()
    try:
        for r in range(args.rounds):
            heads.append(headless(args.seconds))
            apps.append(with_app(app, args.clients, args.dragging, args.seconds, args.hz))
            a = apps[-1]
            print(f"round {r + 1}: headless {heads[-1]:,.0f} eval/s, app {a['rate']:,.0f} eval/s "
                  f"({len(a['rtt'])} drags)", flush=True)
    finally:
        app.stop()
    rtt = [x for a in apps for x in a["rtt"]]
    server = [x for a in apps for x in a["server"]]
    ratio = np.mean([a["rate"] for a in apps]) / np.mean(heads)
    pairs = [a["rate"] / h for a, h in zip(apps, heads)]
    print(f"\n{args.clients} tabs connected, {args.dragging} dragging at {args.hz:g} Hz, while planar CMA-ES "
          f"(population 50) trains, "
          f"{args.rounds} x {args.seconds:g} s, {os.cpu_count()} cores, load average before {load[0]:.1f}, "
          f"after {os.getloadavg()[0]:.1f}")
    print(f"marker -> pose, loopback round trip: p50 {pct(rtt, 50):.2f} ms, p95 {pct(rtt, 95):.2f} ms, "
          f"max {pct(rtt, 100):.1f} ms ({len(rtt)} drags)")
    print(f"marker -> pose, in the server callback: p50 {pct(server, 50):.2f} ms, p95 {pct(server, 95):.2f} ms")
    print(f"training throughput with the app: {100 * ratio:.0f} % of headless "
          f"({np.mean([a['rate'] for a in apps]):,.0f} vs {np.mean(heads):,.0f} evaluations/s; "
          f"round by round {', '.join(f'{100 * p:.0f}' for p in pairs)} %)")


if __name__ == "__main__":
    main()
