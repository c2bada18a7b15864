"""What the Rerun logger costs a training run.

Times a planar CMA-ES run (default 1000 generations, population 50, 70 goals) with and without
lab.recording.logger.RerunLogger, interleaved (A B, B A, ...) with the same seed in each pair so that
load from other processes hits both alike. Prints the median wall times of `runner.run()`
(which includes writing and closing the recording) and their ratio (target <= 1.10); the CPU time
ratio (less sensitive to other processes on a shared machine; it includes the writer process,
whose work runs beside the optimizer on the other core, and its compaction of the file after
the run); the time spent before the run (creating the logger) and the recording's size.

    .venv/bin/python benchmarks/bench_recording.py [--repeats 10] [--generations 1000] [--method neat]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lab import Runner, TrainConfig, methods  # noqa: E402
from lab.recording.logger import RerunLogger  # noqa: E402


def one_run(config: TrainConfig, path: Path | None, **logger_options) -> dict:
    runner = Runner(config)
    t0 = time.perf_counter()
    logger = RerunLogger(runner, path=path, **logger_options) if path is not None else None
    t_setup = time.perf_counter() - t0
    if logger is not None:
        runner.subscribe(logger)
    t0, c0 = time.perf_counter(), _cpu()
    summary = runner.run()
    t_run = time.perf_counter() - t0
    if logger is not None:
        logger.wait()  # compaction, by the writer process after the run: waited for here, timed apart
    t_compact, c_run = time.perf_counter() - t0 - t_run, _cpu() - c0
    assert summary.state == "finished", summary.error
    size = path.stat().st_size if path is not None else 0
    return {"run": t_run, "cpu": c_run, "setup": t_setup, "compact": t_compact, "size": size,
            "mse": summary.train_mse}


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the writer process, which runs `rerun rrd
    optimize` for the compaction)."""
    me, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + children.ru_utime + children.ru_stime


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10, help="pairs of runs (the box is noisy: runs vary by 10-15 %%)")
    ap.add_argument("--generations", type=int, default=1000)
    ap.add_argument("--population", type=int, default=50)
    ap.add_argument("--robot", default="planar")
    ap.add_argument("--method", default=methods.DEFAULT_METHOD, choices=methods.names())
    ap.add_argument("--pose-every", type=int, default=None)
    ap.add_argument("--no-compact", action="store_true")
    args = ap.parse_args(argv)
    options = {k: v for k, v in dict(pose_every=args.pose_every).items()
               if v is not None}
    if args.no_compact:
        options["compact"] = False
    config = TrainConfig(robot=args.robot, method=args.method, generations=args.generations,
                         population=args.population)
    one_run(config.replace(generations=20), None)  # compile and warm caches
    plain, logged = [], []
    with tempfile.TemporaryDirectory(prefix="bench-recording-") as tmp:
        for k in range(args.repeats):
            cfg = config.replace(seed=k)
            path = Path(tmp) / f"run{k}.rrd"
            order = (None, path) if k % 2 == 0 else (path, None)
            for p in order:
                r = one_run(cfg, p, **options)
                (logged if p is not None else plain).append(r)
            a, b = plain[-1], logged[-1]
            print(f"pair {k}: without {a['run']:.3f} s   with {b['run']:.3f} s   ratio {b['run'] / a['run']:.3f}   "
                  f"CPU ratio {b['cpu'] / a['cpu']:.3f}   file {b['size'] / 1024:.0f} KiB", flush=True)
    t0 = statistics.median(r["run"] for r in plain)
    t1 = statistics.median(r["run"] for r in logged)
    ratios = [b["run"] / a["run"] for a, b in zip(plain, logged)]
    print(f"\n{args.robot} {args.method}, {args.generations} generations x {args.population}, {args.repeats} pairs")
    print(f"median run time   without logger {t0:.3f} s   with logger {t1:.3f} s")
    print(f"ratio of medians  {t1 / t0:.3f}   (median of pair ratios {statistics.median(ratios):.3f}; target <= 1.10)")
    c0 = statistics.median(r["cpu"] for r in plain)
    c1 = statistics.median(r["cpu"] for r in logged)
    print(f"CPU time          without logger {c0:.3f} s   with logger {c1:.3f} s   ratio {c1 / c0:.3f}")
    print(f"compaction        {statistics.median(r['compact'] for r in logged) * 1e3:.0f} ms after the run "
          f"(by the writer process; in the CPU time, not in the run time)")
    print(f"logger creation   {statistics.median(r['setup'] for r in logged) * 1e3:.1f} ms (before the run, not counted)")
    print(f"recording size    {statistics.median(r['size'] for r in logged) / 1024:.0f} KiB (median)")


if __name__ == "__main__":
    main()
