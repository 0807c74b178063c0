"""TRLSD's settings: checked at construction (naming the argument), and the reward heads they build."""

from __future__ import annotations

import copy
import math
import os
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd.features import RBFGrid
from sb3_trlsd.observations import state_space_of
from sb3_trlsd.policies import LinearPolicy
from sb3_trlsd.reward_heads import REWARD_HEAD_NAMES, SIMILARITIES, RewardFn, RewardHead, make_reward_head

__all__ = [
    "check_arguments",
    "hyperparameters_of",
    "known_reward_fn",
    "new_reward_head",
    "resolve_policy",
    "shared_features",
]

# Settings of the features Phi that belong to TRLSD (which shares Phi between the policy and the heads).
FEATURE_SETTINGS = ("features", "rbf_per_dim", "rbf_sigma")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _require(condition: bool, name: str, meaning: str, value: Any) -> None:
    if not condition:
        raise ValueError(f"{name} must be {meaning}, got {value!r}")


def check_arguments(model: Any) -> None:
    """
    Reject bad settings of ``model``, naming the argument (NaN and infinite values included).

    :raises ValueError: for the first bad setting found
    """
    # load() builds the model without an env first: the spaces are checked once they are known.
    action_space = getattr(model, "action_space", None)
    if action_space is not None and not isinstance(action_space, spaces.Discrete):
        raise ValueError(f"TRLSD needs a Discrete action space (env), got {action_space}")
    observation_space = getattr(model, "observation_space", None)
    if observation_space is not None:
        state_space_of(observation_space)
    if not isinstance(model.reward_head, RewardHead) and model.reward_head not in REWARD_HEAD_NAMES:
        raise ValueError(
            f"reward_head must be one of {sorted(REWARD_HEAD_NAMES)} or a RewardHead instance, "
            f"got {model.reward_head!r}"
        )

    def finite(name: str) -> float:
        value = getattr(model, name)
        _require(_is_number(value) and math.isfinite(value), name, "a finite number", value)
        return float(value)

    _require(finite("kappa") >= 0, "kappa", ">= 0 (0 is the non-optimistic method)", model.kappa)
    _require(finite("sigma") > 0, "sigma", "> 0 (the width of the similarity)", model.sigma)
    _require(
        finite("update_ratio") > 1,
        "update_ratio",
        "> 1 (the CI must shrink to trigger a refit)",
        model.update_ratio,
    )
    _require(0 < finite("gamma") < 1, "gamma", "in (0, 1)", model.gamma)
    _require(finite("fqi_tol") >= 0, "fqi_tol", ">= 0 (a relative tolerance)", model.fqi_tol)
    _require(finite("rbf_sigma") > 0, "rbf_sigma", "> 0 (the width of the RBF features)", model.rbf_sigma)
    _require(
        isinstance(model.rbf_per_dim, (int, np.integer)) and model.rbf_per_dim >= 1,
        "rbf_per_dim",
        "an integer >= 1",
        model.rbf_per_dim,
    )
    iterations = model.fqi_max_iterations
    _require(
        iterations is None or (isinstance(iterations, (int, np.integer)) and iterations >= 1),
        "fqi_max_iterations",
        "an integer >= 1 or None",
        iterations,
    )
    if model.similarity not in SIMILARITIES:
        raise ValueError(f"similarity must be 'state' or 'features', got {model.similarity!r}")
    source = model.source_transitions
    _require(
        not isinstance(source, bool)
        and (
            source is None
            or isinstance(source, (str, os.PathLike))
            or (isinstance(source, (int, np.integer)) and source >= 1)
        ),
        "source_transitions",
        "None, a number >= 1 or the path of a .npz",
        source,
    )
    _require(
        isinstance(model.log_picture_every, (int, np.integer)) and model.log_picture_every >= 0,
        "log_picture_every",
        "an integer >= 0",
        model.log_picture_every,
    )
    shadowed = sorted(set(model.policy_kwargs or {}) & set(FEATURE_SETTINGS))
    if shadowed:
        raise ValueError(
            f"policy_kwargs may not set {shadowed}: the features are TRLSD's, shared by the policy and the "
            "reward heads; give rbf_per_dim and rbf_sigma to TRLSD(...) instead"
        )


