"""Reward heads: the optimistic reward proxy R~_tau = R^_tau + CI_tau of one task (paper, section 3, eq. 5).

Each head learns from the samples Xi_tau of its task (their start states and rewards, float64, states (n, d),
rewards (n,)) and answers, for any states: the estimate R^ (``estimate``), the kappa-free uncertainty
(``uncertainty``), the confidence interval CI = kappa * uncertainty (``bonus``) and R~ = R^ + CI capped at
``r_max`` if given (``optimistic``). ``tracker`` keeps R~ up to date on a fixed, growable set of states
(a replay buffer's start states), which is what relabelling the buffer asks for at every refit.

- ``RidgeRewardHead``: the continuous setting. R^ is a ridge regression on the features Phi(s) with
  Tikhonov regularisation lambda = 1, kept as running sufficient statistics; CI by eq. 9 with the
  neighbouring weight W_tau(s) of eq. 8 under the similarity of eq. 6 (states) or eq. 7 (features).
- ``TabularRewardHead``: the discrete setting. R^ is a per-cell mean, CI by eq. 10; an optional set of
  allowed cells encodes the prior that rewards are zero elsewhere (``make_tabular_head("corners")``).
- ``KnownRewardHead``: the reward is known, CI = 0.

Edge cases, decided here so that R^, CI and R~ are never infinite or NaN for finite query states:

- W_tau(s) -> 0 far from every sample (exactly 0 once exp underflows, beyond ~39 sigma), and N_tau(s) = 0 in
  an unvisited cell: eq. 9 and 10 give an infinite CI. W and N are floored at ``w_floor`` (default 1e-6),
  so the bonus is at most kappa * sqrt(log|Xi_tau| / w_floor). The floor only bites where the state is
  practically unknown: with the paper's sigma = 0.2, W < 1e-6 means no sample within ~1.05 (5.3 sigma) of
  s, and N counts whole samples, so any N >= 1 is above it. There the bonus (~263 for kappa = 0.1 and
  1,000 samples) dwarfs any reward the maze gives, which is the "infinitely optimistic where never
  visited" behaviour of UCB the paper builds on, kept finite so that FQI stays numerically sane. Where an
  upper bound of the reward is known, ``r_max`` caps R~ instead.
- |Xi_tau| <= 1: log 1 = 0 would remove all optimism after the first sample and log 0 = -inf, so the log
  factor is log(max(|Xi_tau|, 2)). With no sample, R^ = 0 and the bonus is the floored maximum everywhere.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from functools import partial

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.features import gaussian_similarity

__all__ = [
    "DEFAULT_W_FLOOR",
    "REWARD_HEAD_NAMES",
    "TABULAR_PRESETS",
    "KernelSumTracker",
    "KnownRewardHead",
    "RewardHead",
    "RewardTracker",
    "RidgeRewardHead",
    "TabularRewardHead",
    "make_reward_head",
    "make_tabular_head",
    "maze_cell_index",
]

DEFAULT_W_FLOOR = 1e-6
MAZE_CORNER_CELLS = (0, 4, 20, 24)
# Tabular presets on the maze's 25 cells: the allowed cells (None: all).
TABULAR_PRESETS: dict[str, tuple[int, ...] | None] = {"cells": None, "corners": MAZE_CORNER_CELLS}
REWARD_HEAD_NAMES = ("ridge", "tabular", "corners", "known")
SIMILARITIES = ("state", "features")
# Kernel sums are computed in blocks of at most this many (query, sample) pairs (32 MB of float64).
KERNEL_BLOCK = 4_000_000

StatesFn = Callable[[np.ndarray], np.ndarray]


def log_sample_count(n_samples: int) -> float:
    """
    log|Xi_tau| of eq. 9 and 10, with |Xi_tau| taken as at least 2 (see the module docstring).

    :param n_samples: |Xi_tau|
    :return: log(max(|Xi_tau|, 2))
    """
    return float(np.log(max(n_samples, 2)))


def confidence_width(log_count: float, weights: np.ndarray, w_floor: float) -> np.ndarray:
    """
    sqrt(log|Xi_tau| / W(s)): eq. 9 (W a neighbouring weight) or eq. 10 (W a count), without kappa.

    :param log_count: log|Xi_tau| (see ``log_sample_count``)
    :param weights: W_tau(s) or N_tau(s), (n,)
    :param w_floor: floor on the weights (> 0)
    :return: (n,)
    """
    return np.sqrt(log_count / np.maximum(weights, w_floor))


def maze_cell_index(states: np.ndarray) -> np.ndarray:
    """
    The maze cell of each state, i = ceil(x), j = ceil(y) clipped to 1..5, as the index 5 (i - 1) + (j - 1).

    :param states: (n, 2)
    :return: cell ids (n,) in 0..24, the maze's task index of the cell's task
    """
    cells = np.clip(np.ceil(np.asarray(states, dtype=np.float64).reshape(-1, 2)), 1, 5).astype(np.int64) - 1
    return 5 * cells[:, 0] + cells[:, 1]


def _check_positive(name: str, value: float, meaning: str) -> float:
    if not value > 0:
        raise ValueError(f"{name} must be > 0 ({meaning}), got {value}")
    return float(value)


class RewardTracker:
    """
    R~ of a head on a fixed but growable set of query states (e.g. every start state of a replay buffer).
    This generic one evaluates the head on the stored states at each call; ``RidgeRewardHead`` returns a
    ``KernelSumTracker``, which keeps its kernel sums up to date.

    :param head: the reward head
    :param states: the initial query states (m, d), possibly none
    """

    def __init__(self, head: RewardHead, states: np.ndarray):
        self.head = head
        self._states = GrowableArray(np.asarray(states).shape[1])
        self.extend(states)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.head!r}, n_states={self.n_states})"

    @property
    def n_states(self) -> int:
        """The number of query states m."""
        return len(self._states)

    @property
    def states(self) -> np.ndarray:
        """The query states (m, d), a view."""
        return self._states.view()

    def extend(self, states: np.ndarray) -> None:
        """
        Append query states.

        :param states: (n, d)
        """
        self._states.append(states)

    def estimate(self) -> np.ndarray:
        """:return: R^_tau at the query states, (m,)"""
        return self.head.estimate(self.states)

    def bonus(self) -> np.ndarray:
        """:return: CI_tau at the query states, (m,)"""
        return self.head.bonus(self.states)

    def optimistic(self) -> np.ndarray:
        """:return: R~_tau at the query states (eq. 5, capped at the head's ``r_max``), (m,)"""
        return self.head.clip_optimistic(self.estimate() + self.bonus())


class RewardHead(ABC):
    """
    Base of the reward heads: sample bookkeeping and validation, CI = kappa * uncertainty, R~ = R^ + CI.

    :param kappa: optimism of the confidence interval (>= 0; 0 is the non-optimistic method)
    :param r_max: optional upper bound on the reward (expert knowledge): R~ is capped at it
    """

    def __init__(self, kappa: float = 0.1, r_max: float | None = None):
        if not kappa >= 0:
            raise ValueError(f"kappa must be >= 0 (0 is the non-optimistic method), got {kappa}")
        if r_max is not None and not np.isfinite(r_max):
            raise ValueError(f"r_max must be a finite number or None (no cap), got {r_max}")
        self.kappa = float(kappa)
        self.r_max = None if r_max is None else float(r_max)
        self.n_samples = 0
        self.state_dim: int | None = None  # fixed by the first update

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(self._repr_items())}, n_samples={self.n_samples})"

    def _repr_items(self) -> list[str]:
        return [f"kappa={self.kappa:g}"]

    def update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """
        Add samples of the task, incrementally: start states of transitions and the rewards observed there.

        :param states: (n, d)
        :param rewards: (n,), finite
        """
        states = np.asarray(states, dtype=np.float64)
        rewards = np.asarray(rewards, dtype=np.float64)
        if states.ndim != 2 or (self.state_dim is not None and states.shape[1] != self.state_dim):
            expected = "(n, d)" if self.state_dim is None else f"(n, {self.state_dim})"
            raise ValueError(f"states must have shape {expected}, got {states.shape}")
        if rewards.shape != (len(states),):
            raise ValueError(f"rewards must have shape ({len(states)},), one per state, got {rewards.shape}")
        if not np.all(np.isfinite(rewards)):
            raise ValueError("rewards must be finite (no NaN or inf)")
        if not np.all(np.isfinite(states)):
            raise ValueError("states must be finite (no NaN or inf)")
        self.state_dim = states.shape[1]
        if len(states):
            self._update(states, rewards)
            self.n_samples += len(rewards)

    def bonus(self, states: np.ndarray) -> np.ndarray:
        """
        CI_tau(s) = kappa * uncertainty(s) (eq. 9, 10).

        :param states: (n, d)
        :return: (n,)
        """
        if self.kappa == 0:  # the non-optimistic method: no kernel sums needed
            return np.zeros(len(states))
        return self.kappa * self.uncertainty(states)

    def optimistic(self, states: np.ndarray) -> np.ndarray:
        """
        R~_tau(s) = R^_tau(s) + CI_tau(s) (eq. 5), capped at ``r_max`` if given.

        :param states: (n, d)
        :return: (n,)
        """
        return self.clip_optimistic(self.estimate(states) + self.bonus(states))

    def clip_optimistic(self, rewards: np.ndarray) -> np.ndarray:
        """
        Cap optimistic rewards at ``r_max`` (no-op without it).

        :param rewards: (n,)
        :return: (n,)
        """
        return rewards if self.r_max is None else np.minimum(rewards, self.r_max)

    def tracker(self, states: np.ndarray) -> RewardTracker:
        """
        R~ on a growable set of query states, kept up to date as the head learns.

        :param states: the initial query states (m, d)
        :return: the tracker
        """
        return RewardTracker(self, states)

    @abstractmethod
    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """Fold in validated samples: states (n, d), rewards (n,), n >= 1."""

    @abstractmethod
    def estimate(self, states: np.ndarray) -> np.ndarray:
        """
        R^_tau(s).

        :param states: (n, d)
        :return: (n,)
        """

    @abstractmethod
    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        """
        The kappa-free confidence width sqrt(log|Xi_tau| / W_tau(s)) (eq. 9, 10 without kappa).

        :param states: (n, d)
        :return: (n,)
        """

    @abstractmethod
    def frozen_uncertainty(self) -> StatesFn:
        """
        The uncertainty function as of now, unaffected by later updates (the refit trigger compares it with
        the current one at encountered states). Cheap: it does not copy the samples.

        :return: states (n, d) -> (n,)
        """


