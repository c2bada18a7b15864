"""What a student run pays beside its training: N runs one after another through ClassRuns (one worker),
with the class's warm workers and with a fresh worker process a run (as before issue #57), side by side.

    python benchmarks/bench_run_overhead.py                   # 4 runs of a 3 s budget each way
    python benchmarks/bench_run_overhead.py --runs 6 --seconds 8 --record

Per run: Submit to its first generation, its last generation to its notebook entry, and the overhead
(Submit to notebook entry less its optimizer seconds). The first run of each way is left out of the
medians (the warm workers start with a class's first run). --queued: every run submitted at once, as a
class pressing Start: (wall time to the last entry - the runs' optimizer seconds) / runs, the first run's
start included. --record: each run recorded (.rrd), so the writer's start and close count too, and a
third way, "served": the warm workers with one writer process for every recording
(lab.recording.service.WriterService), as the classroom server records; "fresh" and "warm" record
with a writer process a run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def runs_of(way: str, n: int, seconds: float, record: bool, queued: bool = False) -> list[dict]:
    import lab
    from app.classroom.class_runs import ClassRuns
    from app.server import rerun_recorder
    from app.training.notebook import Notebook
    from lab.recording.service import WriterService
    from lab.running.worker import ProcessRunner

    def fresh(config, history_limit=None):
        return ProcessRunner(config, history_limit=history_limit, spare=False)

    folder = tempfile.mkdtemp(prefix="bench-overhead-")
    service = WriterService() if way == "served" else None  # started before the first run, as the app's first
    runs = ClassRuns(Notebook(os.path.join(folder, "notebook.db")), None, workers=1,
                     runner=fresh if way == "fresh" else None,
                     recorder=rerun_recorder(os.path.join(folder, "class"), service) if record else None)
    rows = []
    if queued:  # every run submitted at once (a class pressing Start): the wall time less the training, a run
        t = time.time()
        for k in range(n):
            why = runs.submit(k, lab.TrainConfig(robot="planar", method=lab.methods.DEFAULT_METHOD, seconds=seconds, population=20, seed=k))
            assert why is None, why
        while not all(runs.notebook.get(r.id) is not None for r in runs.rows()):
            time.sleep(0.01)
        wall = time.time() - t
        assert all(r.state == "finished" for r in runs.rows())
        runs.shutdown()
        service and service.close()
        return [{"overhead_s": (wall - sum(r.summary.seconds for r in runs.rows())) / n}] * 2
    for k in range(n):
        first: list[float] = []
        t = time.time()
        why = runs.submit(k, lab.TrainConfig(robot="planar", method=lab.methods.DEFAULT_METHOD, seconds=seconds, population=20, seed=k))
        assert why is None, why
        run = runs.run_of(k)
        while run.runner is None:
            time.sleep(0.005)
        run.runner.subscribe(lambda _e, first=first: first or first.append(time.time()))
        while runs.notebook.get(run.id) is None:
            time.sleep(0.01)
        end = time.time()
        assert run.state == "finished" and first, run.status()
        rows.append({"to_first_s": first[0] - t, "last_to_entry_s": end - first[0] - run.summary.seconds,
                     "overhead_s": end - t - run.summary.seconds})
    runs.shutdown()
    service and service.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=3.0, help="each run's time budget")
    ap.add_argument("--record", action="store_true", help="record each run (.rrd), as the classroom server does")
    ap.add_argument("--queued", action="store_true", help="submit every run at once: the overhead a run of the class's wall time")
    args = ap.parse_args()
    result = {"runs": args.runs, "seconds": args.seconds, "record": args.record, "queued": args.queued,
              "load": round(os.getloadavg()[0], 1)}
    for way in ("fresh", "warm") + (("served",) if args.record else ()):
        rows = runs_of(way, args.runs, args.seconds, args.record, args.queued)[1:]
        for key in ("overhead_s",) if args.queued else ("to_first_s", "last_to_entry_s", "overhead_s"):
            result[f"{way}_{key}"] = round(statistics.median(r[key] for r in rows), 2)
    result["overhead_ratio_fresh_to_warm"] = round(result["fresh_overhead_s"] / max(result["warm_overhead_s"], 1e-3), 1)
    if args.record:
        result["overhead_ratio_warm_to_served"] = round(result["warm_overhead_s"] / max(result["served_overhead_s"], 1e-3), 1)
    result["load_after"] = round(os.getloadavg()[0], 1)
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
