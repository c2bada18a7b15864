"""Command line: `python -m lab train ...` (see `python -m lab --help`)."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: runs share two cores with others

import argparse  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402

import robots  # noqa: E402

from lab import cli_tools, methods  # noqa: E402
from lab.experiments import cli as experiments_cli  # noqa: E402
from lab.problem import environment  # noqa: E402
from lab.problem.encoding import FEATURES  # noqa: E402
from lab.running.config import UNBOUNDED, TrainConfig  # noqa: E402


def method_options() -> dict:
    """Every registered method's options: name -> (type, help, [methods that have it])."""
    seen: dict = {}
    for m in methods.all_methods():
        for name, (_default, kind, text) in m.options.describe().items():
            seen.setdefault(name, (kind, text, []))[2].append(m.name)
    return seen


def add_method_options(p) -> None:
    """A flag per method option (--sigma0, --mutation-power, ...), each unset by default."""
    group = p.add_argument_group("method options (each method's own; unset: its default for the arm)")
    for name, (kind, text, owners) in method_options().items():
        flag = "--" + name.replace("_", "-")
        text = f"{text} [{', '.join(owners)}]"
        if kind is bool:
            group.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=None, help=text)
        else:
            group.add_argument(flag, dest=name, type=kind, default=None, help=text)


def given_options(args) -> dict:
    return {name: getattr(args, name) for name in method_options() if getattr(args, name, None) is not None}


def _train_parser(sub) -> None:
    p = sub.add_parser("train", help="evolve one controller and print its training and held-out MSE",
                       description="Evolve one neuro-controller; shows a progress bar, then the final "
                                   "training and held-out MSE.")
    p.add_argument("--robot", default="planar", help=f"one of: {', '.join(robots.names())}; or erd:NAME (an "
                   "example-robot-data robot: erd:ur3, erd:bravo7_no_ee), or a URDF file's path")
    p.add_argument("--ee", default=None, metavar="FRAME",
                   help="the tool frame (default: the robot's; a URDF's: the end of its longest chain)")
    p.add_argument("--method", default=methods.DEFAULT_METHOD,
                   help="; ".join(f"{m.name}: {m.summary}" for m in methods.all_methods()))
    p.add_argument("--generations", type=int, default=None, help="default: the method's for the arm (the paper: 1000)")
    p.add_argument("--seconds", type=float, default=None, metavar="S",
                   help="a time budget: the run ends after S seconds of optimizer time, with its best controller "
                        "(with --generations too: whichever comes first; without: generations unbounded, the "
                        "method's defaults for that budget)")
    p.add_argument("--population", type=int, default=None, help="default: the method's for the arm (the paper: 50)")
    p.add_argument("--targets", type=int, default=None,
                   help="number of fixed training goals (default: the method's for the arm; the paper: 70)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--paper", action="store_true", help="the paper's method literally (the method's `paper` settings: TrainConfig.preset(paper=True))")
    p.add_argument("--hidden", type=int, default=None, help="MLP hidden units; graph methods: initial hidden nodes")
    p.add_argument("--heads", type=int, default=None,
                   help="MLP output heads, each a joint-value proposal; the one closest to the goal answers "
                        "(default: the method's for the arm, else 1)")
    p.add_argument("--goal", default="position", choices=("position", "pose"),
                   help="what the network answers: positions, or tool frames (pose: a real arm; docs/pose.md)")
    p.add_argument("--reach", type=int, default=None, metavar="PASSES",
                   help="pose goals: passes of the closed-form elbow and shoulder (default: the method's and arm's; "
                        "0: the network places the arm itself; docs/pose.md)")
    p.add_argument("--features", default=None, choices=FEATURES, help="network inputs")
    p.add_argument("--margin", type=float, default=None, help="output range widening before clipping to the limits")
    p.add_argument("--test-goals", type=int, default=None, help="held-out goals (default 1000)")
    p.add_argument("--resample", action="store_true",
                   help="draw new training goals every generation (the paper: fixed goals); the best so far "
                        "is kept by its MSE on the fixed goals")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    rec = p.add_mutually_exclusive_group()
    rec.add_argument("--recording", metavar="PATH", default=None,
                     help="Rerun recording to write (a .rrd file or a folder; default: "
                          "recordings/<robot>-<method>-s<seed>-<time>.rrd)")
    rec.add_argument("--no-recording", action="store_true", help="write no Rerun recording")
    p.add_argument("--overwrite", action="store_true", help="replace a recording already at --recording")
    add_method_options(p)


def _replay_parser(sub) -> None:
    p = sub.add_parser("replay", help="show a Rerun recording of a training run",
                       description="Open a recording in the Rerun viewer; with no display (or --web), serve "
                                   "the web viewer on 127.0.0.1 and print its URL. Ends the viewer on exit.")
    p.add_argument("path", help="a .rrd file written by `python -m lab train`")
    p.add_argument("--web", action="store_true", default=None, help="serve the web viewer even with a display")
    p.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                   help="end the viewer after this many seconds (default: when it is closed, or Ctrl-C)")
    p.add_argument("--web-port", type=int, default=None, help="web viewer port (default: a free one)")
    p.add_argument("--grpc-port", "--data-port", dest="grpc_port", type=int, default=None,
                   help="port of the HTTP server the web viewer loads the recording from (default: a free one)")


