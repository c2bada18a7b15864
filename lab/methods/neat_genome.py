"""FastGenome: neat-python 2.0's DefaultGenome, bit for bit, without its per-gene overhead.

neat-python spends most of a generation in pure-Python genome code: speciation's distance,
crossover (a method call, hasattr checks and asserts per gene, and a quadratic cycle test for
every inherited connection) and mutation (every attribute of every gene reads its rates from
the config by name). FastGenome does the same work with the config values read once per
genome and the per-gene loops written out. It is a drop-in for neat.DefaultGenome (section
[FastGenome] in the config file) and produces the very same genomes:

- the same calls to the global `random` module in the same order (random(), gauss(),
  choice(), uniform() ...), so a run leaves the same random state behind;
- the same genes in the same dict order (crossover walks the same set of innovation
  numbers, built the same way, so in the same iteration order);
- the same floating-point operations in the same order (distance sums gene by gene in the
  genome's order, as neat does; clamps are min/max written as the comparisons they make).

Rare paths (replacing a value by a fresh draw, a string option mutation, new genes from
configure_new or structural mutations) call neat-python's own attribute code.

Crossover's cycle test: every connection a child inherits has a key of parent1 (the fitter
parent), so when parent1's connection keys are acyclic the child's are a subset, and neat's
creates_cycle can never fire. FastGenome records that knowledge as `_acyclic_at`: the number
of connections the genome had when its key set was last known acyclic (-1: not known). Under
feed_forward every way neat-python makes or changes a genome keeps the keys acyclic
(configure_new; add node splits a link; add connection checks creates_cycle; deletions and
crossover take subsets), so every FastGenome it makes carries the mark; a parent without it
(a hand-built genome, one edited by add_connection, a DefaultGenome, a genome whose connection
count changed behind FastGenome's back) gets neat's exact per-gene test instead. Code that edits
`connections` in place must go through the genome's methods or reset `_acyclic_at` to -1.

Distance has no per-genome cache: only about a quarter of the genome pairs speciation compares
share their gene order, and a cached path measured no faster than the plain loop here (speciation
is FastSpeciesSet's, neat_species.py, which computes distances compiled).

FastReproduction is neat.DefaultReproduction, unchanged, except that while its reproduce runs the
genome config carries a cache: FastGenome then builds each parent's {innovation: gene} dict and
the set of its innovations once per call rather than once per child (parents do not change while
their children are made), and reads the mutation rates from the config once. The union of the two
parents' sets is still made from two set objects, as neat makes it: `s | s` only copies s, where
the union of two equal sets resizes its table and can iterate in another order.

The gene subclasses keep their attributes in __slots__ (no per-gene dict is made); they behave
as, and are instances of, DefaultNodeGene and DefaultConnectionGene.
"""

from __future__ import annotations

import warnings
from random import choice, gauss, random

from neat.genes import DefaultConnectionGene, DefaultNodeGene
from neat.genome import DefaultGenome, DefaultGenomeConfig
from neat.graphs import creates_cycle
from neat.reproduction import DefaultReproduction

_new = object.__new__


class FastNodeGene(DefaultNodeGene):
    __slots__ = ("key", "bias", "response", "activation", "aggregation", "time_constant")

    def mutate(self, config):
        _mutate_nodes((self,), config, _node_plan(config))


class FastConnectionGene(DefaultConnectionGene):
    __slots__ = ("key", "innovation", "weight", "enabled")

    def mutate(self, config):
        _mutate_connections((self,), config, _connection_plan(config))


_NODE_ATTRS = ("bias", "response", "activation", "aggregation", "time_constant")
_CONNECTION_ATTRS = ("weight", "enabled")
assert tuple(a.name for a in DefaultNodeGene._gene_attributes) == _NODE_ATTRS
assert tuple(a.name for a in DefaultConnectionGene._gene_attributes) == _CONNECTION_ATTRS
_BIAS, _RESPONSE, _ACTIVATION, _AGGREGATION, _TIME_CONSTANT = DefaultNodeGene._gene_attributes
_WEIGHT, _ENABLED = DefaultConnectionGene._gene_attributes


