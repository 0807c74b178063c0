"""Nothing lost on save and load: the pieces ``TRLSD`` adds to SB3's.

The shared buffer's rows travel in the zip as the "pytorch variable" ``BUFFER_ROWS`` (``TRLSD.load`` puts
them back in the new, empty buffer); ``read_replay_buffer`` checks a buffer from ``save_replay_buffer``
before it replaces the model's.
"""

from __future__ import annotations

import io
import pathlib
import pickle

import torch as th
from stable_baselines3.common.save_util import load_from_pkl

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer

__all__ = ["BUFFER_ROWS", "empty_rows", "read_replay_buffer"]

# The attribute through which the buffer's rows travel in the zip, as one of SB3's "pytorch variables".
BUFFER_ROWS = "_buffer_rows"


def empty_rows() -> th.Tensor:
    """The placeholder of ``BUFFER_ROWS`` between a save and a load."""
    return th.zeros(0, dtype=th.float64)


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