def _replay_arguments(args) -> str | None:
    """What is wrong with replay's numbers, or None (a NaN timeout never ended; a negative one or a
    port out of range printed the URL of a viewer already gone)."""
    import math

    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout > 0):
        return f"--timeout must be a positive number of seconds, got {args.timeout}"
    for name in ("web_port", "grpc_port"):
        port = getattr(args, name)
        if port is not None and not 1 <= port <= 65535:
            return f"--{name.replace('_', '-')} must be in 1..65535, got {port}"
    return None


def replay(args) -> int:
    from lab.recording.replay import replay as show

    try:
        bad = _replay_arguments(args)
        if bad:
            raise ValueError(bad)
        return show(args.path, web=args.web, timeout=args.timeout, web_port=args.web_port, grpc_port=args.grpc_port)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def train(args) -> int:
    from tqdm import tqdm

    from lab.running.evolve import Run
    from lab.running.runner import Runner

    try:
        config = TrainConfig.preset(
            paper=args.paper, robot=args.robot, ee=args.ee, method=args.method, generations=args.generations,
            population=args.population, targets=args.targets, seed=args.seed, hidden=args.hidden,
            heads=args.heads, features=args.features, margin=args.margin, test_goals=args.test_goals, resample=args.resample,
            seconds=args.seconds, goal=args.goal, reach=args.reach, **given_options(args))
    except (ValueError, TypeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    runner = Runner(config)
    logger = None
    if not args.no_recording:
        from lab.recording.logger import RerunLogger

        try:  # before training: a recording that cannot be written stops here
            logger = RerunLogger(runner, path=args.recording, overwrite=args.overwrite)
        except (OSError, ValueError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        runner.subscribe(logger)
    unbounded = config.seconds is not None and config.generations == UNBOUNDED
    bar = tqdm(total=None if unbounded else config.generations, unit="gen", disable=args.quiet, dynamic_ncols=True,
               desc=f"{config.robot} {config.method}")

    def progress(event) -> None:
        bar.update(1)
        if event.index % 10 == 0 or event.index == config.generations - 1:
            left = {} if config.seconds is None else {"left": f"{max(config.seconds - event.seconds, 0):.1f}s"}
            bar.set_postfix(best=f"{event.best:.4g}", median=f"{event.median:.4g}", **left, refresh=False)

    runner.subscribe(progress)
    try:  # the run in its own thread: Ctrl-C reaches this one, which stops the run after its generation
        runner.start()
        summary = runner.join()
    except KeyboardInterrupt:
        runner.stop()
        summary = runner.join()
    finally:
        if logger is not None:
            try:
                logger.close(wait=True)  # the run's end has closed it: waits for the compaction
            except RuntimeError:
                pass  # said in one line when it happened (logger.failure())
    bar.close()
    if summary.state == "failed":
        print(f"error: training failed: {summary.error}", file=sys.stderr)
        return 1
    run = Run.from_summary(summary)
    print(f"robot {config.robot}  method {config.method}{' (paper preset)' if config.paper else ''}  "
          f"seed {config.seed}  generations {summary.generations}  evaluations {run.evaluations}  "
          f"parameters {run.n_params}  time {run.seconds:.1f} s"
          + (f" (budget {config.seconds:g} s{', spent' if summary.ended_by == 'seconds' else ''})"
             if config.seconds is not None else ""))
    if config.goal == "pose":
        print("fitness: mean of ||p - p_goal||^2 + (L angle)^2 over the pose goals "
              f"(L = {runner.problem.encoding.weight:.4g} m/rad)")
    print(f"training MSE  {run.train_mse:.6g}  ({config.targets} goals)")
    print(f"held-out MSE  {run.test_mse:.6g}  ({config.test_goals} goals)")
    if logger is not None and logger.failure() is None:
        print(f"recording     {logger.path}  (python -m lab replay {logger.path})")
    return 0


def _interrupt(signum, _frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def main(argv=None) -> int:
    """The command; a LAB_* environment variable that is not accepted: one line and exit status 2."""
    try:
        environment.check_all()  # before any work: a worker thread would only see it after the start
        return _main(argv)
    except environment.SettingError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def _main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lab", description="Neuro-IK Lab: evolve neuro-controllers.")
    sub = parser.add_subparsers(dest="command", required=True)
    _train_parser(sub)
    _replay_parser(sub)
    experiments_cli.add_parser(sub)
    experiments_cli.add_claims_parser(sub)
    cli_tools.add_parsers(sub)
    args = parser.parse_args(argv)
    # a service manager's SIGTERM and a closing terminal's SIGHUP stop a command as Ctrl-C does: a
    # training is stopped after its generation, an experiment's workers are ended, nothing is left running
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    return {"train": train, "replay": replay, "reproduce": experiments_cli.main,
            "claims": experiments_cli.claims_main, "solve": cli_tools.solve_main,
            "export": cli_tools.export_main}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
