"""FastSpeciesSet: neat-python 2.0's DefaultSpeciesSet, bit for bit, with compiled distances.

DefaultSpeciesSet.speciate spends its time in genome distances (through a GenomeDistanceCache)
and in Python bookkeeping around them. FastSpeciesSet gives the very same species: it copies
every genome's genes into flat arrays once per call (keys as small integers, in each genome's
dict order) and runs speciate's two loops in one compiled call, so that:

- the same distances are computed, each as DefaultGenome.distance(self=first, other=second)
  computes it: homologous genes summed in the first genome's dict order, the same float
  operations in the same order (numba, no fast-math: no reassociation, no fused multiply-add);
- the cache is GenomeDistanceCache's: one value per pair of genome keys, the one computed first,
  in whichever argument order that was (an old representative can be an elite of the new
  population, so both orders of a pair occur);
- the control flow is speciate's: old species in sorted id order each take the unspeciated
  genome (ascending keys) closest to their old representative, min taking the first of equal
  distances; the rest, in ascending key order, join the species whose new representative is
  closest among those under the threshold, or found a new species, which later genomes see;
- members, representatives, genome_to_species and new species ids come out in neat's orders,
  and the mean and deviation of the cached distances are reported (only when a reporter listens:
  neat-python computes them for its info line alone) over the cache's values in its order.

Anything the compiled path does not model gets neat-python's own speciate: a genome type whose
distance is not DefaultGenome's (or FastGenome's, the same), the config's gene types with their own
distance, a genome stored under a key other than its own, two genomes with one key, an old species
that finds no genome left (neat's error), gene values that numpy does not read as float64 (weights,
biases, responses, time constants) and bool (enabled). The values are taken to be what neat-python
makes, Python floats and bools: a population that mixes them with, say, numpy float32 values (which
Python would subtract in single precision) is not detected. Genes are read when speciate is
called: nothing is cached on genomes, so a genome changed between generations is read as it is.
"""

from __future__ import annotations

import numba
import numpy as np
from neat.genes import DefaultConnectionGene, DefaultNodeGene
from neat.genome import DefaultGenome
from neat.math_util import mean, stdev
from neat.species import DefaultSpeciesSet, Species

from lab.methods.neat_genome import FastGenome

# no fastmath: the distances must be neat-python's to the last bit
_JIT = dict(cache=True, nogil=True, error_model="numpy")

_DISTANCES = (DefaultGenome.distance, FastGenome.distance)


class _Ids(dict):
    """Numbers hashable things 0, 1, 2 ... in order of first lookup."""

    def __missing__(self, key):
        self[key] = n = len(self)
        return n


@numba.njit(**_JIT)
def _distance(a, b, c_off, c_id, c_w, c_en, n_off, n_id, n_b, n_r, n_t, n_act, n_agg, wc, dc, c_pos, n_pos):
    """DefaultGenome.distance(a, b) (FastGenome.distance): homologous genes in a's order.
    c_pos, n_pos: all -1 on entry and on return (b's genes are scattered in and cleared)."""
    node_distance = 0.0
    a0, a1, b0, b1 = n_off[a], n_off[a + 1], n_off[b], n_off[b + 1]
    if a1 > a0 or b1 > b0:
        for j in range(b0, b1):
            n_pos[n_id[j]] = j
        matched = 0
        for i in range(a0, a1):
            j = n_pos[n_id[i]]
            if j >= 0:
                matched += 1
                d = abs(n_b[i] - n_b[j]) + abs(n_r[i] - n_r[j])
                d += abs(n_t[i] - n_t[j])
                if n_act[i] != n_act[j]:
                    d += 1.0
                if n_agg[i] != n_agg[j]:
                    d += 1.0
                node_distance += d * wc
        for j in range(b0, b1):
            n_pos[n_id[j]] = -1
        n, m = a1 - a0, b1 - b0
        node_distance = (node_distance + (dc * (n + m - 2 * matched))) / max(n, m)

    connection_distance = 0.0
    a0, a1, b0, b1 = c_off[a], c_off[a + 1], c_off[b], c_off[b + 1]
    if a1 > a0 or b1 > b0:
        for j in range(b0, b1):
            c_pos[c_id[j]] = j
        matched = 0
        for i in range(a0, a1):
            j = c_pos[c_id[i]]
            if j >= 0:
                matched += 1
                d = abs(c_w[i] - c_w[j])
                if c_en[i] != c_en[j]:
                    d += 1.0
                connection_distance += d * wc
        for j in range(b0, b1):
            c_pos[c_id[j]] = -1
        n, m = a1 - a0, b1 - b0
        connection_distance = (connection_distance + (dc * (n + m - 2 * matched))) / max(n, m)

    return node_distance + connection_distance


