"""Reward heads: the optimistic reward proxy R~_tau = R^_tau + CI_tau of a task (paper, section 3).

Each head learns from the samples Xi_tau of its task (their start states and rewards) and answers, for any
states: the estimate R^ (``estimate``), the kappa-free uncertainty (``uncertainty``), the confidence
interval CI = kappa * uncertainty (``bonus``) and R~ = R^ + CI (``optimistic``).

- ``RidgeRewardHead``: the continuous setting. R^ is a ridge regression on the features Phi(s) with
  Tikhonov regularisation lambda = 1, kept as running sufficient statistics; CI by eq. 9 with the
  neighbouring weight W_tau(s) of eq. 8 under the similarity of eq. 6 (states) or eq. 7 (features).
- ``TabularRewardHead``: the discrete setting. R^ is a per-cell mean, CI by eq. 10; an optional set of
  allowed cells encodes the prior that rewards are zero elsewhere (the corners experiment).
- ``KnownRewardHead``: the reward is known, CI = 0.

Edge cases, decided here so that R~ is never infinite or NaN:

- W_tau(s) -> 0 far from every sample (and exactly 0 once exp underflows, beyond about 3.9 / 0.2 widths):
  W is floored at ``w_floor`` (default 1e-6), so the bonus is at most
  kappa * sqrt(log|Xi_tau| / w_floor). With the paper's sigma = 0.2, W < 1e-6 means no sample within about
  0.74 of s: all such states are equally unknown, and the bonus there dwarfs any reward (about 260 for
  kappa = 0.1), which is the optimism the method relies on. ``r_max`` (expert knowledge of a bound on the
  reward) caps R~ instead, where a bound is known.
- |Xi_tau| <= 1: log 1 = 0 would remove all optimism after the first sample and log 0 is undefined, so the
  log factor is log(max(|Xi_tau|, 2)). With no sample, R^ = 0 and the bonus is the floored maximum
  everywhere.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from functools import partial

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.features import gaussian_similarity

__all__ = [
    "REWARD_HEAD_NAMES",
    "KnownRewardHead",
    "RewardHead",
    "RewardTracker",
    "RidgeRewardHead",
    "TabularRewardHead",
    "make_reward_head",
    "maze_cell_index",
]

DEFAULT_W_FLOOR = 1e-6
MAZE_CORNER_CELLS = (0, 4, 20, 24)
REWARD_HEAD_NAMES = frozenset({"ridge", "tabular", "corners", "known"})
# Kernel sums are computed in blocks of at most this many (query, sample) pairs, to bound memory.
KERNEL_BLOCK = 4_000_000

StatesFn = Callable[[np.ndarray], np.ndarray]


def log_sample_count(n_samples: int) -> float:
    """log|Xi_tau| of eq. 9 and 10, with |Xi_tau| taken as at least 2 (see the module docstring)."""
    return float(np.log(max(n_samples, 2)))


def confidence_width(log_count: float, weights: np.ndarray, w_floor: float) -> np.ndarray:
    """sqrt(log|Xi_tau| / W(s)): eq. 9 (W a neighbouring weight) or eq. 10 (W a count) without kappa."""
    return np.sqrt(log_count / np.maximum(weights, w_floor))


class RewardTracker:
    """
    R~ of a head on a fixed but growable set of query states (e.g. every start state of a replay buffer).
    This generic one evaluates the head from scratch; ``RidgeRewardHead`` keeps its kernel sums up to date.

    :param head: the reward head
    :param states: the initial query states (n, d), possibly none
    """

    def __init__(self, head: RewardHead, states: np.ndarray):
        self.head = head
        self._states = GrowableArray(np.asarray(states).shape[1])
        self.extend(states)

    @property
    def n_states(self) -> int:
        return len(self._states)

    @property
    def states(self) -> np.ndarray:
        return self._states.view()

    def extend(self, states: np.ndarray) -> None:
        """Append query states, (n, d)."""
        self._states.append(states)

    def estimate(self) -> np.ndarray:
        return self.head.estimate(self.states)

    def bonus(self) -> np.ndarray:
        return self.head.bonus(self.states)

    def optimistic(self) -> np.ndarray:
        return self.head.clip_optimistic(self.estimate() + self.bonus())


class RewardHead(ABC):
    """
    Base of the reward heads.

    :param kappa: optimism of the confidence interval (>= 0)
    :param r_max: optional upper bound on the reward (expert knowledge): R~ is capped at it
    """

    def __init__(self, kappa: float = 0.1, r_max: float | None = None):
        if not kappa >= 0:
            raise ValueError(f"kappa must be >= 0 (0 is the non-optimistic method), got {kappa}")
        self.kappa = float(kappa)
        self.r_max = r_max
        self.n_samples = 0

    def __repr__(self) -> str:
        return f"{type(self).__name__}(kappa={self.kappa}, n_samples={self.n_samples})"

    def update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """
        Add samples of the task: the start states of transitions and the rewards observed there.

        :param states: (n, d)
        :param rewards: (n,)
        """
        states = np.asarray(states, dtype=np.float64)
        states = states.reshape(len(states), -1)
        rewards = np.asarray(rewards, dtype=np.float64).reshape(-1)
        if len(rewards) != len(states):
            raise ValueError(
                f"rewards must have one entry per state, got {len(rewards)} for {len(states)} states"
            )
        if not np.all(np.isfinite(rewards)):
            raise ValueError("rewards must be finite (no NaN or inf)")
        if not np.all(np.isfinite(states)):
            raise ValueError("states must be finite (no NaN or inf)")
        self._update(states, rewards)
        self.n_samples += len(rewards)

    def bonus(self, states: np.ndarray) -> np.ndarray:
        """CI_tau(s) = kappa * uncertainty(s), shape (n,)."""
        return self.kappa * self.uncertainty(states)

    def optimistic(self, states: np.ndarray) -> np.ndarray:
        """R~_tau(s) = R^_tau(s) + CI_tau(s) (eq. 5), capped at ``r_max`` if given, shape (n,)."""
        return self.clip_optimistic(self.estimate(states) + self.bonus(states))

    def clip_optimistic(self, rewards: np.ndarray) -> np.ndarray:
        return rewards if self.r_max is None else np.minimum(rewards, self.r_max)

    def tracker(self, states: np.ndarray) -> RewardTracker:
        """R~ on a growable set of query states, kept up to date as the head learns."""
        return RewardTracker(self, states)

    @abstractmethod
    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None: ...

    @abstractmethod
    def estimate(self, states: np.ndarray) -> np.ndarray:
        """R^_tau(s), shape (n,)."""

    @abstractmethod
    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        """The kappa-free confidence width sqrt(log|Xi_tau| / W_tau(s)), shape (n,)."""

    @abstractmethod
    def frozen_uncertainty(self) -> StatesFn:
        """The uncertainty function as of now, unaffected by later updates (for the refit trigger)."""


class RidgeRewardHead(RewardHead):
    """
    Continuous setting: ridge regression of the reward on Phi(s) and the neighbouring-weight CI of eq. 9.

    :param features: Phi, states (n, d) -> (n, k) (e.g. an ``RBFGrid``)
    :param kappa: optimism (eq. 9)
    :param sigma: width of the similarity (eq. 6 / 7)
    :param similarity: ``"state"`` (eq. 6) or ``"features"`` (eq. 7)
    :param ridge: Tikhonov regularisation lambda (1 in the paper)
    :param w_floor: floor on W_tau(s) (see the module docstring)
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
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}")
        if similarity not in ("state", "features"):
            raise ValueError(f"similarity must be 'state' (eq. 6) or 'features' (eq. 7), got {similarity!r}")
        if not ridge > 0:
            raise ValueError(f"ridge must be > 0, got {ridge}")
        if not w_floor > 0:
            raise ValueError(f"w_floor must be > 0, got {w_floor}")
        self.features = features
        self.sigma = float(sigma)
        self.similarity = similarity
        self.ridge = float(ridge)
        self.w_floor = float(w_floor)
        self._gram: np.ndarray | None = None  # lambda I + Phi^T Phi, (k, k)
        self._moments: np.ndarray | None = None  # Phi^T r, (k,)
        self._weights: np.ndarray | None = None  # cached solution, None when stale
        self._points: GrowableArray | None = None  # what the similarity compares: states or Phi(states)

    def similarity_points(self, states: np.ndarray, phi: np.ndarray | None = None) -> np.ndarray:
        """The vectors the similarity compares: the states (eq. 6) or their features (eq. 7)."""
        if self.similarity == "state":
            return states
        return self.features(states) if phi is None else phi

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        phi = self.features(states)  # (n, k)
        if self._gram is None:
            self._gram = self.ridge * np.eye(phi.shape[1])
            self._moments = np.zeros(phi.shape[1])
        assert self._moments is not None
        self._gram += phi.T @ phi
        self._moments += phi.T @ rewards
        self._weights = None
        points = self.similarity_points(states, phi)
        if self._points is None:
            self._points = GrowableArray(points.shape[1])
        self._points.append(points)

    @property
    def weights(self) -> np.ndarray | None:
        """Ridge solution (Phi^T Phi + lambda I)^-1 Phi^T r, or None before the first sample."""
        if self._weights is None and self._gram is not None:
            self._weights = np.linalg.solve(self._gram, self._moments)
        return self._weights

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return self.estimate_from_features(self.features(np.asarray(states, dtype=np.float64)))

    def estimate_from_features(self, phi: np.ndarray) -> np.ndarray:
        """R^ from precomputed features (n, k)."""
        weights = self.weights
        return np.zeros(len(phi)) if weights is None else phi @ weights

    def kernel_sums(self, points: np.ndarray, start: int = 0, stop: int | None = None) -> np.ndarray:
        """
        W(s) = sum_j S(s, s_j) (eq. 8) over the samples ``start:stop`` (all by default).

        :param points: similarity points of the query states (n, p) (see ``similarity_points``)
        :return: (n,)
        """
        sums = np.zeros(len(points))
        if self._points is None:
            return sums
        samples = self._points.view(start, stop)
        block = max(1, KERNEL_BLOCK // max(1, len(points)))
        for first in range(0, len(samples), block):
            sums += gaussian_similarity(points, samples[first : first + block], self.sigma).sum(axis=1)
        return sums

    def uncertainty_at(self, states: np.ndarray, n_samples: int | None = None) -> np.ndarray:
        """Eq. 9 without kappa, using only the first ``n_samples`` samples (all by default)."""
        n = self.n_samples if n_samples is None else n_samples
        states = np.asarray(states, dtype=np.float64).reshape(len(states), -1)
        weights = self.kernel_sums(self.similarity_points(states), 0, n)
        return confidence_width(log_sample_count(n), weights, self.w_floor)

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return self.uncertainty_at(states)

    def frozen_uncertainty(self) -> StatesFn:
        # Samples are only ever appended, so the first n samples are the head as of now.
        return partial(self.uncertainty_at, n_samples=self.n_samples)

    def tracker(self, states: np.ndarray) -> RewardTracker:
        return KernelSumTracker(self, states)


class KernelSumTracker(RewardTracker):
    """
    R~ of a ``RidgeRewardHead`` on a growable set of query states, with their features and kernel sums W
    cached: each call folds in only the samples the head received since the previous one.
    """

    head: RidgeRewardHead

    def __init__(self, head: RidgeRewardHead, states: np.ndarray):
        self._phi: GrowableArray | None = None
        self._points: GrowableArray | None = None
        self._kernel_sums = np.zeros(0)
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
        new_sums = self.head.kernel_sums(points, 0, self._n_folded)
        self._kernel_sums = np.concatenate([self._kernel_sums, new_sums])

    def _fold_new_samples(self) -> None:
        if self.head.n_samples > self._n_folded and self._points is not None:
            self._kernel_sums += self.head.kernel_sums(
                self._points.view(), self._n_folded, self.head.n_samples
            )
            self._n_folded = self.head.n_samples

    def estimate(self) -> np.ndarray:
        if self._phi is None:
            return np.zeros(0)
        return self.head.estimate_from_features(self._phi.view())

    def bonus(self) -> np.ndarray:
        self._fold_new_samples()
        width = confidence_width(log_sample_count(self.head.n_samples), self._kernel_sums, self.head.w_floor)
        return self.head.kappa * width


class TabularRewardHead(RewardHead):
    """
    Discrete setting: per-cell mean rewards and the UCB-style CI of eq. 10 on a discretisation of the states.

    :param cell_fn: states (n, d) -> cell ids (n,) in 0..n_cells-1
    :param n_cells: number of cells
    :param kappa: optimism (eq. 10)
    :param allowed_cells: cells where the reward may be non-zero (expert knowledge); elsewhere R^ = 0 and
        there is no bonus. None: every cell
    :param w_floor: floor on the count N_tau(s) of an unvisited cell (see the module docstring)
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
        if not w_floor > 0:
            raise ValueError(f"w_floor must be > 0, got {w_floor}")
        self.cell_fn = cell_fn
        self.n_cells = int(n_cells)
        self.w_floor = float(w_floor)
        self.allowed = np.ones(self.n_cells, dtype=bool)
        if allowed_cells is not None:
            self.allowed[:] = False
            self.allowed[list(allowed_cells)] = True
        self.counts = np.zeros(self.n_cells)
        self.sums = np.zeros(self.n_cells)

    def _cells(self, states: np.ndarray) -> np.ndarray:
        return np.asarray(self.cell_fn(np.asarray(states, dtype=np.float64)), dtype=np.int64)

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        cells = self._cells(states)
        np.add.at(self.counts, cells, 1.0)
        np.add.at(self.sums, cells, rewards)

    def cell_means(self) -> np.ndarray:
        """R^ per cell: the mean reward of its samples, 0 where it has none or is not allowed, (n_cells,)."""
        means = np.divide(self.sums, self.counts, out=np.zeros(self.n_cells), where=self.counts > 0)
        return np.where(self.allowed, means, 0.0)

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return self.cell_means()[self._cells(states)]

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return frozen_cell_uncertainty(
            self.counts, self.allowed, self.n_samples, self.w_floor, self.cell_fn, states
        )

    def frozen_uncertainty(self) -> StatesFn:
        return partial(
            frozen_cell_uncertainty,
            self.counts.copy(),
            self.allowed,
            self.n_samples,
            self.w_floor,
            self.cell_fn,
        )


def frozen_cell_uncertainty(
    counts: np.ndarray,
    allowed: np.ndarray,
    n_samples: int,
    w_floor: float,
    cell_fn: Callable[[np.ndarray], np.ndarray],
    states: np.ndarray,
) -> np.ndarray:
    """Eq. 10 without kappa for per-cell counts N_tau: sqrt(log|Xi_tau| / N_tau(s)), 0 outside allowed."""
    per_cell = np.where(allowed, confidence_width(log_sample_count(n_samples), counts, w_floor), 0.0)
    return per_cell[np.asarray(cell_fn(np.asarray(states, dtype=np.float64)), dtype=np.int64)]


class KnownRewardHead(RewardHead):
    """
    The reward function is known (the paper's first experiment): R^ is it and CI = 0.

    :param reward_fn: states (n, d) -> expected rewards (n,)
    """

    def __init__(self, reward_fn: StatesFn):
        super().__init__(kappa=0.0)
        self.reward_fn = reward_fn

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """Nothing to learn: only the sample count moves."""

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return np.asarray(self.reward_fn(np.asarray(states, dtype=np.float64)), dtype=np.float64)

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        return np.zeros(len(states))

    def frozen_uncertainty(self) -> StatesFn:
        return self.uncertainty


def maze_cell_index(states: np.ndarray) -> np.ndarray:
    """The maze cell of each state as the index 5 (ceil(x) - 1) + (ceil(y) - 1) in 0..24."""
    cells = np.clip(np.ceil(np.asarray(states, dtype=np.float64).reshape(-1, 2)), 1, 5).astype(np.int64) - 1
    return 5 * cells[:, 0] + cells[:, 1]


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

    :param name: the head's name
    :param features: Phi for the ridge head
    :param kappa: optimism
    :param sigma: similarity width of the ridge head
    :param similarity: similarity of the ridge head, ``"state"`` or ``"features"``
    :param reward_fn: the known expected reward, states -> (n,)
    :param kwargs: further arguments of the head's class (``w_floor``, ``r_max``, ``ridge``)
    """
    if name == "ridge":
        if features is None:
            raise ValueError("the 'ridge' reward_head needs features")
        return RidgeRewardHead(features, kappa=kappa, sigma=sigma, similarity=similarity, **kwargs)
    if name in ("tabular", "corners"):
        allowed = MAZE_CORNER_CELLS if name == "corners" else None
        return TabularRewardHead(maze_cell_index, 25, kappa=kappa, allowed_cells=allowed, **kwargs)
    if name == "known":
        if reward_fn is None:
            raise ValueError("the 'known' reward_head needs reward_fn, the expected reward of the task")
        return KnownRewardHead(reward_fn)
    raise ValueError(f"reward_head must be one of {sorted(REWARD_HEAD_NAMES)}, got {name!r}")
