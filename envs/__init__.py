"""Gymnasium environments of sb3-trlsd. Importing this package registers them (Gymnasium 1.x has no
plugin entry points)."""

from gymnasium.envs.registration import register, registry

from sb3_trlsd_envs.dynamics import (
    DEFAULT_WALLS,
    EAST,
    NORTH,
    SOUTH,
    WEST,
    cell_of,
    make_walls,
    maze_step,
    segment_crosses_walls,
)
from sb3_trlsd_envs.maze import (
    CORNER_TASKS,
    N_TASKS,
    SharedDynamicsMaze,
    expected_reward,
    task_cell,
    task_index,
)
from sb3_trlsd_envs.rendering import draw_maze, render_maze, save_maze_png

__all__ = [
    "CORNER_TASKS",
    "DEFAULT_WALLS",
    "EAST",
    "MAZE_ID",
    "NORTH",
    "N_TASKS",
    "SOUTH",
    "WEST",
    "SharedDynamicsMaze",
    "cell_of",
    "draw_maze",
    "expected_reward",
    "make_walls",
    "maze_step",
    "render_maze",
    "save_maze_png",
    "segment_crosses_walls",
    "task_cell",
    "task_index",
]

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"

# Registering an id twice makes Gymnasium warn; the module cache usually prevents it, this guard covers
# reloads and a registration made elsewhere first.
if MAZE_ID not in registry:
    register(id=MAZE_ID, entry_point="sb3_trlsd_envs.maze:SharedDynamicsMaze")
