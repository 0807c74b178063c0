"""Nothing lost on save and load: what ``TRLSD.save`` / ``load`` / ``load_replay_buffer`` add to SB3's.

SB3 saves a model's attributes and networks, not its replay buffer. TRLSD's task learners (reward heads
with their samples, trigger state, refit counts) are attributes and go with them; ``SavesSharedBuffer``
also puts the shared buffer's rows in the zip, as one of SB3's "pytorch variables" (a float64 tensor), and
puts them back at ``load``, so that a loaded model goes on learning as an uninterrupted one would. What
is derived from them (relabelling caches, FQI factorisations) is rebuilt on the first refit. Known reward
heads get their reward function again (it is not saved: it is often an env's method), and a buffer read
by ``load_replay_buffer`` is checked before it replaces the model's.
"""

from __future__ import annotations

import io
import pathlib
import pickle
from typing import Any, TypeVar

import torch as th
from stable_baselines3.common.save_util import load_from_pkl
from stable_baselines3.common.type_aliases import GymEnv

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.builders import known_reward_fn
from sb3_trlsd.reward_heads import KnownRewardHead

SelfSaves = TypeVar("SelfSaves", bound="SavesSharedBuffer")

__all__ = ["BUFFER_ROWS", "SavesSharedBuffer", "empty_rows", "read_replay_buffer", "restore_after_load"]

# The attribute through which the buffer's rows travel in the zip, as one of SB3's "pytorch variables".
BUFFER_ROWS = "_buffer_rows"


def empty_rows() -> th.Tensor:
    """The placeholder of ``BUFFER_ROWS`` between a save and a load."""
    return th.zeros(0, dtype=th.float64)


def restore_after_load(model: Any) -> None:
    """
    After SB3's ``load``: put the saved rows back in the (new, empty) shared buffer and give the known
    reward heads their reward function (the model's ``reward_fn`` or the env's ``expected_reward``).

    :param model: the model SB3's ``load`` returned
    """
    rows = getattr(model, BUFFER_ROWS)
    if len(rows):
        model.replay_buffer.restore_packed_rows(rows.numpy())
    setattr(model, BUFFER_ROWS, empty_rows())
    reward_fn = known_reward_fn(model, required=False)
    for learner in model.task_learners.values():
        if (
            isinstance(learner.head, KnownRewardHead)
            and learner.head.reward_fn is None
            and reward_fn is not None
        ):
            learner.head.bind(reward_fn)


def read_replay_buffer(
    path: str | pathlib.Path | io.BufferedIOBase, expected: SharedDynamicsReplayBuffer, verbose: int = 0
) -> SharedDynamicsReplayBuffer:
    """
    A buffer saved by ``save_replay_buffer``, checked against the model's own.

    :param path: the file (``.pkl`` added if missing, as SB3 does)
    :param expected: the model's buffer, whose layout the loaded one must have
    :param verbose: SB3's verbosity
    :return: the buffer
    :raises ValueError: naming the file, when it cannot be read or holds another kind or layout of buffer
    """
    try:
        buffer = load_from_pkl(path, verbose)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError, ValueError) as error:
        raise ValueError(f"cannot read a replay buffer from {path}: {error}") from error
    if not isinstance(buffer, SharedDynamicsReplayBuffer):
        raise ValueError(
            f"{path} holds a {type(buffer).__name__}, not a SharedDynamicsReplayBuffer: "
            "TRLSD loads the buffers its save_replay_buffer wrote"
        )
    layout = ("obs_shape", "n_tasks", "n_envs")
    found = {name: getattr(buffer, name, None) for name in layout}
    wanted = {name: getattr(expected, name) for name in layout}
    if found != wanted or buffer.action_space != expected.action_space:
        raise ValueError(
            f"the buffer in {path} does not fit this model: it has {found} and actions "
            f"{buffer.action_space}, the model {wanted} and actions {expected.action_space}"
        )
    return buffer


class SavesSharedBuffer:
    """
    A mixin of ``TRLSD`` (listed before ``OffPolicyAlgorithm``, whose save and load it extends): SB3's save
    and load of an algorithm whose ``replay_buffer`` is a ``SharedDynamicsReplayBuffer`` and whose
    ``task_learners`` may hold known reward heads.
    Derived state is left out of the zip: ``features``, ``_fit_rows``, ``_warned_unfitted``, and the
    ``reward_fn``.
    """

    replay_buffer: SharedDynamicsReplayBuffer
    _buffer_rows: th.Tensor

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
        cls: type[SelfSaves],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfSaves:
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
