"""NEAT (neat-python 2.0) evolving topology and weights (paper, sections 3 and 4.3).

The paper's parameters map onto neat-python as follows:
    connected input nodes = all          initial_connection = full_direct
    P(add node) = 0.002                  node_add_prob = 0.002
    P(add connection) = 0.002            conn_add_prob = 0.002
    P(mutate weight) = 0.5               weight_mutate_rate = 0.5 (bias likewise)
    weight cap 1000                      weight_min/max_value = -/+1000 (bias likewise)
    mutation weight range 1              weight_mutate_power = 1.0
    P(re-enable) = 0.25                  enabled_rate_to_true_add = 0.5: a disabled gene is
                                         redrawn with p = 0.5, and comes back True half the time
    activation tanh                      "tanh_": the textbook tanh (neat's own "tanh" is tanh(2.5 z))

neat-python 2.0 traps handled here (docs/methods.md, "Backends"): a fresh Config per run (its
innovation tracker keeps state); single_structural_mutation set explicitly (an omitted value
is the truthy string 'false'); fitness_criterion = max with fitness = -MSE (min is broken
before 2.1). neat-python draws from the global `random` module: each backend keeps its own
random state and swaps it in under a lock for every generation, so runs are reproducible by
seed even when several run in threads of one process.

Generations are advanced one at a time (the body of Population.run), so the runner can
pause and stop between any two; all genomes of a generation are compiled to one program and
evaluated in one compiled call. Genomes are FastGenome (neat_genome.py): the very genomes
neat.DefaultGenome makes from the same random state, in about half the time; species are
FastSpeciesSet's (neat_species.py): neat.DefaultSpeciesSet's species, with the distances compiled;
reproduction is FastReproduction (neat_genome.py): neat's, with per-parent work done once per call.
A generation's genomes compile straight to the arrays the fitness kernel walks (genome_program,
compile_genomes: compile_programs' arrays without a GraphController per genome).
"""

from __future__ import annotations

import functools
import math
import os
import random
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

import neat
import numpy as np


from lab.methods.base import Backend, Options, StepResult, option, real_arm_io
from lab.methods.registry import LivePlot, Method, SpeedReference, register
from lab.problem.checks import real
from lab.problem.controllers import GraphController, join_programs, lay_out, run_programs
from lab.methods.neat_genome import FastGenome, FastReproduction
from lab.methods.neat_species import FastSpeciesSet
from lab.problem.robot import arm_kind

_RANDOM_LOCK = threading.Lock()
BAD_FITNESS = -1e30  # neat-python needs a finite float; NaN/inf outputs get this
TARGET_SPECIES = 5

PAPER_NEAT = dict(node_add_prob=0.002, conn_add_prob=0.002, weight_mutate_rate=0.5, weight_cap=1000.0,
                  weight_mutate_power=1.0, enabled_rate_to_true_add=0.5)


@dataclass(frozen=True)
class NEATOptions(Options):
    mutation_power: float = option(0.05, "std of a weight or bias perturbation (paper: 1)")
    add_node: float = option(0.002, "probability of an add-node mutation (paper: 0.002)")
    add_connection: float = option(0.002, "probability of an add-connection mutation (paper: 0.002)")

    def check(self) -> None:
        real(self, "mutation_power", 0, 1e6, "a positive number up to 1,000,000", closed_below=False)
        for name in ("add_node", "add_connection"):
            real(self, name, 0, 1, "a probability in [0, 1]")


def neat_parameters(config) -> dict:
    """The paper's NEAT parameters with this run's mutation power and structural rates."""
    o = config.options
    return dict(PAPER_NEAT, weight_mutate_power=o.mutation_power, node_add_prob=o.add_node,
                conn_add_prob=o.add_connection)


def _gene_floats(name: str, p: dict) -> str:
    """The genome section's lines of a float gene (bias or weight): both follow the paper's weight rules."""
    cap = p["weight_cap"]
    items = [("init_mean", 0.0), ("init_stdev", 1.0), ("max_value", cap), ("min_value", -cap),
             ("mutate_power", p["weight_mutate_power"]), ("mutate_rate", p["weight_mutate_rate"]),
             ("replace_rate", 0.0)]
    return "\n".join(f"{name}_{key:<18s}= {value}" for key, value in items)


