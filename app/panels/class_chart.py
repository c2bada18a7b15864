"""The class chart: each finished student run's held-out MSE against one setting, among runs that
differ only in that setting (app/panels/class_board.py draws it in the Class tab, small, and in the
presenter's own tab, large, for a projector).

    plotted, left_out, why = comparable(runs, "hidden units")
    svg = chart_svg(runs, "hidden units")                      # the Class tab's (about 320 x 200 px)
    svg = chart_svg(runs, "hidden units", big=True)            # the projector's (fills its panel)

A chart that mixed runs of 300 and 3,000 generations in one column would say nothing about hidden
units: the runs are grouped by every other setting (robot, method, population, hidden units, goals,
generations or time budget, goal kind; the plotted one left out), the seed counting as a repeat (the
line goes through each value's median over the seeds) unless the seed is what is plotted. The largest
group is plotted (the newest on a tie); the chart says how many finished runs it left out and which
settings set them apart. Everything a student typed is escaped before it is drawn; each point's
name, value and error are its tooltip (an SVG <title>: the browser shows it on hover).
"""

from __future__ import annotations

import html
import math
from collections import Counter

import numpy as np

import lab

# the chart's settings: label -> the run's value of it
AXES = {"hidden units": lambda c: c.hidden, "population": lambda c: c.population, "goals": lambda c: c.targets,
        "seed": lambda c: c.seed, "method": lambda c: lab.methods.get(c.method).label}
# the settings a group shares: label -> the run's value of it (the plotted one and, but when it is
# plotted, the seed left out)
SETTINGS = {"robot": lambda c: c.robot, **AXES,
            "length": lambda c: f"{c.seconds:g} s" if c.seconds is not None else f"{c.generations:,} gen",
            "goal kind": lambda c: getattr(c, "goal", "position")}


def _key(config, axis: str) -> tuple:
    return tuple((name, value(config)) for name, value in SETTINGS.items()
                 if name != axis and (name != "seed" or axis == "seed"))


def finished(runs: list) -> list:
    """The runs with a held-out MSE to plot (finished, a finite positive error)."""
    out = []
    for r in runs:
        y = r.held_out() if r.state == "finished" else None
        if y is not None and math.isfinite(y) and y > 0:
            out.append(r)
    return out


def comparable(runs: list, axis: str) -> tuple[list, list, str]:
    """(the runs plotted, the finished runs left out, why in words): the largest group of finished
    runs that share every setting but `axis` (and the seed, a repeat, unless `axis` is the seed)."""
    done = finished(runs)
    if not done:
        return [], [], ""
    groups: dict[tuple, list] = {}
    for r in done:
        groups.setdefault(_key(r.config, axis), []).append(r)
    order = {id(r): k for k, r in enumerate(done)}
    key = max(groups, key=lambda k: (len(groups[k]), max(order[id(r)] for r in groups[k])))
    plotted = groups[key]
    left = [r for r in done if _key(r.config, axis) != key]
    if not left:
        return plotted, [], ""
    shared = dict(key)
    apart = Counter()
    for r in left:
        for name, value in _key(r.config, axis):
            if shared.get(name) != value:
                apart[f"{name} {value}"] += 1
    shown = ", ".join(f"{n} with {what}" for what, n in apart.most_common(3)) + (" ..." if len(apart) > 3 else "")
    sets = ", ".join(f"{name} {value}" for name, value in key)
    why = (f"{len(left)} finished run{'s' * (len(left) != 1)} left out: other settings than the plotted "
           f"runs' ({shown}); plotted: {sets}")
    return plotted, left, why


def _nice(v: float) -> str:
    return f"{v:g}" if 1e-3 <= abs(v) < 1e4 else f"{v:.0e}"


