"""What of a transition (s, a, s') its reward belongs to, and what a reward head therefore learns from.

The paper's reward R_tau(s) belongs to the state a step starts from; Gymnasium's envs pay for a step
r(s, a, s'), most often for where it led, some for the step itself (a reward paid the first time a state is
reached, as in MO-Gymnasium's four-room, is neither a function of s nor of s'), and some for the action (a
fuel or thrust cost, as in MO-Gymnasium's minecart and mountain car). A reward head sees one vector per
transition, its input: the start state s (d,), the next state s' (d,), both side by side [s, s'] (2d,), or
the whole step [s, a, s'] (2d + 1,), the action as its index. The features of a pair are those of each state
side by side, and those of a step put the action's one-hot code between them (``TransitionFeatures``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sb3_trlsd.feature_maps import FeatureMap

__all__ = [
    "ACTION_WIDTH",
    "REWARD_TIMINGS",
    "TransitionFeatures",
    "input_box",
    "input_widths",
    "rewarded_inputs",
    "staying_inputs",
]

# The start state (the paper's R_tau(s), and this package's own envs), the state it arrives at (a goal paid
# on arrival), the transition (s, s') (a reward paid for a change of state), or the step (s, a, s') (a reward
# that also depends on the action taken: a cost per action).
REWARD_TIMINGS = ("start_state", "next_state", "transition", "step")

# The similarity's width along the action index of a step: two different actions are 1 apart, so their
# similarity is exp(-1 / (2 * 0.25^2)) = 3e-4: a reward learnt for one action says next to nothing of another.
ACTION_WIDTH = 0.25


def rewarded_inputs(
    states: np.ndarray, actions: np.ndarray, next_states: np.ndarray, timing: str
) -> np.ndarray:
    """
    The inputs of a reward head for transitions from ``states`` to ``next_states`` by ``actions``.

    :param states: start states (n, d)
    :param actions: action indices (n,)
    :param next_states: next states (n, d)
    :param timing: one of ``REWARD_TIMINGS``
    :return: (n, d) for ``"start_state"`` and ``"next_state"``, (n, 2d) rows [s, s'] for ``"transition"``,
        (n, 2d + 1) rows [s, a, s'] for ``"step"``
    """
    if timing == "start_state":
        return states
    if timing == "next_state":
        return next_states
    if timing == "transition":
        return np.concatenate([states, next_states], axis=-1)
    if timing == "step":
        column = np.asarray(actions, dtype=np.float64).reshape(-1, 1)
        return np.concatenate([np.asarray(states, dtype=np.float64), column, next_states], axis=-1)
    raise ValueError(f"reward_timing must be one of {list(REWARD_TIMINGS)}, got {timing!r}")


def staying_inputs(states: np.ndarray, timing: str, n_actions: int) -> list[np.ndarray]:
    """
    The inputs of staying at each state, a picture of a head: one array, or one per action for ``"step"``
    (whose picture is then their mean).

    :param states: states (n, d)
    :param timing: one of ``REWARD_TIMINGS``
    :param n_actions: the env's actions
    :return: arrays of inputs (n, ...), one per action the reward depends on
    """
    actions = range(n_actions) if timing == "step" else range(1)
    return [rewarded_inputs(states, np.full(len(states), a), states, timing) for a in actions]


def input_box(
    low: np.ndarray, high: np.ndarray, timing: str, n_actions: int
) -> tuple[np.ndarray, np.ndarray]:
    """
    The box of a reward head's inputs, given the state box [low, high] and the env's actions: itself, twice
    side by side for ``"transition"``, and with the action indices [0, n_actions - 1] between for ``"step"``.
    """
    if timing == "transition":
        return np.concatenate([low, low]), np.concatenate([high, high])
    if timing == "step":
        top = max(n_actions - 1, 1)  # a box of one action still has low < high
        return np.concatenate([low, [0.0], low]), np.concatenate([high, [float(top)], high])
    return low, high


def input_widths(widths: np.ndarray, timing: str) -> np.ndarray:
    """
    The similarity's widths along a head's inputs, given those along a state (d,): themselves, twice for
    ``"transition"``, and ``ACTION_WIDTH`` along the action index between them for ``"step"``.
    """
    if timing == "transition":
        return np.concatenate([widths, widths])
    if timing == "step":
        return np.concatenate([widths, [ACTION_WIDTH], widths])
    return widths


@dataclass(frozen=True)
class TransitionFeatures(FeatureMap):
    """
    Phi of transitions: of rows [s, s'] (n, 2d), [Phi(s), Phi(s')] (n, 2k); of rows [s, a, s'] (n, 2d + 1)
    when ``n_actions`` is given, [Phi(s), e_a, Phi(s')] (n, 2k + n_actions), e_a the action's one-hot code. A
    linear function of them is g(s') - h(s) + c_a among others: a reward for reaching s' from outside a
    region, for leaving one, for a flag that flips, and a cost per action.

    :param state_features: Phi of one state, (n, d) -> (n, k)
    :param n_actions: the actions of rows [s, a, s'] (0: rows [s, s'])
    """

    state_features: FeatureMap
    n_actions: int = 0
    low: tuple[float, ...] = field(init=False)
    high: tuple[float, ...] = field(init=False)

    def __post_init__(self) -> None:
        low, high = np.asarray(self.state_features.low), np.asarray(self.state_features.high)
        timing = "step" if self.n_actions else "transition"
        low, high = input_box(low, high, timing, self.n_actions)
        object.__setattr__(self, "low", tuple(float(v) for v in low))
        object.__setattr__(self, "high", tuple(float(v) for v in high))

    @property
    def n_features(self) -> int:
        """2k, or 2k + n_actions."""
        return 2 * self.state_features.n_features + self.n_actions

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        :param states: rows [s, s'] (n, 2d), or [s, a, s'] (n, 2d + 1) when ``n_actions`` is given
        :return: [Phi(s), Phi(s')] (n, 2k), or [Phi(s), e_a, Phi(s')] (n, 2k + n_actions)
        """
        rows = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        half = len(self.state_features.low)
        parts = [self.state_features(rows[:, :half])]
        if self.n_actions:
            actions = np.clip(np.rint(rows[:, half]).astype(np.int64), 0, self.n_actions - 1)
            parts.append(np.eye(self.n_actions)[actions])
        parts.append(self.state_features(rows[:, -half:]))
        return np.concatenate(parts, 1)
