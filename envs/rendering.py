"""Pictures of the maze in the style of the paper's Figures 1-4.

Walls in black, the reward (its estimate, or the target cell) in green, the trajectory as a blue broken
line, and the greedy action at each cell centre as a red arrow. y points down, so NORTH is up.
matplotlib is imported only when drawing.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

import numpy as np

from envs.dynamics import ACTION_DIRECTIONS, MAZE_SIZE, make_walls

__all__ = ["draw_maze", "render_maze", "save_maze_png"]

TARGET_GREEN = (0.55, 0.85, 0.45)
WALL_WIDTH = 5.0


def _green_heat_map(values: np.ndarray) -> np.ndarray:
    """
    RGB image of values as shades of green, white at 0 and full green at the largest value; negative
    values are shown as 0 (the paper shows rewards in green, and only where they are positive).
    """
    values = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    top = values.max(initial=0.0)
    level = np.clip(values / top, 0.0, 1.0) if top > 0 else np.zeros_like(values)
    white, green = np.ones(3), np.array(TARGET_GREEN) * 0.8
    return white + level[..., None] * (green - white)


def draw_maze(
    ax: Any,
    walls: Iterable | np.ndarray,
    *,
    target_cells: Iterable[tuple[int, int]] = (),
    trajectory: np.ndarray | None = None,
    cell_values: np.ndarray | None = None,
    state_values: np.ndarray | None = None,
    policy: np.ndarray | None = None,
    title: str | None = None,
) -> None:
    """
    Draw the maze and its overlays on a matplotlib Axes.

    :param ax: the Axes
    :param walls: wall layout (the border is added) or an ``(m, 4)`` array from ``make_walls``
    :param target_cells: cells ``(i, j)`` filled in green when no heat map is given, outlined otherwise
    :param trajectory: (t, 2) states joined by a blue broken line
    :param cell_values: (5, 5) values indexed ``[i - 1, j - 1]``, as a green heat map
    :param state_values: (ny, nx) values on a regular grid over the square (row = y), as a green heat map
    :param policy: (5, 5) actions indexed ``[i - 1, j - 1]``, as red arrows at the cell centres
    :param title: optional title
    """
    from matplotlib.patches import Rectangle

    segments = walls if isinstance(walls, np.ndarray) and walls.ndim == 2 else make_walls(walls)
    extent = (0.0, float(MAZE_SIZE), float(MAZE_SIZE), 0.0)
    heat = None
    if cell_values is not None:
        heat = np.asarray(cell_values, dtype=np.float64).T  # rows are y (j), columns are x (i)
    elif state_values is not None:
        heat = np.asarray(state_values, dtype=np.float64)
    if heat is not None:
        ax.imshow(_green_heat_map(heat), extent=extent, interpolation="nearest", zorder=0)
    for i, j in target_cells:
        ax.add_patch(
            Rectangle(
                (i - 1, j - 1),
                1,
                1,
                facecolor=TARGET_GREEN if heat is None else "none",
                edgecolor=TARGET_GREEN,
                linewidth=0 if heat is None else 3,
                zorder=1,
            )
        )
    for x0, y0, x1, y1 in segments:
        ax.plot(
            [x0, x1], [y0, y1], color="black", linewidth=WALL_WIDTH, solid_capstyle="projecting", zorder=4
        )
    if policy is not None:
        actions = np.asarray(policy, dtype=np.int64)
        centres = np.arange(MAZE_SIZE) + 0.5
        x, y = np.meshgrid(centres, centres, indexing="ij")  # [i - 1, j - 1]
        direction = ACTION_DIRECTIONS[actions]
        ax.quiver(
            x,
            y,
            direction[..., 0],
            direction[..., 1],
            color="red",
            angles="xy",
            scale_units="xy",
            scale=2.5,
            width=0.012,
            zorder=3,
        )
    if trajectory is not None and len(trajectory):
        path = np.asarray(trajectory, dtype=np.float64)
        ax.plot(path[:, 0], path[:, 1], color="blue", linewidth=1.5, marker="o", markersize=2.5, zorder=2)
    ax.set_xlim(0, MAZE_SIZE)
    ax.set_ylim(MAZE_SIZE, 0)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title)


def render_maze(walls: Iterable | np.ndarray, *, size_px: int = 400, **overlays: Any) -> np.ndarray:
    """
    The maze as an RGB image filling the whole picture: pixel ``(row, col)`` shows the point
    ``(x, y) = (5 col / W, 5 row / H)``.

    :param walls: wall layout
    :param size_px: width and height of the image
    :param overlays: keyword arguments of :func:`draw_maze` (``title`` is not drawn: no room for it)
    :return: (size_px, size_px, 3) uint8
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    overlays.pop("title", None)
    figure = Figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    canvas = FigureCanvasAgg(figure)
    ax = figure.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    draw_maze(ax, walls, **overlays)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def save_maze_png(path: str | os.PathLike, walls: Iterable | np.ndarray, **overlays: Any) -> None:
    """Draw the maze (with its overlays and optional ``title``) to a PNG file."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(4.5, 4.8 if overlays.get("title") else 4.5), dpi=100)
    FigureCanvasAgg(figure)
    draw_maze(figure.add_subplot(), walls, **overlays)
    figure.savefig(path, bbox_inches="tight")
