"""How TRLSD chooses an action from Q-values while learning: the greedy action (eq. 3), a tie among equal
Q-values taken at random or the first, and epsilon-greedy over a task's first online steps (none in the
paper). The settings name the rules (``TIE_BREAKS``, ``Exploration``); the engine applies them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["TIE_BREAKS", "Exploration", "explore_rng", "greedy_actions", "tie_rng"]

# How the greedy action of equal Q-values is taken while learning: the first such action, or one of them at
# random (a Q that is 0 everywhere, before any reward was seen with kappa = 0, then acts at random instead of
# repeating action 0).
TIE_BREAKS = ("random", "first")


def _run_rng(seed: int | None, stream: int) -> np.random.Generator:
    """A generator of its own for each ``stream`` of a run, derived from the run's seed (or fresh entropy)."""
    if seed is None:
        return np.random.default_rng()
    return np.random.default_rng(np.random.SeedSequence([int(seed) % 2**64, stream]))


def tie_rng(seed: int | None) -> np.random.Generator:
    """
    The generator of a run's random tie-breaks, derived from the run's seed (fresh entropy without one).

    :param seed: the run's seed (a model's ``seed``)
    """
    return _run_rng(seed, 5)


def explore_rng(seed: int | None) -> np.random.Generator:
    """
    The generator of a run's exploratory actions, derived from the run's seed (fresh entropy without one).

    :param seed: the run's seed (a model's ``seed``)
    """
    return _run_rng(seed, 7)


@dataclass(frozen=True)
class Exploration:
    """
    Epsilon-greedy behaviour while learning, per task: over a task's first ``steps`` online samples the
    rate falls linearly from ``initial_eps`` to ``final_eps``, and stays at ``final_eps`` after; a step
    takes a uniformly random action with that probability, else the greedy one.

    :param initial_eps: the rate at a task's first online step, in [0, 1]
    :param final_eps: the rate from its ``steps``-th on, in [0, 1]
    :param steps: the online samples of a task over which the rate falls (0: ``final_eps`` from the start)
    """

    initial_eps: float = 0.0
    final_eps: float = 0.0
    steps: int = 0

    def rate(self, samples: int) -> float:
        """
        The exploration rate of a task with ``samples`` online samples so far.

        :param samples: the task's online samples (>= 0)
        """
        if samples >= self.steps:
            return self.final_eps
        return self.initial_eps + (self.final_eps - self.initial_eps) * samples / self.steps

    @property
    def explores(self) -> bool:
        """Whether any step may be exploratory."""
        return self.initial_eps > 0 or self.final_eps > 0


def greedy_actions(
    q_values: np.ndarray, rngs: Sequence[np.random.Generator | None] | None = None
) -> np.ndarray:
    """
    argmax_a Q(s, a) of each state (eq. 3), a tie taken at random with the state's generator (None: the
    first tied action). A draw is made for each state with a tie, in order, and for no other: the same
    states give the same draws whichever way they are batched.

    :param q_values: (n, n_actions)
    :param rngs: one generator (or None) per state; None: no random tie-break
    :return: actions (n,)
    """
    actions = q_values.argmax(axis=1)
    if rngs is None:
        return actions
    tied = q_values == q_values[np.arange(len(q_values)), actions][:, None]
    for i in np.flatnonzero(tied.sum(axis=1) > 1):
        rng = rngs[int(i)]
        if rng is not None:
            choices = np.flatnonzero(tied[i])
            actions[i] = choices[rng.integers(len(choices))]
    return actions
