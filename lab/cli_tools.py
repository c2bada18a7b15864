"""`python -m lab solve` and `python -m lab export`: a controller used, and written for elsewhere.

    python -m lab solve --robot erd:ur3 --ee tool0 --goal pose     # the solver alone on 1,000 poses
    python -m lab solve --robot panda --goal pose --controller shipped
    python -m lab export app/pretrained/panda-pose-cmaes.json --onnx panda.onnx
    python -m lab export recordings/ur5-cmaes-s0-....rrd --onnx ur5.onnx

A RUN is a recording (.rrd, `python -m lab train`'s), a controller file (.json: app/pretrained's
format {"settings", ..., "controller"}, or a controller's to_dict() alone), or "shipped" (the robot's
shipped controller, lab.pretrained).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from lab.methods import DEFAULT_METHOD

ROBOT_HELP = ("a registered name (planar, ur5, panda, ...), erd:NAME (an example-robot-data robot: erd:ur3, "
              "erd:bravo7_no_ee), or a URDF file's path")


def load_run(run: str, robot=None, goal: str = "position", method: str = DEFAULT_METHOD):
    """(controller, robot string or None) of a RUN (see the module)."""
    from lab.problem.controllers import controller_from_dict

    if run == "shipped":
        from lab.shipped import pretrained

        if robot is None:
            raise ValueError("RUN 'shipped' needs --robot")
        return pretrained(robot, goal=goal, method=method), robot
    path = Path(run)
    if not path.is_file():
        raise ValueError(f"{run}: no such file (a RUN is a .rrd recording, a controller .json, or 'shipped')")
    if path.suffix == ".rrd":
        from lab.recording.replay import read_recording

        rec = read_recording(path)
        return controller_from_dict(rec.controller_doc()["controller"]), rec.protocol.get("robot")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{run}: not a recording (.rrd) nor a controller file (JSON): {e}") from None
    doc = data.get("controller", data) if isinstance(data, dict) else data
    settings = data.get("settings") if isinstance(data, dict) else None
    return controller_from_dict(doc), (settings or {}).get("robot") if isinstance(settings, dict) else None


def sample_goals(arm, controller_goal: str, n: int, seed: int) -> np.ndarray:
    """n held-out goals of the arm: poses (n, 4, 4) for pose goals, else positions."""
    if controller_goal == "pose":
        from robots import pose

        return pose.sample_poses(arm, n, seed=seed)
    return arm.sample_goals(n, seed=seed)


def add_parsers(sub) -> None:
    p = sub.add_parser("solve", help="solve held-out goals of a robot: a controller's answers made exact (lab.solve)",
                       description="Sample held-out goals of a robot and solve them with lab.solve (its defaults: "
                                   "position goals, the network then 3 refinement steps; pose goals, the compiled "
                                   "solver with TRAC-IK's terms, 5 ms, 1e-5 m, 1e-5 rad); prints the success and "
                                   "the time a goal.")
    p.add_argument("--robot", default="ur5", help=ROBOT_HELP)
    p.add_argument("--ee", default=None, metavar="FRAME", help="the tool frame (default: the robot's)")
    p.add_argument("--goal", default="position", choices=("position", "pose"))
    p.add_argument("--controller", default=None, metavar="RUN",
                   help="a .rrd recording, a controller .json, 'shipped' (lab.pretrained) or 'none' (the solver "
                        "alone; pose goals only). Default: the shipped one where there is one, else none")
    p.add_argument("--goals", type=int, default=1000, help="held-out goals (default 1000)")
    p.add_argument("--seed", type=int, default=1, help="the goals' seed (default 1)")
    p.add_argument("--seconds", type=float, default=None, help="pose goals: a goal's budget (default 0.005)")
    p.add_argument("--steps", type=int, default=None, help="refinement steps (default 3; pose goals: the solver)")
    p.add_argument("--tol", type=float, default=None, help="position tolerance [m] (default: lab.solve's)")
    p.add_argument("--angle-tol", type=float, default=None, help="angle tolerance [rad] (default: lab.solve's)")

    p = sub.add_parser("export", help="write a controller's network as ONNX (lab/export.py)",
                       description="Write the network part of a controller as an ONNX file (float64: the input "
                                   "encoding, the network, the output mapping; not the turn, the head choice, a "
                                   "pose network's closed form or the refinement: docs/api.md), checked with "
                                   "onnxruntime against the lab's own outputs to 1e-6 on held-out goals.")
    p.add_argument("run", metavar="RUN", help="a .rrd recording, a controller .json, or 'shipped' (with --robot)")
    p.add_argument("--onnx", required=True, metavar="PATH", help="the ONNX file to write")
    p.add_argument("--robot", default=None, help="the robot (default: the RUN's own); " + ROBOT_HELP)
    p.add_argument("--goal", default="position", choices=("position", "pose"), help="with RUN 'shipped'")
    p.add_argument("--goals", type=int, default=1000, help="held-out goals of the check (default 1000)")


def solve_main(args) -> int:
    import lab
    from lab.problem.robot import load_arm

    try:
        arm = load_arm(args.robot, args.ee)
        which = args.controller
        if which is None:
            from lab.shipped import pretrained_path

            which = "shipped" if pretrained_path(arm, args.goal).is_file() else "none"
        controller = None if which == "none" else load_run(which, arm, args.goal)[0]
        if args.goals < 1:
            raise ValueError(f"--goals must be at least 1, got {args.goals}")
        goals = sample_goals(arm, args.goal, args.goals, args.seed)
        t0 = time.perf_counter()
        s = lab.solve(controller, arm, goals, seconds=args.seconds, steps=args.steps, tol=args.tol,
                      angle_tol=args.angle_tol)
        per_goal = (time.perf_counter() - t0) / len(goals)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    unit = "m" if robot_in_metres(arm) else "units"
    angle = f" and {s.angle_tol:.3g} rad" if s.angle_tol is not None else ""
    print(f"robot {arm.name}  ({arm.nq} joints, tool {', '.join(arm.effectors)})  controller {which}")
    print(f"{args.goal} goals {len(goals)}: {100 * s.success:.2f} % within {s.tol:.3g} {unit}{angle}; "
          f"median error {np.median(s.error):.3g} {unit}"
          + (f", {np.degrees(np.median(s.angle)):.3g} degrees" if s.angle is not None else "")
          + f"; {1e3 * per_goal:.3f} ms a goal (the call's wall time / goals, one thread)")
    return 0


def robot_in_metres(arm) -> bool:
    from lab.problem.robot import arm_kind

    return arm_kind(arm) in ("real", "tree")


def export_main(args) -> int:
    from lab import export
    from lab.problem.robot import load_arm

    try:
        controller, robot = load_run(args.run, args.robot, args.goal)
        robot = args.robot or robot
        goals = None
        if robot is not None:
            arm = load_arm(robot)
            robot = arm.name
            if args.goals < 1:
                raise ValueError(f"--goals must be at least 1, got {args.goals}")
            goals = sample_goals(arm, getattr(controller, "goal", "position"), args.goals, 1)
        worst = export.save(controller, args.onnx, goals, robot=robot)
    except ImportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    heads = getattr(controller, "heads", 1)
    print(f"wrote {args.onnx}: {controller.kind} network, {getattr(controller, 'goal', 'position')} goals, "
          f"{heads} head(s), {controller.encoding.n_outputs} joints; inputs 'goals', outputs 'outputs' and "
          "'joints' (heads, n, nq)")
    if worst is not None:
        print(f"checked with onnxruntime on {args.goals} held-out goals of {robot}: largest difference {worst:.2g} "
              f"(tolerance {export.TOLERANCE:g})")
    else:
        print("not checked: " + ("no robot known for the RUN (--robot)" if goals is None else "onnxruntime is "
                                 "not installed (pip install 'neuro-ik-lab[onnx]')"))
    left = export.left_out(controller)
    if left:
        print("left out (the lab does them with the arm's kinematics): " + "; ".join(left))
    return 0
