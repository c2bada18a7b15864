"""Batched `arm.fk` against the per-configuration Pinocchio loop a user would write.

One generation of the paper is 50 networks x 70 goals = 3,500 configurations. For each
arm both are timed side by side in this run (median of repeated rounds, interleaved),
and the ratio is printed. Target: at least 5x on every arm.

    .venv/bin/python benchmarks/bench_fk.py [--arms planar,scara,ur5] [--n 3500] [--rounds 30]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pinocchio as pin

import robots


def pinocchio_loop(model, data, fid, q_pin):
    out = np.empty((len(q_pin), 3))
    for i, q in enumerate(q_pin):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacement(model, data, fid)
        out[i] = data.oMf[fid].translation
    return out


def timed(fn, *args) -> float:
    t = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="planar,scara,ur5")
    ap.add_argument("--n", type=int, default=3500)
    ap.add_argument("--rounds", type=int, default=30)
    args = ap.parse_args()
    print(f"{'arm':8s} {'pinocchio loop':>15s} {'arm.fk':>10s} {'speed-up':>9s}  (n={args.n}, median of {args.rounds})")
    worst = np.inf
    for name in args.arms.split(","):
        arm = robots.load(name)
        q = arm.sample_q(args.n, seed=0)
        q_pin = arm.to_pinocchio(q)
        data = arm.model.createData()
        ref = pinocchio_loop(arm.model, data, arm.ee_frame_id, q_pin)
        assert np.allclose(arm.fk(q), ref, atol=1e-9), name
        t_loop, t_fk = [], []
        for _ in range(args.rounds):  # interleaved, so both see the same machine load
            t_loop.append(timed(pinocchio_loop, arm.model, data, arm.ee_frame_id, q_pin))
            t_fk.append(timed(arm.fk, q))
        a, b = np.median(t_loop), np.median(t_fk)
        worst = min(worst, a / b)
        print(f"{name:8s} {a * 1e3:12.2f} ms {b * 1e3:7.3f} ms {a / b:8.1f}x")
    print(f"worst speed-up {worst:.1f}x (target >= 5x): {'PASS' if worst >= 5 else 'FAIL'}")


if __name__ == "__main__":
    main()
