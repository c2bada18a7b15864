"""`python -m app` (`make app`): start the lab in the browser and print the URL it serves.

    python -m app                         # http://127.0.0.1:8080 (the next free port if taken)
    python -m app --host 0.0.0.0          # a classroom network: every machine that can reach this one
    python -m app --port 9000 --robot ur5
    python -m app --robot erd:ur3         # any example-robot-data robot, or a URDF: --robot my_arm.urdf --ee tool0
    python -m app --host 0.0.0.0 --open   # every tab may change the run (on purpose)
    python -m app --host 0.0.0.0 --presenter-token-file ~/.lab-token   # a token of your own, not in `ps`
    python -m app --host 0.0.0.0 --ray HOST:6379   # students' runs on a Ray cluster ("local": one started here)

Beyond loopback only presenter tabs (opened with the printed presenter link) change the run and the
shared settings; every other tab is a viewer (app/classroom/access.py). A token of your own (at least
16 characters) comes, as Jupyter's does, from a file (--presenter-token-file), the environment
(LAB_PRESENTER_TOKEN) or the command line (--presenter-token, which every local user sees in `ps`:
a warning says so).
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

# runs start at 20 generations a second: a paper arm's 1,000 generations take under a minute and
# its first hundred, where it learns most, about five seconds that an audience can follow
WATCHING_SPEED = 20.0


TOKEN_ENV = "LAB_PRESENTER_TOKEN"  # as Jupyter's JUPYTER_TOKEN: a token that does not show in `ps`


def presenter_token(args) -> tuple[str | None, str | None]:
    """(token, None) from --presenter-token, --presenter-token-file or LAB_PRESENTER_TOKEN (None: none
    given), or (None, the error line)."""
    if args.presenter_token is not None and args.presenter_token_file is not None:
        return None, "error: --presenter-token and --presenter-token-file contradict each other; give one"
    if args.presenter_token_file is not None:
        from app.classroom.access import read_token_file

        source = "--presenter-token-file"
        try:  # a pipe, a device, a folder or a file over 4 KiB is refused before anything blocks
            token = read_token_file(args.presenter_token_file)
        except ValueError as e:
            return None, f"error: --presenter-token-file {e}"
    elif args.presenter_token is not None:
        source, token = "--presenter-token", args.presenter_token
        print("warning: --presenter-token shows the token to every user of this machine (`ps`); "
              f"--presenter-token-file PATH or {TOKEN_ENV} keep it out of sight", file=sys.stderr, flush=True)
    elif os.environ.get(TOKEN_ENV):
        source, token = TOKEN_ENV, os.environ[TOKEN_ENV].strip()
    else:
        return None, None
    if args.open:
        return None, f"error: --open and a presenter token ({source}) contradict each other"
    from app.classroom.access import token_problem

    problem = token_problem(token)
    return (None, f"error: {source}: {problem}") if problem else (token, None)


def parse(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m app", description="Neuro-IK Lab in the browser (viser).")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    p.add_argument("--port", type=int, default=8080, help="port; viser takes the next free one when taken")
    p.add_argument("--robot", default="planar", help="the arm (or tree of several end effectors: g1, allegro, ...) shown first: "
                   "a registered name, erd:NAME (any example-robot-data robot) or a URDF file's path (docs/robots.md)")
    p.add_argument("--ee", default=None, metavar="FRAME[,FRAME]",
                   help="the tool frame of --robot (several, comma-separated: a tree); default: the end of its longest chain")
    p.add_argument("--goal", default="position", choices=("position", "pose"),
                   help="what a goal is: a position, or a pose (position and orientation of the tool; the real "
                        "arms: ur5 ur10 panda xarm7 kinova z1 so100 so101); the Train panel's Goal changes it")
    p.add_argument("--notebook", default=os.path.join("recordings", "notebook.db"),
                   help="the runs list (SQLite; a notebook.json of earlier versions is imported once), kept across restarts")
    p.add_argument("--recordings", default="recordings", help="folder of the runs' Rerun recordings")
    p.add_argument("--no-record", action="store_true", help="do not write Rerun recordings")
    p.add_argument("--presenter-token", default=None, metavar="TOKEN",
                   help="the presenter link's token (default: a random one beyond loopback; on loopback, "
                        "giving one makes the other tabs viewers); at least 16 of letters, digits and . _ ~ - ; "
                        "visible in `ps` to every local user: prefer --presenter-token-file or "
                        f"{TOKEN_ENV}")
    p.add_argument("--presenter-token-file", default=None, metavar="PATH",
                   help=f"read the presenter token from this file (its first line); or set {TOKEN_ENV}")
    p.add_argument("--limit", action="append", default=[], metavar="NAME=N",
                   help="raise (or set) a bound on the settings this server accepts: population, hidden, goals, "
                        "generations, seconds (a time budget; beyond loopback: 200, 64, 1000, 100000, 600 unless "
                        "raised); repeatable")
    p.add_argument("--speed", type=float, default=WATCHING_SPEED, metavar="GENERATIONS_PER_S",
                   help=f"how fast runs go at first, so that an audience can follow (default {WATCHING_SPEED:g} "
                        "generations a second; 0: as fast as the machine goes); the Speed menu changes it")
    p.add_argument("--open", action="store_true",
                   help="every tab may change the run and the shared settings, also beyond loopback")
    p.add_argument("--class-workers", type=_workers, default=None, metavar="N",
                   help="students' own runs (a viewer's My experiment) trained at once, the others queued "
                        "(default: the cores the shared run and the server leave, at least 1; with --ray the "
                        "cluster's CPUs)")
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="train students' own runs on this Ray cluster (HOST:PORT, as `ray start --head` prints; "
                        "local: a Ray instance started here); needs the ray extra (pip install -e \".[ray]\")")
    return p.parse_args(argv)


def _workers(text: str) -> int:
    """--class-workers: a whole number from 1 (argparse's error names the option otherwise)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number from 1, got {text[:40]!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"a whole number from 1, got {n}")
    return n


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

    try:  # any robot string (robots/sources.py): the canonical one names it from here on, in every process
        args.robot = robots.load(args.robot, ee=args.ee.split(",") if args.ee else None).name
    except Exception as e:  # noqa: BLE001 - an unknown name, a missing file, a frame it lacks, a joint refused
        print(f"error: --robot {args.robot}{f' --ee {args.ee}' if args.ee else ''}: {e}", file=sys.stderr)
        return 2
    if args.goal == "pose":
        from app.tab.posegoal import pose_refusal

        if (why := pose_refusal(args.robot)) is not None:
            print(f"error: --goal pose --robot {args.robot}: {why}", file=sys.stderr)
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
    from app.training.notebook import Notebook, NotebookError

    token, problem = presenter_token(args)
    if problem:
        print(problem, file=sys.stderr)
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
    class_runner, args.class_runs_go_to = None, "local worker processes"
    if args.ray is not None:  # before the server starts: a missing Ray or an unreachable cluster stops here
        from lab.running import ray_runner

        try:
            args.class_runs_go_to = ray_runner.connect(args.ray)
        except (ray_runner.RayMissing, ConnectionError, ValueError) as e:
            print(f"error: --ray {args.ray}: {e}", file=sys.stderr)
            return 2
        class_runner = ray_runner.RayRunner
        if args.class_workers is None:
            args.class_workers = ray_runner.cpus()
    print("starting Neuro-IK Lab (the first start after an install compiles what its page needs: under a "
          "minute; later starts take seconds)", flush=True)
    # the training kernels compile in the spare training process (lab/running/worker.py), started now
    # so that it compiles while the server starts and the page serves: every step is told here, unless
    # they all load from the cache
    try:
        import lab.running.worker as lab_worker

        lab_worker.on_warmup(WarmupLines())
        lab_worker.prestart(args.robot)
        from app.server import LabApp

        app = LabApp(args.host, args.port, robot=args.robot, notebook=notebook, recordings=args.recordings,
                     record=not args.no_record, presenter_token=token, open_access=args.open,
                     limits=limits, speed=args.speed or None, class_workers=args.class_workers,
                     class_runner=class_runner, goal=args.goal)
    except KeyboardInterrupt:  # Ctrl-C while it starts: nothing to stop yet (the spare ends with us)
        print("stopped while starting", file=sys.stderr, flush=True)
        return 130
    # every way of stopping (Ctrl-C, SIGTERM from a service manager, SIGHUP from a closing terminal)
    # ends as Ctrl-C does, from here on: the run is stopped and noted, its recording closed; a second
    # signal waits
    stopping = SignalWait((signal.SIGINT, signal.SIGTERM, signal.SIGHUP))
    try:
        _serve(args, app, t0)
        stopping.wait()
        print("stopping: the runs going are stopped, their recordings closed and their entries noted (in the "
              "notebook, or in its journal when it cannot be written: the log says so)", flush=True)
    finally:
        stopping.close()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, _already_stopping)
        try:
            app.stop()
            if args.ray is not None:  # after every student run has ended; a local instance ends with it
                import ray

                ray.shutdown()
        finally:  # the entries not written yet (a locked notebook, a full disk) go to its journal: the
            notebook.close()  # exit below skips atexit, so this is their last chance; the log names them
    return 0


