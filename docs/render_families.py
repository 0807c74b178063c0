"""Draw the pictures of the README's family sections: docs/four_rooms.png and docs/goal_cartpole.png.

Run from the repository's root: ``python docs/render_families.py`` (seed 0, a few seconds).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sb3_trlsd_envs import FOUR_ROOMS_ID, GOAL_CARTPOLE_ID
from sb3_trlsd_envs.family_rendering import draw_cartpole, draw_four_rooms

DOCS = Path(__file__).resolve().parent
SEED = 0


def random_states(env: gym.Env, n_steps: int, seed: int) -> np.ndarray:
    """The states of one random trajectory of at most ``n_steps`` steps, the start included."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    states = [env.unwrapped.state.copy()]
    for _ in range(n_steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        states.append(env.unwrapped.state.copy())
        if terminated or truncated:
            break
    return np.array(states)


def four_rooms_picture(path: Path) -> None:
    """The rooms, the 16 goals with their task indices (task 15's filled), a random trajectory of 40 steps."""
    env = gym.make(FOUR_ROOMS_ID, task=15, termination_prob=0.0)
    path_states = random_states(env, 40, SEED)
    rooms = env.unwrapped
    figure = Figure(figsize=(4.5, 4.8), dpi=100)
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    draw_four_rooms(
        ax, rooms.walls, rooms.goals, rooms.goal_radius, target=15, trajectory=path_states, label_goals=True
    )
    ax.set_title(f"{FOUR_ROOMS_ID}: task 15, 40 random steps")
    figure.savefig(path, bbox_inches="tight")


def goal_cartpole_picture(path: Path) -> None:
    """A random episode of task 3 (its poles, the last in brown) and the reward of every task along x."""
    env = gym.make(GOAL_CARTPOLE_ID, task=3)
    states = random_states(env, 200, SEED)
    cartpole = env.unwrapped
    figure = Figure(figsize=(7.0, 4.6), dpi=100)
    FigureCanvasAgg(figure)
    top, bottom = figure.subplots(2, 1, height_ratios=(1.3, 1))
    draw_cartpole(top, states[-1], cartpole.targets, cartpole.goal_width, target=3, trail=states[:-1])
    top.set_title(f"{GOAL_CARTPOLE_ID}: task 3, a random episode of {len(states) - 1} steps")
    on_track = np.zeros((500, 4))
    on_track[:, 0] = np.linspace(-2.7, 2.7, 500)
    for task, target in enumerate(cartpole.targets):
        bold = task == 3
        bottom.plot(
            on_track[:, 0],
            cartpole.expected_reward(on_track, task),
            color="darkgreen" if bold else "gray",
            lw=2.5 if bold else 1,
            label=f"task {task}: x = {target:g}" if bold else None,
        )
    bottom.set_xlim(top.get_xlim())
    bottom.set_xlabel("cart position x (m), pole upright")
    bottom.set_ylabel("expected reward")
    bottom.legend(loc="upper left", fontsize=8)
    figure.savefig(path, bbox_inches="tight")


if __name__ == "__main__":
    four_rooms_picture(DOCS / "four_rooms.png")
    goal_cartpole_picture(DOCS / "goal_cartpole.png")
    print(f"wrote {DOCS / 'four_rooms.png'} and {DOCS / 'goal_cartpole.png'}")