def _float_plan(attr, config):
    """What FloatAttribute.mutate_value reads: (mutate rate, replace rate + mutate rate, power, min, max)."""
    mutate_rate = getattr(config, attr.mutate_rate_name)
    return (mutate_rate, getattr(config, attr.replace_rate_name) + mutate_rate,
            getattr(config, attr.mutate_power_name), getattr(config, attr.min_value_name),
            getattr(config, attr.max_value_name))


def _node_plan(config):
    return (_float_plan(_BIAS, config), _float_plan(_RESPONSE, config),
            getattr(config, _ACTIVATION.mutate_rate_name), getattr(config, _AGGREGATION.mutate_rate_name),
            _float_plan(_TIME_CONSTANT, config))


def _connection_plan(config):
    rate = getattr(config, _ENABLED.mutate_rate_name)
    # BoolAttribute.mutate_value: the rate for a True value, then for a False one
    return (_float_plan(_WEIGHT, config), rate + getattr(config, _ENABLED.rate_to_false_add_name),
            rate + getattr(config, _ENABLED.rate_to_true_add_name))


def _mutated(v, plan, attr, config):
    """FloatAttribute.mutate_value with its config values read once (plan: _float_plan)."""
    rate, replace, power, lo, hi = plan
    r = random()
    if r < rate:
        v = v + gauss(0.0, power)
        if hi < v:  # max(min(v, hi), lo), as min and max compare
            v = hi
        if lo > v:
            v = lo
        return v
    if r < replace:
        return attr.init_value(config)
    return v


def _mutate_connections(genes, config, plan):
    """Each gene's BaseGene.mutate: weight (FloatAttribute), then enabled (BoolAttribute)."""
    w_plan, e_true, e_false = plan
    for cg in genes:
        cg.weight = _mutated(cg.weight, w_plan, _WEIGHT, config)
        rate = e_true if cg.enabled else e_false
        if rate > 0:
            if random() < rate:
                cg.enabled = random() < 0.5


def _mutate_nodes(genes, config, plan):
    """Each gene's BaseGene.mutate: bias, response (floats), activation, aggregation (strings),
    time_constant (float)."""
    b_plan, r_plan, act_rate, agg_rate, t_plan = plan
    for ng in genes:
        ng.bias = _mutated(ng.bias, b_plan, _BIAS, config)
        ng.response = _mutated(ng.response, r_plan, _RESPONSE, config)
        if act_rate > 0:
            if random() < act_rate:
                ng.activation = choice(getattr(config, _ACTIVATION.options_name))
        if agg_rate > 0:
            if random() < agg_rate:
                ng.aggregation = choice(getattr(config, _AGGREGATION.options_name))
        ng.time_constant = _mutated(ng.time_constant, t_plan, _TIME_CONSTANT, config)


_REPRODUCING = "_fast_reproduction"  # genome config attribute while FastReproduction.reproduce runs
_PLANS = "plans"


def _innovations(cache: dict, parent):
    """A parent's {innovation: gene} and the set of its keys, as configure_crossover builds them,
    made once per reproduce call (parents do not change while their children are made)."""
    entry = cache.get(id(parent))
    if entry is None or entry[0] is not parent:
        innovations = {cg.innovation: cg for cg in parent.connections.values()}
        entry = cache[id(parent)] = (parent, innovations, set(innovations.keys()))
    return entry[1], entry[2]


class FastReproduction(DefaultReproduction):
    """neat.DefaultReproduction, unchanged, with a cache that FastGenome reads while it runs: each
    parent's innovation map and the mutation rates, made once per call instead of once per child."""

    def reproduce(self, config, species, pop_size, generation):
        gc = config.genome_config
        setattr(gc, _REPRODUCING, {})
        try:
            return super().reproduce(config, species, pop_size, generation)
        finally:
            delattr(gc, _REPRODUCING)


def _known_acyclic(genome) -> bool:
    """True when the genome's connection keys are known to form no cycle (see the module docstring)."""
    return getattr(genome, "_acyclic_at", -1) == len(genome.connections)


