"""A robot the lab was never told about, trained and solved with no settings.

For each robot (default: example-robot-data's UR3 by its URDF path, a 6-joint arm the registry lacks,
and erd:panda, a 7-joint one under a name the lab's defaults do not know), in one process and one
thread (LAB_THREADS=1, OPENBLAS_NUM_THREADS=1):

    position   lab.evolve(robot, seconds=S): its held-out median error in % of reach (2,000 goals,
               lab.experiments.arms.held_out), then lab.solve(controller, arm, goals) (the network
               and at most 3 refinement steps): the share within 0.1 mm and the time a goal
    solver     lab.solve(None, arm, poses): the compiled pose solver alone from the rest pose (its
               default: TRAC-IK's terms, 5 ms, 1e-5 m, 1e-5 rad): the share solved and the time a pose
    pose       lab.evolve(robot, seconds=S, goal="pose"), then lab.solve(controller, arm, poses): the
               network's proposals first, then the same solver

Times are the call's wall time over its goals (the network included), and its CPU time (`cpu`), in ms
a goal: on a busy machine the wall time rises, and the solver's 5 ms budget (wall time) is cut short
when the process waits for a core, so its success falls with the load;
the `load` column is the 1-minute load average when each row began, and `cpu s` the CPU time the
position run's 60 s of wall time got (a budget is wall time: on a shared machine a run gets less).

    python benchmarks/bench_your_robot.py                       # erd:ur3 and erd:panda, 60 s each
    python benchmarks/bench_your_robot.py --robots erd:ur3 --seconds 20 --poses 500
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("LAB_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import lab  # noqa: E402
import robots  # noqa: E402
from lab.experiments import arms  # noqa: E402
from robots import pose  # noqa: E402

POSE_SEED = 7  # the held-out poses' seed (training poses come from the run's goal seed)


def timed_solve(controller, arm, goals, seconds=None):
    """(solution, wall ms a goal, CPU ms a goal) of lab.solve's defaults (pose goals: seconds, if given)."""
    t, c = time.perf_counter(), time.process_time()
    s = lab.solve(controller, arm, goals, **({} if seconds is None else {"seconds": seconds}))
    return s, 1e3 * (time.perf_counter() - t) / len(goals), 1e3 * (time.process_time() - c) / len(goals)


def ur3_urdf() -> str:
    """example-robot-data's UR3 URDF, by its path (its table names UR5Loader "ur3" in version 5.0.0, so
    erd:ur3 is a UR5: a URDF path is the UR3)."""
    from robots.registry import _erd_paths

    return os.path.join(os.path.dirname(_erd_paths("ur5")[0]), "ur3_robot.urdf")


def generations(run) -> int:
    """The run's generations (its history is thinned on long runs)."""
    return int(run.evaluations // lab.methods.get(run.config.method).evaluations_per_step(None, run.config))


def row(robot: str, seconds: float, n_goals: int, n_poses: int, position: bool, pose_training: bool,
        budget: float | None) -> dict:
    arm = robots.load(robot)
    out = {"robot": arm.name, "joints": arm.nq, "load": os.getloadavg()[0]}
    cpu = time.process_time()
    if position:
        run = lab.evolve(arm, seconds=seconds, seed=0)
        out["cpu"] = time.process_time() - cpu
        stats = arms.held_out(arm, run.controller, n=n_goals)
        s, ms, _ = timed_solve(run.controller, arm, arms.held_out_goals(arm, n_goals))
        out.update(generations=generations(run), median_pct=stats["median_pct"], refined=100 * s.success,
                   refined_ms=ms)
    poses = pose.sample_poses(arm, n_poses, seed=POSE_SEED)
    lab.solve(None, arm, poses[:2])  # the solver's kernels loaded (or compiled) before it is timed
    s, ms, cpu = timed_solve(None, arm, poses, budget)
    out.update(solver=100 * s.success, solver_ms=ms, solver_cpu=cpu)
    if pose_training:
        cpu = time.process_time()
        run = lab.evolve(arm, seconds=seconds, seed=0, goal="pose")
        out["pose_train_cpu"] = time.process_time() - cpu
        lab.solve(run.controller, arm, poses[:2])
        s, ms, cpu = timed_solve(run.controller, arm, poses, budget)
        out.update(pose_generations=generations(run), pose=100 * s.success, pose_ms=ms, pose_cpu=cpu,
                   pose_network_mm=1e3 * float(np.median(s.network_error)),
                   pose_network_deg=float(np.degrees(np.median(s.network_angle))))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default=None,
                    help="comma-separated robot strings (default: example-robot-data's UR3 URDF by its path, erd:panda)")
    ap.add_argument("--seconds", type=float, default=60.0, help="each training run's budget (default 60)")
    ap.add_argument("--goals", type=int, default=arms.HELD_OUT, help="held-out position goals (default 2000)")
    ap.add_argument("--poses", type=int, default=2000, help="held-out poses (default 2000)")
    ap.add_argument("--no-pose-training", action="store_true", help="skip the pose network")
    ap.add_argument("--no-position", action="store_true", help="skip the position run")
    ap.add_argument("--budget", type=float, default=None,
                    help="pose goals: lab.solve's seconds a pose (default: its own, 5 ms; on a busy machine a "
                         "budget scaled by the wall / CPU ratio stands for 5 ms of CPU)")
    args = ap.parse_args(argv)
    print(f"one thread; {args.seconds:g} s of CMA-ES per run; pose budget "
          f"{'5 ms (the default)' if args.budget is None else f'{1e3 * args.budget:g} ms'}; {args.goals} held-out goals, {args.poses} poses; "
          "success: position within 0.1 mm after <= 3 steps, pose within 1e-5 m and 1e-5 rad in the budget")
    print(f"{'robot':<28} {'nq':>2} {'load':>5} {'cpu s':>5} | {'gens':>6} {'median %':>8} {'refined %':>9} {'ms':>6} | "
          f"{'solver %':>8} {'ms':>6} {'cpu':>6} | {'cpu s':>5} {'gens':>6} {'net mm':>7} {'net deg':>7} {'pose %':>7} {'ms':>6} {'cpu':>6}")
    for robot in (args.robots.split(",") if args.robots else [ur3_urdf(), "erd:panda"]):
        r = row(robot, args.seconds, args.goals, args.poses, not args.no_position, not args.no_pose_training,
                args.budget)
        pose_part = (f"{r['pose_train_cpu']:>5.0f} {r['pose_generations']:>6} {r['pose_network_mm']:>7.1f} {r['pose_network_deg']:>7.1f} "
                     f"{r['pose']:>7.2f} {r['pose_ms']:>6.3f} {r['pose_cpu']:>6.3f}" if "pose" in r else "")
        position = (f"{r['cpu']:>5.0f} | {r['generations']:>6} {r['median_pct']:>8.2f} {r['refined']:>9.2f} "
                    f"{r['refined_ms']:>6.3f}" if "cpu" in r else f"{'':>5} | {'':>6} {'':>8} {'':>9} {'':>6}")
        print(f"{r['robot'][-28:]:<28} {r['joints']:>2} {r['load']:>5.1f} {position} | {r['solver']:>8.2f} "
              f"{r['solver_ms']:>6.3f} {r['solver_cpu']:>6.3f} | {pose_part}", flush=True)


if __name__ == "__main__":
    main()
