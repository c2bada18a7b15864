"""Compile the numba kernels once, so the first training run does not wait for them.

numba compiles on first call and caches the machine code under __pycache__/ (about 30 s of
compiling on a 2-core machine, then milliseconds to load). `make install` runs this once;
the app runs `compile_kernels` in a background thread at startup.

    python -m lab.running.warmup
"""

from __future__ import annotations

import time


def compile_kernels() -> float:
    """Call every kernel once (forward kinematics, each method's fitness, controllers); seconds taken."""
    import robots
    from lab import methods

    from lab.running.evolve import evolve

    t = time.perf_counter()
    arm = robots.load("planar")
    q = arm.sample_q(2, seed=0)
    arm.fk(q)
    arm.joint_positions(q)
    for method in methods.names():
        run = evolve("planar", method, generations=2, population=10, targets=5, test_goals=5, seed=0)
        run.controller(arm.sample_goals(2, seed=1))
    return time.perf_counter() - t


def main() -> None:
    print(f"numba kernels compiled and cached in {compile_kernels():.1f} s")


if __name__ == "__main__":
    main()
