"""The lab notebook: one entry per run started in the app, kept across restarts.

Stored as JSON at recordings/notebook.json by default (beside the runs' Rerun recordings;
`python -m app --notebook PATH` changes it). Each entry:

    run_id, started (ISO 8601, local time), robot, method, seed, settings (the TrainConfig),
    state (finished / stopped / failed), generations, evaluations, seconds,
    train_mse, test_mse (held-out), recording (path of the .rrd or null),
    controller (the final best controller's to_dict(), so an entry replays without its recording)

Writes go to a temporary file then replace the old one, so a crash never leaves half a file.
A path that holds something else (a folder, a file that is not a lab notebook) is refused with
NotebookError, and left as it is.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time

DEFAULT_PATH = os.path.join("recordings", "notebook.json")


class NotebookError(ValueError):
    """The notebook's path holds something that is not a lab notebook (it is left untouched)."""


class Notebook:
    """Entries are kept as they were read: top-level keys it does not know and entries without a
    run_id are written back unchanged (entries() lists only the runs)."""

    def __init__(self, path: str = DEFAULT_PATH):
        self.path = path
        self._lock = threading.Lock()
        self._doc, self._all = self._read()  # the file's other keys; every entry, runs or not

    @property
    def _entries(self) -> list[dict]:
        return [e for e in self._all if "run_id" in e]

    def _read(self) -> tuple[dict, list[dict]]:
        if not os.path.lexists(self.path):
            return {}, []
        if os.path.isdir(self.path):
            raise NotebookError(f"notebook {self.path} is a folder; give the path of a .json file")
        try:
            with open(self.path, encoding="utf-8") as f:
                text = f.read()
            data = json.loads(text) if text.strip() else []  # an empty file: an empty notebook
            doc, entries = ({k: v for k, v in data.items() if k != "runs"}, data.get("runs")) \
                if isinstance(data, dict) else ({}, data)
            if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
                raise ValueError("no list of run entries in it")
        except (OSError, ValueError) as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
            raise NotebookError(f"notebook {self.path} is not a lab notebook ({e}); it was left as it is: "
                                "move it away or give another path") from e
        return doc, entries

    def entries(self) -> list[dict]:
        with self._lock:
            return list(self._entries)

    def get(self, run_id: str) -> dict | None:
        return next((e for e in self.entries() if e["run_id"] == run_id), None)

    def add(self, entry: dict) -> None:
        with self._lock:
            self._all = [e for e in self._all if e.get("run_id") != entry["run_id"]] + [entry]
            self._write()

    def _write(self) -> None:
        folder = os.path.dirname(self.path) or "."
        os.makedirs(folder, exist_ok=True)
        tmp = f"{self.path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump({"version": 1, **self._doc, "runs": self._all}, f, indent=1)
        os.replace(tmp, self.path)


def entry_from_summary(summary, started: float, recording: str | None) -> dict:
    """A notebook entry from a lab.RunSummary."""
    cfg = summary.config
    finite = lambda x: float(x) if x is not None and math.isfinite(x) else None  # noqa: E731
    numbers = summary.numbers()
    return {
        "run_id": summary.run_id,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(started)),
        "robot": cfg.robot, "method": cfg.method, "seed": cfg.seed, "settings": cfg.to_dict(),
        **numbers, "seconds": round(float(numbers["seconds"]), 3),
        "train_mse": finite(numbers["train_mse"]), "test_mse": finite(numbers["test_mse"]),
        "recording": str(recording) if recording else None,
        "controller": summary.controller.to_dict() if summary.controller is not None else None,
    }


def label(entry: dict) -> str:
    """One line for the runs list."""
    mse = entry.get("test_mse")
    mse_s = f"{mse:.3g}" if isinstance(mse, (int, float)) else "-"
    return (f"{entry.get('started', '?')[5:16].replace('T', ' ')} {entry['robot']} {entry['method']} "
            f"s{entry['seed']} {entry['generations']}g held-out {mse_s} [{entry['run_id'][:6]}]")
