"""Teaching views: the workspace error map and the network drawing.

Error map: the inverse-kinematics counterpart of a classifier's decision surface. Goals on
a grid over the workspace (the task plane of a planar arm; the horizontal slice through the
middle of the workspace for the others), kept where the arm can reach (a grid cell holds at
least one end-effector position of joint vectors drawn uniformly within the limits), each
coloured by the controller's end-effector error ||g - reach(controller(g))||.

Network: the controller as an SVG: inputs on the left, outputs (joints) on the right, hidden
nodes by depth; enabled connections coloured by weight sign (red +, blue -), their width and
opacity growing with |w|.
"""

from __future__ import annotations

import functools
import html
from dataclasses import dataclass

import numpy as np

import robots
from lab.problem.controllers import network_layout
from lab.recording.population import ramp
from app.training.live import swatch
from robots.ik import workspace_size

GRID = 64
GRID_3D = 40
MAP_SCALE = 0.1  # the map's colours: dark purple on the goal, yellow at this fraction of the workspace's width or more


@dataclass(frozen=True, eq=False)
class MapGrid:
    """Reachable cells of an n x n grid over the workspace (x, y) at height z."""

    goals: np.ndarray  # (k, len(task_axes)) goal at each reachable cell's centre
    cells: np.ndarray  # (k, 2) cell indices (i along x, j along y)
    origin: np.ndarray  # (2,) x, y of the grid's corner
    cell: float  # cell size [length]
    n: int
    z: float

    @property
    def center(self) -> np.ndarray:
        return np.array([*(self.origin + 0.5 * self.n * self.cell), self.z])


def has_map(arm: robots.Arm) -> bool:
    """Whether the arm has an error map: one end effector (a tree's goal is a point per effector)."""
    return not arm.is_tree


@functools.lru_cache(maxsize=16)
def map_grid(arm: robots.Arm, n: int | None = None) -> MapGrid:
    """The plane: 64 x 64 cells from 20,000 joint samples; a 3D arm's slice: 40 x 40 cells from
    400,000 samples (a slab one cell thick holds few of them). ValueError on a tree (has_map)."""
    if not has_map(arm):
        raise ValueError(f"{arm.name} has {arm.n_effectors} end effectors: an error map needs one")
    planar = len(arm.task_axes) == 2
    n = n or (GRID if planar else GRID_3D)
    samples = arm.fk(arm.sample_q(20_000 if planar else 400_000, seed=4321))  # (k, 3)
    lo, hi = arm.workspace_bounds
    axes = list(arm.task_axes)
    lo_xy, hi_xy = np.array([lo[axes.index(0)], lo[axes.index(1)]]), np.array([hi[axes.index(0)], hi[axes.index(1)]])
    cell = float(np.max(hi_xy - lo_xy)) / (n - 1)
    origin = 0.5 * (lo_xy + hi_xy) - 0.5 * n * cell
    z = 0.0
    if 2 in axes:  # the slice through the middle of the workspace, one cell thick
        z = 0.5 * (lo[axes.index(2)] + hi[axes.index(2)])
        samples = samples[np.abs(samples[:, 2] - z) < max(cell, 0.02 * workspace_size(arm))]
    cells = np.unique(np.clip(np.floor((samples[:, :2] - origin) / cell).astype(int), 0, n - 1), axis=0)
    xyz = np.column_stack([origin + (cells + 0.5) * cell, np.full(len(cells), z)])
    return MapGrid(xyz[:, axes], cells, origin, cell, n, z)


def error_map(arm: robots.Arm, controller) -> tuple[np.ndarray, np.ndarray, float]:
    """(RGBA image (n, n, 4), errors (k,), colour scale [length]) of a controller over map_grid(arm).

    Image row r holds cell row j = r (viser draws row 0 at the image plane's -y side);
    unreachable cells are transparent."""
    grid = map_grid(arm)
    scale = map_scale(arm)  # fixed per arm, so colours compare across training
    image = np.zeros((grid.n, grid.n, 4), np.uint8)
    if controller is None or len(grid.goals) == 0:
        err, rgb = np.full(len(grid.goals), np.nan), np.full((len(grid.goals), 3), 160, np.uint8)
    else:
        err = np.linalg.norm(arm.reach(controller(grid.goals)) - grid.goals, axis=1)
        rgb = ramp(err / scale)
    i, j = grid.cells[:, 0], grid.cells[:, 1]
    image[j, i, :3] = rgb
    image[j, i, 3] = 235 if len(arm.task_axes) == 2 else 140  # a slice lets the arm show through
    return image, err, scale


def map_scale(arm: robots.Arm) -> float:
    """The error the map draws yellow (and beyond) [length]: MAP_SCALE x the workspace's width."""
    return MAP_SCALE * workspace_size(arm)


def yellow_words(arm: robots.Arm, fmt) -> str:
    """What yellow means on the map, in the arm's units (fmt: a length as text, with its unit):
    "misses by 4.672 units or more (10 % of the workspace's width)"; a real arm's also in % of its reach."""
    scale = map_scale(arm)
    reach = f", {100 * scale / arm.reach_radius:.0f} % of its reach" if robots.in_metres(arm.name) else ""
    return f"misses by {fmt(scale)} or more ({100 * MAP_SCALE:.0f} % of the workspace's width{reach})"


