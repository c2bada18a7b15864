"""FastGenome (lab/methods/neat_genome.py) is neat-python's DefaultGenome and FastSpeciesSet
(lab/methods/neat_species.py) its DefaultSpeciesSet, bit for bit: the same genomes, species,
distances and random state, generation after generation."""

import copy
import functools
import itertools
import pickle
import random
import re
import warnings

import neat
import numpy as np
import pytest

import lab
from lab.methods.neat import PAPER_NEAT, NEATBackend, config_from_text, make_neat_config, neat_config_text
from lab.methods.neat_genome import FastConnectionGene, FastGenome, FastNodeGene, FastReproduction
from lab.methods.neat_species import FastSpeciesSet
from lab.running.runner import build_problem

STRUCTURAL = dict(PAPER_NEAT, node_add_prob=0.2, conn_add_prob=0.3, weight_mutate_power=0.5)

# neat-python settings beyond the project's config: deletions, re-enabling and disabling, value
# replacement, string mutations, single structural mutations, other initial connections, recurrence
VARIANTS = {
    "project": {},
    "deletions": dict(node_delete_prob=0.05, conn_delete_prob=0.08, enabled_mutate_rate=0.05,
                      enabled_rate_to_false_add=0.02, bias_replace_rate=0.05, weight_replace_rate=0.02,
                      response_mutate_rate=0.2, response_mutate_power=0.1, response_min_value=0.5,
                      response_max_value=2.0, time_constant_mutate_rate=0.3, time_constant_mutate_power=0.2,
                      activation_options="tanh_ sigmoid", activation_mutate_rate=0.1,
                      aggregation_options="sum product", aggregation_mutate_rate=0.1, num_hidden=2,
                      initial_connection="partial_direct 0.6"),
    "single": dict(single_structural_mutation=True, structural_mutation_surer="true",
                   initial_connection="unconnected", conn_delete_prob=0.1, node_delete_prob=0.05,
                   bias_init_type="uniform", weight_init_type="uniform", weight_min_value=-1.0,
                   weight_max_value=1.0, bias_min_value=-1.5, bias_max_value=1.5, activation_default="random",
                   activation_options="tanh_ relu", enabled_default="random"),
    "recurrent": dict(feed_forward=False, initial_connection="full_nodirect", num_hidden=1,
                      conn_delete_prob=0.05),
}
# many species (3 to 12 at a time, about 40 over a run), stagnant ones removed
VARIANTS["species"] = dict(VARIANTS["deletions"], weight_mutate_power=3.0, compatibility_threshold=3.0,
                           max_stagnation=6, species_elitism=1)
DEFAULT_TYPES = (neat.DefaultGenome, neat.DefaultSpeciesSet, neat.DefaultReproduction)
FAST_TYPES = (FastGenome, FastSpeciesSet, FastReproduction)


def neat_config(genome_type, variant, pop_size=50, seed=11, species_set_type=neat.DefaultSpeciesSet,
                reproduction_type=neat.DefaultReproduction):
    text = neat_config_text(4, 3, pop_size, 0, seed, STRUCTURAL, genome_type.__name__, species_set_type.__name__,
                            reproduction_type.__name__)
    for key, value in VARIANTS[variant].items():
        line = f"{key} = {value}"
        text, n = re.subn(rf"^{key}\s*=.*$", line, text, flags=re.M)
        if n == 0:  # not in the project's text: add it to the genome section
            text = text.replace(f"[{genome_type.__name__}]\n", f"[{genome_type.__name__}]\n{line}\n")
    return config_from_text(text, genome_type, species_set_type, reproduction_type)


class InfoLog(neat.reporting.BaseReporter):
    """neat's info lines (speciation reports the mean and deviation of the distances it computed)."""

    def __init__(self):
        self.lines = []

    def info(self, msg):
        self.lines.append(msg)


def species_snapshot(species_set):
    """Species in their dict order: representative, members in order, creation, improvement; and
    genome_to_species in its order."""
    return ([(sid, s.representative.key, list(s.members), s.created, s.last_improved, s.fitness_history)
             for sid, s in species_set.species.items()], list(species_set.genome_to_species.items()))


def snapshot(genome):
    """Everything a genome holds, in its dicts' order (floats compared exactly by ==)."""
    return (genome.key,
            [(k, n.key, n.bias, n.response, n.activation, n.aggregation, n.time_constant)
             for k, n in genome.nodes.items()],
            [(k, c.key, c.innovation, c.weight, c.enabled, type(c.enabled))
             for k, c in genome.connections.items()])


