"""A student's run as *My experiment* offers it: its default length, sized by measurement, and how
long a queued run will wait.

    student_length("planar", "cmaes")   # {"generations": 3000, "seconds": None}
    student_length("ur5", "cmaes")      # {"generations": None, "seconds": 15.0}
    ahead, seconds = queue_wait(runs, run)   # runs ahead of a queued one, its estimated wait (None: unknown)

**Defaults** (docs/results/class.md, `python benchmarks/bench_class_defaults.py`, one thread): the
lab's preset for a paper arm (70 goals, 1000 generations) is fast there, and the 200 generations the
panel gave before ended at a held-out MSE of 0.79 on the planar arm in under 2 s. A student's run on an arm
whose preset is the paper's (at most PAPER_GENERATIONS generations, not a tree) runs the method's
`class_generations` (the registry's; a fixed number: the class's runs compare seed for seed, whatever
the load); on a real
arm or a tree, and with a method that has none, a time budget of BUDGET seconds (the method's
budget defaults, lab docs/results/budgets.md). Each is 5-20 s of training on one worker of the
2-core machine it was measured on.

**The wait**: the runs ahead (running, then queued before it) on `runs.workers` workers, each run's
length estimated from what this server has measured: an ended run of the same settings (its wall
time from start to end), else the same robot and method's wall time a generation, else (a time
budget) its seconds plus the start and end the ended runs paid. None when nothing is measured yet.
"""

from __future__ import annotations

import heapq
import statistics
import time

import lab
import robots

PAPER_GENERATIONS = 1000  # a preset of at most this many generations is the paper's short run
BUDGET = 15.0  # s: a real arm's or a tree's student run, or another method's


def student_length(robot: str, method: str) -> dict:
    """{"generations": N or None, "seconds": S or None}: a student's default run length on this robot
    with this method (ValueError from the preset for an unknown robot or method)."""
    preset = lab.TrainConfig.preset(robot=robot, method=method)
    tree = robots.load(robot).is_tree
    generations = lab.methods.get(method).class_generations
    if generations is not None and preset.generations <= PAPER_GENERATIONS and not tree:
        return {"generations": generations, "seconds": None}
    return {"generations": None, "seconds": BUDGET}


def _same(a, b) -> bool:
    return a.to_dict() == b.to_dict()


def _length(run, ended: list, now: float) -> float | None:
    """Estimated wall seconds from start to end of `run` (its settings), from the ended runs."""
    c = run.config
    same = [r.ended_at - r.started for r in ended if _same(r.config, c)]
    if same:
        return statistics.median(same)
    kin = [r for r in ended if r.config.robot == c.robot and r.config.method == c.method
           and r.config.population == c.population and r.generation > 0]
    if c.seconds is not None:
        paid = [(r.ended_at - r.started) - r.summary.seconds for r in ended if r.summary is not None]
        return c.seconds + (statistics.median(paid) if paid else 0.0)
    if kin:
        per = statistics.median((r.ended_at - r.started) / r.generation for r in kin)
        return per * c.generations
    return None


def _remaining(run, ended: list, now: float) -> float | None:
    """Estimated seconds left of a running run."""
    elapsed = now - (run.started or now)
    c = run.config
    if c.seconds is None and run.generation > 0:  # its own pace so far
        return max(0.0, elapsed / run.generation * (c.generations - run.generation))
    length = _length(run, ended, now)
    return None if length is None else max(0.0, length - elapsed)


def queue_wait(runs, run, now: float | None = None) -> tuple[int, float | None]:
    """(runs ahead of `run` (the running ones and those queued before it), estimated seconds until it
    starts, None when a run ahead has no estimate yet); (0, 0.0) for a run that is not queued."""
    now = time.time() if now is None else now
    rows = runs.rows()
    ended = [r for r in rows if r.ended and r.ended_at and r.started and r.state == "finished"]
    running = [r for r in rows if r.state in ("running", "paused")]
    if run.state != "queued" or run not in rows:
        return 0, 0.0
    # the queue is first come first served: the queued runs submitted before it (rows are in that order)
    queued = [r for r in rows[:rows.index(run)] if r.state == "queued"]
    ahead = len(running) + len(queued)
    free = []
    for r in running:
        left = _remaining(r, ended, now)
        if left is None:
            return ahead, None
        free.append(left)
    free += [0.0] * max(0, runs.workers - len(free))
    heapq.heapify(free)
    for r in queued:
        length = _length(r, ended, now)
        if length is None:
            return ahead, None
        heapq.heappush(free, heapq.heappop(free) + length)
    return ahead, free[0] if free else 0.0


def wait_words(ahead: int, seconds: float | None) -> str:
    """"2 runs ahead of yours, about 40 s" (the queued run's status line)."""
    runs = f"{ahead} run{'s' * (ahead != 1)} ahead of yours"
    if seconds is None:
        return f"{runs}; no estimate of the wait yet (no run of these settings has ended on this server)"
    if seconds < 60:
        return f"{runs}, about {max(5, 5 * round(seconds / 5)):.0f} s to wait"
    return f"{runs}, about {seconds / 60:.0f} min to wait"
