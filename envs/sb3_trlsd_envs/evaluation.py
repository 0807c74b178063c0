"""Evaluating by the expected (noise-free) reward: greedy policies on the maze, many runs at once, and the
envs of this package under their wrappers (``task_family_of``)."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from sb3_trlsd_envs.dynamics import DEFAULT_WALLS, make_walls, maze_step
from sb3_trlsd_envs.maze import SharedDynamicsMaze
from sb3_trlsd_envs.maze_tasks import expected_reward
from sb3_trlsd_envs.multitask import TaskFamilyEnv

__all__ = ["greedy_expected_rewards", "task_family_of"]

QFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


def greedy_expected_rewards(
    q_values: QFunction,
    tasks: np.ndarray,
    n_steps: int,
    rng: np.random.Generator,
    walls=DEFAULT_WALLS,
    termination_prob: float = 0.02,
) -> np.ndarray:
    """
    Follow the greedy policy of ``q_values`` on the maze in one run per entry of ``tasks`` and record the
    expected reward E[R_task(s_t)] of every visited state. Trajectories restart from a uniform state with
    probability ``termination_prob`` after each step, as in the paper's experiments.

    :param q_values: ``q_values(states (n, 2), tasks (n,)) -> (n, n_actions)``, e.g. ``policy.q_values``
    :param tasks: task index of each run, shape (n_runs,)
    :param n_steps: steps per run
    :param rng: random generator of the dynamics and resets
    :param walls: wall layout of the maze
    :param termination_prob: probability of a reset after each step
    :return: expected rewards, shape (n_runs, n_steps)
    """
    tasks = np.asarray(tasks, dtype=np.int64)
    wall_segments = make_walls(walls)
    states = rng.uniform(0.0, 5.0, size=(len(tasks), 2))
    rewards = np.empty((len(tasks), n_steps))
    for step in range(n_steps):
        for task in np.unique(tasks):
            rows = tasks == task
            rewards[rows, step] = expected_reward(states[rows], int(task))
        actions = q_values(states, tasks).argmax(axis=1)
        states = maze_step(states, actions, rng, wall_segments)
        reset = rng.random(len(tasks)) < termination_prob
        states[reset] = rng.uniform(0.0, 5.0, size=(int(reset.sum()), 2))
    return rewards


def task_family_of(env: gym.Env) -> SharedDynamicsMaze | TaskFamilyEnv:
    """
    The env of this package under ``env``'s wrappers: its ``task``, ``state`` and ``expected_reward``.

    :param env: the maze, the four rooms or the goal cart-pole, wrapped or not
    :return: ``env.unwrapped``
    :raises TypeError: for any other env
    """
    unwrapped = env.unwrapped
    if not isinstance(unwrapped, (SharedDynamicsMaze, TaskFamilyEnv)):
        raise TypeError(f"expected an env of sb3_trlsd_envs, got {type(unwrapped).__name__}")
    return unwrapped