def evolve(genome_type, species_set_type, reproduction_type, variant, fitness, generations):
    """neat-python's own Population.run; per generation: every genome, the species, the genome
    type's distances between genomes, and neat's info lines."""
    saved = random.getstate()
    config = neat_config(genome_type, variant, species_set_type=species_set_type, reproduction_type=reproduction_type)
    pop = neat.Population(config, seed=5)
    assert type(pop.species) is species_set_type and type(pop.reproduction) is reproduction_type
    log = InfoLog()
    pop.add_reporter(log)
    rng = np.random.default_rng(3)
    record = [species_snapshot(pop.species)]

    def evaluate(genomes, cfg):
        gs = [g for _, g in genomes]
        assert all(type(g) is genome_type for g in gs)
        if genome_type is FastGenome:  # crossover's cycle test is skipped for every feed-forward parent
            assert all((g._acyclic_at == len(g.connections)) == cfg.genome_config.feed_forward for g in gs)
        distances = [a.distance(b, cfg.genome_config) for k in (1, 2, 7) for a, b in zip(gs, gs[k:] + gs[:k])]
        record.append(([snapshot(g) for g in gs], species_snapshot(pop.species), distances, log.lines[:]))
        log.lines.clear()
        if fitness == "random":
            values = rng.random(len(gs)).tolist()
        else:  # a function of the genome: rewards enabled weight and bias, penalises size
            values = [sum(c.weight for c in g.connections.values() if c.enabled)
                      + 0.5 * sum(n.bias for n in g.nodes.values()) - 0.05 * len(g.connections) for g in gs]
        for g, f in zip(gs, values):
            g.fitness = f

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # neat's "will not connect to hidden nodes" and the like
            for _ in range(generations):
                try:
                    pop.run(evaluate, 1)
                except RuntimeError as e:  # neat's spawn adjustment can give up: so must the other
                    record.append(("error", str(e)))
                    break
        tracker = pop.reproduction.innovation_tracker
        end = (random.getstate(), tracker.global_counter, next(config.genome_config.node_indexer),
               next(pop.reproduction.genome_indexer), next(pop.species.indexer), species_snapshot(pop.species),
               [snapshot(g) for g in pop.population.values()], log.lines)
    finally:
        random.setstate(saved)
    return record, end


GENERATIONS = 60


@functools.lru_cache(maxsize=None)
def neat_run(variant, fitness):
    """The run with neat-python's own DefaultGenome and DefaultSpeciesSet."""
    return evolve(*DEFAULT_TYPES, variant, fitness, GENERATIONS)


