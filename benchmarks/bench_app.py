"""Responsiveness of the app while it trains (the results: docs/results/app-speed.md).

    python benchmarks/bench_app.py                  # 10 tabs, one dragging; 4 rounds of 6 s each
    python benchmarks/bench_app.py --clients 10 --dragging 10 --hz 10   # every tab drags
    python benchmarks/bench_app.py --no-population  # the tabs' population view off (it is on by default)
    python benchmarks/bench_app.py --robot g1       # another arm or a tree (g1: 29 joints, 4 effectors)

Two numbers, measured side by side in rounds (headless then app, app then headless, ...):

1. Marker update -> pose sent, with `--clients` tabs connected while a run trains. Every tab
   is a headless websocket client (app/probe.py) in a separate process; `--dragging` of them
   drag their own goal marker `--hz` times a second (on a tree, one effector's marker at a time, to
   reachable goals); for each drag it times from sending the update to receiving
   the arm's new pose (the loopback round trip, client decoding included), and the server
   side is timed from the update's arrival in viser's event loop (a handler placed first in
   its handler list) to the new pose being flushed to the sender, in the marker callback.
   Target: server side p95 <= 5 ms.
2. Training throughput (evaluations per second over the same window) with the app serving
   those tabs, over headless training (lab.Runner in this process's thread, as `python -m lab
   train` runs, nothing else running). The app trains in its worker process
   (lab.running.worker.ProcessRunner), started from the panel's code path (app.state.start).
   Target: >= 80 %.

Every tab shows the population view (each candidate's end-effector point at its goal,
redrawn at most 5 times a second per tab as the run sends populations, at most 10 a second) unless
--no-population; the headless run computes the same populations (lab.Runner sends them to its
subscribers) so both sides pay for them.

A lecture hall: `--clients 100 --dragging 20 --hz 10 --classroom` (the server restricted by a
presenter token, so the 100 tabs are viewers, as students' tabs are). Every mode counts the
tracebacks the server printed or logged (target: none).

    python benchmarks/bench_app.py --cycles 200     # tabs connect and disconnect 200 times, one by one:
                                                    # memory (target: within 20 MB), threads, open files
    python benchmarks/bench_app.py --soak 600       # 10 minutes of back-to-back runs with 10 tabs (one
                                                    # dragging): the memory's slope (target: flat)
    python benchmarks/bench_app.py --soak 300 --run-seconds 300   # one long run: the memory's slope

The clients share the machine's cores with the server (a classroom's browsers would not), so
both numbers are pessimistic. To keep that cost small the tabs share one event loop (one thread),
and the tabs that only watch read the server's frames without decoding them (app.probe.Probe.drain);
the client process's CPU is reported over the drag window (connecting 100 tabs is not in it), and
so are the frames a second the server sent to all tabs. No Rerun recording in either case, unless --record: then both
record (headless with lab.recording.logger.RerunLogger, as `python -m lab train` does by default; the
app with its recorder, as `make app` does).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import gc  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import lab  # noqa: E402

CONFIG = dict(robot="planar", method=lab.methods.DEFAULT_METHOD, generations=10**7, population=50, seed=0)


class Meter:
    """Runner subscriber: (wall time, the optimizer's CPU time, evaluations) per generation. The
    optimizer's CPU time: this thread's (lab.Runner calls subscribers in its training thread), or
    the worker process's (`pid`: lab.running.worker.ProcessRunner)."""

    def __init__(self, pid: int | None = None):
        self.points = []
        self.stat = f"/proc/{pid}/stat" if pid else None
        self._read = (-1.0, 0.0)  # (when, CPU seconds) of the last read of the worker's /proc entry

    def __call__(self, event):
        self.points.append((time.perf_counter(), self.cpu(), event.evaluations))

    def cpu(self) -> float:
        if self.stat is None:
            return time.thread_time()
        # read the worker's CPU time at most every 10 ms: once a generation (hundreds a second) this
        # meter took 6 % of the app's process, which it was measuring
        now = time.perf_counter()
        if now - self._read[0] < 0.01:
            return self._read[1]
        with open(self.stat) as f:
            fields = f.read().rsplit(")", 1)[1].split()
        self._read = (now, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"))  # utime + stime
        return self._read[1]

    def window(self, t0: float, t1: float):
        pts = [p for p in self.points if t0 <= p[0] <= t1]
        if len(pts) < 2:  # was an IndexError at load 15-17
            raise SystemExit(f"bench_app: the run trained {len(pts)} generation(s) in the {t1 - t0:.1f} s window "
                             "(a machine too loaded to measure on?); try a longer --seconds")
        return pts[0], pts[-1]

    def rate(self, t0: float, t1: float) -> float:
        """Evaluations per wall-clock second."""
        a, b = self.window(t0, t1)
        return (b[2] - a[2]) / (b[0] - a[0])

    def cores(self, t0: float, t1: float) -> float:
        """CPU the optimizer got, in cores (the machine's other load shows here)."""
        a, b = self.window(t0, t1)
        return (b[1] - a[1]) / (b[0] - a[0])


def headless(seconds: float, record: str | None = None) -> float:
    sys.setswitchinterval(0.005)
    runner, meter = lab.Runner(lab.TrainConfig.preset(**CONFIG)), Meter()
    logger = None
    if record:
        from lab.recording.logger import RerunLogger

        logger = RerunLogger(runner, path=record + "/")
        runner.subscribe(logger)
    runner.subscribe(meter)
    runner.start()
    time.sleep(1.0)  # warm-up
    t0 = time.perf_counter()
    time.sleep(seconds)
    t1 = time.perf_counter()
    runner.stop()
    if logger is not None:
        logger.wait()  # its compaction, before the next round
    return dict(rate=meter.rate(t0, t1), runner_cpu=meter.cores(t0, t1))


arrivals: dict = {}  # tab -> perf_counter times its marker updates reached the server


def record_arrivals(app) -> None:
    """Time each marker update as the server's event loop receives it: a handler put first in
    viser's (private) handler list for TransformControlsUpdateMessage."""
    from viser._messages import TransformControlsUpdateMessage

    def arrived(client_id, _message) -> None:
        arrivals.setdefault(client_id, []).append(time.perf_counter())

    app.server._websock_server._incoming_handlers.setdefault(TransformControlsUpdateMessage, []).insert(0, arrived)


def with_app(app, clients: int, dragging: int, seconds: float, hz: float, population: bool = True) -> dict:
    from app.server import SWITCH_INTERVAL

    sys.setswitchinterval(SWITCH_INTERVAL)
    proc = subprocess.Popen([sys.executable, __file__, "--serve-clients", app.url, str(clients), str(dragging),
                             str(seconds), str(hz), CONFIG["robot"]],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "connected"
    deadline = time.monotonic() + 30
    while len(app.sessions) < clients and time.monotonic() < deadline:
        time.sleep(0.05)
    for session in list(app.sessions.values()):
        session.show_population.value = population
    assert app.state.start(lab.TrainConfig.preset(**CONFIG)) is None
    meter = Meter(app.state.runner.pid)
    app.state.runner.subscribe(meter)
    time.sleep(1.0)  # warm-up: training and the redraws it causes
    app.latency.clear()
    arrivals.clear()
    t0, cpu0 = time.perf_counter(), time.process_time()
    out = json.loads(proc.communicate(timeout=seconds + 60)[0].strip().splitlines()[-1])
    t1, cpu1 = time.perf_counter(), time.process_time()
    server, work = [], []
    for cid, start, flushed in list(app.latency):  # pair each pose with the update that caused it
        before = [t for t in arrivals.get(cid, ()) if t <= start]
        if before:
            server.append(flushed - before[-1])
            work.append(flushed - start)
    app.state.stop()
    app.state.reset()
    time.sleep(3.0)  # the next warm worker (lab.running.worker.prestart) imports and loads its kernels: not in the next round
    if app.state.recorder is not None:
        time.sleep(3.0)  # the recording's compaction (by its writer process), before the next round
    runner_cpu = meter.cores(t0, t1)
    return dict(rate=meter.rate(t0, t1), rtt=out["rtt"], frames=out["frames"] / (t1 - t0), server=server, work=work,
                runner_cpu=runner_cpu,
                app_cpu=(cpu1 - cpu0) / (t1 - t0), client_cpu=out["cores"])


def drag_targets(robot: str, seed: int):
    """An endless stream of (marker name, 3D position) a dragging tab sends: the planar arm's goals
    drawn over its workspace and beyond, as before; another arm's or a tree's, reachable goals (on
    a tree each drag moves one effector's marker, in turn)."""
    import robots
    from app.tab.goals import marker_name

    rng = np.random.default_rng(seed)
    if robot == "planar":
        while True:
            yield marker_name(0), (rng.uniform(-5, 20), rng.uniform(-15, 20), 0.0)
    arm = robots.load(robot)
    points = arm.to_3d(arm.sample_goals(500, seed=seed)).reshape(500, -1, 3)
    k = 0
    while True:
        e = k % points.shape[1]
        yield marker_name(0, e), tuple(points[rng.integers(len(points)), e])
        k += 1


def serve_clients(url: str, clients: int, dragging: int, seconds: float, hz: float, robot: str = "planar") -> None:
    """The client process: `clients` tabs, the first `dragging` of them dragging their marker `hz`
    times a second (the others only receive what the server sends)."""
    import asyncio

    from app.probe import Probe

    # one event loop (one thread) for all the tabs: the simulated browsers' cost on this machine, which a
    # classroom's browsers do not share, kept small
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True, name="probes").start()
    probes = [Probe(url, loop=loop).start() for _ in range(clients)]
    for p in probes:
        p.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
    for p in probes[dragging:]:  # watchers: their browsers decode on the students' machines, not here
        p.drain()
    print("connected", flush=True)
    time.sleep(1.0)  # the server's warm-up
    frames0, cpu0, wall0 = sum(p.frames for p in probes), time.process_time(), time.perf_counter()
    rtts: list[float] = []
    lock = threading.Lock()

    def drag(k: int, probe) -> None:
        targets = drag_targets(robot, k)
        end, period = time.perf_counter() + seconds, 1.0 / hz
        while time.perf_counter() < end:
            t = time.perf_counter()
            name, goal = next(targets)
            dt = probe.drag(name, goal)
            with lock:
                rtts.append(dt)
            time.sleep(max(0.0, period - (time.perf_counter() - t)))

    threads = [threading.Thread(target=drag, args=(k, p)) for k, p in enumerate(probes[:dragging])]
    for t in threads:
        t.start()
    time.sleep(seconds)
    for t in threads:
        t.join()
    frames = sum(p.frames for p in probes) - frames0
    cores = (time.process_time() - cpu0) / (time.perf_counter() - wall0)  # while dragging, not connecting
    for p in probes:
        p.close()
    print(json.dumps({"rtt": rtts, "frames": frames, "cores": cores}), flush=True)


class Tracebacks(io.TextIOBase):
    """Counts the tracebacks the server prints (viser's thread pool, threading's excepthook) or logs
    (logging with exc_info), passing stderr through."""

    def __init__(self, stream):
        self.stream, self.count, self.first = stream, 0, None

    def write(self, text: str) -> int:
        if "Traceback (most recent call last)" in text:
            self.count += 1
        if self.count and self.first is None:
            self.first = ""
        if self.first is not None and len(self.first) < 4000:
            self.first += text
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


def count_tracebacks() -> Tracebacks:
    tb = Tracebacks(sys.stderr)
    sys.stderr = tb
    logging.basicConfig(stream=tb, level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s", force=True)
    return tb


def rss_mb(pid: int | str = "self") -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024
    except (OSError, StopIteration):
        return float("nan")


def threads_and_files() -> tuple[int, int]:
    return len(os.listdir("/proc/self/task")), len(os.listdir("/proc/self/fd"))


def cycles(app, n: int) -> None:
    """n tabs connect (scene built) and disconnect, one after the other: the server's memory, threads
    and open files after, against before (after 10 cycles of warm-up)."""
    from app.probe import Probe

    def one() -> None:
        probe = Probe(app.url).start()
        probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
        owner = int(probe.owner("/tab/goal0/marker"))
        deadline = time.monotonic() + 20
        while owner not in app.sessions and time.monotonic() < deadline:
            time.sleep(0.01)
        probe.close()
        deadline = time.monotonic() + 20
        while owner in app.sessions and time.monotonic() < deadline:
            time.sleep(0.01)

    for _ in range(10):
        one()
    time.sleep(1.0)
    gc.collect()
    m0, (t0, f0) = rss_mb(), threads_and_files()
    start = time.perf_counter()
    samples = []
    for k in range(n):
        one()
        if (k + 1) % 50 == 0:
            gc.collect()
            samples.append((k + 1, rss_mb()))
    time.sleep(1.0)
    gc.collect()
    m1, (t1, f1) = rss_mb(), threads_and_files()
    print(f"{n} connect/disconnect cycles in {time.perf_counter() - start:.0f} s (load average {os.getloadavg()[0]:.1f}): "
          f"memory {m0:.1f} -> {m1:.1f} MB ({m1 - m0:+.1f} MB; after each 50: "
          f"{', '.join(f'{v:.1f}' for _k, v in samples)}), threads {t0} -> {t1}, open files {f0} -> {f1}")


def soak(app, seconds: float, tabs: int = 10, run_seconds: float = 20.0) -> None:
    """Back-to-back runs (each stopped after run_seconds) with `tabs` tabs connected, one dragging at
    10 Hz: the server's memory sampled every 10 s and its least-squares slope."""
    from app.probe import Probe

    probes = [Probe(app.url).start() for _ in range(tabs)]
    for p in probes:
        p.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
    # the tabs run in this process: those that only watch read frames without decoding them, so that the
    # memory measured is the server's (decoded messages, even when let go, left pymalloc's arenas partly
    # used: about 0.7 MB a run that was the clients')
    for p in probes[1:]:
        p.drain()
    stop = threading.Event()

    def trim(probe, keep=lambda m: False) -> None:
        """The headless tabs live in this process and keep every message they get: let them go, so that
        the memory measured is the server's."""
        with probe._cond:
            probe.messages[:] = [(t, m) for t, m in probe.messages if keep(m)]

    def drag() -> None:
        targets = drag_targets(CONFIG["robot"], 0)
        while not stop.is_set():
            trim(probes[0], keep=lambda m: m.get("name", "").startswith("/tab/goal0/marker"))
            try:
                probes[0].drag(*next(targets))
            except TimeoutError:
                pass
            stop.wait(0.1)

    dragger = threading.Thread(target=drag, daemon=True)
    dragger.start()
    samples, worker, runs, t0 = [], [], 0, time.perf_counter()
    next_sample, generations = t0, 0
    try:
        while time.perf_counter() - t0 < seconds:
            assert app.state.start(lab.TrainConfig.preset(**CONFIG)) is None
            runs += 1
            end = time.perf_counter() + run_seconds
            while time.perf_counter() < end and time.perf_counter() - t0 < seconds:
                if time.perf_counter() >= next_sample:
                    for p in probes[1:]:
                        trim(p)
                    gc.collect()
                    samples.append((time.perf_counter() - t0, rss_mb()))
                    worker.append((time.perf_counter() - t0, rss_mb(app.state.runner.pid)))
                    next_sample += 10.0
                time.sleep(0.2)
            generations += app.state.progress()["generation"]
            app.state.stop()
            app.state.reset()
    finally:
        stop.set()
        dragger.join(5)
        for p in probes:
            p.close()
    t = np.array([s[0] for s in samples])
    m = np.array([s[1] for s in samples])
    half = len(m) // 2
    slope = np.polyfit(t / 60, m, 1)[0] if len(m) > 2 else float("nan")
    slope2 = np.polyfit(t[half:] / 60, m[half:], 1)[0] if len(m) - half > 2 else float("nan")
    w = np.array([v for _t, v in worker])
    wt = np.array([t for t, _v in worker])
    ok = np.isfinite(w)
    wslope = np.polyfit(wt[ok] / 60, w[ok], 1)[0] if runs == 1 and ok.sum() > 2 else float("nan")
    wh = wt[ok] >= wt[ok][-1] / 2 if ok.any() else ok  # its second half: after the worker's warm-up
    wslope2 = np.polyfit(wt[ok][wh] / 60, w[ok][wh], 1)[0] if runs == 1 and wh.sum() > 2 else float("nan")
    print(f"soak: {runs} back-to-back runs ({generations:,} generations) in {seconds:.0f} s with {tabs} tabs (one dragging at 10 Hz), load average "
          f"{os.getloadavg()[0]:.1f}: memory {m[0]:.1f} -> {m[-1]:.1f} MB (max {m.max():.1f}); slope "
          f"{slope:+.2f} MB/min over the whole soak, {slope2:+.2f} MB/min over its second half"
          + (f"; the run's worker process {w[ok][0]:.1f} -> {w[ok][-1]:.1f} MB, {wslope:+.2f} MB/min "
             f"({wslope2:+.2f} over the second half)" if runs == 1 else ""))


def pct(x, q) -> float:
    return 1e3 * float(np.percentile(x, q)) if len(x) else float("nan")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--serve-clients":
        serve_clients(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6]),
                      sys.argv[7])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--robot", default=CONFIG["robot"],
                    help="the arm (or tree) shown, trained and dragged (default: %(default)s)")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--dragging", type=int, default=1, help="how many of the tabs drag their marker")
    ap.add_argument("--record", action="store_true", help="both sides write a Rerun recording")
    ap.add_argument("--hz", type=float, default=30.0, help="marker updates per second per dragging tab")
    ap.add_argument("--no-population", dest="population", action="store_false",
                    help="the tabs' population view off (on by default)")
    ap.add_argument("--classroom", action="store_true",
                    help="the server restricted by a presenter token: the tabs are viewers, as students' are")
    ap.add_argument("--cycles", type=int, default=0, help="instead: this many connect/disconnect cycles")
    ap.add_argument("--soak", type=float, default=0.0, help="instead: this many seconds of back-to-back runs")
    ap.add_argument("--run-seconds", type=float, default=20.0,
                    help="--soak: each run's length (as long as the soak: one long run)")
    args = ap.parse_args()
    import robots
    from app.server import LabApp

    if args.robot not in robots.names():
        ap.error(f"unknown robot {args.robot!r}; known robots: {', '.join(robots.names())}")
    CONFIG["robot"] = args.robot

    tracebacks = count_tracebacks()
    folder = tempfile.mkdtemp(prefix="bench-app-")
    app = LabApp(port=0, robot=args.robot, notebook=os.path.join(folder, "notebook.json"), recordings=folder,
                 record=args.record,
                 presenter_token="bench-presenter" if args.classroom else None)
    if args.cycles or args.soak:
        try:
            cycles(app, args.cycles) if args.cycles else soak(app, args.soak, run_seconds=args.run_seconds)
        finally:
            app.stop()
        print(f"tracebacks printed or logged by the server: {tracebacks.count}")
        if tracebacks.first:
            print(tracebacks.first, file=sys.__stderr__)
        return
    record_arrivals(app)
    heads, apps = [], []
    load = os.getloadavg()
    try:
        for r in range(args.rounds):
            if r % 2 == 0:  # alternate which goes first, so a trend in the machine's load cancels out
                heads.append(headless(args.seconds, folder if args.record else None))
                apps.append(with_app(app, args.clients, args.dragging, args.seconds, args.hz, args.population))
            else:
                apps.append(with_app(app, args.clients, args.dragging, args.seconds, args.hz, args.population))
                heads.append(headless(args.seconds, folder if args.record else None))
            a, h = apps[-1], heads[-1]
            print(f"round {r + 1}: headless {h['rate']:,.0f} eval/s (optimizer {h['runner_cpu']:.2f} cores), "
                  f"app {a['rate']:,.0f} eval/s (optimizer {a['runner_cpu']:.2f} cores, app process "
                  f"{a['app_cpu']:.2f}, client process {a['client_cpu']:.2f}; {len(a['rtt'])} drags, "
                  f"{a['frames']:,.0f} frames/s to the tabs)", flush=True)
    finally:
        app.stop()
    rtt = [x for a in apps for x in a["rtt"]]
    server = [x for a in apps for x in a["server"]]
    work = [x for a in apps for x in a["work"]]
    rate_h, rate_a = np.mean([h["rate"] for h in heads]), np.mean([a["rate"] for a in apps])
    pairs = [a["rate"] / h["rate"] for a, h in zip(apps, heads)]
    per_cpu_h = np.mean([h["rate"] / h["runner_cpu"] for h in heads])
    per_cpu_a = np.mean([a["rate"] / a["runner_cpu"] for a in apps])
    print(f"\n{args.clients} tabs connected (population view {'on' if args.population else 'off'}), "
          f"{args.dragging} dragging at {args.hz:g} Hz, while {args.robot} CMA-ES "
          f"(population 50) trains{', both recording' if args.record else ''}, "
          f"{args.rounds} x {args.seconds:g} s, {os.cpu_count()} cores, load average before {load[0]:.1f}, "
          f"after {os.getloadavg()[0]:.1f}")
    print(f"marker -> pose, loopback round trip: p50 {pct(rtt, 50):.2f} ms, p95 {pct(rtt, 95):.2f} ms, "
          f"max {pct(rtt, 100):.1f} ms ({len(rtt)} drags)")
    print(f"marker -> pose, server side (update received -> pose flushed to the sender): p50 {pct(server, 50):.2f} ms, "
          f"p95 {pct(server, 95):.2f} ms; of which in the callback: p50 {pct(work, 50):.2f} ms, p95 {pct(work, 95):.2f} ms")
    print(f"training throughput with the app: {100 * rate_a / rate_h:.0f} % of headless "
          f"({rate_a:,.0f} vs {rate_h:,.0f} evaluations/s; round by round {', '.join(f'{100 * p:.0f}' for p in pairs)} %)")
    print(f"  per CPU-second of the optimizer: {100 * per_cpu_a / per_cpu_h:.0f} % "
          f"({per_cpu_a:,.0f} vs {per_cpu_h:,.0f}); the app's process used "
          f"{np.mean([a['app_cpu'] for a in apps]):.2f} cores, the client process {np.mean([a['client_cpu'] for a in apps]):.2f}")
    print(f"tracebacks printed or logged by the server: {tracebacks.count}"
          f"{' (tabs were viewers: --classroom)' if args.classroom else ''}")
    if tracebacks.first:
        print(tracebacks.first, file=sys.__stderr__)


if __name__ == "__main__":
    main()
