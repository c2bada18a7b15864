"""Pose refinement (robots.ik.refine on (n, 4, 4) goals) and damped least squares with random restarts
(robots.ik.dls_pose_ik), on poses of uniformly random joint vectors: the share within 0.1 mm and 0.1
degree (and within TRAC-IK's 1e-5 m and 1e-5 rad), from the true joint vector plus noise and from the
rest pose, and the time a pose on one thread.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pose_refine.py [--arms ur5,panda] [--n 1000]

Starts measured, each on the same poses:
    noise S, k steps     refine from q_true + N(0, S^2) per joint (within the limits), at most k steps
    rest, k steps        refine from the rest pose, at most k steps (one start, no restarts)
    dls restarts R, d    dls_pose_ik from the rest pose, then at most R random restarts, damping d
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

import robots
from robots import pose
from robots.ik import dls_pose_ik, refine

SEED = 4242  # the poses' joint vectors: a seed no training or test uses


def rates(arm, poses, q):
    p, a = pose.pose_errors(arm, poses, q)
    return float(np.mean((p < 1e-4) & (a < math.radians(0.1)))), float(np.mean((p < 1e-5) & (a < 1e-5)))


def row(label, arm, poses, q, seconds):
    ok, trac = rates(arm, poses, q)
    print(f"  {label:<28} {100 * ok:7.2f} % {100 * trac:9.2f} % {1e6 * seconds / len(poses):9.0f} us")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="ur5,panda,so100")
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--restarts", type=int, default=20)
    args = ap.parse_args()
    for name in args.arms.split(","):
        arm = robots.load(name)
        q_true = arm.sample_q(args.n, seed=SEED)
        poses = pose.fk_pose(arm, q_true)
        refine(arm, poses[:2], q_true[:2])  # warm
        kind = "full pose" if pose.approach_axis(arm) is None else "position + approach axis"
        print(f"{name} ({arm.nq} joints, {kind}), {args.n} poses of seed {SEED}")
        print(f"  {'start':<28} {'0.1 mm+0.1 deg':>9} {'1e-5 m+rad':>11} {'per pose':>12}")
        rng = np.random.default_rng(0)
        for noise in (0.05, 0.2):
            q0 = arm.within_limits(q_true + rng.normal(0, noise, q_true.shape))
            for steps in (3, 10):
                r = refine(arm, poses, q0, steps=steps)
                row(f"noise {noise} rad, {steps} steps", arm, poses, r.q, r.seconds)
            tight = refine(arm, poses, q0, steps=10, tol=1e-5, angle_tol=1e-5)
            row(f"noise {noise}, 10 steps to 1e-5", arm, poses, tight.q, tight.seconds)
        rest = np.tile(arm.rest, (len(poses), 1))
        for steps in (3, 100):
            r = refine(arm, poses, rest, steps=steps)
            row(f"rest, {steps} steps", arm, poses, r.q, r.seconds)
        for damping in (0.005, 0.02):
            t0 = time.perf_counter()
            res = [dls_pose_ik(arm, g, restarts=args.restarts, damping=damping, seed=0) for g in poses]
            seconds = time.perf_counter() - t0
            row(f"dls restarts {args.restarts}, {damping}", arm, poses, np.array([r.q for r in res]), seconds)
            print(f"  {'':<28} mean restarts {np.mean([r.restarts for r in res]):.2f}")


if __name__ == "__main__":
    main()
