"""TRLSD's settings: checked at construction, naming the argument, and listed for TensorBoard's HParams."""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd.feature_maps import FEATURE_MAPS, FeatureMap
from sb3_trlsd.observations import state_space_of
from sb3_trlsd.reward_heads import (
    CONFIDENCE_BOUND_HEAD_NAMES,
    REWARD_HEAD_NAMES,
    SIMILARITIES,
    RewardHead,
)
from sb3_trlsd.task_learner import FIRST_FIT_RULES

__all__ = ["check_arguments", "hyperparameters_of", "resolve_policy"]

# The heads TRLSD builds by name: the paper's, and those with other confidence bounds.
HEAD_NAMES = REWARD_HEAD_NAMES + CONFIDENCE_BOUND_HEAD_NAMES
# Settings of the features Phi that belong to TRLSD (which shares Phi between the policy and the heads).
FEATURE_SETTINGS = ("features", "rbf_per_dim", "rbf_sigma", "state_bounds")


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
    if not isinstance(model.reward_head, RewardHead) and model.reward_head not in HEAD_NAMES:
        raise ValueError(
            f"reward_head must be one of {list(HEAD_NAMES)} or a RewardHead instance, "
            f"got {model.reward_head!r}"
        )

    def finite(name: str) -> float:
        value = getattr(model, name)
        _require(_is_number(value) and math.isfinite(value), name, "a finite number", value)
        return float(value)

    def widths(name: str, meaning: str) -> None:
        value = getattr(model, name)
        array = np.asarray(value if value is not None else 1.0)
        ok = array.dtype.kind in "fiu" and array.ndim <= 1 and array.size and np.all(np.isfinite(array))
        _require(
            bool(ok) and np.all(array > 0),
            name,
            f"None or a width > 0 (or one per dimension): {meaning}",
            value,
        )

    _require(finite("kappa") >= 0, "kappa", ">= 0 (0 is the non-optimistic method)", model.kappa)
    widths("sigma", "the similarity's, a fraction of the state box")
    widths("rbf_sigma", "the features', a fraction of the state box")
    if model.feature_map not in FEATURE_MAPS and not isinstance(model.feature_map, FeatureMap):
        raise ValueError(
            f"feature_map must be one of {list(FEATURE_MAPS)} or a FeatureMap, got {model.feature_map!r}"
        )

    def integer(name: str, minimum: int, none_allowed: bool = False) -> None:
        value = getattr(model, name)
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= minimum
        meaning = f"an integer >= {minimum}" + (" or None" if none_allowed else "")
        _require(ok or (none_allowed and value is None), name, meaning, value)

    integer("fourier_features", 1, none_allowed=True)
    _require(
        finite("update_ratio") > 1,
        "update_ratio",
        "> 1 (the CI must shrink to trigger a refit)",
        model.update_ratio,
    )
    _require(0 < finite("gamma") < 1, "gamma", "in (0, 1)", model.gamma)
    _require(finite("fqi_tol") >= 0, "fqi_tol", ">= 0 (a relative tolerance)", model.fqi_tol)
    integer("rbf_per_dim", 1)
    integer("fqi_max_iterations", 1, none_allowed=True)
    if model.similarity not in SIMILARITIES:
        raise ValueError(f"similarity must be 'state' or 'features', got {model.similarity!r}")
    if model.reward_head == "bernstein" and model.similarity != "state":
        raise ValueError(
            f"similarity must be 'state' with reward_head='bernstein' (its weights are eq. 6's), "
            f"got {model.similarity!r}"
        )
    if model.first_fit not in FIRST_FIT_RULES:
        raise ValueError(
            f"first_fit must be one of {list(FIRST_FIT_RULES)} (when a task's Q is first fitted), "
            f"got {model.first_fit!r}"
        )
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
    integer("log_picture_every", 0)
    shadowed = sorted(set(model.policy_kwargs or {}) & set(FEATURE_SETTINGS))
    if shadowed:
        raise ValueError(
            f"policy_kwargs may not set {shadowed}: the features are TRLSD's, shared by the policy and the "
            "reward heads; give feature_map, rbf_per_dim, rbf_sigma or state_bounds to TRLSD(...) instead"
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
        "first_fit": model.first_fit,
        "fqi_max_iterations": model.fqi_max_iterations,
        "fqi_tol": model.fqi_tol,
        "feature_map": model.feature_map
        if isinstance(model.feature_map, str)
        else type(model.feature_map).__name__,
        "n_features": getattr(model.features, "n_features", 0),
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
