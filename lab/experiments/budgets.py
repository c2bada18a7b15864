"""What a method is measured to reach on an arm in a time budget, for a user to know before a run.

    expected("ur5", "neat", 60)   # {"seconds": 60.0, "median_pct": ..., "median_mm": ..., ...} or None

The figures are benchmarks/bench_budget.py's held-out medians (its `--write` stores them in
BUDGETS_FILE, with the date and machine they were measured on): a run of `seconds` is quoted the
figure of the largest measured budget not above it (the smallest measured one below them all),
so the quote never promises more time than the run has. They were measured on one machine with
one seed; another machine fits more or fewer generations in the same seconds.
"""

from __future__ import annotations

import functools
import json
import os

BUDGETS_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "budgets.json")
# a controller worse than this share of the reach (median) is not worth much as an IK answer:
# the app says so before a run starts
POOR_PCT = 5.0


@functools.cache
def _measured(path: str = BUDGETS_FILE) -> dict:
    """{"machine": ..., "date": ..., "runs": [{robot, method, seconds, median_pct, median_mm, ...}]} or {}."""
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        return {}
    if not isinstance(doc, dict) or not isinstance(doc.get("runs"), list):
        raise ValueError(f"{path}: not a budgets file (a mapping with a list of runs)")
    return doc


def expected(robot: str, method: str, seconds: float | None, path: str = BUDGETS_FILE) -> dict | None:
    """The measured figure for `method` on `robot` in `seconds` of optimizer time (None: the largest
    budget measured), or None when nothing was measured for that pair."""
    doc = _measured(path)
    runs = sorted((r for r in doc.get("runs", []) if r.get("robot") == robot and r.get("method") == method
                   and "median_pct" in r), key=lambda r: r["seconds"])
    if not runs:
        return None
    within = [r for r in runs if seconds is None or r["seconds"] <= seconds]
    run = within[-1] if within else runs[0]
    return {**run, "date": doc.get("date"), "machine": doc.get("machine")}


def write(rows: list[dict], machine: str, date: str, path: str = BUDGETS_FILE) -> None:
    """Store benchmark rows (bench_budget.py's) as the measured figures, merged over those already
    there for other (robot, method, seconds); written whole to a temporary file, then moved over."""
    keep = ("robot", "method", "seconds", "seed", "generations", "median_pct", "median_mm", "p90_pct", "p99_pct")
    old = {(r["robot"], r["method"], float(r["seconds"])): r for r in _measured(path).get("runs", [])}
    for row in rows:
        if "error" not in row:
            old[(row["robot"], row["method"], float(row["seconds"]))] = {k: row[k] for k in keep if k in row}
    doc = {"machine": machine, "date": date, "command": "python benchmarks/bench_budget.py --write",
           "runs": [old[k] for k in sorted(old)]}
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)
    _measured.cache_clear()
