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
KINDS = ("arm", "tree")  # the kernels of a serial arm (one end effector), of a tree (several)
KIND_LABELS = {"arm": "serial arms", "tree": "trees of several end effectors"}

# A step's estimate is its method's compile_seconds (lab.methods.Method, measured on the 2-core machine
# of docs/log.md with an empty numba cache), a serial arm's before a tree's: a tree's kernels call most
# of an arm's, so a tree's step before its method's arm step takes both (and the arm's then a fifth of
# its own); scaled by how the long steps done so far compared with their estimates (a busy machine is slower)
KINEMATICS_SECONDS = 18.0  # the kinematics, the pose solver and a tree's limbs: 18.6 s measured on a cold cache
SCALED_BY = 5.0  # s: only steps at least this long scale the estimate (a short one is mostly imports)


@dataclass(frozen=True)
class Step:
    """One step of the warm-up: `work()` compiles the kernels of `method` (None: the kinematics) for
    one kind of robot ("arm": a serial arm's, "tree": a tree's, "all": both)."""

    index: int
    steps: int
    label: str
    method: str | None
    kind: str
    work: Callable[[], None]

    @property
    def key(self) -> tuple:
        return (self.method or "kinematics", self.kind)

    def needed_by(self, method: str, kind: str) -> bool:
        """Whether a run of `method` on a robot of `kind` calls this step's kernels."""
        return self.method in (None, warmed_by(method)) and self.kind in ("all", kind)


def warmed_by(method: str) -> str:
    """The method whose warm-up step compiles `method`'s kernels (Method.warms_with; itself if none)."""
    from lab import methods

    try:
        return methods.get(method).warms_with or method
    except ValueError:  # an unknown method: the run itself says so
        return method


def kind_of(robot: str) -> str:
    """"tree" for a robot of several end effectors, else "arm" (an unknown name too)."""
    import robots

    try:
        return "tree" if robots.kind(robot) == "tree" else "arm"
    except Exception:  # noqa: BLE001 - the run itself says what is wrong with its robot
        return "arm"


def plan(first: str | None = None, first_kind: str = "arm") -> list[Step]:
    """The warm-up's steps: the kinematics; `first`'s kernels (None: lab.methods.DEFAULT_METHOD, what
    the app's page opens with) for `first_kind`, then for the other kind; then every other method's (lab.methods.names() order), a serial arm's first."""
    from lab import methods

    names = [m.name for m in methods.all_methods() if not m.warms_with]  # one step stands for both
    first = warmed_by(methods.DEFAULT_METHOD if first is None else first)
    order = [first] + [m for m in names if m != first] if first in names else list(names)
    pairs = [(order[0], first_kind), (order[0], next(k for k in KINDS if k != first_kind))]
    pairs += [(m, k) for m in order[1:] for k in KINDS]
    n = len(pairs) + 1
    steps = [Step(1, n, "forward kinematics", None, "all", _kinematics)]
    for index, (method, kind) in enumerate(pairs, 2):
        robot = TREE if kind == "tree" else "planar"
        steps.append(Step(index, n, f"{methods.get(method).label} for {KIND_LABELS[kind]}", method, kind,
                          lambda m=method, r=robot: _method(m, r)))
    return steps


def _kinematics() -> None:
    import robots

    from robots import limbs, pose, pose_solve

    arm = robots.load("planar")
    q = arm.sample_q(2, seed=0)
    arm.fk(q)
    arm.joint_positions(q)
    ur5 = robots.load("ur5")  # pose goals: the tool frame, its Jacobian and the compiled pose solver
    pose_solve.solve_pose(ur5, pose.sample_poses(ur5, 1, seed=0)[0], seconds=None)
    tree = robots.load(TREE)  # a tree's limbs in closed form, which refine applies first
    q = tree.sample_q(2, seed=0)
    limbs.solve(tree, tree.reach(q), q)


def _method(method: str, robot: str) -> None:
    """A tiny run of `method` on `robot` and its controller once: every kernel they call, compiled."""
    import robots
    from lab.running.evolve import evolve

    run = evolve(robot, method, generations=2, population=10, targets=5, test_goals=5, seed=0)
    run.controller(robots.load(robot).sample_goals(2, seed=1))


class Estimate:
    """Seconds a step takes: its method's compile_seconds (for the steps done so far) scaled by the long
    steps done."""

    def __init__(self):
        self.done, self.typical_done = 0.0, 0.0
        self.keys: set = set()  # the steps done

    def scale(self) -> float:
        return self.done / self.typical_done if self.typical_done > 0 else 1.0

    @staticmethod
    def _typical(method: str, kind: str) -> float:
        if method == "kinematics":
            return KINEMATICS_SECONDS
        from lab import methods

        return methods.get(method).compile_seconds[KINDS.index(kind)]

    def typical(self, step: Step) -> float:
        method, kind = step.key
        own = self._typical(method, kind)
        if kind == "tree" and (method, "arm") not in self.keys:
            return own + self._typical(method, "arm")
        if kind == "arm" and (method, "tree") in self.keys:
            return own / 5
        return own

    def seconds(self, step: Step) -> float:
        return self.typical(step) * self.scale()

    def finished(self, step: Step, seconds: float) -> None:
        typical = self.typical(step)
        if typical >= SCALED_BY:
            self.done += seconds
            self.typical_done += typical
        self.keys.add(step.key)


def compile_kernels(progress: Callable | None = None, first: str | None = None) -> float:
    """Call every kernel once (forward kinematics, each method's fitness and controller, for a serial
    arm and a tree); seconds taken. progress(step, seconds): told before each step, with the s it is
    expected to take (None: silent)."""
    t = time.perf_counter()
    estimate = Estimate()
    for step in plan(first):
        if progress is not None:
            progress(step, estimate.seconds(step))
        t_step = time.perf_counter()
        step.work()
        estimate.finished(step, time.perf_counter() - t_step)
    return time.perf_counter() - t


def main() -> None:
    seconds = compile_kernels(lambda step, _s: print(f"compiling kernels ({step.index}/{step.steps}): {step.label}",
                                                     flush=True))
    print(f"numba kernels compiled and cached in {seconds:.1f} s (once: later runs load them)")


if __name__ == "__main__":
    main()