def _serve(args, app, t0: float) -> None:
    """Say where the lab serves, who may change the run, what it opened with."""
    print(f"\nNeuro-IK Lab ready in {time.perf_counter() - t0:.1f} s: {app.url}", flush=True)
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
        print("  every tab is a presenter (loopback only); a presenter token (--presenter-token-file PATH) makes "
              "other tabs viewers", flush=True)
    else:
        print("  --open: every tab may change the run", flush=True)
    workers = app.class_runs.workers
    print(f"  students' own runs: {args.class_runs_go_to}, {workers} at once", flush=True)
    print(f"  startup controller: {app.startup_note}; runs list: {args.notebook}. Ctrl-C stops.", flush=True)


class SignalWait:
    """From its making, `signals` are noted, not raised; wait() blocks until one arrives (its number).

    Not a sleep in a loop that a KeyboardInterrupt ends: the kernel may deliver a signal to any of the
    app's threads (viser's, a run's reader, the training kernels' warm-up), and Python then only
    marks it for the main thread, which a sleep does not wake: under load a Ctrl-C was lost for
    minutes (docs/faults.md). The C handler writes every signal's number to the wakeup descriptor,
    whichever thread it interrupts, and that wakes wait's select. A signal between the making and
    wait() is kept there. Main thread only (signal.set_wakeup_fd)."""

    def __init__(self, signals):
        self.signals = {int(s) for s in signals}
        self.read, self.write = os.pipe()
        os.set_blocking(self.write, False)
        os.set_blocking(self.read, False)
        for sig in signals:
            signal.signal(sig, _noted)
        self.previous = signal.set_wakeup_fd(self.write, warn_on_full_buffer=False)

    def wait(self) -> int:
        import select

        while True:
            select.select([self.read], [], [])
            try:
                data = os.read(self.read, 64)
            except BlockingIOError:
                continue
            for number in data:
                if number in self.signals:
                    return number

    def close(self) -> None:
        signal.set_wakeup_fd(self.previous)
        os.close(self.read)
        os.close(self.write)


