"""claims.md and its figures, from the stored runs of the claims experiment (claims.py; its
design in claims_design.py).

Per arm and method, in each setting (equal evaluations, equal time): the held-out error (median
and worst run), the runs stuck in a poor optimum, the evaluations and seconds to reach a target
error; Welch's test per pair of methods; the same for fixed against resampled training goals;
a verdict per claim written from these numbers by the rules stated with it.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import numpy as np

import robots
from lab import methods
from lab.experiments import claims_design as C
from lab.experiments.figures import band, pyplot
from lab.experiments.report import failure_lines, machine_lines, time_lines
from lab.experiments.stats import welch
from lab.experiments.tables import fmt, md_table
from lab.running.config import TrainConfig

EVOLVED, GRADIENT = C.METHODS[:-1], C.METHODS[-1]
SNAKES = tuple(r for r in C.ROBOTS if robots.kind(r) == "snake")  # "highly redundant"
TREES = tuple(r for r in C.ROBOTS if robots.kind(r) == "tree")  # the paper's reason: bipeds, humanoids
SETTINGS = {"evaluations": "equal budget in evaluations", "seconds": "equal wall time"}


def _label(method: str) -> str:
    return methods.get(method).label


def _reach(robot: str) -> float:
    """The arm's reach in the unit its errors are reported in (mm for a real arm)."""
    return robots.load(robot).reach_radius * (1000.0 if robots.in_metres(robot) else 1.0)


def _in_metres() -> list[str]:
    return [r for r in C.ROBOTS if robots.in_metres(r)]


def _goals_line() -> str:
    """Each method's default number of training goals on each kind of robot in the experiment."""
    kinds = {}
    for r in C.ROBOTS:
        kinds.setdefault(robots.kind(r), r)
    return "; ".join(f"{kind} ({r}): " + ", ".join(f"{_label(m)} {TrainConfig.preset(robot=r, method=m).targets:,}"
                                                    for m in C.METHODS) for kind, r in kinds.items())


def _unit(robot: str) -> str:
    return "mm" if robots.in_metres(robot) else "units"


def reached(run: dict, target: float) -> tuple[float, float]:
    """(evaluations, seconds) at the first checkpoint whose held-out error is <= target; inf if none."""
    cp = run["checkpoints"]
    for e, s, err in zip(cp["evaluations"], cp["seconds"], cp["error"]):
        if err <= target:
            return float(e), float(s)
    return np.inf, np.inf


def _count(v: float) -> str:
    return f"{v:,.0f}"


def _median_reached(values: list[float], show) -> str:
    """The median over runs (a run that never reached the target counts as infinite) and how many reached it."""
    if not values:
        return "—"
    k = sum(np.isfinite(v) for v in values)
    med = float(np.median(values))
    return f"{show(med) if np.isfinite(med) else 'not reached'} ({k}/{len(values)})"


def arm_rows(result, robot: str, kind: str) -> tuple[list[list[str]], dict]:
    """The table rows of one arm in one setting, and the numbers the verdicts use."""
    errors = {m: [d["held_out"] for d in result.runs(robot, m, kind)] for m in C.METHODS}
    reach = _reach(robot)
    stuck_counts = C.stuck(errors, C.POOR_REACH * reach)
    target = C.TARGET_REACH * reach
    rows, numbers = [], {}
    for m in C.METHODS:
        runs = result.runs(robot, m, kind)
        if not runs:
            continue
        e = np.array(errors[m])
        rel, ab, n = stuck_counts[m]
        hits = [reached(d, target) for d in runs]
        numbers[m] = {"median": float(np.median(e)), "worst": float(np.max(e)), "rel": rel, "abs": ab, "n": n}
        rows.append([robot, _label(m), str(n),
                     str(int(np.median([d["generations"] for d in runs]))),
                     _count(float(np.median([d["evaluations"] for d in runs]))),
                     fmt(float(np.median([d["seconds"] for d in runs])), 2),
                     f"**{fmt(numbers[m]['median'], 3)}** / {fmt(numbers[m]['worst'], 3)}",
                     f"{rel}/{n}", f"{ab}/{n}",
                     _median_reached([h[0] for h in hits], _count),
                     _median_reached([h[1] for h in hits], lambda v: f"{v:.3g}")])
    return rows, numbers


