"""The memory of a lab whose lesson tabs switch robots, round after round.

A LabApp opens on `--robot` (g1); each round opens, for each robot of `--robots` in turn, `--tabs`
headless tabs with a lesson link of that robot (on loopback every tab is a presenter: the link
switches the lab's robot, and every open tab rebuilds its scene for it), then closes them (or, with
--keep, keeps a round's tabs open until its end: a class of lesson tabs). After each round the
process's RSS is read once the closed tabs are gone, after gc and malloc_trim (what the app's render
loop does every 30 s): a leak grows it round after round; what each robot keeps once (its vertices,
its kernels, its error-map grid) shows in round 0 only. Also printed: the visual models kept
(robots.arm._visual_cache, at most robots.arm.VISUAL_MODELS) and the tabs still held.

    .venv/bin/python benchmarks/bench_app_memory.py [--robot g1] [--robots g1,planar,ur5,talos-legs,scara,panda]
        [--rounds 6] [--tabs 3] [--keep]

--plain: rounds of tabs that connect and close, no lesson, no switch (a server kept 15-18
MiB per 300 such tabs, round after round). Each round opens `--tabs` plain tabs (`--batch` at a time,
each until its scene is built), closes them all, and prints the RSS once they are gone, with what the
app's per-tab structures still hold (their entries should be none); --viewers makes them viewers of
a class (a presenter token is set: each gets My experiment and its own replay); --trace also prints
the allocations that grew most from the first round's end to the last's (tracemalloc).

    .venv/bin/python benchmarks/bench_app_memory.py --plain --robot planar --tabs 300 --rounds 3 [--viewers] [--trace]
"""

from __future__ import annotations

import argparse
import asyncio
import ctypes
import gc
import sys
import tempfile
import threading
import time
import weakref
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="g1", help="the robot the lab opens on")
    p.add_argument("--robots", default="g1,planar,ur5,talos-legs,scara,panda", help="the robots the lesson tabs switch to")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--tabs", type=int, default=3, help="tabs opened with each robot's lesson link")
    p.add_argument("--keep", action="store_true", help="keep a round's tabs open until its end")
    p.add_argument("--plain", action="store_true", help="rounds of plain tabs that connect and close")
    p.add_argument("--batch", type=int, default=25, help="--plain: tabs open at once")
    p.add_argument("--viewers", action="store_true", help="--plain: the tabs are a class's viewers")
    p.add_argument("--trace", action="store_true", help="--plain: the allocations that grew, by line")
    p.add_argument("--frames", type=int, default=6, help="--trace: frames kept of each allocation")
    args = p.parse_args()
    if args.plain:
        return plain_rounds(args)

    import psutil

    sys.path.insert(0, str(ROOT))
    import robots.arm as robot_arm
    from lab.methods import DEFAULT_METHOD
    from app.classroom.lesson import lesson_link
    from app.probe import Probe
    from app.server import LabApp

    me = psutil.Process()
    try:
        trim = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        trim = None

    def rss() -> float:
        gc.collect()
        if trim is not None:
            trim(0)
        return me.memory_info().rss / 2**20

    def until(predicate, timeout: float = 120.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.05)
        return False

    folder = tempfile.mkdtemp(prefix="bench-app-memory-")
    app = LabApp(port=0, robot=args.robot, notebook=f"{folder}/notebook.db", recordings=f"{folder}/rec", record=False)
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True).start()
    names = args.robots.split(",")
    held = []
    print(f"a {args.robot} lab; each round: {args.tabs} lesson tab(s) for each of {', '.join(names)}"
          f"{' (kept open to the round end)' if args.keep else ''}")
    print(f"start: {rss():.0f} MiB")
    try:
        for r in range(args.rounds):
            t0, opened = time.perf_counter(), []
            for name in names:
                link = lesson_link(app.url, {"lesson": "1", "robot": name, "method": DEFAULT_METHOD})
                ws = unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")
                tabs = [Probe(ws, loop=loop).start(120) for _ in range(args.tabs)]
                tabs[-1].wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
                until(lambda: app.state.arm.name == name and all(
                    s.arm is app.state.arm and s.version == app.state.shown.version for s in list(app.sessions.values())))
                held += [weakref.ref(s) for s in list(app.sessions.values())]
                for tab in tabs:
                    tab.drain()
                opened += tabs
                if not args.keep:
                    for tab in tabs:
                        tab.close()
            for tab in opened:
                tab.close()
            until(lambda: not app.sessions and not app.server.get_clients(), 60)
            mib = rss()
            alive = sum(ref() is not None for ref in held)
            print(f"round {r}: {mib:.0f} MiB ({time.perf_counter() - t0:.0f} s); visual models kept "
                  f"{robot_arm._visual_cache.cache_info().currsize}; closed tabs still held {alive}")
    finally:
        app.stop()
        loop.call_soon_threadsafe(loop.stop)


