"""Figures 5 and 6: convergence of every run and the best run per method, log scale.

As in the paper, two panels per arm: top, every run's best training MSE so far against the
generation (thin) with the best run of each method (bold); bottom, the best runs alone, with the
median over runs (dashed). Written with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lab import methods

FIGURE_NUMBER = {"planar": 5, "scara": 6}


def figure_name(robot: str) -> str:
    n = FIGURE_NUMBER.get(robot)
    return f"fig{n}_{robot}.png" if n else f"fig_{robot}.png"


def _positive(h: np.ndarray) -> np.ndarray:
    """Log axes need positive values: clip at the smallest positive float."""
    return np.clip(np.asarray(h, dtype=np.float64), np.finfo(float).tiny, None)


def pyplot():
    """matplotlib.pyplot with the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def band(ax, xs, ys, color: str, label: str) -> None:
    """Curves sampled at the same checkpoints (one per run): their median (line, at the median x)
    and their range, lowest to highest run (band), on log axes."""
    n = min(len(x) for x in xs)
    X = np.array([np.asarray(x, dtype=np.float64)[:n] for x in xs])
    Y = np.array([_positive(np.asarray(y)[:n]) for y in ys])
    x = _positive(np.median(X, axis=0))
    ax.plot(x, np.median(Y, axis=0), color=color, lw=2.0, label=f"{label}: median of {len(xs)} runs")
    ax.fill_between(x, Y.min(axis=0), Y.max(axis=0), color=color, alpha=0.18, lw=0)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.25)


def convergence_figure(exp, robot: str, out: Path) -> Path:
    plt = pyplot()
    fig, (ax_all, ax_best) = plt.subplots(2, 1, figsize=(8, 8), sharex=True, constrained_layout=True)
    n_fig = FIGURE_NUMBER.get(robot)
    for method in exp.config.methods:
        runs = exp.runs_of(robot, method)
        if not runs:
            continue
        color, label = methods.get(method).hex, methods.get(method).label
        hist = [_positive(d["history"]) for d in runs]
        for h in hist:
            ax_all.plot(np.arange(len(h)), h, color=color, lw=0.6, alpha=0.35)
        best = min(runs, key=lambda d: d["train_mse"])
        hb = _positive(best["history"])
        for ax in (ax_all, ax_best):
            ax.plot(np.arange(len(hb)), hb, color=color, lw=2.4,
                    label=f"{label} best run (seed {best['seed']}, MSE {best['train_mse']:.4g})")
        length = min(len(h) for h in hist)
        median = np.median(np.stack([h[:length] for h in hist]), axis=0)
        ax_best.plot(np.arange(length), median, color=color, lw=1.4, ls="--",
                     label=f"{label} median of {len(runs)} runs")
        ax_all.plot([], [], color=color, lw=0.8, alpha=0.6, label=f"{label}: all {len(runs)} runs")
    for ax in (ax_all, ax_best):
        ax.set_yscale("log")
        ax.set_ylabel("best training MSE so far")
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=8, loc="upper right")
    ax_best.set_xlabel("Generation")
    title = f"Figure {n_fig} (reproduction)" if n_fig else "Convergence"
    preset = "paper preset" if exp.config.paper else "tuned defaults"
    ax_all.set_title(f"{title}: {robot} arm, every run ({preset}, population {exp.config.population})")
    ax_best.set_title("best run per method and median over runs")
    path = out / figure_name(robot)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
