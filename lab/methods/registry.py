"""The registry of methods: every part of the lab asks it, none asks which method is running.

    from lab import methods
    methods.names()                 # ('cmaes', 'neat', ...) in registration order
    m = methods.get("cmaes")        # a Method: label, colour, options, defaults, backend, ...
    m.backend(problem, config)      # its Backend (the class is imported on first use)
    methods.register(Method(...))   # a method of your own (examples/custom_method.py)

A method is one module that declares itself once with `register(Method(...))`. Built-in
methods are lab/methods/cmaes.py and neat.py; others load from the modules named in the
environment variable LAB_METHODS (comma-separated, so that worker processes load them too)
and from the entry points of group `neuro_ik_lab.methods` of installed packages, when the registry
is first asked (get, names, all_methods): a LAB_METHODS module that cannot be imported raises
lab.problem.environment.SettingError there, which `python -m lab` and `python -m app` print in one line.
"""

from __future__ import annotations

import importlib
import threading
from dataclasses import dataclass, field
from typing import Callable, Mapping

from lab.methods.base import Backend, Options
from lab.problem import environment
from lab.problem.checks import shown

DEFAULT_METHOD = "cmaes"
_REGISTRY: dict[str, "Method"] = {}


@dataclass(frozen=True)
class SpeedReference:
    """The library's own loop with a trivial fitness: what a backend's overhead is measured against.
    loop(config, problem, generations) -> seconds; target: the largest acceptable ratio."""

    what: str
    target: float
    loop: Callable


@dataclass(frozen=True)
class LivePlot:
    """A plot of one of a method's StepResult extras per generation, drawn live in the app beside
    the convergence curve.

    key: the extras entry; title: the plot's title; about: two sentences on what a class sees;
    kind: "line" (a number per generation) or "stacked" (a {name: size} mapping per generation,
        drawn as stacked bands, as neat-python's plot_species draws species sizes);
    log: a log y axis (lines).
    """

    key: str
    title: str
    about: str
    kind: str = "line"
    log: bool = False

    def __post_init__(self):
        if self.kind not in ("line", "stacked"):
            raise ValueError(f"live plot {self.key!r}: kind must be 'line' or 'stacked', got {self.kind!r}")


