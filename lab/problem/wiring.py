"""A tree's limb-wired MLP: each group of limbs its own hidden units, each joint hearing only its group.

A tree's effectors fall into groups that share no joint (robots' chain.path(e): the joints that
move effector e): a biped's two legs, a quadruped's four, a hand's four fingers, a humanoid's two
legs and its two arms with the waist that moves both hands. A group's joints need only its own
effectors' goals: a leg's angles depend on its foot's goal alone, an arm's on both hands' goals (the
waist it hangs from serves both). The wired network gives each group its own hidden units, which
hear only the input blocks of that group's effectors (TreeEncoding: one block per effector), and
each joint hears only its group's hidden units. It is the ordinary MLP (MLPController, the kernels)
with every other weight zero: `expand` writes a wired genome (the wired weights alone, group after
group, each group's in the MLP layout of its own small network) into the full weight vector.

The summed effector error then splits into one term per group, each a function of its group's
weights alone (`Problem.wired_mse` gives them side by side), so a search may treat the groups as
separate problems. Hidden units are shared out over the groups in proportion to their effectors
(the largest remainders first); each group needs at least one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lab.problem.controllers import mlp_size


def limb_groups(arm) -> list[list[int]]:
    """The effectors of a tree grouped so that no two groups share a joint (connected by shared
    joints), each group's effectors in order, the groups by their first effector
    (robots.kinematics.limb_groups)."""
    return arm.chain.limb_groups


@dataclass(frozen=True, eq=False)
class Wiring:
    """Which weights of an MLP (n_inputs, hidden, n_outputs) a tree's wired network uses
    (n_outputs: heads x the arm's joints).

    groups: each group's effectors; joints: each group's joints (sorted); inputs: each group's input
    indices (its effectors' blocks); units: each group's hidden unit indices; index: each group's
    wired weights' places in the full vector, in the order of that group's small MLP genome
    (w_i (ni_g + 1, nh_g), bias row last, then w_o (nh_g, no_g)); sizes: each group's genome length."""

    n_inputs: int
    hidden: int
    n_outputs: int
    groups: tuple
    joints: tuple
    inputs: tuple
    units: tuple
    index: tuple
    heads: int = 1

    @classmethod
    def for_arm(cls, arm, n_inputs: int, hidden: int, heads: int = 1) -> "Wiring":
        """The wiring of a tree's network with n_inputs inputs (one equal block per effector),
        `hidden` hidden units and `heads` output heads (a multi-head MLP: lab/problem/controllers.py;
        each group's hidden units feed its joints in every head, so a group's small network has
        heads x its joints outputs, head after head); ValueError when the arm is not a tree, the
        inputs do not split into one block per effector, or there are fewer hidden units than groups."""
        if not getattr(arm, "is_tree", False):
            raise ValueError(f"{arm.name} has one end effector: a wired network is for trees (several effectors)")
        E, nq, heads = arm.n_effectors, arm.nq, int(heads)
        if heads < 1:
            raise ValueError(f"heads must be at least 1, got {heads}")
        if n_inputs % E:
            raise ValueError(f"a wired network needs one equal input block per effector: {n_inputs} inputs "
                             f"do not split into {E} blocks")
        groups = limb_groups(arm)
        hidden = int(hidden)
        if hidden < len(groups):
            raise ValueError(f"a wired network of {arm.name} needs at least one hidden unit for each of its "
                             f"{len(groups)} limb groups, got hidden={hidden}")
        counts = _share(hidden, [len(g) for g in groups])
        block = n_inputs // E
        joints, inputs, units, index = [], [], [], []
        start = 0
        for g, nh_g in zip(groups, counts):
            js = np.array(sorted({int(j) for e in g for j in arm.chain.path(e)}), dtype=np.int64)
            ins = np.concatenate([np.arange(e * block, (e + 1) * block) for e in g]).astype(np.int64)
            hs = np.arange(start, start + nh_g, dtype=np.int64)
            start += nh_g
            rows = np.concatenate([ins, [n_inputs]])  # the bias is the last input row
            w_i = (rows[:, None] * hidden + hs[None, :]).ravel()
            outs = (np.arange(heads)[:, None] * nq + js[None, :]).ravel()  # head after head, each its group's joints
            w_o = ((n_inputs + 1) * hidden + hs[:, None] * (nq * heads) + outs[None, :]).ravel()
            joints.append(js), inputs.append(ins), units.append(hs), index.append(np.concatenate([w_i, w_o]))
        return cls(int(n_inputs), hidden, nq * heads, tuple(groups), tuple(joints), tuple(inputs), tuple(units),
                   tuple(index), heads)

    @property
    def size(self) -> int:
        """The full weight vector's length."""
        return mlp_size(self.n_inputs, self.hidden, self.n_outputs)

    @property
    def sizes(self) -> tuple[int, ...]:
        """Each group's genome length."""
        return tuple(len(i) for i in self.index)

    @property
    def dim(self) -> int:
        """The wired genome's length (the groups' genomes one after the other)."""
        return int(sum(self.sizes))

    @property
    def places(self) -> np.ndarray:
        """(dim,) the wired genome's places in the full weight vector."""
        return np.concatenate(self.index)

    @property
    def mask(self) -> np.ndarray:
        """(size,) True where the full weight vector holds a wired weight."""
        m = np.zeros(self.size, bool)
        m[self.places] = True
        return m

    def expand(self, genomes: np.ndarray) -> np.ndarray:
        """Wired genomes (P, dim) or (dim,) -> full weight vectors (P, size) or (size,), zero off the wiring."""
        g = np.asarray(genomes, dtype=np.float64)
        if g.shape[-1] != self.dim or g.ndim not in (1, 2):
            raise ValueError(f"a wired genome has {self.dim} weights, got shape {g.shape}")
        out = np.zeros(g.shape[:-1] + (self.size,))
        out[..., self.places] = g
        return out

    def genome(self, weights: np.ndarray) -> np.ndarray:
        """Full weight vectors (..., size) -> their wired genomes (..., dim) (the weights off the wiring dropped)."""
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1] != self.size:
            raise ValueError(f"a full weight vector has {self.size} weights, got shape {w.shape}")
        return w[..., self.places]

    def split(self, genomes: np.ndarray) -> list[np.ndarray]:
        """Wired genomes (P, dim) -> each group's genomes (P, size_g)."""
        edges = np.cumsum((0,) + self.sizes)
        return [genomes[..., a:b] for a, b in zip(edges[:-1], edges[1:])]


def _share(total: int, weights: list[int]) -> list[int]:
    """total split in proportion to weights, at least 1 each, the largest remainders rounded up first."""
    exact = np.asarray(weights, float) * total / sum(weights)
    counts = np.maximum(np.floor(exact).astype(int), 1)
    for i in np.argsort(-(exact - np.floor(exact)), kind="stable"):
        if counts.sum() >= total:
            break
        counts[i] += 1
    while counts.sum() > total:  # the minimum of one each took more than the share
        counts[int(np.argmax(counts))] -= 1
    return counts.tolist()
