"""The source set a ``TRLSD`` model's ``source_transitions`` argument names: collected from the user's env as
given (wrappers kept), or read from a file."""

from __future__ import annotations

import copy
import warnings
from typing import Any

import gymnasium as gym
from stable_baselines3.common.monitor import Monitor

from sb3_trlsd.data import Transitions, collect_transitions

__all__ = ["load_source_once", "source_env_of", "source_transitions_of"]


def source_env_of(model: Any) -> gym.Env:
    """
    The env ``source_transitions=<number>`` collects from: ``model.source_env`` (an env, or a function
    making one), else a copy of the model's env as the user gave it, its wrappers kept (the Monitor SB3 adds
    left out): a deep copy, or where the env cannot be copied, ``gym.make`` of its spec with the wrappers
    it records.

    :param model: a ``TRLSD`` model
    :return: an env the caller may step and close
    :raises ValueError: when neither works, saying to pass ``source_env``
    """
    if model.source_env is not None:
        return (
            model.source_env()
            if callable(model.source_env) and not isinstance(model.source_env, gym.Env)
            else copy.deepcopy(model.source_env)
        )
    if model.env is None:
        raise ValueError("source_transitions=<number> collects them from the model's env: give it one")
    user_env = model.env.envs[0] if hasattr(model.env, "envs") else None
    if isinstance(user_env, Monitor):
        user_env = user_env.env
    if user_env is not None:
        try:
            return copy.deepcopy(user_env)
        except Exception:
            pass
    spec = user_env.spec if user_env is not None else model.env.get_attr("spec", indices=0)[0]
    try:
        if spec is None:
            raise ValueError("the env has no spec")
        return gym.make(spec)
    except Exception as error:
        raise ValueError(
            "source_transitions=<number> collects them from a copy of the env, which could not be made "
            f"({error}): pass source_env=<an env or a function making one>, or the path of a saved .npz"
        ) from error


def source_transitions_of(model: Any) -> Transitions:
    """
    The transitions ``model.source_transitions`` names: that many random transitions from
    ``source_env_of(model)`` (seeded by ``source_seed`` or the model's seed), or the ``.npz`` at that path.

    :param model: a ``TRLSD`` model
    :return: the transitions (their rewards are the env's; the caller decides whether to keep them)
    """
    source = model.source_transitions
    if not isinstance(source, int):
        return Transitions.load(source)
    source_env = source_env_of(model)
    seed = model.source_seed if model.source_seed is not None else model.seed
    try:
        return collect_transitions(source_env, source, seed=seed)
    finally:
        source_env.close()


def load_source_once(model: Any) -> None:
    """
    Before ``learn``: load the source set into the shared buffer the first time (rewards discarded), and
    warn when the buffer is empty although the model learnt before (a model saved without its rows).

    :param model: the model
    """
    if model.source_transitions is not None and not model._source_loaded:
        model.load_transitions(source_transitions_of(model), keep_rewards=False)
        model._source_loaded = True
    learnt_before = model._source_loaded or any(learner.fitted for learner in model.task_learners.values())
    if model.replay_buffer.size() == 0 and learnt_before:
        warnings.warn(
            "the shared buffer is empty although this model has learnt before (a model saved without its "
            "buffer rows): restore it with model.load_replay_buffer(path) (saved by save_replay_buffer) or "
            "model.load_transitions(...) before learn",
            stacklevel=3,
        )