@dataclass(frozen=True)
class Method:
    """What the lab needs to know of a method, declared once in the method's module.

    name: the id in configs, files and the CLI ("cmaes"); label: what people read ("CMA-ES");
    color: (r, g, b) in its plots, recordings and the app; summary: one line for help texts.
    backend_class: the Backend subclass, or "module:Class" to import on first use (a method
        whose library is slow to import keeps `import lab` fast).
    options: its Options dataclass; defaults(arm) -> dict: the settings it runs with on an arm
        when none are given, TrainConfig fields (features, margin, hidden, generations,
        population, targets) and option values alike; so defaults can differ per arm class.
    budget_defaults(arm, seconds) -> dict: optional, the settings for a run with a time budget of
        `seconds` s of optimizer time (TrainConfig.seconds), same keys as defaults: a method may
        choose its schedule from the budget. A `generations` it gives bounds the run besides the
        budget (whichever comes first); without one the run's generations are unbounded
        (TrainConfig's UNBOUNDED). None: defaults(arm) without its generations (for_budget).
    paper: the paper's literal settings (same keys), or None when the paper has no such method.
    controller: what its networks are, "mlp" (the paper's fixed MLP) or "graph" (NEAT-like);
        recordings and the app draw them accordingly.
    min_population / min_hidden: the smallest population and hidden size it accepts.
    max_heads: the most output heads its MLPs may have (TrainConfig.heads; 1: single-head networks only).
    search_title / search_series: its /search plot (StepResult.extras) in words, for the
        recording's views; cost: CPU per evaluation relative to CMA-ES, to schedule experiments;
    ablations: settings compared with its defaults in benchmarks/bench_quality.py ("sigma0=0.4").
    step_evaluations(arm, config) -> int: the evaluations one step() counts (StepResult.evaluations);
        None: one per controller of the population (config.population). Experiments at equal
        budget (lab/experiments/claims.py) derive generations from it.
    reference: the bare library's loop that benchmarks/bench_speed.py times this method's backend
        against (None: nothing to compare with).
    live_plots: its LivePlots (the app draws them beside the convergence curve, and shows their
        latest values beside the population view).
    compile_seconds: (serial arm, tree) s its numba kernels take to compile on a cold cache, measured
        on the 2-core machine (docs/log.md); lab/running/warmup.py tells a waiting Start from them.
    pose_defaults(arm, seconds) -> dict: optional, the settings that differ for pose goals
        (TrainConfig.goal "pose", a real arm; seconds None without a budget), over defaults_for's.
    warms_with: optional, another method whose warm-up (lab/running/warmup.py) compiles every kernel
        this one calls: its step stands for both, and this method has none of its own.
    class_generations: optional, the generations of a student's default run on a paper arm, sized to
        teach in 5-20 s on one worker (docs/results/class.md); None: such a run has a time budget.
    """

    name: str
    label: str
    color: tuple[int, int, int]
    summary: str
    backend_class: type[Backend] | str
    options: type[Options]
    defaults: Callable[..., Mapping]
    controller: str = "mlp"
    paper: Mapping | None = None
    min_population: int = 2
    min_hidden: int = 0
    max_heads: int = 1
    search_title: str = "search state"
    search_series: str = "the method's own numbers per generation"
    cost: float = 1.0
    step_evaluations: Callable | None = field(default=None, compare=False)
    ablations: tuple[str, ...] = ()
    reference: SpeedReference | None = field(default=None, compare=False)
    live_plots: tuple[LivePlot, ...] = ()
    budget_defaults: Callable[..., Mapping] | None = field(default=None, compare=False)
    compile_seconds: tuple[float, float] = (10.0, 5.0)
    pose_defaults: Callable[..., Mapping] | None = field(default=None, compare=False)
    warms_with: str | None = None
    class_generations: int | None = None

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name.isidentifier() and self.name.islower()):
            raise ValueError(f"a method name must be a lowercase identifier, got {self.name!r}")
        if self.controller not in ("mlp", "graph"):
            raise ValueError(f"method {self.name}: controller must be 'mlp' or 'graph', got {self.controller!r}")
        if not (isinstance(self.options, type) and issubclass(self.options, Options)):
            raise ValueError(f"method {self.name}: options must be an Options dataclass, got {self.options!r}")

    @property
    def backend(self) -> type[Backend]:
        """The Backend class (imported now if it was declared as "module:Class")."""
        if isinstance(self.backend_class, str):
            module, _, name = self.backend_class.partition(":")
            cls = getattr(importlib.import_module(module), name)
            object.__setattr__(self, "backend_class", cls)
        return self.backend_class

    def defaults_for(self, arm, seconds: float | None = None, goal: str = "position") -> dict:
        """The settings the method runs with on `arm` when none are given: defaults(arm) without a
        time budget (seconds None); with one, budget_defaults(arm, seconds), or where the method has
        none, defaults(arm) less its generations (those were chosen for a run without a budget).
        goal="pose" (pose goals, a real arm): those, with pose_defaults(arm, seconds) over them."""
        if goal == "pose":
            base = self.defaults_for(arm, seconds)
            return {**base, **(self.pose_defaults(arm, seconds) if self.pose_defaults is not None else {})}
        if seconds is None:
            return dict(self.defaults(arm))
        if self.budget_defaults is not None:
            return dict(self.budget_defaults(arm, seconds))
        return {k: v for k, v in self.defaults(arm).items() if k != "generations"}

    def evaluations_per_step(self, arm, config) -> int:
        """Evaluations one step (generation) of this method counts on arm with config."""
        return int(self.step_evaluations(arm, config)) if self.step_evaluations else int(config.population)

    @property
    def hex(self) -> str:
        return "#{:02x}{:02x}{:02x}".format(*self.color)

    def known_options(self, given: Mapping | None) -> dict:
        """given as a dict, when every name in it is one of this method's options (ValueError, naming them, else)."""
        given = dict(given or {})
        unknown = sorted(set(given) - set(self.options.names()))
        if unknown:
            raise ValueError(f"{', '.join(unknown)}: not an option of {self.name}; its options: "
                             f"{', '.join(self.options.names()) or 'none'}")
        return given

    def options_for(self, arm, given: Mapping | Options | None = None, seconds: float | None = None,
                    goal: str = "position") -> Options:
        """The method's options on `arm` (with a time budget of `seconds`: defaults_for): its
        defaults there, with `given` values over them."""
        if isinstance(given, self.options):
            return given
        if isinstance(given, Options):
            raise ValueError(f"options of {type(given).__name__} given to method {self.name}")
        given = self.known_options(given)
        base = {k: v for k, v in self.defaults_for(arm, seconds, goal).items() if k in self.options.names()}
        return self.options(**{**base, **given})