def neat_config_text(n_inputs: int, n_outputs: int, pop_size: int, hidden: int, seed: int,
                     params: dict = PAPER_NEAT, genome_section: str = "DefaultGenome",
                     species_section: str = "DefaultSpeciesSet",
                     reproduction_section: str = "DefaultReproduction") -> str:
    """neat-python's config file; genome_section, species_section, reproduction_section: the genome,
    species set and reproduction types' names (neat.Config reads the sections named after its types)."""
    p = params
    return f"""
[NEAT]
fitness_criterion     = max
fitness_threshold     = 1e30
pop_size              = {pop_size}
reset_on_extinction   = True
no_fitness_termination = True
seed                  = {seed}

[{genome_section}]
num_inputs              = {n_inputs}
num_outputs             = {n_outputs}
num_hidden              = {hidden}
feed_forward            = True
initial_connection      = full_direct
activation_default      = tanh_
activation_mutate_rate  = 0.0
activation_options      = tanh_
aggregation_default     = sum
aggregation_mutate_rate = 0.0
aggregation_options     = sum
{_gene_floats('bias', p)}
response_init_mean      = 1.0
response_init_stdev     = 0.0
response_max_value      = 1.0
response_min_value      = 1.0
response_mutate_power   = 0.0
response_mutate_rate    = 0.0
response_replace_rate   = 0.0
{_gene_floats('weight', p)}
enabled_default         = True
enabled_mutate_rate     = 0.0
enabled_rate_to_true_add = {p["enabled_rate_to_true_add"]}
enabled_rate_to_false_add = 0.0
compatibility_disjoint_coefficient = 1.0
compatibility_weight_coefficient   = 0.5
conn_add_prob           = {p["conn_add_prob"]}
conn_delete_prob        = 0.0
node_add_prob           = {p["node_add_prob"]}
node_delete_prob        = 0.0
single_structural_mutation = False
structural_mutation_surer  = default

[{species_section}]
compatibility_threshold = 3.0

[DefaultStagnation]
species_fitness_func = max
max_stagnation       = 20
species_elitism      = 2

[{reproduction_section}]
elitism            = 2
survival_threshold = 0.2
min_species_size   = 2
"""


def textbook_tanh(z: float) -> float:
    """tanh(z); neat-python's own "tanh" is tanh(2.5 z)."""
    return math.tanh(z)


def make_neat_config(n_inputs: int, n_outputs: int, pop_size: int, hidden: int, seed: int,
                     params: dict = PAPER_NEAT, genome_type=FastGenome,
                     species_set_type=FastSpeciesSet, reproduction_type=FastReproduction) -> neat.Config:
    """A fresh neat.Config (never reuse one between runs) with the textbook tanh registered.
    genome_type: FastGenome (the same genomes as neat.DefaultGenome, faster) or neat.DefaultGenome;
    species_set_type: FastSpeciesSet (the same species as neat.DefaultSpeciesSet, faster) or
    neat.DefaultSpeciesSet; reproduction_type: FastReproduction (neat.DefaultReproduction, with a
    cache FastGenome reads) or neat.DefaultReproduction."""
    text = neat_config_text(n_inputs, n_outputs, pop_size, hidden, seed, params, genome_type.__name__,
                            species_set_type.__name__, reproduction_type.__name__)
    return config_from_text(text, genome_type, species_set_type, reproduction_type)


def config_from_text(text: str, genome_type=FastGenome, species_set_type=FastSpeciesSet,
                     reproduction_type=FastReproduction) -> neat.Config:
    """A fresh neat.Config from the text of a config file (neat reads only files), with the textbook
    tanh registered as "tanh_"."""
    fd, path = tempfile.mkstemp(suffix=".ini", prefix="neat-")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        config = neat.Config(genome_type, reproduction_type, species_set_type, neat.DefaultStagnation, path)
    finally:
        os.unlink(path)
    config.genome_config.add_activation("tanh_", textbook_tanh)
    return config


