"""python -m robots describe ROBOT [--ee FRAME ...]: a robot's chains, their joints with kind and limits,
and the candidate tool frames (robots/describe.py). ROBOT: a registered name, erd:NAME or a URDF path."""

from __future__ import annotations

import argparse
import logging
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m robots", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("describe", help="the chains, joints, limits and candidate frames of a robot")
    d.add_argument("robot", help="a registered name, erd:NAME (example-robot-data) or a URDF file's path")
    d.add_argument("--ee", nargs="+", default=None, help="the tool frame, or several (a tree)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    from robots.describe import describe

    try:
        text, loads = describe(args.robot, ee=args.ee)
    except (ValueError, OSError) as e:
        print(f"python -m robots describe: {e}", file=sys.stderr)
        return 2
    print(text)
    return 0 if loads else 2


if __name__ == "__main__":
    sys.exit(main())