class RidgeRewardHead(RewardHead):
    """
    Continuous setting: ridge regression of the reward on Phi(s) and the neighbouring-weight CI of eq. 9.

    R^(s) = Phi(s) . w with w = (Phi^T Phi + lambda I)^-1 Phi^T r from running sums of Phi^T Phi and Phi^T r,
    solved lazily (k x k) and cached until the next update. The sample states (or their features, for the
    eq. 7 similarity) are kept in a growable array for the kernel sums W_tau(s) of eq. 8.

    :param features: Phi, states (n, d) -> (n, k) (e.g. an ``RBFGrid``)
    :param kappa: optimism (eq. 9), >= 0
    :param sigma: width of the similarity (eq. 6 / 7), > 0
    :param similarity: ``"state"`` (S_S, eq. 6, on states) or ``"features"`` (S_Phi, eq. 7, on Phi(s))
    :param ridge: Tikhonov regularisation lambda (1 in the paper), > 0
    :param w_floor: floor on W_tau(s), > 0 (see the module docstring)
    :param r_max: optional cap on R~
    """

    def __init__(
        self,
        features: StatesFn,
        kappa: float = 0.1,
        sigma: float = 0.2,
        similarity: str = "state",
        ridge: float = 1.0,
        w_floor: float = DEFAULT_W_FLOOR,
        r_max: float | None = None,
    ):
        super().__init__(kappa, r_max)
        if similarity not in SIMILARITIES:
            raise ValueError(f"similarity must be 'state' (eq. 6) or 'features' (eq. 7), got {similarity!r}")
        self.features = features
        self.sigma = _check_positive("sigma", sigma, "the width of the similarity")
        self.similarity = similarity
        self.ridge = _check_positive("ridge", ridge, "the Tikhonov regularisation lambda, 1 in the paper")
        self.w_floor = _check_positive("w_floor", w_floor, "the floor of the neighbouring weight W")
        self._gram: np.ndarray | None = None  # Phi^T Phi + lambda I, (k, k)
        self._moments: np.ndarray | None = None  # Phi^T r, (k,)
        self._weights: np.ndarray | None = None  # cached solution, None when stale
        self._points: GrowableArray | None = None  # what the similarity compares: states or Phi(states)

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"sigma={self.sigma:g}", f"similarity={self.similarity!r}"]

    def similarity_points(self, states: np.ndarray, phi: np.ndarray | None = None) -> np.ndarray:
        """
        The vectors the similarity compares: the states (eq. 6) or their features (eq. 7).

        :param states: (n, d)
        :param phi: Phi(states) (n, k) if already computed
        :return: (n, d) or (n, k)
        """
        if self.similarity == "state":
            return np.asarray(states, dtype=np.float64)
        return self.features(states) if phi is None else phi

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        phi = self.features(states)  # (n, k)
        if self._gram is None:
            self._gram = self.ridge * np.eye(phi.shape[1])
            self._moments = np.zeros(phi.shape[1])
        assert self._moments is not None
        # Running sufficient statistics of the ridge regression.
        self._gram += phi.T @ phi
        self._moments += phi.T @ rewards
        self._weights = None
        points = self.similarity_points(states, phi)
        if self._points is None:
            self._points = GrowableArray(points.shape[1])
        self._points.append(points)

    @property
    def weights(self) -> np.ndarray | None:
        """Ridge solution w = (Phi^T Phi + lambda I)^-1 Phi^T r, (k,), or None before the first sample."""
        if self._weights is None and self._gram is not None:
            self._weights = np.linalg.solve(self._gram, self._moments)
        return self._weights

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return self.estimate_from_features(self.features(np.asarray(states, dtype=np.float64)))

    def estimate_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        R^ from precomputed features.

        :param phi: Phi(s), (n, k)
        :return: (n,), 0 before the first sample
        """
        weights = self.weights
        return np.zeros(len(phi)) if weights is None else phi @ weights

    def kernel_sums(self, points: np.ndarray, start: int = 0, stop: int | None = None) -> np.ndarray:
        """
        W(s) = sum_j S(s, s_j) (eq. 8) over the samples ``start:stop`` (all by default), in blocks.

        :param points: similarity points of the query states (n, p) (see ``similarity_points``)
        :param start: first sample
        :param stop: end of the samples (exclusive), None for all
        :return: (n,)
        """
        sums = np.zeros(len(points))
        if self._points is None:
            return sums
        samples = self._points.view(start, stop)  # (m, p)
        block = max(1, KERNEL_BLOCK // max(1, len(points)))
        for first in range(0, len(samples), block):
            # eq. 8 with S = eq. 6 (or eq. 7 on feature points)
            sums += gaussian_similarity(points, samples[first : first + block], self.sigma).sum(axis=1)
        return sums

    def uncertainty_at(self, states: np.ndarray, n_samples: int | None = None) -> np.ndarray:
        """
        Eq. 9 without kappa as if the head only had its first ``n_samples`` samples.

        :param states: (n, d)
        :param n_samples: samples to use, all if None
        :return: (n,)
        """
        n = self.n_samples if n_samples is None else n_samples
        weights = self.kernel_sums(self.similarity_points(states), 0, n)
        return confidence_width(log_sample_count(n), weights, self.w_floor)  # eq. 9 / kappa

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return self.uncertainty_at(states)

    def frozen_uncertainty(self) -> StatesFn:
        # Samples are only ever appended, so the first n samples are the head as of now.
        return partial(self.uncertainty_at, n_samples=self.n_samples)

    def tracker(self, states: np.ndarray) -> KernelSumTracker:
        return KernelSumTracker(self, states)


class KernelSumTracker(RewardTracker):
    """
    R~ of a ``RidgeRewardHead`` on a growable set of query states, with their features and kernel sums W
    (eq. 8) cached: each call folds in only the samples the head received since the previous one, so
    relabelling m states after n new samples costs O(m n) instead of O(m |Xi_tau|).

    :param head: the ridge head
    :param states: the initial query states (m, d)
    """

    head: RidgeRewardHead

    def __init__(self, head: RidgeRewardHead, states: np.ndarray):
        self._phi: GrowableArray | None = None  # Phi(query), (m, k)
        self._points: GrowableArray | None = None  # similarity points of the queries, (m, p)
        self._kernel_sums = GrowableArray(1)  # W(query) over the first _n_folded samples, (m, 1)
        self._n_folded = head.n_samples
        super().__init__(head, states)

    def extend(self, states: np.ndarray) -> None:
        states = np.asarray(states, dtype=np.float64)
        phi = self.head.features(states)
        points = self.head.similarity_points(states, phi)
        if self._phi is None or self._points is None:
            self._phi, self._points = GrowableArray(phi.shape[1]), GrowableArray(points.shape[1])
        self._phi.append(phi)
        self._points.append(points)
        super().extend(states)
        self._kernel_sums.append(self.head.kernel_sums(points, 0, self._n_folded))

    def _fold_new_samples(self) -> None:
        if self.head.n_samples > self._n_folded and self._points is not None:
            # Eq. 8 is a sum over samples: add the terms of the new ones only.
            self._kernel_sums.view()[:, 0] += self.head.kernel_sums(
                self._points.view(), self._n_folded, self.head.n_samples
            )
        self._n_folded = self.head.n_samples

    def estimate(self) -> np.ndarray:
        if self._phi is None:
            return np.zeros(0)
        return self.head.estimate_from_features(self._phi.view())

    def bonus(self) -> np.ndarray:
        if self.head.kappa == 0:
            return np.zeros(self.n_states)
        self._fold_new_samples()
        weights = self._kernel_sums.view()[:, 0]
        return self.head.kappa * confidence_width(
            log_sample_count(self.head.n_samples), weights, self.head.w_floor
        )  # eq. 9


class TabularRewardHead(RewardHead):
    """
    Discrete setting: per-cell mean rewards and the UCB-style CI of eq. 10 on a discretisation of the states.

    :param cell_fn: states (n, d) -> cell ids (n,) in 0..n_cells-1 (e.g. ``maze_cell_index``)
    :param n_cells: number of cells, >= 1
    :param kappa: optimism (eq. 10), >= 0
    :param allowed_cells: cells where the reward may be non-zero (expert knowledge); elsewhere R^ = 0 and
        there is no bonus. None: every cell
    :param w_floor: floor on the count N_tau(s) of an unvisited cell, > 0 (see the module docstring)
    :param r_max: optional cap on R~
    """

    def __init__(
        self,
        cell_fn: Callable[[np.ndarray], np.ndarray],
        n_cells: int,
        kappa: float = 0.1,
        allowed_cells: Iterable[int] | None = None,
        w_floor: float = DEFAULT_W_FLOOR,
        r_max: float | None = None,
    ):
        super().__init__(kappa, r_max)
        if not n_cells >= 1:
            raise ValueError(f"n_cells must be an integer >= 1, got {n_cells}")
        self.cell_fn = cell_fn
        self.n_cells = int(n_cells)
        self.w_floor = _check_positive("w_floor", w_floor, "the floor of the cell count N")
        self.allowed = np.ones(self.n_cells, dtype=bool)
        if allowed_cells is not None:
            allowed = np.asarray(list(allowed_cells), dtype=np.int64)
            if np.any((allowed < 0) | (allowed >= self.n_cells)):
                raise ValueError(f"allowed_cells must be cell ids in 0..{self.n_cells - 1}, got {allowed}")
            self.allowed[:] = False
            self.allowed[allowed] = True
        self.counts = np.zeros(self.n_cells)  # N_tau per cell
        self.sums = np.zeros(self.n_cells)  # sum of rewards per cell

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"n_cells={self.n_cells}", f"allowed={int(self.allowed.sum())}"]

    def cells(self, states: np.ndarray) -> np.ndarray:
        """
        The cell of each state.

        :param states: (n, d)
        :return: cell ids (n,)
        """
        cells = np.asarray(self.cell_fn(np.asarray(states, dtype=np.float64)), dtype=np.int64).reshape(-1)
        if len(cells) and (cells.min() < 0 or cells.max() >= self.n_cells):
            raise ValueError(f"cell_fn must return cell ids in 0..{self.n_cells - 1}")
        return cells

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        cells = self.cells(states)
        self.counts += np.bincount(cells, minlength=self.n_cells)
        self.sums += np.bincount(cells, weights=rewards, minlength=self.n_cells)

    def cell_means(self) -> np.ndarray:
        """R^ per cell: the mean reward of its samples, 0 where it has none or is not allowed, (n_cells,)."""
        means = np.divide(self.sums, self.counts, out=np.zeros(self.n_cells), where=self.counts > 0)
        return np.where(self.allowed, means, 0.0)

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return self.cell_means()[self.cells(states)]

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return self._cell_uncertainty(self.counts, self.n_samples, states)

    def frozen_uncertainty(self) -> StatesFn:
        # The counts are n_cells floats: copying them is the cheap snapshot.
        return partial(self._cell_uncertainty, self.counts.copy(), self.n_samples)

    def _cell_uncertainty(self, counts: np.ndarray, n_samples: int, states: np.ndarray) -> np.ndarray:
        """Eq. 10 without kappa for per-cell counts N_tau: sqrt(log|Xi_tau| / N_tau(s)), 0 outside allowed."""
        per_cell = confidence_width(log_sample_count(n_samples), counts, self.w_floor)  # eq. 10 / kappa
        return np.where(self.allowed, per_cell, 0.0)[self.cells(states)]


class KnownRewardHead(RewardHead):
    """
    The reward is known (the paper's first experiment): R^ = R_tau and CI = 0, so R~ = R_tau.

    :param reward_fn: states (n, d) -> expected rewards (n,)
    """

    def __init__(self, reward_fn: StatesFn):
        super().__init__(kappa=0.0)
        self.reward_fn = reward_fn

    def __repr__(self) -> str:
        return f"KnownRewardHead(n_samples={self.n_samples})"

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """Nothing to learn: only the sample count moves."""

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return np.asarray(self.reward_fn(np.asarray(states, dtype=np.float64)), dtype=np.float64)

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return np.zeros(len(states))

    def frozen_uncertainty(self) -> StatesFn:
        return self.uncertainty


def make_tabular_head(preset: str = "cells", kappa: float = 0.1, **kwargs) -> TabularRewardHead:
    """
    A tabular head on the maze's 25 cells (cell 5 (ceil(x) - 1) + (ceil(y) - 1), see ``maze_cell_index``).

    :param preset: ``"cells"`` (the discrete setting: any cell may be rewarded) or ``"corners"`` (rewards
        only possible in the 4 corner cells 0, 4, 20, 24: the corners experiment's prior)
    :param kappa: optimism (eq. 10)
    :param kwargs: further arguments of ``TabularRewardHead`` (``w_floor``, ``r_max``)
    :return: the head
    """
    if preset not in TABULAR_PRESETS:
        raise ValueError(f"preset must be one of {sorted(TABULAR_PRESETS)}, got {preset!r}")
    allowed = TABULAR_PRESETS[preset]
    return TabularRewardHead(maze_cell_index, 25, kappa=kappa, allowed_cells=allowed, **kwargs)


def make_reward_head(
    name: str,
    *,
    features: StatesFn | None = None,
    kappa: float = 0.1,
    sigma: float = 0.2,
    similarity: str = "state",
    reward_fn: StatesFn | None = None,
    **kwargs,
) -> RewardHead:
    """
    A reward head by name: ``"ridge"`` (continuous setting), ``"tabular"`` (the maze's 25 cells),
    ``"corners"`` (the 25 cells, rewards only possible in the 4 corners) or ``"known"`` (``reward_fn``).
    Arguments a head does not use (``sigma`` and ``similarity`` of the tabular heads, ``kappa`` of the
    known one) are ignored.

    :param name: the head's name
    :param features: Phi for the ridge head
    :param kappa: optimism
    :param sigma: similarity width of the ridge head
    :param similarity: similarity of the ridge head, ``"state"`` or ``"features"``
    :param reward_fn: the known expected reward, states (n, d) -> (n,)
    :param kwargs: further arguments of the head's class (``ridge``, ``w_floor``, ``r_max``)
    :return: the head
    """
    if name == "ridge":
        if features is None:
            raise ValueError("the 'ridge' reward_head needs features (Phi, e.g. an RBFGrid)")
        return RidgeRewardHead(features, kappa=kappa, sigma=sigma, similarity=similarity, **kwargs)
    if name in ("tabular", "corners"):
        return make_tabular_head("cells" if name == "tabular" else "corners", kappa=kappa, **kwargs)
    if name == "known":
        if reward_fn is None:
            raise ValueError("the 'known' reward_head needs reward_fn, the expected reward of the task")
        return KnownRewardHead(reward_fn, **kwargs)
    raise ValueError(f"reward_head must be one of {list(REWARD_HEAD_NAMES)}, got {name!r}")