def _noted(_signum, _frame):
    """The Python side of a stopping signal: nothing (SignalWait.wait reads it from the wakeup fd)."""


def _already_stopping(signum, _frame):
    print(f"{signal.Signals(signum).name}: already stopping", file=sys.stderr, flush=True)


class WarmupLines:
    """Prints the training kernels' warm-up (lab.running.worker.on_warmup), a line per step, once numba
    compiles: a warm-up that loads every kernel from the cache says nothing."""

    def __init__(self):
        self._lock = threading.Lock()
        self._held: dict[int, list] = {}  # a worker's pid -> its lines held back (None: printing them)

    def __call__(self, warmup) -> None:
        if warmup.done:
            line = f"  training kernels ready ({warmup.seconds:.0f} s, once: later starts load them)"
        elif warmup.steps:
            about = "no estimate yet" if warmup.expected is None else f"about {warmup.expected:.0f} s"
            line = f"  preparing the training kernels: step {warmup.index} of {warmup.steps}, {warmup.label} ({about})"
        else:
            line = None
        with self._lock:
            held = self._held.setdefault(warmup.pid, [])
            if held is not None and not warmup.compiling:  # loading from the cache so far
                if warmup.done:
                    del self._held[warmup.pid]
                elif line and (not held or held[-1] != line):
                    held.append(line)
                return
            lines = (held or []) + ([line] if line and (not held or held[-1] != line) else [])
            for text in lines:
                print(text, flush=True)
            if warmup.done:
                del self._held[warmup.pid]
            else:
                self._held[warmup.pid] = None


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # everything is closed (the run noted, the notebook committed or its journal written, the
    # recordings' writers finish on their own): the interpreter's teardown of a gigabyte of modules,
    # seconds of CPU on a loaded machine, would only delay the exit that Ctrl-C asked for (docs/faults.md)
    os._exit(code)
