"""The pose problem: training and held-out pose goals of one real arm, and the pose fitness.

Goals are tool frames (n, 4, 4) of uniformly random joint vectors (robots.pose.sample_poses: the
same joint vectors as the position problem's goals of that seed). The fitness of a controller is
the mean over the goals of

    ||p - p_g||^2 + (L theta)^2

theta the geodesic angle between the tool's rotation and the goal's (the SO arms: between the
approach axes), L the encoding's weight in metres per radian (lab.problem.pose_encoding). It is
compiled as the position fitness is (lab.problem.pose_kernels), threads and slices alike, so a
generation costs about what a position generation costs. `PoseProblem` answers what methods ask of
a `Problem`: mlp_mse (with heads), program_mse / graphs_mse (NEAT's graphs), mlp_gradient (the
gradient method: the pose Jacobian, robots.pose.fk_pose_and_jacobian) and controller_mse.
"""

from __future__ import annotations

import numpy as np

import robots
from lab.problem.controllers import Controller, compile_programs
from lab.problem.fitness import RESAMPLE_STREAM, _MIN_SLICE, Problem, _pool, _t
from lab.problem import pose_kernels
from lab.problem.pose_encoding import PoseEncoding

DISPLAY_SEED = 7  # the pose goal a run's recording draws its population's reach for


