"""The optimistic reward proxy R~_tau = R^_tau + CI_tau of one task (paper, section 3, eq. 5): the base class.

Each head learns from the samples Xi_tau of its task (their start states and rewards, float64, states (n, d),
rewards (n,)) and answers, for any states: the estimate R^ (``estimate``), the kappa-free uncertainty
(``uncertainty``), the confidence interval CI = kappa * uncertainty (``bonus``) and R~ = R^ + CI capped at
``r_max`` if given (``optimistic``). ``tracker`` keeps R~ up to date on a fixed, growable set of states
(a replay buffer's start states), which is what relabelling the buffer asks for at every refit.
``snapshot`` records the uncertainty as of now as plain data and ``uncertainty_as_of`` evaluates it later:
the refit trigger of section 3 compares the two.

Edge cases, decided here so that R^, CI and R~ are never infinite or NaN for finite query states:

- W_tau(s) -> 0 far from every sample (exactly 0 once exp underflows, beyond ~39 sigma), and N_tau(s) = 0 in
  an unvisited cell: eq. 9 and 10 give an infinite CI. W and N are floored at ``w_floor`` (default 1e-6),
  so the bonus is at most kappa * sqrt(log|Xi_tau| / w_floor). The floor only bites where the state is
  practically unknown: with the paper's sigma = 0.2, W < 1e-6 means no sample within ~1.05 (5.3 sigma) of
  s, and N counts whole samples, so any N >= 1 is above it. There the bonus (~263 for kappa = 0.1 and
  1,000 samples) dwarfs any reward the maze gives, which is the "infinitely optimistic where never
  visited" behaviour of UCB the paper builds on, kept finite so that FQI stays numerically sane. Where an
  upper bound of the reward is known, ``r_max`` caps R~ instead.
- |Xi_tau| <= 1: log 1 = 0 would remove all optimism after the first sample and log 0 = -inf. The paper
  does not say what it did; a head's ``log_count_rule`` picks one of ``LOG_COUNT_RULES``:

  - ``"at_least_2"`` (the default): log(max(|Xi_tau|, 2)). Eq. 9 and 10 as written from two samples on, and
    log 2 before, so that the head is optimistic from its first fit (at a task's first step, with no
    sample) and stays so after its first sample. With no sample, R^ = 0 and the bonus is the floored
    maximum everywhere.
  - ``"plus_1"``: log(|Xi_tau| + 1), the smoothing UCB-style bounds often use (log(t + 1)): continuous in
    |Xi_tau|, log 2 at one sample as the default, but 0 with no sample, so a task's first fit at its first
    step sees no optimism at all (R~ = 0 everywhere).
  - ``"at_least_1"``: log(max(|Xi_tau|, 1)), eq. 9 and 10 taken literally with log 0 read as 0 (no count,
    no bonus): no optimism at all before the second sample.

  Under the last two the CI is 0 at a first fit; ``refit_due`` then refits once it is no longer 0 (a CI of 0
  cannot be "divided by 2", and the task would otherwise never be refitted).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from sb3_trlsd.arrays import GrowableArray

__all__ = [
    "DEFAULT_LOG_COUNT_RULE",
    "DEFAULT_W_FLOOR",
    "LOG_COUNT_RULES",
    "RewardHead",
    "RewardTracker",
    "check_log_count_rule",
    "check_positive",
    "confidence_width",
    "log_sample_count",
]

DEFAULT_W_FLOOR = 1e-6
# log|Xi_tau| at small counts (see the module docstring): rule -> the count whose log is taken.
LOG_COUNT_RULES = {
    "at_least_2": lambda n: max(n, 2),
    "plus_1": lambda n: n + 1,
    "at_least_1": lambda n: max(n, 1),
}
DEFAULT_LOG_COUNT_RULE = "at_least_2"


def log_sample_count(n_samples: int, rule: str = DEFAULT_LOG_COUNT_RULE) -> float:
    """
    log|Xi_tau| of eq. 9 and 10 under one of ``LOG_COUNT_RULES`` (see the module docstring).

    :param n_samples: |Xi_tau|
    :param rule: how small counts are taken (default: log(max(|Xi_tau|, 2)))
    :return: the log factor, >= 0
    """
    return float(np.log(LOG_COUNT_RULES[rule](n_samples)))


def check_log_count_rule(rule: str) -> str:
    """``rule`` if it is one of ``LOG_COUNT_RULES``; otherwise a ValueError naming ``log_count`` and them."""
    if rule not in LOG_COUNT_RULES:
        raise ValueError(f"log_count must be one of {list(LOG_COUNT_RULES)}, got {rule!r}")
    return rule


def confidence_width(log_count: float, weights: np.ndarray, w_floor: float) -> np.ndarray:
    """
    sqrt(log|Xi_tau| / W(s)): eq. 9 (W a neighbouring weight) or eq. 10 (W a count), without kappa.

    :param log_count: log|Xi_tau| (see ``log_sample_count``)
    :param weights: W_tau(s) or N_tau(s), (n,)
    :param w_floor: floor on the weights (> 0)
    :return: (n,)
    """
    return np.sqrt(log_count / np.maximum(weights, w_floor))


def check_positive(name: str, value: float, meaning: str) -> float:
    """``value`` as a float if it is > 0 (NaN is not); otherwise a ValueError naming ``name``."""
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

    has_uncertainty = True  # False for a head whose CI is 0 by construction (the known reward)
    # How log|Xi_tau| is taken at small counts; set through ``log_count_rule`` (heads saved before it existed
    # read this class default, the rule they were built with).
    _log_count_rule = DEFAULT_LOG_COUNT_RULE

    def __init__(self, kappa: float = 0.1, r_max: float | None = None):
        if not kappa >= 0 or not np.isfinite(kappa):
            raise ValueError(
                f"kappa must be a finite number >= 0 (0 is the non-optimistic method), got {kappa}"
            )
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

    @property
    def log_count_rule(self) -> str:
        """How log|Xi_tau| of eq. 9 and 10 is taken at small counts: one of ``LOG_COUNT_RULES``."""
        return self._log_count_rule

    @log_count_rule.setter
    def log_count_rule(self, rule: str) -> None:
        self._log_count_rule = check_log_count_rule(rule)

    def log_count(self, n_samples: int) -> float:
        """
        log|Xi_tau| under the head's ``log_count_rule``.

        :param n_samples: |Xi_tau|
        :return: the log factor of eq. 9 and 10
        """
        return log_sample_count(n_samples, self._log_count_rule)

    def check_samples(self, states: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Samples as float64 arrays if ``update`` would take them; otherwise a ValueError saying what is wrong.

        :param states: (n, d)
        :param rewards: (n,)
        :return: states and rewards, float64
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
        return states, rewards

    def update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """
        Add samples of the task, incrementally: start states of transitions and the rewards observed there.
        Bad samples raise a ValueError and leave the head unchanged.

        :param states: (n, d)
        :param rewards: (n,), finite
        """
        states, rewards = self.check_samples(states, rewards)
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

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        """
        The kappa-free confidence width sqrt(log|Xi_tau| / W_tau(s)) (eq. 9, 10 without kappa).

        :param states: (n, d)
        :return: (n,)
        """
        return self.uncertainty_as_of(self.snapshot(), states)

    def uncertainty_then_and_now(self, snapshot: Any, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        The uncertainty as of ``snapshot`` and as of now at the same states: what the refit trigger of
        section 3 compares. A head can compute both at once (the ridge head: one similarity per sample).

        :param snapshot: a value of ``snapshot()``
        :param states: (n, d)
        :return: then (n,), now (n,)
        """
        return self.uncertainty_as_of(snapshot, states), self.uncertainty(states)

    def refit_due(self, snapshot: Any, state: np.ndarray, update_ratio: float) -> bool:
        """
        The refit trigger of section 3: the kappa-free uncertainty at the encountered state has been divided
        by ``update_ratio`` since ``snapshot`` (the last refit). A head whose confidence set shrinks otherwise
        can bring its own rule (``RidgePosteriorRewardHead``: determinant doubling).

        :param snapshot: ``snapshot()`` at the last refit
        :param state: the state just encountered, (1, d)
        :param update_ratio: the factor (> 1)
        :return: whether the task is due for a refit
        """
        then, now = (value[0] for value in self.uncertainty_then_and_now(snapshot, state))
        if then == 0:
            # A CI of 0 cannot be divided: the refit saw no optimism here, and it is due once there is some
            # (a first fit with log|Xi_tau| = 0, see the module docstring; never under the default rule).
            return bool(now > 0)
        return bool(then >= update_ratio * now)

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
    def snapshot(self) -> Any:
        """
        What the uncertainty depends on, as of now, as plain data (an int or arrays, never a closure), so
        that ``uncertainty_as_of`` gives the uncertainty of this moment after later updates. Cheap: it does
        not copy the samples.
        """

    @abstractmethod
    def uncertainty_as_of(self, snapshot: Any, states: np.ndarray) -> np.ndarray:
        """
        The uncertainty the head had when ``snapshot`` was taken.

        :param snapshot: a value of ``snapshot()``
        :param states: (n, d)
        :return: (n,)
        """
