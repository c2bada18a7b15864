"""Neuro-controllers: goal positions in, joint values out.

Two kinds, one contract (`Controller`): called on goals (n, len(task_axes)) (a tree's: (n, E,
len(task_axes)), lab/problem/tree_encoding.py; a pose controller's, whose encoding is a PoseEncoding
and whose `goal` is "pose": poses (n, 4, 4), lab/problem/pose_encoding.py) they return joint values
(n, nq) within the joint limits; `to_dict()` is complete enough to rebuild them
(`controller_from_dict`), which is how the Rerun logger stores them.

- `MLPController`: the paper's fixed-topology MLP (section 4.3), a weight vector.
- `GraphController`: a NEAT genome compiled to a feed-forward program (nodes in evaluation
  order, each tanh(bias + response * sum w v)), evaluated in one compiled call for all goals.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from lab.problem import kernels
from lab.problem.kernels import TREE_FIELDS, check_chain, check_tree
from lab.problem.encoding import Encoding
from lab.problem.encodings import encoding_from_dict
from robots.kinematics import limb_groups


class Controller(Protocol):
    kind: str
    encoding: Encoding

    @property
    def n_params(self) -> int: ...

    def outputs(self, goals: np.ndarray) -> np.ndarray: ...

    def __call__(self, goals: np.ndarray) -> np.ndarray: ...

    def to_dict(self) -> dict: ...


def mlp_size(n_inputs: int, hidden: int, n_outputs: int) -> int:
    """Genome length N = (ni + 1) nh + nh no (paper, section 4.3)."""
    return (n_inputs + 1) * hidden + hidden * n_outputs


# head k's anchor: mid + c h, with c = (first joint's, the other joints') corner of HEAD_CORNERS[k]
# (MAX_HEADS of them): the centre, the base mid-range and the arm leaning back, then leaning forward
# (on the SO arms: curled over the base axis), then the other corners of that square, then nearer
# and farther ones
HEAD_CORNERS = ((0.0, 0.0), (-0.7, -0.7), (0.0, 0.7), (0.7, -0.7), (0.7, 0.7), (-0.7, 0.7), (-0.35, -0.35),
                (0.35, 0.35), (-0.85, -0.85))
MAX_HEADS = len(HEAD_CORNERS)


def head_anchors(encoding: Encoding, heads: int) -> np.ndarray:
    """(heads, nq) the joint values each head of a multi-hypothesis MLP starts from: head k at
    mid + c h (h the half range), c the first joint's corner of HEAD_CORNERS[k] on the first joint
    (the base's turn on every arm of the lab) and the other corner on every other joint. So the
    heads begin on different IK branches: head 1 leaning back (-0.7 on every joint: on SO100,
    SO101 and Z1, folded back over the shoulder for the goals behind the base), head 2 leaning
    forward with the base mid-range (+0.7 on every other joint: on the SO arms curled over the
    base axis, the tip beyond it, for the goals behind the base near that axis), head 3 the mirror
    image of head 1 in the base joint (+0.7 on the base, still leaning back: the goals behind the
    base on the other side), ...; head 0 is the single-head network's start, mid-range."""
    heads = _check_heads(heads)
    mid, half = 0.5 * (encoding.q_lo + encoding.q_hi), 0.5 * (encoding.q_hi - encoding.q_lo)
    first = np.arange(len(mid)) == 0
    return np.stack([mid + np.where(first, base, rest) * half for base, rest in HEAD_CORNERS[:heads]])


def _check_heads(heads) -> int:
    if isinstance(heads, bool) or not isinstance(heads, (int, np.integer)) or not 1 <= heads <= MAX_HEADS:
        raise ValueError(f"heads must be an integer in [1, {MAX_HEADS}], got {heads!r}")
    return int(heads)


def anchor_offsets(encoding: Encoding, anchors: np.ndarray) -> np.ndarray:
    """(heads nq,) output pre-activation offsets that put each head's zero-weight output on its
    anchor: atanh of the anchor's place in the output mapping (mid-range: 0)."""
    a = (np.asarray(anchors, dtype=np.float64) - encoding.q_offset) / encoding.q_scale - 1.0
    return np.ascontiguousarray(np.arctanh(np.clip(a, -0.999, 0.999)).reshape(-1))


@dataclass(frozen=True, eq=False)
class MLPController:
    """The paper's MLP: w_i (ni+1, nh) with the bias as last input, then w_o (nh, no).

    heads > 1: a multi-hypothesis network. Its output layer has heads x nq outputs, head k's with
    fixed pre-activation offsets that start it at anchors[k] (head_anchors); every head proposes
    joint values and the controller answers with the head whose end effector lands closest to the
    goal, by forward kinematics of `chain` (the arm's robots.kinematics.ChainKinematics.arrays,
    carried with the controller). Its fitness is the mean over goals of the smallest squared
    error over the heads (kernels.mlp_heads_mse): a single continuous network must cut the
    workspace somewhere between IK branches; heads that start on different branches can each
    serve a part of it (SO100, SO101: goals behind the base need the arm folded back over its
    shoulder, which no single-head run found).
    """

    encoding: Encoding
    hidden: int
    weights: np.ndarray  # (N,)
    heads: int = 1
    anchors: np.ndarray | None = None  # (heads, nq); None: head_anchors(encoding, heads)
    chain: tuple | None = None  # the arm's kinematic arrays; needed when heads > 1
    kind: str = "mlp"

    def __post_init__(self):
        object.__setattr__(self, "heads", _check_heads(self.heads))
        n = mlp_size(self.encoding.n_inputs, self.hidden, self.encoding.n_outputs * self.heads)
        w = np.ascontiguousarray(self.weights, dtype=np.float64)
        if w.shape != (n,):
            heads = "" if self.heads == 1 else f" and {self.heads} heads"
            raise ValueError(f"MLP with {self.hidden} hidden units{heads} needs {n} weights, got shape {w.shape}")
        object.__setattr__(self, "weights", w)
        anchors = head_anchors(self.encoding, self.heads) if self.anchors is None else \
            np.asarray(self.anchors, dtype=np.float64)
        if anchors.shape != (self.heads, self.encoding.n_outputs) or not np.all(np.isfinite(anchors)):
            raise ValueError(f"anchors must be {self.heads} x {self.encoding.n_outputs} finite joint values, "
                             f"got shape {anchors.shape}")
        object.__setattr__(self, "anchors", anchors)
        if self.heads > 1:
            if self.chain is None:
                raise ValueError("an MLP with several heads needs the arm's kinematic chain to pick a head")
            effectors = getattr(self.encoding, "effectors", None)
            object.__setattr__(self, "chain", check_chain(self.chain, self.encoding.n_outputs) if effectors is None
                               else check_tree(self.chain, self.encoding.n_outputs, effectors))

    @property
    def n_params(self) -> int:
        return self.weights.size

    @property
    def goal(self) -> str:
        """"pose" when it answers pose goals (n, 4, 4) (a PoseEncoding), else "position"."""
        return getattr(self.encoding, "goal", "position")

    def proposals(self, goals) -> np.ndarray:
        """(k, n, nq) every head's answer, the nearest its goal first (lab.problem.controllers.proposals)."""
        return proposals(self, goals)

    @property
    def n_outputs(self) -> int:
        """The network's outputs: heads x joints."""
        return self.heads * self.encoding.n_outputs

    @functools.cached_property
    def offsets(self) -> np.ndarray:
        """(heads nq,) the fixed output pre-activation offsets (zeros for one head); computed once."""
        if self.heads == 1:
            return np.zeros(self.encoding.n_outputs)
        return anchor_offsets(self.encoding, self.anchors)

    @property
    def w_i(self) -> np.ndarray:
        ni = self.encoding.n_inputs
        return self.weights[: (ni + 1) * self.hidden].reshape(ni + 1, self.hidden)

    @property
    def w_o(self) -> np.ndarray:
        ni = self.encoding.n_inputs
        return self.weights[(ni + 1) * self.hidden :].reshape(self.hidden, self.n_outputs)

    @functools.cached_property
    def tree_heads(self) -> "TreeHeads | None":
        """A tree's head choice per limb group (TreeHeads); None on a serial arm or with one head."""
        if self.heads == 1 or getattr(self.encoding, "effectors", None) is None:
            return None
        return TreeHeads(self.chain, self.encoding.n_outputs)

    def outputs(self, goals: np.ndarray) -> np.ndarray:
        """Network outputs a_o in [-1, 1] of the answering head, (n, nq) (a tree's: each limb group's)."""
        if self.heads > 1:
            a = self.head_outputs(goals)
            Q = self.encoding.joints(a, goals)
            if self.tree_heads is not None:
                return self.tree_heads.assemble(a, self.tree_heads.choose(Q, goals))
            pick = choose_heads(self.encoding, self.chain, Q, goals)
            return a[pick, np.arange(len(goals))]
        XT = np.ascontiguousarray(self.encoding.inputs(goals).T)
        out = np.empty((self.encoding.n_outputs, XT.shape[1]))
        kernels.mlp_outputs(XT, self.weights[None, :], self.hidden, out)
        return out.T

    def head_outputs(self, goals: np.ndarray) -> np.ndarray:
        """(heads, n, nq): every head's outputs in [-1, 1]."""
        return mlp_head_outputs(self.encoding, self.hidden, self.offsets, self.weights[None, :], goals)[0]

    def choose(self, goals: np.ndarray) -> np.ndarray:
        """(n,) the head that answers each goal: the one whose end effector lands closest (a tree's:
        (groups, n), each limb group's head, TreeHeads.groups)."""
        Q = self.encoding.joints(self.head_outputs(goals), goals)
        if self.tree_heads is not None:
            return self.tree_heads.choose(Q, goals)
        return choose_heads(self.encoding, self.chain, Q, goals)

    def __call__(self, goals: np.ndarray) -> np.ndarray:
        if self.heads > 1:
            return mlp_joints(self.encoding, self.hidden, self.weights[None, :], goals, self)[0]
        return self.encoding.joints(self.outputs(goals), goals)

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "encoding": self.encoding.to_dict(), "hidden": self.hidden,
             "weights": self.weights.tolist()}
        if self.heads > 1:
            names = TREE_FIELDS[:len(self.chain)]  # a serial chain's five arrays, a tree's seven
            d.update(heads=self.heads, anchors=self.anchors.tolist(),
                     chain={k: np.asarray(a).tolist() for k, a in zip(names, self.chain)})
        return d


