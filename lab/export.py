"""A controller's network as an ONNX file, for use outside the lab (`python -m lab export RUN --onnx F`).

    from lab import export
    model = export.to_onnx(controller)          # an onnx.ModelProto (needs the `onnx` extra)
    export.save(controller, "arm.onnx")         # written, and checked with onnxruntime when installed

What the file holds, in float64 (onnxruntime's CPU kernels; float32 would differ by up to 1e-6 rad):
- input "goals": positions (n, len(task_axes)) or, for a pose controller, poses (n, 4, 4);
- the input encoding (lab/problem/encoding.py): the goal's coordinates, its distance r and bearing phi
  about the base axis, the slack of reach and, for "sphere" and "bearings", the distance from the
  shoulder's sphere, its elevation and slack, each scaled to [-1, 1]; a pose's orientation as its 6-D
  rotation (or its approach axis on the SO arms): plain affine and trigonometric maps;
- the network: an MLP (MatMul, Add, Tanh; every head, with its fixed output offsets) or a NEAT graph
  (one node at a time, tanh(bias + response * sum w v));
- output "outputs" (heads, n, nq): each head's outputs in [-1, 1] (a NEAT graph: heads = 1);
- output "joints" (heads, n, nq): each head's outputs mapped onto the joint ranges (the margin, the
  clip to the limits, a continuous joint wrapped by whole turns).

What it leaves out (the lab does them with the arm's kinematics; docs/api.md):
- the turn of the first joint toward the goal's bearing (turn=True, a real arm's default with a time
  budget and for pose goals): "joints" holds the network's own first joint, before the turn;
- the choice among heads (the head whose tool lands nearest the goal, by forward kinematics);
- a pose network's closed-form wrist and reach (the UR arms', Panda's, ...): their joints in "joints"
  are the network's raw picks, which only choose the branch;
- the refinement (lab.solve): the network's answer is a start, not the exact answer.
A tree's controller (several end effectors) is refused by name: its encoding is per limb frame.
"""

from __future__ import annotations

import json

import numpy as np

TOLERANCE = 1e-6  # the largest difference allowed between onnxruntime's outputs and the lab's
HALVINGS, ATAN_TERMS = 3, 12  # atan2's angle halvings and series terms (_Graph.atan2)
OPSET = 17


def _onnx():
    try:
        import onnx
    except ImportError:
        raise ImportError("ONNX export needs the onnx package: pip install 'neuro-ik-lab[onnx]' "
                          "(or pip install onnx onnxruntime)") from None
    return onnx


