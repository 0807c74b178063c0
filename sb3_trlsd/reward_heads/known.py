"""The reward is known (the paper's first experiment): R^ = R_tau and CI = 0, so R~ = R_tau."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from sb3_trlsd.reward_heads.base import RewardHead

__all__ = ["EnvAttributes", "KnownRewardHead", "RewardFn", "env_reward_fn"]

# reward_fn(states (n, d), task) -> the expected reward E[R_task(s)] of each state, (n,), finite.
RewardFn = Callable[[np.ndarray, int], np.ndarray]
EXPECTED_REWARD = "expected_reward"  # the env method the known head reads by default


class EnvAttributes(Protocol):
    """What a known head reads of an env (SB3's ``VecEnv`` has it): its unwrapped env's attributes."""

    def has_attr(self, attr_name: str) -> bool: ...

    def get_attr(self, attr_name: str, indices: int | Sequence[int] | None = None) -> list[Any]: ...


def env_reward_fn(env: EnvAttributes | None, several_tasks: bool) -> RewardFn | None:
    """
    The env's own expected reward as a ``RewardFn``: its unwrapped env's ``expected_reward(states, task)``, or
    for an env of one task (a state Box), ``expected_reward(states)``.

    :param env: the (vectorised) env, or None
    :param several_tasks: whether its observations carry a task (a ``{"state", "task"}`` Dict)
    :return: the function, or None when the env has none
    """
    if env is None or not env.has_attr(EXPECTED_REWARD):
        return None
    method = env.get_attr(EXPECTED_REWARD, indices=0)[0]
    return method if several_tasks else _OneTaskReward(method)


class _OneTaskReward:
    """An env of one task's ``expected_reward(states)`` seen as ``reward_fn(states, task)``."""

    def __init__(self, expected_reward: Callable[[np.ndarray], np.ndarray]):
        self.expected_reward = expected_reward

    def __call__(self, states: np.ndarray, task: int) -> np.ndarray:
        return self.expected_reward(states)


class KnownRewardHead(RewardHead):
    """
    The reward is known: R^ = R_tau, given by ``reward_fn(states, task)``, and CI = 0.

    The function is not saved with the head (it is often a method of an env, which would be pickled with
    it): after unpickling, ``reward_fn`` is None until ``bind`` gives it again (``TRLSD.load`` does, from
    its ``reward_fn`` or the env's ``expected_reward``).

    :param reward_fn: ``reward_fn(states (n, d), task) -> (n,)``, the noise-free expected reward, finite
    :param task: the task passed to ``reward_fn``
    """

    has_uncertainty = False

    def __init__(self, reward_fn: RewardFn | None, task: int = 0):
        super().__init__(kappa=0.0)
        self.task = int(task)
        self.reward_fn: RewardFn | None = None
        if reward_fn is not None:
            self.bind(reward_fn)

    def __repr__(self) -> str:
        return f"KnownRewardHead(task={self.task}, n_samples={self.n_samples})"

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["reward_fn"] = None
        return state

    def bind(self, reward_fn: RewardFn) -> None:
        """
        Give the head its reward function (again, after loading).

        :param reward_fn: ``reward_fn(states, task) -> (n,)``
        """
        if not callable(reward_fn):
            raise ValueError(
                f"reward_fn must be a function reward_fn(states, task) -> (n,), got {reward_fn!r}"
            )
        self.reward_fn = reward_fn

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        """Nothing to learn: only the sample count moves."""

    def estimate(self, states: np.ndarray) -> np.ndarray:
        if self.reward_fn is None:
            raise ValueError(
                "the 'known' reward head has no reward_fn: pass reward_fn= to TRLSD (or to TRLSD.load), "
                "or use an env whose unwrapped object has expected_reward(states, task)"
            )
        states = np.asarray(states, dtype=np.float64)
        rewards = np.asarray(self.reward_fn(states, self.task), dtype=np.float64)
        if rewards.shape != (len(states),) or not np.all(np.isfinite(rewards)):
            raise ValueError(
                f"reward_fn(states, task={self.task}) must return {len(states)} finite rewards, shape "
                f"({len(states)},), one per state; got shape {rewards.shape}"
                + ("" if rewards.shape != (len(states),) else " with NaN or inf")
            )
        return rewards

    def snapshot(self) -> None:
        return None

    def uncertainty_as_of(self, snapshot: None, states: np.ndarray) -> np.ndarray:
        return np.zeros(len(states))
