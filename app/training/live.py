"""What a class watches of a run as it goes: its population and its method's live plots.

`RunTrack` keeps, for one run (a race has two), the numbers the views draw: best and median MSE
per generation, each of the method's LivePlot series per generation (read generically from the
events' extras, as the method declares them in the registry), and the latest population sent
with its controllers. Its memory is bounded: the series keep at most TRACK_POINTS generations,
thinned as the run goes on (lab.running.history), so a run of 10^9 generations costs what one of
5,000 does. The drawing helpers here turn them into colours, legends and SVG; nothing
here knows viser.

Colours (lab.recording.population, the recordings' too): a candidate's training MSE on one log
scale per generation, from its best (dark purple) to its worst (yellow), the error map's ramp;
species: one colour per species id from a fixed palette.
"""

from __future__ import annotations

import html
import threading

import numpy as np

from lab.recording.population import SPECIES, mse_colors, mse_scale, ramp, species_colors
from lab.running.history import History, Thinned

PLOT_POINTS = 400  # the convergence and live plots are decimated to this many generations
TRACK_POINTS = 4096  # generations a RunTrack keeps of each series (then thinned)


_last_colors: tuple = (None, None, None)  # (population, by_species, colors): every tab draws the same population


def candidate_colors(population, by_species: bool) -> np.ndarray:
    """(n, 3) uint8: each candidate's colour (by species, else by training MSE); computed once per
    population for all the tabs that draw it."""
    global _last_colors
    last, how, colors = _last_colors
    if last is population and how == by_species:
        return colors
    if by_species and population.species is not None:
        colors = species_colors(population.species)
    else:
        colors = mse_colors(population.mse)
    _last_colors = (population, by_species, colors)
    return colors


def swatch(rgb, text: str) -> str:
    r, g, b = (int(c) for c in rgb)
    return (f'<span style="display:inline-block;width:10px;height:10px;background:rgb({r},{g},{b});'
            f'margin:0 3px 0 8px"></span>{html.escape(text)}')


def population_legend(population, by_species: bool, fmt, label: str = "", head: bool = True) -> str:
    """HTML: what the cloud's colours mean for this population (fmt: an MSE as text); head=False
    leaves out the line's "Generation g: n candidates" opening."""
    if population is None:
        return "<small>No population yet: start a run (each candidate of a generation is drawn at its reach).</small>"
    head = f"<b>{html.escape(label)}Generation {population.generation + 1}</b>: {len(population)} candidate" \
           f"{'s' if len(population) != 1 else ''}. " if head else ""
    if by_species and population.species is not None:
        ids, counts = np.unique(population.species, return_counts=True)
        items = "".join(swatch(species_colors([i])[0], f"{i} ({c})") for i, c in zip(ids, counts))
        return f"<small>{head}{'Colour' if head else 'Or, on the tab toggle, colour'}: species (id and size):{items}</small>"
    lo, hi = mse_scale(population.mse)
    steps = "".join(swatch(c, "") for c in ramp(np.linspace(0, 1, 5)))
    return (f"<small>{head}Colour: training MSE on a log scale, {steps} from {fmt(lo)} (best of the generation) "
            f"to {fmt(hi)} (worst).</small>")


class RunTrack:
    """The live numbers of one run (thread-safe: the run's reader thread adds, the render loop reads)."""

    def __init__(self, method):
        self.method = method
        self.plots = tuple(method.live_plots)
        self._lock = threading.Lock()
        self.history = History(TRACK_POINTS)  # best and median MSE
        self.series: dict[str, Thinned] = {p.key: Thinned(TRACK_POINTS) for p in self.plots}
        self.population = None  # the latest population sent with its controllers
        self.population_version = 0
        self.extras: dict = {}

    def add(self, event) -> None:
        with self._lock:
            self.history.append(event.best, event.median)
            for key, values in self.series.items():
                values.append(event.extras.get(key))
            self.extras = event.extras
            if event.population is not None and event.population.controllers is not None:
                self.population = event.population
                self.population_version += 1

    def __len__(self) -> int:
        return len(self.history)

    def curves(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(0-based generations, best, median) of the kept points."""
        with self._lock:
            return self.history.arrays()

    def series_of(self, key: str) -> tuple[list[int], list]:
        """(0-based generations, values) of a live plot's kept points."""
        with self._lock:
            series = self.series.get(key)
            return series.items() if series is not None else ([], [])

    def statistics(self) -> str:
        """The latest value of each of the method's live plots, in words (the panel's line)."""
        with self._lock:
            extras = self.extras
        parts = []
        for p in self.plots:
            v = extras.get(p.key)
            if p.kind == "stacked" and isinstance(v, dict):
                sizes = ", ".join(str(n) for n in sorted(v.values(), reverse=True))
                parts.append(f"{p.title}: {len(v)} ({sizes})")
            elif isinstance(v, (int, float)):
                parts.append(f"{p.title}: {v:.4g}")
        return " · ".join(parts)


def decimate(n: int, points: int = PLOT_POINTS) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, points)).astype(int)) if n else np.zeros(0, int)