@pytest.mark.parametrize("fitness", ["random", "genome"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_fast_types_evolve_exactly_as_neat_types(variant, fitness, compiled_only):
    """FastGenome, FastSpeciesSet and FastReproduction against DefaultGenome, DefaultSpeciesSet and
    DefaultReproduction."""
    expected, expected_end = neat_run(variant, fitness)
    got, got_end = evolve(*FAST_TYPES, variant, fitness, GENERATIONS)
    assert len(got) == len(expected)
    for gen, (a, b) in enumerate(zip(got, expected)):
        assert a == b, f"generation {gen} differs"
    assert got_end == expected_end
    # the runs exercised what they should: structure grew, genes were disabled, speciation reported
    last = expected[-1][0] if expected[-1][0] != "error" else expected[-2][0]
    assert max(len(nodes) for _, nodes, _ in last) >= 5
    assert any(not c[4] for _, _, conns in last for c in conns)
    assert len(expected) >= GENERATIONS // 2
    assert all(any(line.startswith("Mean genetic distance") for line in r[3]) for r in expected[2:] if r[0] != "error")
    if variant == "species":  # many species made, some removed as stagnant
        assert expected_end[4] > 20 and max(len(r[1][0]) for r in expected[1:]) >= 10


def fresh_genome(config, key, connections, nodes=(0, 1, 2, 5, 6), innovations=None):
    """A hand-built FastGenome (neat-python would not make a cycle such as 5 -> 6 -> 5);
    innovation numbers by key, or from innovations (key -> number)."""
    gc = config.genome_config
    g = FastGenome(key)
    for k in nodes:
        g.nodes[k] = g.create_node(gc, k)
    for n, (i, o) in enumerate(connections):
        innovation = (innovations or {}).get((i, o), 100 + 10 * i + o)
        g.add_connection(gc, i, o, 0.1 * n - 0.3, n % 3 != 0, innovation=innovation)
    return g


def test_crossover_tests_cycles_for_parents_not_known_acyclic(keep_random_state):
    config = neat_config(FastGenome, "project")
    gc = config.genome_config
    random.seed(1)
    p1 = fresh_genome(config, 1, [(-1, 5), (5, 6), (6, 5), (6, 0), (-2, 6), (5, 1)])
    p2 = fresh_genome(config, 2, [(-1, 5), (5, 6), (6, 0), (-3, 2)])
    p1.fitness, p2.fitness = 1.0, 0.5
    assert p1._acyclic_at == -1  # add_connection does not check
    children = []
    for method in (neat.DefaultGenome.configure_crossover, FastGenome.configure_crossover):
        random.seed(2)
        child = FastGenome(3)
        method(child, p1, p2, gc)
        children.append((snapshot(child), random.getstate()))
    assert children[0] == children[1]
    keys = {k for k, *_ in children[1][0][2]}
    assert len(keys & {(5, 6), (6, 5)}) == 1  # the cycle was cut


def test_crossover_warns_on_innovation_collisions_as_neat_does(keep_random_state):
    config = neat_config(FastGenome, "project")
    gc = config.genome_config
    random.seed(1)
    p1 = fresh_genome(config, 1, [(-1, 5), (5, 0), (-2, 1)], innovations={(5, 0): 7})
    p2 = fresh_genome(config, 2, [(-1, 5), (-3, 2), (-2, 1)], innovations={(-3, 2): 7})
    p1.fitness, p2.fitness = 0.5, 1.0
    p2._acyclic_at = len(p2.connections)
    children = []
    for method in (neat.DefaultGenome.configure_crossover, FastGenome.configure_crossover):
        random.seed(3)
        child = FastGenome(3)
        with pytest.warns(RuntimeWarning, match="Innovation number collision"):
            method(child, p1, p2, gc)
        children.append((snapshot(child), random.getstate()))
    assert children[0] == children[1]


def test_fast_genes_mutate_as_neat_genes_and_copy_pickle(keep_random_state):
    config = neat_config(FastGenome, "deletions")
    gc = config.genome_config
    random.seed(4)
    gc.innovation_tracker = neat.innovation.InnovationTracker()
    g = FastGenome(1)
    g.configure_new(gc)
    for _ in range(30):
        g.mutate(gc)
    assert isinstance(g.nodes[0], FastNodeGene)
    assert isinstance(next(iter(g.connections.values())), FastConnectionGene)
    results = []
    for node_mutate, conn_mutate in ((neat.DefaultNodeGene.mutate, neat.DefaultConnectionGene.mutate),
                                     (FastNodeGene.mutate, FastConnectionGene.mutate)):
        h = copy.deepcopy(g)
        random.seed(5)
        for _ in range(50):
            for n in h.nodes.values():
                node_mutate(n, gc)
            for c in h.connections.values():
                conn_mutate(c, gc)
        results.append((snapshot(h), random.getstate()))
    assert results[0] == results[1]
    again = pickle.loads(pickle.dumps(g))
    assert snapshot(again) == snapshot(g) and again._acyclic_at == g._acyclic_at
    assert vars(g.nodes[0]) == {} and vars(next(iter(g.connections.values()))) == {}  # all in slots


def test_neat_backend_runs_as_with_neat_types(monkeypatch, compiled_only):
    cfg = lab.TrainConfig(method="neat", population=30, generations=40, targets=30, test_goals=50, seed=2,
                          add_node=0.2, add_connection=0.3, hidden=1, mutation_power=1.0)

    def run():
        b = NEATBackend(build_problem(cfg), cfg)
        steps = [b.step() for _ in range(cfg.generations)]
        return ([r.fitness.tolist() for r in steps], [r.extras for r in steps],
                [snapshot(g) for g in b.population.population.values()], b.best.to_dict(),
                b._random_state, species_snapshot(b.population.species),
                b.population.config.species_set_config.compatibility_threshold)

    fast = run()
    assert (NEATBackend.genome_type, NEATBackend.species_set_type, NEATBackend.reproduction_type) == FAST_TYPES
    monkeypatch.setattr(NEATBackend, "genome_type", neat.DefaultGenome)
    monkeypatch.setattr(NEATBackend, "species_set_type", neat.DefaultSpeciesSet)
    monkeypatch.setattr(NEATBackend, "reproduction_type", neat.DefaultReproduction)
    default = run()
    assert fast == default
    assert max(len(nodes) for _, nodes, _ in fast[2]) >= 5
    assert max(e["species"] for e in fast[1]) >= 4


def test_make_neat_config_builds_either_type():
    fast = make_neat_config(3, 2, 10, 0, 1)
    default = make_neat_config(3, 2, 10, 0, 1, genome_type=neat.DefaultGenome,
                               species_set_type=neat.DefaultSpeciesSet, reproduction_type=neat.DefaultReproduction)
    assert fast.genome_type is FastGenome and default.genome_type is neat.DefaultGenome
    assert fast.species_set_type is FastSpeciesSet and default.species_set_type is neat.DefaultSpeciesSet
    assert fast.reproduction_type is FastReproduction and default.reproduction_type is neat.DefaultReproduction
    for name in ("elitism", "survival_threshold", "min_species_size"):
        assert getattr(fast.reproduction_config, name) == getattr(default.reproduction_config, name)
    assert fast.genome_config.connection_gene_type is FastConnectionGene
    assert vars(fast.genome_config).keys() == vars(default.genome_config).keys()
    for name in ("weight_mutate_rate", "bias_max_value", "conn_add_prob", "enabled_rate_to_true_add"):
        assert getattr(fast.genome_config, name) == getattr(default.genome_config, name)
    assert fast.species_set_config.compatibility_threshold == default.species_set_config.compatibility_threshold == 3.0


class RecordingSpeciesSet(neat.DefaultSpeciesSet):
    """neat's species set, keeping a copy of what each speciate call started from."""

    cases = []

    def speciate(self, config, population, generation):
        RecordingSpeciesSet.cases.append(pickle.dumps((population, self.species, generation)))
        super().speciate(config, population, generation)


@pytest.fixture
def compiled_only(monkeypatch):
    """FastSpeciesSet must not hand a call to neat's speciate (it does for what it does not model)."""
    neat_speciate = neat.DefaultSpeciesSet.speciate

    def speciate(self, *args):
        assert not isinstance(self, FastSpeciesSet), "FastSpeciesSet fell back to neat's speciate"
        return neat_speciate(self, *args)

    monkeypatch.setattr(neat.DefaultSpeciesSet, "speciate", speciate)


@functools.lru_cache(maxsize=None)
def speciation_cases():
    """config and (population, old species, generation), pickled, at every speciate call of a run with
    many species, old representatives shared with the population where neat shares them (elites)."""
    RecordingSpeciesSet.cases = []
    saved = random.getstate()
    try:
        config = neat_config(FastGenome, "species", seed=7, species_set_type=RecordingSpeciesSet)
        pop = neat.Population(config, seed=9)
        rng = np.random.default_rng(4)

        def evaluate(genomes, cfg):
            for (_, g), f in zip(genomes, rng.random(len(genomes)).tolist()):
                g.fitness = f

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pop.run(evaluate, 40)
    finally:
        random.setstate(saved)
    return config, RecordingSpeciesSet.cases


def speciate_with(species_set_type, config, case, threshold, again=False):
    """One speciate call (two with again: the second re-speciates the population it just speciated,
    every old representative a member); the species, new ids, info lines and the distances cached
    (in the cache's order, as speciate hands them to mean()), or the error raised."""
    import lab.methods.neat_species as fast_module
    import neat.species as neat_module

    cached = []

    def mean(values):
        cached.append(list(values))
        return neat.math_util.mean(values)

    population, species, generation = pickle.loads(case)
    ss_config = copy.copy(config.species_set_config)
    ss_config.compatibility_threshold = threshold
    reporters = neat.reporting.ReporterSet()
    log = InfoLog()
    reporters.add(log)
    ss = species_set_type(ss_config, reporters)
    ss.species = species
    ss.indexer = itertools.count(1000)
    fast_module.mean = neat_module.mean = mean
    try:
        for _ in range(2 if again else 1):
            ss.speciate(config, population, generation)
    except Exception as e:  # noqa: BLE001
        return type(e), str(e)
    finally:
        fast_module.mean = neat_module.mean = neat.math_util.mean
    assert len(cached) == (2 if again else 1)
    return species_snapshot(ss), next(ss.indexer), log.lines, cached


def test_fast_species_set_speciates_as_neat(compiled_only):
    config, cases = speciation_cases()
    shared = 0
    for n, case in enumerate(cases):
        population, species, _ = pickle.loads(case)
        shared += sum(population.get(s.representative.key) is s.representative for s in species.values())
        for threshold in (0.7, 2.0, 3.0, 5.0)[n % 2::2]:
            for again in (False, True):
                expected = speciate_with(neat.DefaultSpeciesSet, config, case, threshold, again)
                assert speciate_with(FastSpeciesSet, config, case, threshold, again) == expected, (n, threshold)
    assert len(cases) > 30 and shared > 100  # old representatives among the genomes speciated (elites)


def test_compiled_distances_are_neats():
    """Every ordered pair, bit for bit (where genes sit in different orders, a.distance(b) and
    b.distance(a) can differ in the last bits: the data has such pairs)."""
    from lab.methods.neat_species import _distance, _flatten

    config, cases = speciation_cases()
    gc = config.genome_config
    asymmetric = 0
    for case in cases[::4]:
        genomes = list(pickle.loads(case)[0].values())
        arrays = _flatten(genomes)
        c_pos, n_pos = np.full(arrays[-2], -1), np.full(arrays[-1], -1)
        for i, a in enumerate(genomes):
            for j, b in enumerate(genomes):
                d = neat.DefaultGenome.distance(a, b, gc)
                assert _distance(i, j, *arrays[:-2], gc.compatibility_weight_coefficient,
                                 gc.compatibility_disjoint_coefficient, c_pos, n_pos) == d
                asymmetric += d != neat.DefaultGenome.distance(b, a, gc)
        assert (c_pos == -1).all() and (n_pos == -1).all()
    assert asymmetric > 100


def test_fast_species_set_takes_the_first_of_equal_distances(compiled_only):
    """Clones (the same genes under another key) tie: min() keeps the first candidate."""
    config, cases = speciation_cases()
    population, species, generation = pickle.loads(cases[25])
    keys = sorted(population)
    x = population[keys[3]]
    clone = copy.deepcopy(x)
    clone.key = keys[-1] + 1
    population[clone.key] = clone
    sids = sorted(species)[:2]
    species = {sid: species[sid] for sid in sids}
    for n, sid in enumerate(sids):  # two old species, represented by further clones of x
        rep = copy.deepcopy(x)
        rep.key = keys[-1] + 2 + n
        species[sid].representative = rep
    case = pickle.dumps((population, species, generation))
    expected = speciate_with(neat.DefaultSpeciesSet, config, case, 100.0)
    assert speciate_with(FastSpeciesSet, config, case, 100.0) == expected
    members = {sid: m for sid, _, m, *_ in expected[0][0]}
    assert members[sids[0]][0] == x.key and members[sids[1]] == [clone.key]  # the first, then the next
    assert len(members[sids[0]]) == len(population) - 1  # the first of the tied representatives


class OtherDistance(FastGenome):
    calls = 0

    def distance(self, other, config):
        OtherDistance.calls += 1
        return 2.0 * super().distance(other, config)


def test_fast_species_set_falls_back_to_neat_where_it_does_not_model_the_distance():
    config, cases = speciation_cases()
    population, species, generation = pickle.loads(cases[20])
    for g in list(population.values()) + [s.representative for s in species.values()]:
        g.__class__ = OtherDistance
    case = pickle.dumps((population, species, generation))
    expected = speciate_with(neat.DefaultSpeciesSet, config, case, 3.0)
    assert OtherDistance.calls
    assert speciate_with(FastSpeciesSet, config, case, 3.0) == expected

    # values that are not the floats and bools neat makes (all of a kind, as a genome type would make them)
    population, species, generation = pickle.loads(cases[20])
    for g in list(population.values()) + [s.representative for s in species.values()]:
        for c in g.connections.values():
            c.weight = np.float32(c.weight)
    odd = pickle.dumps((population, species, generation))
    assert speciate_with(FastSpeciesSet, config, odd, 3.0) == speciate_with(neat.DefaultSpeciesSet, config, odd, 3.0)

    # more old species than genomes: neat's min() of nothing
    population, species, generation = pickle.loads(cases[20])
    assert len(species) > 2
    few = pickle.dumps((dict(list(population.items())[:2]), species, generation))
    expected = speciate_with(neat.DefaultSpeciesSet, config, few, 3.0)
    assert expected[0] is ValueError
    assert speciate_with(FastSpeciesSet, config, few, 3.0) == expected