def genome_to_controller(genome, config: neat.Config, encoding, record: bool = True) -> GraphController:
    """Compile a genome into the network neat.nn.FeedForwardNetwork.create builds from it.

    The same nodes (neat.graphs.required_for_output: the outputs and every non-input node with a
    path to one), each summing the same enabled links in the genome's connection order (links from
    required nodes and inputs), evaluated in a topological order: the same values as neat's
    layer by layer order. Linear in the genome's size (neat's feed_forward_layers is quadratic).
    record: also keep all the genome's nodes and connections (for logs and display).
    """
    gc = config.genome_config
    keys, weights = _enabled(genome)
    genes = genome.nodes
    nodes = []
    for key, gene_key, links in _wiring(keys, tuple(gc.input_keys), tuple(gc.output_keys)):
        ng = genes[gene_key]
        links = tuple([(i, float(weights[j])) for i, j in links])
        nodes.append((key, float(ng.bias), float(ng.response), links))
    record = {
        "nodes": [[int(k), float(n.bias)] for k, n in sorted(genome.nodes.items())],
        "connections": [[int(i), int(o), float(c.weight), bool(c.enabled)] for (i, o), c in sorted(genome.connections.items())],
    } if record else {}
    return GraphController(encoding, tuple(nodes), tuple(gc.input_keys), tuple(gc.output_keys), record)


def _enabled(genome) -> tuple[tuple, list]:
    """The keys (a tuple: the wiring caches' key) and weights of a genome's enabled connections, in its order."""
    keys, weights = [], []
    for cg in genome.connections.values():
        if cg.enabled:
            keys.append(cg.key)
            weights.append(cg.weight)
    return tuple(keys), weights


@functools.lru_cache(maxsize=4096)
def _wiring(enabled: tuple, input_keys: tuple, output_keys: tuple) -> tuple:
    """What genome_to_controller compiles, from the enabled connections' keys alone (in the
    genome's order; the genomes of a population mostly share them, hence the cache): the
    required nodes in evaluation order, each as (int key, key, ((int source, index in enabled), ...))."""
    inputs = set(input_keys)
    preds: dict[int, list] = {}
    for i, o in enabled:
        preds.setdefault(o, []).append(i)
    required = set(output_keys)
    stack = list(output_keys)
    while stack:
        for a in preds.get(stack.pop(), ()):
            if a not in inputs and a not in required:
                required.add(a)
                stack.append(a)
    incoming: dict[int, list] = {}  # in the order neat sums them: the genome's connection order
    for j, (i, o) in enumerate(enabled):
        if o in required and (i in required or i in inputs):
            incoming.setdefault(o, []).append((int(i), j))
    return tuple((int(key), key, tuple(incoming.get(key, ()))) for key in _topological(required, incoming))


@functools.lru_cache(maxsize=4096)
def _layout(enabled: tuple, input_keys: tuple, output_keys: tuple) -> tuple:
    """A wiring (_wiring) as compile_programs lays out its GraphController (controllers.lay_out):
    the node genes' keys in evaluation order, each link's source slot and index in `enabled`,
    each node's end in the links, each output's slot (-1: absent)."""
    wiring = _wiring(enabled, input_keys, output_keys)
    link_src, link_j, link_end, out_slot = lay_out([(key, links) for key, _, links in wiring], input_keys, output_keys)
    return tuple(gene_key for _, gene_key, _ in wiring), link_src, link_j, link_end, out_slot


def genome_program(genome, config: neat.Config) -> tuple:
    """What compile_programs takes from genome_to_controller(genome), as join_programs reads it:
    (biases, responses, link sources, link weights, node ends, output slots)."""
    gc = config.genome_config
    keys, weights = _enabled(genome)
    gene_keys, link_src, link_j, link_end, out_slot = _layout(keys, tuple(gc.input_keys), tuple(gc.output_keys))
    genes = genome.nodes
    nodes = [genes[k] for k in gene_keys]
    return [n.bias for n in nodes], [n.response for n in nodes], link_src, [weights[j] for j in link_j], link_end, out_slot