class _Graph:
    """A graph under construction: nodes and constants, each value a fresh name."""

    def __init__(self, onnx):
        self.onnx, self.h = onnx, onnx.helper
        self.nodes, self.inits, self.count = [], [], 0

    def name(self, stem: str) -> str:
        self.count += 1
        return f"{stem}_{self.count}"

    def const(self, value, stem: str = "c") -> str:
        arr = np.asarray(value)
        arr = arr if arr.dtype.kind == "b" else arr.astype(np.int64) if arr.dtype.kind in "iu" else \
            arr.astype(np.float64)
        name = self.name(stem)
        self.inits.append(self.onnx.numpy_helper.from_array(arr, name))
        return name

    def op(self, kind: str, *inputs, stem: str | None = None, **attrs) -> str:
        out = self.name(stem or kind.lower())
        self.nodes.append(self.h.make_node(kind, list(inputs), [out], **attrs))
        return out

    # ------------------------------------------------ small maps built of ONNX ops
    def column(self, x: str, j: int) -> str:
        """x[:, j:j+1] of a 2-D tensor."""
        return self.op("Slice", x, self.const([j]), self.const([j + 1]), self.const([1]))

    def atan2(self, y: str, x: str) -> str:
        """atan2(y, x) as numpy's (pi on the negative x axis, 0 at the origin) in float64, of ops that
        onnxruntime runs in float64 (its Atan is float32 alone): reflected into x >= 0 (angle
        sign(y) pi - atan2(y, -x)), then halved HALVINGS times (atan2(y, x) = 2 atan2(y, x + r), no
        cancellation with x >= 0), then atan's series on |y / x| <= tan(pi / 16) (error below 1e-17)."""
        zero = self.const(0.0)
        left = self.op("Less", x, zero)
        ax = self.op("Abs", x)
        u, v = ax, y
        for _ in range(HALVINGS):
            u = self.op("Add", u, self.op("Sqrt", self.op("Add", self.op("Mul", u, u), self.op("Mul", v, v))))
        origin = self.op("Equal", u, zero)
        t = self.op("Div", v, self.op("Where", origin, self.const(1.0), u))
        t2 = self.op("Mul", t, t)
        series = self.const(0.0)
        for k in range(ATAN_TERMS - 1, -1, -1):  # Horner: sum (-1)^k t^(2k+1) / (2k+1)
            series = self.op("Add", self.const((-1.0) ** k / (2 * k + 1)), self.op("Mul", t2, series))
        half = self.op("Mul", self.op("Mul", t, series), self.const(float(2 ** HALVINGS)))
        upper = self.op("Where", self.op("Less", y, zero), self.const(-np.pi), self.const(np.pi))
        return self.op("Where", left, self.op("Sub", upper, half), half)

    def mod(self, x: str, m: float) -> str:
        """x mod m in [0, m), as numpy's np.mod (ONNX's fmod takes the dividend's sign)."""
        f = self.op("Mod", x, self.const(m), fmod=1)
        return self.op("Where", self.op("Less", f, self.const(0.0)), self.op("Add", f, self.const(m)), f)

    def wrapped(self, a: str) -> str:
        """An angle turned by whole turns into [-pi, pi) (encoding._wrapped)."""
        return self.op("Sub", self.mod(self.op("Add", a, self.const(np.pi)), 2 * np.pi), self.const(np.pi))

    def slack(self, d: str, d_max: float) -> str:
        """sqrt(clip(1 - d / d_max, 0, 1)) (encoding._slack)."""
        s = self.op("Sub", self.const(1.0), self.op("Div", d, self.const(d_max)))
        return self.op("Sqrt", self.op("Clip", s, self.const(0.0), self.const(1.0)))


def _features(g: _Graph, enc, goals: str) -> str:
    """The position encoding's inputs (n, n_inputs) of goals (n, m), as Encoding.inputs computes them."""
    m = len(enc.task_axes)
    cols = [g.column(goals, j) for j in range(m)]
    if enc.features == "cartesian":
        raw = [goals]
    else:
        x = g.op("Sub", cols[0], g.const(float(enc.axis_xy[0])))
        y = g.op("Sub", cols[1], g.const(float(enc.axis_xy[1])))
        r = g.op("Sqrt", g.op("Add", g.op("Mul", x, x), g.op("Mul", y, y)))
        phi = g.atan2(y, x)
        if enc.features == "bearings":
            phi = g.wrapped(g.op("Sub", phi, g.const(float(enc.facing))))
        if enc.features == "cylindrical":
            raw = [r, phi, *cols[2:]]
        elif enc.features == "polar":
            raw = [goals, r, phi]
        else:  # reach, sphere, bearings
            raw = [goals, r, phi, g.slack(r, enc.r_max)]
            if enc.features in ("sphere", "bearings"):
                h = g.op("Sub", cols[2], g.const(float(enc.z_c)))
                rho = g.op("Sqrt", g.op("Add", g.op("Mul", r, r), g.op("Mul", h, h)))
                raw += [rho, g.atan2(h, r), g.slack(rho, enc.rho_max)]
                if enc.features == "bearings":
                    raw.append(g.wrapped(g.op("Sub", phi, g.const(np.pi))))
    raw = raw[0] if len(raw) == 1 else g.op("Concat", *raw, axis=1)
    scale = 2.0 / (enc.in_hi - enc.in_lo)
    return g.op("Sub", g.op("Mul", g.op("Sub", raw, g.const(enc.in_lo)), g.const(scale)), g.const(1.0))