def map_legend(arm: robots.Arm, err: np.ndarray, fmt) -> str:
    """The Views tab's legend of the error map `err` (error_map's errors), with its units."""
    finite = err[np.isfinite(err)]
    where = "" if len(arm.task_axes) == 2 else " (the slice through the middle of the workspace, drawn on the floor)"
    ramp_html = "".join(swatch(c, "") for c in ramp(np.linspace(0.0, 1.0, 5)))
    numbers = (f"Median {fmt(float(np.median(finite)))}, max {fmt(float(finite.max()))}."
               if len(finite) else "No controller.")
    return (f"<small><b>Error map</b> of the shown network over {len(err):,} reachable goals{where}: how far the arm "
            f"ends from each goal, {ramp_html} from dark purple, on the goal, to yellow, {yellow_words(arm, fmt)}. "
            f"{numbers}</small>")


@dataclass(frozen=True)
class MapKey:
    """The error map's legend in the scene: a colour bar left of the map's reachable cells, in its plane,
    from dark purple (bottom) to yellow (top), with a label at each end."""

    image: np.ndarray  # (n, 1, 3) the bar's colours, row 0 (drawn at -y) dark purple
    center: np.ndarray  # (2,) x, y of the bar's centre in the map's plane
    width: float
    height: float
    top: tuple[np.ndarray, str, str]  # (x, y) where the label of the bar's top end is anchored, its text, anchor
    bottom: tuple[np.ndarray, str, str]


def map_key(arm: robots.Arm, fmt) -> MapKey:
    """Where and what the scene's legend of map_grid(arm)'s error map is. Each label starts at the bar's
    left edge and runs to the right, the top one above the bar and the bottom one below it (screen up is
    +y in the map's plane in every default camera), so that no text runs off a page whose scene begins
    near the bar (a lesson's column on the left, a phone); short lines, so the text stays narrow."""
    grid = map_grid(arm)
    side = grid.n * grid.cell
    width, height = 0.06 * side, 0.3 * side
    lo, hi = grid.origin + grid.cell * grid.cells.min(axis=0), grid.origin + grid.cell * (grid.cells.max(axis=0) + 1)
    x = lo[0] - 0.05 * side  # beside the reachable cells' left edge, half way up them
    y0 = 0.5 * (lo[1] + hi[1]) - 0.5 * height
    image = ramp(np.linspace(0.0, 1.0, 32))[:, None, :]
    left = x - 0.5 * width
    return MapKey(image, np.array([x, y0 + 0.5 * height]), width, height,
                  top=(np.array([left, y0 + height]), f"error map\nyellow = misses by ≥ {fmt(map_scale(arm))}\n"
                                                      f"({100 * MAP_SCALE:.0f} % of the workspace)", "bottom-left"),
                  bottom=(np.array([left, y0]), "dark purple = on the goal", "top-left"))


# ---------------------------------------------------------------------------- network drawing
def network_svg(controller, width: int = 300, height: int = 220) -> str:
    """An SVG drawing of the controller's network (a short note when there is none)."""
    if controller is None:
        return "<p style='font-size:0.8em'>No controller yet.</p>"
    nodes, links = network_layout(controller)
    layers: dict[int, list] = {}
    for key, layer, label, _kind in nodes:
        layers.setdefault(layer, []).append((key, label))
    n_layers = max(layers) + 1
    pos = {}
    for layer, members in layers.items():
        x = 24 + (width - 48) * layer / max(n_layers - 1, 1)
        for m, (key, _label) in enumerate(members):
            pos[key] = (x, 12 + (height - 24) * (m + 0.5) / len(members))
    wmax = max([abs(w) for *_, w in links] + [1e-9])
    parts = [f"<svg xmlns='http://www.w3.org/2000/svg' width='100%' viewBox='0 0 {width} {height}'>"]
    for src, dst, w in links:
        if src not in pos or dst not in pos:
            continue
        a = abs(w) / wmax
        color = "#d62728" if w > 0 else "#1f77b4"
        (x1, y1), (x2, y2) = pos[src], pos[dst]
        parts.append(f"<line x1='{x1:.1f}' y1='{y1:.1f}' x2='{x2:.1f}' y2='{y2:.1f}' stroke='{color}' "
                     f"stroke-width='{0.4 + 2.6 * a:.2f}' stroke-opacity='{0.15 + 0.85 * a:.2f}'/>")
    for key, layer, label, kind in nodes:
        x, y = pos[key]
        fill = {"input": "#444", "output": "#2ca02c", "hidden": "#ff7f0e"}[kind]
        parts.append(f"<circle cx='{x:.1f}' cy='{y:.1f}' r='5' fill='{fill}'/>")
        if label:
            dx = -8 if layer == 0 else 8
            anchor = "end" if layer == 0 else "start"
            parts.append(f"<text x='{x + dx:.1f}' y='{y + 3:.1f}' font-size='9' text-anchor='{anchor}' "
                         f"fill='currentColor'>{html.escape(label)}</text>")
    parts.append("</svg>")
    n_hidden = sum(1 for node in nodes if node.kind == "hidden")
    caption = f"{controller.kind}: {n_hidden} hidden, {len(links)} connections, {controller.n_params} parameters"
    return "".join(parts) + f"<p style='font-size:0.75em;margin:0'>{caption}</p>"