def program_hidden(program: tuple) -> int:
    """Hidden nodes of a genome_program's network: its nodes less the outputs it expresses."""
    bias, out_slot = program[0], program[5]
    return len(bias) - sum(1 for s in out_slot if s >= 0)


def compile_genomes(programs) -> tuple:
    """compile_programs([genome_to_controller(g) for g in genomes]), the same arrays, from the
    genomes' genome_program: no GraphController made (numpy's float64 of each value is float()'s)."""
    return join_programs(programs)


def _topological(required: set, incoming: dict) -> list:
    """Required nodes ordered so that every node comes after the required nodes it reads (Kahn)."""
    waiting = {n: sum(1 for i, _ in incoming.get(n, ()) if i in required) for n in required}
    readers: dict[int, list] = {}
    for n in required:
        for i, _ in incoming.get(n, ()):
            if i in required:
                readers.setdefault(i, []).append(n)
    ready = sorted(n for n, k in waiting.items() if k == 0)
    order = []
    while ready:
        n = ready.pop()
        order.append(n)
        for r in readers.get(n, ()):
            waiting[r] -= 1
            if waiting[r] == 0:
                ready.append(r)
    if len(order) != len(required):
        raise ValueError("the genome's enabled connections form a cycle: not a feed-forward network")
    return order


