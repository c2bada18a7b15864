"""Training configuration: one frozen dataclass, validated before any work starts.

`TrainConfig.preset(paper=...)` gives the two settings the project compares:
- paper=True: the paper's method literally (goals scaled to [-1, 1] as inputs, one MLP
  trained by plain CMA-ES from one start; NEAT with the paper's parameters);
- paper=False (the default): this project's choices, each backed by a measured comparison
  in benchmarks/bench_quality.py (README, "Quality").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import robots

from .encoding import FEATURES

METHODS = ("cmaes", "neat")


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
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        for name in ("generations", "population", "targets", "test_goals"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.population < 4 and self.method == "cmaes":
            raise ValueError(f"population must be >= 4 for CMA-ES, got {self.population}")
        if self.population < 2:
            raise ValueError(f"population must be >= 2, got {self.population}")
        for name, defaults in (("hidden", DEFAULT_HIDDEN), ("features", DEFAULT_FEATURES), ("margin", DEFAULT_MARGIN)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, defaults[self.method])
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        if not isinstance(self.hidden, int) or self.hidden < (1 if self.method == "cmaes" else 0):
            raise ValueError(f"hidden must be an integer >= {1 if self.method == 'cmaes' else 0}, got {self.hidden!r}")
        if not (self.sigma0 > 0 and self.sigma0 < 1e6):
            raise ValueError(f"sigma0 must be a positive number, got {self.sigma0!r}")
        if not isinstance(self.diagonal, int) or isinstance(self.diagonal, bool) or self.diagonal < 0:
            raise ValueError(f"diagonal must be an integer >= 0 (generations), got {self.diagonal!r}")
        if not (self.mutation_power > 0 and self.mutation_power < 1e6):
            raise ValueError(f"mutation_power must be a positive number, got {self.mutation_power!r}")
        for name in ("add_node", "add_connection"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be a probability in [0, 1], got {getattr(self, name)!r}")

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
