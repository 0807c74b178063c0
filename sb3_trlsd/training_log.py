"""What a TRLSD model writes to SB3's logger while it learns: a refit's scalars (``record_refit``), a step's
(``record_step``), a task's picture and the run's HParams, the last two written when they are made.

SB3's logger keeps one value per key until it dumps, every ``log_interval`` episodes: a picture recorded
between two dumps replaces the previous one. ``write_now`` writes a value straight to the logger's
TensorBoard output instead, at the step it belongs to, so none is lost.

A task's picture comes from the env: an env whose unwrapped object has a method
``task_picture(view: TaskView) -> np.ndarray`` (an (H, W, 3) uint8 RGB image) gets one at the task's first
refit and then every ``log_picture_every`` refits (the maze draws the paper's Figures 1-4 style).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from stable_baselines3.common.logger import HParam, Image, Logger, TensorBoardOutputFormat
from stable_baselines3.common.vec_env import VecEnv

from sb3_trlsd.fqi import FQIResult
from sb3_trlsd.reward_timing import staying_inputs
from sb3_trlsd.task_learner import TaskLearner

__all__ = [
    "PICTURE_METHOD",
    "TaskView",
    "has_tensorboard",
    "log_hyperparameters",
    "log_task_picture",
    "picture_due",
    "record_refit",
    "record_step",
    "task_view",
    "write_now",
]

PICTURE_METHOD = "task_picture"  # the env method that draws a task's learner


class TaskView(NamedTuple):
    """What a picture of a task's learner may show, as functions of states (n, d)."""

    task: int
    estimate: Callable[[np.ndarray], np.ndarray]  # R^_tau, (n,)
    bonus: Callable[[np.ndarray], np.ndarray]  # CI_tau = R~ - R^ before any cap, (n,)
    q_values: Callable[[np.ndarray], np.ndarray]  # Q_tau(s, .), (n, n_actions)
    trajectory: np.ndarray  # the task's latest states, (t, d), NaN rows at resets


def has_tensorboard(logger: Logger) -> bool:
    """Whether the logger writes to TensorBoard."""
    return any(isinstance(output, TensorBoardOutputFormat) for output in logger.output_formats)


def write_now(logger: Logger, key: str, value: Any, step: int) -> None:
    """
    Write ``value`` under ``key`` to the logger's TensorBoard outputs at ``step``, now (not at the next dump).

    :param logger: the model's logger
    :param key: the tag, e.g. ``"pictures/task_4"``
    :param value: anything SB3's TensorBoard output takes (``Image``, ``HParam``, a number, ...)
    :param step: the step it belongs to (``model.num_timesteps``)
    """
    for output in logger.output_formats:
        if isinstance(output, TensorBoardOutputFormat):
            output.write({key: value}, {key: ()}, step=step)


def log_task_picture(logger: Logger, env: VecEnv | None, view: TaskView, step: int) -> None:
    """
    Write a picture of a task's learner, when the logger writes to TensorBoard and the env draws tasks
    (``task_picture``).

    :param logger: the model's logger
    :param env: the model's env (None: no picture)
    :param view: what the picture may show
    :param step: the step it belongs to
    """
    if env is None or not has_tensorboard(logger) or not env.has_attr(PICTURE_METHOD):
        return
    picture = env.get_attr(PICTURE_METHOD, indices=0)[0](view)
    write_now(logger, f"pictures/task_{view.task}", Image(picture, "HWC"), step)


def log_hyperparameters(
    logger: Logger, hyperparameters: dict[str, int | float | str | bool], step: int
) -> None:
    """
    Write a run's HParams to TensorBoard, now.

    :param logger: the model's logger
    :param hyperparameters: the settings, as the HParams tab shows them
    :param step: the step they belong to
    """
    metrics = {"rollout/ep_rew_mean": 0.0, "train/policy_updates": 0.0}
    write_now(logger, "hparams", HParam(hyperparameters, metrics), step)


def record_refit(
    logger: Logger, learner: TaskLearner, result: FQIResult, rewards: np.ndarray, refits: int
) -> None:
    """
    Record a refit's scalars: ``train/policy_updates`` (every task's refits so far), ``train/fqi_iterations``
    (its steps, each a pass over the rows), ``train/fqi_policy_evaluations`` (those of them that evaluated a
    policy exactly), ``train/bellman_residual``, ``train/fqi_change`` (the stopping rule's last change, in its
    units of ``fqi_tol``), ``train/fqi_converged`` (1 where the rule was met, 0 at the cap), and, when the
    logger writes somewhere, ``reward/ci_mean`` (the optimism applied: the mean of R~ - R^ over the
    relabelled rows, from the task's relabelling).

    :param logger: the model's logger
    :param learner: the task refitted
    :param result: the fit
    :param rewards: the relabelled rewards it fitted on
    :param refits: every task's refits so far
    """
    logger.record("train/policy_updates", refits)
    logger.record("train/fqi_iterations", result.iterations)
    logger.record("train/fqi_policy_evaluations", result.policy_evaluations)
    logger.record("train/bellman_residual", result.bellman_residual)
    logger.record("train/fqi_change", result.change)
    logger.record("train/fqi_converged", float(result.converged))
    if logger.output_formats:
        logger.record("reward/ci_mean", learner.bonus_mean(rewards))


def record_step(logger: Logger, learner: TaskLearner, exploration_rate: float) -> None:
    """
    Record a step's scalars, those of the task of its last transition: ``reward/target_samples`` (its online
    samples) and ``rollout/exploration_rate`` (its epsilon at the next step, as SB3's DQN logs its own).
    """
    logger.record("reward/target_samples", learner.head.n_samples)
    logger.record("rollout/exploration_rate", exploration_rate)


def picture_due(learner: TaskLearner, every: int) -> bool:
    """Whether a refit of ``learner`` gets a picture: its first, then every ``every`` (0: never)."""
    return bool(every) and (learner.refits == 1 or learner.refits % every == 0)


def task_view(
    learner: TaskLearner, q_values: Callable[[np.ndarray, int], np.ndarray], n_actions: int
) -> TaskView:
    """
    What a picture of a task's learner may show: its head's estimate and bonus of staying at a state
    (averaged over the actions when the reward belongs to the step), its Q, and its latest trajectory.

    :param learner: the task's learner
    :param q_values: ``q_values(states, task)`` of the model's policy
    :param n_actions: the env's actions
    """

    def staying(values: Callable[[np.ndarray], np.ndarray], states: np.ndarray) -> np.ndarray:
        inputs = staying_inputs(states, learner.reward_timing, n_actions)
        return np.mean([values(rows) for rows in inputs], axis=0)

    return TaskView(
        task=learner.task,
        estimate=lambda states: staying(learner.head.estimate, states),
        bonus=lambda states: staying(learner.head.bonus, states),
        q_values=lambda states: q_values(states, learner.task),
        trajectory=learner.recent_states(),
    )