class FastGenome(DefaultGenome):
    """neat.DefaultGenome with the same results, faster: see the module docstring."""

    @classmethod
    def parse_config(cls, param_dict):
        param_dict["node_gene_type"] = FastNodeGene
        param_dict["connection_gene_type"] = FastConnectionGene
        return DefaultGenomeConfig(param_dict, cls.__name__)

    def __init__(self, key):
        super().__init__(key)
        self._acyclic_at = 0  # no connections: acyclic

    # ------------------------------------------------------------ creation
    def configure_new(self, config):
        super().configure_new(config)
        # feed-forward initial connections run input -> hidden -> output; recurrent ones add self-loops
        self._acyclic_at = len(self.connections) if config.feed_forward else -1

    def configure_crossover(self, genome1, genome2, config):
        """DefaultGenome.configure_crossover and BaseGene.crossover/copy, written out."""
        if genome1.fitness > genome2.fitness:
            parent1, parent2 = genome1, genome2
        else:
            parent1, parent2 = genome2, genome1

        # the same dicts and the same set, built the same way: the same iteration order
        parents = getattr(config, _REPRODUCING, None)
        if parents is None:
            parent1_innovations = {cg.innovation: cg for cg in parent1.connections.values()}
            parent2_innovations = {cg.innovation: cg for cg in parent2.connections.values()}
            all_innovations = set(parent1_innovations.keys()) | set(parent2_innovations.keys())
        else:  # FastReproduction: each parent's dict and set made once per reproduce call
            parent1_innovations, set1 = _innovations(parents, parent1)
            parent2_innovations, set2 = _innovations(parents, parent2)
            if set2 is set1:  # one parent twice: `s | s` only copies s, where two equal sets resize
                set2 = set(parent2_innovations.keys())  # as neat's union of two sets does (another order)
            all_innovations = set1 | set2

        feed_forward = config.feed_forward
        parent1_acyclic = _known_acyclic(parent1)
        check_cycles = feed_forward and not parent1_acyclic
        connections = self.connections
        get1, get2 = parent1_innovations.get, parent2_innovations.get
        for innovation_num in all_innovations:
            cg1 = get1(innovation_num)
            if cg1 is None:
                continue  # genes only in parent2 (less fit) are not inherited
            cg2 = get2(innovation_num)
            new_gene = _new(type(cg1))
            new_gene.key = key = cg1.key
            new_gene.innovation = cg1.innovation
            if cg2 is not None and cg2.key == key:
                # matching genes: BaseGene.crossover (one draw per attribute, then the 75% disable rule)
                new_gene.weight = cg1.weight if random() > 0.5 else cg2.weight
                new_gene.enabled = cg1.enabled if random() > 0.5 else cg2.enabled
                if not cg1.enabled or not cg2.enabled:
                    if random() < 0.75:
                        new_gene.enabled = False
            else:
                if cg2 is not None:
                    warnings.warn(
                        f"Innovation number collision: innovation {innovation_num} assigned to both "
                        f"{cg1.key} and {cg2.key}. Treating as disjoint genes.",
                        RuntimeWarning
                    )
                # disjoint or excess gene of the fittest parent: BaseGene.copy
                new_gene.weight = cg1.weight
                new_gene.enabled = cg1.enabled
            # the key is parent1's: no cycle possible when parent1's keys are acyclic
            if check_cycles and creates_cycle(list(connections), key):
                continue
            connections[key] = new_gene

        nodes = self.nodes
        get2 = parent2.nodes.get
        for key, ng1 in parent1.nodes.items():
            ng2 = get2(key)
            new_gene = _new(type(ng1))
            new_gene.key = ng1.key
            if ng2 is None:  # BaseGene.copy
                new_gene.bias = ng1.bias
                new_gene.response = ng1.response
                new_gene.activation = ng1.activation
                new_gene.aggregation = ng1.aggregation
                new_gene.time_constant = ng1.time_constant
            else:  # BaseGene.crossover
                new_gene.bias = ng1.bias if random() > 0.5 else ng2.bias
                new_gene.response = ng1.response if random() > 0.5 else ng2.response
                new_gene.activation = ng1.activation if random() > 0.5 else ng2.activation
                new_gene.aggregation = ng1.aggregation if random() > 0.5 else ng2.aggregation
                new_gene.time_constant = ng1.time_constant if random() > 0.5 else ng2.time_constant
            nodes[key] = new_gene

        # checked gene by gene, or a subset of parent1's acyclic keys
        self._acyclic_at = len(connections) if feed_forward or parent1_acyclic else -1

    # ------------------------------------------------------------ mutation
    def mutate(self, config):
        """DefaultGenome.mutate: the same structural draws, then every gene's attributes."""
        if config.single_structural_mutation:
            div = max(1, (config.node_add_prob + config.node_delete_prob +
                          config.conn_add_prob + config.conn_delete_prob))
            r = random()
            if r < (config.node_add_prob / div):
                self.mutate_add_node(config)
            elif r < ((config.node_add_prob + config.node_delete_prob) / div):
                self.mutate_delete_node(config)
            elif r < ((config.node_add_prob + config.node_delete_prob +
                       config.conn_add_prob) / div):
                self.mutate_add_connection(config)
            elif r < ((config.node_add_prob + config.node_delete_prob +
                       config.conn_add_prob + config.conn_delete_prob) / div):
                self.mutate_delete_connection()
        else:
            if random() < config.node_add_prob:
                self.mutate_add_node(config)

            if random() < config.node_delete_prob:
                self.mutate_delete_node(config)

            if random() < config.conn_add_prob:
                self.mutate_add_connection(config)

            if random() < config.conn_delete_prob:
                self.mutate_delete_connection()

        plans = getattr(config, _REPRODUCING, None)
        if plans is None:
            connection_plan, node_plan = _connection_plan(config), _node_plan(config)
        else:  # FastReproduction: read from the config once per reproduce call
            connection_plan, node_plan = plans.get(_PLANS) or plans.setdefault(
                _PLANS, (_connection_plan(config), _node_plan(config)))
        _mutate_connections(self.connections.values(), config, connection_plan)
        _mutate_nodes(self.nodes.values(), config, node_plan)

    # The structural mutations are neat-python's own; these keep the acyclic mark up to date.
    def mutate_add_node(self, config):
        known = _known_acyclic(self)
        super().mutate_add_node(config)  # splits a link, or (no links) may call mutate_add_connection
        self._acyclic_at = len(self.connections) if known and config.feed_forward else -1

    def mutate_add_connection(self, config):
        known = _known_acyclic(self)
        super().mutate_add_connection(config)  # tests creates_cycle under feed_forward
        self._acyclic_at = len(self.connections) if known and config.feed_forward else -1

    def mutate_delete_node(self, config):
        known = _known_acyclic(self)
        result = super().mutate_delete_node(config)
        self._acyclic_at = len(self.connections) if known else -1
        return result

    def mutate_delete_connection(self):
        known = _known_acyclic(self)
        super().mutate_delete_connection()
        self._acyclic_at = len(self.connections) if known else -1

    def add_connection(self, config, input_key, output_key, weight, enabled, innovation=None):
        super().add_connection(config, input_key, output_key, weight, enabled, innovation)
        self._acyclic_at = -1  # unchecked; mutate_add_node restores the mark after its split

    # ------------------------------------------------------------ speciation
    def distance(self, other, config):
        """DefaultGenome.distance with the genes' distance written out, summed in the same order."""
        wc, dc = config.compatibility_weight_coefficient, config.compatibility_disjoint_coefficient
        return (_genes_distance(self.nodes, other.nodes, _node_distance, wc, dc)
                + _genes_distance(self.connections, other.connections, _connection_distance, wc, dc))


