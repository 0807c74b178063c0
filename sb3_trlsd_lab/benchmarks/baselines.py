"""
What the benchmark measures TRLSD against: SB3's DQN, from scratch or with the source transitions in its
replay buffer (their rewards zeroed, as a user without a reward model would have them), and a uniformly
random policy. Each is measured as TRLSD is in ``run_online``: the noise-free expected reward
E[R_task(s_t)] of the state each online step starts from.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import DictReplayBuffer

from sb3_trlsd.data import Transitions
from sb3_trlsd_envs.evaluation import task_family_of

__all__ = ["DQN_SETTINGS", "ExpectedRewards", "dqn_rewards", "fill_replay_buffer", "random_rewards"]

# One setting for every family, for a budget of 1,000-2,000 online steps (SB3's defaults are for 10^5-10^7).
DQN_SETTINGS: dict[str, Any] = {
    "learning_rate": 1e-3,  # SB3's 1e-4 barely moves a 64x64 MLP in 2,000 gradient steps
    "buffer_size": 50_000,  # the 25,000 source transitions and every online one, none overwritten
    "learning_starts": 100,  # a first batch of random actions, then a gradient step per env step
    "batch_size": 64,
    "gamma": 0.9,  # TRLSD's default: both methods optimise the same discounted return
    "train_freq": 1,
    "gradient_steps": 1,
    "target_update_interval": 250,  # 4-8 target updates over the budget (SB3's 10,000 would give none)
    "exploration_fraction": 0.5,  # epsilon from 1 to its floor over the first half of the budget
    "exploration_final_eps": 0.05,
}


class ExpectedRewards(gym.Wrapper):
    """
    Records E[R_task(s_t)] of the state s_t each step starts from, before the step: the measure of every
    method of the benchmark, taken inside whatever loop drives the env (DQN's ``learn``, a random policy).

    :param env: an env of a task family (``env.unwrapped.state`` and ``expected_reward(states)``)
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.expected: list[float] = []

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Record the expected reward of the current state, then step."""
        family = task_family_of(self.env)
        self.expected.append(float(family.expected_reward(np.asarray(family.state)[None])[0]))
        return self.env.step(action)


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """Torch on one thread within the block: a small MLP gains nothing from more, the other runs lose."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def fill_replay_buffer(model: DQN, source: Transitions, task: int) -> None:
    """
    Add ``source`` to ``model``'s replay buffer as transitions of ``task`` with reward 0: what DQN can make
    of another task's transitions without a reward model. A truncation is stored as SB3 stores a time
    limit (``done`` with ``TimeLimit.truncated``: DQN bootstraps through it), a termination as absorbing.

    :param model: a DQN on ``{"state", "task"}`` Dict observations
    :param source: the transitions (their rewards and tasks are ignored)
    :param task: the task index written in the observations
    """
    buffer = model.replay_buffer
    assert isinstance(buffer, DictReplayBuffer), "a DQN on Dict observations has SB3's DictReplayBuffer"
    task_column = np.array([task])
    for row in range(len(source.actions)):
        terminated, truncated = bool(source.terminations[row]), bool(source.truncations[row])
        buffer.add(
            {"state": source.states[row : row + 1], "task": task_column},
            {"state": source.next_states[row : row + 1], "task": task_column},
            source.actions[row : row + 1],
            np.zeros(1),
            np.array([terminated or truncated]),
            [{"TimeLimit.truncated": truncated and not terminated}],
        )


def dqn_rewards(
    env: ExpectedRewards, seed: int, n_steps: int, source: Transitions | None = None
) -> tuple[np.ndarray, int]:
    """
    ``DQN("MultiInputPolicy", env, **DQN_SETTINGS)`` learning online for ``n_steps`` transitions.

    :param env: the target task's env, wrapped to record the measure
    :param seed: the model's seed (SB3 seeds the env's first reset and the exploration with it)
    :param n_steps: online transitions
    :param source: transitions put in the replay buffer before learning, rewards zeroed (None: none)
    :return: the expected reward of each online step's state, (n_steps,), and DQN's gradient steps
    """
    with one_torch_thread():
        model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **DQN_SETTINGS)
        if source is not None:
            fill_replay_buffer(model, source, int(task_family_of(env).task))
        model.learn(total_timesteps=n_steps)
    return np.array(env.expected[:n_steps]), model._n_updates


def random_rewards(env: ExpectedRewards, seed: int, n_steps: int) -> np.ndarray:
    """
    A uniformly random policy for ``n_steps`` transitions, reset with ``seed``.

    :return: the expected reward of each step's state, (n_steps,)
    """
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(n_steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    return np.array(env.expected)
