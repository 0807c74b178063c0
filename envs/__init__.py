"""Gymnasium environments of sb3-trlsd. Importing this package registers them (Gymnasium 1.x has no
plugin entry points)."""

from gymnasium.envs.registration import register, registry

from envs.maze import CORNER_TASKS, N_TASKS, SharedDynamicsMaze, expected_reward, task_cell, task_index

__all__ = [
    "CORNER_TASKS",
    "MAZE_ID",
    "N_TASKS",
    "SharedDynamicsMaze",
    "expected_reward",
    "task_cell",
    "task_index",
]

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"

if MAZE_ID not in registry:
    register(id=MAZE_ID, entry_point="envs.maze:SharedDynamicsMaze")
