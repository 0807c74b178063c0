"""The source set a ``TRLSD`` model's ``source_transitions`` argument names: collected from the user's env as
given (wrappers kept), or read from a file or a local Minari dataset."""

from __future__ import annotations

import copy
import os
from collections.abc import Callable

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

from sb3_trlsd.data import Transitions, collect_transitions
from sb3_trlsd.foreign_data import read_rows

__all__ = ["SourceEnv", "check_source_transitions", "source_env_of", "source_transitions_of"]

SourceEnv = gym.Env | Callable[[], gym.Env]
SourceSpec = int | str | os.PathLike


def check_source_transitions(source: SourceSpec | None) -> None:
    """
    Reject a ``source_transitions`` setting that is not None, a number >= 1, a path or a Minari dataset id,
    naming it.

    :raises ValueError: for any other value
    """
    ok = not isinstance(source, bool) and (
        source is None
        or isinstance(source, (str, os.PathLike))
        or (isinstance(source, (int, np.integer)) and source >= 1)
    )
    if not ok:
        raise ValueError(
            "source_transitions must be None, a number >= 1, the path of a Transitions .npz or of a "
            f"save_replay_buffer .pkl, or the id of a local Minari dataset, got {source!r}"
        )


def source_env_of(source_env: SourceEnv | None, env: VecEnv | None) -> gym.Env:
    """
    The env ``source_transitions=<number>`` collects from: ``source_env`` (an env, or a function making
    one), else a copy of the model's env as the user gave it, its wrappers kept (the Monitor SB3 adds left
    out): a deep copy, or where the env cannot be copied, ``gym.make`` of its spec with the wrappers it
    records.

    :param source_env: the model's ``source_env`` setting
    :param env: the model's (vectorised) env
    :return: an env the caller may step and close
    :raises ValueError: when neither works, saying to pass ``source_env``
    """
    if source_env is not None:
        if callable(source_env) and not isinstance(source_env, gym.Env):
            return source_env()
        return copy.deepcopy(source_env)
    if env is None:
        raise ValueError("source_transitions=<number> collects them from the model's env: give it one")
    user_env = env.envs[0] if hasattr(env, "envs") else None
    if isinstance(user_env, Monitor):
        user_env = user_env.env
    if user_env is not None:
        try:
            return copy.deepcopy(user_env)
        except Exception:
            pass
    spec = user_env.spec if user_env is not None else env.get_attr("spec", indices=0)[0]
    try:
        if spec is None:
            raise ValueError("the env has no spec")
        return gym.make(spec)
    except Exception as error:
        raise ValueError(
            "source_transitions=<number> collects them from a copy of the env, which could not be made "
            f"({error}): pass source_env=<an env or a function making one>, or the path of a saved .npz"
        ) from error


def source_transitions_of(
    source: SourceSpec, source_env: SourceEnv | None, env: VecEnv | None, seed: int | None
) -> Transitions:
    """
    The transitions a ``source_transitions`` setting names: that many random transitions from
    ``source_env_of(source_env, env)``, or those of the file at that path (a ``Transitions`` ``.npz``, a
    ``save_replay_buffer`` ``.pkl``, which is unpickled) or of the local Minari dataset of that id. Their
    rewards are not learnt (the caller discards them), so their tasks, which rows of Box observations do not
    have, are not asked for.

    :param source: the setting: a number of transitions, a path or a Minari dataset id
    :param source_env: the model's ``source_env`` setting
    :param env: the model's (vectorised) env
    :param seed: the seed of the collection
    :return: the transitions (their rewards are the env's; the caller decides whether to keep them)
    """
    if not isinstance(source, (int, np.integer)):
        return read_rows(source).transitions
    collecting = source_env_of(source_env, env)
    try:
        return collect_transitions(collecting, int(source), seed=seed)
    finally:
        collecting.close()
