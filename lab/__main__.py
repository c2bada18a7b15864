"""Command line: `python -m lab train ...` (see `python -m lab --help`)."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: runs share two cores with others

import argparse  # noqa: E402
import sys  # noqa: E402

import robots  # noqa: E402

from .config import METHODS, TrainConfig  # noqa: E402


def _train_parser(sub) -> None:
    p = sub.add_parser("train", help="evolve one controller and print its training and held-out MSE",
                       description="Evolve one neuro-controller; shows a progress bar, then the final "
                                   "training and held-out MSE.")
    p.add_argument("--robot", default="planar", help=f"one of: {', '.join(robots.names())}")
    p.add_argument("--method", default="cmaes", help=f"one of: {', '.join(METHODS)}")
    p.add_argument("--generations", type=int, default=1000)
    p.add_argument("--population", type=int, default=50)
    p.add_argument("--targets", type=int, default=70, help="number of fixed training goals")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--paper", action="store_true", help="the paper's method literally (lab.config.PAPER_PRESET)")
    p.add_argument("--hidden", type=int, default=None, help="MLP hidden units; NEAT: initial hidden nodes")
    p.add_argument("--sigma0", type=float, default=None, help="CMA-ES initial step size")
    p.add_argument("--features", default=None, choices=("cartesian", "polar"), help="network inputs")
    p.add_argument("--test-goals", type=int, default=None, help="held-out goals (default 1000)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def train(args) -> int:
    from tqdm import tqdm

    from .evolve import Run
    from .runner import Runner

    try:
        config = TrainConfig.preset(
            paper=args.paper, robot=args.robot, method=args.method, generations=args.generations,
            population=args.population, targets=args.targets, seed=args.seed, hidden=args.hidden,
            sigma0=args.sigma0, features=args.features, test_goals=args.test_goals)
    except (ValueError, TypeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    runner = Runner(config)
    bar = tqdm(total=config.generations, unit="gen", disable=args.quiet, dynamic_ncols=True,
               desc=f"{config.robot} {config.method}")

    def progress(event) -> None:
        bar.update(1)
        if event.index % 10 == 0 or event.index == config.generations - 1:
            bar.set_postfix(best=f"{event.best:.4g}", median=f"{event.median:.4g}", refresh=False)

    runner.subscribe(progress)
    try:
        summary = runner.run()
    except KeyboardInterrupt:  # pragma: no cover - interactive
        runner.stop()
        summary = runner.join()
    bar.close()
    if summary.state == "failed":
        print(f"error: training failed: {summary.error}", file=sys.stderr)
        return 1
    run = Run.from_summary(summary)
    print(f"robot {config.robot}  method {config.method}{' (paper preset)' if config.paper else ''}  "
          f"seed {config.seed}  generations {summary.generations}  evaluations {run.evaluations}  "
          f"parameters {run.n_params}  time {run.seconds:.1f} s")
    print(f"training MSE  {run.train_mse:.6g}  ({config.targets} goals)")
    print(f"held-out MSE  {run.test_mse:.6g}  ({config.test_goals} goals)")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lab", description="Neuro-IK Lab: evolve neuro-controllers.")
    sub = parser.add_subparsers(dest="command", required=True)
    _train_parser(sub)
    args = parser.parse_args(argv)
    return {"train": train}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
