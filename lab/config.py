"""Training configuration: one frozen dataclass, validated before any work starts.

`TrainConfig.preset(paper=...)` gives the two settings the project compares:
- paper=True: the paper's method literally (goals scaled to [-1, 1] as inputs, one MLP
  trained by plain CMA-ES from one start; NEAT with the paper's parameters);
- paper=False (the default): this project's choices, each backed by a measured comparison
  in benchmarks/bench_quality.py (README, "Quality").
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import numpy as np

import robots

from .encoding import FEATURES

METHODS = ("cmaes", "neat")
# upper bounds that keep a run within this machine's memory and time (a population of 10^9 would
# hang in pycma's or neat's setup; hidden 256 is a CMA-ES search space of about 2,300 weights)
LIMITS = {"population": 10_000, "goals": 1_000_000, "hidden": 256}


@dataclass(frozen=True)
class TrainConfig:
    robot: str = "planar"
    method: str = "cmaes"
    generations: int = 1000
    population: int = 50
    targets: int = 70
    seed: int = 0
    test_goals: int = 1000
    goal_seed: int = 0  # the training and held-out goals; fixed across runs, as in the paper
    features: str | None = None  # network inputs (lab/encoding.py; None: DEFAULT_FEATURES of the method)
    margin: float | None = None  # output range widening before clipping to the limits (lab/encoding.py;
                                 # None: DEFAULT_MARGIN of the method)
    hidden: int | None = None  # MLP hidden units (CMA-ES); NEAT: hidden nodes of the first genomes
                               # (None: DEFAULT_HIDDEN of the method)
    sigma0: float = 0.2  # CMA-ES initial step size
    diagonal: int = 100  # CMA-ES: generations that adapt only the diagonal of C first (pycma CMA_diagonal)
    restarts: bool = False  # CMA-ES: restart from a new point when a start stagnates (same budget)
    mutation_power: float = 0.05  # NEAT: std of a weight or bias perturbation (paper: 1)
    add_node: float = 0.002  # NEAT: probability of an add-node mutation (paper: 0.002)
    add_connection: float = 0.002  # NEAT: probability of an add-connection mutation (paper: 0.002)
    paper: bool = False  # record that this is the paper's literal method (see preset)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; known methods: {', '.join(METHODS)}")
        if self.robot not in robots.names():
            raise ValueError(f"unknown robot {self.robot!r}; known robots: {', '.join(robots.names())}")
        for name in ("seed", "goal_seed"):
            self._whole(name, 0)
        for name, most in (("generations", 10**9), ("population", LIMITS["population"]),
                           ("targets", LIMITS["goals"]), ("test_goals", LIMITS["goals"])):
            self._whole(name, 1, most)
        if self.population < 4 and self.method == "cmaes":
            raise ValueError(f"population must be >= 4 for CMA-ES, got {self.population}")
        if self.population < 2:
            raise ValueError(f"population must be >= 2, got {self.population}")
        for name, defaults in (("hidden", DEFAULT_HIDDEN), ("features", DEFAULT_FEATURES), ("margin", DEFAULT_MARGIN)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, defaults[self.method])
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        self._whole("hidden", 1 if self.method == "cmaes" else 0, LIMITS["hidden"])
        self._whole("diagonal", 0, 10**9)
        self._real("margin", 0, 10, "a number in [0, 10)", closed_above=False)
        for name in ("sigma0", "mutation_power"):
            self._real(name, 0, 1e6, "a positive number", closed_below=False)
        for name in ("add_node", "add_connection"):
            self._real(name, 0, 1, "a probability in [0, 1]")
        for name in ("restarts", "paper"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))

    def _whole(self, name: str, least: int, most: int | None = None) -> None:
        """Check that field `name` is a whole number in [least, most], and store it as an int."""
        v = getattr(self, name)
        if not isinstance(v, numbers.Integral) or isinstance(v, (bool, np.bool_)) or v < least \
                or (most is not None and v > most):
            bound = f">= {least}" if most is None else f"in {least}..{most:,}"
            raise ValueError(f"{name} must be an integer {bound}, got {v!r}")
        object.__setattr__(self, name, int(v))

    def _real(self, name: str, lo: float, hi: float, what: str, closed_below: bool = True,
              closed_above: bool = True) -> None:
        """Check that field `name` is a real number within (lo, hi) as closed, and store it as a float."""
        v = getattr(self, name)
        ok = isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v) and \
            (v >= lo if closed_below else v > lo) and (v <= hi if closed_above else v < hi)
        if not ok:
            raise ValueError(f"{name} must be {what}, got {v!r}")
        object.__setattr__(self, name, float(v))

    @classmethod
    def preset(cls, paper: bool = False, **overrides) -> "TrainConfig":
        """The paper's literal method (paper=True) or this project's tuned defaults, then overrides."""
        base = dict(PAPER_PRESET if paper else {}, paper=paper)
        method = overrides.get("method", "cmaes")
        if paper and method in PAPER_HIDDEN:
            base.update(hidden=PAPER_HIDDEN[method])
        # None leaves a tuning option at its preset value (the CLI passes None for unset flags)
        base.update({k: v for k, v in overrides.items() if v is not None or k not in _OPTIONAL})
        return cls(**base)

    def replace(self, **changes) -> "TrainConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# The paper fixes no hidden-layer size or step size; these are the values a reader of the
# paper would pick (bench_quality.py measures them against the tuned defaults).
PAPER_PRESET = dict(features="cartesian", margin=0.0, sigma0=0.5, diagonal=0, restarts=False, mutation_power=1.0, add_node=0.002,
                    add_connection=0.002)
_OPTIONAL = {"hidden", "sigma0", "diagonal", "features", "margin", "test_goals", "goal_seed", "restarts", "mutation_power",
             "add_node", "add_connection"}
PAPER_HIDDEN = {"cmaes": 8, "neat": 0}  # NEAT starts with inputs wired to outputs (paper, 4.3)
DEFAULT_HIDDEN = {"cmaes": 5, "neat": 0}
# measured in bench_quality.py: CMA-ES gains from the slack-of-reach input and a wide margin, NEAT
# loses with both (SCARA held-out 7.3 with these, 12 with "reach", 240 with "reach" and margin 2)
DEFAULT_FEATURES = {"cmaes": "reach", "neat": "polar"}
DEFAULT_MARGIN = {"cmaes": 2.0, "neat": 0.5}
