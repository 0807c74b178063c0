"""Several mazes stepped at once: one vectorised move for all of them, each drawing from its own generator.

A batch of runs in lockstep (``sb3_trlsd_lab.execution.lockstep``) steps the mazes of all its runs with
``step_mazes``; ``SharedDynamicsMaze.step`` is ``step_mazes`` with one maze. Each maze draws what a step of
it alone draws, in the same order (its reward noise, its move noise and rebounds, its end-of-trajectory
draw), so a maze stepped in a batch follows the trajectory it follows alone with the same seed.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from sb3_trlsd_envs.dynamics import cell_of, cell_task, maze_step, reward_noise_scales

if TYPE_CHECKING:
    from sb3_trlsd_envs.maze import SharedDynamicsMaze

__all__ = ["MazeSteps", "step_mazes"]


class MazeSteps:
    """
    What ``step_mazes`` returns, one row per maze.

    :param states: the states reached, (n, 2) float64 (observations are their float32 rounding)
    :param rewards: the rewards, drawn for the states the steps start from, (n,)
    :param truncated: the trajectory ended (``termination_prob``), (n,) bool
    """

    def __init__(self, states: np.ndarray, rewards: np.ndarray, truncated: np.ndarray):
        self.states, self.rewards, self.truncated = states, rewards, truncated


def _dynamics_settings(maze: SharedDynamicsMaze) -> tuple:
    return (
        maze.walls.tobytes(),
        maze.along_noise_std,
        maze.across_noise_std,
        maze.reward_noise_stds.tobytes(),
        maze.termination_prob,
    )


def step_mazes(mazes: Sequence[SharedDynamicsMaze], actions: np.ndarray) -> MazeSteps:
    """
    Step every maze with its action: move, reward the state the move starts from (eq. 12 on s_t), end the
    trajectory with ``termination_prob``. Each maze's ``state`` and ``trajectory`` are updated.

    :param mazes: the (unwrapped) mazes, with the same walls, noises and termination probability
    :param actions: one action in 0..3 per maze, (n,)
    :return: the states reached, rewards and ends of trajectory
    """
    first = mazes[0]
    if any(_dynamics_settings(maze) != _dynamics_settings(first) for maze in mazes[1:]):
        raise ValueError("step_mazes steps mazes of one dynamics: the same walls, noises and termination")
    generators = [maze.np_random for maze in mazes]
    states = np.array([maze.state for maze in mazes], dtype=np.float64).reshape(len(mazes), 2)
    # E[R_tau(s_t)] (eq. 12) of each maze's task, and its noise (of s_t's cell): the first draw of a step.
    expected = (cell_task(cell_of(states)) == np.array([maze.task for maze in mazes])).astype(np.float64)
    noise = np.array([g.normal() for g in generators])
    rewards = expected + reward_noise_scales(states, first.reward_noise_stds) * noise
    next_states = maze_step(
        states, np.asarray(actions), generators, first.walls, first.along_noise_std, first.across_noise_std
    )
    truncated = np.array([g.random() < first.termination_prob for g in generators], dtype=bool)
    for maze, state in zip(mazes, next_states, strict=True):
        maze.state = state
        maze.trajectory.append(state.copy())
    return MazeSteps(next_states, rewards, truncated)
