"""`python -m app` (`make app`): start the lab in the browser and print the URL it serves.

    python -m app                         # http://127.0.0.1:8080 (the next free port if taken)
    python -m app --host 0.0.0.0          # a classroom network: every machine that can reach this one
    python -m app --port 9000 --robot ur5
    python -m app --host 0.0.0.0 --open   # every tab may change the run (on purpose)

Beyond loopback only presenter tabs (opened with the printed presenter link) change the run and the
shared settings; every other tab is a viewer (app/classroom/access.py).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "LAB_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy: training shares the cores with the server

import argparse  # noqa: E402
import logging  # noqa: E402
import signal  # noqa: E402
import socket  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402


def parse(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m app", description="Neuro-IK Lab in the browser (viser).")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    p.add_argument("--port", type=int, default=8080, help="port; viser takes the next free one when taken")
    p.add_argument("--robot", default="planar", help="the arm shown first")
    p.add_argument("--notebook", default=os.path.join("recordings", "notebook.db"),
                   help="the runs list (SQLite; a notebook.json of earlier versions is imported once), kept across restarts")
    p.add_argument("--recordings", default="recordings", help="folder of the runs' Rerun recordings")
    p.add_argument("--no-record", action="store_true", help="do not write Rerun recordings")
    p.add_argument("--presenter-token", default=None, metavar="TOKEN",
                   help="the presenter link's token (default: a random one beyond loopback; on loopback, "
                        "giving one makes the other tabs viewers); letters, digits and . _ ~ - only")
    p.add_argument("--limit", action="append", default=[], metavar="NAME=N",
                   help="raise (or set) a bound on the settings this server accepts: population, hidden, goals, "
                        "generations (beyond loopback: 200, 64, 1000, 100000 unless raised); repeatable")
    p.add_argument("--open", action="store_true",
                   help="every tab may change the run and the shared settings, also beyond loopback")
    return p.parse_args(argv)


def _cannot_listen_on(host: str) -> str | None:
    """Why no server can listen on host (unknown name, an address of another machine), or None."""
    try:
        family, kind, _, _, address = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind) as s:
            s.bind(address)
    except OSError as e:
        return e.strerror or str(e)
    return None


def main(argv=None) -> int:
    args = parse(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from lab import methods
    from lab.problem import environment

    try:  # every LAB_* variable, and the modules of LAB_METHODS imported, before the server starts
        environment.check_all()
        methods.names()
    except environment.SettingError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    import robots

    if args.robot not in robots.names():
        print(f"error: unknown robot {args.robot!r}; known robots: {', '.join(robots.names())}", file=sys.stderr)
        return 2
    if not 0 <= args.port < 65536:
        print(f"error: --port must be in 0..65535, got {args.port}", file=sys.stderr)
        return 2
    problem = _cannot_listen_on(args.host)
    if problem:  # viser would wait forever for a server that cannot start
        print(f"error: cannot serve on --host {args.host}: {problem}", file=sys.stderr)
        return 2
    from lab.recording.logger import not_a_folder

    if not args.no_record and (blocker := not_a_folder(args.recordings)) is not None:
        print(f"error: --recordings must be a folder, but {blocker} is a file", file=sys.stderr)
        return 2
    from app.classroom.access import Access
    from app.training.notebook import Notebook, NotebookError
    from app.server import LabApp

    if args.open and args.presenter_token is not None:
        print("error: --open and --presenter-token contradict each other", file=sys.stderr)
        return 2
    try:
        Access(args.host, args.presenter_token, args.open)
    except ValueError as e:
        print(f"error: --presenter-token: {e}", file=sys.stderr)
        return 2
    from app.classroom.limits import parse_limit

    try:
        limits = dict(parse_limit(text) for text in args.limit)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    t0 = time.perf_counter()
    try:
        notebook = Notebook(args.notebook)
    except NotebookError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    app = LabApp(args.host, args.port, robot=args.robot, notebook=notebook, recordings=args.recordings,
                 record=not args.no_record, presenter_token=args.presenter_token, open_access=args.open,
                 limits=limits)
    print(f"\nNeuro-IK Lab ready in {time.perf_counter() - t0:.1f} s: {app.url}", flush=True)
    # the first Start would otherwise wait for numba to compile the fitness kernels (~30 s, once)
    from lab.running.warmup import compile_kernels

    threading.Thread(target=compile_kernels, name="kernel-warmup", daemon=True).start()
    if args.host in ("0.0.0.0", ""):
        print(f"  on this network: http://{socket.gethostname()}:{app.port}", flush=True)
    if app.state.limits:
        print("  settings accepted: at most " + ", ".join(f"{k} {v:,}" for k, v in app.state.limits.items())
              + " (--limit NAME=N raises one)", flush=True)
    if app.access.restricted:
        here = f"http://{socket.gethostname()}:{app.port}" if args.host in ("0.0.0.0", "") else app.url
        print(f"  presenter link (keep it to yourself; other tabs are viewers): {app.access.link(here)}", flush=True)
        if here != app.url:
            print(f"  presenter link on this machine: {app.presenter_url}", flush=True)
    elif not args.open:
        print("  every tab is a presenter (loopback only); --presenter-token TOKEN makes other tabs viewers", flush=True)
    else:
        print("  --open: every tab may change the run", flush=True)
    print(f"  startup controller: {app.startup_note}; runs list: {args.notebook}. Ctrl-C stops.", flush=True)
    # every way of stopping (Ctrl-C, SIGTERM from a service manager, SIGHUP from a closing terminal)
    # ends as Ctrl-C does: the run is stopped and noted, its recording closed; a second signal waits
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        print("stopping: the run (if any) is stopped, noted in the notebook and its recording closed", flush=True)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, _already_stopping)
        app.stop()
    return 0


def _interrupt(signum, _frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _already_stopping(signum, _frame):
    print(f"{signal.Signals(signum).name}: already stopping", file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
