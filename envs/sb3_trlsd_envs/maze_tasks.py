"""
The maze's 25 tasks (eq. 12): naming them (an index or the cell ``(i, j)`` each rewards), sets of them
(``"all"``, ``"corners"``), the noise-free expected reward of each, and the table of reward noise by cell of
the maze's variant (``CELL_NOISE_STDS``).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from sb3_trlsd_envs.dynamics import MAZE_SIZE, cell_of

__all__ = [
    "CELL_NOISE_STDS",
    "CORNER_TASKS",
    "N_TASKS",
    "Task",
    "expected_reward",
    "task_cell",
    "task_index",
    "task_indices",
]

N_TASKS = MAZE_SIZE * MAZE_SIZE
Task = int | tuple[int, int]
# The maze variant whose reward noise differs by cell (``reward_noise_std=CELL_NOISE_STDS``), for the heads
# that weigh how much neighbours agree (``BernsteinRewardHead``): a checkerboard of quiet cells (standard
# deviation 0.1, the 13 cells with i + j even, the corners among them) and loud ones (1.44, the 12 others),
# whose mean variance over the 25 cells is the paper's 1 (13 x 0.1^2 + 12 x 1.44^2 = 25.01): the same noise on
# average, spread unevenly. Every task has quiet and loud cells next to its own; 12 tasks' own cell is loud.
QUIET_STD, LOUD_STD = 0.1, 1.44
CELL_NOISE_STDS = tuple(
    tuple(QUIET_STD if (i + j) % 2 == 0 else LOUD_STD for j in range(1, MAZE_SIZE + 1))
    for i in range(1, MAZE_SIZE + 1)
)


def task_index(task: Task) -> int:
    """
    The index of a task: tau_ij (eq. 12) is ``5 (i - 1) + (j - 1)``.

    :param task: ``(i, j)`` with i, j in 1..5, or an index in 0..24
    :return: the index
    :raises ValueError: naming ``task`` for anything else
    """
    if isinstance(task, np.ndarray) and task.ndim == 0:
        task = task.item()
    if isinstance(task, (int, np.integer)) and not isinstance(task, bool):
        if 0 <= task < N_TASKS:
            return int(task)
    elif isinstance(task, (tuple, list, np.ndarray)) and len(task) == 2:
        i, j = task
        integers = all(isinstance(k, (int, np.integer)) and not isinstance(k, bool) for k in (i, j))
        if integers and 1 <= i <= MAZE_SIZE and 1 <= j <= MAZE_SIZE:
            return MAZE_SIZE * (int(i) - 1) + (int(j) - 1)
    raise ValueError(
        f"task must be (i, j) with i, j in 1..{MAZE_SIZE} or an index in 0..{N_TASKS - 1}, got {task!r}"
    )


def task_cell(index: Task) -> tuple[int, int]:
    """
    The cell rewarded by a task.

    :param index: the task's index in 0..24 (or ``(i, j)``, returned as is once validated)
    :return: ``(i, j)``, both in 1..5
    :raises ValueError: naming ``task`` for anything else
    """
    index = task_index(index)
    return index // MAZE_SIZE + 1, index % MAZE_SIZE + 1


CORNER_TASKS = tuple(task_index(cell) for cell in ((1, 1), (1, 5), (5, 1), (5, 5)))


def task_indices(tasks: str | Iterable[Task]) -> tuple[int, ...]:
    """
    The indices of a set of tasks.

    :param tasks: ``"all"`` (the 25), ``"corners"`` (tau_11, tau_15, tau_51, tau_55) or a list of tasks
    :return: their indices, in order
    :raises ValueError: naming ``tasks`` (or ``task`` for a bad member)
    """
    if isinstance(tasks, str):
        if tasks == "all":
            return tuple(range(N_TASKS))
        if tasks == "corners":
            return CORNER_TASKS
        raise ValueError(f"tasks must be 'all', 'corners' or a list of tasks, got {tasks!r}")
    indices = tuple(task_index(task) for task in tasks)
    if not indices:
        raise ValueError("tasks must name at least one task")
    return indices


def expected_reward(states: np.ndarray, task: Task) -> np.ndarray:
    """
    The noise-free expected reward E[R_tau(s)] of eq. 12: 1 in the task's cell, 0 elsewhere.

    :param states: (n, 2) states
    :param task: the task, ``(i, j)`` or index
    :return: (n,) expected rewards
    """
    i, j = task_cell(task)
    cells = cell_of(states)
    return ((cells[:, 0] == i) & (cells[:, 1] == j)).astype(np.float64)