class NEATBackend(Backend):
    genome_type = FastGenome  # neat.DefaultGenome gives the same runs, slower
    species_set_type = FastSpeciesSet  # neat.DefaultSpeciesSet likewise
    reproduction_type = FastReproduction  # neat.DefaultReproduction likewise

    def __init__(self, problem, config):
        super().__init__(problem, config)
        enc = problem.encoding
        self.params = neat_parameters(config)
        self._compiled: dict[int, tuple] = {}  # genome key -> genome_program
        self.neat_config = make_neat_config(enc.n_inputs, enc.n_outputs, config.population, config.hidden,
                                            config.seed, self.params, self.genome_type, self.species_set_type,
                                            self.reproduction_type)
        with _RANDOM_LOCK:
            saved = random.getstate()
            self.population = neat.Population(self.neat_config, seed=config.seed)
            self._fit_species()
            self._random_state = random.getstate()
            random.setstate(saved)

    @classmethod
    def settings(cls, problem, config) -> dict:
        return {**neat_parameters(config), "initial_hidden": config.hidden, "pop_size": config.population,
                "activation": "tanh", "neat-python": getattr(neat, "__version__", "2.0")}

    def _step(self) -> StepResult:
        with _RANDOM_LOCK:
            saved = random.getstate()
            random.setstate(self._random_state)
            try:
                result = self._generation()
            finally:
                self._random_state = random.getstate()
                random.setstate(saved)
        return result

    def _generation(self) -> StepResult:
        """One pass of neat.Population.run's loop, with a batched fitness evaluation."""
        pop = self.population
        genomes = list(pop.population.values())
        enc = self.problem.encoding
        # genomes are never changed once made, and elites live on: compile each genome once
        cache = {g.key: self._compiled.get(g.key) or genome_program(g, self.neat_config) for g in genomes}
        self._compiled = cache
        programs = [cache[g.key] for g in genomes]
        compiled = compile_genomes(programs)
        mse = self.problem.program_mse(compiled)
        for g, m in zip(genomes, mse.tolist()):
            g.fitness = -m if math.isfinite(m) else BAD_FITNESS
        if self._after_evaluation(genomes, mse):  # a subclass changed genomes (their fitness with them)
            programs = [cache[g.key] for g in genomes]
            compiled = compile_genomes(programs)
        i = int(np.argmin(mse))
        self._offer(mse[i], lambda: genome_to_controller(genomes[i], self.neat_config, enc))
        best = genomes[i]
        self._evaluated = (genomes, dict(pop.species.genome_to_species), compiled)
        pop.reporters.post_evaluate(pop.config, pop.population, pop.species, best)
        if pop.best_genome is None or best.fitness > pop.best_genome.fitness:
            pop.best_genome = best
        extras = {
            "species": len(pop.species.species),
            "nodes": len(best.nodes), "connections": sum(c.enabled for c in best.connections.values()),
            "hidden": program_hidden(programs[i]),
            # for the live plot of species sizes (not a number: left out of the /search series)
            "species_sizes": {int(k): len(s.members) for k, s in pop.species.species.items()},
        }
        pop.population = self._reproduce()
        if not pop.species.species:  # complete extinction: start afresh (reset_on_extinction)
            pop.population = pop.reproduction.create_new(pop.config.genome_type, pop.config.genome_config,
                                                         pop.config.pop_size)
        pop.species.speciate(pop.config, pop.population, pop.generation)
        self._fit_species()
        pop.generation += 1
        return StepResult(mse, extras)

    def _after_evaluation(self, genomes: list, mse: np.ndarray) -> bool:
        """Between a generation's evaluation and its reproduction: a subclass may change genomes (their
        weights, their fitness, mse in place, self._compiled[key]); returns whether it did. NEAT: no."""
        return False

    keeps_candidates = True

    def _candidate_controllers(self):
        genomes, _species, _compiled = self._evaluated
        return [genome_to_controller(g, self.neat_config, self.problem.encoding, record=False) for g in genomes]

    def _candidate_species(self):
        genomes, species_of, _compiled = self._evaluated
        return [species_of.get(g.key, -1) for g in genomes]

    def _candidate_joints(self, goals):
        """From the arrays the generation was evaluated with (no controller built)."""
        enc = self.problem.encoding
        a = run_programs(self._evaluated[2], enc.inputs(goals))  # (n, goals, nq)
        return enc.joints(a, goals)

    def _reproduce(self) -> dict:
        """neat-python's reproduce; it can fail to fit spawn counts to a small population
        ("Internal error adjusting spawn counts"): then re-speciate coarser and try again."""
        pop = self.population
        for attempt in range(4):
            try:
                return pop.reproduction.reproduce(pop.config, pop.species, pop.config.pop_size, pop.generation)
            except RuntimeError:
                if attempt == 3:
                    raise
                pop.config.species_set_config.compatibility_threshold *= 1.5
                pop.species.species = {}
                pop.species.speciate(pop.config, pop.population, pop.generation)

    def _fit_species(self) -> None:
        """Steer the compatibility threshold toward TARGET_SPECIES species (Stanley's dynamic
        threshold), and re-speciate at once when there are too many species for neat-python's
        per-species minimum (pop_size >= species x min_species_size), which it would refuse."""
        pop = self.population
        ss = pop.config.species_set_config
        n = len(pop.species.species)
        ss.compatibility_threshold *= 1.1 if n > TARGET_SPECIES else (0.97 if n < TARGET_SPECIES else 1.0)
        ss.compatibility_threshold = max(ss.compatibility_threshold, 0.3)
        limit = pop.config.pop_size // pop.config.reproduction_config.min_species_size
        while len(pop.species.species) > limit:  # every old species keeps a member: start afresh
            ss.compatibility_threshold *= 1.5
            pop.species.species = {}
            pop.species.speciate(pop.config, pop.population, pop.generation)


def reference_loop(config, problem, generations: int) -> float:
    """Seconds of neat-python's own Population.run with the same configuration, its own
    DefaultGenome and DefaultSpeciesSet, and a trivial fitness (uniform random numbers, so that
    selection and speciation have work to do, as in a real run); benchmarks/bench_speed.py."""
    enc = problem.encoding
    cfg = make_neat_config(enc.n_inputs, enc.n_outputs, config.population, config.hidden, config.seed,
                           neat_parameters(config), genome_type=neat.DefaultGenome,
                           species_set_type=neat.DefaultSpeciesSet)
    saved = random.getstate()
    pop = neat.Population(cfg, seed=config.seed)
    rng = np.random.default_rng(config.seed)

    def trivial(genomes, _config):
        for (_, g), f in zip(genomes, rng.random(len(genomes)).tolist()):
            g.fitness = f

    t = time.perf_counter()
    stdout, sys.stdout = sys.stdout, open(os.devnull, "w")  # its closing "meets fitness threshold" line
    try:
        pop.run(trivial, generations)
    finally:
        sys.stdout.close()
        sys.stdout = stdout
        random.setstate(saved)
    return time.perf_counter() - t