class _SingleTaskReward:
    """A Box-observation env's ``expected_reward(states)`` seen as ``reward_fn(states, task)`` (one task)."""

    def __init__(self, expected_reward: Any):
        self.expected_reward = expected_reward

    def __call__(self, states: np.ndarray, task: int) -> np.ndarray:
        return self.expected_reward(states)


def known_reward_fn(model: Any, required: bool = True) -> RewardFn | None:
    """
    The expected reward the ``"known"`` head uses: the model's ``reward_fn``, or else the env's
    ``expected_reward(states, task)`` (``expected_reward(states)`` for a single-task Box observation).

    :param model: the model
    :param required: raise when there is none (else return None)
    :return: ``reward_fn(states, task) -> (n,)``
    """
    if model.reward_fn is not None:
        return model.reward_fn
    env = model.env
    if env is not None and env.has_attr("expected_reward"):
        method = env.get_attr("expected_reward", indices=0)[0]
        return method if isinstance(model.observation_space, spaces.Dict) else _SingleTaskReward(method)
    if required:
        raise ValueError(
            "the 'known' reward_head needs reward_fn=reward_fn(states, task) -> expected rewards (n,), "
            "or an env whose unwrapped object has expected_reward(states, task)"
        )
    return None


def new_reward_head(model: Any, task: int) -> RewardHead:
    """
    A reward head for ``task`` with no samples, as the model's settings say: a copy of the model's
    ``RewardHead`` instance, or the named head with kappa, sigma, the shared features and the head kwargs.

    :param model: the model
    :param task: the task
    :return: the head
    """
    if isinstance(model.reward_head, RewardHead):
        return copy.deepcopy(model.reward_head)
    return make_reward_head(
        model.reward_head,
        task=task,
        features=model.features,
        state_space=state_space_of(model.observation_space),
        kappa=model.kappa,
        sigma=model.sigma,
        similarity=model.similarity,
        reward_fn=known_reward_fn(model) if model.reward_head == "known" else None,
        **model.reward_head_kwargs,
    )


def hyperparameters_of(model: Any) -> dict[str, int | float | str | bool]:
    """The settings of ``model``, as TensorBoard's HParams tab shows them (numbers, or their text)."""
    head = model.reward_head if isinstance(model.reward_head, str) else type(model.reward_head).__name__
    settings = {
        "algorithm": type(model).__name__,
        "policy": model.policy_class.__name__,
        "gamma": model.gamma,
        "reward_head": head,
        "kappa": model.kappa,
        "sigma": model.sigma,
        "similarity": model.similarity,
        "update_ratio": model.update_ratio,
        "fqi_max_iterations": model.fqi_max_iterations,
        "fqi_tol": model.fqi_tol,
        "rbf_per_dim": model.rbf_per_dim,
        "rbf_sigma": model.rbf_sigma,
        "source_transitions": model.source_transitions,
        "seed": model.seed,
    }
    return {
        key: value if isinstance(value, (int, float, bool)) else str(value) for key, value in settings.items()
    }


def resolve_policy(policy: Any, aliases: dict[str, type]) -> type:
    """
    The policy class of ``policy``: a class as it is, or the class of a name among ``aliases``.

    :raises ValueError: for an unknown name
    """
    if not isinstance(policy, str):
        return policy
    if policy not in aliases:
        raise ValueError(f"policy must be one of {sorted(aliases)} or a policy class, got {policy!r}")
    return aliases[policy]


def shared_features(model: Any) -> RBFGrid | None:
    """
    The feature map Phi of ``model``, built once from its ``rbf_per_dim`` and ``rbf_sigma`` over the state
    Box and shared by the linear policy and the ridge heads; None when neither uses features.

    :param model: a ``TRLSD`` model with its spaces
    """
    if not (issubclass(model.policy_class, LinearPolicy) or model.reward_head == "ridge"):
        return None
    return RBFGrid.for_box(state_space_of(model.observation_space), model.rbf_per_dim, model.rbf_sigma)
