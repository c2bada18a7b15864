"""Outputs of an experiment and report.md: what was run, on what, how long, and the headline.

write_outputs(exp) writes into exp.config.out: table3.md/.csv, table4.md, table5.md, one
convergence figure per arm (fig5_planar.png, fig6_scara.png), generalization.md, experiment.rrd
and report.md, all from the stored runs.
"""

from __future__ import annotations

import os
import platform
import subprocess
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from lab import methods
from lab.experiments import paper
from lab.experiments.figures import convergence_figure, figure_name
from lab.experiments.record import write_recording
from lab.experiments.stats import welch
from lab.experiments.tables import fmt, generalization, md_table, table3, tests_table

PACKAGES = ("neuro-ik-lab", "numpy", "scipy", "cma", "neat-python", "numba", "pin", "rerun-sdk", "matplotlib", "ray")


def write_outputs(exp) -> dict[str, Path]:
    t0 = time.perf_counter()
    out = exp.config.out
    out.mkdir(parents=True, exist_ok=True)
    o = exp.outputs
    o["table3.csv"], o["table3.md"] = table3(exp, out)
    o["table4.md"] = tests_table(exp, out, best=None)
    o["table5.md"] = tests_table(exp, out, best=10)
    for robot in exp.config.robots:
        o[figure_name(robot)] = convergence_figure(exp, robot, out)
    o["generalization.md"] = generalization(exp, out)
    if exp.config.recording:
        o["experiment.rrd"] = write_recording(exp, out / "experiment.rrd")
    outputs_seconds = time.perf_counter() - t0
    o["report.md"] = out / "report.md"
    o["report.md"].write_text(report_md(exp, outputs_seconds))
    return o


def command(c) -> str:
    parts = [f"python -m lab reproduce --runs {c.runs} --generations {c.generations} --population {c.population}",
             f"--methods {','.join(c.methods)} --robots {','.join(c.robots)} --seed {c.seed} --out {c.out}"]
    if c.paper:
        parts.append("--paper")
    if c.ray:
        parts.append(f"--ray {c.ray}")
    return " ".join(parts)


def _git() -> str:
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                              text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head}{' (with uncommitted changes)' if dirty else ''}" if head else "unknown"


def _cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _process_seconds() -> float | None:
    """Seconds since this process started (Linux), to include interpreter start-up and imports."""
    try:
        start_ticks = int(open("/proc/self/stat").read().rsplit(")", 1)[1].split()[19])
        btime = next(int(line.split()[1]) for line in open("/proc/stat") if line.startswith("btime"))
        return time.time() - (btime + start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, StopIteration, IndexError):
        return None


def _versions() -> str:
    found = []
    for p in PACKAGES:
        try:
            found.append(f"{p} {metadata.version(p)}")
        except metadata.PackageNotFoundError:
            pass
    return f"Python {platform.python_version()}; " + ", ".join(found)


def _headline(exp) -> str:
    rows = []
    for robot in exp.config.robots:
        for method in exp.config.methods:
            v = np.array(exp.values(robot, method))
            p = paper.column(robot, method)
            ours = f"{fmt(v.mean())} ± {fmt(v.std(ddof=1))}" if len(v) > 1 else "—"
            theirs = f"{fmt(p.mean())} ± {fmt(p.std(ddof=1))}" if p is not None else "—"
            rows.append([robot, methods.get(method).label, str(len(v)), ours,
                         fmt(float(np.median(v))) if len(v) else "—", fmt(float(v.min())) if len(v) else "—",
                         theirs, fmt(float(p.min())) if p is not None else "—"])
    md = [md_table(["arm", "method", "runs", "training MSE μ ± σ", "median", "best",
                    "paper μ ± σ", "paper best"], rows, left=2)]
    if set(paper.METHODS) <= set(exp.config.methods):
        rows = []
        for robot in exp.config.robots:
            for best, key in ((None, "all"), (10, "best10")):
                x, y = np.array(exp.values(robot, paper.METHODS[0])), np.array(exp.values(robot, paper.METHODS[1]))
                if best:
                    x, y = np.sort(x)[:best], np.sort(y)[:best]
                if len(x) < 2 or len(y) < 2:
                    continue
                w = welch(x, y)
                pr = paper.tests().get((robot, key))
                rows.append([robot, "all runs" if best is None else f"best {best}",
                             f"t = {fmt(w.t)}, df = {fmt(w.df)}", f"{fmt(w.p_one)} / {fmt(w.p_two)}",
                             w.decision(sided="two"),
                             f"t = {fmt(pr['t'])}, p = {fmt(pr['p'])}: {pr['decision']}" if pr else "—"])
        md.append(md_table(["arm", "selection", "Welch (CMA-ES vs NEAT)", "p one-sided / two-sided",
                            "decision α=0.05 (two-sided)", "paper (p one-sided)"], rows, left=2))
    return "\n".join(md)


def _n(k: int, noun: str) -> str:
    return f"{k} {noun}{'' if k == 1 else 's'}"


