"""The envs of a batch of runs, stepped together (the ``EnvBatch`` of ``lockstep``).

``env_batch`` picks how: mazes with only pass-through wrappers around them move as one vectorised call
(``sb3_trlsd_envs.maze.step_mazes``), each drawing what it draws alone, their time limits counted
here; any other env is stepped one by one through its wrappers.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit

from sb3_trlsd.observations import split_observation, state_space_of
from sb3_trlsd_envs.maze import SharedDynamicsMaze, step_mazes

__all__ = ["GymEnvBatch", "MazeBatch", "env_batch"]

# Wrappers that change nothing a maze's step returns but the end of a trajectory (TimeLimit, counted here).
PASS_THROUGH = (TimeLimit, OrderEnforcing, PassiveEnvChecker)


class GymEnvBatch:
    """
    Any envs, stepped one after the other through their wrappers.

    :param envs: one env per run, of one observation space (a state Box or a ``{"state", "task"}`` Dict)
    """

    def __init__(self, envs: Sequence[gym.Env]):
        self.envs = list(envs)
        self.state_dim = state_space_of(self.envs[0].observation_space).shape[0]

    def _split(self, observations: list) -> tuple[np.ndarray, np.ndarray]:
        pairs = [split_observation(obs, self.state_dim) for obs in observations]
        states = np.array([state[0] for state, _ in pairs], dtype=np.float32).reshape(-1, self.state_dim)
        return states, np.array([task[0] for _, task in pairs], dtype=np.int64)

    def reset(
        self, runs: Sequence[int] | np.ndarray, seeds: Sequence[int | None]
    ) -> tuple[np.ndarray, np.ndarray]:
        return self._split(
            [self.envs[run].reset(seed=seed)[0] for run, seed in zip(runs, seeds, strict=True)]
        )

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        steps = [env.step(int(action)) for env, action in zip(self.envs, actions, strict=True)]
        states, _ = self._split([step[0] for step in steps])
        rewards = np.array([step[1] for step in steps], dtype=np.float64)
        terminated = np.array([step[2] for step in steps], dtype=bool)
        return states, rewards, terminated, np.array([step[3] for step in steps], dtype=bool)


class MazeBatch(GymEnvBatch):
    """
    Mazes moved as one vectorised step; resets go through each env's wrappers (its round robin, its seed).

    :param envs: one maze per run (``gym.make`` of the maze id, or the env itself), of one dynamics
    """

    def __init__(self, envs: Sequence[gym.Env]):
        super().__init__(envs)
        self.mazes: list[SharedDynamicsMaze] = []
        for env in self.envs:
            assert isinstance(env.unwrapped, SharedDynamicsMaze), "env_batch gives mazes alone to MazeBatch"
            self.mazes.append(env.unwrapped)
        limits = [_time_limit(env) for env in self.envs]
        self.max_episode_steps = np.array([np.inf if limit is None else limit for limit in limits])
        self.elapsed = np.zeros(len(self.envs), dtype=np.int64)

    def reset(
        self, runs: Sequence[int] | np.ndarray, seeds: Sequence[int | None]
    ) -> tuple[np.ndarray, np.ndarray]:
        self.elapsed[np.asarray(runs, dtype=np.int64)] = 0
        return super().reset(runs, seeds)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        moved = step_mazes(self.mazes, np.asarray(actions, dtype=np.int64))
        self.elapsed += 1
        truncated = moved.truncated | (self.elapsed >= self.max_episode_steps)
        # The maze observes its state in float32; its steps never terminate.
        return (
            moved.states.astype(np.float32),
            moved.rewards,
            np.zeros(len(self.mazes), dtype=bool),
            truncated,
        )


def _time_limit(env: gym.Env) -> int | None:
    """The ``TimeLimit`` of a chain of pass-through wrappers (None: none)."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, TimeLimit):
            return env._max_episode_steps
        env = env.env
    return None


def _is_plain_maze(env: gym.Env) -> bool:
    while isinstance(env, gym.Wrapper):
        if not isinstance(env, PASS_THROUGH):
            return False
        env = env.env
    return type(env) is SharedDynamicsMaze


def env_batch(envs: Sequence[gym.Env]) -> GymEnvBatch:
    """The envs of a batch: a ``MazeBatch`` for mazes with only ``PASS_THROUGH`` wrappers, else one by one."""
    if all(_is_plain_maze(env) for env in envs):
        return MazeBatch(envs)
    return GymEnvBatch(envs)