def chart_svg(runs: list, axis: str, width: int = 330, height: int = 210, big: bool = False) -> str:
    """SVG (in a <div> with its caption): the plotted runs' held-out MSE on a log axis with a grid of
    decades, against `axis`; a numeric setting on a linear axis (a log one over a wide range of
    positive values) with a line through each value's median, a method one column each. big: sized
    for a projector (1200 x 600, large type), scaled to its panel's width."""
    if big:
        width, height = 1200, 600
    font = 24 if big else 9
    plotted, left, why = comparable(runs, axis)
    if not plotted:
        return f"<small>Class chart: no finished run yet (held-out MSE against {html.escape(axis)}).</small>"
    points = [(AXES[axis](r.config), r.held_out(), r.name, r.config.seed) for r in plotted]
    xs = sorted({p[0] for p in points}, key=lambda v: (isinstance(v, str), v))
    numeric = all(isinstance(x, (int, float)) for x in xs)
    pad_l, pad_b, pad_t, pad_r = (4.6 * font, 3.4 * font, 1.0 * font, 1.5 * font)
    w, h = width - pad_l - pad_r, height - pad_t - pad_b
    if numeric:
        # values over a wide range of positive numbers (hidden units 2 to 64) on a log axis, else linear
        scale = np.log if min(xs) > 0 and max(xs) >= 8 * min(xs) else float
        lo, hi = scale(min(xs)), scale(max(xs))
        span = hi - lo if hi > lo else 1.0
        inset = 0.04 * w
        place = lambda x: pad_l + inset + (w - 2 * inset) * ((scale(x) - lo) / span if hi > lo else 0.5)  # noqa: E731
    else:
        place = lambda x: pad_l + w * (xs.index(x) + 0.5) / len(xs)  # noqa: E731
    logs = np.log10([p[1] for p in points])
    ylo, yhi = math.floor(float(logs.min())), math.ceil(float(logs.max()))
    if yhi <= ylo:
        yhi = ylo + 1
    ypos = lambda v: pad_t + h * (yhi - v) / (yhi - ylo)  # noqa: E731
    grid, labels = [], []
    for k in range(ylo, yhi + 1):  # a line at each decade, fainter ones at 2 and 5
        y = ypos(k)
        grid.append(f'<line x1="{pad_l:.0f}" y1="{y:.1f}" x2="{pad_l + w:.0f}" y2="{y:.1f}" stroke="#bbb"/>')
        labels.append(f'<text x="{pad_l - 0.4 * font:.0f}" y="{y + 0.35 * font:.1f}" font-size="{font}" '
                      f'text-anchor="end">{_nice(10.0 ** k)}</text>')
        if k < yhi:
            for m in (2, 5):
                y = ypos(k + math.log10(m))
                grid.append(f'<line x1="{pad_l:.0f}" y1="{y:.1f}" x2="{pad_l + w:.0f}" y2="{y:.1f}" stroke="#e4e4e4"/>')
    ticks = xs if len(xs) <= 12 else [xs[i] for i in np.linspace(0, len(xs) - 1, 6).round().astype(int)]
    for x in ticks:
        grid.append(f'<line x1="{place(x):.1f}" y1="{pad_t:.0f}" x2="{place(x):.1f}" y2="{pad_t + h:.0f}" stroke="#e4e4e4"/>')
        labels.append(f'<text x="{place(x):.1f}" y="{pad_t + h + 1.2 * font:.1f}" font-size="{font}" '
                      f'text-anchor="middle">{html.escape(str(x))}</text>')
    r = 0.45 * font if big else 3.5
    dots = "".join(
        f'<circle cx="{place(x):.1f}" cy="{ypos(np.log10(y)):.1f}" r="{r:.1f}" fill="#d62728" fill-opacity="0.7">'
        f'<title>{html.escape(n)}: {html.escape(axis)} {html.escape(str(x))}, seed {s}, held-out MSE {y:.3g}</title>'
        f'</circle>' for x, y, n, s in points)
    curve = ""
    if numeric and len(xs) > 1:  # the class's curve: the median held-out MSE (in log) at each value
        medians = [(x, float(np.median([np.log10(y) for px, y, _n, _s in points if px == x]))) for x in xs]
        line = " ".join(f"{place(x):.2f},{ypos(m):.2f}" for x, m in medians)
        curve = (f'<polyline points="{line}" fill="none" stroke="#1f77b4" stroke-width="{4 if big else 2}">'
                 f'<title>the class\'s median held-out MSE at each {html.escape(axis)}</title></polyline>')
    frame = (f'<rect x="{pad_l:.0f}" y="{pad_t:.0f}" width="{w:.0f}" height="{h:.0f}" fill="none" stroke="#888"/>'
             f'<text x="{pad_l + w / 2:.0f}" y="{height - 0.5 * font:.0f}" font-size="{font * 1.1:.0f}" '
             f'text-anchor="middle">{html.escape(axis)}</text>'
             f'<text transform="translate({1.1 * font:.0f},{pad_t + h / 2:.0f}) rotate(-90)" font-size="{font * 1.1:.0f}" '
             f'text-anchor="middle">held-out MSE (log scale)</text>')
    n = len(points)
    caption = (f"<b>Class chart</b>: held-out MSE of {n} finished run{'s' * (n != 1)} against {html.escape(axis)}"
               f"{'; the line: the class median at each value' if curve else ''}"
               f"{' (seeds are repeats)' if axis != 'seed' and len({p[3] for p in points}) > 1 else ''}."
               + (f" {html.escape(why)}." if why else ""))
    size = (f'width="100%" viewBox="0 0 {width} {height}" preserveAspectRatio="xMidYMid meet"' if big
            else f'width="{width}" height="{height}"')
    svg = (f"<svg {size} xmlns=\"http://www.w3.org/2000/svg\" font-family=\"sans-serif\">"
           f"{''.join(grid)}{frame}{''.join(labels)}{curve}{dots}</svg>")
    if not big:
        return f"<div><small>{caption}</small>{svg}</div>"
    # a projector's: a short title in large type, the chart, then what the line is and what was left out
    title = f"Held-out MSE against {html.escape(axis)}: {n} finished run{'s' * (n != 1)}"
    notes = (f"{'The line: the class median at each value. ' if curve else ''}"
             f"{'Seeds are repeats. ' if axis != 'seed' and len({p[3] for p in points}) > 1 else ''}"
             f"{html.escape(why) + '.' if why else ''}")
    return (f'<div><div style="font-size:28px;font-weight:bold;margin:4px 0">{title}</div>{svg}'
            f'<div style="font-size:16px">{notes}</div></div>')
