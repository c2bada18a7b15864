"""`python -m lab reproduce` and `python -m lab claims`: the experiments from the command line
(see reproduce.py and claims.py)."""

from __future__ import annotations

import os
import sys

from lab import methods
from lab.experiments import paper


def _scheduling(p) -> None:
    """The flags every experiment shares: seeds, where runs execute, resuming."""
    p.add_argument("--seed", type=int, default=0, help="run i uses seed SEED + i (default 0)")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: all cores)")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run on a Ray cluster at ADDRESS ('local' starts one here, 'auto' finds one); "
                        "needs the 'ray' extra")
    p.add_argument("--overwrite", action="store_true",
                   help="redo stored runs made with other settings instead of refusing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


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
    _scheduling(p)
    p.add_argument("--no-recording", action="store_true", help="no Rerun recording (experiment.rrd)")


def add_claims_parser(sub) -> None:
    from lab.experiments import claims as C

    labels = ", ".join(methods.get(m).label for m in C.METHODS)
    p = sub.add_parser("claims", help="test the paper's claims: evolution vs gradient descent, fixed vs resampled goals",
                       description=f"{labels} on {', '.join(C.ROBOTS)}, --runs seeds each, at equal budget in "
                                   "evaluations and separately at equal wall time; fixed vs resampled training goals "
                                   f"({methods.get(C.METHODS[0]).label}, {', '.join(C.RESAMPLE_ROBOTS)}). Writes "
                                   "claims.md (tables, Welch tests, verdicts) and figures to --out. Rerun with the "
                                   "same --out to resume. The default size is cut to fit 10 minutes on a 2-core "
                                   f"machine: {C.DEFAULT_RUNS} seeds instead of 10, a budget of "
                                   f"{C.DEFAULT_GENERATIONS} generations instead of 1000.")
    p.add_argument("--runs", type=int, default=C.DEFAULT_RUNS,
                   help=f"seeds per arm, method and setting (default {C.DEFAULT_RUNS}; the full test is 10)")
    p.add_argument("--generations", type=int, default=C.DEFAULT_GENERATIONS,
                   help=f"the budget, in generations of {methods.get(C.METHODS[0]).label} at its population "
                        f"(default {C.DEFAULT_GENERATIONS}; the paper's 1000); the equal-time limit scales with it")
    p.add_argument("--seconds", type=float, default=None,
                   help="the equal-time limit for every arm (default: generations x the reference method's "
                        "measured seconds per generation on the arm)")
    p.add_argument("--out", default="results/claims", help="output folder (default results/claims)")
    _scheduling(p)


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def _workers(args) -> int | None:
    cores = os.cpu_count() or 1
    if args.workers is not None and args.workers > cores:
        print(f"note: --workers {args.workers} capped at {cores}, this machine's cores", file=sys.stderr)
        return cores
    return args.workers


def _report(exp, out) -> int:
    print(f"{len(exp.results)}/{len(exp.specs)} runs ({exp.executed} executed, {exp.resumed} resumed) in "
          f"{exp.wall_seconds:.1f} s; outputs in {out}/")
    for f in exp.failures:
        print(f"FAILED {f['name']} after {f['attempts']} attempts: {f['error']}", file=sys.stderr)
    return 1 if exp.failures else 0


def _stopped(args) -> int:
    """Ctrl-C, SIGTERM or SIGHUP: the workers are ended (the executor does it), the finished runs stay stored."""
    print(f"stopped: the finished runs are stored in {args.out}/runs; the same command resumes", file=sys.stderr)
    return 130


def _refused(e: Exception) -> int:
    print(f"error: {e}", file=sys.stderr)
    return 2


REFUSED = (ValueError, TypeError, OSError, RuntimeError)  # runs.ConfigMismatch is a ValueError


def _run(args, make_config, run, experiment) -> int:
    """Build the config, run, report; a refused setting is one line, Ctrl-C/SIGTERM keep what is stored."""
    try:
        config = make_config()
        result = run(config)
    except REFUSED as e:
        return _refused(e)
    except KeyboardInterrupt:
        return _stopped(args)
    return _report(experiment(result), config.out)


def main(args) -> int:
    from lab.experiments.reproduce import ReproduceConfig, reproduce

    return _run(args, lambda: ReproduceConfig(
        runs=args.runs, generations=args.generations, population=args.population, methods=_names(args.methods),
        robots=_names(args.robots), out=args.out, paper=args.paper, seed=args.seed, workers=_workers(args),
        ray=args.ray, overwrite=args.overwrite, progress=not args.quiet, recording=not args.no_recording),
        reproduce, lambda exp: exp)


def claims_main(args) -> int:
    from lab.experiments.claims import ClaimsConfig, claims

    return _run(args, lambda: ClaimsConfig(
        runs=args.runs, generations=args.generations, seconds=args.seconds, out=args.out, seed=args.seed,
        workers=_workers(args), ray=args.ray, overwrite=args.overwrite, progress=not args.quiet),
        claims, lambda result: result.experiment)