def sample(gens: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """A kept series' value at generations `at`: the value of the latest kept generation at or before
    each (a thinned best-so-far curve is a step function); NaN before the first and after the last."""
    gens, values, at = np.asarray(gens), np.asarray(values, float), np.asarray(at)
    out = np.full(len(at), np.nan)
    if len(gens):
        i = np.searchsorted(gens, at, side="right") - 1
        ok = (i >= 0) & (at <= gens[-1])
        out[ok] = values[i[ok]]
    return out


def line_data(gens: list, values: list) -> tuple[np.ndarray, np.ndarray]:
    """(generation numbers from 1, values) of a line plot, decimated; missing values NaN."""
    idx = decimate(len(values))
    y = np.array([float(values[i]) if isinstance(values[i], (int, float)) else np.nan for i in idx])
    return np.asarray(gens, float)[idx] + 1.0 if len(idx) else np.zeros(0), y


def stacked_svg(gens: list, rows: list, title: str, width: int = 320, height: int = 160) -> str:
    """Stacked bands of {name: size} per generation (neat-python's plot_species, as SVG): each
    name a band in id order, its height the size, zero where it is absent."""
    idx = decimate(len(rows), 200)
    gens = [gens[i] for i in idx]
    rows = [rows[i] if isinstance(rows[i], dict) else {} for i in idx]
    if not rows:
        return f"<small>{html.escape(title)}: no generation yet.</small>"
    names = sorted({k for r in rows for k in r})
    sizes = np.array([[r.get(k, 0) for k in names] for r in rows], float)  # (generations, names)
    top = np.cumsum(sizes, axis=1)
    total = max(float(top[:, -1].max()), 1.0) if len(names) else 1.0
    pad_l, pad_b = 28, 18
    w, h = width - pad_l - 4, height - pad_b - 4
    x = pad_l + (np.arange(len(rows)) / max(len(rows) - 1, 1)) * w
    y = lambda v: 4 + h * (1 - v / total)  # noqa: E731
    bands = []
    for j, name in enumerate(names):
        lower = top[:, j] - sizes[:, j]
        pts = [f"{a:.1f},{y(b):.1f}" for a, b in zip(x, top[:, j])]
        pts += [f"{a:.1f},{y(b):.1f}" for a, b in zip(x[::-1], lower[::-1])]
        r, g, b = species_colors([name])[0] if isinstance(name, (int, np.integer)) else SPECIES[j % len(SPECIES)]
        bands.append(f'<polygon points="{" ".join(pts)}" fill="rgb({r},{g},{b})" fill-opacity="0.85">'
                     f'<title>{html.escape(str(name))}</title></polygon>')
    first, last = int(gens[0]) + 1, int(gens[-1]) + 1
    axes = (f'<line x1="{pad_l}" y1="{4 + h}" x2="{pad_l + w}" y2="{4 + h}" stroke="#888"/>'
            f'<line x1="{pad_l}" y1="4" x2="{pad_l}" y2="{4 + h}" stroke="#888"/>'
            f'<text x="{pad_l - 3}" y="12" font-size="9" text-anchor="end">{total:.0f}</text>'
            f'<text x="{pad_l - 3}" y="{4 + h}" font-size="9" text-anchor="end">0</text>'
            f'<text x="{pad_l}" y="{height - 4}" font-size="9">{first}</text>'
            f'<text x="{pad_l + w}" y="{height - 4}" font-size="9" text-anchor="end">generation {last}</text>')
    return (f'<div><small><b>{html.escape(title)}</b> ({len(names)} species so far, {len(rows[-1])} now)</small>'
            f'<svg width="{width}" height="{height}" xmlns="http://www.w3.org/2000/svg">{"".join(bands)}{axes}</svg></div>')


def lead_line(a: RunTrack, b: RunTrack, label_a: str, label_b: str) -> str:
    """Which run of a race leads, by how much: best MSE at the same generation (the shorter run's)."""
    ga, best_a, _ = a.curves()
    gb, best_b, _ = b.curves()
    n = min(len(a), len(b))
    if n == 0:
        return "Race: waiting for both runs' first generation."
    ea, eb = float(sample(ga, best_a, [n - 1])[0]), float(sample(gb, best_b, [n - 1])[0])
    if ea == eb:
        return f"Race, generation {n}: level, best MSE {ea:.4g} each."
    (wl, wv), (ll, lv) = ((label_a, ea), (label_b, eb)) if ea < eb else ((label_b, eb), (label_a, ea))
    ratio = lv / wv if wv > 0 else np.inf
    return (f"Race, generation {n}: **{wl} leads**, best MSE {wv:.4g} against {lv:.4g} "
            f"({ratio:.3g}x lower).")
