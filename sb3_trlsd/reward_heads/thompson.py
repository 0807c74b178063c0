"""Posterior (Thompson) sampling of the ridge head's weights, one draw per refit.

``ThompsonRidgeRewardHead``: PSRL with known dynamics (Osband, Russo & Van Roy, "(More) efficient
reinforcement learning via posterior sampling", NeurIPS 2013) on the posterior of
``RidgePosteriorRewardHead`` (``posterior.py``), whose uncertainty, refit rule and tracker it keeps.
"""

from __future__ import annotations

import numpy as np

from sb3_trlsd.reward_heads.posterior import (
    PosteriorSnapshot,
    RidgePosteriorRewardHead,
    StatesFn,
    sample_posterior_weights,
)

__all__ = ["KAPPA_SCALES", "ThompsonRidgeRewardHead"]

# What the posterior scale kappa is measured in: the env's reward units, or the largest absolute reward the
# head has seen (1 before any: until a reward is met, the greedy policy on a draw does not depend on its
# scale).
KAPPA_SCALES = ("reward", "observed")


class ThompsonRidgeRewardHead(RidgePosteriorRewardHead):
    """
    Posterior sampling of the ridge weights, as PSRL does with known dynamics (Osband, Russo & Van Roy,
    "(More) efficient reinforcement learning via posterior sampling", NeurIPS 2013): at each refit one
    draw w~ ~ N(w_hat, v^2 A^-1), A = Phi^T Phi + lambda I, and

        R~(s) = Phi(s) . w~,  i.e. R^(s) = Phi(s) . w_hat and CI(s) = Phi(s) . (w~ - w_hat)

    with ``kappa`` = v, the posterior scale (the reward noise's standard deviation makes the posterior the
    Bayesian one under a N(0, v^2 / lambda I) prior: 1 on the paper's maze; 0 is the non-optimistic method).
    The "CI" is a random deviation, negative at some states: optimism comes from acting greedily on a
    plausible reward function, not from a bonus.

    When a new draw is made: FQI must see one reward function per fit, and each fit a draw from the
    posterior of its own moment. ``snapshot()`` (which a ``TaskLearner`` takes right after each refit)
    spends the current draw; the first R~ asked for after the head has received a new sample is then a new
    draw from the posterior as of that moment (a ``TaskLearner`` asks at its next refit). Reads in between
    (a picture of the refit just made) see the draw the fit used. ``resample()`` asks for a new draw at the
    next read, for users that do not snapshot (e.g. a relabelling buffer). The generator's state is part of
    the head: a pickled or deep-copied head draws what the original would.

    The uncertainty, the refit rule and the tracker are those of ``RidgePosteriorRewardHead``.

    With ``kappa_scale="observed"`` the posterior scale is kappa times the largest absolute reward the head
    has seen (kappa alone before any nonzero reward), so that the env's rewards multiplied by a constant c
    give draws multiplied by c, and the same greedy policy (a Q-function fitted on c R~ is c times the one
    fitted on R~); before the first reward R~ = Phi . w~ is v times a draw of scale 1, whatever v.

    :param features: Phi, states (n, d) -> (n, k) (picklable, no lambda)
    :param kappa: the posterior scale v, >= 0, in the units ``kappa_scale`` says
    :param ridge: Tikhonov regularisation lambda, > 0
    :param seed: seed of the head's generator of draws (an int >= 0, or None for fresh entropy); every
        deep copy of a head starts from the same state, so copies for several tasks draw the same normals
    :param r_max: optional cap on R~
    :param kappa_scale: one of ``KAPPA_SCALES``: ``"reward"`` (kappa in the env's reward units) or
        ``"observed"`` (in units of the largest absolute reward seen)
    """

    def __init__(
        self,
        features: StatesFn,
        kappa: float = 0.1,
        ridge: float = 1.0,
        seed: int | None = None,
        r_max: float | None = None,
        kappa_scale: str = "reward",
    ):
        super().__init__(features, kappa=kappa, ridge=ridge, r_max=r_max)
        if seed is not None and not (isinstance(seed, (int, np.integer)) and seed >= 0):
            raise ValueError(f"seed must be an integer >= 0 or None (fresh entropy), got {seed!r}")
        if kappa_scale not in KAPPA_SCALES:
            raise ValueError(f"kappa_scale must be one of {list(KAPPA_SCALES)}, got {kappa_scale!r}")
        self.kappa_scale = kappa_scale
        self.largest_reward = 0.0  # the largest absolute reward among the head's samples
        self.seed = None if seed is None else int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._sampled_weights: np.ndarray | None = None  # w~ of the current draw, (k,)
        # A new draw is due at the first read once n_samples exceeds this; None: keep the current draw.
        self._redraw_after: int | None = None

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"seed={self.seed}", f"kappa_scale={self.kappa_scale!r}"]

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        super()._update(states, rewards)
        if len(rewards):
            self.largest_reward = max(self.largest_reward, float(np.abs(rewards).max()))

    @property
    def posterior_scale(self) -> float:
        """v: kappa, times the largest absolute reward seen under ``kappa_scale="observed"`` (once > 0)."""
        if self.kappa_scale == "observed" and self.largest_reward > 0:
            return self.kappa * self.largest_reward
        return self.kappa

    def resample(self) -> None:
        """Spend the current draw: the next R~ asked for is a new draw from the posterior as of then."""
        self._redraw_after = -1

    def sampled_weights(self, n_features: int) -> np.ndarray:
        """
        The current draw w~, drawn now if due (see the class docstring).

        :param n_features: k, the width of Phi (needed before the first sample, when A = lambda I)
        :return: (k,)
        """
        redraw_due = self._redraw_after is not None and self.n_samples > self._redraw_after
        if self._sampled_weights is None or redraw_due:
            weights = self.weights
            mean = np.zeros(n_features) if weights is None else weights
            gram = self.ridge * np.eye(n_features) if self._gram is None else self._gram
            self._sampled_weights = sample_posterior_weights(self._rng, mean, gram, self.posterior_scale)[0]
            self._redraw_after = None
        assert len(self._sampled_weights) == n_features
        return self._sampled_weights

    def bonus_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        CI = Phi(s) . (w~ - w_hat), so that R^ + CI = Phi(s) . w~.

        :param phi: Phi(s), (n, k)
        :return: (n,)
        """
        if self.kappa == 0:
            return np.zeros(len(phi))
        deviation = self.sampled_weights(phi.shape[1])
        weights = self.weights
        return phi @ (deviation if weights is None else deviation - weights)

    def optimistic_from_features(self, phi: np.ndarray) -> np.ndarray:
        """
        R~ = Phi(s) . w~, capped at ``r_max``: computed from w~ alone, so that it stays the same to the bit
        while w_hat moves between two refits.

        :param phi: Phi(s), (n, k)
        :return: (n,)
        """
        if self.kappa == 0:
            return self.clip_optimistic(self.estimate_from_features(phi))
        return self.clip_optimistic(phi @ self.sampled_weights(phi.shape[1]))

    def snapshot(self) -> PosteriorSnapshot:
        # The refit moment: the draw the fit used is spent once a new sample arrives.
        self._redraw_after = self.n_samples
        return super().snapshot()
