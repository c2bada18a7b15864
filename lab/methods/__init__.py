"""The methods: one registry, one module per method (see registry.py).

    from lab import methods
    methods.names(), methods.get("neat").label
    backend = methods.make_backend(problem, config)   # the Backend of config.method
    backend.step()                                    # one generation

- base.py: Options (a method's settings), RunSettings (what it reads of a run's settings),
  Backend (one step = one generation), StepResult;
- registry.py: Method (what the lab knows of a method), register, get, names;
- cmaes.py: CMA-ES on the paper's MLP (pycma);
- gradient.py: Adam on the same MLP, gradient by backpropagation through the arm's Jacobian;
- neat.py: NEAT (neat-python) with its faster genome and species code (neat_genome.py,
  neat_species.py), bit for bit neat-python's;
- neat_cma.py: NEAT-CMA, NEAT with its best networks' weights tuned by CMA-ES (Lamarckian).
"""

from __future__ import annotations

from lab.methods.base import Backend, Options, Population, RunSettings, StepResult, option
from lab.methods.registry import DEFAULT_METHOD, LivePlot, Method, all_methods, by_label, get, load_plugins, names, register, unregister


def make_backend(problem, config: RunSettings) -> Backend:
    """The backend of config.method on problem."""
    return get(config.method).backend(problem, config)


from lab.methods import cmaes, gradient, neat, neat_cma  # noqa: E402,F401  (each registers itself)

# the modules of LAB_METHODS and the installed entry points are imported when the registry is first
# asked (registry._load_environment): a module that cannot be imported is then a SettingError

__all__ = ["Backend", "DEFAULT_METHOD", "LivePlot", "Method", "Population", "Options", "RunSettings", "StepResult",
           "all_methods", "by_label", "get", "load_plugins", "make_backend", "names", "option", "register", "unregister"]
