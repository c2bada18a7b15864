"""Experiments: the paper's Tables 3-5 and Figures 5-6, reproduced side by side with its numbers.

    python -m lab reproduce --runs 30 --generations 1000 --population 50 --out results/paper

    from lab.experiments import ReproduceConfig, reproduce, welch
    exp = reproduce(ReproduceConfig(runs=3, generations=20, population=10, out="/tmp/x"))

reproduce.py schedules the runs (processes or Ray, resume, retry), runs.py trains and stores one
run, stats.py is Welch's t-test, tables.py / figures.py / record.py / report.py write the outputs.
"""

from lab.experiments.reproduce import Experiment, ReproduceConfig, reproduce
from lab.experiments.runs import RunSpec, RunStore, train_run
from lab.experiments.stats import WelchTest, welch

__all__ = ["Experiment", "ReproduceConfig", "RunSpec", "RunStore", "WelchTest", "reproduce", "train_run", "welch"]
