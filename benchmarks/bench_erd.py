"""Every example-robot-data robot, as a user would bring it: loaded, trained and solved with no settings.

For each entry of `example_robot_data.ROBOTS` (or --robots a,b), opened as `erd:NAME` (robots.load picks
the end of its longest serial chain from the root to a hand, tool or foot, and says which), in a process
of its own with one thread (OPENBLAS_NUM_THREADS=1, LAB_THREADS=1):

    loads      whether robots.load takes it; the frame it picked and the chain's joint count; else the
               reason it gives (an SDF-only robot, no moving joint, ...)
    position   lab.evolve(arm, seconds=S) (its default method, CMA-ES, with the defaults the lab picks
               for an unknown arm): the held-out median error in % of the reach (lab.experiments.arms
               held_out, --goals goals), then lab.solve(controller, arm, goals) (the network and at most
               3 refinement steps; the goals its proposals miss tried again from the arm's seed table,
               robots.seeds): the share within 0.1 mm; and the same with table=0 (the network's
               proposals alone)
    pose       on a 5-7 joint chain: lab.evolve(arm, seconds=S, goal="pose"), then lab.solve(controller,
               arm, poses) with the pose default (TRAC-IK's terms: 1e-5 m, 1e-5 rad, 5 ms a pose): the
               share solved, and lab.solve(None, arm, poses), the solver alone from the rest pose

A robot that loads but fails later (training, solving) gives its reason in the last column. Prints a
markdown table (docs/results/your-robot.md). The 5 ms budget is wall time: on a loaded machine a pose
gets less CPU, and the share falls; the `load` column is the 1-minute load average at each row's start.

    python benchmarks/bench_erd.py                          # all 72, 60 s runs, one at a time (hours)
    python benchmarks/bench_erd.py --jobs 4                 # four robots at once (four cores)
    python benchmarks/bench_erd.py --robots ur3,panda,bravo7_no_ee --seconds 10
    python benchmarks/bench_erd.py --joints 6,7 --no-pose   # the arms of 6-7 joints, position only
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("LAB_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import concurrent.futures as cf  # noqa: E402
import logging  # noqa: E402
import multiprocessing  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402

POSE_JOINTS = range(5, 8)  # TRAC-IK's terms are measured on 5-7 joint chains
POSE_SEED = 7  # held-out poses (training poses come from the run's goal seed)


def erd_names() -> list[str]:
    import example_robot_data as erd

    return sorted(erd.ROBOTS)


def row(name: str, seconds: float, n_goals: int, n_poses: int, joints=None, with_pose: bool = True) -> dict:
    """One robot's figures (a dict; `reason` says where it stopped)."""
    logging.getLogger("robots").setLevel(logging.ERROR)  # the frame picked is in the row
    import lab
    import robots
    from lab.experiments import arms
    from robots import pose

    out = {"robot": name, "load": os.getloadavg()[0]}
    try:
        arm = robots.load("erd:" + name)
    except Exception as e:  # noqa: BLE001 - refused: its reason is the row
        return {**out, "loads": False, "reason": _one_line(e)}
    out.update(loads=True, frame=",".join(arm.effectors), joints=arm.nq, no_pose=not with_pose)
    if joints is not None and arm.nq not in joints:
        return {**out, "skipped": True}
    stage = "position training"
    try:
        t = time.perf_counter()
        run = lab.evolve(arm, seconds=seconds, seed=0)
        out.update(method=run.config.method, generations=len(run.history), train_s=time.perf_counter() - t)
        stage = "held-out error"
        out["median_pct"] = arms.held_out(arm, run.controller, n=n_goals)["median_pct"]
        stage = "refinement"
        goals = arms.held_out_goals(arm, n_goals)
        out["refined"] = 100 * float(lab.solve(run.controller, arm, goals, progress=False).success)
        out["refined_network"] = 100 * float(lab.solve(run.controller, arm, goals, table=0, progress=False).success)
        if with_pose and arm.nq in POSE_JOINTS and not arm.is_tree:
            poses = pose.sample_poses(arm, n_poses, seed=POSE_SEED)
            stage = "pose solver"
            lab.solve(None, arm, poses[:2], progress=False)  # its kernels loaded (or compiled) first
            out["solver"] = 100 * float(lab.solve(None, arm, poses, progress=False).success)
            stage = "pose training"
            prun = lab.evolve(arm, seconds=seconds, seed=0, goal="pose")
            stage = "pose solve"
            lab.solve(prun.controller, arm, poses[:2], progress=False)
            out["pose"] = 100 * float(lab.solve(prun.controller, arm, poses, progress=False).success)
    except Exception as e:  # noqa: BLE001 - loads, but this stage fails: said, the rest of the sweep goes on
        out["reason"] = f"{stage}: {_one_line(e)}"
        out["trace"] = traceback.format_exc(limit=3)
    return out