def _genes_distance(genes1: dict, genes2: dict, gene_distance, weight_coefficient: float,
                    disjoint_coefficient: float) -> float:
    """One half of DefaultGenome.distance (node or connection genes): the homologous genes' distances
    in genes1's order, then the disjoint genes, normalised by the larger genome."""
    if not (genes1 or genes2):
        return 0.0
    get = genes2.get
    total, matched = 0.0, 0
    for k1, g1 in genes1.items():
        g2 = get(k1)
        if g2 is not None:
            matched += 1
            total += gene_distance(g1, g2) * weight_coefficient
    n, m = len(genes1), len(genes2)
    return (total + (disjoint_coefficient * (n + m - 2 * matched))) / max(n, m)


def _node_distance(n1, n2) -> float:
    """DefaultNodeGene.distance without its compatibility_weight_coefficient."""
    d = abs(n1.bias - n2.bias) + abs(n1.response - n2.response)
    d += abs(n1.time_constant - n2.time_constant)
    if n1.activation != n2.activation:
        d += 1.0
    if n1.aggregation != n2.aggregation:
        d += 1.0
    return d


def _connection_distance(c1, c2) -> float:
    """DefaultConnectionGene.distance without its compatibility_weight_coefficient."""
    d = abs(c1.weight - c2.weight)
    if c1.enabled != c2.enabled:
        d += 1.0
    return d