TABLE_HEADER = ["arm", "method", "runs", "generations", "evaluations", "seconds",
                "held-out error median / worst run", f"stuck: > {C.POOR_FACTOR:g}x best run",
                f"stuck: > {100 * C.POOR_REACH:g}% of reach",
                f"evaluations to ≤ {100 * C.TARGET_REACH:g}% of reach", f"seconds to ≤ {100 * C.TARGET_REACH:g}% of reach"]


def welch_rows(result, robot: str, kind: str, pairs) -> list[list[str]]:
    rows = []
    for x, y in pairs:
        a = [d["held_out"] for d in result.runs(robot, x, kind)]
        b = [d["held_out"] for d in result.runs(robot, y, kind)]
        lx, ly = _label(x), _label(y)
        if len(a) < 2 or len(b) < 2:
            rows.append([robot, f"{lx} vs {ly}", f"{len(a)}/{len(b)}"] + ["—"] * 5)
            continue
        w = welch(a, b)
        rows.append([robot, f"{lx} vs {ly}", f"{w.n_x}/{w.n_y}", fmt(w.mean_x, 3), fmt(w.mean_y, 3),
                     f"t = {fmt(w.t, 3)}, df = {fmt(w.df, 1)}", fmt(w.p_two), w.decision(x=lx, y=ly)])
    return rows


WELCH_HEADER = ["arm", "pair (x vs y)", "runs", "mean x", "mean y", "Welch t", "p two-sided", "decision α=0.05"]


def _resampled_rows(result) -> tuple[list[list[str]], list[list[str]], dict]:
    ref = C.METHODS[0]
    rows, tests, numbers = [], [], {}
    for robot in C.RESAMPLE_ROBOTS:
        for kind, name in (("evaluations", "fixed (the paper)"), ("resampled", "drawn anew each generation")):
            runs = result.runs(robot, ref, kind)
            if not runs:
                continue
            e = np.array([d["held_out"] for d in runs])
            tr = np.array([d["train_mse"] for d in runs])
            numbers[(robot, kind)] = e
            numbers.setdefault((robot, "mse"), {})[kind] = float(np.median([d["test_mse"] for d in runs]))
            rows.append([robot, name, str(len(runs)), f"**{fmt(float(np.median(e)), 3)}** / {fmt(float(e.max()), 3)}",
                         fmt(float(np.median(tr))), fmt(float(np.median([d["test_mse"] for d in runs])))])
        a, b = numbers.get((robot, "evaluations"), []), numbers.get((robot, "resampled"), [])
        if len(a) >= 2 and len(b) >= 2:
            w = welch(a, b)
            tests.append([robot, "fixed vs resampled", f"{w.n_x}/{w.n_y}", fmt(w.mean_x, 3), fmt(w.mean_y, 3),
                          f"t = {fmt(w.t, 3)}, df = {fmt(w.df, 1)}", fmt(w.p_two),
                          w.decision(x="fixed", y="resampled")])
            numbers[robot] = w
    return rows, tests, numbers


# ---------------------------------------------------------------- verdicts
RULE_GRADIENT = (
    "on an arm, claim (ii) is *supported* when an evolved method has a lower median held-out error than the "
    "gradient method and fewer stuck runs (both criteria counted together); *contradicted* when the gradient "
    "method's median is the lowest and it has no more stuck runs than any evolved method; *mixed* otherwise.")
RULE_RESAMPLING = (
    "Welch's two-sided test on the held-out errors at α = 0.05: the conclusion is supported on an arm when "
    "the fixed runs' mean is significantly lower, contradicted when the resampled runs' is, not shown otherwise.")


def _n(num: dict, m: str) -> str:
    """Its stuck runs by both criteria: 'relative/n, absolute/n'."""
    return f"{num[m]['rel']}/{num[m]['n']} and {num[m]['abs']}/{num[m]['n']}"


