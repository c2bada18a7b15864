"""Compile the numba kernels once, so the first training run does not wait for them.

numba compiles on first call and caches the machine code under __pycache__/ (NUMBA_CACHE_DIR when
set): about a minute of compiling on a 2-core machine, then milliseconds to load. `make test` runs
this first. The app has its spare training process (lab/running/worker.py) do it as the page
serves, the opened robot's own kernels for the method the page opens with first, each step told
to the app (`python -m app` prints them, the tab says what a Start waits for): a process of its
own, so the app's threads never wait on numba's compiler and Ctrl-C ends the app at once.

Which kernels a run calls depends on its method and on its robot's settings (a tree's kernels, an
MLP of several heads, pose goals): a step is named by that `key` (run_key), and a run waits only for
the kinematics and the step of its own key (`Step.needed_by`). A step's estimate comes from this
machine: the seconds the same step took the last time it compiled here (FIGURES, a small JSON
beside numba's cache, written after every step that compiled), scaled by how the steps done so far
this time compared with their own last figures (a busy machine is slower); a step never timed here
is scaled from the method's compile_seconds by the same measure. Nothing timed yet and no figure:
no estimate (`Estimate.seconds` is None).

    python -m lab.running.warmup            # every step
    python -m lab.running.warmup --first    # only what the app's first Start needs (make app)
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Callable

PLANAR = "planar"  # the serial arms' kernels (one end effector, one head)
HEADS = "ur5"  # a real arm's, with CMA-ES's several heads
TREE = "talos-legs"  # the trees' (several end effectors; every tree shares them)
REPRESENTATIVES = (PLANAR, HEADS, TREE)
KINEMATICS = "kinematics"  # the key of the step every run waits for
FIGURES = "warmup-seconds.json"  # beside numba's cache: each step's seconds the last time it compiled here
# reference s of a step on the 2-core machine of docs/log.md with an empty cache, used only as the
# ratio of one step to another where this machine has no figure of its own (scaled by its own steps)
REFERENCE_SECONDS = {KINEMATICS: 2.5, "pose": 9.5, "limbs": 2.5}
LOADS = "_load"  # in FIGURES: the machine's busy factor (busy()) when each figure was taken
SCALED_BY = 5.0  # s: compiled steps this long in all scale the estimates by themselves, else the load does


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
        kind = robots.kind(robot)
        if kind not in ("paper", "snake", "real", "tree"):  # erd:NAME or a URDF: the arm says (robots.load caches it)
            from lab.problem.robot import arm_kind, load_arm

            kind = arm_kind(load_arm(robot))
        return "tree" if kind == "tree" else "arm"
    except Exception:  # noqa: BLE001 - the run itself says what is wrong with its robot
        return "arm"


def run_key(config) -> str:
    """What decides the kernels a run of this TrainConfig calls: its (warming) method, a tree or an
    arm, one head or several, wired or not, its kind of goal. "cmaes/arm/heads/position"."""
    return "/".join((warmed_by(config.method), kind_of(config.robot), "heads" if (config.heads or 1) > 1 else "1",
                     *(["wired"] if config.wiring else []), config.goal))


def default_config(robot: str = PLANAR, method: str | None = None):
    """The run a Start on `robot` makes with the method's defaults (None: the robot's default method)."""
    from lab.running.config import TrainConfig

    return TrainConfig.preset(robot=robot, method=method)


@dataclass(frozen=True)
class Step:
    """One step of the warm-up: `work()` compiles the kernels of `key` (KINEMATICS: the forward
    kinematics every run calls; "pose", "limbs": the app's own solvers, which no run calls; else a
    run_key)."""

    index: int
    steps: int
    label: str
    key: str
    work: Callable[[], None]

    def needed_by(self, key: str) -> bool:
        """Whether a run of run_key `key` calls this step's kernels."""
        return self.key in (KINEMATICS, key)

    def numbered(self, index: int, steps: int) -> "Step":
        return Step(index, steps, self.label, self.key, self.work)


def method_step(config, label: str | None = None) -> Step:
    """The step that compiles what a run of `config` calls: a tiny run of its settings."""
    from lab import methods

    label = label or f"{methods.get(warmed_by(config.method)).label} for {config.robot}"
    return Step(0, 0, label, run_key(config), lambda: _tiny_run(config))