def register(method: Method, replace: bool = False) -> Method:
    """Add a method to the registry (replace=True: take the place of one of the same name)."""
    if not isinstance(method, Method):
        raise TypeError(f"register() takes a Method, got {type(method).__name__}")
    if method.name in _REGISTRY and not replace and _REGISTRY[method.name] != method:
        raise ValueError(f"a method named {method.name!r} is already registered (replace=True to replace it)")
    _REGISTRY[method.name] = method
    return method


def unregister(name: str) -> None:
    _REGISTRY.pop(name, None)


def get(name: str) -> Method:
    """The method of that name; ValueError naming the known ones otherwise."""
    _load_environment()
    if isinstance(name, str) and name in _REGISTRY:
        return _REGISTRY[name]
    raise ValueError(f"unknown method {shown(name)}; known methods: {', '.join(_REGISTRY)}")


def names() -> tuple[str, ...]:
    _load_environment()
    return tuple(_REGISTRY)


def all_methods() -> tuple[Method, ...]:
    _load_environment()
    return tuple(_REGISTRY.values())


def by_label(label) -> str:
    """The name of the method people read as `label` ("CMA-ES" -> "cmaes"); ValueError naming the value
    when it is none of them."""
    name = next((m.name for m in all_methods() if m.label == label), None)
    if name is None:
        raise ValueError(f"method {label!r:.40} is not one of {', '.join(m.label for m in all_methods())}")
    return name


def load_plugins(spec: str | None) -> None:
    """Import the modules named in `spec` (comma-separated) and the installed entry points of group
    `neuro_ik_lab.methods`: each registers its methods on import."""
    for module in filter(None, (s.strip() for s in (spec or "").split(","))):
        importlib.import_module(module)
    _load_entry_points()


def _load_entry_points() -> None:
    from importlib.metadata import entry_points

    for ep in entry_points(group="neuro_ik_lab.methods"):
        ep.load()


_environment_state = "not loaded"  # -> "loading" (in the thread that imports) -> "loaded"
_environment_lock = threading.RLock()  # a module being imported may ask the registry itself


def _load_environment() -> None:
    """Once per process: the modules of LAB_METHODS and the installed entry points. A module that
    cannot be imported: SettingError naming LAB_METHODS and the module (raised again at the next ask)."""
    global _environment_state
    if _environment_state == "loaded":
        return
    with _environment_lock:
        if _environment_state != "not loaded":  # loaded meanwhile, or asked by a module being imported
            return
        _environment_state = "loading"
        try:
            for module in environment.method_modules():
                try:
                    importlib.import_module(module)
                except Exception as e:
                    raise environment.cannot_import(module, e) from e
            _load_entry_points()
        except BaseException:
            _environment_state = "not loaded"
            raise
        _environment_state = "loaded"
