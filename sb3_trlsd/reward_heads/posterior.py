"""A reward head on the ridge regression's posterior: OFUL / LinUCB's ellipsoid (Thompson: ``thompson.py``).

- ``RidgePosteriorRewardHead``: the ellipsoidal bound of OFUL / LinUCB, CI(s) = beta sqrt(phi(s)^T A^-1
  phi(s)) with A = Phi^T Phi + lambda I (Abbasi-Yadkori, Pal & Szepesvari, "Improved algorithms for linear
  stochastic bandits", NeurIPS 2011), and their rarely-switching refit rule: refit once det A has grown by
  a factor (``refit_due``).
- ``ThompsonRidgeRewardHead`` (``thompson.py``) draws the weights from this posterior instead.

The maths is in plain functions over arrays (``posterior_widths``, ``sample_posterior_weights``); the heads
hold the running sums. Other confidence bounds: ``bernstein.py``; the paper's: ``ridge.py``, ``tabular.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.reward_heads.base import (
    RewardHead,
    RewardTracker,
    check_positive,
)
from sb3_trlsd.reward_heads.ridge_regression import RidgeRegression

__all__ = [
    "PosteriorSnapshot",
    "PosteriorTracker",
    "RidgePosteriorRewardHead",
    "posterior_widths",
    "sample_posterior_weights",
]

StatesFn = Callable[[np.ndarray], np.ndarray]


# ------------------------------------------------------------------------------------------- linear posterior
def posterior_widths(phi: np.ndarray, gram_inverse: np.ndarray) -> np.ndarray:
    """
    The ellipsoidal width ||phi(s)||_{A^-1} = sqrt(phi(s)^T A^-1 phi(s)) of OFUL / LinUCB, row by row.

    :param phi: Phi(s), (n, k)
    :param gram_inverse: A^-1, (k, k), symmetric positive definite
    :return: (n,)
    """
    quadratic = np.einsum("ij,ij->i", phi @ gram_inverse, phi)  # phi_i^T A^-1 phi_i
    return np.sqrt(np.maximum(quadratic, 0.0))  # >= 0 up to rounding


def sample_posterior_weights(
    rng: np.random.Generator, weights: np.ndarray, gram: np.ndarray, scale: float, n_draws: int = 1
) -> np.ndarray:
    """
    Draws w~ ~ N(w_hat, v^2 A^-1): with A = L L^T (Cholesky), w~ = w_hat + v L^-T z, z ~ N(0, I), whose
    covariance is v^2 L^-T L^-1 = v^2 A^-1. ``n_draws`` draws at once take the same normals as as many
    single draws in a row.

    :param rng: the generator of z
    :param weights: the posterior mean w_hat, (k,)
    :param gram: A = Phi^T Phi + lambda I, (k, k)
    :param scale: the posterior scale v (>= 0)
    :param n_draws: the number of draws
    :return: (n_draws, k)
    """
    lower = np.linalg.cholesky(gram)  # A = L L^T
    normals = rng.standard_normal((n_draws, len(weights)))  # z, one row per draw
    return weights + scale * np.linalg.solve(lower.T, normals.T).T  # w_hat + v L^-T z


class PosteriorSnapshot(NamedTuple):
    """What the linear-posterior heads' uncertainty and refit rule depend on, as of a refit."""

    gram_inverse: np.ndarray | None  # A^-1, (k, k); None before the first sample (A = lambda I)
    log_det_gram: float | None  # log det A; None before the first sample


