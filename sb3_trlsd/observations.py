"""What TRLSD reads from an observation: a state vector, and the task it belongs to.

An env with one task observes its state as a Box; a multi-task env as a ``{"state": Box, "task":
Discrete}`` Dict. Everything that unpacks an observation goes through ``split_observation``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

__all__ = ["split_observation", "state_space_of", "task_count_of"]


def state_space_of(observation_space: spaces.Space) -> spaces.Box:
    """
    The Box holding the state: the observation space itself, or its ``"state"`` entry for the
    ``{"state", "task"}`` Dict observations of multi-task envs.

    :raises ValueError: for any other observation space
    """
    if isinstance(observation_space, spaces.Dict) and isinstance(
        observation_space.spaces.get("state"), spaces.Box
    ):
        state_space = observation_space["state"]
        task_space = observation_space.spaces.get("task")
        if not isinstance(task_space, spaces.Discrete) or len(observation_space.spaces) != 2:
            raise ValueError(
                "observation_space must be a Box or a Dict with exactly a 'state' Box and a 'task' Discrete, "
                f"got {observation_space}"
            )
    elif isinstance(observation_space, spaces.Box):
        state_space = observation_space
    else:
        raise ValueError(
            "observation_space must be a Box or a Dict with a 'state' Box and a 'task' Discrete, "
            f"got {observation_space}"
        )
    assert isinstance(state_space, spaces.Box)
    if len(state_space.shape) != 1:
        raise ValueError(f"the state Box must be one-dimensional (a vector), got shape {state_space.shape}")
    return state_space


def task_count_of(observation_space: spaces.Space) -> int:
    """The number of tasks: the ``"task"`` Discrete's size, 1 for a plain Box observation."""
    state_space_of(observation_space)
    if isinstance(observation_space, spaces.Dict):
        return int(observation_space["task"].n)
    return 1


def split_observation(obs: Any, state_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """
    The states and tasks of an observation, single or batched, as numpy arrays (torch tensors accepted).

    :param obs: a Box observation (d,) or (n, d), or a ``{"state", "task"}`` Dict of them
    :param state_dim: d
    :return: states (n, d) float64 and tasks (n,) int64 (all 0 for a Box observation)
    """
    if isinstance(obs, dict):
        states = _as_array(obs["state"]).reshape(-1, state_dim)
        tasks = _as_array(obs["task"]).reshape(-1)
        if len(tasks) == 1 and len(states) > 1:  # one task for a batch of states
            tasks = np.repeat(tasks, len(states))
    else:
        states = _as_array(obs).reshape(-1, state_dim)
        tasks = np.zeros(len(states), dtype=np.int64)
    if len(tasks) != len(states):
        raise ValueError(f"an observation has {len(states)} states but {len(tasks)} tasks")
    if np.any(tasks != np.round(tasks)):
        raise ValueError(f"tasks must be integers, got {tasks}")
    return states.astype(np.float64), tasks.astype(np.int64)


def _as_array(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()
    return np.asarray(value)