def plan(first=None, robot: str = PLANAR) -> list[Step]:
    """The warm-up's steps: the kinematics; `first`'s kernels (a TrainConfig; None: the robot's default
    method on `robot`, what the app's page opens with); the app's pose solver and a tree's limbs;
    then every method (lab.methods.names() order, the first one's first) on a serial arm, an arm of
    several heads and a tree, each key once."""
    from lab import methods

    first = default_config(robot) if first is None else first
    steps = [Step(0, 0, "forward kinematics", KINEMATICS, lambda r=first.robot: _kinematics(r)),
             method_step(first),
             Step(0, 0, "pose goals (the app's pose solver)", "pose", _pose),
             Step(0, 0, "a tree's limbs in closed form", "limbs", _limbs)]
    lead = warmed_by(first.method)
    order = [lead] + [m.name for m in methods.all_methods() if not m.warms_with and m.name != lead]
    for method in order:
        for robot_name in REPRESENTATIVES:
            try:
                config = default_config(robot_name, method)
            except ValueError:  # a method that does not train this robot
                continue
            if all(run_key(config) != s.key for s in steps):
                steps.append(method_step(config, f"{methods.get(method).label} for {_kind_label(config)}"))
    return [s.numbered(i, len(steps)) for i, s in enumerate(steps, 1)]


def for_run(steps: list[Step], done: set, config) -> list[Step]:
    """The steps a run of `config` still waits for, numbered for it: of `steps`, those it needs and
    not in `done` (their keys), with its own step when none of them is its key."""
    key = run_key(config)
    wanted = [s for s in steps if s.needed_by(key) and s.key not in done]
    if key not in done and all(s.key != key for s in wanted):
        wanted.append(method_step(config))
    return [s.numbered(i, len(wanted)) for i, s in enumerate(wanted, 1)]


def _kind_label(config) -> str:
    if kind_of(config.robot) == "tree":
        return "trees of several end effectors"
    return "arms of several heads" if (config.heads or 1) > 1 else "serial arms"


def _kinematics(robot: str) -> None:
    import robots

    for name in dict.fromkeys((PLANAR, robot)):
        arm = robots.load(name)
        q = arm.sample_q(2, seed=0)
        arm.fk(q)
        arm.joint_positions(q)


def _pose() -> None:
    import robots

    from robots import pose, pose_solve

    ur5 = robots.load(HEADS)  # pose goals: the tool frame, its Jacobian and the compiled pose solver
    pose_solve.solve_pose(ur5, pose.sample_poses(ur5, 1, seed=0)[0], seconds=None)


def _limbs() -> None:
    import robots

    from robots import limbs

    tree = robots.load(TREE)  # a tree's limbs in closed form, which refine applies first
    q = tree.sample_q(2, seed=0)
    limbs.solve(tree, tree.reach(q), q)


def _tiny_run(config) -> None:
    """A tiny run of `config`'s settings and its controller once: every kernel they call, compiled."""
    import robots
    from lab.running.evolve import Run
    from lab.running.runner import Runner

    tiny = config.replace(generations=2, population=10, targets=5, test_goals=5, seconds=None, seed=0)
    summary = Runner(tiny).run()
    if summary.state == "failed":
        raise RuntimeError(f"the warm-up's run of {run_key(config)} failed: {summary.error}")
    arm = robots.load(config.robot)
    if config.goal == "pose":
        from robots import pose

        goals = pose.sample_poses(arm, 2, seed=1)
    else:
        goals = arm.sample_goals(2, seed=1)
    Run.from_summary(summary).controller(goals)


# ---------------------------------------------------------------------- the estimates
def figures_path() -> str:
    """FIGURES beside numba's cache: in NUMBA_CACHE_DIR when set, else in this package's __pycache__."""
    folder = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                               "__pycache__")
    return os.path.join(folder, FIGURES)


def stored_figures(path: str | None = None) -> dict[str, float]:
    """The seconds each step took the last time it compiled here ({} when none, or unreadable)."""
    try:
        with open(path or figures_path(), encoding="utf-8") as f:
            d = json.load(f)
    except (OSError, ValueError):
        return {}
    return {k: float(v) for k, v in d.items() if isinstance(v, (int, float)) and v > 0} if isinstance(d, dict) else {}


def busy() -> float:
    """How much slower than alone a process runs here now: runnable processes (the load average over
    a minute) per core, at least 1."""
    try:
        return max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))
    except OSError:
        return 1.0


def stored_loads(path: str | None = None) -> dict[str, float]:
    """busy() when each stored figure was taken ({} when not stored)."""
    try:
        with open(path or figures_path(), encoding="utf-8") as f:
            d = json.load(f).get(LOADS, {})
        return {k: max(1.0, float(v)) for k, v in d.items() if isinstance(v, (int, float))}
    except (OSError, ValueError, AttributeError):
        return {}


def store_figure(key: str, seconds: float, path: str | None = None, load: float | None = None) -> None:
    """Write (atomically) that step `key` took `seconds` to compile here, with busy() then (load); a
    folder that cannot be written leaves the estimates as they were."""
    path = path or figures_path()
    figures = stored_figures(path)
    figures[key] = round(float(seconds), 2)
    figures[LOADS] = {**stored_loads(path), key: round(busy() if load is None else load, 2)}
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix=".warmup-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(figures, f, indent=0, sort_keys=True)
        os.replace(tmp, path)
    except OSError:
        pass