def _what_was_run(exp) -> list[str]:
    c = exp.config
    preset = ("**the paper's literal method** (`--paper`: `TrainConfig.preset(paper=True)`)" if c.paper else
              "**this project's tuned defaults** (no `--paper`; `TrainConfig.preset(paper=False)`)")
    cfg = {m: next(s for s in exp.specs if s.method == m).config().to_dict() for m in c.methods}
    return ["## What was run\n",
            f"- Method settings: {preset}.",
            f"- {_n(len(c.robots), 'arm')} ({', '.join(c.robots)}) × {_n(len(c.methods), 'method')} "
            f"({', '.join(c.methods)}) × "
            f"{c.runs} runs = {len(exp.specs)} runs; {c.generations} generations, population {c.population}, "
            f"{c.targets} fixed training goals, {c.test_goals} held-out goals.",
            f"- Seeds: run i of every arm and method uses seed {c.seed} + i ({c.seed}..{c.seed + c.runs - 1}); "
            f"goals fixed across runs (goal_seed {cfg[c.methods[0]]['goal_seed']}).",
            *[f"- {methods.get(m).label} config: `{cfg[m]}`" for m in c.methods],
            f"- Executed: {exp.executed} runs in this call on {exp.executor}; resumed from `runs/`: {exp.resumed}."]


def machine_lines(exp) -> list[str]:
    loaded = exp.load_before and exp.load_before[0] > 0.5
    return ["\n## Machine and versions\n",
            f"- {platform.node()}: {_cpu_model()}, {os.cpu_count()} cores, {platform.platform()}.",
            f"- Load average (1, 5, 15 min) at start: {', '.join(f'{v:.2f}' for v in exp.load_before)}; at the end "
            f"of the runs: {', '.join(f'{v:.2f}' for v in exp.load_after)}."
            + (" **Other work was running on this machine at the start: times are pessimistic.**" if loaded else ""),
            f"- {_versions()}; lab commit {_git()}."]


def time_lines(exp, outputs_seconds: float) -> list[str]:
    ran = [exp.results[s.name] for s in exp.specs if s.name in exp.results]
    run_seconds = sum(d.get("wall_seconds", d["seconds"]) for d in ran)
    cpu_seconds = sum(d.get("cpu_seconds", 0.0) for d in ran)
    since_start = _process_seconds()
    line = (f"- Runs: **{exp.wall_seconds:.1f} s** wall for the {exp.executed} runs executed in this call "
            f"(sum of all {len(ran)} runs' own wall times: {run_seconds:.1f} s, CPU times: {cpu_seconds:.1f} s, "
            f"/ {os.cpu_count()} cores = {cpu_seconds / (os.cpu_count() or 1):.1f} s, the ideal wall time on idle cores); "
            f"outputs: {outputs_seconds:.1f} s.")
    if since_start:
        line += f" Since the process started (imports included): **{since_start:.1f} s**."
    if exp.resumed:
        line += f" The {exp.resumed} resumed runs took their time in earlier calls."
    return ["\n## Time taken\n", line]


def failure_lines(exp) -> list[str]:
    if not (exp.failures or exp.retried):
        return []
    return ["## Failures\n",
            *[f"- **{f['name']} failed {f['attempts']} times** and is missing from the tables: {f['error']} "
              f"(runs/{f['name']}.failed.json)" for f in exp.failures],
            *[f"- {r['name']} failed once ({r['errors'][0]}) and succeeded on retry." for r in exp.retried], ""]


def _files(c) -> list[str]:
    return ["## Files\n",
            "- [table3.md](table3.md), [table3.csv](table3.csv): final training MSEs, sorted, with the paper's",
            "- [table4.md](table4.md), [table5.md](table5.md): Welch t-tests over all runs and the best 10",
            *[f"- [{figure_name(r)}]({figure_name(r)}): convergence, {r} arm" for r in c.robots],
            "- [generalization.md](generalization.md): held-out against training MSE per run",
            "- `experiment.rrd`: every run's curve on the `generation` timeline (`rerun experiment.rrd`)"
            if c.recording else "- no Rerun recording (`--no-recording`)",
            "- `runs/<arm>-<method>-s<seed>.json`: each run's result (history, MSEs, seconds, config, controller)", ""]


def report_md(exp, outputs_seconds: float) -> str:
    md = [f"# Reproduction of {paper.AUTHORS} ({paper.YEAR}), Tables 3-5 and Figures 5-6\n",
          f"Command: `{command(exp.config)}`  \nStarted {exp.started}.\n",
          *_what_was_run(exp), *machine_lines(exp), *time_lines(exp, outputs_seconds),
          "\n## Headline: this experiment against the paper\n",
          "Final training MSE (Table 3's statistics):\n", _headline(exp),
          "Welch's t-test: p one-sided is in the direction of the observed difference (the paper's "
          "*Significance*); two-sided is twice that. table4.md and table5.md add the paper's own Table 3 "
          "recomputed.\n" if set(paper.METHODS) <= set(exp.config.methods) else "",
          *failure_lines(exp), *_files(exp.config)]
    return "\n".join(md)