def _stuck(num: dict, m: str) -> int:
    return num[m]["abs"] + num[m]["rel"]


def judge_arm(num: dict) -> str:
    """'supported', 'contradicted' or 'mixed' for one arm's numbers (RULE_GRADIENT)."""
    g = num[GRADIENT]
    if any(num[m]["median"] < g["median"] and _stuck(num, m) < _stuck(num, GRADIENT) for m in EVOLVED):
        return "supported"
    if all(g["median"] <= num[m]["median"] and _stuck(num, GRADIENT) <= _stuck(num, m) for m in EVOLVED):
        return "contradicted"
    return "mixed"


def _spelled(arms: dict, names: list[str]) -> str:
    """Each arm's medians and stuck runs, the gradient method first."""
    return "; ".join(
        f"{r}: {_label(GRADIENT)} median {fmt(arms[r][GRADIENT]['median'], 3)} (stuck, above "
        f"{C.POOR_FACTOR:g}x the best run and above {100 * C.POOR_REACH:g}% of reach: {_n(arms[r], GRADIENT)}) against "
        + ", ".join(f"{_label(m)} {fmt(arms[r][m]['median'], 3)} ({_n(arms[r], m)})" for m in EVOLVED)
        for r in names)


def verdict_gradient(per_setting: dict) -> str:
    """Claim (ii) from the numbers: per setting, per arm judge_arm, the snakes spelled out."""
    parts, tallies = [], []
    for kind, arms in per_setting.items():
        judged = {r: judge_arm(num) for r, num in arms.items() if all(m in num for m in C.METHODS)}
        tally = {v: [r for r, j in judged.items() if j == v] for v in ("supported", "contradicted", "mixed")}
        tallies.append(tally)
        snake_text = _spelled(arms, [r for r in SNAKES if r in judged])
        tree_text = _spelled(arms, [r for r in TREES if r in judged])
        best = [min(num, key=lambda m: num[m]["median"]) for r, num in arms.items() if r in judged]
        lowest = ", ".join(f"{_label(m)} on {best.count(m)}" for m in C.METHODS)
        trapped = [f"{r} {arms[r][GRADIENT]['rel']}/{arms[r][GRADIENT]['n']}" for r in judged
                   if arms[r][GRADIENT]["rel"]]
        if trapped:
            snake_text += (f". {_label(GRADIENT)} runs more than {C.POOR_FACTOR:g}x worse than the best run: "
                           f"{', '.join(trapped)}: it has poor optima too")
        parts.append(
            f"At {SETTINGS[kind]}, on the highly redundant snakes: {snake_text or 'no runs'}. On the robots the paper "
            f"names as its reason (trees of several end effectors): {tree_text or 'no runs'}. Lowest median held-out "
            f"error over the {len(judged)} arms: {lowest}. The claim is "
            + "; ".join(f"{v} on {len(tally[v])} arm(s) ({', '.join(tally[v]) or 'none'})" for v in tally) + ".")
    if tallies and all(not t["supported"] and t["contradicted"] for t in tallies):
        head = ("**The numbers contradict the paper's claim (ii):** given the same evaluations or the same time, "
                "on no arm is an evolved method both more accurate and less often stuck than the gradient method, "
                "and on several the gradient method has the lowest held-out error with no more stuck runs.")
    elif tallies and all(t["supported"] and not t["contradicted"] and not t["mixed"] for t in tallies):
        head = "**The numbers support the paper's claim (ii)** on every arm in both settings."
    else:
        head = ("**The numbers do not bear the paper's claim (ii) out as a general rule:** it depends on the arm "
                "and the setting.")
    return " ".join([head, *parts])