class Estimate:
    """Seconds a step takes on this machine now: its stored figure (else its reference figure, taken
    on a quiet machine), scaled by the steps that compiled so far this time, each against its own
    figure, once they add up to SCALED_BY s; before that by how busy the machine is now against
    when the figure was taken (busy(): a short step is mostly imports, which say little)."""

    def __init__(self, figures: dict[str, float] | None = None, loads: dict[str, float] | None = None):
        self.figures = stored_figures() if figures is None else dict(figures)
        self.loads = stored_loads() if loads is None else dict(loads)
        self.now, self.then = 0.0, 0.0  # s the compiled steps took this time, and by their figures

    def scale(self, key: str | None = None) -> float:
        """How much longer than its figure a step of `key` takes now: the load now against the load
        then, times how much longer than so scaled the steps done this time took (once they are long
        enough to tell)."""
        done = self.now / self.then if self.now >= SCALED_BY and self.then > 0 else 1.0
        return busy() / self.loads.get(key, 1.0) * done

    def _base(self, key: str) -> tuple[float, bool]:
        """(the figure, whether this machine measured it)."""
        if key in self.figures:
            return self.figures[key], True
        if key in REFERENCE_SECONDS:
            return REFERENCE_SECONDS[key], False
        from lab import methods

        method, kind = key.split("/")[:2]
        try:
            return methods.get(method).compile_seconds[1 if kind == "tree" else 0], False
        except ValueError:
            return 10.0, False

    def seconds(self, step: Step) -> float | None:
        """The step's expected seconds; None when this machine has measured nothing to base it on."""
        base, measured = self._base(step.key)
        if not measured and self.then == 0:
            return None
        return base * self.scale(step.key)

    def finished(self, step: Step, seconds: float, compiled: bool, store: bool = True) -> None:
        """Step done in `seconds`; compiled: numba compiled in it (a step that loaded from the cache
        says nothing of this machine's compiling). Its figure is stored for the next warm-up."""
        if not compiled:
            return
        base, _ = self._base(step.key)
        load = self.loads.get(step.key, 1.0)
        self.now += seconds
        self.then += base * busy() / load  # its figure at this load: the long steps' ratio is load-free
        self.figures[step.key], self.loads[step.key] = seconds, busy()
        if store:
            store_figure(step.key, seconds, load=self.loads[step.key])


class CompileWatch:
    """Counts numba's compiles in this process (a kernel that missed the cache); on_first() once at
    the first."""

    def __init__(self, on_first: Callable[[], None] | None = None):
        from numba.core import event

        self.count, self._on_first = 0, on_first
        watch = self

        class Listener(event.Listener):
            def on_start(self, _event) -> None:
                watch.count += 1
                if watch.count == 1 and watch._on_first is not None:
                    watch._on_first()

            def on_end(self, _event) -> None:
                pass

        event.register("numba:compile", Listener())


def run_steps(steps: list[Step], progress: Callable | None = None, estimate: Estimate | None = None,
              watch: CompileWatch | None = None) -> float:
    """Do `steps` in order; seconds taken. progress(step, seconds or None): told before each step."""
    t = time.perf_counter()
    estimate = estimate or Estimate()
    watch = watch or CompileWatch()
    for step in steps:
        if progress is not None:
            progress(step, estimate.seconds(step))
        count, t_step = watch.count, time.perf_counter()
        step.work()
        estimate.finished(step, time.perf_counter() - t_step, watch.count > count)
    return time.perf_counter() - t


def compile_kernels(progress: Callable | None = None, first=None, robot: str = PLANAR,
                    only_first: bool = False) -> float:
    """Call every kernel once (forward kinematics, each method's fitness and controller, for a serial
    arm, an arm of several heads and a tree); seconds taken. progress(step, seconds): told before
    each step, with the s it is expected to take (None: silent). only_first: only what `first`'s run
    (a TrainConfig; None: the default method on `robot`) waits for."""
    steps = plan(first, robot)
    if only_first:
        steps = for_run(steps, set(), first if first is not None else default_config(robot))
    return run_steps(steps, progress)


def main(argv: list[str]) -> None:
    def say(step, seconds) -> None:
        about = f" (about {seconds:.0f} s)" if seconds is not None else ""
        print(f"compiling kernels ({step.index}/{step.steps}): {step.label}{about}", flush=True)

    seconds = compile_kernels(say, only_first="--first" in argv)
    print(f"numba kernels compiled and cached in {seconds:.1f} s (once: later runs load them)")


if __name__ == "__main__":
    main(sys.argv[1:])
