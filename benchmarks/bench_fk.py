"""Batched `arm.fk` against the per-configuration Pinocchio loop a user would write.

One generation of the paper is 50 networks x 70 goals = 3,500 configurations. For each
arm the loop, `arm.fk` (a numba kernel) and a straightforward batched numpy composition of
the same chain (the alternative to a compiler) are timed side by side in this run (median
of repeated rounds, interleaved), and the ratios to the loop are printed. Target: at least
5x on every arm.

    .venv/bin/python benchmarks/bench_fk.py [--arms planar,scara,ur5] [--n 3500] [--rounds 30]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pinocchio as pin

import robots
from robots.kinematics import PRISMATIC


def pinocchio_loop(model, data, fid, q_pin):
    out = np.empty((len(q_pin), 3))
    for i, q in enumerate(q_pin):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacement(model, data, fid)
        out[i] = data.oMf[fid].translation
    return out


def numpy_chain(chain, q):
    """The same chain composed with batched numpy, (N, n) -> (N, 3): per joint p += R pos_k,
    R = R rot_k (skipped where identity), then R's first two columns turn by q_k (revolute)
    or p += q_k R[:, 2] (prismatic); finally p + R ee_pos."""
    R = np.broadcast_to(np.eye(3), (len(q), 3, 3))
    p = np.zeros((len(q), 3))
    for k in range(chain.n):
        p = p + R @ chain.pos[k]
        if not chain.identity[k]:
            R = R @ chain.rot[k]
        if chain.kind[k] == PRISMATIC:
            p = p + q[:, k, None] * R[:, :, 2]
        else:
            c, s = np.cos(q[:, k])[:, None], np.sin(q[:, k])[:, None]
            x, y = R[:, :, 0], R[:, :, 1]
            R = np.stack([c * x + s * y, c * y - s * x, R[:, :, 2]], axis=2)
    return p + R @ chain.ee_pos


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
    print(f"{'arm':8s} {'pinocchio loop':>15s} {'arm.fk':>10s} {'speed-up':>9s} {'numpy batch':>12s} {'speed-up':>9s}"
          f"  (n={args.n}, median of {args.rounds})")
    worst = np.inf
    for name in args.arms.split(","):
        arm = robots.load(name)
        q = arm.sample_q(args.n, seed=0)
        q_pin = arm.to_pinocchio(q)
        data = arm.model.createData()
        ref = pinocchio_loop(arm.model, data, arm.ee_frame_id, q_pin)
        assert np.allclose(arm.fk(q), ref, atol=1e-9), name
        assert np.allclose(numpy_chain(arm.chain, q), ref, atol=1e-9), name
        t_loop, t_fk, t_np = [], [], []
        for _ in range(args.rounds):  # interleaved, so all see the same machine load
            t_loop.append(timed(pinocchio_loop, arm.model, data, arm.ee_frame_id, q_pin))
            t_fk.append(timed(arm.fk, q))
            t_np.append(timed(numpy_chain, arm.chain, q))
        a, b, c = np.median(t_loop), np.median(t_fk), np.median(t_np)
        worst = min(worst, a / b)
        print(f"{name:8s} {a * 1e3:12.2f} ms {b * 1e3:7.3f} ms {a / b:8.1f}x {c * 1e3:9.3f} ms {a / c:8.1f}x")
    print(f"worst speed-up {worst:.1f}x (target >= 5x): {'PASS' if worst >= 5 else 'FAIL'}")


if __name__ == "__main__":
    main()
