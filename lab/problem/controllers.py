"""Neuro-controllers: goal positions in, joint values out.

Two kinds, one contract (`Controller`): called on goals (n, len(task_axes)) they return joint
values (n, nq) within the joint limits; `to_dict()` is complete enough to rebuild them
(`controller_from_dict`), which is how the Rerun logger stores them.

- `MLPController`: the paper's fixed-topology MLP (section 4.3), a weight vector.
- `GraphController`: a NEAT genome compiled to a feed-forward program (nodes in evaluation
  order, each tanh(bias + response * sum w v)), evaluated in one compiled call for all goals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from lab.problem import kernels
from lab.problem.encoding import Encoding


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


@dataclass(frozen=True, eq=False)
class MLPController:
    """The paper's MLP: w_i (ni+1, nh) with the bias as last input, then w_o (nh, no)."""

    encoding: Encoding
    hidden: int
    weights: np.ndarray  # (N,)
    kind: str = "mlp"

    def __post_init__(self):
        n = mlp_size(self.encoding.n_inputs, self.hidden, self.encoding.n_outputs)
        w = np.ascontiguousarray(self.weights, dtype=np.float64)
        if w.shape != (n,):
            raise ValueError(f"MLP with {self.hidden} hidden units needs {n} weights, got shape {w.shape}")
        object.__setattr__(self, "weights", w)

    @property
    def n_params(self) -> int:
        return self.weights.size

    @property
    def w_i(self) -> np.ndarray:
        ni = self.encoding.n_inputs
        return self.weights[: (ni + 1) * self.hidden].reshape(ni + 1, self.hidden)

    @property
    def w_o(self) -> np.ndarray:
        ni = self.encoding.n_inputs
        return self.weights[(ni + 1) * self.hidden :].reshape(self.hidden, self.encoding.n_outputs)

    def outputs(self, goals: np.ndarray) -> np.ndarray:
        """Network outputs a_o in [-1, 1], (n, nq)."""
        XT = np.ascontiguousarray(self.encoding.inputs(goals).T)
        out = np.empty((self.encoding.n_outputs, XT.shape[1]))
        kernels.mlp_outputs(XT, self.weights[None, :], self.hidden, out)
        return out.T

    def __call__(self, goals: np.ndarray) -> np.ndarray:
        return self.encoding.joints(self.outputs(goals))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "encoding": self.encoding.to_dict(), "hidden": self.hidden,
                "weights": self.weights.tolist()}


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
    def n_hidden(self) -> int:
        return sum(1 for key, *_ in self.nodes if key not in self.output_keys)

    def program(self):
        return compile_programs([self])

    def outputs(self, goals: np.ndarray) -> np.ndarray:
        X = self.encoding.inputs(goals)
        return run_programs(self.program(), X)[0]

    def __call__(self, goals: np.ndarray) -> np.ndarray:
        return self.encoding.joints(self.outputs(goals))

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


def controller_from_dict(d: dict) -> Controller:
    """Rebuild a controller from its `to_dict()`; ValueError, naming what is wrong, for anything else."""
    if not isinstance(d, dict):
        raise ValueError(f"not a controller: expected a dict, got {type(d).__name__}")
    try:
        return _from_dict(d)
    except KeyError as e:
        raise ValueError(f"not a controller: its field {e.args[0]!r} is missing") from e
    except (TypeError, ValueError, AttributeError) as e:
        raise ValueError(f"not a controller: {e}") from e


def _from_dict(d: dict) -> Controller:
    enc = Encoding.from_dict(d["encoding"])
    if d["kind"] == "mlp":
        return MLPController(enc, int(d["hidden"]), np.asarray(d["weights"], dtype=np.float64))
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
        nh = controller.hidden
        nodes = [NetNode(("i", k), 0, in_labels[k], "input") for k in range(enc.n_inputs)]
        nodes += [NetNode(("h", h), 1, "", "hidden") for h in range(nh)]
        nodes += [NetNode(("o", o), 2, f"q{o + 1}", "output") for o in range(n_out)]
        links = [(("i", k), ("h", h), float(w_i[k, h])) for k in range(enc.n_inputs) for h in range(nh)]
        links += [(("h", h), ("o", o), float(w_o[h, o])) for h in range(nh) for o in range(n_out)]
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
