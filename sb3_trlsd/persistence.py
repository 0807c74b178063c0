"""Nothing lost on save and load: the pieces ``TRLSD`` adds to SB3's.

The shared buffer's rows travel in the zip as the "pytorch variable" ``BUFFER_ROWS`` (``TRLSD.load`` puts
them back in the new, empty buffer); ``read_replay_buffer`` checks a buffer from ``save_replay_buffer``
before it replaces the model's.
"""

from __future__ import annotations

import io
import os
import pathlib
import pickle
import zipfile

import torch as th
from stable_baselines3.common.save_util import load_from_pkl

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer

__all__ = ["BUFFER_ROWS", "MODEL_ENTRIES", "check_model_zip", "empty_rows", "read_replay_buffer"]

# The attribute through which the buffer's rows travel in the zip, as one of SB3's "pytorch variables".
BUFFER_ROWS = "_buffer_rows"
# What every zip of ``TRLSD.save`` holds: the settings, the Q-functions, and the buffer's rows.
MODEL_ENTRIES = ("data", "policy.pth", "pytorch_variables.pth")


def empty_rows() -> th.Tensor:
    """The placeholder of ``BUFFER_ROWS`` between a save and a load."""
    return th.zeros(0, dtype=th.float64)


def check_model_zip(path: str | pathlib.Path | io.BufferedIOBase) -> None:
    """
    Refuse a file that is not a whole zip of ``TRLSD.save`` before SB3 reads it (SB3 fails on one with a
    KeyError or an AssertionError that names no file). A path is read as SB3's ``load`` reads it (with
    ``.zip`` added if it is not found as given); a file object is read from where it is, and left there.

    :param path: what ``TRLSD.load`` was given
    :raises ValueError: naming the file, when it is not a zip (cut short, damaged) or lacks one of
        ``MODEL_ENTRIES``
    """
    if isinstance(path, (str, os.PathLike)):
        name = pathlib.Path(path)
        if not name.exists() and pathlib.Path(f"{name}.zip").exists():
            name = pathlib.Path(f"{name}.zip")
        if not name.is_file():
            return  # SB3 raises FileNotFoundError (or IsADirectoryError) naming it
        label = repr(os.fspath(name))
        with open(name, "rb") as file:
            entries = _zip_entries(file, label)
    else:
        label, start = "the file object given", path.tell()
        try:
            entries = _zip_entries(path, label)
        finally:
            path.seek(start)
    missing = [entry for entry in MODEL_ENTRIES if entry not in entries]
    if not entries:
        raise ValueError(f"{label} is not a TRLSD model: its zip is empty; load a file that TRLSD.save wrote")
    if missing:
        raise ValueError(
            f"{label} is not a whole TRLSD model: its zip lacks {missing} (TRLSD.save writes "
            f"{list(MODEL_ENTRIES)}); load a file that TRLSD.save wrote"
        )


def _zip_entries(file: io.BufferedIOBase, label: str) -> set[str]:
    """The names in the zip ``file``, or a ValueError naming it (``label``)."""
    try:
        with zipfile.ZipFile(file) as archive:
            return set(archive.namelist())
    except (zipfile.BadZipFile, EOFError) as error:
        raise ValueError(
            f"{label} is not a TRLSD model: it is not a readable zip, it is empty, cut short or damaged "
            f"({type(error).__name__}: {error}); load a file that TRLSD.save wrote"
        ) from error


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
