"""The controllers the app opens with, one per arm, so the first drag already shows something sensible.

The app ships app/pretrained/<robot>-<method>.json for every robot in robots.names(), each trained
with that arm's default method and settings (`lab.evolve(robot)`): the file holds the settings,
the training and held-out MSE, the held-out position error (lab.experiments.arms) and the
controller. When an arm's file is missing or no longer loads, a quick run (QUICK) is trained
instead. Regenerate them all (the real arms take minutes each; times in docs/app.md) with

    python -m app.startup                     # every robot
    python -m app.startup --robots planar,ur5 # some of them
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time

import numpy as np

import lab
import robots

log = logging.getLogger(__name__)

PRETRAINED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pretrained")
QUICK = dict(generations=400, population=20, seed=0)
# the paper's arms and the snakes train in seconds: give them four times the paper's budget (real arms: their
# default); a tree (several end effectors) ten minutes of its budget defaults
SHIPPED = {"paper": dict(generations=4000), "snake": dict(generations=4000), "tree": dict(seconds=600)}


def default_method(robot: str) -> str:
    return lab.TrainConfig(robot=robot).method


def pretrained_path(robot: str, method: str | None = None, goal: str = "position") -> str:
    """app/pretrained/<robot>-<method>.json; a pose controller's <robot>-pose-<method>.json."""
    kind = "pose-" if goal == "pose" else ""
    return os.path.join(PRETRAINED_DIR, f"{robot}-{kind}{method or default_method(robot)}.json")


def made_for(controller, arm: robots.Arm) -> bool:
    """Whether a controller was made for this arm: its goals are the arm's task coordinates (a pose
    controller's: the arm's pose goals, app/tab/posegoal.py) and its outputs the arm's joints,
    within the arm's limits."""
    enc = getattr(controller, "encoding", None)
    if getattr(controller, "goal", "position") == "pose":
        from app.tab.posegoal import pose_refusal

        if pose_refusal(arm.name) is not None:
            return False
        lo, hi = getattr(enc, "q_lo", None), getattr(enc, "q_hi", None)
        if lo is not None and hi is not None and not (len(lo) == arm.nq and bool(np.allclose(lo, arm.lower))
                                                      and bool(np.allclose(hi, arm.upper))):
            return False
        nq = getattr(controller, "nq", None)
        return (lo is not None or nq is not None) and (nq is None or nq == arm.nq)
    fits = (enc is not None and tuple(enc.task_axes) == tuple(arm.task_axes) and len(enc.q_lo) == arm.nq
            and bool(np.allclose(enc.q_lo, arm.lower)) and bool(np.allclose(enc.q_hi, arm.upper)))
    chain = getattr(controller, "chain", None)  # a multi-head MLP picks its head by this arm's kinematics
    return fits and (chain is None or all(np.shape(a) == np.shape(b) and np.allclose(a, b)
                                          for a, b in zip(chain, arm.chain.arrays)))


def load_pretrained(robot: str, goal: str = "position"):
    """(controller, description) of the shipped controller of `robot` (goal "pose": its pose
    controller); raises when there is none or it does not load or does not fit the arm."""
    path = pretrained_path(robot, goal=goal)
    if goal == "pose" and not os.path.exists(path):  # a pose controller of another method
        import glob

        path = next(iter(sorted(glob.glob(os.path.join(PRETRAINED_DIR, f"{robot}-pose-*.json")))), path)
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    controller = lab.controller_from_dict(data["controller"])
    arm = robots.load(robot)
    if not made_for(controller, arm) or (getattr(controller, "goal", "position") == "pose") != (goal == "pose"):
        raise ValueError(f"{path} holds a controller for another arm or goal")
    if goal == "pose":
        from robots import pose

        controller(pose.sample_poses(arm, 1, seed=0))  # it runs
    else:
        controller(arm.sample_goals(1, seed=0))  # it runs
    err = data.get("held_out")
    what = (f"median error {err['median']:.3g} {err['unit']}" if err and "median" in err and "unit" in err
            else f"held-out MSE {data['test_mse']:.3g}")
    if err and "median_deg" in err:  # a pose controller's angle error too
        what += f", {err['median_deg']:.0f}°"
    settings = data["settings"]  # a budgeted run's generations are only its cap: say its time
    budget = f"{settings['seconds']:g} s" if settings.get("seconds") else f"{settings['generations']:,} generations"
    return controller, f"shipped ({budget}, {what})"


def startup_controller(robot: str = "planar", goal: str = "position"):
    """(controller, description): the arm's shipped controller, else a quickly trained one. For pose
    goals the arm's shipped pose controller, else its position controller on the pose's position
    (app/tab/posegoal.py PositionSeed: it ignores the turn; Start trains a pose controller). A robot
    outside the registry (erd:NAME, a URDF) has none shipped: (None, app.any_robot.NO_NETWORK)."""
    if robot not in robots.names():  # nothing shipped, and no quick run that would hold the page up
        from app.any_robot import NO_NETWORK

        return None, NO_NETWORK
    if goal == "pose":
        try:
            return load_pretrained(robot, "pose")
        except Exception as e:  # noqa: BLE001 - none shipped yet
            log.info("no shipped pose controller for %s (%s); the position network stands in", robot, e)
        from app.tab.posegoal import PositionSeed

        position, _note = startup_controller(robot)
        return PositionSeed(position), ("no pose network shipped for this arm: its position network, which "
                                        "ignores the turn (Start trains a pose network)")
    try:
        return load_pretrained(robot)
    except Exception as e:  # missing, or written by an older lab: train one now
        log.info("no shipped controller for %s (%s); training a quick one", robot, e)
    t0 = time.perf_counter()
    run = lab.evolve(robot, **QUICK)
    return run.controller, f"trained at startup in {time.perf_counter() - t0:.1f} s (held-out MSE {run.test_mse:.3g})"


def write_pretrained(run, held_out: dict | None = None, selection: dict | None = None) -> str:
    """Write a run as the shipped controller of its arm and method; returns the path. selection: how
    it was picked among runs of several training seeds (benchmarks/bench_arms.py --seeds), if it was."""
    path = pretrained_path(run.config.robot, run.config.method)
    os.makedirs(PRETRAINED_DIR, exist_ok=True)
    doc = {"settings": run.config.to_dict(), "train_mse": run.train_mse, "test_mse": run.test_mse,
           "seconds": run.seconds, "held_out": held_out, "controller": run.controller.to_dict()}
    if selection is not None:
        doc["selection"] = selection
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(doc, f)
    os.replace(tmp, path)
    return path


def main(argv=None) -> None:
    from lab.experiments import arms

    ap = argparse.ArgumentParser(prog="python -m app.startup", description="Train and write the app's shipped controllers.")
    ap.add_argument("--robots", default=",".join(robots.names()), help="comma-separated (default: every robot)")
    args = ap.parse_args(argv)
    for robot in args.robots.split(","):
        run = lab.evolve(robot, seed=0, **SHIPPED.get(robots.kind(robot), {}))
        stats = arms.held_out(robots.load(robot), run.controller)
        path = write_pretrained(run, stats)
        print(f"wrote {path}: {run.seconds:.0f} s, held-out MSE {run.test_mse:.4g}, median error "
              f"{stats['median']:.3g} {stats['unit']} ({stats['median_pct']:.2f} % of reach)", flush=True)


if __name__ == "__main__":
    main()