def _pose_features(g: _Graph, enc, poses: str) -> str:
    """A pose encoding's inputs: the position's, then the 6-D rotation (columns 1 and 2 of R) or R axis."""
    start = lambda *v: g.const(list(v))  # noqa: E731
    position = g.op("Reshape", g.op("Slice", poses, start(0, 3), start(3, 4), start(1, 2)), g.const([-1, 3]))
    if enc.axis is None:
        R = g.op("Slice", poses, start(0, 0), start(3, 2), start(1, 2))  # (n, 3, 2)
        rotation = g.op("Reshape", g.op("Transpose", R, perm=[0, 2, 1]), g.const([-1, 6]))
    else:
        R = g.op("Slice", poses, start(0, 0), start(3, 3), start(1, 2))  # (n, 3, 3)
        rotation = g.op("Reshape", g.op("MatMul", R, g.const(np.asarray(enc.axis).reshape(3, 1))),
                        g.const([-1, 3]))
    return g.op("Concat", _features(g, enc.position, position), rotation, axis=1)


def _mlp(g: _Graph, c, X: str) -> str:
    """(n, heads nq) outputs: tanh(offsets + tanh(X w_i + b) w_o)."""
    ni = c.encoding.n_inputs
    W_i = c.w_i
    H = g.op("Tanh", g.op("Add", g.op("MatMul", X, g.const(W_i[:ni])), g.const(W_i[ni])))
    return g.op("Tanh", g.op("Add", g.op("MatMul", H, g.const(c.w_o)), g.const(c.offsets)))


def _graph(g: _Graph, c, X: str) -> str:
    """(n, nq) outputs of a NEAT graph: each node tanh(bias + response * sum w v), in evaluation order."""
    values = {key: g.column(X, j) for j, key in enumerate(c.input_keys)}
    for key, bias, response, links in c.nodes:
        if links:
            sources = g.op("Concat", *(values[s] for s, _ in links), axis=1) if len(links) > 1 else values[links[0][0]]
            total = g.op("MatMul", sources, g.const(np.array([[w] for _, w in links])))
        else:
            total = g.op("Mul", values[c.input_keys[0]], g.const(0.0))
        values[key] = g.op("Tanh", g.op("Add", g.op("Mul", total, g.const(float(response))), g.const(float(bias))))
    zero = g.op("Mul", values[c.input_keys[0]], g.const(0.0))
    return g.op("Concat", *(values.get(k, zero) for k in c.output_keys), axis=1)


def _mapped(g: _Graph, enc, A: str) -> str:
    """Encoding.mapped: outputs (..., nq) -> joint values within the limits, before any turn."""
    q = g.op("Add", g.const(enc.q_offset), g.op("Mul", g.op("Add", A, g.const(1.0)), g.const(enc.q_scale)))
    wrap = np.asarray(enc.wrap, bool)
    if wrap.any():
        turned = g.op("Add", g.const(enc.q_lo), g.mod(g.op("Sub", q, g.const(enc.q_lo)), 2 * np.pi))
        q = g.op("Where", g.const(wrap), g.op("Min", turned, g.const(enc.q_hi)), q)
    if enc.margin == 0 and not wrap.any():
        return q
    return g.op("Max", g.op("Min", q, g.const(enc.q_hi)), g.const(enc.q_lo))


def check_exportable(controller) -> None:
    """ValueError, naming why, for a controller this module cannot write."""
    kind = getattr(controller, "kind", None)
    if kind not in ("mlp", "graph"):
        raise ValueError(f"cannot export {type(controller).__name__}: only the lab's MLP and NEAT graph controllers")
    enc = controller.encoding
    if getattr(enc, "effectors", None):
        raise ValueError("a tree's controller (several end effectors) is not exported: its inputs are per limb frame")


