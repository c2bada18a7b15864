"""How goals enter a network and how its outputs become joint values.

Inputs (features):
    "cartesian"  the goal's task coordinates, each scaled to [-1, 1] by the workspace bounds
                 (the paper's encoding);
    "polar"      the same, plus the goal's distance from the base axis r = hypot(x - x_a, y - y_a) and
                 its bearing phi = atan2(y - y_a, x - x_a), both scaled to [-1, 1] by their ranges over
                 the workspace; (x_a, y_a) = axis_xy, where the arm's first joint axis (upright within NEARLY_UPRIGHT)
                 crosses the x-y plane (arm.base_axis): the origin on most arms, 4-5 cm beside it on
                 the SO arms, whose base joint then turns phi alone;
    "cylindrical"  r and phi in place of x and y (then z, for 3D goals): as many inputs as
                 "cartesian", in the coordinates of an arm whose first joint turns about z;
    "reach"      "polar" plus the slack of reach s = sqrt(1 - r / r_max) (0 beyond r_max), r_max the
                 largest r of the workspace. Near full reach an arm's inverse kinematics has a fold:
                 the elbow angle goes as acos(r / r_max) ~ sqrt(2 (1 - r / r_max)), whose slope in r
                 is unbounded; in s it is almost linear (the SCARA's theta2 = 2 acos(1 - s^2) is
                 within 6% of 2.83 s over its range), so a small tanh network needs no steep units.
    "sphere"     "reach" plus the same fold about the shoulder, for an arm in space (3 task axes):
                 rho = |g - c|, the distance from the centre c = (0, 0, z_c) of the smallest sphere
                 about the base axis that holds the workspace (near the shoulder of a yaw-pitch arm:
                 its elbow angle goes as acos of rho), its slack sqrt(1 - rho / rho_max), and the
                 elevation atan2(z - z_c, r). The outer shell of a 3D arm's workspace, where the
                 cylinder's slack s says nothing, held most of a UR5's refinement failures with
                 "reach" inputs (docs/log.md).
    "bearings"   "sphere" with the bearing twice: phi measured from the bearing the arm faces most
                 (`facing`: the circular mean bearing of the workspace's goals, 0 where it faces +x),
                 so that its seam at +-pi lies behind the arm, and phi' measured from the opposite
                 bearing, its seam in front. An arm whose base turns less than a full turn (the SO
                 arms: +-110-115 degrees) reaches the goals behind it folded back over its shoulder,
                 its base turned to phi -+ pi, and phi's seam runs through those goals; phi' has none
                 there (SO101's default: docs/results/real-arms.md).
Outputs: a network output a in [-1, 1] maps linearly onto the joint range widened by a
margin m on each side, then clipped to the limits (a continuous joint: see below):
    q = clip(lower - m h + (a + 1) (1 + m) h, lower, upper),   h = (upper - lower) / 2.
m = 0 is the paper's mapping (q = lower + (a + 1) h). With m > 0 a tanh output reaches a joint
limit at a finite pre-activation: the paper's goals are drawn uniformly in joint space, so many
sit at a limit, where m = 0 asks the output tanh to saturate.
A continuous joint (no limit: an angle in [-pi, pi] here) maps onto two turns, [c - 2 pi, c + 2 pi]
(c its range's middle), and is turned by whole turns into its range instead of clipped: the network
can then reach every angle from either side, with no seam where -pi meets pi (the Kinova has
three continuous joints; what this mapping gained there: docs/log.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

import robots
from lab.problem import kernels

FEATURES = ("cartesian", "polar", "cylindrical", "reach", "sphere", "bearings")
_N_EXTRA = {"cartesian": 0, "polar": 2, "cylindrical": 0, "reach": 3, "sphere": 6, "bearings": 7}  # beyond the task axes
_SPHERE = ("sphere", "bearings")  # the inputs that need the workspace's sphere about the base axis
_REACH = ("reach", *_SPHERE)  # and those that need r_max
# r and phi are taken about the base axis where it stands within this of upright (1 - |cos tilt|: about
# 0.8 degrees): a URDF's rounding tilts an axis meant to be vertical (bluevolta_bravo7's by 0.09
# degrees, 0.89 m from the origin); about the origin instead, its inputs were 7x worse (docs/log.md)
NEARLY_UPRIGHT = 1e-4


@dataclass(frozen=True, eq=False)
class Encoding:
    """Input scaling and output mapping of one arm (all arrays float64)."""

    features: str
    task_axes: tuple[int, ...]
    in_lo: np.ndarray  # (ni,) raw feature value that maps to -1
    in_hi: np.ndarray  # (ni,) raw feature value that maps to +1
    q_lo: np.ndarray  # (nq,) joint lower limits
    q_hi: np.ndarray  # (nq,) joint upper limits
    margin: float = 0.0  # output range widening (fraction of the half range), then clipped
    r_max: float = 0.0  # "reach": the largest distance from the base axis in the workspace
    wrap: np.ndarray | None = None  # (nq,) True for a continuous joint: two turns, wrapped (None: none)
    z_c: float = 0.0  # "sphere": the height of the centre of the workspace's smallest sphere about the base axis
    rho_max: float = 0.0  # "sphere": that sphere's radius
    axis_xy: np.ndarray | None = None  # (2,) where the arm's base axis crosses the x-y plane: r and phi are about it
    facing: float = 0.0  # "bearings": the bearing [rad] the arm faces most; phi is measured from it
    turn: np.ndarray | None = None  # (10,) the first joint's closed-form turn (kernels.NO_TURN's layout); None: off
    chain: tuple | None = None  # the arm's kinematic arrays (kernels' chain), needed by the turn

    def __post_init__(self):
        wrap = np.zeros(len(self.q_lo), bool) if self.wrap is None else np.asarray(self.wrap, bool).reshape(-1)
        if wrap.shape != (len(self.q_lo),):
            raise ValueError(f"wrap must hold one flag per joint ({len(self.q_lo)}), got {len(wrap)}")
        object.__setattr__(self, "wrap", wrap)
        axis_xy = np.zeros(2) if self.axis_xy is None else np.asarray(self.axis_xy, dtype=np.float64).reshape(-1)
        if axis_xy.shape != (2,) or not np.all(np.isfinite(axis_xy)):
            raise ValueError(f"axis_xy must be 2 finite coordinates, got {self.axis_xy!r}")
        object.__setattr__(self, "axis_xy", axis_xy)
        if self.turn is not None:
            self._check_turn()
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        if not 0 <= self.margin < 10:
            raise ValueError(f"margin must be in [0, 10), got {self.margin!r}")
        m = len(self.task_axes)
        if not (1 <= m <= 3 and len(set(self.task_axes)) == m and all(a in (0, 1, 2) for a in self.task_axes)):
            raise ValueError(f"task_axes must be distinct axes among 0, 1, 2, got {self.task_axes!r}")
        if not (np.isfinite(self.facing) and -np.pi <= self.facing <= np.pi):
            raise ValueError(f"facing must be a bearing in [-pi, pi], got {self.facing!r}")
        if self.features in _REACH and not (np.isfinite(self.r_max) and self.r_max > 0):
            raise ValueError(f"{self.features} features need a positive r_max, got {self.r_max!r}")
        if self.features in _SPHERE and not (m == 3 and np.isfinite(self.z_c) and np.isfinite(self.rho_max)
                                             and self.rho_max > 0):
            raise ValueError(f"sphere features need 3 task axes, a finite z_c and a positive rho_max, got "
                             f"{m} axes, z_c {self.z_c!r}, rho_max {self.rho_max!r}")
        n_in = _N_EXTRA[self.features] + m
        for lo, hi, n, what in ((self.in_lo, self.in_hi, n_in, f"input ranges ({self.features}, {m} task axes)"),
                                (self.q_lo, self.q_hi, len(self.q_lo), "joint ranges")):
            if not (lo.shape == hi.shape == (n,) and np.all(np.isfinite(lo) & np.isfinite(hi)) and np.all(lo < hi)):
                raise ValueError(f"{what} must be {n} finite (lo < hi) pairs, got lo {lo.tolist()}, hi {hi.tolist()}")

    def _check_turn(self) -> None:
        turn = np.ascontiguousarray(np.asarray(self.turn, dtype=np.float64).reshape(-1))
        if turn.shape != (10,) or not np.all(np.isfinite(turn)) or turn[0] != 1.0:
            raise ValueError(f"turn must be 10 finite numbers [1, axis point (3), axis direction (3), lower, upper, "
                             f"continuous], got {self.turn!r}")
        if abs(np.linalg.norm(turn[4:7]) - 1.0) > 1e-9 or tuple(self.task_axes) != (0, 1, 2):
            raise ValueError("the turn needs a unit axis direction and the task axes x, y, z")
        if self.chain is None:
            raise ValueError("an encoding that turns its first joint needs the arm's kinematic chain")
        object.__setattr__(self, "turn", turn)
        object.__setattr__(self, "chain", kernels.check_chain(self.chain, len(self.q_lo)))

    @property
    def turns(self) -> bool:
        """Whether the first joint is turned in closed form toward each goal's bearing (see the module)."""
        return self.turn is not None

    @property
    def turn_spec(self) -> np.ndarray:
        """The turn as the kernels take it (kernels.NO_TURN when off)."""
        return self.turn if self.turn is not None else kernels.NO_TURN

    @property
    def turned_joints(self) -> np.ndarray:
        """The joints turned in closed form: the first one when the encoding turns, else none."""
        return np.zeros(1 if self.turn is not None else 0, np.int64)

    @staticmethod
    def turn_for(arm: robots.Arm) -> np.ndarray:
        """The turn of arm's first joint: [1, axis point, axis direction, lower, upper, continuous];
        ValueError when it has none (a prismatic first joint, or fewer than 3 task axes)."""
        if arm.is_prismatic[0] or tuple(arm.task_axes) != (0, 1, 2):
            raise ValueError(f"{arm.name}: the turn needs a revolute first joint and 3 task axes (x, y, z)")
        c, w = arm.base_axis
        return np.concatenate([[1.0], c, w, [arm.lower[0], arm.upper[0], float(arm.chain.continuous[0])]])

    @classmethod
    def for_arm(cls, arm: robots.Arm, features: str = "cartesian", margin: float = 0.0,
                turn: bool = False) -> "Encoding":
        if arm.is_tree:  # several end effectors: one block of inputs per effector (tree_encoding.py)
            raise ValueError(f"{arm.name} is a tree of several end effectors: its encoding is TreeEncoding's "
                             "(lab.problem.encoding_for picks the kind of any arm)")
        goals = arm.sample_goals(20_000, seed=12345)
        # r and phi about the base axis where it stands upright
        upright = abs(arm.base_axis[1][2]) > 1.0 - NEARLY_UPRIGHT
        axis_xy = arm.base_axis[0][:2] if upright and len(arm.task_axes) >= 2 else np.zeros(2)
        about = np.column_stack([goals[:, :2] - axis_xy, goals[:, 2:]]) if goals.shape[1] >= 2 else goals
        r_max = float(np.hypot(about[:, 0], about[:, 1]).max()) if features in _REACH else 0.0
        z_c, rho_max = _enclosing_sphere(about) if features in _SPHERE and goals.shape[1] == 3 else (0.0, 0.0)
        facing = 0.0
        if features == "bearings" and goals.shape[1] >= 2:  # the circular mean of the goals' bearings
            facing = float(np.angle(np.mean(np.exp(1j * np.arctan2(about[:, 1], about[:, 0])))))
        raw = _raw_features(goals, features, len(arm.task_axes), r_max, z_c, rho_max, axis_xy, facing)
        lo, hi = raw.min(axis=0), raw.max(axis=0)
        flat = hi - lo < 1e-9
        lo, hi = np.where(flat, lo - 0.5, lo), np.where(flat, hi + 0.5, hi)
        return cls(features, tuple(arm.task_axes), lo, hi, arm.lower.copy(), arm.upper.copy(), float(margin), r_max,
                   np.asarray(arm.chain.continuous, bool).copy(), z_c, rho_max, axis_xy.copy(), facing,
                   cls.turn_for(arm) if turn else None, arm.chain.arrays if turn else None)

    @property
    def n_inputs(self) -> int:
        return len(self.in_lo)

    @property
    def input_names(self) -> list[str]:
        """One short label per network input, in order."""
        task = ["xyz"[a] for a in self.task_axes]
        return {"cartesian": task, "polar": task + ["r", "φ"], "cylindrical": ["r", "φ"] + task[2:],
                "reach": task + ["r", "φ", "s"], "sphere": task + ["r", "φ", "s", "ρ", "ψ", "σ"],
                "bearings": task + ["r", "φ", "s", "ρ", "ψ", "σ", "φ′"]}[self.features]

    @property
    def n_outputs(self) -> int:
        return len(self.q_lo)

    def inputs(self, goals: np.ndarray) -> np.ndarray:
        """Goals (n, len(task_axes)) -> network inputs (n, n_inputs) in about [-1, 1]."""
        goals = np.asarray(goals, dtype=np.float64)
        if goals.ndim != 2 or goals.shape[1] != len(self.task_axes):
            raise ValueError(f"goals must have shape (n, {len(self.task_axes)}), got {goals.shape}")
        raw = _raw_features(goals, self.features, len(self.task_axes), self.r_max, self.z_c, self.rho_max,
                            self.axis_xy, self.facing)
        return 2.0 * (raw - self.in_lo) / (self.in_hi - self.in_lo) - 1.0

    def compiled_inputs(self, goals: np.ndarray) -> np.ndarray:
        """inputs(goals) computed by kernels.polar_inputs where the features are polar ("reach",
        "sphere", "bearings"; one goal in about 2 us against 17): the same within rounding, not bit
        for bit (numpy's and numba's atan2, hypot and modulo may differ in the last bit), so the pose
        networks take these and the position networks keep inputs(), whose published figures stay."""
        goals = np.asarray(goals, dtype=np.float64)
        mode, k = kernels.POLAR_MODES.get(self.features, -1), goals.shape[-1] if goals.ndim == 2 else 0
        if mode < 0 or k != len(self.task_axes) or k < 2 or (mode > 0 and k != 3):
            return self.inputs(goals)
        out = np.empty((len(goals), len(self.in_lo)))
        kernels.polar_inputs(goals, mode, self.r_max, self.z_c, self.rho_max, float(self.axis_xy[0]),
                             float(self.axis_xy[1]), self.facing, self.in_lo, self.in_hi, out)
        return out

    @functools.cached_property
    def q_offset(self) -> np.ndarray:
        """lower - m h: the joint value an output of -1 maps to before clipping (a continuous joint: c - 2 pi)."""
        mid = 0.5 * (self.q_lo + self.q_hi)
        return np.where(self.wrap, mid - 2 * np.pi, self.q_lo - self.margin * 0.5 * (self.q_hi - self.q_lo))

    @functools.cached_property
    def q_scale(self) -> np.ndarray:
        """(1 + m) h: the change of joint value per unit of output above -1 (a continuous joint: 2 pi)."""
        return np.where(self.wrap, 2 * np.pi, (1.0 + self.margin) * 0.5 * (self.q_hi - self.q_lo))

    @functools.cached_property
    def clip_lo(self) -> np.ndarray:
        """Where the fitness clips joint values from below: the limits (-inf for a continuous joint,
        whose angle forward kinematics takes modulo a turn)."""
        return np.where(self.wrap, -np.inf, self.q_lo)

    @functools.cached_property
    def clip_hi(self) -> np.ndarray:
        return np.where(self.wrap, np.inf, self.q_hi)

    def joints(self, a: np.ndarray, goals: np.ndarray | None = None) -> np.ndarray:
        """Network outputs in [-1, 1] (..., n, nq) -> joint values (..., n, nq) within the limits (NaN
        stays NaN). An encoding that turns its first joint needs the goals (n, 3) the outputs answer."""
        q = self.mapped(a)
        if self.turn is None:
            return q
        if goals is None:
            raise ValueError("this encoding turns the first joint toward each goal's bearing: joints() needs the goals")
        return self.turned(q, goals)

    def mapped(self, a: np.ndarray) -> np.ndarray:
        """The output mapping alone: outputs (..., nq) -> joint values within the limits, before any turn."""
        q = self.q_offset + (np.asarray(a) + 1.0) * self.q_scale
        wraps = self._wraps
        if wraps:  # by whole turns into [lower, lower + 2 pi), then clipped like the others
            turned = self.q_lo + np.mod(q - self.q_lo, 2 * np.pi)
            q = np.where(self.wrap, np.minimum(turned, self.q_hi), q)
        return q if self.margin == 0 and not wraps else np.clip(q, self.q_lo, self.q_hi)

    @functools.cached_property
    def _wraps(self) -> bool:
        """Whether any joint is continuous (computed once: the arrays of a frozen encoding do not change)."""
        return bool(self.wrap.any())

    def turned(self, q: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """Joint values q (..., n, nq) with the first joint turned toward each goal's (n, 3) bearing."""
        goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
        q = np.asarray(q, dtype=np.float64)
        nq = len(self.q_lo)
        if q.ndim < 2 or q.shape[-2:] != (len(goals), nq) or goals.shape[1] != 3:
            raise ValueError(f"the turn needs joint values (..., {len(goals)}, {nq}) for goals (n, 3), got joint "
                             f"values {q.shape} for goals {goals.shape}")
        QT = np.ascontiguousarray(q.reshape(-1, nq).T)
        tiled = np.ascontiguousarray(np.tile(goals.T, (1, QT.shape[1] // len(goals))))
        kernels.turn_first_joint(QT, tiled, self.chain, self.turn)
        return QT.T.reshape(q.shape)

    def to_dict(self) -> dict:
        return {
            "features": self.features, "task_axes": list(self.task_axes),
            "in_lo": self.in_lo.tolist(), "in_hi": self.in_hi.tolist(),
            "q_lo": self.q_lo.tolist(), "q_hi": self.q_hi.tolist(), "margin": self.margin,
            **({"r_max": self.r_max} if self.features in _REACH else {}),
            **({"z_c": self.z_c, "rho_max": self.rho_max} if self.features in _SPHERE else {}),
            **({"facing": self.facing} if self.features == "bearings" else {}),
            **({"wrap": self.wrap.tolist()} if self.wrap.any() else {}),
            **({"axis_xy": self.axis_xy.tolist()} if self.axis_xy.any() else {}),
            **({"turn": self.turn.tolist(), "chain": dict(zip(("rot", "pos", "kind", "identity", "ee_pos"),
                                                              (np.asarray(x).tolist() for x in self.chain)))}
               if self.turn is not None else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Encoding":
        if "effectors" in d:  # a tree's (lab/problem/tree_encoding.py)
            raise ValueError("a tree's encoding (it has effectors): TreeEncoding.from_dict reads it "
                             "(lab.problem.encoding_from_dict reads either kind)")
        return cls(d["features"], tuple(d["task_axes"]),
                   *(np.atleast_1d(np.asarray(d[k], float)) for k in ("in_lo", "in_hi", "q_lo", "q_hi")),
                   float(d.get("margin", 0.0)), float(d.get("r_max", 0.0)), d.get("wrap"),
                   float(d.get("z_c", 0.0)), float(d.get("rho_max", 0.0)), d.get("axis_xy"), float(d.get("facing", 0.0)),
                   d.get("turn"), d.get("chain"))


def _enclosing_sphere(goals: np.ndarray) -> tuple[float, float]:
    """(z_c, rho_max): the centre height and radius of the smallest sphere centred on the base axis
    that holds the goals. max_i |g_i - (0, 0, z)| is convex in z: golden-section search."""
    r2, z = goals[:, 0] ** 2 + goals[:, 1] ** 2, goals[:, 2]

    def radius(zc: float) -> float:
        return float(np.sqrt(np.max(r2 + (z - zc) ** 2)))

    a, b = float(z.min()), float(z.max())
    g = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        c, d = b - g * (b - a), a + g * (b - a)
        if radius(c) < radius(d):
            b = d
        else:
            a = c
    z_c = 0.5 * (a + b)
    return z_c, radius(z_c)


def _raw_features(goals: np.ndarray, features: str, k: int, r_max: float = 0.0, z_c: float = 0.0,
                  rho_max: float = 0.0, axis_xy=(0.0, 0.0), facing: float = 0.0) -> np.ndarray:
    if features == "cartesian":
        return goals
    if k < 2:
        raise ValueError("polar features need at least two task axes")
    x, y = goals[:, 0] - axis_xy[0], goals[:, 1] - axis_xy[1]  # about the base axis
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    if features == "bearings":  # from the bearing the arm faces: the seam behind it
        phi = _wrapped(phi - facing)
    if features == "cylindrical":
        return np.column_stack([r, phi, goals[:, 2:]])
    if features in _REACH:
        if features in _SPHERE and k != 3:
            raise ValueError(f"{features} features need three task axes")
        reach = np.column_stack([goals, r, phi, _slack(r, r_max)])
        if features == "reach":
            return reach
        h = goals[:, 2] - z_c
        rho = np.hypot(r, h)
        sphere = np.column_stack([reach, rho, np.arctan2(h, r), _slack(rho, rho_max)])
        return sphere if features == "sphere" else np.column_stack([sphere, _wrapped(phi - np.pi)])
    return np.column_stack([goals, r, phi])


def _wrapped(angle: np.ndarray) -> np.ndarray:
    """An angle turned by whole turns into [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _slack(d: np.ndarray, d_max: float) -> np.ndarray:
    """sqrt(1 - d / d_max), 0 at the outer shell d = d_max (clipped to [0, 1])."""
    return np.sqrt(np.clip(1.0 - d / d_max, 0.0, 1.0))