# NEAT's defaults (benchmarks/bench_quality.py; docs/results/paper-budget.md, the figures in docs/log.md):
# "polar" inputs and a small margin; it loses with the slack-of-reach input and a wide margin
REAL_ARM_GENERATIONS = 8_000  # a real arm's budget: about 5 minutes of a population of 100 on one core


def defaults(arm) -> dict:
    """The settings NEAT runs with on an arm when none are given (the comparisons behind them:
    docs/results/paper-budget.md, docs/results/budgets.md; their figures: docs/log.md).

    The paper's arms, the snakes and the trees: polar inputs, output margin 0.5, no hidden node at first;
    on a tree, each limb that moves one effector alone turned in closed form (as every method's trees:
    the comparison in docs/log.md).
    A real arm: the real-arm inputs and output mapping every method shares (real_arm_io: the first
    joint turned in closed form), 300 goals, a population of 100, weight perturbations of 0.1 and
    structural mutations 25-50 times the paper's (add node 0.05, add connection 0.1), so that
    networks grow within minutes, from no hidden node; REAL_ARM_GENERATIONS generations."""
    if arm_kind(arm) == "tree":  # and each limb that moves one effector alone turned, as every method's trees
        return dict(features="polar", margin=0.5, hidden=0, turn=True)
    if arm_kind(arm) != "real":  # the paper's arms and the snakes
        return dict(features="polar", margin=0.5, hidden=0)
    return dict(real_arm_io(arm), hidden=0, targets=300, population=100, generations=REAL_ARM_GENERATIONS,
                mutation_power=0.1, add_node=0.05, add_connection=0.1)


def budget_defaults(arm, seconds: float) -> dict:
    """With a time budget: defaults(arm) without its generations."""
    return {k: v for k, v in defaults(arm).items() if k != "generations"}


def pose_defaults(arm, seconds: float | None) -> dict:
    """Pose goals (TrainConfig.goal "pose", a real arm): the real-arm inputs and output mapping every
    method shares (real_arm_io: the first joint turned toward the position's bearing), over defaults_for's."""
    return dict(real_arm_io(arm))


METHOD = register(Method(
    name="neat", label="NEAT", color=(214, 39, 40),
    summary="NEAT (neat-python): topology and weights evolved together",
    backend_class=NEATBackend, options=NEATOptions, controller="graph",
    defaults=defaults, budget_defaults=budget_defaults, pose_defaults=pose_defaults,
    # the paper's parameters (section 4.3); NEAT starts with the inputs wired to the outputs
    paper=dict(features="cartesian", margin=0.0, hidden=0, mutation_power=1.0, add_node=0.002, add_connection=0.002),
    min_population=2, min_hidden=0,
    search_title="NEAT species and best network size",
    search_series="number of species, nodes and enabled connections of the best genome",
    class_generations=1000,  # a student's default run on a paper arm (docs/results/class.md)
    cost=6.0, compile_seconds=(7.0, 4.5), ablations=("mutation_power=1.0", "margin=0.0", "features=reach"),
    reference=SpeedReference("neat-python Population.run, random fitness", 1.5, reference_loop),
    live_plots=(
        LivePlot("species_sizes", "NEAT species sizes", kind="stacked", about=(
            "Each band is one species, its height the number of genomes in it, stacked to the population "
            "size (neat-python's plot_species, drawn live). Bands appear when a new structure is "
            "different enough to found a species, and end when a species stagnates and is removed.")),
    ),
))
