"""Running a training: its configuration and the loops that drive a method's backend.

- config.py: TrainConfig, the run's settings (shared fields + the method's Options);
- runner.py: Runner, a run in a background thread (start, pause, resume, stop, one event per
  generation to any subscriber); RunBase, what every runner shares; the RunSummary;
- worker.py: ProcessRunner, the same run in a worker process (`python -m lab.running.worker`);
- decimation.py: which generations (and populations) a run hands on, and the display goal;
- pipes.py: the messages between lab's processes;
- evolve.py: lab.evolve, a blocking run; warmup.py: compiles the kernels once.

ProcessRunner is not named here: `python -m lab.running.worker` must be its module's first import.
"""

from lab.running.config import TrainConfig
from lab.running.evolve import Run, evolve
from lab.running.runner import GenerationEvent, Runner, RunSummary, TimeLimit

__all__ = ["GenerationEvent", "Run", "RunSummary", "Runner", "TimeLimit", "TrainConfig", "evolve"]
