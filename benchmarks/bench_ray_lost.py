"""How soon a class on a Ray cluster learns that its node is lost: a local Ray instance
(`--ray local`'s), one student run going per CPU and one queued, the board asking
ClassRuns.unavailable() 4 times a second as the render loop does; then the raylet is SIGKILLed (as
the OOM killer does). Prints the seconds from the kill to: the cluster said lost, every run going
failed, the queued run failed; the slots still busy; the queued run's status and a new run's refusal.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_ray_lost.py [--rounds 2]
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import lab  # noqa: E402
from app.classroom.class_runs import ClassRuns  # noqa: E402
from app.classroom.limits import CLASSROOM  # noqa: E402
from app.training.notebook import Notebook  # noqa: E402

LONG = dict(robot="planar", method=lab.methods.DEFAULT_METHOD, generations=100_000, population=10)


def raylet_pid(ray) -> int:
    """The raylet of this process's Ray instance (its command line names the session)."""
    session = ray.get_runtime_context().get_session_name()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/comm") as f, open(f"/proc/{pid}/cmdline", "rb") as g:
                if f.read().strip() == "raylet" and session.encode() in g.read():
                    return int(pid)
        except OSError:
            continue
    raise RuntimeError(f"no raylet of {session}")


def until(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def one_round() -> None:
    import ray

    from lab.running import ray_runner

    ray_runner.connect("local")
    runs = ClassRuns(Notebook(tempfile.mkdtemp() + "/nb.db"), CLASSROOM, workers=ray_runner.cpus(),
                     runner=ray_runner.RayRunner)
    stop = threading.Event()

    def board():  # the render loop's board: 4 times a second
        while not stop.is_set():
            runs.unavailable()
            time.sleep(0.25)

    threading.Thread(target=board, daemon=True).start()
    for tab in range(runs.workers + 1):
        assert runs.submit(tab, lab.TrainConfig(**LONG, seed=tab)) is None
    going, queued = [runs.run_of(t) for t in range(runs.workers)], runs.run_of(runs.workers)
    assert until(lambda: all(r.generation > 0 for r in going), 300), [r.status() for r in going]
    t0 = time.monotonic()
    os.kill(raylet_pid(ray), signal.SIGKILL)
    marks: dict[str, float] = {}
    checks = {"said lost": lambda: runs.unavailable() is not None,
              f"{len(going)} going failed": lambda: all(r.ended for r in going), "queued failed": lambda: queued.ended}
    while len(marks) < len(checks) and time.monotonic() - t0 < 300:
        for name, check in checks.items():
            if name not in marks and check():
                marks[name] = time.monotonic() - t0
        time.sleep(0.05)
    print(", ".join(f"{k} {v:.1f} s" for k, v in marks.items()), f"after the kill; slots busy: {len(runs.running())}")
    print("  queued run:", queued.status())
    print("  a new run:", runs.submit(10_000, lab.TrainConfig(**LONG)))
    stop.set()
    ray.shutdown()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=1)
    args = p.parse_args()
    for _ in range(args.rounds):
        one_round()


if __name__ == "__main__":
    main()