class RidgePosteriorRewardHead(RidgeRegression, RewardHead):
    """
    Ridge regression of the reward on Phi(s) with the ellipsoidal confidence bound of OFUL / LinUCB
    (Abbasi-Yadkori, Pal & Szepesvari, "Improved algorithms for linear stochastic bandits", NeurIPS 2011):

        R^(s) = Phi(s) . w_hat,  w_hat = A^-1 Phi^T r,  A = Phi^T Phi + lambda I
        CI(s) = kappa sqrt(phi(s)^T A^-1 phi(s))

    ``kappa`` is a constant beta: OFUL's beta_t grows like sqrt(log det A) and needs the noise level and a
    bound on ||w||, which TRLSD does not assume (LinUCB's choice). A >= lambda I bounds the width by
    ||phi(s)|| / sqrt(lambda): no floor is needed, but the width vanishes where the features do (far from
    every RBF centre), where eq. 9 is at its largest.

    The refit rule of rarely-switching OFUL, det A_now >= update_ratio * det A_then, is ``refit_due``; the
    uncertainty (``uncertainty_then_and_now``) also serves the paper's pointwise trigger.

    :param features: Phi, states (n, d) -> (n, k) (e.g. an ``RBFGrid``; picklable, no lambda)
    :param kappa: optimism beta, >= 0
    :param ridge: Tikhonov regularisation lambda (1 in the paper), > 0
    :param r_max: optional cap on R~
    """

    def __init__(
        self, features: StatesFn, kappa: float = 0.1, ridge: float = 1.0, r_max: float | None = None
    ):
        super().__init__(kappa, r_max)
        if not callable(features):
            raise ValueError(f"features must be Phi, a callable states (n, d) -> (n, k), got {features!r}")
        self.features = features
        self.ridge = check_positive("ridge", ridge, "the Tikhonov regularisation lambda, 1 in the paper")
        self._start_ridge_regression()
        # Derived from A on demand, None when stale.
        self._gram_inverse: np.ndarray | None = None
        self._log_det_gram: float | None = None

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"ridge={self.ridge:g}"]

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        self._accumulate(self.features(states), rewards)
        self._gram_inverse = self._log_det_gram = None

    @property
    def gram(self) -> np.ndarray | None:
        """A = Phi^T Phi + lambda I, (k, k), or None before the first sample."""
        return self._gram

    @property
    def gram_inverse(self) -> np.ndarray | None:
        """A^-1, (k, k), symmetric, or None before the first sample."""
        if self._gram_inverse is None and self._gram is not None:
            inverse = np.linalg.inv(self._gram)
            self._gram_inverse = 0.5 * (inverse + inverse.T)  # symmetric up to rounding: make it exactly
        return self._gram_inverse

    @property
    def log_det_gram(self) -> float | None:
        """log det A (by ``slogdet``: det A itself overflows with many samples), or None before any."""
        if self._log_det_gram is None and self._gram is not None:
            sign, log_det = np.linalg.slogdet(self._gram)
            assert sign > 0, "A = Phi^T Phi + lambda I is positive definite"
            self._log_det_gram = float(log_det)
        return self._log_det_gram

    def widths_from_features(self, phi: np.ndarray, gram_inverse: np.ndarray | None) -> np.ndarray:
        """
        sqrt(phi^T A^-1 phi) for a given A^-1 (None: the prior A = lambda I, sqrt(||phi||^2 / lambda)).

        :param phi: Phi(s), (n, k)
        :param gram_inverse: A^-1 (k, k) or None
        :return: (n,)
        """
        if gram_inverse is None:
            return np.sqrt(np.einsum("ij,ij->i", phi, phi) / self.ridge)
        return posterior_widths(phi, gram_inverse)

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        """
        The kappa-free width sqrt(phi(s)^T A^-1 phi(s)).

        :param states: (n, d)
        :return: (n,)
        """
        return self.widths_from_features(
            self.features(np.asarray(states, dtype=np.float64)), self.gram_inverse
        )

    def bonus_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        CI from precomputed features: kappa sqrt(phi^T A^-1 phi).

        :param phi: Phi(s), (n, k)
        :return: (n,)
        """
        if self.kappa == 0:
            return np.zeros(len(phi))
        return self.kappa * self.widths_from_features(phi, self.gram_inverse)

    def bonus(self, states: np.ndarray) -> np.ndarray:
        return self.bonus_from_features(self.features(np.asarray(states, dtype=np.float64)))

    def optimistic(self, states: np.ndarray) -> np.ndarray:
        return self.optimistic_from_features(self.features(np.asarray(states, dtype=np.float64)))

    def optimistic_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        R~ = R^ + CI from precomputed features, capped at ``r_max``.

        :param phi: Phi(s), (n, k)
        :return: (n,)
        """
        return self.clip_optimistic(self.estimate_from_features(phi) + self.bonus_from_features(phi))

    def snapshot(self) -> PosteriorSnapshot:
        gram_inverse = self.gram_inverse
        return PosteriorSnapshot(None if gram_inverse is None else gram_inverse.copy(), self.log_det_gram)

    def uncertainty_as_of(self, snapshot: PosteriorSnapshot, states: np.ndarray) -> np.ndarray:
        phi = self.features(np.asarray(states, dtype=np.float64))
        return self.widths_from_features(phi, snapshot.gram_inverse)

    def uncertainty_then_and_now(
        self, snapshot: PosteriorSnapshot, states: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        phi = self.features(np.asarray(states, dtype=np.float64))  # once for both
        return (
            self.widths_from_features(phi, snapshot.gram_inverse),
            self.widths_from_features(phi, self.gram_inverse),
        )

    def refit_due(self, snapshot: PosteriorSnapshot, state: np.ndarray, update_ratio: float) -> bool:
        """
        The refit rule of rarely-switching OFUL (Abbasi-Yadkori et al. 2011, section 5): refit once
        det A_now >= update_ratio * det A_then (2 there: determinant doubling), i.e. once the confidence
        ellipsoid's volume has shrunk by sqrt(update_ratio). Computed on log det (``slogdet``), which stays
        finite where det A overflows. The rule is global: ``state`` is not used, it is the argument the
        pointwise trigger of section 3 takes, so that a ``TaskLearner`` can call either rule the same way.

        :param snapshot: ``snapshot()`` at the last refit
        :param state: the state just encountered (d,) or (1, d), unused
        :param update_ratio: the factor det A must have grown by (> 1)
        :return: whether the task is due for a refit
        """
        if not update_ratio > 1:
            raise ValueError(f"update_ratio must be > 1 (the factor det A must grow by), got {update_ratio}")
        log_det_now = self.log_det_gram
        if log_det_now is None or self._gram is None:  # no sample yet: A is still lambda I
            return False
        log_det_then = snapshot.log_det_gram
        if log_det_then is None:  # the refit was before any sample: A was lambda I
            log_det_then = len(self._gram) * float(np.log(self.ridge))
        return bool(log_det_now - log_det_then >= np.log(update_ratio))

    def tracker(self, states: np.ndarray) -> PosteriorTracker:
        return PosteriorTracker(self, states)


class PosteriorTracker(RewardTracker):
    """
    R~ of a ``RidgePosteriorRewardHead`` (or ``ThompsonRidgeRewardHead``) on a growable set of query states
    with their features cached: each call costs products with the current w_hat and A^-1 (or w~), O(m k^2),
    and no feature evaluation.

    :param head: the linear-posterior head
    :param states: the initial query states (m, d)
    """

    head: RidgePosteriorRewardHead

    def __init__(self, head: RidgePosteriorRewardHead, states: np.ndarray):
        self._phi: GrowableArray | None = None  # Phi(query), (m, k)
        super().__init__(head, states)

    def extend(self, states: np.ndarray) -> None:
        states = np.asarray(states, dtype=np.float64)
        phi = self.head.features(states)
        if self._phi is None:
            self._phi = GrowableArray(phi.shape[1])
        self._phi.append(phi)
        super().extend(states)

    @property
    def phi(self) -> np.ndarray:
        """Phi of the query states, (m, k), a view."""
        assert self._phi is not None  # set by extend in __init__
        return self._phi.view()

    def estimate(self) -> np.ndarray:
        return self.head.estimate_from_features(self.phi)

    def bonus(self) -> np.ndarray:
        return self.head.bonus_from_features(self.phi)

    def optimistic(self) -> np.ndarray:
        return self.head.optimistic_from_features(self.phi)
