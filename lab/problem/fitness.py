"""The learning problem: an arm, its fixed training goals, held-out goals, and the fitness.

Fitness (paper, section 4.3): the mean over the training goals of ||p - p'||^2, p' the
end-effector position the controller's joint values reach (task coordinates only).
Lower is better; NaN or infinite becomes +inf. A tree of several end effectors (arm.is_tree): goals
(n, E, m), and the error of a goal is the sum over the effectors of ||p_e - p'_e||^2 (the tree kernels,
lab.problem.kernels.tree_mlp_mse and its kin; docs/methods.md).

Resampled training goals (resample_seed not None; TrainConfig.resample): the paper keeps its 70
training goals fixed for the whole run. With resampling, `draw_goals(generation)` replaces them
before every generation by as many new goals, drawn from a stream seeded by (goal_seed, the
run's seed, generation), so a run is still reproducible by its seed. `reference_goals` keeps the
fixed set of goal_seed (the goals a fixed run trains on): fitness values of different generations
are then on different goals, so methods keep their best controller so far by its MSE on the
reference goals (lab.methods.base.Backend._offer).

Threads: a population's MLPs are evaluated in `threads` slices side by side (the kernels release
the GIL; each candidate's MSE is computed the same way whatever slice it is in, so the numbers are
the same bit for bit). The default is LAB_THREADS from the environment, else the cores this process
may use, at most 4. Processes that work beside others set LAB_THREADS=1: the app's training worker
and the Rerun writer (lab.running.pipes.start), parallel experiment runs (lab.experiments.executors).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import robots
from lab.problem import environment, kernels
from lab.problem.controllers import Controller, compile_programs
from lab.problem.encoding import Encoding
from lab.problem.tree_encoding import tree_arrays  # noqa: F401 (the tree kernels' arrays, named here too)

TEST_SEED_OFFSET = 1_000_003  # held-out goals come from another stream than the training goals
RESAMPLE_STREAM = 2_000_003  # resampled training goals: yet another stream
THREADS_VAR = environment.THREADS
MAX_THREADS = 4  # 50 candidates of a few hundred goals: more slices cost more than they save
_MIN_SLICE = 4_000  # network-goal evaluations per slice below which a thread is not worth its hand-off
# (the paper's 50 x 70 stay in one thread; a real arm's 50 x 300 go to two)

_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def default_threads() -> int:
    """LAB_THREADS if set (an integer >= 1; lab.problem.environment.SettingError otherwise), else the
    cores this process may use, at most MAX_THREADS."""
    n = environment.threads()
    if n is not None:
        return n
    return max(1, min(MAX_THREADS, len(os.sched_getaffinity(0))))


def _pool(n: int) -> ThreadPoolExecutor:
    """One shared pool per thread count, made on first use."""
    with _pools_lock:
        pool = _pools.get(n)
        if pool is None:
            pool = _pools[n] = ThreadPoolExecutor(n, thread_name_prefix="lab-fitness")
        return pool


class Problem:
    """Training and held-out goals of one arm, with batched fitness evaluation."""

    def __init__(self, arm: robots.Arm, encoding: Encoding, targets: int = 70, test_goals: int = 1000,
                 goal_seed: int = 0, resample_seed: int | None = None, threads: int | None = None):
        self.arm = arm
        self.threads = default_threads() if threads is None else int(threads)
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads!r}")
        self.encoding = encoding
        self.goal_seed = int(goal_seed)
        self.train_goals = self._sample_goals(targets, self.goal_seed)
        self.reference_goals = self.train_goals  # fixed: what the best so far is kept by when resampling
        self.resample_seed = resample_seed
        self.test_goals = self._sample_goals(test_goals, self.goal_seed + TEST_SEED_OFFSET)
        self._train = self._arrays(self.train_goals)
        self._test = self._arrays(self.test_goals)
        self._axes = np.asarray(arm.task_axes, dtype=np.int64)
        self._qmap = (encoding.q_offset, encoding.q_scale, encoding.clip_lo, encoding.clip_hi, encoding.turn_spec)
        if arm.is_tree:  # the sum of the effectors' squared errors: each effector's chain in turn
            self._chain = tree_arrays(arm)
            self._mlp_kernel, self._graph_kernel = kernels.tree_mlp_mse, kernels.tree_graph_mse
        else:
            self._chain = arm.chain.arrays
            self._mlp_kernel, self._graph_kernel = kernels.mlp_mse, kernels.graph_mse

    def _sample_goals(self, n: int, seed: int) -> np.ndarray:
        return self.arm.sample_goals(n, seed=seed)

    def _arrays(self, goals: np.ndarray) -> tuple:
        """What the kernels take of goals: (inputs, goals), the goals along the last, contiguous axis."""
        return _t(self.encoding.inputs(goals)), _goals_t(goals)

    @property
    def resampling(self) -> bool:
        """Whether the training goals are drawn anew every generation (draw_goals)."""
        return self.resample_seed is not None

    def draw_goals(self, generation: int) -> None:
        """Replace the training goals by new ones, the same for the same (goal_seed, resample_seed,
        generation) whatever came before."""
        seq = np.random.SeedSequence([self.goal_seed, RESAMPLE_STREAM, int(self.resample_seed), int(generation)])
        self.train_goals = self.arm.sample_goals(len(self.reference_goals), seed=int(seq.generate_state(1)[0]))
        self._train = (_t(self.encoding.inputs(self.train_goals)), _goals_t(self.train_goals))

    def _split(self, test: bool):
        return self._test if test else self._train

    def mlp_mse(self, W: np.ndarray, hidden: int, test: bool = False, offsets: np.ndarray | None = None) -> np.ndarray:
        """MSE of every MLP weight vector in W (P, D): (P,). offsets: a multi-hypothesis MLP's output
        offsets (lab.problem.controllers.MLPController.offsets, heads x nq): each goal then counts
        the smallest squared error over the heads (None: one head, the paper's MLP)."""
        XT, goalsT = self._split(test)
        W = np.ascontiguousarray(W, dtype=np.float64)
        out = np.empty(len(W))
        if offsets is None or len(offsets) == self.encoding.n_outputs:
            kernel, extra = self._mlp_kernel, ()
        elif self.arm.is_tree:
            raise ValueError(f"{self.arm.name} is a tree of {self.arm.n_effectors} end effectors: its multi-head MLPs "
                             "(heads > 1) are scored per limb group, wired (Problem.wired_mse)")
        else:
            kernel, extra = kernels.mlp_heads_mse, (np.ascontiguousarray(offsets, dtype=np.float64),)
        heads = 1 if not extra else len(offsets) // self.encoding.n_outputs
        slices = min(self.threads, heads * len(W) * XT.shape[1] // _MIN_SLICE, len(W))
        if slices <= 1:
            kernel(XT, goalsT, self._axes, W, int(hidden), *extra, self._qmap, self._chain, out)
            return out
        edges = np.linspace(0, len(W), slices + 1).astype(int)
        jobs = [_pool(slices).submit(kernel, XT, goalsT, self._axes, W[a:b], int(hidden), *extra, self._qmap,
                                     self._chain, out[a:b]) for a, b in zip(edges[:-1], edges[1:])]
        for job in jobs:
            job.result()
        return out

    def wired_mse(self, G: np.ndarray, wiring, test: bool = False, offsets: np.ndarray | None = None) -> np.ndarray:
        """(P, groups): each limb group's share of the MSE of the wired networks G (P, wiring.dim)
        (lab.problem.wiring): the mean over goals of the summed squared errors of that group's
        effectors, by its own small MLP on its own joints. The row sums are mlp_mse of
        wiring.expand(G) (to rounding): the other weights are zero, and no group moves another's effectors.
        Several heads (wiring.heads > 1; offsets: the MLP's output offsets, heads x nq): each goal counts,
        per group, the smallest of its heads' errors (kernels.tree_mlp_heads_mse), as the controller picks
        a head for each group."""
        XT, goalsT = self._split(test)
        G = np.ascontiguousarray(G, dtype=np.float64)
        if G.ndim != 2 or G.shape[1] != wiring.dim:
            raise ValueError(f"wired genomes must be (P, {wiring.dim}), got shape {G.shape}")
        parts = self._wired_parts(wiring)
        heads = wiring.heads
        if heads > 1:
            offsets = np.asarray(offsets, dtype=np.float64) if offsets is not None else None
            if offsets is None or offsets.shape != (wiring.n_outputs,):
                raise ValueError(f"a wired network of {heads} heads needs its {wiring.n_outputs} output offsets, got "
                                 f"{None if offsets is None else offsets.shape}")
            per_head = offsets.reshape(heads, -1)
        results = np.empty((len(parts), len(G)))
        # each group's candidates in as many slices as threads (the groups differ in cost: g1's arms
        # and waist cost more than both legs together), every slice its own job
        slices = max(1, min(self.threads, len(G) * XT.shape[1] // _MIN_SLICE, len(G)))
        edges = np.linspace(0, len(G), slices + 1).astype(int)
        jobs = []
        for k, ((rows, goal_rows, qmap, tree), W) in enumerate(zip(parts, wiring.split(G))):
            X_k, goals_k, W = (np.ascontiguousarray(XT[rows]), np.ascontiguousarray(goalsT[goal_rows]),
                               np.ascontiguousarray(W))
            extra = () if heads == 1 else (np.ascontiguousarray(per_head[:, wiring.joints[k]].ravel()),)
            for a, b in zip(edges[:-1], edges[1:]):
                jobs.append((X_k, goals_k, self._axes, W[a:b], len(wiring.units[k]), *extra, qmap, tree,
                             results[k, a:b]))
        kernel = kernels.tree_mlp_mse if heads == 1 else kernels.tree_mlp_heads_mse
        if self.threads <= 1:
            for args in jobs:
                kernel(*args)
        else:
            futures = [_pool(self.threads).submit(kernel, *args) for args in jobs]
            for f in futures:
                f.result()
        return np.where(np.isfinite(results.T), results.T, np.inf)

    def _wired_parts(self, wiring) -> list:
        """Per limb group: (input rows, goal rows, output mapping, tree) as the tree kernels take them."""
        cache = self.__dict__.setdefault("_wired_cache", {})
        key = (id(wiring), wiring.n_inputs, wiring.hidden, wiring.heads)
        if key in cache and cache[key][0] is wiring:
            return cache[key][1]
        m = len(self.arm.task_axes)
        enc, parts = self.encoding, []
        for g, js, ins in zip(wiring.groups, wiring.joints, wiring.inputs):
            where = {int(j): i for i, j in enumerate(js)}
            paths = [[where[int(j)] for j in self.arm.chain.path(e)] for e in g]
            tree = kernels.pack_tree([self.arm.chain.effector_arrays(e) for e in g], paths, len(js))
            qmap = tuple(np.ascontiguousarray(a[js]) for a in (enc.q_offset, enc.q_scale, enc.clip_lo, enc.clip_hi)) \
                + (np.ascontiguousarray(enc.turn_spec[list(g)]),)
            goal_rows = np.concatenate([np.arange(e * m, (e + 1) * m) for e in g])
            parts.append((np.asarray(ins), goal_rows, qmap, tree))
        cache[key] = (wiring, parts)
        return parts

    def mlp_gradient(self, w: np.ndarray, hidden: int, test: bool = False) -> tuple[float, np.ndarray]:
        """(MSE, d MSE / d w) of one MLP weight vector w (D,) on the goals, by backpropagation.

        Forward: h = tanh([x, 1] w_i), a = tanh(h w_o), q = clip(offset + (a + 1) scale, lo, hi)
        (the encoding's mapping, clipped as the fitness kernel clips), p = fk(q)[task_axes],
        MSE = mean_g ||p_g - goal_g||^2. Backward: dMSE/dq = (2/n) J^T (p - goal) with J the arm's
        positional Jacobian (robots.Arm.jacobian) on the task axes; the clip passes the gradient
        only where the unclipped value is within the limits; then through the two tanh layers.
        The MSE is numpy's (it equals mlp_mse's to rounding; mlp_mse is the fitness)."""
        enc = self.encoding
        XT, goalsT = self._split(test)
        X, goals = XT.T, goalsT.T  # (n, ni), (n, k)
        n = X.shape[0]
        layers = self._mlp_forward(X, w, hidden)
        q = layers[-1]
        if enc.turns:  # the first joint turned in closed form: at the turn the error is stationary in it
            q = enc.turned(q, goals.reshape(n, -1, 3) if self.arm.is_tree else goals)
        axes = list(self.arm.task_axes)
        err = self.arm.fk(q)[..., axes].reshape(n, -1) - goals  # (n, k); a tree's (n, E k), the errors stacked
        mse = float(np.mean(np.sum(err * err, axis=1)))
        J = self.arm.jacobian(q)[..., axes, :].reshape(n, err.shape[1], -1)  # (n, k, nq), a tree's stacked
        dq = (2.0 / n) * np.einsum("gk,gkj->gj", err, J)
        return (mse if np.isfinite(mse) else np.inf), self._mlp_backward(X, layers, dq)

    def _mlp_forward(self, X: np.ndarray, w: np.ndarray, hidden: int) -> tuple:
        """The MLP w (D,) on inputs X (n, ni), as the fitness kernels compute it: (w_o, H, A, raw, q)
        with h = tanh([x, 1] w_i), a = tanh(h w_o), raw = offset + (a + 1) scale, q = clip(raw)."""
        enc = self.encoding
        ni, nh, no = X.shape[1], int(hidden), enc.n_outputs
        w = np.asarray(w, dtype=np.float64)
        w_i = w[: (ni + 1) * nh].reshape(ni + 1, nh)
        w_o = w[(ni + 1) * nh:].reshape(nh, no)
        H = np.tanh(X @ w_i[:ni] + w_i[ni])
        A = np.tanh(H @ w_o)
        raw = enc.q_offset + (A + 1.0) * enc.q_scale
        return w_o, H, A, raw, np.clip(raw, enc.clip_lo, enc.clip_hi)

    def _mlp_backward(self, X: np.ndarray, layers: tuple, dq: np.ndarray) -> np.ndarray:
        """d loss / d w (D,) from d loss / d q (n, nq) and _mlp_forward's layers: the turned joints'
        outputs are unused, the clip passes the gradient only within the limits, then the two tanh layers."""
        enc = self.encoding
        w_o, H, A, raw, _ = layers
        if enc.turns:  # the network's outputs for the turned joints are unused
            dq[:, enc.turned_joints] = 0.0
        dA = dq * ((raw >= enc.clip_lo) & (raw <= enc.clip_hi)) * enc.q_scale
        dZo = dA * (1.0 - A * A)
        dZh = (dZo @ w_o.T) * (1.0 - H * H)
        return np.concatenate([(X.T @ dZh).ravel(), dZh.sum(axis=0), (H.T @ dZo).ravel()])

    def outputs_mse(self, A: np.ndarray, test: bool = False) -> np.ndarray:
        """MSE of network outputs A (P, n, nq) in [-1, 1] on the goals: (P,)."""
        _, goalsT = self._split(test)
        QT = np.ascontiguousarray(self.encoding.mapped(np.asarray(A, dtype=np.float64)).transpose(0, 2, 1))
        out = np.empty(len(QT))
        if self.arm.is_tree:
            kernels.tree_joints_mse(QT, goalsT, self._axes, self._chain, self.encoding.turn_spec, out)
        else:
            kernels.joints_mse(QT, goalsT, self._axes, self._chain, self.encoding.turn_spec, out)
        return out

    def graphs_mse(self, graphs, test: bool = False) -> np.ndarray:
        """MSE of every GraphController in graphs: (P,)."""
        return self.program_mse(compile_programs(graphs), test)

    def program_mse(self, program: tuple, test: bool = False) -> np.ndarray:
        """MSE of every graph of a compiled program (lab.problem.controllers.compile_programs): (P,)."""
        XT, goalsT = self._split(test)
        out = np.empty(len(program[0]))
        self._graph_kernel(XT, goalsT, self._axes, program, self._qmap, self._chain, out)
        return out

    def controller_mse(self, controller: Controller, goals: np.ndarray | None = None) -> float:
        """MSE of one controller on goals (the fixed training goals by default), through `arm.fk`."""
        goals = self.reference_goals if goals is None else goals
        return float(goal_errors(self.arm, controller, goals).mean())


def _t(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).T)


def _goals_t(goals: np.ndarray) -> np.ndarray:
    """Goals as the kernels take them: (k, n), a tree's (n, E, k) as (E k, n), effector after effector."""
    goals = np.asarray(goals, dtype=np.float64)
    return _t(goals.reshape(len(goals), -1))


def goal_errors(arm: robots.Arm, controller: Controller, goals: np.ndarray) -> np.ndarray:
    """Squared end-effector error ||p - p'||^2 of a controller on each goal: (n,); a tree's summed over its
    effectors. NaN -> inf."""
    reached = arm.reach(controller(goals))
    err = np.sum(((np.asarray(goals) - reached) ** 2).reshape(len(reached), -1), axis=-1)
    return np.where(np.isfinite(err), err, np.inf)
