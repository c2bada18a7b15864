"""The lesson "The class as a search" with a simulated class: N headless student tabs open the lesson's
link on a classroom server, each gets its part of the search (its hidden units and seed, from the
link's class_hidden= list, app/panels/my_run.py take_part) and presses Start my run.

    python benchmarks/bench_class_search.py --students 30 --workers 1

Prints one table row per student, in the order the tabs opened the link (what
docs/lessons/class-as-a-search.md quotes; its snippet prints the same rows with lab.evolve), then the
class's curve (the median held-out MSE of each number of hidden units), the class's wall time, the
machine's load before and after, and that every run finished with its named notebook entry.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main() -> None:
    import argparse
    import urllib.parse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--students", type=int, default=30)
    ap.add_argument("--workers", type=int, default=1, help="student runs at once")
    args = ap.parse_args()

    from app.classroom.lesson import LESSONS
    from app.probe import Probe
    from app.server import LabApp

    load_before = Path("/proc/loadavg").read_text().split()[:3]
    folder = tempfile.mkdtemp(prefix="bench-class-search-")
    app = LabApp(port=0, notebook=os.path.join(folder, "notebook.db"), recordings=os.path.join(folder, "rec"),
                 record=False, presenter_token="bench-class-search-token", class_workers=args.workers, startup=None,
                 limits={"population": 200})
    lesson = LESSONS["class-as-a-search"]
    url = urllib.parse.unquote(lesson.link(app.url).split("?websocket=", 1)[1]).replace("ws://", "http://")
    students = []
    for _ in range(args.students):  # one after the other: the N-th to open the link gets the N-th part
        p = Probe(url).start(60)
        p.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
        owner = int(p.owner("/tab/goal0/marker"))
        deadline = time.monotonic() + 60
        while (owner not in app.sessions or "part of the class" not in app.sessions[owner].my_run.part.content) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "part of the class" in app.sessions[owner].my_run.part.content, "the lesson gave no part"
        students.append((owner, p.drain()))
    t0 = time.perf_counter()
    for owner, _p in students:
        why = app.sessions[owner].my_run.start()
        assert why is None, why
    runs = [app.class_runs.run_of(o) for o, _p in students]
    while not all(r.ended for r in runs):
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    print("| student | hidden (weights) | seed | training MSE | held-out MSE | seconds |")
    print("|---:|:---|---:|:---|:---|:---|")
    for k, r in enumerate(runs):
        s = r.summary
        print(f"| {k + 1} | {r.config.hidden} ({s.controller.n_params}) | {r.config.seed} | {s.train_mse:.3g} | {s.test_mse:.3g} "
              f"| {s.seconds:.1f} |")
    curve = {}
    for r in runs:
        curve.setdefault(r.config.hidden, []).append(r.summary.test_mse)
    entries = [app.state.notebook.get(r.id) for r in runs]
    print(json.dumps({
        "students": args.students, "workers": app.class_runs.workers, "cores": os.cpu_count(),
        "finished": sum(r.state == "finished" for r in runs),
        "entries_with_name": sum(e is not None and e.get("student", "").startswith("student ") for e in entries),
        "class_wall_s": round(wall, 1),
        "curve_median_held_out": {h: float(f"{statistics.median(v):.3g}") for h, v in sorted(curve.items())},
        "load_before": load_before, "load_after": Path("/proc/loadavg").read_text().split()[:3],
    }), flush=True)
    for _o, p in students:
        p.close()
    app.stop()


if __name__ == "__main__":
    main()