@numba.njit(**_JIT)
def _remember(r, g, d, cache, known, miss_a, miss_b, miss_d, n_miss):
    """GenomeDistanceCache: d stands for both orders of the pair, recorded as the n_miss-th computed."""
    cache[r, g] = d
    cache[g, r] = d
    known[r, g] = True
    known[g, r] = True
    miss_a[n_miss], miss_b[n_miss], miss_d[n_miss] = r, g, d
    return n_miss + 1


@numba.njit(**_JIT)
def _speciate(n_pop, old_reps, threshold, c_off, c_id, c_w, c_en, n_off, n_id, n_b, n_r, n_t, n_act, n_agg,
              n_cids, n_nids, wc, dc):
    """DefaultSpeciesSet.speciate's two loops over genome indices (0 .. n_pop-1: the population in
    ascending key order; then old representatives outside it). old_reps: each old species'
    representative (species in ascending id order).

    Returns (n_slots, rep, slot, miss, n_miss): slots are the new species' representatives in
    neat's insertion order (the old species first, then new ones as they were founded); rep[s] the
    genome representing slot s; slot[g] the slot of population genome g; miss[k] = (first,
    second, distance) of the k-th distance computed (the cache's insertion order).
    n_slots = -1: an old species found no genome left (neat's min() raises; the caller lets it)."""
    n_all = c_off.shape[0] - 1
    cache = np.empty((n_all, n_all))
    known = np.zeros((n_all, n_all), np.bool_)
    c_pos = np.full(n_cids, -1, np.int64)
    n_pos = np.full(n_nids, -1, np.int64)
    miss_a = np.empty(n_all * n_all, np.int64)
    miss_b = np.empty(n_all * n_all, np.int64)
    miss_d = np.empty(n_all * n_all)
    n_miss = 0
    n_old = old_reps.shape[0]
    rep = np.empty(n_old + n_pop, np.int64)
    slot = np.full(n_pop, -1, np.int64)

    # each old species: the closest unspeciated genome to its old representative
    for s in range(n_old):
        r = old_reps[s]
        best = -1
        best_d = 0.0
        for g in range(n_pop):
            if slot[g] >= 0:
                continue
            if known[r, g]:
                d = cache[r, g]
            else:
                d = _distance(r, g, c_off, c_id, c_w, c_en, n_off, n_id, n_b, n_r, n_t, n_act, n_agg, wc, dc,
                              c_pos, n_pos)
                n_miss = _remember(r, g, d, cache, known, miss_a, miss_b, miss_d, n_miss)
            if best < 0 or d < best_d:  # min(): the first of equal keys
                best, best_d = g, d
        if best < 0:
            return -1, rep, slot, miss_a, miss_b, miss_d, n_miss
        rep[s] = best
        slot[best] = s

    # the others in ascending key order: the closest representative under the threshold, or a new species
    n_slots = n_old
    for g in range(n_pop):
        if slot[g] >= 0:
            continue
        best = -1
        best_d = 0.0
        for s in range(n_slots):
            r = rep[s]
            if known[r, g]:
                d = cache[r, g]
            else:
                d = _distance(r, g, c_off, c_id, c_w, c_en, n_off, n_id, n_b, n_r, n_t, n_act, n_agg, wc, dc,
                              c_pos, n_pos)
                n_miss = _remember(r, g, d, cache, known, miss_a, miss_b, miss_d, n_miss)
            if d < threshold:
                if best < 0 or d < best_d:
                    best, best_d = s, d
        if best >= 0:
            slot[g] = best
        else:
            rep[n_slots] = g
            slot[g] = n_slots
            n_slots += 1
    return n_slots, rep, slot, miss_a, miss_b, miss_d, n_miss


_MODELLED: dict = {}


def _modelled(genome_type) -> bool:
    """Whether the genome type's distance is DefaultGenome's."""
    ok = _MODELLED.get(genome_type)
    if ok is None:
        ok = _MODELLED[genome_type] = getattr(genome_type, "distance", None) in _DISTANCES
    return ok


