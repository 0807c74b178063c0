"""TensorBoard pictures and HParams, written when they are made.

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

__all__ = [
    "PICTURE_METHOD",
    "TaskView",
    "has_tensorboard",
    "log_hyperparameters",
    "log_refit",
    "log_task_picture",
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
            output.write({key: value}, {key: None}, step=step)


def log_task_picture(model: Any, learner: Any, trail: int = 50) -> None:
    """
    Write a picture of ``learner``'s task at its first refit, then every ``model.log_picture_every``
    refits, when the model logs to TensorBoard and its env draws tasks (``task_picture``).

    :param model: a ``TRLSD`` model
    :param learner: the task's ``TaskLearner``, just refitted
    :param trail: states of the task's latest trajectory shown
    """
    every = model.log_picture_every
    if not every or (learner.refits != 1 and learner.refits % every) or not has_tensorboard(model.logger):
        return
    if model.env is None or not model.env.has_attr(PICTURE_METHOD):
        return
    view = TaskView(
        task=learner.task,
        estimate=learner.head.estimate,
        bonus=learner.head.bonus,
        q_values=lambda states: model.policy.q_values(states, learner.task),
        trajectory=model.replay_buffer.recent_states(learner.task, trail),
    )
    picture = model.env.get_attr(PICTURE_METHOD, indices=0)[0](view)
    write_now(model.logger, f"pictures/task_{learner.task}", Image(picture, "HWC"), model.num_timesteps)


def log_hyperparameters(model: Any) -> None:
    """Write the model's HParams (``model.hyperparameters()``) to TensorBoard, now."""
    metrics = {"rollout/ep_rew_mean": 0.0, "train/policy_updates": 0.0}
    write_now(model.logger, "hparams", HParam(model.hyperparameters(), metrics), model.num_timesteps)


def log_refit(model: Any, learner: Any, result: Any, rewards: np.ndarray, trail: int = 50) -> None:
    """
    What a refit writes to the logger (nothing when the model has no logger yet, outside ``learn``):
    ``train/policy_updates``, ``train/fqi_iterations``, ``train/bellman_residual``, ``reward/ci_mean`` (the
    optimism applied, mean of R~ - R^ over the relabelled set), and the task's picture when one is due.

    :param model: a ``TRLSD`` model
    :param learner: the task's ``TaskLearner``, just refitted
    :param result: the ``FQIResult`` of the refit
    :param rewards: the relabelled rewards the Q-function was fitted on
    :param trail: states of the task's latest trajectory shown in its picture
    """
    if getattr(model, "_logger", None) is None:
        return
    model.logger.record("train/policy_updates", sum(model.policy_updates.values()))
    model.logger.record("train/fqi_iterations", result.iterations)
    model.logger.record("train/bellman_residual", result.bellman_residual)
    if len(rewards):
        states = model.replay_buffer.transitions().states
        model.logger.record("reward/ci_mean", float(np.mean(rewards - learner.head.estimate(states))))
    log_task_picture(model, learner, trail)
