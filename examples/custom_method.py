"""A method of your own: random search, registered from outside the lab's package.

Each generation tries `population` Gaussian perturbations of the best MLP found so far and keeps
the best. Registering it is all it takes: lab.evolve, the Runner, the Rerun logger, the CLI
options and the experiments then know it like CMA-ES and NEAT (for the app and the experiments'
worker processes, name this module in LAB_METHODS).

    .venv/bin/python examples/custom_method.py [recording.rrd]
"""

import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import lab
from lab.methods import Backend, Method, Options, StepResult, option, register
from lab.problem.checks import real
from lab.problem.controllers import MLPController, mlp_size


@dataclass(frozen=True)
class RandomSearchOptions(Options):
    step: float = option(0.1, "std of the Gaussian perturbations of the best weights")

    def check(self) -> None:
        real(self, "step", 0, 1e6, "a positive number", closed_below=False)


class RandomSearch(Backend):
    def __init__(self, problem, config):
        super().__init__(problem, config)
        enc = problem.encoding
        self.rng = np.random.default_rng(config.seed)  # the run's own generator: same seed, same run
        self.x = self.rng.normal(0.0, 0.1, mlp_size(enc.n_inputs, config.hidden, enc.n_outputs))
        self.fx = np.inf

    def _step(self) -> StepResult:
        X = self.x + self.options.step * self.rng.standard_normal((self.config.population, self.x.size))
        f = self.problem.mlp_mse(X, self.config.hidden)  # (population,) MSE on the training goals
        i = int(np.argmin(f))
        if f[i] < self.fx:
            self.x, self.fx = X[i].copy(), float(f[i])
        self._offer(f[i], lambda: MLPController(self.problem.encoding, self.config.hidden, X[i].copy()))
        return StepResult(f, {"best_so_far": self.fx})


register(Method(
    name="random", label="Random search", color=(120, 120, 120), summary="Gaussian perturbations of the best MLP",
    backend_class=RandomSearch, options=RandomSearchOptions, controller="mlp",
    defaults=lambda arm: dict(features="reach", margin=2.0, hidden=5),
    search_title="Random search: best so far", search_series="the best training MSE found so far"))


def main() -> None:
    run = lab.evolve("planar", "random", generations=100, seed=0)
    print(f"lab.evolve: training MSE {run.train_mse:.6g}, held-out MSE {run.test_mse:.6g}")

    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp()) / "random-search.rrd"
    runner = lab.Runner(lab.TrainConfig(robot="planar", method="random", generations=100, step=0.1))
    logger = lab.RerunLogger(runner, path=path, overwrite=True)
    runner.subscribe(logger)
    runner.run()
    logger.close(wait=True)

    controller = lab.load_controller(path)  # the last generation's controller, from the file alone
    held_out = runner.problem.controller_mse(controller, runner.problem.test_goals)
    logged = lab.read_recording(path).summary["test_mse"]
    print(f"recording {path}: held-out MSE {held_out!r} (reloaded), {logged!r} (logged)")
    assert held_out == logged, "the reloaded controller's error differs from the logged one"


if __name__ == "__main__":
    main()
