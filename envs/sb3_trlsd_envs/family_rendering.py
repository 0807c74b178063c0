"""Pictures of the four-rooms world and of the goal cart-pole, in the maze's colours.

Walls and the cart in black, rewards in green, trajectories in blue. matplotlib is imported only when
drawing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sb3_trlsd_envs.cartpole_dynamics import target_rewards
from sb3_trlsd_envs.rendering import TARGET_GREEN, WALL_WIDTH

__all__ = ["draw_cartpole", "draw_four_rooms", "render_cartpole", "render_four_rooms"]

POLE_BROWN = (0.79, 0.6, 0.4)  # Gymnasium's pole colour
CART_SIZE = (0.4, 0.2)  # width and height of the cart in metres, as Gymnasium draws it (50 x 30 px)


def _image(draw: Callable[[Any], None], width_px: int, height_px: int) -> np.ndarray:
    """What ``draw(ax)`` draws on axes filling a ``height_px`` x ``width_px`` picture, as RGB uint8."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_px / 100, height_px / 100), dpi=100)
    canvas = FigureCanvasAgg(figure)
    ax = figure.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    draw(ax)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def draw_four_rooms(
    ax: Any,
    walls: np.ndarray,
    goals: np.ndarray,
    goal_radius: float,
    *,
    target: int | None = None,
    trajectory: np.ndarray | None = None,
    label_goals: bool = False,
) -> None:
    """
    Draw the four-rooms world on a matplotlib Axes, y pointing down (NORTH is up).

    :param ax: the Axes; its limits are set to the unit square
    :param walls: (k, 4) segments from :func:`sb3_trlsd_envs.four_rooms.make_room_walls`
    :param goals: (n_tasks, 2) goal centres, drawn as green circles
    :param goal_radius: radius of the goal discs
    :param target: the task whose goal disc is filled
    :param trajectory: (t, 2) states joined by a blue broken line
    :param label_goals: write each goal's task index at its centre
    """
    from matplotlib.patches import Circle

    for index, (x, y) in enumerate(np.asarray(goals)):
        filled = index == target
        ax.add_patch(
            Circle(
                (x, y),
                goal_radius,
                facecolor=TARGET_GREEN if filled else "none",
                edgecolor=TARGET_GREEN,
                lw=2,
            )
        )
        if label_goals:
            ax.text(x, y, str(index), ha="center", va="center", fontsize=8, color="dimgray")
    for x0, y0, x1, y1 in walls:
        ax.plot([x0, x1], [y0, y1], color="black", linewidth=WALL_WIDTH, solid_capstyle="projecting")
    if trajectory is not None and len(trajectory):
        path = np.asarray(trajectory, dtype=np.float64)
        ax.plot(path[:, 0], path[:, 1], color="blue", linewidth=1.5, marker="o", markersize=2.5)
    ax.set_xlim(0, 1)
    ax.set_ylim(1, 0)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def render_four_rooms(
    walls: np.ndarray, goals: np.ndarray, goal_radius: float, *, size_px: int = 400, **overlays: Any
) -> np.ndarray:
    """The four-rooms world as a ``(size_px, size_px, 3)`` uint8 image; overlays as in ``draw_four_rooms``."""
    return _image(lambda ax: draw_four_rooms(ax, walls, goals, goal_radius, **overlays), size_px, size_px)


def draw_cartpole(
    ax: Any,
    state: np.ndarray,
    targets: Sequence[float] | np.ndarray,
    goal_width: float,
    *,
    target: int | None = None,
    x_threshold: float = 2.4,
    pole_length: float = 1.0,
    trail: np.ndarray | None = None,
) -> None:
    """
    Draw the cart-pole on a matplotlib Axes, in metres: the track with its ends, the reward of the task as a
    green band under it, the cart in black, the pole in brown and earlier poles in blue.

    :param ax: the Axes
    :param state: ``(x, x_dot, theta, theta_dot)``; theta > 0 leans the pole to the right
    :param targets: the target cart positions of the tasks, ticked under the track
    :param goal_width: standard deviation of the rewarded bump around a target
    :param target: the current task, whose reward shades the band
    :param x_threshold: the track's half length (the episode ends beyond it)
    :param pole_length: the pole's full length
    :param trail: earlier states (t, 4), their poles drawn as blue lines, fainter the older
    """
    from matplotlib.patches import Rectangle

    left, right = -x_threshold - 0.3, x_threshold + 0.3
    if target is not None:
        on_track = np.zeros((400, 4))
        on_track[:, 0] = np.linspace(left, right, 400)
        reward = target_rewards(on_track, targets[target], goal_width)[None]  # 0 off the track
        shades = 1 + reward[..., None] * (np.array(TARGET_GREEN) - 1)
        ax.imshow(shades, extent=(left, right, -0.25, -0.05), aspect="auto", interpolation="bilinear")
    for index, x in enumerate(targets):
        ax.plot([x, x], [-0.25, -0.05], color="darkgreen" if index == target else "gray", lw=1)
    ax.plot([-x_threshold, x_threshold], [0, 0], color="black", lw=1)
    for end in (-x_threshold, x_threshold):
        ax.plot([end, end], [-0.05, 0.15], color="black", lw=WALL_WIDTH / 2)
    width, height = CART_SIZE
    axle = height * 0.75

    def pole(state: np.ndarray) -> tuple[list[float], list[float]]:
        x, _, theta, _ = state
        return [x, x + pole_length * np.sin(theta)], [axle, axle + pole_length * np.cos(theta)]

    earlier = np.zeros((0, 4)) if trail is None else np.asarray(trail, dtype=np.float64).reshape(-1, 4)
    for age, old in enumerate(earlier[::-1], start=1):
        ax.plot(*pole(old), color="blue", lw=1.5, alpha=0.6 * (1 - age / (len(earlier) + 1)), zorder=2)
    x = float(state[0])
    ax.add_patch(Rectangle((x - width / 2, 0.0), width, height, color="black", zorder=3))
    ax.plot(
        *pole(np.asarray(state, dtype=np.float64)), color=POLE_BROWN, lw=6, solid_capstyle="butt", zorder=4
    )
    ax.set_xlim(left, right)
    ax.set_ylim(-0.3, 1.3)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def render_cartpole(
    state: np.ndarray, targets: Sequence[float] | np.ndarray, goal_width: float, **overlays: Any
) -> np.ndarray:
    """The cart-pole as a ``(160, 540, 3)`` uint8 image; ``overlays`` as in :func:`draw_cartpole`."""
    return _image(lambda ax: draw_cartpole(ax, state, targets, goal_width, **overlays), 540, 160)
