"""The source set a ``TRLSD`` model's ``source_transitions`` argument names, collected or read."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import gymnasium as gym

from sb3_trlsd.data import Transitions, collect_transitions

__all__ = ["load_source_once", "source_transitions_of"]


def source_transitions_of(model: Any) -> Transitions:
    """
    The transitions ``model.source_transitions`` names: that many random transitions from a copy of the
    model's env (``gym.make`` of its spec, seeded by ``source_seed`` or the model's seed), or the ``.npz``
    file at that path.

    :param model: the model
    :return: the transitions (their rewards are the env's; the caller decides whether to keep them)
    """
    source = model.source_transitions
    if not isinstance(source, int):
        return Transitions.load(source)
    if model.env is None:
        raise ValueError("source_transitions=<number> collects them from the model's env: give it one")
    spec = model.env.get_attr("spec", indices=0)[0]
    if spec is None:
        raise ValueError(
            "source_transitions=<number> collects them from a copy of the env made with gym.make, "
            "but this env has no spec: pass the path of a saved .npz instead"
        )
    # The spec without the wrappers added after gym.make (SB3's Monitor cannot be recreated).
    source_env = gym.make(dataclasses.replace(spec, additional_wrappers=()))
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