def per_tab_entries(app) -> dict[str, int]:
    """What the app's per-tab structures hold (app.per_tab_entries when the app has it, else the known ones)."""
    if hasattr(app, "per_tab_entries"):
        return app.per_tab_entries()
    ws = app.server._websock_server
    return {"sessions": len(app.sessions), "closed-tab ids": len(getattr(app, "_gone", ())),
            "class_runs names": len(app.class_runs._names), "lesson seats": len(app.class_runs._seats),
            "access roles": len(app.access._roles), "access viewers": len(app.access._viewers),
            "upload starts": len(app.runs.uploads._starts), "viser clients": len(app.server.get_clients()),
            "viser client states": len(ws._client_state_from_id),
            "viser broadcast cursors": len(ws._broadcast_buffer.generator_cursors)}


def plain_rounds(args) -> None:
    import psutil

    sys.path.insert(0, str(ROOT))
    from app.probe import Probe
    from app.server import LabApp

    if args.trace:
        import tracemalloc

        tracemalloc.start(args.frames)
    me = psutil.Process()
    try:
        trim = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        trim = None

    def rss() -> float:
        gc.collect()
        if trim is not None:
            trim(0)
        return me.memory_info().rss / 2**20

    def until(predicate, timeout: float = 120.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.05)
        return False

    folder = tempfile.mkdtemp(prefix="bench-app-memory-")
    app = LabApp(port=0, robot=args.robot, notebook=f"{folder}/notebook.db", recordings=f"{folder}/rec", record=False,
                 presenter_token="bench-token" if args.viewers else None)
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True).start()
    held, snapshots = [], []
    print(f"a {args.robot} lab; each round {args.tabs} {'viewer' if args.viewers else 'plain'} tabs connect "
          f"({args.batch} at a time, each until its scene is built) and close")
    print(f"start: {rss():.0f} MiB")
    try:
        for r in range(args.rounds):
            t0 = time.perf_counter()
            for first in range(0, args.tabs, args.batch):
                tabs = [Probe(app.url, loop=loop).start(120) for _ in range(min(args.batch, args.tabs - first))]
                for tab in tabs:
                    tab.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
                    tab.drain()
                held += [weakref.ref(s) for s in list(app.sessions.values())]
                for tab in tabs:
                    tab.close()
                until(lambda: not app.sessions and not app.server.get_clients(), 60)
            raw = me.memory_info().rss / 2**20  # before gc and malloc_trim (the render loop's, every 30 s)
            mib = rss()
            alive = sum(ref() is not None for ref in held)
            left = {k: v for k, v in per_tab_entries(app).items() if v}
            print(f"round {r}: {mib:.0f} MiB ({raw:.0f} before gc and trim; {time.perf_counter() - t0:.0f} s); "
                  f"closed tabs still held {alive}; "
                  f"per-tab entries left {left or 'none'}", flush=True)
            if args.trace:
                snapshots.append(tracemalloc.take_snapshot())
        if args.trace and len(snapshots) > 1:
            grew = snapshots[-1].compare_to(snapshots[0], "traceback")
            print(f"grew from round 0 to round {len(snapshots) - 1} (tracemalloc, the largest 12):")
            for stat in grew[:12]:
                print(f"  {stat.size_diff / 2**10:+9.1f} KiB {stat.count_diff:+7d} blocks")
                for line in stat.traceback.format()[-8:]:
                    print("     " + line)
    finally:
        app.stop()
        loop.call_soon_threadsafe(loop.stop)


if __name__ == "__main__":
    main()
