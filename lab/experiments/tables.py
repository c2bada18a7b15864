"""Tables 3-5 and the generalization table, beside the paper's, as Markdown and CSV.

Table 3: per arm and method the final training MSEs sorted ascending, mean and sample standard
deviation (ddof=1, as the paper's sigma). Tables 4 and 5: Welch's t-test, x = CMA-ES, y = NEAT,
over all runs (4) and the best 10 runs (5); for each arm three rows: this experiment, the paper
as printed, and the paper's own Table 3 columns recomputed with the same code.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from lab import methods
from lab.experiments import paper
from lab.experiments.stats import ALPHA, welch



def fmt(v: float | None, digits: int = 4) -> str:
    """Four decimals like the paper; scientific for tiny or huge values; '—' for missing."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    if v != 0 and (abs(v) < 10 ** -(digits - 1) or abs(v) >= 1e6):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}f}"


def md_table(header: list[str], rows: list[list[str]], left: int = 0) -> str:
    """A Markdown table; the first `left` columns left-aligned, the others right-aligned."""
    align = [":---" if i < left else "---:" for i in range(len(header))]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _arms(exp) -> list[tuple[str, str]]:
    return [(r, m) for r in exp.config.robots for m in exp.config.methods]


def table3(exp, out: Path) -> tuple[Path, Path]:
    """table3.csv (one column per arm/method, ours and the paper's) and table3.md."""
    arms = _arms(exp)
    ours = {a: np.sort(exp.values(*a)) for a in arms}
    theirs = {a: paper.column(*a) for a in arms}
    n = max([len(v) for v in ours.values()] + [len(v) for v in theirs.values() if v is not None])
    cols = [(f"{r}_{m}", ours[(r, m)]) for r, m in arms] + \
           [(f"paper_{r}_{m}", theirs[(r, m)]) for r, m in arms if theirs[(r, m)] is not None]

    def cell(v, i):
        return repr(float(v[i])) if v is not None and i < len(v) else ""

    def stat(v, f):
        return repr(float(f(v))) if v is not None and len(v) > 1 else ""

    csv_path = out / "table3.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["rank"] + [c for c, _ in cols])
        for i in range(n):
            w.writerow([i + 1] + [cell(v, i) for _, v in cols])
        w.writerow(["mean"] + [stat(v, np.mean) for _, v in cols])
        w.writerow(["std"] + [stat(v, lambda x: np.std(x, ddof=1)) for _, v in cols])

    header = ["rank"]
    for r, m in arms:
        header += [f"{r} {methods.get(m).label}", "paper"]
    rows = []
    for i in range(n):
        row = [str(i + 1)]
        for a in arms:
            row += [fmt(float(v[i])) if v is not None and i < len(v) else "" for v in (ours[a], theirs[a])]
        rows.append(row)
    for name, f in (("**μ**", np.mean), ("**σ**", lambda x: np.std(x, ddof=1))):
        row = [name]
        for a in arms:
            row += [f"**{fmt(float(f(v)))}**" if v is not None and len(v) > 1 else "—" for v in (ours[a], theirs[a])]
        rows.append(row)
    md = ["# Table 3: final training MSE per run, sorted ascending\n",
          f"{_preset_line(exp)} Columns `paper` are the paper's Table 3. μ: mean, σ: sample standard "
          "deviation (ddof = 1). Training MSE: the mean over the 70 fixed training goals of ||p − p′||², "
          "of the best controller at the end of the run.\n", md_table(header, rows)]
    md_path = out / "table3.md"
    md_path.write_text("\n".join(md))
    return csv_path, md_path


def _preset_line(exp) -> str:
    c = exp.config
    preset = "the paper's literal method (`--paper`)" if c.paper else "this project's tuned defaults (not `--paper`)"
    return (f"{c.runs} runs per arm and method, {c.generations} generations, population {c.population}, "
            f"{preset}.")


TEST_HEADER = ["arm", "source", "n", "mean CMA-ES", "mean NEAT", "t", "df", "p one-sided",
               "p two-sided", f"decision α={ALPHA} (two-sided)", "decision (one-sided)"]