def verdict_resampling(numbers: dict) -> str:
    """The paper's conclusion (fixed goals train better) from the numbers (RULE_RESAMPLING)."""
    parts, signs = [], {}
    for robot in C.RESAMPLE_ROBOTS:
        w = numbers.get(robot)
        if w is None:
            parts.append(f"{robot}: too few runs for a test.")
            continue
        d = w.decision(x="fixed", y="resampled")
        signs[robot] = "supported" if d.startswith("fixed") else "contradicted" if d.startswith("resampled") else "none"
        fixed, res = numbers[(robot, "evaluations")], numbers[(robot, "resampled")]
        mse = numbers[(robot, "mse")]
        parts.append(f"{robot}: median held-out error {fmt(float(np.median(fixed)), 3)} with fixed goals against "
                     f"{fmt(float(np.median(res)), 3)} resampled (p = {fmt(w.p_two)}: {d}); the held-out MSE, "
                     f"which the worst goals dominate, {fmt(mse['evaluations'])} against {fmt(mse['resampled'])}.")
    against = [r for r, v in signs.items() if v == "contradicted"]
    backing = [r for r, v in signs.items() if v == "supported"]
    if signs and all(v == "supported" for v in signs.values()):
        head = "**The numbers support the paper's conclusion** that fixed training goals train better."
    elif backing and not against:
        head = (f"**The numbers support the paper's conclusion on {', '.join(backing)} only:** elsewhere fixed and "
                "resampled goals give no significantly different held-out error at this size.")
    elif against:
        head = (f"**The numbers contradict the paper's conclusion** on {', '.join(against)}: goals drawn anew "
                "each generation give a lower held-out error there.")
    else:
        head = ("**The numbers do not show the paper's conclusion:** not every arm has a significantly lower "
                "held-out error with fixed goals at this size (the fixed runs do fit their own 70 goals better: "
                "see the training MSE column).")
    return " ".join([head, *parts])


def still_falling(result, drop: float = 0.9) -> str:
    """Which evolved methods were still improving when their equal budget ended: median held-out
    error at the end below `drop` x its median at the checkpoint two before (at `since` of the budget)."""
    since = np.geomspace(C.FIRST_CHECKPOINT, 1.0, C.CHECKPOINTS)[-3]
    falling = {m: [r for r in C.ROBOTS if (runs := result.runs(r, m, "evaluations"))
                   and np.median([d["checkpoints"]["error"][-1] for d in runs])
                   < drop * np.median([d["checkpoints"]["error"][-3] for d in runs])] for m in EVOLVED}
    return ("Still improving at the end of the equal budget (median held-out error down by more than "
            f"{100 * (1 - drop):g}% from {100 * since:.0f}% of the budget to its end): "
            + "; ".join(f"{_label(m)} on {', '.join(v) or 'no arm'}" for m, v in falling.items()) + ".")


# ---------------------------------------------------------------- figures
def arm_figure(result, robot: str, out: Path) -> Path:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), constrained_layout=True)
    for ax, kind, xkey in ((axes[0], "evaluations", "evaluations"), (axes[1], "seconds", "seconds")):
        for m in C.METHODS:
            runs = result.runs(robot, m, kind)
            if runs:
                band(ax, [d["checkpoints"][xkey] for d in runs], [d["checkpoints"]["error"] for d in runs],
                     methods.get(m).hex, _label(m))
        ax.axhline(C.TARGET_REACH * _reach(robot), color="grey", ls=":", lw=1, label=f"{100 * C.TARGET_REACH:g}% of reach")
        ax.set_xlabel("evaluations" if kind == "evaluations" else "seconds (optimizer time)")
        ax.set_ylabel(f"held-out median error [{_unit(robot)}]")
        ax.set_title(f"{robot}: {SETTINGS[kind]}")
        ax.legend(fontsize=8)
    fig.suptitle("held-out error of each run's best controller so far: line, the median over runs; band, "
                 "from the best to the worst run", fontsize=9)
    path = out / f"claims_{robot}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def resample_figure(result, out: Path) -> Path:
    plt = pyplot()
    fig, axes = plt.subplots(1, len(C.RESAMPLE_ROBOTS), figsize=(6 * len(C.RESAMPLE_ROBOTS), 4.6),
                             constrained_layout=True, squeeze=False)
    for ax, robot in zip(axes[0], C.RESAMPLE_ROBOTS):
        for kind, color, name in (("evaluations", "#1f77b4", "fixed goals"), ("resampled", "#d62728", "resampled goals")):
            runs = result.runs(robot, C.METHODS[0], kind)
            if runs:
                band(ax, [d["checkpoints"]["evaluations"] for d in runs], [d["checkpoints"]["error"] for d in runs],
                     color, name)
        ax.set_xlabel("evaluations")
        ax.set_ylabel(f"held-out median error [{_unit(robot)}]")
        ax.set_title(f"{robot}: {_label(C.METHODS[0])}, fixed vs resampled goals")
        ax.legend(fontsize=8)
    path = out / "claims_resampled.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# ---------------------------------------------------------------- claims.md
