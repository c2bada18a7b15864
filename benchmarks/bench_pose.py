"""Full-pose IK solvers side by side on TRAC-IK's own terms: poses of uniformly random joint vectors,
success within 1e-5 m and 1e-5 rad in a 5 ms budget a pose, one solve at a time on one thread.

    .venv/bin/pip install -e ".[pose-bench]"        # pin-pink, qpsolvers[daqp], ik-geo (keeps pin 4.1)
    .venv/bin/python benchmarks/bench_pose.py [--poses 10000] [--robots ur5,ur10,...] [--json out.json]

Each pose is solved alone (one call, timed on the budget's clock), with NUMBA_NUM_THREADS,
LAB_THREADS and the BLAS set to one thread (set here before numpy loads). Every solver aims at
1e-5 m and 1e-5 rad and stops at 5 ms (a solver that checks its clock only between starts can run
past it: such an answer counts as a failure). Columns:

    1e-5, 5 ms      position error < 1e-5 m and angle error < 1e-5 rad, returned within 5 ms. The
                    errors are norms (|dp| and the geodesic angle), at least as strict as TRAC-IK's
                    1e-5 on each axis of the twist.
    0.1 mm, 0.1 deg the same answers within 1e-4 m and 0.1 degree (and 5 ms)
    mean, p99       time a pose on the budget's clock, all poses (a failure costs its whole budget)

The clock (--clock): "cpu", this thread's CPU time (time.thread_time, the default), what wall time
is on a quiet machine and what a machine shared with other CPU-bound work leaves of it; "wall",
perf_counter, for a quiet machine. The wall time's mean is printed beside it either way.

On the 5-joint SO arms a pose is a position and the gripper's approach axis (5 constraints,
robots.pose.approach_axis; the roll about it is free), for every solver.

Solvers:
    network + refine        the shipped pose controller app/pretrained/<arm>-pose-cmaes.json, all its
                            heads as proposals, then lab.solve's refinement (robots.ik.refine) to 1e-5
                            (at most 20 steps); "none shipped" where that file does not exist
    ... then DLS restarts   the same, then, while the budget lasts, the DLS baseline's starts (the
                            rest pose, then random joint vectors) in what is left of it
    network + compiled LM   the same network's proposals as the starts of robots.pose_solve.solve_pose
                            (compiled Levenberg-Marquardt descents, then random restarts until 5 ms):
                            what lab.solve(..., seconds=0.005) runs, on the budget's clock
    network (batched) ...   the same, the proposals of all poses from one forward pass, its time
                            shared equally among them (lab.solve on many poses at once)
    compiled LM, restarts   robots.pose_solve.solve_pose from arm.rest, then random restarts: the same
                            solver without the network
    pink, rest pose         pink (Pinocchio's differential IK, a QP a step, daqp) from arm.rest: steps of
                            dt 1 with its configuration and velocity limits until 1e-5, a stall (|e| down
                            by less than 1 % in a step) or 5 ms
    pink, restarts          the same, then from uniformly random joint vectors until 5 ms
    DLS, restarts           robots.ik.dls_pose_ik (damped least squares from the rest pose, then random
                            restarts, seconds=5 ms): the KDL-like baseline
    ik-geo (UR5, UR10)      ik-geo's closed-form solutions (three parallel axes, two intersecting),
                            built from the arm's Pinocchio model at q = 0; the nearest exact one

The poses: seed 20261205 (arm.sample_q, then robots.pose.fk_pose), a seed no training, test or
other benchmark uses. Results and commands: docs/results/pose.md.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "LAB_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one thread, as TRAC-IK's figures are; before numpy and numba load

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import lab  # noqa: E402
from lab.problem.controllers import proposals  # noqa: E402
import robots  # noqa: E402
from robots import pose, pose_solve  # noqa: E402
from robots.ik import dls_pose_ik  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEED = 20261205
BUDGET = 0.005  # [s] a pose, TRAC-IK's
TOL = 1e-5  # [m] and [rad]
ROBOTS = ("ur5", "ur10", "panda", "xarm7", "kinova", "z1", "so100", "so101")
ANALYTIC = ("ur5", "ur10")  # ik-geo's family: three parallel axes, the last two intersecting
CLOCKS = {"cpu": time.thread_time, "wall": time.perf_counter}
clock = time.thread_time  # the budget's clock (--clock): this thread's CPU time, or wall time
INSTALL = 'missing {what}: install the benchmark\'s extra with  .venv/bin/pip install -e ".[pose-bench]"'


def _need(module: str):
    try:
        return __import__(module)
    except ImportError:
        sys.exit(INSTALL.format(what=module))


# ---------------------------------------------------------------- the network, then refinement
def shipped_controller(name: str):
    """The shipped pose controller of `name`, or None."""
    path = ROOT / "app" / "pretrained" / f"{name}-pose-cmaes.json"
    if not path.exists():
        return None, path
    with open(path) as f:
        return lab.controller_from_dict(json.load(f)["controller"]), path


def network_solver(arm, controller, restarts: bool):
    def solve(goal, i):
        t0 = clock()
        s = lab.solve(controller, arm, goal[None], steps=20, tol=TOL, angle_tol=TOL)
        q = s.q[0]
        if restarts and not s.converged[0] and clock() - t0 < BUDGET:
            q = dls_restarts(arm, goal, arm.rest, t0, i)  # the DLS baseline's starts, in what is left
            if max(*pose.pose_errors(arm, goal[None], s.q)) < max(*pose.pose_errors(arm, goal[None], q[None])):
                q = s.q[0]
        return q, clock() - t0
    return solve


def compiled_solver(arm, controller, poses=None):
    """robots.pose_solve.PoseSolver from the network's proposals (controller None: from arm.rest),
    then random restarts, within the budget on the bench's clock. poses given: the proposals of all
    of them in one batched forward pass first, its time shared equally among the poses (what
    lab.solve does with many poses at once)."""
    def starts_of(goals):  # as lab.solve takes them: every head's, the nearest first
        own = controller.proposals if hasattr(controller, "proposals") else partial(proposals, controller)
        return np.asarray(own(goals))

    batch, share = None, 0.0
    solver = pose_solve.PoseSolver(arm, tol=TOL, angle_tol=TOL)  # the arm's arrays once, as lab.solve does
    if controller is not None and poses is not None:
        starts_of(poses[:2])  # warm
        t0 = clock()
        batch = starts_of(poses)
        share = (clock() - t0) / len(poses)

    def solve(goal, i):
        t0 = clock()
        starts = None
        if controller is not None:
            starts = batch[:, i] if batch is not None else starts_of(goal[None])[:, 0]
        r = solver.solve(goal, starts, seconds=BUDGET - share - (clock() - t0), seed=i, clock=clock)
        return r.q, clock() - t0 + share
    return solve


# ---------------------------------------------------------------- damped least squares
def dls_restarts(arm, goal, start, t0: float, seed: int):
    """dls_pose_ik's starts (at most 100 damped least-squares steps from `start`, then from uniformly
    random joint vectors) while the budget lasts on the bench's clock: the best answer."""
    rng = np.random.default_rng(seed)
    best, score = None, math.inf
    while True:
        r = dls_pose_ik(arm, goal, q0=start, restarts=0, tol=TOL, angle_tol=TOL)
        s = max(r.error, r.angle) / TOL
        if s < score:
            best, score = r.q, s
        if r.converged or clock() - t0 >= BUDGET:
            return best
        start = arm.lower + (arm.upper - arm.lower) * rng.random(arm.nq)


