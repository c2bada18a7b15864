"""Compile the numba kernels once, so the first training run does not wait for them.

numba compiles on first call and caches the machine code under __pycache__/ (NUMBA_CACHE_DIR when
set): about a minute of compiling on a 2-core machine, then milliseconds to load. `make test` runs
this first. The app has its spare training process (lab/running/worker.py) do it as the page
serves, the method the page opens with (CMA-ES) first, each step told to the app
(`python -m app` prints them, the tab says what a Start waits for): a process of its own, so the
app's threads never wait on numba's compiler and Ctrl-C ends the app at once.

    python -m lab.running.warmup
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

TREE = "talos-legs"  # the tree whose kernels are compiled (every tree shares them)
FIRST_METHOD = "cmaes"  # what the app's page opens with (lab.methods.DEFAULT_METHOD): compiled first

# s each step took on a 2-core machine with nothing else running (docs/log.md, 2026-12-05): the steps'
# shares of the whole, from which a warm-up estimates the time left as it goes (scaled by how the
# steps done so far compared with these)
TYPICAL_SECONDS = {"kinematics": 6.0, "cmaes": 16.0, "gradient": 3.0, "neat": 17.0}


@dataclass(frozen=True)
class Step:
    """One step of the warm-up: `parts` are (kind, callable) pairs, each callable compiling one kind
    of robot's kernels ("arm": a serial arm's, "tree": a tree's, "all": both); `method` is None for
    the kinematics."""

    index: int
    steps: int
    label: str
    method: str | None
    parts: tuple

    @property
    def key(self) -> str:
        return self.method or "kinematics"

    def describe(self) -> str:
        return f"step {self.index} of {self.steps}: {self.label}"


def plan(first: str = FIRST_METHOD) -> list[Step]:
    """The warm-up's steps: the kinematics, then `first`'s fitness and controller, then every other
    method's (lab.methods.names() order)."""
    from lab import methods

    names = methods.names()
    order = [first] + [m for m in names if m != first] if first in names else list(names)
    n = len(order) + 1
    steps = [Step(1, n, "forward kinematics", None, (("all", _kinematics),))]
    for k, method in enumerate(order, 2):
        steps.append(Step(k, n, f"{methods.get(method).label} fitness and controller", method,
                          (("arm", lambda m=method: _method(m, "planar")), ("tree", lambda m=method: _method(m, TREE)))))
    return steps


def _kinematics() -> None:
    import robots

    arm = robots.load("planar")
    q = arm.sample_q(2, seed=0)
    arm.fk(q)
    arm.joint_positions(q)


def _method(method: str, robot: str) -> None:
    """A tiny run of `method` on `robot` and its controller once: every kernel they call, compiled."""
    import robots
    from lab.running.evolve import evolve

    run = evolve(robot, method, generations=2, population=10, targets=5, test_goals=5, seed=0)
    run.controller(robots.load(robot).sample_goals(2, seed=1))


class Estimate:
    """Seconds left of a warm-up, from TYPICAL_SECONDS scaled by the steps done so far."""

    def __init__(self, steps: list[Step]):
        self.steps, self.done, self.typical_done = steps, 0.0, 0.0

    def scale(self) -> float:
        return self.done / self.typical_done if self.typical_done > 0 else 1.0

    def step_seconds(self, step: Step) -> float:
        return TYPICAL_SECONDS.get(step.key, 10.0) * self.scale()

    def finished(self, step: Step, seconds: float) -> None:
        self.done += seconds
        self.typical_done += TYPICAL_SECONDS.get(step.key, 10.0)


def compile_kernels(progress: Callable | None = None, first: str = FIRST_METHOD,
                    stop: Callable[[], bool] | None = None) -> float:
    """Call every kernel once (forward kinematics, each method's fitness, controllers); seconds taken.
    progress(step, seconds): told before each step, with the s that step is expected to take
    (None: silent). stop(): asked before each part of a step; True ends the warm-up there."""
    t = time.perf_counter()
    steps = plan(first)
    estimate = Estimate(steps)
    for step in steps:
        if stop is not None and stop():
            break
        if progress is not None:
            progress(step, estimate.step_seconds(step))
        t_step = time.perf_counter()
        for _kind, part in step.parts:
            part()
        estimate.finished(step, time.perf_counter() - t_step)
    return time.perf_counter() - t


def main() -> None:
    seconds = compile_kernels(lambda step, _s: print(f"compiling kernels ({step.index}/{step.steps}): {step.label}",
                                                     flush=True))
    print(f"numba kernels compiled and cached in {seconds:.1f} s (once: later runs load them)")


if __name__ == "__main__":
    main()
