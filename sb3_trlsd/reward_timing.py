"""What of a transition (s, a, s') its reward belongs to, and what a reward head therefore learns from.

The paper's reward R_tau(s) belongs to the state a step starts from; Gymnasium's envs pay for a step, most
often for where it led, and some for the step itself (a reward paid the first time a state is reached, as
in MO-Gymnasium's four-room, is neither a function of s nor of s'). A reward head sees one vector per
transition, its input: the start state s (d,), the next state s' (d,), or both side by side [s, s'] (2d,),
whose features are those of each state side by side (``TransitionFeatures``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sb3_trlsd.feature_maps import FeatureMap

__all__ = ["REWARD_TIMINGS", "TransitionFeatures", "input_box", "rewarded_inputs"]

# The start state (the paper's R_tau(s), and this package's own envs), the state it arrives at (a goal paid
# on arrival), or the transition (s, s') (a reward paid for a change of state).
REWARD_TIMINGS = ("start_state", "next_state", "transition")


def rewarded_inputs(states: np.ndarray, next_states: np.ndarray, timing: str) -> np.ndarray:
    """
    The inputs of a reward head for transitions from ``states`` to ``next_states``.

    :param states: start states (n, d)
    :param next_states: next states (n, d)
    :param timing: one of ``REWARD_TIMINGS``
    :return: (n, d) for ``"start_state"`` and ``"next_state"``, (n, 2d) rows [s, s'] for ``"transition"``
    """
    if timing == "start_state":
        return states
    if timing == "next_state":
        return next_states
    if timing == "transition":
        return np.concatenate([states, next_states], axis=-1)
    raise ValueError(f"reward_timing must be one of {list(REWARD_TIMINGS)}, got {timing!r}")


def input_box(low: np.ndarray, high: np.ndarray, timing: str) -> tuple[np.ndarray, np.ndarray]:
    """
    The box of a reward head's inputs, given the state box [low, high]: itself, or twice side by side for
    ``"transition"``.
    """
    if timing == "transition":
        return np.concatenate([low, low]), np.concatenate([high, high])
    return low, high


@dataclass(frozen=True)
class TransitionFeatures(FeatureMap):
    """
    Phi of transitions given as rows [s, s'] (n, 2d): [Phi(s), Phi(s')] (n, 2k). A linear function of them
    is g(s') - h(s) among others: a reward for reaching s' from outside a region, for leaving one, or for a
    flag that flips.

    :param state_features: Phi of one state, (n, d) -> (n, k)
    """

    state_features: FeatureMap
    low: tuple[float, ...] = field(init=False)
    high: tuple[float, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "low", tuple(self.state_features.low) * 2)
        object.__setattr__(self, "high", tuple(self.state_features.high) * 2)

    @property
    def n_features(self) -> int:
        """2k."""
        return 2 * self.state_features.n_features

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        :param states: rows [s, s'] (n, 2d)
        :return: [Phi(s), Phi(s')], (n, 2k)
        """
        pairs = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        half = len(self.state_features.low)
        return np.concatenate([self.state_features(pairs[:, :half]), self.state_features(pairs[:, half:])], 1)
