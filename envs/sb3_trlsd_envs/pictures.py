"""
What a task's learner looks like on the maze, as in the paper's Figures 1-4: the reward estimate R^ and
the confidence bonus as green heat maps, the greedy policy as red arrows per cell, the latest trajectory
in blue. ``SharedDynamicsMaze.task_picture`` draws it for ``TRLSD``'s TensorBoard pictures
(``log_picture_every``); the experiments draw their snapshots from the same grids.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_trlsd_envs.dynamics import MAZE_SIZE
from sb3_trlsd_envs.maze_tasks import task_cell
from sb3_trlsd_envs.rendering import draw_maze

__all__ = ["greedy_policy_grid", "state_grid", "task_picture"]

PICTURE_GRID = 50  # heat maps are drawn on a PICTURE_GRID x PICTURE_GRID grid of states


def state_grid(n_per_side: int = PICTURE_GRID) -> np.ndarray:
    """
    The centres of an ``n_per_side x n_per_side`` grid over the maze, row by row (row = y).

    :return: (n_per_side ** 2, 2) states; values on them reshape to (n_per_side, n_per_side)
    """
    centres = (np.arange(n_per_side) + 0.5) * MAZE_SIZE / n_per_side
    x, y = np.meshgrid(centres, centres)  # row = y
    return np.column_stack([x.ravel(), y.ravel()])


def greedy_policy_grid(q_values: Any, task: int) -> np.ndarray:
    """
    The greedy action at each cell centre of the maze.

    :param q_values: ``q_values(states, task) -> (n, n_actions)``, e.g. ``model.policy.q_values``
    :param task: the task
    :return: (5, 5) actions indexed ``[i - 1, j - 1]`` (cell i = ceil(x), j = ceil(y))
    """
    cell_centres = np.arange(MAZE_SIZE) + 0.5
    ci, cj = np.meshgrid(cell_centres, cell_centres, indexing="ij")  # [i - 1, j - 1]
    q = q_values(np.column_stack([ci.ravel(), cj.ravel()]), task)
    return np.asarray(q).argmax(axis=1).reshape(MAZE_SIZE, MAZE_SIZE)


def task_picture(view: Any, walls: Any, size_px: int = 360) -> np.ndarray:
    """
    Two panels side by side: R^ with the greedy policy and the trajectory, and the bonus R~ - R^ (CI).
    The task's target cell is outlined in green.

    :param view: what to draw of a task's learner: ``task``, ``estimate(states)``, ``bonus(states)``,
        ``q_values(states)`` and ``trajectory`` (e.g. ``sb3_trlsd.training_log.TaskView``)
    :param walls: the maze's wall layout
    :param size_px: height of the picture; the width is twice that
    :return: (size_px, 2 * size_px, 3) uint8 RGB image
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    grid = state_grid()
    estimate = np.asarray(view.estimate(grid)).reshape(PICTURE_GRID, PICTURE_GRID)
    bonus = np.asarray(view.bonus(grid)).reshape(PICTURE_GRID, PICTURE_GRID)
    policy = greedy_policy_grid(lambda states, _task: view.q_values(states), view.task)
    i, j = task_cell(view.task)
    trajectory = np.asarray(view.trajectory, dtype=np.float64).reshape(-1, 2)
    figure = Figure(figsize=(2 * size_px / 100, size_px / 100), dpi=100)
    canvas = FigureCanvasAgg(figure)
    left, right = figure.subplots(1, 2)
    draw_maze(
        left,
        walls,
        target_cells=[(i, j)],
        state_values=estimate,
        policy=policy,
        trajectory=trajectory,
        title=f"tau_{i}{j}: R^ (max {estimate.max():.2f}), greedy policy",
    )
    draw_maze(
        right,
        walls,
        target_cells=[(i, j)],
        state_values=bonus,
        title=f"optimism R~ - R^ (max {bonus.max():.2f})",
    )
    for ax in (left, right):
        ax.title.set_fontsize(14)
    figure.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.9, wspace=0.04)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
