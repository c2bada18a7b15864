"""`lab.pretrained`: the controllers the project ships, one call away.

    controller = lab.pretrained("ur5")                  # its position controller (CMA-ES)
    controller = lab.pretrained("panda", goal="pose")   # its pose controller
    s = lab.solve(controller, "panda", poses)           # then the compiled solver (lab/solver.py)

The files are app/pretrained/<robot>-<method>.json (a pose controller's <robot>-pose-<method>.json),
package data of `app` (python -m app.startup and the benchmarks write them; app opens each arm with
its own). They are located through the import system without importing app (lab knows nothing of
the GUI; importlib.util.find_spec reads where the package lies), so an installed lab finds them as a
checkout does.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

from lab.methods import DEFAULT_METHOD
from lab.problem.controllers import Controller, controller_from_dict
from lab.problem.pose_encoding import check_goal
from lab.problem.robot import load_arm, robot_name


def pretrained_dir() -> Path:
    """The folder of the shipped controllers (app/pretrained/), found without importing app."""
    spec = importlib.util.find_spec("app")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the shipped controllers are package data of `app`, which is not installed")
    return Path(next(iter(spec.submodule_search_locations))) / "pretrained"


def pretrained_path(robot, goal: str = "position", method: str = DEFAULT_METHOD) -> Path:
    """app/pretrained/<robot>-<method>.json, or <robot>-pose-<method>.json for goal "pose"."""
    kind = "pose-" if check_goal(goal) == "pose" else ""
    return pretrained_dir() / f"{robot_name(robot)}-{kind}{method}.json"


def shipped(goal: str = "position", method: str = DEFAULT_METHOD) -> tuple[str, ...]:
    """The robots with a shipped controller for these goals and method, by name."""
    tail = f"-pose-{method}.json" if check_goal(goal) == "pose" else f"-{method}.json"
    folder = pretrained_dir()
    names = (p.name[: -len(tail)] for p in folder.glob(f"*{tail}")) if folder.is_dir() else ()
    return tuple(sorted(n for n in names if goal == "pose" or not n.endswith("-pose")))


def pretrained(robot, goal: str = "position", method: str = DEFAULT_METHOD) -> Controller:
    """The controller the project ships for `robot` (a name or an Arm), for position or pose goals,
    trained by `method`; ValueError naming the robots that have one where this one has none, and
    where the file holds a controller of another arm or goal."""
    arm = load_arm(robot)
    path = pretrained_path(arm, goal, method)
    if not path.is_file():
        have = shipped(goal, method)
        raise ValueError(f"no shipped {goal} controller of {method} for {arm.name} (shipped: "
                         f"{', '.join(have) or 'none'}); train one: lab.evolve({arm.name!r}, method={method!r}, "
                         f"goal={goal!r}, seconds=60)")
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    controller = controller_from_dict(data["controller"], arm)
    if getattr(controller, "goal", "position") != goal:
        raise ValueError(f"{path} holds a controller of {controller.goal} goals, not {goal}")
    return controller
