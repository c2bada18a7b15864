"""A simulated class: N headless student tabs each start their own run on a classroom server while the
presenter's shared run trains and the presenter drags a goal.

    python benchmarks/bench_class.py                          # 30 students, 30 s runs, the default workers
    python benchmarks/bench_class.py --students 30 --seconds 3 --workers 1
    python benchmarks/bench_class.py --ray 127.0.0.1:6390           # the runs on a Ray cluster's actors
    python benchmarks/bench_class.py --default --spread 60          # each the panel's default run, Starts over a minute
    python benchmarks/bench_class.py --default --spread 60 --record # ... each run recorded, as the classroom server does

Each student tab (app/probe.py, one event loop for all, in this process) gets a name, a planar CMA-ES
run with a time budget of --seconds, and presses "Start my run"; the presenter's tab drags its goal
marker 10 times a second throughout. Reports: how long the last run waited in the queue, the whole
class's wall time, the presenter's drags (the server's work per drag, callback to pose sent: p50/p95,
app.latency; and the round trip the probe saw, inflated by its sharing this process), how long the
Class board took to show each run's end (the largest), and that every run finished and has its
notebook entry with its student's name. --default: each student presses Start on *My experiment*'s
default run (the robot, method and length the panel offers; only the seed is the student's own),
--spread S: the Starts one after another over S seconds (a class pressing Start within a minute:
60); class_wall_s is then the first Start to the last run's end. --record: the shared run and every
student run recorded (.rrd, a Rerun writer process each), as `python -m app` does. With --ray ADDRESS the runs go to that Ray cluster (as
`python -m app --ray ADDRESS`; "local": a local instance), at most its CPUs at once unless --workers
says otherwise, and it counts the runs each node trained.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def whole_recordings(entries: list, runs: list) -> int:
    """How many runs' notebook entries name a recording that reads back to the run's last generation."""
    from lab.recording.replay import read_recording

    whole = 0
    for e, r in zip(entries, runs):
        try:
            whole += e is not None and bool(e.get("recording")) and \
                read_recording(e["recording"]).last_generation == r.generation - 1
        except (OSError, ValueError):
            pass
    return whole


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--students", type=int, default=30)
    ap.add_argument("--seconds", type=float, default=30.0, help="each student run's time budget")
    ap.add_argument("--workers", type=int, default=None, help="student runs at once (default: cores - 2, at least 1)")
    ap.add_argument("--ray", default=None, metavar="ADDRESS", help="run the students' runs on this Ray cluster")
    ap.add_argument("--hz", type=float, default=10.0, help="the presenter's drags a second")
    ap.add_argument("--default", action="store_true", help="each student runs My experiment's default (only the seed set)")
    ap.add_argument("--spread", type=float, default=0.0, help="the Starts spread evenly over this many seconds")
    ap.add_argument("--record", action="store_true", help="record every run (.rrd), as the classroom server does")
    args = ap.parse_args()

    import numpy as np

    import lab
    from app.classroom.class_runs import describe
    from app.probe import Probe
    from app.server import LabApp

    runner, workers, where = None, args.workers, "local worker processes"
    if args.ray:
        from lab.running import ray_runner

        where = ray_runner.connect(args.ray)
        runner, workers = ray_runner.RayRunner, args.workers or ray_runner.cpus()
    folder = tempfile.mkdtemp(prefix="bench-class-")
    token = "bench-class-presenter-token"
    app = LabApp(port=0, notebook=os.path.join(folder, "notebook.db"), recordings=os.path.join(folder, "rec"),
                 record=args.record, presenter_token=token, class_workers=workers, class_runner=runner, startup=None, speed=20.0,
                 limits={"population": 200})
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True, name="probes").start()
    import urllib.parse

    presenter = Probe(urllib.parse.unquote(app.presenter_url.split("websocket=")[1]), loop=loop).start(60)
    presenter.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 60)
    students = [Probe(app.url, loop=loop).start(60) for _ in range(args.students)]
    for p in students:
        p.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
    owners = {int(p.owner("/tab/goal0/marker")): p for p in students}
    deadline = time.monotonic() + 60
    while not all(o in app.sessions for o in owners) and time.monotonic() < deadline:
        time.sleep(0.05)
    for p in students:
        p.drain()  # their browsers decode on the students' machines, not here
    why = app.state.start(lab.TrainConfig(robot="planar", generations=100_000, population=50))
    assert why is None, why
    ended: dict[str, float] = {}  # run id -> when its end was known
    seen: dict[str, float] = {}  # run id -> when the board showed it
    lasted: dict[str, float] = {}  # run id -> s from its start to its end
    original = app.class_runs._ended

    def noted(run, summary):
        ended[run.id] = time.perf_counter()
        lasted[run.id] = time.time() - run.started  # from its start (its worker's too) to its end
        original(run, summary)

    app.class_runs._ended = noted
    stop = threading.Event()

    most = [0]  # student runs at once, at most

    def watch_board() -> None:
        while not stop.is_set():
            most[0] = max(most[0], len(app.class_runs.running()))
            content = app.board.table.content
            for run in app.class_runs.rows():
                if run.id in ended and run.id not in seen and \
                        f"<b>{run.name}</b></td><td>{describe(run.config)}</td><td>{run.state}" in content:
                    seen[run.id] = time.perf_counter()
            time.sleep(0.01)

    threading.Thread(target=watch_board, daemon=True).start()
    rtts: list[float] = []
    presenter_id = int(presenter.owner("/tab/goal0/marker"))

    def drag() -> None:
        rng = np.random.default_rng(0)
        while not stop.is_set():
            t = time.perf_counter()
            try:
                rtts.append(presenter.drag("/tab/goal0/marker", (rng.uniform(-5, 20), rng.uniform(-15, 20), 0.0)))
            except TimeoutError:
                rtts.append(float("inf"))
            time.sleep(max(0.0, 1.0 / args.hz - (time.perf_counter() - t)))

    app.latency.clear()
    dragger = threading.Thread(target=drag, daemon=True)
    dragger.start()
    t0, default_run = time.perf_counter(), None
    for k, (owner, _probe) in enumerate(owners.items()):
        panel = app.sessions[owner].my_run
        assert app.class_runs.set_name(owner, f"bench {k + 1}") is None
        panel.seed.value = float(k)
        if not args.default:
            panel.population.value, panel.budget.value = 20.0, float(args.seconds)
            panel.generations.value = 100_000.0  # the time budget ends the run
        elif k == 0:
            default_run = f"{panel.robot.value}, {panel.method.value}, population {int(panel.population.value)}, " \
                f"{int(panel.generations.value)} generations, budget {panel.budget.value} s"
        why = panel.start()
        assert why is None, why
        if args.spread and k < len(owners) - 1:
            time.sleep(max(0.0, t0 + args.spread * (k + 1) / (len(owners) - 1) - time.perf_counter()))
    runs = [app.class_runs.run_of(o) for o in owners]
    while not all(r.ended for r in runs):
        time.sleep(0.1)
    wall = time.perf_counter() - t0
    time.sleep(2.0)  # the board's last redraw
    stop.set()
    dragger.join(15)
    work = [flushed - start for cid, start, flushed in list(app.latency) if cid == presenter_id]
    waits = [r.started - r.submitted for r in runs if r.started is not None]
    board = [seen[r.id] - ended[r.id] for r in runs if r.id in seen]
    entries = [app.state.notebook.get(r.id) for r in runs]
    shared_ok = app.state.runner is not None and app.state.runner.state == "running"
    result = {
        "students": args.students, "run": default_run if args.default else f"planar, {args.seconds} s",
        "spread_s": args.spread, "workers": app.class_runs.workers,
        "cores": os.cpu_count(),
        "finished": sum(r.state == "finished" for r in runs),
        "entries_with_name": sum(e is not None and e.get("student", "").startswith("bench ") for e in entries),
        "last_wait_s": round(max(waits), 1) if waits else None,
        "class_wall_s": round(wall, 1),
        "drag_work_ms_p50": round(1000 * statistics.median(work), 2) if work else None,
        "drag_work_ms_p95": round(1000 * float(np.percentile(work, 95)), 2) if work else None,
        "drag_rtt_ms_p95": round(1000 * float(np.percentile(rtts, 95)), 1) if rtts else None,
        "drags": len(work),
        "runs_at_once_max": most[0],
        "run_wall_s_mean": round(statistics.mean(lasted.values()), 2) if lasted else None,
        # a run's cost beside its training: its start (worker, writer) to its end (the target: at most 1 s)
        "run_overhead_s_mean": round(statistics.mean(lasted[r.id] - r.summary.seconds for r in runs
                                                     if r.id in lasted and r.summary is not None), 2) if lasted else None,
        "generations_mean": round(statistics.mean(r.generation for r in runs), 1),
        "board_update_max_s": round(max(board), 2) if board else None,
        "board_seen": len(board),
        "recordings_whole": whole_recordings(entries, runs) if args.record else None,
        "shared_run_still_running": shared_ok,
        "runs_went_to": where,
    }
    if args.ray:
        import collections

        nodes = collections.Counter(getattr(r.runner, "node_id", None) for r in runs)
        result["runs_per_node"] = {(k or "none")[:12]: v for k, v in nodes.items()}
    print(json.dumps(result), flush=True)
    for p in [presenter, *students]:
        p.close()
    app.state.reset()
    app.stop()


if __name__ == "__main__":
    main()
