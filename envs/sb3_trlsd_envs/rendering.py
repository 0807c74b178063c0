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

from sb3_trlsd_envs.dynamics import ACTION_DIRECTIONS, EAST, MAZE_SIZE, NORTH, SOUTH, WEST, make_walls

__all__ = ["draw_maze", "render_maze", "save_maze_png"]

TARGET_GREEN = (0.55, 0.85, 0.45)
WALL_WIDTH = 5.0


def _green_heat_map(values: np.ndarray) -> np.ndarray:
    """
    RGB image of values as shades of green.

    Normalisation: values are clipped to [0, max], white at 0 and full green at the largest value, so
    negative values (noisy reward estimates) show as white; the paper shows rewards in green, and only
    where they are positive. NaN and infinite values show as white too.

    :param values: any array of values
    :return: the same shape plus a last axis of 3 RGB floats in [0, 1]
    """
    values = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    top = values.max(initial=0.0)
    level = np.clip(values / top, 0.0, 1.0) if top > 0 else np.zeros_like(values)
    white, green = np.ones(3), np.array(TARGET_GREEN) * 0.8
    return white + level[..., None] * (green - white)


def _cell_array(values: np.ndarray, name: str) -> np.ndarray:
    """``values`` as a (5, 5) float array indexed ``[i - 1, j - 1]``, or a ValueError naming ``name``."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (MAZE_SIZE, MAZE_SIZE):
        raise ValueError(
            f"{name} must be a ({MAZE_SIZE}, {MAZE_SIZE}) array indexed [i - 1, j - 1], got {array.shape}"
        )
    return array


def _heat_values(cell_values: np.ndarray | None, state_values: np.ndarray | None) -> np.ndarray | None:
    """The heat map to draw as an image over the square (rows are y), or None."""
    if cell_values is not None:
        return _cell_array(cell_values, "cell_values").T  # rows are y (j), columns are x (i)
    if state_values is None:
        return None
    heat = np.asarray(state_values, dtype=np.float64)
    if heat.ndim != 2 or not heat.size:
        raise ValueError(f"state_values must be an (ny, nx) array, got shape {heat.shape}")
    return heat


def _draw_policy(ax: Any, policy: np.ndarray) -> None:
    """Red arrows at the cell centres, pointing the way each cell's action moves (NORTH up)."""
    actions = _cell_array(policy, "policy")
    if not np.isin(actions, (NORTH, WEST, SOUTH, EAST)).all():
        raise ValueError(f"policy must hold actions in 0..3, got {np.unique(actions)}")
    centres = np.arange(MAZE_SIZE) + 0.5
    x, y = np.meshgrid(centres, centres, indexing="ij")  # [i - 1, j - 1]
    direction = ACTION_DIRECTIONS[actions.astype(np.int64)]
    # angles="xy" draws the arrows in data coordinates, so they follow the inverted y axis.
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

    :param ax: the Axes; its limits are set to the square, with y pointing down (NORTH is up)
    :param walls: wall layout (the border is added), as accepted by :func:`sb3_trlsd_envs.dynamics.make_walls`
    :param target_cells: cells ``(i, j)`` filled in green when no heat map is given, outlined otherwise
    :param trajectory: (t, 2) states joined by a blue broken line
    :param cell_values: (5, 5) values indexed ``[i - 1, j - 1]``, as a green heat map
    :param state_values: (ny, nx) values on a regular grid over the square (row = y), as a green heat map
    :param policy: (5, 5) actions indexed ``[i - 1, j - 1]``, as red arrows at the cell centres
    :param title: optional title
    """
    from matplotlib.patches import Rectangle

    segments = make_walls(walls)
    extent = (0.0, float(MAZE_SIZE), float(MAZE_SIZE), 0.0)
    heat = _heat_values(cell_values, state_values)
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
        _draw_policy(ax, policy)
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

    if not isinstance(size_px, (int, np.integer)) or size_px < 1:
        raise ValueError(f"size_px must be a positive integer, got {size_px!r}")
    overlays.pop("title", None)
    figure = Figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    canvas = FigureCanvasAgg(figure)
    ax = figure.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    draw_maze(ax, walls, **overlays)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def save_maze_png(path: str | os.PathLike, walls: Iterable | np.ndarray, **overlays: Any) -> None:
    """
    Draw the maze to a PNG file, with its title above it if one is given.

    :param path: the file to write
    :param walls: wall layout
    :param overlays: keyword arguments of :func:`draw_maze`, ``title`` included
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(4.5, 4.8 if overlays.get("title") else 4.5), dpi=100)
    FigureCanvasAgg(figure)
    draw_maze(figure.add_subplot(), walls, **overlays)
    figure.savefig(path, bbox_inches="tight")