class FastSpeciesSet(DefaultSpeciesSet):
    """neat.DefaultSpeciesSet with the same species, faster: see the module docstring.
    Config section [FastSpeciesSet] (compatibility_threshold), as DefaultSpeciesSet's."""

    def speciate(self, config, population, generation):
        assert isinstance(population, dict)
        gc = config.genome_config
        if not (issubclass(gc.node_gene_type, DefaultNodeGene)
                and gc.node_gene_type.distance is DefaultNodeGene.distance
                and issubclass(gc.connection_gene_type, DefaultConnectionGene)
                and gc.connection_gene_type.distance is DefaultConnectionGene.distance):
            return super().speciate(config, population, generation)
        keys = sorted(population)
        genomes = [population[k] for k in keys]
        index = {}
        for i, g in enumerate(genomes):
            if not _modelled(type(g)) or index.setdefault(g.key, i) != i:
                return super().speciate(config, population, generation)  # a key not its own, or shared
        if keys != [g.key for g in genomes]:
            return super().speciate(config, population, generation)
        sids = sorted(self.species)
        old_reps = []
        for sid in sids:
            r = self.species[sid].representative
            i = index.setdefault(r.key, len(genomes))
            if i == len(genomes):
                if not _modelled(type(r)):
                    return super().speciate(config, population, generation)
                genomes.append(r)
            elif genomes[i] is not r:  # the cache would mix two genomes under one key
                return super().speciate(config, population, generation)
            old_reps.append(i)
        arrays = _flatten(genomes)
        if arrays is None:
            return super().speciate(config, population, generation)
        n_slots, rep, slot, miss_a, miss_b, miss_d, n_miss = _speciate(
            len(keys), np.array(old_reps, np.int64), float(self.species_set_config.compatibility_threshold),
            *arrays, float(gc.compatibility_weight_coefficient), float(gc.compatibility_disjoint_coefficient))
        if n_slots < 0:  # an old species found no genome: neat's min() raises
            return super().speciate(config, population, generation)

        # neat's new_representatives and new_members, in its insertion orders
        rep = rep[:n_slots].tolist()
        slot = slot.tolist()
        slot_sids = sids + [next(self.indexer) for _ in range(n_slots - len(sids))]
        members = [[keys[r]] for r in rep]
        for i, s in enumerate(slot):
            if rep[s] != i:
                members[s].append(keys[i])

        self.genome_to_species = genome_to_species = {}
        for sid, s_rep, s_members in sorted(zip(slot_sids, rep, members)):
            s = self.species.get(sid)
            if s is None:
                s = Species(sid, generation)
                self.species[sid] = s
            for gid in s_members:
                genome_to_species[gid] = sid
            s.update(genomes[s_rep], {gid: population[gid] for gid in s_members})

        # neat computes these for its info line alone
        if len(population) > 1 and getattr(self.reporters, "reporters", True):
            values = []
            for a, b, d in zip(miss_a[:n_miss].tolist(), miss_b[:n_miss].tolist(), miss_d[:n_miss].tolist()):
                values += (d, d) if genomes[a].key != genomes[b].key else (d,)
            self.reporters.info(f'Mean genetic distance {mean(values):.3f}, standard deviation {stdev(values):.3f}')


def _flatten(genomes):
    """Every genome's genes as flat arrays, in each genome's dict order; None when a value is not
    a float (weights, biases ...) or a bool (enabled) as neat-python makes them."""
    conns = [g.connections for g in genomes]
    nodes = [g.nodes for g in genomes]
    cs = [c for d in conns for c in d.values()]
    ns = [n for d in nodes for n in d.values()]
    c_ids, n_ids, names = _Ids(), _Ids(), _Ids()
    c_id = np.array(list(map(c_ids.__getitem__, [k for d in conns for k in d])), np.int64)
    n_id = np.array(list(map(n_ids.__getitem__, [k for d in nodes for k in d])), np.int64)
    act = np.array(list(map(names.__getitem__, [n.activation for n in ns])), np.int64)
    agg = np.array(list(map(names.__getitem__, [n.aggregation for n in ns])), np.int64)
    c_w = np.array([c.weight for c in cs]) if cs else np.empty(0)
    c_en = np.array([c.enabled for c in cs]) if cs else np.empty(0, np.bool_)
    if ns:
        n_b = np.array([n.bias for n in ns])
        n_r = np.array([n.response for n in ns])
        n_t = np.array([n.time_constant for n in ns])
    else:
        n_b = n_r = n_t = np.empty(0)
    if c_en.dtype != np.bool_ or c_w.dtype != np.float64 or n_b.dtype != np.float64 \
            or n_r.dtype != np.float64 or n_t.dtype != np.float64:
        return None
    c_off = np.zeros(len(conns) + 1, np.int64)
    np.cumsum(list(map(len, conns)), out=c_off[1:])
    n_off = np.zeros(len(nodes) + 1, np.int64)
    np.cumsum(list(map(len, nodes)), out=n_off[1:])
    return (c_off, c_id, c_w, c_en, n_off, n_id, n_b, n_r, n_t, act, agg, max(len(c_ids), 1), max(len(n_ids), 1))
