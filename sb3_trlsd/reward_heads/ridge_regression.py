"""The running ridge regression of the reward on Phi(s) that eq. 9's head and the posterior heads share."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["RidgeRegression"]


class RidgeRegression:
    """
    R^(s) = Phi(s) . w with w = A^-1 Phi^T r, A = Phi^T Phi + lambda I, from running sums of Phi^T Phi and
    Phi^T r (``_accumulate``), solved lazily (k x k) and cached until the next sample.

    A mixin of reward heads (before ``RewardHead`` in the bases): the head sets ``features`` (Phi) and
    ``ridge`` (lambda) and calls ``_start_ridge_regression`` in its constructor.
    """

    features: Callable[[np.ndarray], np.ndarray]
    ridge: float

    def _start_ridge_regression(self) -> None:
        """No sample yet: A and Phi^T r are made at the first (their size is the features')."""
        self._gram: np.ndarray | None = None  # A = Phi^T Phi + lambda I, (k, k)
        self._moments: np.ndarray | None = None  # Phi^T r, (k,)
        self._weights: np.ndarray | None = None  # the cached solution, None when stale

    def _accumulate(self, phi: np.ndarray, rewards: np.ndarray) -> None:
        """
        Add samples to the running sums.

        :param phi: Phi(s) of the samples, (n, k)
        :param rewards: their rewards, (n,)
        """
        if self._gram is None:
            self._gram = self.ridge * np.eye(phi.shape[1])
            self._moments = np.zeros(phi.shape[1])
        assert self._moments is not None
        self._gram += phi.T @ phi
        self._moments += phi.T @ rewards
        self._weights = None

    @property
    def weights(self) -> np.ndarray | None:
        """The ridge solution w = A^-1 Phi^T r, (k,), or None before the first sample."""
        if self._weights is None and self._gram is not None and self._moments is not None:
            self._weights = np.linalg.solve(self._gram, self._moments)
        return self._weights

    def estimate(self, states: np.ndarray) -> np.ndarray:
        """R^(s) = Phi(s) . w, (n,), 0 before the first sample."""
        return self.estimate_from_features(self.features(np.asarray(states, dtype=np.float64)))

    def estimate_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        R^ from precomputed features.

        :param phi: Phi(s), (n, k)
        :return: (n,), 0 before the first sample
        """
        weights = self.weights
        return np.zeros(len(phi)) if weights is None else phi @ weights