def _what(result) -> list[str]:
    c = result.config
    budgets = ", ".join(f"{r} {c.budget(r):,}" for r in C.ROBOTS)
    limits = ", ".join(f"{r} {c.time_limit(r):g} s" for r in C.ROBOTS)
    cmd = f"python -m lab claims --runs {c.runs} --generations {c.generations} --seed {c.seed} --out {c.out}"
    if c.seconds is not None:
        cmd += f" --seconds {c.seconds:g}"
    return [f"Command: `{cmd}`  \nStarted {result.experiment.started}.\n", "## What was run\n",
            f"- Arms: {', '.join(C.ROBOTS)}; methods, each at its defaults for the arm: "
            f"{', '.join(_label(m) for m in C.METHODS)}; seeds {c.seed}..{c.seed + c.runs - 1} ({c.runs} per arm, "
            "method and setting).",
            f"- **Equal budget in evaluations** (one controller evaluated on all its training goals, as each "
            f"method counts it; {_label(GRADIENT)}: 1 + nq per step): E = {c.generations} generations of "
            f"{_label(C.METHODS[0])} at its population, per arm: {budgets}; each method runs E // (its "
            "evaluations per step) steps. Methods keep their own default numbers of training goals, so an "
            "evaluation is not the same kinematic work for all (" + _goals_line() + ").",
            f"- **Equal wall time** (optimizer time, stopped by `lab.running.TimeLimit`): per arm {limits} "
            f"(generations x the {_label(C.METHODS[0])} seconds per generation measured on this machine, "
            "claims.SECONDS_PER_GENERATION); generation cap "
            f"{C.CAP}x the equal-budget generations ({_label(GRADIENT)}'s learning-rate decay spans that cap, so "
            "it ends the time with its rate only partly decayed). **These runs depend on the machine's speed "
            "and load**; the equal-budget runs are reproducible number for number.",
            f"- **Fixed vs resampled goals**: {_label(C.METHODS[0])} on {', '.join(C.RESAMPLE_ROBOTS)} at equal "
            "budget; resampled runs draw new training goals (as many) before every generation from a stream "
            "seeded by the run's seed (`TrainConfig(resample=True)`); their best controller so far is chosen by "
            "its MSE on the fixed goals of goal_seed 0 (the fixed runs' training goals), one extra evaluation per "
            "generation not counted in the budget. The fixed runs are the equal-budget runs above.",
            "- **Held-out error** of a run: the median over 2,000 held-out goals (lab.experiments.arms, drawn apart "
            "from every training goal) of the end-effector position error of its final best controller, in mm "
            f"for the robots in metres ({', '.join(_in_metres())}) and in the paper's units otherwise; on a tree of "
            "several end effectors the median over goals and effectors; curves: the same at "
            f"{C.CHECKPOINTS} log-spaced points of each run's budget.",
            f"- **Stuck in a poor optimum**: held-out error above {C.POOR_FACTOR:g}x the best run of any method on "
            f"that arm in that setting, and, separately, above {100 * C.POOR_REACH:g}% of the arm's reach. "
            f"**Time to reach**: the evaluations and seconds at the first checkpoint with held-out error at or "
            f"below {100 * C.TARGET_REACH:g}% of the arm's reach (median over runs, a run that never reaches it "
            "counting as infinite; in brackets how many reached it).",
            f"- **Cut to fit 10 minutes on this 2-core machine:** {c.runs} seeds instead of 10; a budget "
            f"of {c.generations} {_label(C.METHODS[0])} generations (E = {c.budget(C.ROBOTS[0]):,} evaluations) "
            "instead of the paper's 1,000 (50,000), far below the real arms' defaults (generations or steps: "
            + ", ".join(f"{_label(m)} {TrainConfig.preset(robot=a, method=m).generations:,} on {a}"
                        for m in C.METHODS for a in C.ROBOTS if robots.kind(a) == "real")
            + "): the real arms' errors are those of short runs.",
            f"- Executed {result.experiment.executed} runs on {result.experiment.executor}; resumed "
            f"{result.experiment.resumed}."]


