"""The app on a robot the lab was never told about: the presenter's tab watches a Start train it live.

    python benchmarks/bench_app_robot.py                                  # erd:ur3_limited, 60 s, Speed unlimited
    python benchmarks/bench_app_robot.py --robot my_arm.urdf#tool0 --seconds 30

`app.server.LabApp` opens on --robot (the same string `python -m app --robot` takes), a headless
presenter tab (app/probe.py) connects and watches, and the panel's own Start runs with its time budget
set to --seconds and Speed "unlimited" (`python -m app` starts at 20 generations a second, which a
presenter lifts to watch an arm learn in a minute). When the run ends, the controller the tab's arm
now shows (the run's best) is scored on held-out goals it never trained on
(lab.experiments.arms.held_out: the median error in % of reach) and refined by lab.solve (the share
within 0.1 mm in at most 3 steps): the figures `lab.evolve(robot, seconds=S)` gives headless
(benchmarks/bench_your_robot.py), now through the app. Prints one JSON line, with the frames the tab
received while the run trained (it watched it happen) and the generations the run made.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="erd:ur3_limited", help="a registered name, erd:NAME or a URDF path (#frame)")
    ap.add_argument("--seconds", type=float, default=60.0, help="the Start's time budget")
    ap.add_argument("--goals", type=int, default=2000, help="held-out goals scored")
    args = ap.parse_args()

    import lab
    from app.probe import Probe
    from app.server import LabApp
    from lab.experiments import arms

    folder = tempfile.mkdtemp(prefix="bench-app-robot-")
    t0 = time.perf_counter()
    app = LabApp(robot=args.robot, port=0, notebook=os.path.join(folder, "notebook.db"),
                 recordings=os.path.join(folder, "rec"), record=False, startup=None, speed=None)
    tab = Probe(app.url).start(60)
    try:
        tab.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
        page = time.perf_counter() - t0
        before = tab.frames if hasattr(tab, "frames") else None
        app.panel.budget.value = float(args.seconds)
        app.panel.generations.value = 10_000_000.0  # the budget ends the run
        why = app.panel.start()
        assert why is None, why
        started = time.perf_counter()
        runner = app.state.runner
        while runner.state in ("running", "paused"):
            time.sleep(0.2)
        time.sleep(1.0)  # the end's notebook entry and the arm's new controller
        arm, controller = app.state.arm, app.state.shown.controller
        stats = arms.held_out(arm, controller, n=args.goals)
        goals = arms.held_out_goals(arm, args.goals)
        solved = lab.solve(controller, arm, goals)
        result = {
            "robot": arm.name, "joints": arm.nq, "seconds": args.seconds, "page_s": round(page, 1),
            "run_wall_s": round(time.perf_counter() - started, 1), "state": runner.state,
            "generations": app.state.progress().get("generation"),
            "shown": app.state.shown.source,
            "held_out_median_pct_reach": round(float(stats["median_pct"]), 2) if "median_pct" in stats else stats,
            "refined_within_0.1mm_pct": round(100.0 * float(solved.converged.mean()), 2),
            "frames_to_tab": (tab.frames - before) if before is not None else None,
            "load": round(os.getloadavg()[0], 1),
        }
        print(json.dumps(result), flush=True)
    finally:
        tab.close()
        app.stop()


if __name__ == "__main__":
    main()
