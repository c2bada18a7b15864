"""Compile the numba kernels once, so the first training run does not wait for them.

numba compiles on first call and caches the machine code under __pycache__/ (about 15 s of
compiling on a 2-core machine, then milliseconds to load). `make test` runs this first; the app
runs `compile_kernels` in a background thread at startup, after its first page is served (that
page needs only the kinematics and the controllers' kernels, which it compiles as it starts).

    python -m lab.running.warmup
"""

from __future__ import annotations

import time

TREE = "talos-legs"  # the tree whose kernels are compiled (every tree shares them)


def compile_kernels(progress=None) -> float:
    """Call every kernel once (forward kinematics, each method's fitness, controllers); seconds taken.
    progress(text): told before each step (None: silent)."""
    import robots
    from lab import methods

    from lab.running.evolve import evolve

    say = progress or (lambda text: None)
    t = time.perf_counter()
    names = methods.names()
    say(f"compiling kernels (1/{len(names) + 1}): forward kinematics")
    arm = robots.load("planar")
    q = arm.sample_q(2, seed=0)
    arm.fk(q)
    arm.joint_positions(q)
    tree = robots.load(TREE)
    for k, method in enumerate(names, 2):
        say(f"compiling kernels ({k}/{len(names) + 1}): {methods.get(method).label} fitness and controller")
        for robot in (arm, tree):  # a serial arm's kernels and a tree's (several end effectors)
            run = evolve(robot.name, method, generations=2, population=10, targets=5, test_goals=5, seed=0)
            run.controller(robot.sample_goals(2, seed=1))
    return time.perf_counter() - t


def main() -> None:
    seconds = compile_kernels(lambda text: print(text, flush=True))
    print(f"numba kernels compiled and cached in {seconds:.1f} s (once: later runs load them)")


if __name__ == "__main__":
    main()
