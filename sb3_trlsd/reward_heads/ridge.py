"""Continuous setting: R^ by ridge regression on Phi(s), CI by the neighbouring weight of eq. 8-9."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.reward_heads.base import (
    DEFAULT_W_FLOOR,
    RewardHead,
    RewardTracker,
    check_positive,
    confidence_width,
)
from sb3_trlsd.reward_heads.ridge_regression import RidgeRegression
from sb3_trlsd.similarity import gaussian_similarity, similarity_widths

__all__ = ["SIMILARITIES", "KernelSumTracker", "RidgeRewardHead"]

SIMILARITIES = ("state", "features")
# Kernel sums are computed in blocks of at most this many (query, sample) pairs (32 MB of float64).
KERNEL_BLOCK = 4_000_000

StatesFn = Callable[[np.ndarray], np.ndarray]


class RidgeRewardHead(RidgeRegression, RewardHead):
    """
    Continuous setting: ridge regression of the reward on Phi(s) and the neighbouring-weight CI of eq. 9.

    R^(s) = Phi(s) . w with w = (Phi^T Phi + lambda I)^-1 Phi^T r (``RidgeRegression``). The sample states
    (or their features, for the eq. 7 similarity) are kept in a growable array for the kernel sums W_tau(s)
    of eq. 8.

    :param features: Phi, states (n, d) -> (n, k) (e.g. an ``RBFGrid``)
    :param kappa: optimism (eq. 9), >= 0
    :param sigma: width of the similarity (eq. 6 / 7), > 0; for the ``"state"`` similarity one width per
        state dimension is allowed (in state units: eq. 6 then weighs each dimension by its own width)
    :param similarity: ``"state"`` (S_S, eq. 6, on states) or ``"features"`` (S_Phi, eq. 7, on Phi(s))
    :param ridge: Tikhonov regularisation lambda (1 in the paper), > 0
    :param w_floor: floor on W_tau(s), > 0 (see the module docstring)
    :param r_max: optional cap on R~
    """

    def __init__(
        self,
        features: StatesFn,
        kappa: float = 0.1,
        sigma: float | Sequence[float] | np.ndarray = 0.2,
        similarity: str = "state",
        ridge: float = 1.0,
        w_floor: float = DEFAULT_W_FLOOR,
        r_max: float | None = None,
    ):
        super().__init__(kappa, r_max)
        if similarity not in SIMILARITIES:
            raise ValueError(f"similarity must be 'state' (eq. 6) or 'features' (eq. 7), got {similarity!r}")
        self.features = features
        self.sigma, self._point_scale = similarity_widths(sigma)
        if np.size(sigma) > 1 and similarity != "state":
            raise ValueError(
                "one sigma per dimension is for the 'state' similarity; eq. 7's takes one number"
            )
        self.similarity = similarity
        self.ridge = check_positive("ridge", ridge, "the Tikhonov regularisation lambda, 1 in the paper")
        self.w_floor = check_positive("w_floor", w_floor, "the floor of the neighbouring weight W")
        self._start_ridge_regression()
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
            states = np.asarray(states, dtype=np.float64)
            return states if self._point_scale is None else states * self._point_scale
        return self.features(states) if phi is None else phi

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        phi = self.features(states)  # (n, k)
        self._accumulate(phi, rewards)
        points = self.similarity_points(states, phi)
        if self._points is None:
            self._points = GrowableArray(points.shape[1])
        self._points.append(points)

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
        return confidence_width(self.log_count(n), weights, self.w_floor)  # eq. 9 / kappa

    def snapshot(self) -> int:
        # Samples are only ever appended, so the first n samples are the head as of now.
        return self.n_samples

    def uncertainty_as_of(self, snapshot: int, states: np.ndarray) -> np.ndarray:
        return self.uncertainty_at(states, snapshot)

    def uncertainty_then_and_now(self, snapshot: int, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # W over the first `snapshot` samples, then over the rest: one similarity per sample (eq. 8).
        points = self.similarity_points(states)
        if self._points is None or len(points) * self.n_samples > KERNEL_BLOCK:
            then = self.kernel_sums(points, 0, snapshot)
            now = then + self.kernel_sums(points, snapshot)
        else:
            similarity = gaussian_similarity(points, self._points.view(), self.sigma)  # eq. 6 or 7
            then = similarity[:, :snapshot].sum(axis=1)
            now = then + similarity[:, snapshot:].sum(axis=1)
        return (
            confidence_width(self.log_count(snapshot), then, self.w_floor),
            confidence_width(self.log_count(self.n_samples), now, self.w_floor),
        )  # eq. 9 / kappa

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
            self.head.log_count(self.head.n_samples), weights, self.head.w_floor
        )  # eq. 9
