"""FastGenome (lab/backends/neat_genome.py) is neat-python's DefaultGenome bit for bit: the same
genomes, species, distances and random state, generation after generation."""

import copy
import os
import pickle
import random
import re
import tempfile
import warnings

import neat
import numpy as np
import pytest

import lab
from lab.backends.neat import PAPER_NEAT, NEATBackend, make_neat_config, neat_config_text, textbook_tanh
from lab.backends.neat_genome import FastConnectionGene, FastGenome, FastNodeGene
from lab.runner import build_problem

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


def neat_config(genome_type, variant, pop_size=50, seed=11):
    text = neat_config_text(4, 3, pop_size, 0, seed, STRUCTURAL, genome_type.__name__)
    for key, value in VARIANTS[variant].items():
        line = f"{key} = {value}"
        text, n = re.subn(rf"^{key}\s*=.*$", line, text, flags=re.M)
        if n == 0:  # not in the project's text: add it to the genome section
            text = text.replace(f"[{genome_type.__name__}]\n", f"[{genome_type.__name__}]\n{line}\n")
    fd, path = tempfile.mkstemp(suffix=".ini")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        config = neat.Config(genome_type, neat.DefaultReproduction, neat.DefaultSpeciesSet,
                             neat.DefaultStagnation, path)
    finally:
        os.unlink(path)
    config.genome_config.add_activation("tanh_", textbook_tanh)
    return config


def snapshot(genome):
    """Everything a genome holds, in its dicts' order (floats compared exactly by ==)."""
    return (genome.key,
            [(k, n.key, n.bias, n.response, n.activation, n.aggregation, n.time_constant)
             for k, n in genome.nodes.items()],
            [(k, c.key, c.innovation, c.weight, c.enabled, type(c.enabled))
             for k, c in genome.connections.items()])


def evolve(genome_type, variant, fitness, generations):
    """neat-python's own Population.run; per generation: every genome, the species, and the
    genome type's distances between genomes."""
    saved = random.getstate()
    config = neat_config(genome_type, variant)
    pop = neat.Population(config, seed=5)
    rng = np.random.default_rng(3)
    record = []

    def evaluate(genomes, cfg):
        gs = [g for _, g in genomes]
        assert all(type(g) is genome_type for g in gs)
        if genome_type is FastGenome:  # crossover's cycle test is skipped for every feed-forward parent
            assert all((g._acyclic_at == len(g.connections)) == cfg.genome_config.feed_forward for g in gs)
        distances = [a.distance(b, cfg.genome_config) for k in (1, 2, 7) for a, b in zip(gs, gs[k:] + gs[:k])]
        record.append(([snapshot(g) for g in gs], dict(pop.species.genome_to_species),
                       {sid: s.representative.key for sid, s in pop.species.species.items()}, distances))
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
               next(pop.reproduction.genome_indexer))
    finally:
        random.setstate(saved)
    return record, end


@pytest.mark.parametrize("fitness", ["random", "genome"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_fast_genome_evolves_exactly_as_default_genome(variant, fitness):
    generations = 60
    expected, expected_end = evolve(neat.DefaultGenome, variant, fitness, generations)
    got, got_end = evolve(FastGenome, variant, fitness, generations)
    assert len(got) == len(expected)
    for gen, (a, b) in enumerate(zip(got, expected)):
        assert a == b, f"generation {gen} differs"
    assert got_end == expected_end
    # the runs exercised what they should: structure grew, genes were disabled
    last = expected[-1][0] if expected[-1][0] != "error" else expected[-2][0]
    assert max(len(nodes) for _, nodes, _ in last) >= 5
    assert any(not c[4] for _, _, conns in last for c in conns)
    assert len(expected) >= generations // 2


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


def test_crossover_tests_cycles_for_parents_not_known_acyclic():
    config = neat_config(FastGenome, "project")
    gc = config.genome_config
    state = random.getstate()
    try:
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
    finally:
        random.setstate(state)


def test_crossover_warns_on_innovation_collisions_as_neat_does():
    config = neat_config(FastGenome, "project")
    gc = config.genome_config
    state = random.getstate()
    try:
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
    finally:
        random.setstate(state)


def test_fast_genes_mutate_as_neat_genes_and_copy_pickle():
    config = neat_config(FastGenome, "deletions")
    gc = config.genome_config
    state = random.getstate()
    try:
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
    finally:
        random.setstate(state)


def test_neat_backend_runs_as_with_default_genome(monkeypatch):
    cfg = lab.TrainConfig(method="neat", population=30, generations=40, targets=30, test_goals=50, seed=2,
                          add_node=0.2, add_connection=0.3, hidden=1)

    def run():
        b = NEATBackend(build_problem(cfg), cfg)
        steps = [b.step() for _ in range(cfg.generations)]
        return ([r.fitness.tolist() for r in steps], [r.extras for r in steps],
                [snapshot(g) for g in b.population.population.values()], b.best.to_dict(),
                b._random_state, b.population.species.genome_to_species)

    fast = run()
    monkeypatch.setattr(NEATBackend, "genome_type", neat.DefaultGenome)
    default = run()
    assert fast == default
    assert max(len(nodes) for _, nodes, _ in fast[2]) >= 5


def test_make_neat_config_builds_either_genome():
    fast = make_neat_config(3, 2, 10, 0, 1)
    default = make_neat_config(3, 2, 10, 0, 1, genome_type=neat.DefaultGenome)
    assert fast.genome_type is FastGenome and default.genome_type is neat.DefaultGenome
    assert fast.genome_config.connection_gene_type is FastConnectionGene
    assert vars(fast.genome_config).keys() == vars(default.genome_config).keys()
    for name in ("weight_mutate_rate", "bias_max_value", "conn_add_prob", "enabled_rate_to_true_add"):
        assert getattr(fast.genome_config, name) == getattr(default.genome_config, name)