class PoseProblem(Problem):
    """Training and held-out pose goals of one arm, with batched pose fitness evaluation."""

    goal = "pose"

    def __init__(self, arm: robots.Arm, encoding: PoseEncoding, targets: int = 300, test_goals: int = 1000,
                 goal_seed: int = 0, resample_seed: int | None = None, threads: int | None = None):
        if not isinstance(encoding, PoseEncoding):
            raise ValueError(f"a pose problem needs a PoseEncoding, got {type(encoding).__name__}")
        super().__init__(arm, encoding, targets=targets, test_goals=test_goals, goal_seed=goal_seed,
                         resample_seed=resample_seed, threads=threads)
        self._chain = encoding.chain
        self._spec = encoding.spec()

    def _sample_goals(self, n: int, seed: int) -> np.ndarray:
        from robots import pose

        return pose.sample_poses(self.arm, n, seed=seed)

    def _arrays(self, poses: np.ndarray) -> tuple:
        return (_t(self.encoding.inputs(poses)), *self.encoding.goal_arrays(poses))

    def draw_goals(self, generation: int) -> None:
        from robots import pose

        seq = np.random.SeedSequence([self.goal_seed, RESAMPLE_STREAM, int(self.resample_seed), int(generation)])
        self.train_goals = pose.sample_poses(self.arm, len(self.reference_goals), seed=int(seq.generate_state(1)[0]))
        self._train = self._arrays(self.train_goals)

    def display_goals(self) -> np.ndarray:
        """(1, 4, 4) the pose a run's recording draws its candidates' reach for."""
        from robots import pose

        return pose.sample_poses(self.arm, 1, seed=DISPLAY_SEED)

    def mlp_mse(self, W: np.ndarray, hidden: int, test: bool = False, offsets: np.ndarray | None = None) -> np.ndarray:
        """The pose fitness of every MLP weight vector in W (P, D): (P,); offsets as Problem.mlp_mse's."""
        XT, GP, GR = self._split(test)
        W = np.ascontiguousarray(W, dtype=np.float64)
        offsets = np.zeros(self.encoding.n_outputs) if offsets is None else np.ascontiguousarray(offsets, np.float64)
        out = np.empty(len(W))
        heads = len(offsets) // self.encoding.n_outputs
        args = (GP, GR)
        slices = min(self.threads, heads * len(W) * XT.shape[1] // _MIN_SLICE, len(W))
        if slices <= 1:
            pose_kernels.pose_mlp_mse(XT, *args, W, int(hidden), offsets, self._qmap, self._chain, self._spec, out)
            return out
        edges = np.linspace(0, len(W), slices + 1).astype(int)
        jobs = [_pool(slices).submit(pose_kernels.pose_mlp_mse, XT, *args, W[a:b], int(hidden), offsets, self._qmap,
                                     self._chain, self._spec, out[a:b]) for a, b in zip(edges[:-1], edges[1:])]
        for job in jobs:
            job.result()
        return out

    def program_mse(self, program: tuple, test: bool = False) -> np.ndarray:
        """The pose fitness of every graph of a compiled program: (P,)."""
        XT, GP, GR = self._split(test)
        out = np.empty(len(program[0]))
        pose_kernels.pose_graph_mse(XT, GP, GR, program, self._qmap, self._chain, self._spec, out)
        return out

    def graphs_mse(self, graphs, test: bool = False) -> np.ndarray:
        return self.program_mse(compile_programs(graphs), test)

    def wired_mse(self, G, wiring, test: bool = False):
        raise ValueError("wired networks are for trees; pose goals are for a serial arm")

    def outputs_mse(self, A: np.ndarray, test: bool = False) -> np.ndarray:
        """The pose fitness of network outputs A (P, n, nq) in [-1, 1]: (P,)."""
        goals = self.test_goals if test else self.train_goals
        q = self.encoding.joints(np.asarray(A, dtype=np.float64), goals)
        return np.mean(self.encoding.sq_errors(q, goals), axis=-1)

    def mlp_gradient(self, w: np.ndarray, hidden: int, test: bool = False) -> tuple[float, np.ndarray]:
        """(fitness, d fitness / d w) of one MLP weight vector w (D,) on the pose goals.

        The loss of a goal is ||p - p_g||^2 + L^2 theta^2. With the tool's angular velocity w = J_w dq
        (robots.pose.pose_jacobian, LOCAL_WORLD_ALIGNED): d theta^2 = 2 phi . w, phi = log3(R R_g^T)
        (the inverse left Jacobian of SO(3) leaves phi unchanged: J^-T phi = phi); an approach axis a
        toward g: d theta = -n . w, n = (a x g) / |a x g|. A turned first joint: its output's gradient
        is dropped and the others' taken at the turned joints (the position part is stationary in it
        there; the angle is not, so this is the gradient with the first joint held)."""
        from robots import pose

        enc = self.encoding
        goals = self.test_goals if test else self.train_goals
        X = self._split(test)[0].T
        n = X.shape[0]
        layers = self._mlp_forward(X, w, hidden)
        q = layers[-1]
        if enc.turns:
            q = enc.finished(q, goals)
        T, J = pose.fk_pose_and_jacobian(self.arm, q)
        dp = T[:, :3, 3] - goals[:, :3, 3]
        if enc.axis is None:
            Rerr = T[:, :3, :3] @ np.swapaxes(goals[:, :3, :3], 1, 2)
            phi = _log3(Rerr)
            ang2 = np.sum(phi * phi, axis=1)
            g_ang = 2.0 * phi  # d theta^2 / d omega
        else:
            a, g = T[:, :3, :3] @ enc.axis, goals[:, :3, :3] @ enc.axis
            cross = np.cross(a, g)
            s = np.linalg.norm(cross, axis=1)
            theta = np.arctan2(s, np.sum(a * g, axis=1))
            nvec = cross / np.where(s > 1e-300, s, 1.0)[:, None]
            ang2 = theta * theta
            g_ang = -2.0 * theta[:, None] * nvec
        L2 = enc.weight ** 2
        loss = float(np.mean(np.sum(dp * dp, axis=1) + L2 * ang2))
        dq = (2.0 * np.einsum("gk,gkj->gj", dp, J[:, :3]) + L2 * np.einsum("gk,gkj->gj", g_ang, J[:, 3:])) / n
        return (loss if np.isfinite(loss) else np.inf), self._mlp_backward(X, layers, dq)

    def controller_mse(self, controller: Controller, goals: np.ndarray | None = None) -> float:
        """The pose fitness of one controller on pose goals (the fixed training goals by default)."""
        goals = self.reference_goals if goals is None else goals
        return float(np.mean(self.encoding.sq_errors(controller(goals), goals)))


def _log3(R: np.ndarray) -> np.ndarray:
    """(n, 3) the rotation vectors of rotations R (n, 3, 3) (robust near 0; near pi by the diagonal)."""
    sk = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = 0.5 * np.linalg.norm(sk, axis=1)
    c = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    theta = np.arctan2(s, c)
    small = s < 1e-9
    factor = np.where(small, 0.5, theta / (2.0 * np.where(small, 1.0, s)))
    phi = sk * factor[:, None]
    near_pi = small & (c < 0)
    if near_pi.any():  # the axis from the diagonal: R = 2 u u^T - I
        for i in np.flatnonzero(near_pi):
            B = 0.5 * (R[i] + np.eye(3))
            k = int(np.argmax(np.diag(B)))
            u = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
            phi[i] = np.pi * u / np.linalg.norm(u)
    return phi


def pose_problem(arm: robots.Arm, features: str, margin: float, turn: bool, targets: int, test_goals: int,
                 goal_seed: int, resample_seed: int | None = None, reach: int | None = None) -> PoseProblem:
    """A run's pose problem: its encoding (PoseEncoding.for_arm; reach None: the arm's default) and goals."""
    enc = PoseEncoding.for_arm(arm, features, margin, turn, reach=reach)
    return PoseProblem(arm, enc, targets=targets, test_goals=test_goals, goal_seed=goal_seed,
                       resample_seed=resample_seed)
