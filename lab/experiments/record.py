"""A Rerun recording of the whole experiment: every run's best-MSE curve on the `generation` timeline.

Entities (one per run): /mse/<robot>/<method>/seed_<seed> (the best training MSE so far) and
/log10_mse/<robot>/<method>/seed_<seed> (its log10: Rerun's plots have no log axis, the paper's
figures are log scale); the best run per arm and method again under /best/<robot>/<method>.
Each curve is sent in one `send_columns` call on the experiment's own RecordingStream; series
colours and names are static. The blueprint shows one log10 plot per arm.

    rerun results/paper/experiment.rrd
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lab import methods



def _send(rec, rr, path: str, history: np.ndarray) -> None:
    rec.send_columns(path, indexes=[rr.TimeColumn("generation", sequence=np.arange(len(history)))],
                     columns=rr.Scalars.columns(scalars=history))


def write_recording(exp, path: Path) -> Path:
    import rerun as rr
    import rerun.blueprint as rrb

    rec = rr.RecordingStream("neuro_ik_reproduce", make_default=False)
    views = [rrb.TimeSeriesView(origin=f"/log10_mse/{r}", name=f"{r}: log10 best MSE") for r in exp.config.robots]
    views.append(rrb.TimeSeriesView(origin="/best", name="best runs (MSE)"))
    rec.save(str(path), default_blueprint=rrb.Blueprint(rrb.Grid(*views), collapse_panels=True))
    try:
        for robot in exp.config.robots:
            for method in exp.config.methods:
                runs = exp.runs_of(robot, method)
                color = list(methods.get(method).color)
                for d in runs:
                    h = np.asarray(d["history"], dtype=np.float64)
                    for tree, values, width in (("mse", h, 1.0), ("log10_mse", np.log10(np.maximum(h, 1e-300)), 1.0)):
                        entity = f"/{tree}/{robot}/{method}/seed_{d['seed']:03d}"
                        rec.log(entity, rr.SeriesLines(colors=[color], names=f"{method} s{d['seed']}",
                                                       widths=width), static=True)
                        _send(rec, rr, entity, values)
                if runs:
                    best = min(runs, key=lambda d: d["train_mse"])
                    entity = f"/best/{robot}/{method}"
                    rec.log(entity, rr.SeriesLines(colors=[color], names=f"{robot} {method} best (s{best['seed']})",
                                                   widths=3.0), static=True)
                    _send(rec, rr, entity, np.asarray(best["history"], dtype=np.float64))
        rec.flush()
    finally:
        rec.disconnect()
    return path