def mlp_head_outputs(encoding: Encoding, hidden: int, offsets: np.ndarray, W: np.ndarray, goals) -> np.ndarray:
    """(P, heads, g, nq) outputs in [-1, 1] of the MLPs of weight rows W (P, N), each head's in turn."""
    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    nq = encoding.n_outputs
    XT = np.ascontiguousarray(encoding.inputs(goals).T)
    A = np.empty((len(offsets), len(W) * len(goals)))
    kernels.mlp_offset_outputs(XT, np.ascontiguousarray(W, dtype=np.float64), hidden,
                               np.ascontiguousarray(offsets, dtype=np.float64), A)
    return A.reshape(len(offsets) // nq, nq, len(W), len(goals)).transpose(2, 0, 3, 1)


def head_errors(encoding: Encoding, chain: tuple, Q: np.ndarray, goals) -> np.ndarray:
    """(..., heads, g) squared end-effector errors (inf where not finite), Q (..., heads, g, nq)."""
    if getattr(encoding, "goal", "position") == "pose":  # ||p - p_g||^2 + (L angle)^2 (lab/problem/pose_encoding.py)
        return encoding.sq_errors(Q, goals)
    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    lead = Q.shape[:-3]
    heads, g, nq = Q.shape[-3:]
    QT = np.ascontiguousarray(np.moveaxis(Q.reshape(-1, nq), -1, 0))  # (nq, N)
    tiled = np.ascontiguousarray(np.tile(goals.T, (1, QT.shape[1] // g)))
    E = np.empty(QT.shape[1])
    kernels.fk_sq_errors(QT, tiled, np.asarray(encoding.task_axes, dtype=np.int64), chain, E)
    return np.where(np.isfinite(E), E, np.inf).reshape(*lead, heads, g)


# a pose answer whose squared error (||p - p_g||^2 + (L angle)^2, m^2) is below this is exact: where
# several heads are, the first of them answers, so that rounding does not flip the arm between branches
EXACT_POSE = 1e-18


def _exact_ties(encoding, E: np.ndarray) -> np.ndarray:
    """E with a pose answer's exact errors (below EXACT_POSE) set to 0 (position errors as they are)."""
    return np.where(E < EXACT_POSE, 0.0, E) if getattr(encoding, "goal", "position") == "pose" else E


def choose_heads(encoding: Encoding, chain: tuple, Q: np.ndarray, goals) -> np.ndarray:
    """(..., g) the head of least squared end-effector error, Q (..., heads, g, nq) joint values (of
    several exact pose answers, the first)."""
    return np.argmin(_exact_ties(encoding, head_errors(encoding, chain, Q, goals)), axis=-2)


class TreeHeads:
    """A tree's multi-head network answers with a head per limb group: the effectors fall into groups
    that share no joint (robots.kinematics.limb_groups: a humanoid's legs, and its arms with the
    waist), a group's effectors depend on its joints alone, so each group takes the head that puts
    its own effectors nearest their goals, and the answer is the groups' heads side by side (a joint
    on no effector's path: head 0's). What the fitness scores (kernels.tree_mlp_heads_mse per group).

    tree: kernels.pack_tree's arrays; groups: each group's effectors; joints: each group's joints."""

    def __init__(self, tree: tuple, nq: int):
        rot, pos, kind, identity, ee_pos, joints, starts = tree
        paths = [joints[a:b] for a, b in zip(starts[:-1], starts[1:])]
        rows = list(zip(starts[:-1], starts[1:]))
        self.nq = int(nq)
        self.groups = limb_groups(paths)
        self.joints = [np.unique(np.concatenate([paths[e] for e in g])) for g in self.groups]
        self.trees = [kernels.pack_tree([(rot[a:b], pos[a:b], kind[a:b], identity[a:b], ee_pos[e])
                                         for e, (a, b) in ((e, rows[e]) for e in g)], [paths[e] for e in g], nq)
                      for g in self.groups]

    def errors(self, Q: np.ndarray, goals) -> np.ndarray:
        """(..., heads, g, groups): each group's summed squared effector errors (inf where not finite),
        joint values Q (..., heads, g, nq) (already turned: the encoding's joints) on goals (g, E, 3)."""
        goals = np.asarray(goals, dtype=np.float64)
        lead, (heads, g, nq) = Q.shape[:-3], Q.shape[-3:]
        QT = np.ascontiguousarray(np.moveaxis(Q.reshape(-1, nq), -1, 0))  # (nq, N)
        out = np.empty((len(self.groups), QT.shape[1]))
        axes = np.arange(3, dtype=np.int64)
        for k, (group, tree) in enumerate(zip(self.groups, self.trees)):
            goalsT = goals[:, group].reshape(g, -1).T
            tiled = np.ascontiguousarray(np.tile(goalsT, (1, QT.shape[1] // g)))
            kernels.tree_sq_errors(QT, tiled, axes, tree, np.zeros((len(group), 10)), out[k])
        out = np.where(np.isfinite(out), out, np.inf)
        return np.moveaxis(out, 0, -1).reshape(*lead, heads, g, len(self.groups))

    def choose(self, Q: np.ndarray, goals) -> np.ndarray:
        """(..., groups, g): each group's head of least error, Q (..., heads, g, nq)."""
        return np.moveaxis(np.argmin(self.errors(Q, goals), axis=-3), -1, -2)

    def assemble(self, X: np.ndarray, picks: np.ndarray) -> np.ndarray:
        """(..., g, nq) from X (..., heads, g, nq) (joint values or outputs): each group's joints from
        its head picks[..., group, :] (choose), a joint on no group's path from head 0."""
        out = X[..., 0, :, :].copy()
        for k, js in enumerate(self.joints):
            taken = np.take_along_axis(X, picks[..., k, None, :, None], axis=-3)[..., 0, :, :]
            out[..., js] = taken[..., js]
        return out

    def ranked(self, Q: np.ndarray, goals) -> np.ndarray:
        """(heads, g, nq) from Q (heads, g, nq): proposal i has every group's i-th nearest head."""
        order = np.argsort(self.errors(Q, goals), axis=0, kind="stable")  # (heads, g, groups)
        return np.stack([self.assemble(Q, np.moveaxis(order[i], -1, 0)) for i in range(len(Q))])


def proposals(controller, goals) -> np.ndarray:
    """(k, n, nq): the joint values a controller proposes for each goal, as robots.ik.refine takes
    them: every head's of a multi-head MLP, the nearest its goal first (k = heads; the first is
    the controller's own answer; a tree's: proposal i has each limb group's i-th nearest head), or
    any other controller's one answer (k = 1)."""
    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    if getattr(controller, "heads", 1) == 1:
        return np.asarray(controller(goals), dtype=np.float64)[None]
    encoding = controller.encoding
    if getattr(encoding, "goal", "position") == "pose":  # joints and errors in one pass of the kernels
        Q, E = encoding.answers(controller.head_outputs(goals), goals)  # (heads, n, nq), (heads, n)
        E = _exact_ties(encoding, E)
    else:
        Q = encoding.joints(controller.head_outputs(goals), goals)
        if controller.tree_heads is not None:
            return controller.tree_heads.ranked(Q, goals)
        E = head_errors(encoding, controller.chain, Q, goals)
    order = np.argsort(E, axis=0, kind="stable")
    return np.take_along_axis(Q, order[:, :, None], axis=0)


def swept_proposals(controller, goals, Q: np.ndarray, count: int, keep: int, weight: float) -> np.ndarray:
    """(keep, n, nq): more proposals for pose goals (n, 4, 4), from the answers Q (k, n, nq) of a pose
    controller with the closed-form reach: each with one joint at a time set to count values over its
    range and the closed form solving the rest (PoseEncoding.swept: a 7-joint arm's redundant joint,
    which the network picks from the goal alone and may pick where another joint meets its limit;
    then the shoulder, whose start picks the solution the reach settles on), the keep nearest each goal first
    (least ||p - p_g||^2 + (weight angle)^2; weight [m/rad]: refine's tol / angle_tol). (0, n, nq) for
    any other controller."""
    encoding = getattr(controller, "encoding", None)
    if not getattr(encoding, "swept_joints", ()):
        return np.empty((0, *np.shape(Q)[-2:]))
    A = encoding.swept(Q, goals, count)
    d, a = encoding.errors(A, goals)
    e = d * d + (weight * a) ** 2
    order = np.argsort(np.where(np.isfinite(e), e, np.inf), axis=0, kind="stable")[:keep]
    return np.take_along_axis(A, order[:, :, None], axis=0)


def mlp_joints(encoding: Encoding, hidden: int, W: np.ndarray, goals, heads_of=None) -> np.ndarray:
    """(P, g, nq) joint values of the MLPs of weight rows W (P, N) on goals (g, task dims); heads_of:
    an MLPController whose heads, anchors and chain they share (None: one head, the paper's MLP)."""
    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    W = np.ascontiguousarray(W, dtype=np.float64)
    nq = encoding.n_outputs
    if heads_of is None or heads_of.heads == 1:
        XT = np.ascontiguousarray(encoding.inputs(goals).T)
        A = np.empty((nq, len(W) * len(goals)))
        kernels.mlp_outputs(XT, W, hidden, A)
        a = A.reshape(nq, len(W), len(goals)).transpose(1, 2, 0)
        return encoding.joints(a, goals)
    Q = encoding.joints(mlp_head_outputs(encoding, hidden, heads_of.offsets, W, goals), goals)  # (P, heads, g, nq)
    if heads_of.tree_heads is not None:  # each limb group's head
        return heads_of.tree_heads.assemble(Q, heads_of.tree_heads.choose(Q, goals))
    pick = choose_heads(encoding, heads_of.chain, Q, goals)  # (P, g)
    return np.take_along_axis(Q, pick[:, None, :, None], axis=1)[:, 0]


@dataclass(frozen=True, eq=False)
class GraphController:
    """A feed-forward graph with tanh nodes: the phenotype of a NEAT genome.

    nodes:       [(key, bias, response, [(source key, weight), ...]), ...] in evaluation order
    input_keys:  keys of the inputs (NEAT: -1, -2, ...), one per encoded input
    output_keys: keys of the outputs, one per joint (an output absent from nodes gives 0)
    genome:      the genome's nodes and connections (all, with enabled flags), for display and logs
    """

    encoding: Encoding
    nodes: tuple
    input_keys: tuple[int, ...]
    output_keys: tuple[int, ...]
    genome: dict
    kind: str = "graph"

    @property
    def n_params(self) -> int:
        """Evolved parameters of the expressed network: enabled weights + node biases."""
        return sum(len(links) for _, _, _, links in self.nodes) + len(self.nodes)

    @property
    def goal(self) -> str:
        """"pose" when it answers pose goals (n, 4, 4) (a PoseEncoding), else "position"."""
        return getattr(self.encoding, "goal", "position")

    @property
    def n_hidden(self) -> int:
        return sum(1 for key, *_ in self.nodes if key not in self.output_keys)

    def program(self):
        return compile_programs([self])

    def outputs(self, goals: np.ndarray) -> np.ndarray:
        X = self.encoding.inputs(goals)
        return run_programs(self.program(), X)[0]

    def __call__(self, goals: np.ndarray) -> np.ndarray:
        return self.encoding.joints(self.outputs(goals), goals)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind, "encoding": self.encoding.to_dict(),
            "nodes": [[k, b, r, [[s, w] for s, w in links]] for k, b, r, links in self.nodes],
            "input_keys": list(self.input_keys), "output_keys": list(self.output_keys),
            "genome": self.genome,
        }


def lay_out(nodes, input_keys, output_keys) -> tuple:
    """Slots of one feed-forward graph, as `kernels.graph_forward` reads them.

    nodes: (key, links) in evaluation order, links ((source key, x), ...). Slots 0 .. ni-1 hold
    the inputs, ni + k the k-th node. Returns (link_src, link_x, link_end, out_slot): each link's
    source slot and its x, where each node's links end, each output's slot (-1: not expressed).
    """
    ni = len(input_keys)
    slot = {k: i for i, k in enumerate(input_keys)}
    link_src, link_x, link_end = [], [], []
    for k, (key, links) in enumerate(nodes):
        for src, x in links:
            link_src.append(slot[src])
            link_x.append(x)
        link_end.append(len(link_src))
        slot[key] = ni + k
    return link_src, link_x, link_end, [slot.get(key, -1) for key in output_keys]


def join_programs(parts) -> tuple:
    """The arrays `kernels.graph_forward` walks, from each graph's (bias, response, link_src, link_w,
    link_end, out_slot) lists (see lay_out): the graphs' nodes and links laid end to end."""
    starts, n_nodes, bias, response, link_start, link_src, link_w, out_slot = [], [], [], [], [0], [], [], []
    for b, r, src, w, end, out in parts:
        starts.append(len(bias))
        n_nodes.append(len(b))
        bias += b
        response += r
        base = len(link_src)
        link_start += [base + e for e in end]
        link_src += src
        link_w += w
        out_slot += out
    no = len(out)
    as_i = lambda x: np.asarray(x, dtype=np.int64)  # noqa: E731
    as_f = lambda x: np.asarray(x, dtype=np.float64)  # noqa: E731
    return (as_i(starts), as_i(n_nodes), as_f(bias), as_f(response), as_i(link_start),
            as_i(link_src), as_f(link_w), as_i(out_slot).reshape(len(starts), no), no)


def compile_programs(graphs) -> tuple:
    """Flatten graphs into the arrays `kernels.graph_forward` walks (see its docstring)."""
    parts = []
    for g in graphs:
        src, w, end, out = lay_out([(key, links) for key, _, _, links in g.nodes], g.input_keys, g.output_keys)
        parts.append(([b for _, b, _, _ in g.nodes], [r for _, _, r, _ in g.nodes], src, w, end, out))
    return join_programs(parts)


def run_programs(program: tuple, X: np.ndarray) -> np.ndarray:
    """Outputs (P, n, no) of every compiled graph on inputs X (n, ni)."""
    XT = np.ascontiguousarray(np.asarray(X, dtype=np.float64).T)
    out = np.empty((len(program[0]), program[-1], XT.shape[1]))
    kernels.graph_forward(XT, *program, out)
    return out.transpose(0, 2, 1)


def controller_from_dict(d: dict, arm=None) -> Controller:
    """Rebuild a controller from its `to_dict()`; ValueError, naming what is wrong, for anything else.
    arm (an Arm, or a robot's string: lab/problem/robot.py): also ValueError unless the controller was
    made for that arm (its joints and their limits, its goals' axes)."""
    if not isinstance(d, dict):
        raise ValueError(f"not a controller: expected a dict, got {type(d).__name__}")
    try:
        controller = _from_dict(d)
    except KeyError as e:
        raise ValueError(f"not a controller: its field {e.args[0]!r} is missing") from e
    except (TypeError, ValueError, AttributeError) as e:
        raise ValueError(f"not a controller: {e}") from e
    if arm is not None:
        check_made_for(controller, arm)
    return controller


def check_made_for(controller, arm) -> None:
    """ValueError, naming the difference, unless `controller` answers `arm`'s joints within its limits
    (arm: an Arm or a robot's string) on its goals' axes (a pose controller: x, y, z)."""
    from lab.problem.robot import load_arm

    arm = load_arm(arm)
    enc = controller.encoding
    if len(enc.q_lo) != arm.nq:
        raise ValueError(f"{arm.name}: this controller answers {len(enc.q_lo)} joints, the arm has {arm.nq}")
    if not (np.allclose(enc.q_lo, arm.lower) and np.allclose(enc.q_hi, arm.upper)):
        raise ValueError(f"{arm.name}: this controller's joint limits are not the arm's (another arm of "
                         f"{arm.nq} joints?)")
    effectors = int(getattr(enc, "effectors", None) or 1)  # a tree's encoding: its number of effectors
    if effectors != arm.n_effectors:
        raise ValueError(f"{arm.name}: this controller answers {effectors} end effector(s), the arm has "
                         f"{arm.n_effectors}")
    if getattr(enc, "goal", "position") != "pose" and tuple(enc.task_axes) != tuple(arm.task_axes):
        raise ValueError(f"{arm.name}: this controller takes goals on task axes {tuple(enc.task_axes)}, the "
                         f"arm's are {tuple(arm.task_axes)}")
    chain = next((c for c in (getattr(controller, "chain", None), getattr(enc, "chain", None)) if c is not None), None)
    if chain is not None and not arm.is_tree and not all(  # the kinematics it carries (heads, turn, pose)
            np.shape(a) == np.shape(b) and np.allclose(a, b) for a, b in zip(chain, arm.chain.arrays)):
        raise ValueError(f"{arm.name}: this controller carries another arm's kinematics (its links differ)")


def _from_dict(d: dict) -> Controller:
    enc = encoding_from_dict(d["encoding"])
    if d["kind"] == "mlp":
        heads = d.get("heads", 1)
        anchors = d.get("anchors")  # absent: head_anchors' rule
        return MLPController(enc, int(d["hidden"]), np.asarray(d["weights"], dtype=np.float64), heads,
                             None if anchors is None else np.asarray(anchors, dtype=np.float64), d.get("chain"))
    if d["kind"] == "graph":
        nodes = tuple((int(k), float(b), float(r), tuple((int(s), float(w)) for s, w in links))
                      for k, b, r, links in d["nodes"])
        input_keys, output_keys = tuple(int(k) for k in d["input_keys"]), tuple(int(k) for k in d["output_keys"])
        _check_graph(enc, nodes, input_keys, output_keys)
        return GraphController(enc, nodes, input_keys, output_keys, d["genome"])
    raise ValueError(f"unknown controller kind {d['kind']!r}")


def _check_graph(enc: Encoding, nodes: tuple, input_keys: tuple, output_keys: tuple) -> None:
    """A graph the kernel can run: one input key per network input, one output key per joint,
    every link reading an input or an earlier node (evaluation order)."""
    if len(input_keys) != enc.n_inputs or len(set(input_keys)) != len(input_keys):
        raise ValueError(f"graph: {len(input_keys)} input_keys, but the encoding has {enc.n_inputs} distinct inputs")
    if len(output_keys) != enc.n_outputs or len(set(output_keys)) != len(output_keys):
        raise ValueError(f"graph: {len(output_keys)} output_keys, but the arm has {enc.n_outputs} joints")
    known = set(input_keys)
    for key, _, _, links in nodes:
        if key in known:
            raise ValueError(f"graph: node {key} is defined twice, or is an input")
        for src, _ in links:
            if src not in known:
                raise ValueError(f"graph: node {key} reads key {src}, which is not an input or an earlier node")
        known.add(key)
    if set(output_keys) & set(input_keys):
        raise ValueError("graph: an output key is also an input key")


class NetNode(NamedTuple):
    """A node of a network drawing: its key, its column (0: inputs, last: joints), label, kind."""

    key: object
    layer: int
    label: str
    kind: str  # "input", "hidden" or "output"


def network_layout(controller: Controller) -> tuple[list[NetNode], list[tuple]]:
    """How to draw a controller's network, the same in the app and in recordings:
    (nodes, links [(source key, target key, weight)]). Inputs are labelled by the encoding
    (x, y, r, ...), joints q1 .. qn; an MLP's hidden units form one column, a graph's hidden
    nodes stand at their longest-path depth from the inputs; a graph's enabled links only."""
    enc = controller.encoding
    in_labels, n_out = enc.input_names, enc.n_outputs
    if controller.kind == "mlp":
        w_i, w_o = controller.w_i, controller.w_o  # (ni+1, nh), (nh, no); last row of w_i: bias
        nh, heads = controller.hidden, controller.heads
        nodes = [NetNode(("i", k), 0, in_labels[k], "input") for k in range(enc.n_inputs)]
        nodes += [NetNode(("h", h), 1, "", "hidden") for h in range(nh)]
        # several heads: q1a .. qna, then q1b .., one column
        nodes += [NetNode(("o", o), 2, f"q{o % n_out + 1}" + ("" if heads == 1 else "abcdefgh"[o // n_out]), "output")
                  for o in range(n_out * heads)]
        links = [(("i", k), ("h", h), float(w_i[k, h])) for k in range(enc.n_inputs) for h in range(nh)]
        links += [(("h", h), ("o", o), float(w_o[h, o])) for h in range(nh) for o in range(n_out * heads)]
        return nodes, links
    genome = controller.genome
    inputs, outputs = list(controller.input_keys), list(controller.output_keys)
    links = [(int(i), int(o), float(w)) for i, o, w, enabled in genome["connections"] if enabled]
    keys = set(inputs) | set(outputs) | {int(k) for k, *_ in genome["nodes"]}
    depth = {k: 0 for k in inputs}
    for _ in range(len(keys)):  # longest path from the inputs (the graph is feed-forward)
        changed = False
        for i, o, _w in links:
            if i in depth and depth.get(o, -1) < depth[i] + 1 and o not in inputs:
                depth[o], changed = depth[i] + 1, True
        if not changed:
            break
    last = max([depth.get(k, 1) for k in keys if k not in outputs] + [0]) + 1
    nodes = [NetNode(k, 0, in_labels[n], "input") for n, k in enumerate(inputs)]
    nodes += [NetNode(k, min(depth.get(k, 1), last - 1) or 1, "", "hidden")
              for k in sorted(keys - set(inputs) - set(outputs))]
    nodes += [NetNode(k, last, f"q{n + 1}", "output") for n, k in enumerate(outputs)]
    return nodes, links
