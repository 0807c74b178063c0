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
from sb3_trlsd_envs.four_rooms import (
    FOUR_ROOMS_GOALS,
    FOUR_ROOMS_WALLS,
    FourRooms,
    four_rooms_step,
    goal_rewards,
    make_room_walls,
)
from sb3_trlsd_envs.goal_cartpole import (
    CARTPOLE_TARGETS,
    STATE_HIGH,
    VELOCITY_BOUNDS,
    GoalCartPole,
    cartpole_step,
    cartpole_terminal,
    target_rewards,
)
from sb3_trlsd_envs.maze import SharedDynamicsMaze
from sb3_trlsd_envs.maze_tasks import (
    CELL_NOISE_STDS,
    CORNER_TASKS,
    N_TASKS,
    expected_reward,
    task_cell,
    task_index,
)
from sb3_trlsd_envs.rendering import draw_maze, render_maze, save_maze_png

__all__ = [
    "CARTPOLE_TARGETS",
    "CELL_NOISE_STDS",
    "CORNER_TASKS",
    "DEFAULT_WALLS",
    "EAST",
    "FOUR_ROOMS_GOALS",
    "FOUR_ROOMS_ID",
    "FOUR_ROOMS_WALLS",
    "GOAL_CARTPOLE_ID",
    "MAZE_ID",
    "NORTH",
    "N_TASKS",
    "SOUTH",
    "STATE_HIGH",
    "VELOCITY_BOUNDS",
    "WEST",
    "FourRooms",
    "GoalCartPole",
    "SharedDynamicsMaze",
    "cartpole_step",
    "cartpole_terminal",
    "cell_of",
    "draw_maze",
    "expected_reward",
    "four_rooms_step",
    "goal_rewards",
    "make_room_walls",
    "make_walls",
    "maze_step",
    "render_maze",
    "save_maze_png",
    "segment_crosses_walls",
    "target_rewards",
    "task_cell",
    "task_index",
]

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"
FOUR_ROOMS_ID = "TRLSD/FourRooms-v0"
GOAL_CARTPOLE_ID = "TRLSD/GoalCartPole-v0"

# Registering an id twice makes Gymnasium warn; the module cache usually prevents it, this guard covers
# reloads and a registration made elsewhere first.
if MAZE_ID not in registry:
    register(id=MAZE_ID, entry_point="sb3_trlsd_envs.maze:SharedDynamicsMaze")
if FOUR_ROOMS_ID not in registry:
    register(id=FOUR_ROOMS_ID, entry_point="sb3_trlsd_envs.four_rooms:FourRooms")
if GOAL_CARTPOLE_ID not in registry:
    # CartPole-v0's time limit; the pole falling ends an episode earlier (terminated=True).
    register(
        id=GOAL_CARTPOLE_ID, entry_point="sb3_trlsd_envs.goal_cartpole:GoalCartPole", max_episode_steps=200
    )
