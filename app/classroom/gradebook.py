"""The class's runs as a CSV file: the teacher's grade book (the Class tab's "Download the class's runs",
presenter-only: app/panels/class_board.py).

    data = class_csv(runs.rows())   # bytes, UTF-8 with a BOM (a spreadsheet reads it)

One row per student run of the session, in the order they were started (the earlier boards' too:
the `board` column says which board each was on): the student's name, the lesson link it came from,
every setting of its run (TrainConfig.to_dict: robot, method, population, hidden, targets, the
generations or time budget it was given, seed, the method's options), then its state, the
generations it ran, its best training MSE, its held-out MSE, its seconds of optimizer time and its
recording. A cell a spreadsheet would read as a formula (one starting with = + - @) is written
with a leading apostrophe: a name such as "-1" is a name, not a formula.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time

LEADING = ("name", "lesson", "board")
OUTCOME = ("state", "generations run", "training MSE", "held-out MSE", "seconds", "recording", "started", "run id")
# settings whose TrainConfig names would read as an outcome: renamed in the header
RENAMED = {"generations": "generations (budget)", "seconds": "time budget (s)"}


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, (list, tuple, dict)):
        value = json.dumps(value, separators=(",", ":"))
    text = str(value)
    return "'" + text if text[:1] in ("=", "+", "-", "@") else text


def _row(run) -> dict:
    summary = run.summary
    settings = run.config.to_dict()
    return {
        "name": run.name, "lesson": run.lesson or "", "board": getattr(run, "board", 1),
        **{RENAMED.get(k, k): v for k, v in settings.items()},
        "state": run.state, "generations run": run.generation,
        "training MSE": summary.train_mse if summary is not None else run.best(),
        "held-out MSE": run.held_out(),
        "seconds": round(float(summary.seconds), 3) if summary is not None else None,
        "recording": run.recording or "",
        "started": time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(run.started or run.submitted)),
        "run id": run.id,
    }


def class_csv(runs: list) -> bytes:
    """The runs as CSV bytes (a header line, then one line per run)."""
    rows = [_row(r) for r in runs]
    settings: list[str] = []
    for row in rows:  # every setting any run has, in the order the first run that has it gives
        for k in row:
            if k not in LEADING and k not in OUTCOME and k not in settings:
                settings.append(k)
    header = [*LEADING, *settings, *OUTCOME]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\r\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([_cell(row.get(k)) for k in header])
    return ("\ufeff" + out.getvalue()).encode("utf-8")