def test_rows(exp, best: int | None) -> list[list[str]]:
    """Welch rows for each arm: this experiment, the paper as printed, the paper's Table 3 recomputed."""
    rows = []
    key = "all" if best is None else f"best{best}"
    for robot in exp.config.robots:
        x, y = paper.METHODS
        samples = [("this experiment", exp.values(robot, x), exp.values(robot, y))]
        px, py = paper.column(robot, x), paper.column(robot, y)
        if px is not None and py is not None:
            samples.append(("paper's Table 3, recomputed", px, py))
        for source, x, y in samples:
            if best is not None:
                x, y = np.sort(x)[:best], np.sort(y)[:best]
            if len(x) < 2 or len(y) < 2:
                rows.append([robot, source, f"{len(x)}/{len(y)}"] + ["—"] * 8)
                continue
            w = welch(x, y)
            rows.append([robot, source, f"{w.n_x}/{w.n_y}", fmt(w.mean_x), fmt(w.mean_y), fmt(w.t), fmt(w.df),
                         fmt(w.p_one), fmt(w.p_two), w.decision(sided="two"), w.decision(sided="one")])
        printed = paper.tests().get((robot, key))
        if printed is not None:
            rows.append([robot, "paper, as printed", "30/30" if best is None else f"{best}/{best}", "—", "—",
                         fmt(printed["t"]), fmt(printed["df"]), fmt(printed["p"]), fmt(2 * printed["p"]),
                         "—", printed["decision"]])
    return rows


TEST_NOTE = (
    "Welch's unequal-variance t-test, x = CMA-ES, y = NEAT (`lab/experiments/stats.py`; equal to "
    "`scipy.stats.ttest_ind(x, y, equal_var=False)`). **p one-sided** is the one-sided p in the direction "
    "of the observed difference (H1: μx < μy when t < 0, μx > μy when t > 0), which is what the paper "
    "prints as *Significance*; **p two-sided** (H1: μx ≠ μy) is twice that. For the paper's printed rows the "
    "two-sided p is derived as 2 × its one-sided p. Decisions at α = 0.05; the paper's one-sided decision "
    "in the observed direction amounts to a two-sided test at α = 0.10.\n")


def tests_table(exp, out: Path, best: int | None) -> Path:
    """table4.md (best=None: all runs) or table5.md (best=10)."""
    name, title = ("table4.md", "Table 4: t-tests over all runs") if best is None else \
        ("table5.md", f"Table 5: t-tests over the best {best} runs of each method")
    md = [f"# {title}\n", _preset_line(exp) + "\n", TEST_NOTE]
    if not set(paper.METHODS) <= set(exp.config.methods):
        md.append(f"Not computed: the experiment must include both `{'` and `'.join(paper.METHODS)}`.\n")
    else:
        md.append(md_table(TEST_HEADER, test_rows(exp, best), left=2))
        if best is not None:
            md.append("\nThe paper's printed Table 5 does not follow from its own Table 3: the best 10 of each "
                      "column of its Table 3 give the *recomputed* row (for example t = −41.81, df = 17.61 "
                      "for the planar arm against the printed −44.57, 17.46). Its printed p values do match "
                      "its printed t and df (one-sided). Table 4 recomputes exactly.\n")
    path = out / name
    path.write_text("\n".join(md))
    return path


def generalization(exp, out: Path) -> Path:
    """generalization.md: every run's held-out MSE (config.test_goals new goals) against its training MSE."""
    c = exp.config
    md = ["# Generalization: held-out MSE against training MSE\n",
          f"Each run's final best controller on {c.test_goals} held-out goals (drawn once, apart from the "
          f"{c.targets} training goals) against its training MSE. {_preset_line(exp)} The paper reports a "
          "deviation of 0.001% of the training error on new goals.\n", "## Summary\n"]
    summary, sections = [], []
    for robot, method in _arms(exp):
        runs = sorted(exp.runs_of(robot, method), key=lambda d: d["train_mse"])
        if not runs:
            continue
        tr = np.array([d["train_mse"] for d in runs])
        te = np.array([d["test_mse"] for d in runs])
        rel = (te - tr) / tr
        summary.append([robot, methods.get(method).label, str(len(runs)), fmt(float(np.median(tr))), fmt(float(np.median(te))),
                        f"{100 * np.median(rel):+.1f}%", f"{100 * np.min(rel):+.1f}%", f"{100 * np.max(rel):+.1f}%"])
        rows = [[str(d["seed"]), fmt(d["train_mse"]), fmt(d["test_mse"]), f"{100 * r:+.1f}%"]
                for d, r in zip(runs, rel)]
        sections.append(f"## {robot}, {methods.get(method).label}\n\n" +
                        md_table(["seed", "training MSE", "held-out MSE", "held-out vs training"], rows))
    md.append(md_table(["arm", "method", "runs", "median training", "median held-out",
                        "median deviation", "min", "max"], summary, left=2))
    md += sections
    path = out / "generalization.md"
    path.write_text("\n".join(md))
    return path
