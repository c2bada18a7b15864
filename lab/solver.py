"""One call for an engineer: a controller's answer made exact.

    import lab, robots
    arm = robots.load("so100")
    controller = lab.controller_from_dict(json.load(open("app/pretrained/so100-cmaes.json"))["controller"])
    goals = arm.sample_goals(100, seed=1)
    s = lab.solve(controller, arm, goals)       # the network, then at most 3 refinement steps
    s.q, s.error, s.converged                   # (n, nq) joint angles, (n,) position errors, (n,) within 0.1 mm

    from robots import pose
    poses = pose.sample_poses(arm, 100, seed=1)  # (n, 4, 4) pose goals
    s = lab.solve(None, arm, poses, q0=q_near)  # no pose controller yet: refine from q0 (or the rest pose)
    s.error, s.angle                            # position [m] and angle [rad] errors
    s = lab.solve(pose_controller, arm, poses)  # the default on poses: compiled descents, then restarts,
                                                # 5 ms a pose at most, within 1e-5 m and 1e-5 rad (TRAC-IK's terms)

The network proposes (every head of a multi-head MLP: lab.problem.controllers.proposals, the
nearest its goal first), robots.ik.refine makes the answer exact: on the shipped SO-100 controller
the proposals of all its heads bring more goals within 0.1 mm than its one chosen answer
(docs/pose.md).

With `seconds` (pose goals; their default, 5 ms), each goal is solved by robots.pose_solve instead: compiled
Levenberg-Marquardt descents from the proposals in order, then from random joint vectors while the
budget lasts (TRAC-IK's terms: docs/results/pose.md).

A pose controller declares `goal = "pose"`, takes (n, 4, 4) poses and returns
(n, nq) joint angles, and may give several answers per goal through a `proposals(poses)` method
returning (k, n, nq); a controller without the attribute answers position goals.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

import robots
from lab.problem.controllers import proposals as _proposals
from lab.problem.controllers import swept_proposals
from lab.problem.robot import load_arm
from robots import pose, pose_solve
from robots.ik import RefineResult, default_tolerance, pose_tolerances, refine
from robots.seeds import table as seed_table


@dataclass(frozen=True)
class Solution:
    """Joint angles for goals and how near each goal they come.

    q          (n, nq) joint angles within the limits
    error      (n,) position error [the arm's length unit: m on a real arm] (a tree: its worst effector's)
    angle      (n,) angle error [rad] for pose goals (robots.pose.pose_errors), None for position goals
    converged  (n,) bool: error < tol (and angle < angle_tol for pose goals)
    tol, angle_tol  the tolerances [length], [rad] (angle_tol None for position goals)
    steps      (n,) refinement steps taken
    choice     (n,) the proposal kept for each goal (0: the controller's own answer), None with one
    network_error, network_angle  (n,) the same errors of the controller's own answer before
               refinement (None without a controller; network_angle None for position goals)
    seconds    wall time of the whole call (the network and the refinement)
    """

    q: np.ndarray
    error: np.ndarray
    angle: np.ndarray | None
    converged: np.ndarray
    tol: float
    angle_tol: float | None
    steps: np.ndarray
    choice: np.ndarray | None
    network_error: np.ndarray | None
    network_angle: np.ndarray | None
    seconds: float

    @property
    def success(self) -> float:
        """The share of goals within tolerance."""
        return float(np.mean(self.converged)) if len(self.converged) else float("nan")


def goal_kind(controller) -> str:
    """"pose" for a controller that declares `goal = "pose"`, else "position"."""
    return "pose" if getattr(controller, "goal", "position") == "pose" else "position"


def _position_errors(arm: robots.Arm, goals: np.ndarray, q: np.ndarray) -> np.ndarray:
    """||reach(q) - goal||, a tree's worst effector's (refine's error)."""
    d = np.linalg.norm(arm.reach(q) - goals, axis=-1)
    return d.max(axis=-1) if arm.is_tree else d


SWEEP = 16  # values of each swept joint tried on pose goals (docs/pose.md)
STEPS = 3  # refinement steps by default (position goals; pose goals with steps given and no seconds)
# pose goals by default: the compiled solver (robots.pose_solve) with TRAC-IK's budget and tolerances
# (5 ms a pose, 1e-5 m, 1e-5 rad; docs/results/pose.md), which meets them on 99.75-100 % of poses
POSE_SECONDS, POSE_TOL = 0.005, 1e-5
SWEEP_KEEP = 4  # of which the nearest each goal are proposed
# position goals left outside tolerance: tried again from this many entries of the arm's seed table
# (robots.seeds), the nearest each goal (docs/results/your-robot.md)
TABLE = 8


def solve(controller, arm, goals, *, q0=None, steps: int | None = None, tol: float | None = None,
          angle_tol: float | None = None, seconds: float | None = None, seed: int | None = 0,
          sweep: int = SWEEP, table: int = TABLE, progress: bool = True) -> Solution:
    """Joint angles that put the arm on `goals`: the controller's answers (every head's, as
    proposals), then at most `steps` refinement steps (robots.ik.refine) toward each goal.

    controller: a lab controller (lab.controller_from_dict, a Run's), or None to refine from q0;
    arm: a robots.Arm or a robot's string robots.load knows (a registered name, erd:NAME, a URDF path); goals: positions (n, len(task_axes)) ((n, E,
    len(task_axes)) on a tree) or poses (n, 4, 4) of the tool frame (robots.pose; a pose controller,
    or controller=None). q0: (n, nq) or (k, n, nq) more proposals, tried after the controller's
    (with controller=None: the only ones; neither given: the rest pose). tol [length] and angle_tol
    [rad]: refine's (default 0.1 mm on a real arm, 0.1 degree). steps=0: the first proposal alone
    (the network's own answer; no refinement, not even refine's turn of the first joint), measured.
    Defaults: position goals, STEPS refinement steps; pose goals, the compiled solver with TRAC-IK's
    terms (seconds=POSE_SECONDS, tol=angle_tol=POSE_TOL: 5 ms, 1e-5 m, 1e-5 rad), unless steps,
    seconds or the tolerances are given (steps alone: refinement, at 0.1 mm and 0.1 degree by default).
    seconds (pose goals): a wall-time budget a goal for robots.pose_solve.solve_pose, which takes
    the proposals' compiled descents (each at most pose_solve.STEPS_FROM_START steps, `steps` not
    used) and then descents from random joint vectors (a generator of `seed` + the goal's index)
    until one is within tolerance or the budget is spent; steps then counts every descent's steps.
    sweep (pose goals
    refined by steps, a pose controller with the closed-form reach): where no answer of the
    controller's is within tolerance, its answers with one joint at a time set to `sweep` values over
    its range and the closed form solving the rest are proposed too, the SWEEP_KEEP nearest each goal after the
    controller's own (lab.problem.controllers.swept_proposals; 0: none). table (position goals refined by
    steps): the goals no proposal brings within tolerance are tried again, each from the `table` entries
    of the arm's seed table (robots.seeds: joint vectors drawn within the limits) that reach nearest it,
    as refine's proposals, and keep the nearer answer (Solution.choice: the number of proposals plus the
    entry's rank; 0: none). ValueError, naming the problem, for a
    controller made for other goals or another arm, and for goals refine refuses.

    An empty batch (0 goals) gives an empty Solution of the same shapes ((0, nq) joint angles).
    Many goals are solved CHUNK at a time (the network's proposals and refinement's work bounded by
    a chunk, not by the batch; each goal's answer is the one it gets alone), with a progress line on
    stderr once the call has run PROGRESS_AFTER seconds (progress=False: none)."""
    t0 = time.perf_counter()
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0):
        raise ValueError(f"steps must be an integer >= 0, got {steps!r}")
    if isinstance(sweep, bool) or not isinstance(sweep, (int, np.integer)) or sweep < 0:
        raise ValueError(f"sweep must be an integer >= 0 (values of the swept joint), got {sweep!r}")
    if isinstance(table, bool) or not isinstance(table, (int, np.integer)) or table < 0:
        raise ValueError(f"table must be an integer >= 0 (the seed table's entries tried a goal), got {table!r}")
    if not isinstance(arm, (str, robots.Arm)):
        raise ValueError(f"arm must be a robots.Arm or a robot's name, got {type(arm).__name__}")
    arm = load_arm(arm)  # a registered name, erd:NAME or a URDF path (lab/problem/robot.py)
    is_pose = pose.is_pose_array(goals)
    if is_pose:
        goals = pose.check_poses(goals, what=f"{arm.name}: pose goals")
    else:
        try:
            goals = np.asarray(goals, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{arm.name}: goals must be an array of numbers") from None
        goals = goals[None] if goals.ndim == (2 if arm.is_tree else 1) else goals
        shape = (*((arm.n_effectors,) if arm.is_tree else ()), len(arm.task_axes))
        if goals.shape[1:] != shape:
            raise ValueError(f"{arm.name}: goals must be positions (n, {', '.join(map(str, shape))}) or poses "
                             f"(n, 4, 4), got shape {goals.shape}")
        if not np.isfinite(goals).all():
            bad = int((~np.isfinite(goals)).reshape(len(goals), -1).any(axis=1).sum())
            raise ValueError(f"{arm.name}: {bad} of {len(goals)} goals hold NaN or infinity")
    kind = "pose" if is_pose else "position"
    if controller is not None:
        if goal_kind(controller) != kind:
            fix = ("; for pose goals without a pose controller pass controller=None and q0 (or nothing: the "
                   "rest pose)" if is_pose else "")
            raise ValueError(f"{arm.name}: this controller answers {goal_kind(controller)} goals, these goals are "
                             f"{kind}s, shape {goals.shape}{fix}")
        encoding = getattr(controller, "encoding", None)
        if encoding is not None and len(getattr(encoding, "q_lo", ())) != arm.nq:
            raise ValueError(f"{arm.name}: this controller answers {len(encoding.q_lo)} joints, the arm has {arm.nq}")
        if encoding is not None and not is_pose and tuple(encoding.task_axes) != tuple(arm.task_axes):
            raise ValueError(f"{arm.name}: this controller takes goals on task axes {tuple(encoding.task_axes)}, "
                             f"the arm's are {tuple(arm.task_axes)}")
    extra = None
    if q0 is not None:
        q0 = np.asarray(q0, dtype=np.float64)
        extra = q0 if q0.ndim == 3 else np.atleast_2d(q0)[None]
        if extra.shape[1:] != (len(goals), arm.nq) or not len(extra):
            raise ValueError(f"{arm.name}: q0 must be ({len(goals)}, {arm.nq}) or (k, {len(goals)}, {arm.nq}), "
                             f"got shape {q0.shape}")
    if is_pose and steps is None and seconds is None:  # the default on poses: the compiled solver, TRAC-IK's terms
        seconds = POSE_SECONDS
    steps = STEPS if steps is None else steps
    if seconds is not None:
        if not is_pose:
            raise ValueError(f"{arm.name}: seconds (the compiled solver's budget) applies to pose goals (n, 4, 4); "
                             f"for position goals leave it None (refinement steps)")
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds > 0:
            raise ValueError(f"seconds must be a number > 0 (a goal's budget), got {seconds!r}")
    if is_pose:
        if seconds is not None:  # the compiled solver: TRAC-IK's tolerances unless given
            tol, angle_tol = (POSE_TOL if tol is None else tol), (POSE_TOL if angle_tol is None else angle_tol)
        tol, angle_tol = pose_tolerances(arm, tol, angle_tol)
    else:
        if angle_tol is not None:
            raise ValueError(f"{arm.name}: angle_tol applies to pose goals (n, 4, 4); these goals have shape "
                             f"{goals.shape}")
        tol = default_tolerance(arm) if tol is None else float(tol)
    args = (controller, arm, steps, tol, angle_tol, seconds, seed, sweep, table, is_pose)
    n = len(goals)
    if 0 < n <= CHUNK:  # one chunk (a drag's one pose): no copies, no progress line
        with _compile_notice(is_pose, controller):
            return _chunk(*args, goals, extra, 0, t0)
    if n == 0:
        return _empty(controller, arm, extra, tol, angle_tol, is_pose, t0)
    parts, bar = [], _Progress(n, f"lab.solve {arm.name}", t0, progress)
    try:
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            with _compile_notice(is_pose, controller):
                parts.append(_chunk(*args, goals[a:b], None if extra is None else extra[:, a:b], a, t0))
            bar.advance(b - a)
    finally:
        bar.close()
    return _joined(parts, time.perf_counter() - t0)


CHUNK = 4096  # goals solved at once: the proposals, swept proposals and refinement's arrays of a chunk at most
PROGRESS_AFTER = 3.0  # s: a call still going after this long shows a progress line (stderr)


class _Progress:
    """A progress line on stderr (tqdm, as python -m lab's), started only once the call has run
    PROGRESS_AFTER seconds: a quick call prints nothing."""

    def __init__(self, total: int, label: str, t0: float, enabled: bool):
        self.total, self.label, self.t0, self.enabled = total, label, t0, enabled
        self.done, self.bar = 0, None

    def advance(self, k: int) -> None:
        self.done += k
        if self.bar is not None:
            self.bar.update(k)
        elif self.enabled and self.done < self.total and time.perf_counter() - self.t0 >= PROGRESS_AFTER:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=self.done, desc=self.label, unit="goal", file=sys.stderr,
                            mininterval=1.0, dynamic_ncols=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _chunk(controller, arm, steps, tol, angle_tol, seconds, seed, sweep, table, is_pose, goals, extra, offset,
           t0) -> Solution:
    """solve on checked goals (at most CHUNK of them), the goals[offset:] of the call; tol and
    angle_tol resolved; extra: the caller's q0 of these goals, (k, n, nq), or None; seconds since t0."""
    seeds = []
    if controller is not None:
        own = controller.proposals(goals) if hasattr(controller, "proposals") else _proposals(controller, goals)
        own = np.asarray(own, dtype=np.float64)
        if own.shape[1:] != (len(goals), arm.nq):
            raise ValueError(f"{arm.name}: the controller proposed shape {own.shape}, not (k, {len(goals)}, {arm.nq})")
        seeds.append(own)
        if is_pose and steps and seconds is None and sweep:
            seeds.append(_swept(controller, arm, goals, own, sweep, tol, angle_tol))
    if extra is not None:
        seeds.append(extra)
    if not seeds:
        seeds.append(np.broadcast_to(arm.rest, (1, len(goals), arm.nq)))
    seeds = np.concatenate(seeds) if len(seeds) > 1 else seeds[0]
    first = arm.within_limits(seeds[0])
    if is_pose:
        first_error, first_angle = pose.pose_errors(arm, goals, first)
    else:
        first_error, first_angle = _position_errors(arm, goals, first), None
    network = controller is not None
    if seconds is not None:
        return _budgeted(arm, goals, seeds, first_error, first_angle, network, tol, angle_tol, seconds,
                         None if seed is None else seed + offset, t0)
    if steps == 0:  # the first proposal alone, measured (refine would still turn the first joint)
        r = RefineResult(first, first_error, np.zeros(len(goals), np.int64), 0.0, angle=first_angle, tol=tol,
                         angle_tol=angle_tol)
    else:
        r = refine(arm, goals, seeds, steps=steps, tol=tol, angle_tol=angle_tol)
        if not is_pose and table and not r.converged.all():
            r = _from_table(arm, goals, r, len(seeds), table, steps)
    return Solution(q=r.q, error=r.error, angle=r.angle, converged=r.converged, tol=r.tol, angle_tol=r.angle_tol,
                    steps=r.steps, choice=r.choice, network_error=first_error if network else None,
                    network_angle=first_angle if network else None, seconds=time.perf_counter() - t0)


def _from_table(arm, goals, r: RefineResult, k: int, table: int, steps: int) -> RefineResult:
    """r with the goals it left outside tolerance refined again from the `table` entries of the arm's
    seed table nearest each (robots.seeds; refine's proposals: each its first step, the nearest after
    it the rest), each goal keeping the nearer answer; its choice then k (r's proposals) plus the
    entry's rank (refine's choice among the entries)."""
    miss = np.flatnonzero(~r.converged)
    again = refine(arm, goals[miss], seed_table(arm).nearest(goals[miss], table), steps=steps, tol=r.tol)
    better = again.error < r.error[miss]
    at = miss[better]
    if not len(at):
        return r
    q, error, taken = r.q.copy(), r.error.copy(), r.steps.copy()
    choice = np.zeros(len(goals), np.int64) if r.choice is None else r.choice.copy()
    q[at], error[at], taken[at] = again.q[better], again.error[better], again.steps[better]
    choice[at] = k + (again.choice[better] if again.choice is not None else 0)
    return RefineResult(q, error, taken, r.seconds + again.seconds, choice, tol=r.tol)


def _empty(controller, arm, extra, tol, angle_tol, is_pose, t0) -> Solution:
    """The answer to 0 goals: arrays of length 0 where a batch has arrays (choice: None when only
    one proposal is known, the rest pose or a single q0; a controller's may be several)."""
    none = np.zeros(0)
    several = controller is not None or (extra is not None and len(extra) > 1)
    return Solution(q=np.zeros((0, arm.nq)), error=none, angle=none.copy() if is_pose else None,
                    converged=np.zeros(0, bool), tol=tol, angle_tol=angle_tol if is_pose else None,
                    steps=np.zeros(0, np.int64), choice=np.zeros(0, np.int64) if several else None,
                    network_error=none.copy() if controller is not None else None,
                    network_angle=none.copy() if controller is not None and is_pose else None,
                    seconds=time.perf_counter() - t0)


def _joined(parts: list[Solution], seconds: float) -> Solution:
    """The chunks' Solutions as one, in order."""
    def cat(name):
        values = [getattr(p, name) for p in parts]
        return None if any(v is None for v in values) else np.concatenate(values)

    head = parts[0]
    return Solution(q=cat("q"), error=cat("error"), angle=cat("angle"), converged=cat("converged"), tol=head.tol,
                    angle_tol=head.angle_tol, steps=cat("steps"), choice=cat("choice"),
                    network_error=cat("network_error"), network_angle=cat("network_angle"), seconds=seconds)


def _swept(controller, arm, goals, own, sweep, tol, angle_tol) -> np.ndarray:
    """(SWEEP_KEEP, n, nq) swept_proposals of the goals that no answer of the controller's own meets
    within tolerance (for the others, copies of their first answer, which refine does not step)."""
    tol, angle_tol = pose_tolerances(arm, tol, angle_tol)
    k, n = own.shape[:2]
    p, a = pose.pose_errors(arm, np.tile(goals, (k, 1, 1)), arm.within_limits(own).reshape(k * n, arm.nq))
    met = ((p < tol) & (a < angle_tol)).reshape(k, n).any(axis=0)
    out = np.repeat(own[:1], SWEEP_KEEP, axis=0)
    if not met.all():
        more = swept_proposals(controller, goals[~met], own[:, ~met], int(sweep), SWEEP_KEEP, tol / angle_tol)
        out = out[: len(more)]
        out[:, ~met] = more
    return out


COMPILE_NOTICE_AFTER = 1.0  # s: where numba's cache cannot be read, a first pose solve this long says it compiles
COMPILE_NOTICE = "lab.solve: compiling the pose solver (once; cached afterwards) ..."
_solved_once = threading.Event()  # set once a pose solve has returned in this process


def _pose_kernels(controller) -> list:
    """The compiled kernels a pose solve calls: the solver's and the tool frame's, and a pose network's
    (its inputs, outputs and closed form) when it has one."""
    kernels = [pose_solve.descend_many, pose._pose_kernel]
    if getattr(getattr(controller, "encoding", None), "goal", None) == "pose":
        from lab.problem import kernels as network, pose_kernels

        kernels += [pose_kernels.finish_joints_errors, network.mlp_offset_outputs, network.polar_inputs]
    return kernels


def _solver_cached(kernels) -> bool | None:
    """Whether numba's on-disk cache holds each of these kernels (not loaded yet) for its current source
    (then a first solve loads them in a moment); None where the cache cannot be read (numba's private API)."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in kernels)
    except Exception:  # noqa: BLE001 - another numba: the timer decides
        return None


@contextlib.contextmanager
def _compile_notice(active: bool = True, controller=None):
    """Around a pose solve (active): the first in this process, where a kernel it calls (_pose_kernels) is
    neither loaded nor cached on disk (numba then compiles: 16-40 s for the solver, as long again for a pose
    network's), prints COMPILE_NOTICE on stderr first; where the cache cannot be read, when the solve
    has not returned after COMPILE_NOTICE_AFTER s and a kernel is not loaded by then. Later solves, and a
    first one that loads its kernels from the cache, say nothing."""
    kernels = _pose_kernels(controller) if active and not _solved_once.is_set() else []
    waiting = [k for k in kernels if not k.signatures]
    if not waiting:
        yield
        return
    cached = _solver_cached(waiting)
    if cached is False:
        print(COMPILE_NOTICE, file=sys.stderr, flush=True)

    def say() -> None:  # unless the kernels are loaded by then (a long batch, not a compile)
        if any(not k.signatures for k in waiting):
            print(COMPILE_NOTICE, file=sys.stderr, flush=True)

    timer = threading.Timer(COMPILE_NOTICE_AFTER, say) if cached is None else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        yield
    finally:
        if timer is not None:
            timer.cancel()
        _solved_once.set()


def _budgeted(arm, goals, seeds, first_error, first_angle, network: bool, tol, angle_tol, seconds,
              seed, t0) -> Solution:
    """solve's seconds: each pose goal by robots.pose_solve.solve_pose from its proposals, then restarts
    (goal i's generator: seed + i)."""
    n = len(goals)
    q, error, angle = np.empty((n, arm.nq)), np.empty(n), np.empty(n)
    converged, steps = np.zeros(n, bool), np.zeros(n, np.int64)
    solver = pose_solve.PoseSolver(arm, tol=tol, angle_tol=angle_tol)
    for i in range(n):
        r = solver.solve(goals[i], seeds[:, i], seconds=float(seconds), seed=None if seed is None else seed + i)
        q[i], error[i], angle[i], converged[i], steps[i] = r.q, r.error, r.angle, r.converged, r.iterations
    return Solution(q=q, error=error, angle=angle, converged=converged, tol=tol, angle_tol=angle_tol, steps=steps,
                    choice=None, network_error=first_error if network else None,
                    network_angle=first_angle if network else None, seconds=time.perf_counter() - t0)
