"""The controller the app opens with, so the first drag already shows something sensible.

The app ships app/pretrained/planar-cmaes.json: a CMA-ES MLP for the planar arm (its
settings and its training and held-out MSE are in the file). When that file is missing or
no longer loads, a quick run is trained instead (about 1-2 s). Regenerate the file with

    python -m app.startup            # planar, CMA-ES, 4000 generations (about 15 s)
"""

from __future__ import annotations

import json
import logging
import os
import time

import lab
from lab import methods

log = logging.getLogger(__name__)

PRETRAINED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pretrained",
                          f"planar-{methods.DEFAULT_METHOD}.json")
QUICK = dict(robot="planar", method=methods.DEFAULT_METHOD, generations=400, population=20, seed=0)


def startup_controller(path: str = PRETRAINED):
    """(controller, description): the shipped controller, else a quickly trained one."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        controller = lab.controller_from_dict(data["controller"])
        controller(controller.encoding.in_lo[None, : len(controller.encoding.task_axes)])  # it runs
        return controller, f"shipped ({data['settings']['generations']} generations, held-out MSE {data['test_mse']:.3g})"
    except Exception as e:  # missing, or written by an older lab: train one now
        log.info("no shipped controller (%s); training a quick one", e)
    t0 = time.perf_counter()
    run = lab.evolve(**QUICK)
    return run.controller, f"trained at startup in {time.perf_counter() - t0:.1f} s (held-out MSE {run.test_mse:.3g})"


def main() -> None:
    run = lab.evolve(robot="planar", method=methods.DEFAULT_METHOD, generations=4000, population=50, seed=0)
    os.makedirs(os.path.dirname(PRETRAINED), exist_ok=True)
    with open(PRETRAINED, "w", encoding="utf-8") as f:
        json.dump({"settings": run.config.to_dict(), "train_mse": run.train_mse, "test_mse": run.test_mse,
                   "controller": run.controller.to_dict()}, f)
    print(f"wrote {PRETRAINED}: training MSE {run.train_mse:.4g}, held-out MSE {run.test_mse:.4g}")


if __name__ == "__main__":
    main()
