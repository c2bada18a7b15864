"""`python -m lab reproduce`: the paper's experiment from the command line (see reproduce.py)."""

from __future__ import annotations

import os
import sys

from lab import methods
from lab.experiments import paper


def add_parser(sub) -> None:
    p = sub.add_parser("reproduce", help="reproduce the paper's Tables 3-5 and Figures 5-6",
                       description="Run every method on every arm --runs times (distinct seeds) in parallel, "
                                   "then write tables, figures, a generalization table, a Rerun recording and "
                                   "report.md to --out. Rerun with the same --out to resume.")
    p.add_argument("--runs", type=int, default=30, help="independent runs per arm and method (default 30)")
    p.add_argument("--generations", type=int, default=1000)
    p.add_argument("--population", type=int, default=50)
    p.add_argument("--methods", default=",".join(paper.METHODS),
                   help=f"comma-separated, among {', '.join(methods.names())} (default: the paper's, {','.join(paper.METHODS)})")
    p.add_argument("--robots", default="planar,scara", help="comma-separated (default planar,scara)")
    p.add_argument("--out", default="results/paper", help="output folder (default results/paper)")
    p.add_argument("--paper", action="store_true",
                   help="the paper's literal method (each method's paper preset) instead of the tuned defaults")
    p.add_argument("--seed", type=int, default=0, help="run i uses seed SEED + i (default 0)")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: all cores)")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run on a Ray cluster at ADDRESS ('local' starts one here); needs the 'ray' extra")
    p.add_argument("--overwrite", action="store_true",
                   help="redo stored runs made with other settings instead of refusing")
    p.add_argument("--no-recording", action="store_true", help="no Rerun recording (experiment.rrd)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def main(args) -> int:
    from lab.experiments.reproduce import ReproduceConfig, reproduce
    from lab.experiments.runs import ConfigMismatch

    cores = os.cpu_count() or 1
    if args.workers is not None and args.workers > cores:
        print(f"note: --workers {args.workers} capped at {cores}, this machine's cores", file=sys.stderr)
        args.workers = cores
    try:
        config = ReproduceConfig(runs=args.runs, generations=args.generations, population=args.population,
                                 methods=_names(args.methods), robots=_names(args.robots), out=args.out,
                                 paper=args.paper, seed=args.seed, workers=args.workers, ray=args.ray,
                                 overwrite=args.overwrite, progress=not args.quiet,
                                 recording=not args.no_recording)
        exp = reproduce(config)
    except (ValueError, TypeError, OSError, ConfigMismatch, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    done = len(exp.results)
    print(f"{done}/{len(exp.specs)} runs ({exp.executed} executed, {exp.resumed} resumed) in "
          f"{exp.wall_seconds:.1f} s; outputs in {config.out}/ (report.md)")
    for f in exp.failures:
        print(f"FAILED {f['name']} after {f['attempts']} attempts: {f['error']}", file=sys.stderr)
    return 1 if exp.failures else 0
