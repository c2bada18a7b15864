"""Training configuration: one frozen dataclass, validated before any work starts.

    TrainConfig(robot="ur5", method="cmaes")                  # None fields: the arm's and method's defaults
    TrainConfig.preset(paper=True, method="neat", seed=3)     # the paper's method literally
    TrainConfig.preset(robot="scara", sigma0=0.3)             # a method option by name
    TrainConfig.from_dict(config.to_dict())                   # what recordings and notebooks store

The fields every method shares are TrainConfig's; each method's own settings are its Options
dataclass (lab.methods), in `options`. to_dict() writes them flat, beside the shared fields
(the format of earlier recordings), and from_dict/preset/replace take them by name.
`seconds` is a time budget: the run ends when its optimizer time (pauses excluded) reaches it,
state "finished", with its best controller; with generations too, whichever comes first; without
them, its generations are UNBOUNDED. Its defaults are then the method's for that budget
(Method.defaults_for(arm, seconds): a method may choose its schedule from the budget).
`preset(paper=...)` gives the two settings the project compares:
- paper=True: the paper's method literally (the method's `paper` settings in its declaration);
- paper=False (the default): this project's choices per method and arm (the method's
  `defaults(arm)`), each backed by a measured comparison (benchmarks/bench_quality.py and
  bench_arms.py: docs/results/paper-budget.md, docs/results/real-arms.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import robots
from lab import methods
from lab.methods import Options
from lab.problem.checks import flag, real, shown, whole
from lab.problem.controllers import MAX_HEADS
from lab.problem.encoding import FEATURES
from lab.problem.pose_encoding import can_reach, check_goal, check_pose_robot, default_reach
from lab.problem.robot import check_robot, load_arm, robot_name

# upper bounds that keep a run within this machine's memory and time (a population of 10^9 would
# hang in pycma's or neat's setup; hidden 256 is a CMA-ES search space of about 2,300 weights)
# seeds: what numpy, SQLite and a recording's file name take (a seed of 10**400 named a file past 255 bytes);
# seconds: 10^9 s of optimizer time (32 years; a float of 1e300 s would pass for a budget)
LIMITS = {"population": 10_000, "goals": 1_000_000, "hidden": 256, "seed": 2**63 - 1, "seconds": 10**9}
# the paper's protocol: what a field left at None becomes when the method's defaults say nothing
PROTOCOL = {"generations": 1000, "population": 50, "targets": 70, "heads": 1, "turn": False, "wiring": False}
# the generations of a run with a time budget and no generation bound: the most a run may have (10^9;
# the recordings and the app's history thin long runs already), so that every reader of
# config.generations keeps an int
UNBOUNDED = 10**9
_PER_METHOD = ("generations", "population", "targets", "features", "margin", "hidden", "heads", "turn", "wiring")


@dataclass(frozen=True, init=False)
class TrainConfig:
    """One training run's settings. TrainConfig(robot=..., method=..., sigma0=...): shared fields
    by name, the method's options by name too (or as `options`, an Options or a dict). robot: a
    registered name, erd:NAME, a URDF path or a robots.Arm, with ee= its tool frame (not a field): the
    field holds the arm's canonical string (lab/problem/robot.py), which robots.load rebuilds."""

    robot: str = "planar"  # a registered name, erd:NAME or a URDF path (lab/problem/robot.py; an Arm: its name)
    method: str = methods.DEFAULT_METHOD
    generations: int | None = None  # None: the method's default for the arm, else 1000 (with seconds: UNBOUNDED)
    population: int | None = None  # None: the method's default for the arm, else 50
    targets: int | None = None  # fixed training goals (None: the method's default for the arm, else 70)
    seed: int = 0
    test_goals: int = 1000
    goal_seed: int = 0  # the training and held-out goals; fixed across runs, as in the paper
    features: str | None = None  # network inputs (lab/problem/encoding.py; None: the method's default)
    margin: float | None = None  # output range widening before clipping to the limits (None: the method's default)
    hidden: int | None = None  # MLP hidden units; graph methods: hidden nodes of the first networks
    heads: int | None = None  # an MLP's output heads (lab.problem.controllers.MLPController; None: the method's default, else 1)
    options: Options | dict | None = None  # the method's own settings (a dict is checked and converted)
    paper: bool = False  # record that this is the paper's literal method (see preset)
    resample: bool = False  # new training goals every generation (the paper: fixed; lab.problem.fitness)
    seconds: float | None = None  # time budget: s of optimizer time (None: none; generations then default to UNBOUNDED)
    turn: bool | None = None  # the first joint (a tree: each lone limb's) turned toward the goal in closed form (None: the default)
    wiring: bool | None = None  # a tree's MLP wired per limb group (lab/problem/wiring.py; None: the method's default)
    goal: str = "position"  # "pose": the network answers tool frames (n, 4, 4) (lab/problem/pose_encoding.py; a real arm)
    reach: int | None = None  # pose goals: passes of the closed-form elbow and shoulder (None: the method's and arm's default)

    def __init__(self, robot: str = "planar", method: str = methods.DEFAULT_METHOD, generations: int | None = None,
                 population: int | None = None, targets: int | None = None, seed: int = 0, test_goals: int = 1000,
                 goal_seed: int = 0, features: str | None = None, margin: float | None = None,
                 hidden: int | None = None, options: Options | dict | None = None, paper: bool = False,
                 resample: bool = False, heads: int | None = None, seconds: float | None = None,
                 turn: bool | None = None, wiring: bool | None = None, goal: str = "position", reach: int | None = None,
                 ee: str | None = None, **option_values):
        if ee is not None or isinstance(robot, robots.Arm):  # the robot's canonical string (lab/problem/robot.py)
            robot = robot_name(robot, ee)
        if option_values:
            base = options.to_dict() if isinstance(options, Options) else dict(options or {})
            options = {**base, **option_values}
        for name, value in (("robot", robot), ("method", method), ("generations", generations),
                            ("population", population), ("targets", targets), ("seed", seed),
                            ("test_goals", test_goals), ("goal_seed", goal_seed), ("features", features),
                            ("margin", margin), ("hidden", hidden), ("options", options), ("paper", paper),
                            ("resample", resample), ("heads", heads), ("seconds", seconds), ("turn", turn),
                            ("wiring", wiring), ("goal", goal), ("reach", reach)):
            object.__setattr__(self, name, value)
        self.__post_init__()

    def __post_init__(self):
        method = methods.get(self.method)
        check_robot(self.robot)  # unknown robot ..., by name, before any work
        check_goal(self.goal)
        self._check(method)  # what was given, before any arm is loaded
        arm = load_arm(self.robot)  # a registered name, erd:NAME or a URDF path (robots.load)
        if arm.name != self.robot:  # the canonical string ("erd:ur3" as robots.load names it)
            object.__setattr__(self, "robot", arm.name)
        if self.goal == "pose":
            check_pose_robot(arm)  # a real arm, or an error naming the robot
        budget = {} if self.seconds is None else {"generations": UNBOUNDED}
        defaults = {**PROTOCOL, **budget, **method.defaults_for(arm, self.seconds, goal=self.goal)}
        for name in _PER_METHOD:
            if getattr(self, name) is None:
                object.__setattr__(self, name, defaults[name])
        object.__setattr__(self, "options", method.options_for(arm, self.options, self.seconds, goal=self.goal))
        if self.reach is None:  # the method's (the gradient method: none), else the arm's where it turns
            object.__setattr__(self, "reach", defaults.get("reach", default_reach(arm) if self.goal == "pose"
                                                           and self.turn else 0))
        self._check(method)  # and the defaults filled in
        if self.reach and self.goal != "pose":
            raise ValueError(f"reach (the closed-form elbow and shoulder) is for pose goals (goal='pose'), got "
                             f"reach={self.reach} with goal={self.goal!r}")
        if self.reach and not (can_reach(arm) and self.turn):
            raise ValueError(f"reach needs the closed-form wrist (or an approach axis) and the turn: {self.robot} "
                             + ("has neither" if not can_reach(arm) else "runs with turn=False"))
        if arm.is_tree and self.heads > 1 and not self.wiring:
            raise ValueError(f"{self.robot} is a tree of {arm.n_effectors} end effectors: its multi-head MLPs "
                             "(heads > 1) are wired per limb group (wiring=True), each group picking its own head")
        if self.wiring and not arm.is_tree:
            raise ValueError(f"wiring is for trees (several end effectors): {self.robot} has one")
        if self.wiring and method.controller != "mlp":
            raise ValueError(f"wiring is for MLP networks: {method.label} does not train one")
        if self.wiring:
            from lab.problem.wiring import limb_groups

            groups = len(limb_groups(arm))
            if self.hidden < groups:
                raise ValueError(f"a wired network of {self.robot} needs at least one hidden unit for each of its "
                                 f"{groups} limb groups, got hidden={self.hidden}")

    def _check(self, method) -> None:
        """Every field that is set (None: a default still to come) is valid, by name."""
        for name in ("seed", "goal_seed"):
            whole(self, name, 0, LIMITS["seed"])
        for name, most in (("generations", 10**9), ("population", LIMITS["population"]),
                           ("targets", LIMITS["goals"]), ("test_goals", LIMITS["goals"])):
            if getattr(self, name) is not None:
                whole(self, name, 1, most)
        if self.population is not None and self.population < method.min_population:
            raise ValueError(f"population must be >= {method.min_population} for {method.label}, got {self.population}")
        if self.features is not None and self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {shown(self.features)}")
        if self.hidden is not None:
            whole(self, "hidden", method.min_hidden, LIMITS["hidden"])
        if self.heads is not None:
            whole(self, "heads", 1, MAX_HEADS)
            if self.heads > method.max_heads:
                raise ValueError(f"heads must be 1 for {method.label} (its networks have one head), got {self.heads}"
                                 if method.max_heads == 1 else
                                 f"heads must be at most {method.max_heads} for {method.label}, got {self.heads}")
        if self.margin is not None:
            real(self, "margin", 0, 10, "a number in [0, 10)", closed_above=False)
        flag(self, "paper")
        flag(self, "resample")
        if self.turn is not None:
            flag(self, "turn")
        if self.wiring is not None:
            flag(self, "wiring")
        if self.reach is not None:
            whole(self, "reach", 0, 16)
        if self.seconds is not None:
            real(self, "seconds", 0, LIMITS["seconds"], "a positive finite number of seconds (optimizer time) up to "
                 f"{LIMITS['seconds']:,}, or None", closed_below=False)
        if isinstance(self.options, dict):  # the given values, checked by the method's own dataclass
            method.options(**method.known_options(self.options))

    def __getattr__(self, name: str):
        """A method option read as config.<name> (config.sigma0), as before options had a class."""
        options = self.__dict__.get("options")
        if options is not None and not name.startswith("_") and name in type(options).names():
            return getattr(options, name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    @classmethod
    def from_dict(cls, d: dict, strict: bool = True) -> "TrainConfig":
        """A TrainConfig from to_dict()'s flat form: shared fields and the method's options by
        name. An option of another method is refused by name, unless strict=False (files written
        before options had a class hold every method's options: those are dropped)."""
        if not isinstance(d, dict):
            raise ValueError(f"a training configuration must be a mapping, got {type(d).__name__}")
        if not strict:
            own = methods.get(d.get("method", methods.DEFAULT_METHOD)).options.names()
            others = {n for m in methods.all_methods() for n in m.options.names()} - set(own)
            d = {k: v for k, v in d.items() if k not in others}
        try:
            return cls(**d)
        except TypeError as e:  # a key that is neither a setting nor an option of any method
            raise ValueError(f"not a training configuration: {e}") from None

    @classmethod
    def preset(cls, paper: bool = False, **overrides) -> "TrainConfig":
        """The paper's literal method (paper=True) or this project's defaults, then overrides.
        A None override leaves that setting to the preset (the CLI passes None for unset flags)."""
        method = methods.get(overrides.get("method") or methods.DEFAULT_METHOD)
        base = {"method": method.name}
        if paper is True:
            if method.paper is None:
                raise ValueError(f"{method.label} has no paper preset (the paper has CMA-ES and NEAT)")
            base.update(method.paper)
        base.update({k: v for k, v in overrides.items() if v is not None})
        return cls.from_dict({**base, "paper": paper})

    def replace(self, **changes) -> "TrainConfig":
        """A copy with some settings changed, options by name too; a new method starts from its
        own default options unless they are given."""
        d = self.to_dict()
        if "method" in changes and changes["method"] != self.method:
            d = {k: v for k, v in d.items() if k not in self.options.names()}
            if methods.get(changes["method"]).controller != "mlp":  # a wired network is an MLP's
                d.pop("wiring", None)
            d.pop("reach", None)  # the closed-form reach is a method's default too (the gradient method: none)
        return TrainConfig.from_dict({**d, **changes})

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "options"}
        if not self.resample:  # the paper's fixed goals: written as before resampling existed, so
            del d["resample"]  # stored runs, recordings and notebooks made earlier still compare equal
        if d["heads"] == 1:  # one head: likewise, as before heads existed
            del d["heads"]
        if d["seconds"] is None:  # no time budget: likewise, as before budgets existed
            del d["seconds"]
        if not d["turn"]:  # no turn: likewise, as before the turn existed
            del d["turn"]
        if not d["wiring"]:  # no wiring: likewise, as before wired networks existed
            del d["wiring"]
        if d["goal"] == "position":  # position goals: likewise, as before pose goals existed
            del d["goal"]
        if not d["reach"]:  # no reach: likewise, as before it existed
            del d["reach"]
        return {**d, **self.options.to_dict()}