def to_onnx(controller, name: str = "neuro_ik_controller", robot: str | None = None):
    """The controller's network as an onnx.ModelProto (see the module for what it holds)."""
    onnx = _onnx()
    check_exportable(controller)
    enc = controller.encoding
    g = _Graph(onnx)
    pose = getattr(enc, "goal", "position") == "pose"
    shape = ["n", 4, 4] if pose else ["n", len(enc.task_axes)]
    X = _pose_features(g, enc, "goals") if pose else _features(g, enc, "goals")
    A = _mlp(g, controller, X) if controller.kind == "mlp" else _graph(g, controller, X)
    heads, nq = getattr(controller, "heads", 1), enc.n_outputs
    g.nodes.append(g.h.make_node("Transpose", [g.op("Reshape", A, g.const([-1, heads, nq]))], ["outputs"],
                                 perm=[1, 0, 2]))
    g.nodes.append(g.h.make_node("Identity", [_mapped(g, getattr(enc, "position", enc), "outputs")], ["joints"]))
    double = onnx.TensorProto.DOUBLE
    graph = g.h.make_graph(g.nodes, name, [g.h.make_tensor_value_info("goals", double, shape)],
                           [g.h.make_tensor_value_info(k, double, [heads, "n", nq]) for k in ("outputs", "joints")],
                           g.inits)
    model = g.h.make_model(graph, opset_imports=[g.h.make_opsetid("", OPSET)], producer_name="neuro-ik-lab")
    model.ir_version = min(model.ir_version, 8)  # readable by onnxruntime 1.18 and later
    meta = {"goal": "pose" if pose else "position", "heads": str(heads), "kind": controller.kind,
            "encoding": json.dumps(enc.to_dict()), "turn": str(bool(getattr(enc, "turns", False))),
            "closed_form": str(bool(getattr(enc, "wrist", False) or getattr(enc, "reach", 0))),
            **({"robot": robot} if robot else {})}
    onnx.helper.set_model_props(model, meta)
    onnx.checker.check_model(model)
    return model


def lab_outputs(controller, goals) -> tuple[np.ndarray, np.ndarray]:
    """(outputs, joints) as the ONNX file computes them, by the lab's own code: each head's outputs
    (heads, n, nq) and their mapping (Encoding.mapped), before any turn, head choice or closed form."""
    enc = controller.encoding
    if getattr(controller, "heads", 1) > 1:
        A = controller.head_outputs(goals)
    else:  # one head: outputs() is the network's (the head choice is a multi-head network's)
        A = np.asarray(controller.outputs(goals))[None]
    return A, getattr(enc, "position", enc).mapped(A)


def check(model, controller, goals) -> float:
    """The largest difference between onnxruntime's outputs and joints and the lab's on goals;
    ValueError when it is above TOLERANCE."""
    import onnxruntime

    session = onnxruntime.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    got = session.run(["outputs", "joints"], {"goals": np.ascontiguousarray(goals, dtype=np.float64)})
    want = lab_outputs(controller, goals)
    worst = max(float(np.max(np.abs(a - b))) if a.size else 0.0 for a, b in zip(got, want))
    if not worst <= TOLERANCE:
        raise ValueError(f"the ONNX model differs from the lab's network by {worst:.3g} (more than {TOLERANCE:g})")
    return worst


def save(controller, path, goals=None, robot: str | None = None) -> float | None:
    """Write the controller's network to `path` (.onnx); with goals and onnxruntime installed, checked
    against the lab's own outputs first (the largest difference returned; None when not checked)."""
    import os

    model = to_onnx(controller, robot=robot)
    worst = None
    if goals is not None:
        try:
            import onnxruntime  # noqa: F401
        except ImportError:
            worst = None
        else:
            worst = check(model, controller, goals)
    tmp = f"{path}.tmp"
    with open(tmp, "wb") as f:
        f.write(model.SerializeToString())
    os.replace(tmp, path)
    return worst


def left_out(controller) -> list[str]:
    """What this controller's answers hold that its ONNX file does not (see the module), in words."""
    enc = controller.encoding
    out = []
    if getattr(enc, "turns", False) and getattr(getattr(enc, "position", enc), "turn", None) is not None:
        out.append("the first joint's turn toward the goal's bearing")
    if getattr(controller, "heads", 1) > 1:
        out.append(f"the choice among its {controller.heads} heads (the nearest by forward kinematics)")
    if getattr(enc, "wrist", False):
        out.append("the closed-form wrist (the last three joints)")
    if getattr(enc, "reach", 0):
        out.append(f"the closed-form reach ({enc.reach} passes: the shoulder and the elbow)")
    out.append("the refinement of lab.solve")
    return out
