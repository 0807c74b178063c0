"""What ``TRLSD`` adds to SB3's algorithm interface: learn and predict, nothing lost on save and load.

SB3 saves a model's attributes and networks, not its replay buffer. TRLSD's task learners (reward heads
with their samples, trigger state, refit counts) are attributes and go with them; ``TRLSDInterface.save``
also puts the shared buffer's rows in the zip, as one of SB3's "pytorch variables" (a float64 tensor), and
``load`` puts them back (``persistence.py``), so that a loaded model goes on learning as an uninterrupted
one would; what is derived from them (relabelling caches, FQI factorisations) is rebuilt at the first refit.
``learn`` loads the source set once and writes the HParams when it starts; ``predict`` warns, once per
task, about a task whose Q-function was never fitted.
"""

from __future__ import annotations

import io
import pathlib
import warnings
from typing import Any, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.callbacks import log_hyperparameters
from sb3_trlsd.observations import split_observation
from sb3_trlsd.persistence import BUFFER_ROWS, empty_rows, read_replay_buffer, restore_after_load
from sb3_trlsd.settings import hyperparameters_of
from sb3_trlsd.source_data import load_source_once

__all__ = ["UNFITTED_TASK", "TRLSDInterface"]

SelfInterface = TypeVar("SelfInterface", bound="TRLSDInterface")
UNFITTED_TASK = (
    "task {task} has never been fitted: its Q-function is 0 and predict returns action 0 for every state; "
    "learn on it first, or call model.update_policy({task})"
)


class TRLSDInterface:
    """
    A mixin of ``TRLSD`` (listed before ``OffPolicyAlgorithm``, whose save and load it extends): SB3's save
    and load of an algorithm whose ``replay_buffer`` is a ``SharedDynamicsReplayBuffer`` and whose
    ``task_learners`` may hold known reward heads.
    Derived state is left out of the zip: ``features``, ``_fit_rows``, ``_warned_unfitted``, and the
    ``reward_fn``.
    """

    replay_buffer: SharedDynamicsReplayBuffer
    _buffer_rows: th.Tensor
    task_learners: dict[int, Any]
    _warned_unfitted: set[int]

    def _excluded_save_params(self) -> list[str]:
        # Rebuilt by _setup_model, or not saved on purpose (a reward_fn is often an env's method).
        return [*super()._excluded_save_params(), "features", "_fit_rows", "_warned_unfitted", "reward_fn"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy"], [BUFFER_ROWS]

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: list[str] | None = None,
        include: list[str] | None = None,
    ) -> None:
        """SB3's ``save``, with the shared buffer's rows in the zip (so that ``load`` can go on learning)."""
        self._buffer_rows = th.as_tensor(self.replay_buffer.packed_rows())
        try:
            super().save(path, exclude=exclude, include=include)
        finally:
            self._buffer_rows = empty_rows()

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfInterface],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfInterface:
        """SB3's ``load``; the shared buffer comes back with its rows, the known heads with reward_fn."""
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        restore_after_load(model)
        return model

    def load_replay_buffer(
        self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True
    ) -> None:
        """
        Load a buffer saved by ``save_replay_buffer``: a ``SharedDynamicsReplayBuffer`` of this env's layout.

        :raises ValueError: naming the file, when it cannot be read or holds another kind of buffer
        """
        buffer = read_replay_buffer(path, self.replay_buffer, self.verbose)
        buffer.device = self.device
        self.replay_buffer = buffer

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        total_timesteps, callback = super()._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        log_hyperparameters(self)
        return total_timesteps, callback

    def hyperparameters(self) -> dict[str, int | float | str | bool]:
        """The settings of this run, as TensorBoard's HParams tab shows them."""
        return hyperparameters_of(self)

    def learn(
        self: SelfInterface,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "TRLSD",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfInterface:
        load_source_once(self)
        super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
        # SB3 dumps the logs every log_interval episodes: a run's last values are kept too.
        self.dump_logs()
        return self

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``; a task whose Q-function was never fitted is warned about, once per task."""
        _, tasks = split_observation(observation, self.replay_buffer.obs_shape[0])
        for task in np.unique(tasks):
            learner = self.task_learners.get(int(task))
            if (learner is None or not learner.fitted) and int(task) not in self._warned_unfitted:
                self._warned_unfitted.add(int(task))
                warnings.warn(UNFITTED_TASK.format(task=task), stacklevel=2)
        return super().predict(observation, state, episode_start, deterministic)
