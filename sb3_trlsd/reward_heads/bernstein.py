"""A reward head with the empirical-Bernstein bound of UCB-V, kernel-weighted (instead of eq. 9).

``BernsteinRewardHead``: the bound of UCB-V (Audibert, Munos & Szepesvari, "Exploration-exploitation
tradeoff using variance estimates in multi-armed bandits", TCS 2009) with the samples weighted by the
similarity of eq. 6: its CI shrinks faster where the neighbours agree on the reward, which eq. 9 ignores.
The maths is in plain functions over arrays (``kernel_reward_sums``, ``kernel_mean``,
``empirical_bernstein_width``); the head holds the samples.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.reward_heads.base import (
    DEFAULT_W_FLOOR,
    RewardHead,
    RewardTracker,
    check_positive,
)
from sb3_trlsd.reward_heads.ridge import KERNEL_BLOCK
from sb3_trlsd.similarity import gaussian_similarity, similarity_widths

__all__ = [
    "BernsteinRewardHead",
    "BernsteinTracker",
    "empirical_bernstein_width",
    "kernel_mean",
    "kernel_reward_sums",
]

StatesFn = Callable[[np.ndarray], np.ndarray]


def kernel_reward_sums(
    points: np.ndarray, sample_points: np.ndarray, rewards: np.ndarray, sigma: float
) -> np.ndarray:
    """
    The kernel-weighted sums (W, sum_j w_j r_j, sum_j w_j r_j^2) at each query, w_j(s) = S(s, s_j) (eq. 6).

    :param points: query states (n, d)
    :param sample_points: sample states (m, d)
    :param rewards: their rewards (m,)
    :param sigma: width of the similarity (> 0)
    :return: (n, 3)
    """
    similarity = gaussian_similarity(points, sample_points, sigma)  # (n, m), eq. 6
    return similarity @ np.column_stack([np.ones(len(rewards)), rewards, rewards**2])


def kernel_mean(sums: np.ndarray, w_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """
    The kernel-weighted mean mu(s) = sum w r / W and variance V(s) = sum w r^2 / W - mu^2 of the rewards,
    W floored at ``w_floor`` (V >= 0 still holds with the floor, by Cauchy-Schwarz; clipped for rounding).

    :param sums: ``kernel_reward_sums``, (n, 3)
    :param w_floor: floor on W (> 0)
    :return: mu (n,), V (n,)
    """
    weights = np.maximum(sums[:, 0], w_floor)
    mean = sums[:, 1] / weights
    return mean, np.maximum(sums[:, 2] / weights - mean**2, 0.0)


def empirical_bernstein_width(
    sums: np.ndarray, log_count: float, reward_range: float, w_floor: float
) -> np.ndarray:
    """
    UCB-V's empirical-Bernstein width with the count replaced by the neighbouring weight W(s) (eq. 8):
    sqrt(2 V(s) L / W(s)) + 3 b L / W(s), L = log|Xi| (Audibert, Munos & Szepesvari 2009, Theorem 1).

    :param sums: ``kernel_reward_sums``, (n, 3)
    :param log_count: L (see ``log_sample_count``)
    :param reward_range: b, the range of the rewards
    :param w_floor: floor on W (> 0)
    :return: (n,)
    """
    weights = np.maximum(sums[:, 0], w_floor)
    _, variance = kernel_mean(sums, w_floor)
    return np.sqrt(2.0 * variance * log_count / weights) + 3.0 * reward_range * log_count / weights


class BernsteinRewardHead(RewardHead):
    """
    A kernel-weighted empirical-Bernstein bound, after UCB-V (Audibert, Munos & Szepesvari,
    "Exploration-exploitation tradeoff using variance estimates in multi-armed bandits", TCS 2009). With
    the weights w_j(s) = S(s, s_j) of eq. 6 and W(s) = sum_j w_j(s) (eq. 8):

        R^(s) = mu(s) = sum_j w_j(s) r_j / W(s)          (the kernel mean, Nadaraya-Watson)
        V(s) = sum_j w_j(s) r_j^2 / W(s) - mu(s)^2        (how much the neighbours disagree)
        CI(s) = kappa (sqrt(2 V(s) L / W(s)) + 3 b L / W(s)),  L = log|Xi_tau|

    R^ is the kernel mean rather than the ridge estimate because V is the spread around it: the bound is
    about that estimator. kappa multiplies the whole bound as in eq. 9 (1 is UCB-V's constant). Where the
    neighbours agree (V -> 0) the CI decays like 1 / W instead of eq. 9's 1 / sqrt(W); under the maze's
    N(0, 1) noise V ~ 1 and the first term is sqrt(2) times eq. 9's width. W is floored at ``w_floor``, so
    the CI is at most kappa 3 b L / w_floor far from every sample (see ``base.py``).

    :param kappa: optimism, >= 0
    :param sigma: width of the similarity (eq. 6) in state units, > 0: one, or one per state dimension (eq. 6
        then weighs each dimension by its own width, as ``RidgeRewardHead`` does)
    :param reward_range: b, the range of the rewards (UCB-V's rewards lie in [0, b]), > 0; 1 is the range of
        the maze's expected rewards, whose observed rewards carry unbounded Gaussian noise: there b is a
        scale of the second-order term, not a bound
    :param w_floor: floor on W(s), > 0
    :param r_max: optional cap on R~
    """

    _point_scale: np.ndarray | None = None  # heads saved before per-dimension widths had one width

    def __init__(
        self,
        kappa: float = 0.1,
        sigma: float | Sequence[float] | np.ndarray = 0.2,
        reward_range: float = 1.0,
        w_floor: float = DEFAULT_W_FLOOR,
        r_max: float | None = None,
    ):
        super().__init__(kappa, r_max)
        if not (check_positive("reward_range", reward_range, "b, the range of the rewards") < np.inf):
            raise ValueError(f"reward_range must be finite (b, the range of the rewards), got {reward_range}")
        self.sigma, self._point_scale = similarity_widths(sigma)  # one width, or one per dimension
        self.reward_range = float(reward_range)
        self.w_floor = check_positive("w_floor", w_floor, "the floor of the neighbouring weight W")
        self._states: GrowableArray | None = None  # s_j as the similarity compares them, (n, d)
        self._rewards = GrowableArray(1)  # r_j, (n, 1)

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"sigma={self.sigma:g}", f"reward_range={self.reward_range:g}"]

    def _points(self, states: np.ndarray) -> np.ndarray:
        """The states as the similarity of width ``sigma`` compares them (rescaled for several widths)."""
        return states if self._point_scale is None else states * self._point_scale

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        if self._states is None:
            self._states = GrowableArray(states.shape[1])
        self._states.append(self._points(states))
        self._rewards.append(rewards)

    def reward_sums(self, states: np.ndarray, start: int = 0, stop: int | None = None) -> np.ndarray:
        """
        (W, sum w r, sum w r^2) at the query states over the samples ``start:stop`` (all by default), in
        blocks of at most ``KERNEL_BLOCK`` (query, sample) pairs.

        :param states: query states (n, d)
        :param start: first sample
        :param stop: end of the samples (exclusive), None for all
        :return: (n, 3)
        """
        states = self._points(np.asarray(states, dtype=np.float64))
        sums = np.zeros((len(states), 3))
        if self._states is None:
            return sums
        samples, rewards = self._states.view(start, stop), self._rewards.view(start, stop)[:, 0]
        block = max(1, KERNEL_BLOCK // max(1, len(states)))
        for first in range(0, len(samples), block):
            chunk = slice(first, first + block)
            sums += kernel_reward_sums(states, samples[chunk], rewards[chunk], self.sigma)
        return sums

    def width_from_sums(self, sums: np.ndarray, n_samples: int) -> np.ndarray:
        """
        The kappa-free width from the kernel sums over ``n_samples`` samples.

        :param sums: (n, 3)
        :param n_samples: |Xi_tau| of the sums
        :return: (n,)
        """
        return empirical_bernstein_width(sums, self.log_count(n_samples), self.reward_range, self.w_floor)

    def optimistic_from_sums(self, sums: np.ndarray) -> np.ndarray:
        """
        R~ = mu + kappa width, capped at ``r_max``, from the sums over all samples.

        :param sums: (n, 3)
        :return: (n,)
        """
        mean, _ = kernel_mean(sums, self.w_floor)
        if self.kappa == 0:
            return self.clip_optimistic(mean)
        return self.clip_optimistic(mean + self.kappa * self.width_from_sums(sums, self.n_samples))

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return kernel_mean(self.reward_sums(states), self.w_floor)[0]

    def optimistic(self, states: np.ndarray) -> np.ndarray:
        return self.optimistic_from_sums(self.reward_sums(states))  # one kernel sum for R^ and CI

    def snapshot(self) -> int:
        # Samples are only ever appended, so the first n samples are the head as of now.
        return self.n_samples

    def uncertainty_as_of(self, snapshot: int, states: np.ndarray) -> np.ndarray:
        return self.width_from_sums(self.reward_sums(states, 0, snapshot), snapshot)

    def uncertainty_then_and_now(self, snapshot: int, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        then = self.reward_sums(states, 0, snapshot)  # one similarity per sample for both
        now = then + self.reward_sums(states, snapshot)
        return self.width_from_sums(then, snapshot), self.width_from_sums(now, self.n_samples)

    def tracker(self, states: np.ndarray) -> BernsteinTracker:
        return BernsteinTracker(self, states)


class BernsteinTracker(RewardTracker):
    """
    R~ of a ``BernsteinRewardHead`` on a growable set of query states with their kernel sums (W, sum w r,
    sum w r^2) cached: each call folds in only the samples the head received since the previous one, so
    relabelling m states after n new samples costs O(m n) instead of O(m |Xi_tau|).

    :param head: the Bernstein head
    :param states: the initial query states (m, d)
    """

    head: BernsteinRewardHead

    def __init__(self, head: BernsteinRewardHead, states: np.ndarray):
        self._sums = GrowableArray(3)  # the sums at the queries over the first _n_folded samples, (m, 3)
        self._n_folded = head.n_samples
        super().__init__(head, states)

    def extend(self, states: np.ndarray) -> None:
        states = np.asarray(states, dtype=np.float64)
        super().extend(states)
        self._sums.append(self.head.reward_sums(states, 0, self._n_folded))

    def sums(self) -> np.ndarray:
        """The kernel sums at the query states over all the head's samples, (m, 3), a view."""
        if self.head.n_samples > self._n_folded:
            # The sums are over samples: add the terms of the new ones only.
            self._sums.view()[:] += self.head.reward_sums(self.states, self._n_folded, self.head.n_samples)
        self._n_folded = self.head.n_samples
        return self._sums.view()

    def estimate(self) -> np.ndarray:
        return kernel_mean(self.sums(), self.head.w_floor)[0]

    def bonus(self) -> np.ndarray:
        if self.head.kappa == 0:
            return np.zeros(self.n_states)
        return self.head.kappa * self.head.width_from_sums(self.sums(), self.head.n_samples)

    def optimistic(self) -> np.ndarray:
        return self.head.optimistic_from_sums(self.sums())