def claims_md(result, outputs_seconds: float) -> str:
    exp = result.experiment
    md = ["# The paper's claims, tested: evolution against gradient descent, fixed against resampled goals\n",
          *_what(result), *machine_lines(exp), *time_lines(exp, outputs_seconds), ""]
    per_setting = {}
    for kind in C.BUDGETS:
        rows, tests, per_setting[kind] = [], [], {}
        for robot in C.ROBOTS:
            r, num = arm_rows(result, robot, kind)
            rows += r
            per_setting[kind][robot] = num
            tests += welch_rows(result, robot, kind, itertools.combinations(C.METHODS, 2))
        md += [f"## Claim (ii) at {SETTINGS[kind]}\n",
               f"Held-out errors in mm for {', '.join(_in_metres())}, in the paper's units otherwise; generations, evaluations "
               "and seconds are medians over runs.\n", md_table(TABLE_HEADER, rows, left=2),
               "Welch's unequal-variance t-test on the runs' held-out errors, per pair of methods:\n",
               md_table(WELCH_HEADER, tests, left=2)]
    rows, tests, numbers = _resampled_rows(result)
    md += ["## Fixed against resampled training goals\n",
           f"{_label(C.METHODS[0])}, equal budget; held-out error as above; training MSE on the fixed 70 goals "
           "(which the fixed runs train on); the Problem's held-out MSE on 1,000 goals.\n",
           md_table(["arm", "training goals", "runs", "held-out error median / worst run", "training MSE median",
                     "held-out MSE median"], rows, left=2),
           md_table(WELCH_HEADER, tests, left=2)]
    md += ["## Verdicts\n",
           "### Claim (ii): evolution avoids the local optima that trap gradient descent on redundant arms\n",
           verdict_gradient(per_setting) + "\n",
           f"Caveat: these are budgets of {result.config.generations} {_label(C.METHODS[0])} generations "
           f"({result.config.budget(C.ROBOTS[0]):,} evaluations) and {result.config.runs} seeds, the real arms far "
           f"from their default budgets. {still_falling(result)} The verdict is about equal budgets of this size; "
           "the paper's protocol is 50,000 evaluations.\n",
           f"Rule: {RULE_GRADIENT}\n",
           "### Conclusion: fixed training goals train better than goals drawn anew each generation\n",
           verdict_resampling(numbers) + "\n",
           f"Rule: {RULE_RESAMPLING}\n",
           *failure_lines(exp),
           "## Files\n",
           *[f"- [claims_{r}.png](claims_{r}.png): held-out error against evaluations (equal budget) and seconds "
             f"(equal time), {r}" for r in C.ROBOTS],
           "- [claims_resampled.png](claims_resampled.png): fixed against resampled goals",
           "- `runs/<arm>-<method>-<setting>-s<seed>.json`: each run (curve, checkpoints, config, controller)", ""]
    return "\n".join(md)


def write_claims(result) -> dict[str, Path]:
    t0 = time.perf_counter()
    out = result.config.out
    out.mkdir(parents=True, exist_ok=True)
    o = result.outputs
    for robot in C.ROBOTS:
        o[f"claims_{robot}.png"] = arm_figure(result, robot, out)
    o["claims_resampled.png"] = resample_figure(result, out)
    o["claims.md"] = out / "claims.md"
    o["claims.md"].write_text(claims_md(result, time.perf_counter() - t0))
    return o