def _one_line(e: BaseException) -> str:
    """The error in one line, a path into example-robot-data's share folder from the package's name on."""
    text = re.sub(r"\S*/share/(example-robot-data/)", r"\1", f"{type(e).__name__}: {e}")
    return " ".join(text.split())[:300]


def table(rows: list[dict], seconds: float) -> str:
    f = lambda v, fmt: "" if v is None else format(v, fmt)  # noqa: E731
    lines = [f"| robot | loads | frame picked | joints | held-out median, % of reach ({seconds:g} s CMA-ES) | "
             "refined within 0.1 mm, % | the same, the network's proposals alone, % | "
             "pose, TRAC-IK's terms, network + solver, % | pose, solver alone, % | generations | load | reason |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("skipped"):
            continue
        lines.append(
            f"| `erd:{r['robot']}` | {'yes' if r.get('loads') else 'no'} | {('`' + r['frame'] + '`') if r.get('frame') else ''} "
            f"| {r.get('joints', '')} | {f(r.get('median_pct'), '.2f')} | {f(r.get('refined'), '.1f')} "
            f"| {f(r.get('refined_network'), '.1f')} "
            f"| {f(r.get('pose'), '.1f') if 'pose' in r else (('not run' if r.get('no_pose') else '') if r.get('joints') in POSE_JOINTS else 'n/a')} "
            f"| {f(r.get('solver'), '.1f')} | {r.get('generations', '')} | {r['load']:.1f} "
            f"| {r.get('reason', '').replace('|', '/')} |")
    rows = [r for r in rows if not r.get("skipped")]
    loaded = [r for r in rows if r.get("loads")]
    trained = [r for r in loaded if "median_pct" in r]
    lines.append("")
    lines.append(f"{len(loaded)} of {len(rows)} load; {len(trained)} of {len(rows)} train with no settings")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python benchmarks/bench_erd.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="each training run's budget (default 60)")
    ap.add_argument("--robots", default=None, help="comma-separated example-robot-data names (default: all)")
    ap.add_argument("--jobs", type=int, default=1, help="robots measured at once, each in its own process")
    ap.add_argument("--goals", type=int, default=1000, help="held-out position goals")
    ap.add_argument("--poses", type=int, default=200, help="held-out poses (5-7 joint chains)")
    ap.add_argument("--joints", default=None, help="comma-separated joint counts: only the robots whose picked "
                                                  "chain has one of them (default: every robot)")
    ap.add_argument("--no-pose", action="store_true", help="position goals only (no pose training or solving)")
    args = ap.parse_args(argv)
    names = args.robots.split(",") if args.robots else erd_names()
    try:
        joints = None if args.joints is None else {int(j) for j in args.joints.split(",")}
    except ValueError:
        sys.exit(f"error: --joints takes comma-separated whole numbers, got {args.joints!r}")
    unknown = sorted(set(names) - set(erd_names()))
    if unknown:
        sys.exit(f"error: not example-robot-data robots: {', '.join(unknown)}")
    print(f"{len(names)} robots, {args.seconds:g} s runs, {args.jobs} at a time, "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, LAB_THREADS={os.environ['LAB_THREADS']}",
          file=sys.stderr, flush=True)
    rows = {}
    t0 = time.perf_counter()
    with cf.ProcessPoolExecutor(max_workers=max(1, args.jobs), mp_context=multiprocessing.get_context("spawn"),
                                max_tasks_per_child=1) as pool:
        futures = {pool.submit(row, n, args.seconds, args.goals, args.poses, joints, not args.no_pose): n
                   for n in names}
        for fut in cf.as_completed(futures):
            n = futures[fut]
            try:
                rows[n] = fut.result()
            except Exception as e:  # noqa: BLE001 - the worker process died (memory, a crash in C)
                rows[n] = {"robot": n, "load": os.getloadavg()[0], "reason": f"worker died: {_one_line(e)}"}
            r = rows[n]
            print(f"[{len(rows)}/{len(names)} {time.perf_counter() - t0:.0f} s] {n}: "
                  f"{r.get('reason') or 'ok'} {json.dumps({k: v for k, v in r.items() if k != 'trace'})}",
                  file=sys.stderr, flush=True)  # each row as it comes: a sweep cut short keeps what it measured
            if r.get("trace"):
                print(r["trace"], file=sys.stderr, flush=True)
    print(f"\n`python benchmarks/bench_erd.py {' '.join(argv if argv is not None else sys.argv[1:])}`\n")
    print(table([rows[n] for n in names], args.seconds))


if __name__ == "__main__":
    main()
