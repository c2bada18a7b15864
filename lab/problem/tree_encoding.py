"""How a tree's goals enter a network: one position per end effector, every effector's inputs side by side.

A tree (robots' trees: a biped's feet, a quadruped's four feet, a hand's fingertips, a humanoid's
hands and feet) has E end effectors; a goal is (E, m), one position per effector, and the network
answers all nq joints at once (the output mapping is Encoding's, unchanged). The inputs are E blocks,
effector e's block the features of goal e alone, each scaled to [-1, 1] by the range of that
effector's own workspace:

    "cartesian"   goal e's task coordinates (scaled by arm.workspace_bounds[e]);
    any other of encoding.FEATURES: the serial arm's features of that name, taken in effector e's
                  limb frame instead of the base frame. The limb is the chain of joints that move
                  effector e (arm.chain.path(e), root first); its first joint hangs from the fixed
                  root, so its axis is fixed in space: the limb frame has its origin on that axis (the
                  point the kinematics place the joint at), its z along the axis, and its x toward the
                  circular mean bearing of the effector's workspace about the axis (so that a bearing's
                  seam at +-pi lies behind the limb). So "polar" adds the distance r of the goal from
                  the limb's first axis and its bearing about it; "reach" the slack of r; "sphere" the
                  distance rho from the centre of the smallest sphere on that axis that holds the
                  effector's workspace (near a leg's hip: its knee goes as the fold of rho), its slack
                  and elevation; "bearings" the bearing from behind too; "cylindrical" r, phi and the
                  height along the axis. Their task coordinates are then the limb frame's.

Outputs: Encoding's mapping, with every joint whose range exceeds a full turn (solo12's +-10 rad)
mapped as a continuous joint (two turns about its middle, wrapped into the turn about its middle):
one output then sweeps every angle without spanning the three turns of such a range.

The turn (turn=True): the first joint of every limb that moves one effector alone (a leg's hip, a
finger's first joint; not g1's waist, which moves both hands) is turned in closed form toward that
effector's goal, as a serial arm's first joint is (lab/problem/encoding.py), on that effector's own
chain. The network's output for such a joint only chooses among whole turns and limits; the other
joints answer the goal's distance from that joint's axis and its height along it.

Goals of any other shape than (n, E, m) are refused, naming the shape expected. A multi-head network
on a tree is wired (lab/problem/wiring.py) and each limb group answers with its own head
(lab.problem.controllers.TreeHeads).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import robots
from lab.problem import kernels
from lab.problem.encoding import FEATURES, Encoding, _enclosing_sphere, _raw_features

_LIMB_FIELDS = ("limb_origin", "limb_frame", "limb_r_max", "limb_z_c", "limb_rho_max", "limb_facing")
_TREE_FIELDS = kernels.TREE_FIELDS
_FEATURE_COUNT = {"cartesian": 3, "polar": 5, "cylindrical": 3, "reach": 6, "sphere": 9, "bearings": 10}


@dataclass(frozen=True, eq=False)
class TreeEncoding(Encoding):
    """Encoding of a tree of `effectors` end effectors: in_lo/in_hi hold the E blocks of inputs one after
    the other; the limb_* arrays (one row per effector) place each effector's limb frame (see the module)."""

    effectors: int = 2
    limb_origin: np.ndarray | None = None  # (E, 3) a point of the first axis of each effector's limb
    limb_frame: np.ndarray | None = None  # (E, 3, 3) the limb frame's axes as columns (z: the first axis)
    limb_r_max: np.ndarray | None = None  # (E,) the largest distance from the first axis ("reach" and beyond)
    limb_z_c: np.ndarray | None = None  # (E,) the height on that axis of the workspace's smallest sphere ("sphere")
    limb_rho_max: np.ndarray | None = None  # (E,) that sphere's radius
    limb_facing: np.ndarray | None = None  # (E,) "bearings": the bearing the limb faces most (0: its x axis)

    def __post_init__(self):
        E = self.effectors
        if isinstance(E, bool) or not isinstance(E, (int, np.integer)) or E < 2:
            raise ValueError(f"a tree's encoding needs at least 2 effectors, got {E!r}")
        object.__setattr__(self, "effectors", int(E))
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        if tuple(self.task_axes) != (0, 1, 2):
            raise ValueError(f"a tree's encoding needs the task axes x, y, z, got {self.task_axes!r}")
        if self.turn is not None:
            self._check_tree_turn()
        if not 0 <= self.margin < 10:
            raise ValueError(f"margin must be in [0, 10), got {self.margin!r}")
        wrap = np.zeros(len(self.q_lo), bool) if self.wrap is None else np.asarray(self.wrap, bool).reshape(-1)
        if wrap.shape != (len(self.q_lo),):
            raise ValueError(f"wrap must hold one flag per joint ({len(self.q_lo)}), got {len(wrap)}")
        object.__setattr__(self, "wrap", wrap)
        object.__setattr__(self, "axis_xy", np.zeros(2))
        shapes = {"limb_origin": (E, 3), "limb_frame": (E, 3, 3), "limb_r_max": (E,), "limb_z_c": (E,),
                  "limb_rho_max": (E,), "limb_facing": (E,)}
        for name, shape in shapes.items():
            value = getattr(self, name)
            a = np.zeros(shape) if value is None else np.asarray(value, dtype=np.float64)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be {shape} finite numbers, got shape {a.shape}")
            object.__setattr__(self, name, a)
        n_in = E * _FEATURE_COUNT[self.features]
        for lo, hi, n, what in ((self.in_lo, self.in_hi, n_in, f"input ranges ({self.features}, {E} effectors)"),
                                (self.q_lo, self.q_hi, len(self.q_lo), "joint ranges")):
            if not (lo.shape == hi.shape == (n,) and np.all(np.isfinite(lo) & np.isfinite(hi)) and np.all(lo < hi)):
                raise ValueError(f"{what} must be {n} finite (lo < hi) pairs, got lo {lo.tolist()}, hi {hi.tolist()}")

    def _check_tree_turn(self) -> None:
        E = self.effectors
        turn = np.ascontiguousarray(np.asarray(self.turn, dtype=np.float64))
        if turn.shape != (E, 10) or not np.all(np.isfinite(turn)) or not np.all(np.isin(turn[:, 0], (0.0, 1.0))) \
                or not turn[:, 0].any():
            raise ValueError(f"a tree's turn must be {E} rows of 10 finite numbers [on (0 or 1), axis point (3), axis "
                             f"direction (3), lower, upper, continuous], one row on at least, got {self.turn!r}")
        on = turn[:, 0] == 1.0
        if np.any(np.abs(np.linalg.norm(turn[on, 4:7], axis=1) - 1.0) > 1e-9):
            raise ValueError("a tree's turn needs a unit axis direction for every turned effector")
        if self.chain is None:
            raise ValueError("an encoding that turns a tree's limbs needs the tree's kinematic arrays (kernels.pack_tree)")
        chain = kernels.check_tree(self.chain, len(self.q_lo), E)
        joints, starts = chain[5], chain[6]
        paths = [joints[starts[e]:starts[e + 1]] for e in range(E)]
        for e in np.flatnonzero(on):
            if any(paths[e][0] in paths[f] for f in range(E) if f != e):
                raise ValueError(f"effector {e}'s first joint (joint {paths[e][0]}) moves other effectors too: "
                                 "only a limb that moves one effector alone is turned")
        object.__setattr__(self, "turn", turn)
        object.__setattr__(self, "chain", chain)

    @property
    def turn_spec(self) -> np.ndarray:
        """The turns as the tree kernels take them: (E, 10), a row per effector (all unset when off)."""
        return self.turn if self.turn is not None else np.zeros((self.effectors, 10))

    @property
    def turned_joints(self) -> np.ndarray:
        """The joints turned in closed form (the first joint of every turned effector's limb), ascending."""
        if self.turn is None:
            return np.zeros(0, np.int64)
        joints, starts = self.chain[5], self.chain[6]
        return np.unique([joints[starts[e]] for e in range(self.effectors) if self.turn[e, 0] == 1.0]).astype(np.int64)

    @staticmethod
    def turns_for(arm: robots.Arm) -> np.ndarray:
        """(E, 10): each effector's limb's first joint (on the fixed root) as its turn, [1, axis point,
        axis direction, lower, upper, continuous] (kernels.NO_TURN's layout); a joint of more than a
        turn between its limits (solo12's) is turned as a continuous one into the turn about its
        middle, as mapped() wraps it. Not turned (the row unset): a prismatic first joint, and one that
        moves other effectors too (g1's waist: turning it for both hands made the hands worse, docs/log.md)."""
        moves = [set(int(j) for j in arm.chain.path(e)) for e in range(arm.n_effectors)]
        shared = {j for e, js in enumerate(moves) for j in js if any(j in moves[f] for f in range(len(moves)) if f != e)}
        rows = []
        for e in range(arm.n_effectors):
            k = int(arm.chain.path(e)[0])
            if arm.is_prismatic[k] or k in shared:
                rows.append(np.zeros(10))
                continue
            rot, pos = arm.chain.effector_arrays(e)[:2]
            w = np.asarray(rot[0], dtype=np.float64)[:, 2]
            lo, hi, cont = float(arm.lower[k]), float(arm.upper[k]), bool(arm.chain.continuous[k])
            if cont or hi - lo > 2 * np.pi + 1e-9:
                mid = 0.5 * (lo + hi)
                lo, hi, cont = mid - np.pi, mid + np.pi, True
            rows.append(np.concatenate([[1.0], np.asarray(pos[0], dtype=np.float64), w / np.linalg.norm(w),
                                        [lo, hi, float(cont)]]))
        return np.asarray(rows)

    @classmethod
    def for_arm(cls, arm: robots.Arm, features: str = "cartesian", margin: float = 0.0,
                turn: bool = False) -> "TreeEncoding":
        if not arm.is_tree:
            raise ValueError(f"{arm.name} has one end effector: its encoding is Encoding.for_arm's "
                             "(lab.problem.encoding_for picks the kind of any arm)")
        if features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {features!r}")
        goals = arm.sample_goals(20_000, seed=12345)  # (N, E, 3), the samples of arm.workspace_bounds
        limbs = {name: [] for name in _LIMB_FIELDS}
        for e in range(arm.n_effectors):
            origin, frame = _limb_frame(arm, e, goals[:, e])
            local = (goals[:, e] - origin) @ frame
            r = np.hypot(local[:, 0], local[:, 1])
            z_c, rho_max = _enclosing_sphere(local)
            facing = float(np.angle(np.mean(np.exp(1j * np.arctan2(local[:, 1], local[:, 0])))))
            for name, value in zip(_LIMB_FIELDS, (origin, frame, float(r.max()), z_c, rho_max, facing)):
                limbs[name].append(value)
        limbs = {name: np.asarray(v, dtype=np.float64) for name, v in limbs.items()}
        raw = _tree_features(goals, features, limbs)
        lo, hi = raw.min(axis=0), raw.max(axis=0)
        flat = hi - lo < 1e-9
        lo, hi = np.where(flat, lo - 0.5, lo), np.where(flat, hi + 0.5, hi)
        # a joint that turns more than a turn between its limits (solo12's +-10 rad) is mapped as a
        # continuous one: two turns about its middle, taken modulo a turn into its range
        wrap = np.asarray(arm.chain.continuous, bool) | ((arm.upper - arm.lower) > 2 * np.pi + 1e-9)
        turns, tree = (cls.turns_for(arm), tree_arrays(arm)) if turn else (None, None)
        return cls(features, tuple(arm.task_axes), lo, hi, arm.lower.copy(), arm.upper.copy(), float(margin),
                   wrap=wrap, turn=turns, chain=tree, effectors=arm.n_effectors, **limbs)

    def mapped(self, a: np.ndarray) -> np.ndarray:
        """Encoding's output mapping, with a wrapped joint taken modulo a turn into the turn about its
        middle (its range's whole turn when it is continuous): a joint of a wider range then lies away
        from its limits, where a refinement's steps are not held (the same pose: the kinematics are
        periodic in it)."""
        a = np.asarray(a, dtype=np.float64)
        if not self.wrap.any():
            return super().mapped(a)
        q = self.q_offset + (a + 1.0) * self.q_scale
        mid = 0.5 * (self.q_lo + self.q_hi)
        q = np.where(self.wrap, mid - np.pi + np.mod(q - mid + np.pi, 2 * np.pi), q)
        return np.clip(q, self.q_lo, self.q_hi)

    def turned(self, q: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """Joint values q (..., n, nq) with every turned limb's first joint turned toward goals (n, E, 3)."""
        goals = np.asarray(goals, dtype=np.float64)
        q = np.asarray(q, dtype=np.float64)
        nq = len(self.q_lo)
        if goals.ndim != 3 or goals.shape[1:] != (self.effectors, 3) or q.ndim < 2 or q.shape[-2:] != (len(goals), nq):
            raise ValueError(f"the turn needs joint values (..., {len(goals)}, {nq}) for goals (n, {self.effectors}, 3), "
                             f"got joint values {q.shape} for goals {goals.shape}")
        QT = np.ascontiguousarray(q.reshape(-1, nq).T)
        goalsT = goals.reshape(len(goals), -1).T
        tiled = np.ascontiguousarray(np.tile(goalsT, (1, QT.shape[1] // len(goals))))
        kernels.tree_turn_joints(QT, tiled, self.chain, self.turn)
        return QT.T.reshape(q.shape)

    @property
    def input_names(self) -> list[str]:
        """One short label per network input: the serial arm's, numbered by effector (x1, y1, ..., x2, ...)."""
        task = ["x", "y", "z"]
        one = {"cartesian": task, "polar": task + ["r", "φ"], "cylindrical": ["r", "φ", "z"],
               "reach": task + ["r", "φ", "s"], "sphere": task + ["r", "φ", "s", "ρ", "ψ", "σ"],
               "bearings": task + ["r", "φ", "s", "ρ", "ψ", "σ", "φ′"]}[self.features]
        return [f"{name}{e + 1}" for e in range(self.effectors) for name in one]

    def inputs(self, goals: np.ndarray) -> np.ndarray:
        """Goals (n, E, 3) -> network inputs (n, n_inputs) in about [-1, 1]."""
        goals = np.asarray(goals, dtype=np.float64)
        if goals.ndim != 3 or goals.shape[1:] != (self.effectors, len(self.task_axes)):
            raise ValueError(f"goals of a tree of {self.effectors} end effectors must have shape "
                             f"(n, {self.effectors}, {len(self.task_axes)}) (one position per effector), "
                             f"got {goals.shape}")
        raw = _tree_features(goals, self.features, {name: getattr(self, name) for name in _LIMB_FIELDS})
        return 2.0 * (raw - self.in_lo) / (self.in_hi - self.in_lo) - 1.0

    def to_dict(self) -> dict:
        return {
            "features": self.features, "task_axes": list(self.task_axes),
            "in_lo": self.in_lo.tolist(), "in_hi": self.in_hi.tolist(),
            "q_lo": self.q_lo.tolist(), "q_hi": self.q_hi.tolist(), "margin": self.margin,
            **({"wrap": self.wrap.tolist()} if self.wrap.any() else {}),
            "effectors": self.effectors, **{name: getattr(self, name).tolist() for name in _LIMB_FIELDS},
            **({"turn": self.turn.tolist(), "tree": dict(zip(_TREE_FIELDS, (np.asarray(x).tolist() for x in self.chain)))}
               if self.turn is not None else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "TreeEncoding":
        return cls(d["features"], tuple(d["task_axes"]),
                   *(np.atleast_1d(np.asarray(d[k], float)) for k in ("in_lo", "in_hi", "q_lo", "q_hi")),
                   float(d.get("margin", 0.0)), wrap=d.get("wrap"), effectors=d["effectors"],
                   turn=d.get("turn"), chain=None if "tree" not in d else tuple(d["tree"][k] for k in _TREE_FIELDS),
                   **{name: d[name] for name in _LIMB_FIELDS})


def tree_arrays(arm: robots.Arm) -> tuple:
    """A tree as the tree kernels take it (lab.problem.kernels.pack_tree): each effector's own serial
    chain (arm.chain.effector_arrays(e)) on its path (arm.chain.path(e))."""
    E = arm.n_effectors
    return kernels.pack_tree([arm.chain.effector_arrays(e) for e in range(E)], [arm.chain.path(e) for e in range(E)],
                             arm.nq)


def _limb_frame(arm: robots.Arm, e: int, goals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), frame (3, 3)) of effector e's limb: the first joint of its path, whose parent is
    the fixed root (its placement is where the kinematics put it, its axis the joint frame's z),
    x toward the circular mean bearing of the effector's goals about that axis."""
    k = int(arm.chain.path(e)[0])
    origin = np.asarray(arm.chain.pos[k], dtype=np.float64).copy()
    w = np.asarray(arm.chain.rot[k], dtype=np.float64)[:, 2]
    w = w / np.linalg.norm(w)
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]  # the world axis least along w
    x = np.cross(helper, w)
    x /= np.linalg.norm(x)
    y = np.cross(w, x)
    d = goals - origin
    mean = np.angle(np.mean(np.exp(1j * np.arctan2(d @ y, d @ x))))
    x, y = np.cos(mean) * x + np.sin(mean) * y, -np.sin(mean) * x + np.cos(mean) * y
    return origin, np.column_stack([x, y, w])


def _tree_features(goals: np.ndarray, features: str, limbs: dict) -> np.ndarray:
    """(n, E * per-effector features): each effector's block, goals (n, E, 3)."""
    blocks = []
    for e in range(goals.shape[1]):
        if features == "cartesian":
            blocks.append(goals[:, e])
            continue
        local = (goals[:, e] - limbs["limb_origin"][e]) @ limbs["limb_frame"][e]
        blocks.append(_raw_features(local, features, 3, limbs["limb_r_max"][e], limbs["limb_z_c"][e],
                                    limbs["limb_rho_max"][e], (0.0, 0.0), limbs["limb_facing"][e]))
    return np.concatenate(blocks, axis=1)