def dls_solver(arm):
    def solve(goal, i):
        t0 = clock()
        return dls_restarts(arm, goal, arm.rest, t0, i), clock() - t0
    return solve


# ---------------------------------------------------------------- pink
def pink_solver(arm, restarts: bool):
    """pink's differential IK: a FrameTask on the tool frame (on an SO arm, on a frame whose z is the
    approach axis, its orientation cost 0 about z), steps of dt 1 (a Gauss-Newton step under pink's
    configuration and velocity limits)."""
    pink = _need("pink")
    _need("qpsolvers")
    from pink.exceptions import PinkError
    from pink.tasks import FrameTask

    axis = pose.approach_axis(arm)
    offset = np.eye(4)
    if axis is not None:  # the frame's z is the approach axis: the roll about it left free
        z = axis / np.linalg.norm(axis)
        x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        offset[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    model = pin.Model(arm.model)  # a frame of its own on the tool (some tool frames' names are not unique)
    tool = model.frames[arm.ee_frame_id]
    frame = "bench_pose_tool"
    model.addFrame(pin.Frame(frame, tool.parentJoint, arm.ee_frame_id, tool.placement * pin.SE3(offset),
                             pin.FrameType.OP_FRAME))
    data = model.createData()
    task = FrameTask(frame, position_cost=1.0, orientation_cost=1.0 if axis is None else [1.0, 1.0, 0.0])
    length = 1.0  # |e| = |dp| + 1 m x angle, for the stall test
    rng_for = np.random.default_rng

    def errors(cfg, goal):
        M = cfg.get_transform_frame_to_world(frame)
        p = float(np.linalg.norm(M.translation - goal[:3, 3]))
        if axis is None:
            a = float(np.linalg.norm(pin.log3(M.rotation.T @ goal[:3, :3])))
        else:  # both z axes: the approach axes
            a = float(pose.axis_angle_between(M.rotation[:, 2], goal[:3, :3] @ offset[:3, 2]))
        return p, a

    def solve(goal, i):
        t0 = clock()
        task.set_target(pin.SE3(goal @ offset))
        rng, start, best, best_e = rng_for(i), arm.rest, arm.rest, math.inf
        while True:
            cfg = pink.Configuration(model, data, arm.to_pinocchio(start))
            prev = p = a = math.inf
            while clock() - t0 < BUDGET:
                p, a = errors(cfg, goal)
                e = p + length * a
                if e < best_e:
                    best, best_e = arm.from_pinocchio(cfg.q.copy()), e
                if (p < TOL and a < TOL) or e > 0.99 * prev:
                    break
                prev = e
                try:
                    v = pink.solve_ik(cfg, [task], 1.0, solver="daqp", safety_break=False)
                except PinkError:  # no QP solution from here: a stall
                    break
                cfg.integrate_inplace(v, 1.0)
            if not restarts or (p < TOL and a < TOL) or clock() - t0 >= BUDGET:
                return arm.within_limits(best), clock() - t0
            start = arm.lower + (arm.upper - arm.lower) * rng.random(arm.nq)
    return solve


# ---------------------------------------------------------------- ik-geo
def ikgeo_robot(arm):
    """ik-geo's Robot for a UR arm from its Pinocchio model at q = 0 (h: the joint axes, p: the
    vectors between joint origins, the wrist's two intersecting axes sharing their origin), and the
    tool frame's rotation at q = 0 (ik-geo's end frame is the base's orientation there). ik-geo
    1.0.3's Python binding reads and returns rotations transposed (row for column): its R is R^T."""
    ik_geo = _need("ik_geo")
    m = arm.model
    d = m.createData()
    pin.forwardKinematics(m, d, np.zeros(m.nq))
    pin.updateFramePlacements(m, d)
    local = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
    h = np.array([d.oMi[j].rotation[:, local[m.joints[j].shortname()]] for j in range(1, m.njoints)])
    o = np.array([d.oMi[j].translation for j in range(1, m.njoints)])
    w = o[5] - o[4]
    if np.linalg.norm(w - (w @ h[4]) * h[4]) > 1e-9:
        raise ValueError(f"{arm.name}: the last two joint axes do not intersect: not ik-geo's family here")
    o[4] = o[5]
    tool = d.oMf[arm.ee_frame_id]
    p = np.vstack([o[0], np.diff(o, axis=0), tool.translation - o[5]])
    return ik_geo.Robot.three_parallel_two_intersecting(h, p), tool.rotation.copy()


def ikgeo_solver(arm):
    robot, R0 = ikgeo_robot(arm)
    lo, hi = arm.lower, arm.upper

    def solve(goal, i):
        t0 = clock()
        q = arm.rest
        for qs, _, least_squares in robot.get_ik_sorted((goal[:3, :3] @ R0.T).T, goal[:3, 3]):
            qs = np.asarray(qs)
            if not least_squares and np.all(qs >= lo) and np.all(qs <= hi):
                q = qs
                break
        return q, clock() - t0
    return solve


def ikgeo_agreement(arm, n: int = 300) -> dict:
    """ik-geo's forward kinematics against robots.pose.fk_pose, and its inverse, with R given as
    is and transposed: the largest errors on n random joint vectors."""
    robot, R0 = ikgeo_robot(arm)
    q = arm.sample_q(n, seed=SEED + 1)
    T = pose.fk_pose(arm, q)
    fk = [robot.forward_kinematics(qi) for qi in q]
    Rf = np.array([f[0] for f in fk])
    out = {"fk position": float(np.abs(np.array([f[1] for f in fk]) - T[:, :3, 3]).max()),
           "fk rotation as given": float(np.abs(Rf @ R0 - T[:, :3, :3]).max()),
           "fk rotation transposed": float(np.abs(np.swapaxes(Rf, 1, 2) @ R0 - T[:, :3, :3]).max())}
    for how, flip in (("as given", False), ("transposed", True)):
        worst = []
        for g in T:
            R = g[:3, :3] @ R0.T
            sols = robot.get_ik_sorted(R.T if flip else R, g[:3, 3])
            qs = np.array([s[0] for s in sols])
            p, a = pose.pose_errors(arm, np.repeat(g[None], len(qs), 0), qs)
            worst.append(float(np.min(np.maximum(p, a))))
        out[f"ik {how}: share within 1e-5"] = float(np.mean(np.array(worst) < TOL))
        out[f"ik {how}: median best error"] = float(np.median(worst))
    return out


# ---------------------------------------------------------------- the run
def measure(arm, poses, solve) -> dict:
    n = len(poses)
    q, t, wall = np.empty((n, arm.nq)), np.empty(n), np.empty(n)
    solve(poses[0], 0)  # warm: compiled kernels, first-call caches
    for i, g in enumerate(poses):
        w0 = time.perf_counter()
        q[i], t[i] = solve(g, i)  # t: on the budget's clock
        wall[i] = time.perf_counter() - w0
    p, a = pose.pose_errors(arm, poses, q)
    within = t <= BUDGET
    return {"trac": float(np.mean((p < TOL) & (a < TOL) & within)),
            "fine": float(np.mean((p < 1e-4) & (a < math.radians(0.1)) & within)),
            "mean_ms": 1e3 * float(t.mean()), "p99_ms": 1e3 * float(np.percentile(t, 99)),
            "over_budget": float(np.mean(~within)), "wall_mean_ms": 1e3 * float(wall.mean())}


def solvers_for(name: str, arm, poses):
    controller, path = shipped_controller(name)
    rows = []
    if controller is None:
        rows += [("network + refine", None, f"none shipped ({path.relative_to(ROOT)})")]
    else:
        rows += [("network + refine", network_solver(arm, controller, False), ""),
                 ("network + refine, then DLS restarts", network_solver(arm, controller, True), ""),
                 ("network + compiled LM, restarts", compiled_solver(arm, controller), ""),
                 ("network (batched) + compiled LM, restarts", compiled_solver(arm, controller, poses), "")]
    rows += [("compiled LM, restarts (rest pose)", compiled_solver(arm, None), ""),
             ("pink, rest pose", pink_solver(arm, False), ""),
             ("pink, restarts", pink_solver(arm, True), ""),
             ("DLS, restarts (dls_pose_ik)", dls_solver(arm), "")]
    if name in ANALYTIC:
        rows += [("ik-geo (analytic)", ikgeo_solver(arm), "")]
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=10_000, help="poses an arm (default 10000)")
    ap.add_argument("--robots", default=",".join(ROBOTS), help="comma-separated arms (default: the 8 real arms)")
    ap.add_argument("--solvers", default="", help="comma-separated substrings of solver names to run (default all)")
    ap.add_argument("--clock", choices=sorted(CLOCKS), default="cpu",
                    help="the budget's and the times' clock: this thread's CPU time (default) or wall time")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    global clock
    clock = CLOCKS[args.clock]
    if args.poses < 1:
        ap.error("--poses must be at least 1")
    names = [s.strip() for s in args.robots.split(",") if s.strip()]
    unknown = [s for s in names if s not in ROBOTS]
    if unknown:
        ap.error(f"unknown arm(s) {unknown}: choose among {', '.join(ROBOTS)}")
    for module in ("pink", "qpsolvers", "daqp", "ik_geo"):
        _need(module)
    wanted = [s.strip() for s in args.solvers.split(",") if s.strip()]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    header = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": commit.strip(),
              "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
              "load_start": open("/proc/loadavg").read().split()[:3], "poses": args.poses, "seed": SEED,
              "clock": args.clock}
    print(json.dumps(header))
    results = {"header": header, "arms": {}}
    with threadpool_limits(1):
        for name in names:
            arm = robots.load(name)
            poses = pose.fk_pose(arm, arm.sample_q(args.poses, seed=SEED))
            kind = "6 constraints" if pose.approach_axis(arm) is None else "5 constraints: position + approach axis"
            print(f"\n{name} ({arm.nq} joints, {kind}), {args.poses} poses of seed {SEED}", flush=True)
            out = results["arms"][name] = {}
            if name in ANALYTIC:
                out["ik-geo agreement"] = ikgeo_agreement(arm)
                print("  ik-geo against fk_pose:", json.dumps(out["ik-geo agreement"]), flush=True)
            for label, solve, note in solvers_for(name, arm, poses):
                if wanted and not any(w in label for w in wanted):
                    continue
                if solve is None:
                    out[label] = {"note": note}
                    print(f"  {label:<42} {note}", flush=True)
                    continue
                r = measure(arm, poses, solve)
                r["load"] = open("/proc/loadavg").read().split()[:3]
                out[label] = r
                print(f"  {label:<42} 1e-5/5ms {100 * r['trac']:6.2f} %  0.1mm/0.1deg {100 * r['fine']:6.2f} %  "
                      f"mean {r['mean_ms']:6.3f} ms (wall {r['wall_mean_ms']:6.3f})  p99 {r['p99_ms']:6.3f} ms  "
                      f"over 5 ms {100 * r['over_budget']:.2f} %"
                      f"  load {' '.join(r['load'])}", flush=True)
            if args.json:
                Path(args.json).write_text(json.dumps(results, indent=1))
    results["header"]["load_end"] = open("/proc/loadavg").read().split()[:3]
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
