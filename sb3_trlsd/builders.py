"""What TRLSD's settings build: the state box, the shared feature map, and each task's reward head.

Features and similarities see states in normalised coordinates, the state box mapped to the unit cube:
``sigma`` and ``rbf_sigma`` are fractions of the box (per dimension if wanted), so the defaults do not
depend on an env's units and a scaled copy of an env learns as the original. On the paper's maze,
(0, 5)^2, the defaults are its sigma = 0.2 and RBF width 0.2, exactly.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd.feature_maps import FeatureMap, default_kernel_width, make_feature_map
from sb3_trlsd.observations import state_space_of, task_count_of
from sb3_trlsd.policies import LinearPolicy
from sb3_trlsd.reward_heads import RewardFn, RewardHead, make_reward_head
from sb3_trlsd.task_learner import TaskLearner

__all__ = [
    "FEATURE_HEAD_NAMES",
    "head_seed",
    "known_reward_fn",
    "new_reward_head",
    "new_task_learner",
    "shared_features",
    "similarity_width",
    "state_box",
]

FEATURES_SIMILARITY_SIGMA = 0.2  # eq. 7 compares feature vectors, whose scale is the features' own
# The named heads that regress the reward on Phi, and so need the shared feature map (and hold a Gram matrix).
FEATURE_HEAD_NAMES = ("ridge", "ridge_posterior", "thompson")
# The named heads whose similarity is eq. 6 on states or eq. 7 on features, of width ``sigma``.
SIMILARITY_HEAD_NAMES = ("ridge", "bernstein")


def state_box(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """
    The box [low, high] normalised coordinates are taken in: ``model.state_bounds`` if given, else the
    state Box's bounds, which must then be finite.

    :param model: a ``TRLSD`` model with its spaces
    :return: low and high, (d,) float64
    :raises ValueError: naming the unbounded dimensions and how to bound them
    """
    space = state_space_of(model.observation_space)
    if model.state_bounds is not None:
        low, high = (np.asarray(bound, dtype=np.float64) for bound in model.state_bounds)
        if (
            low.shape != space.shape
            or high.shape != space.shape
            or not np.all(np.isfinite(low) & np.isfinite(high))
        ):
            raise ValueError(
                f"state_bounds must be (low, high), finite, of shape {space.shape} each, "
                f"got {model.state_bounds!r}"
            )
        if not np.all(low < high):
            raise ValueError(
                f"state_bounds must have low < high in every dimension, got {model.state_bounds!r}"
            )
        return low, high
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    unbounded = np.flatnonzero(~(np.isfinite(low) & np.isfinite(high)))
    if len(unbounded):
        raise ValueError(
            f"the state Box is unbounded in dimension(s) {unbounded.tolist()} (low {low[unbounded]}, high "
            f"{high[unbounded]}), and TRLSD's features and similarities are taken relative to the box: give "
            "TRLSD(state_bounds=(low, high)) with the range the states really take, or wrap the env so "
            "that its observation space is finite (gymnasium.wrappers.TransformObservation with np.clip and "
            "a bounded Box, then RescaleObservation if wanted)"
        )
    return low, high


def similarity_width(model: Any, low: np.ndarray, high: np.ndarray) -> float | np.ndarray:
    """
    The width of the similarity of the ridge (and Bernstein) heads in the units it compares: for eq. 6
    (``"state"``) ``sigma`` (default ``default_kernel_width(d)``, 0.04 in 2-D) times the box's size per
    dimension; for eq. 7 (``"features"``) ``sigma`` as given (default 0.2).
    """
    if model.similarity == "features":
        return FEATURES_SIMILARITY_SIGMA if model.sigma is None else float(model.sigma)
    sigma = (
        default_kernel_width(len(low)) if model.sigma is None else np.asarray(model.sigma, dtype=np.float64)
    )
    return sigma * (high - low)


def shared_features(model: Any) -> FeatureMap | None:
    """
    The feature map Phi of ``model``, built once over its state box and shared by the linear policy and the
    heads of ``FEATURE_HEAD_NAMES`` (None when neither uses features): its own ``feature_map`` instance, or
    one by name.

    :param model: a ``TRLSD`` model with its spaces
    """
    uses_features = model.reward_head in FEATURE_HEAD_NAMES
    if not (issubclass(model.policy_class, LinearPolicy) or uses_features):
        return None
    if isinstance(model.feature_map, FeatureMap):
        return model.feature_map
    low, high = state_box(model)
    assert isinstance(model.action_space, spaces.Discrete)
    return make_feature_map(
        model.feature_map,
        low,
        high,
        rbf_per_dim=model.rbf_per_dim,
        rbf_sigma=model.rbf_sigma,
        fourier_features=model.fourier_features,
        seed=0 if model.seed is None else model.seed,
        n_actions=int(model.action_space.n),
        n_tasks=task_count_of(model.observation_space) if uses_features else 0,
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


def head_seed(seed: int | None, task: int) -> int | None:
    """
    The seed of a named ``"thompson"`` head's draws: one per run and task, derived from the run's seed so that
    every task of every run draws its own normals, reproducibly (None, fresh entropy, without a seed).

    :param seed: the run's seed (a model's ``seed``)
    :param task: the task
    :return: an integer >= 0, or None
    """
    if seed is None:
        return None
    return int(np.random.SeedSequence([int(seed) % 2**64, int(task), 3]).generate_state(1)[0])


def new_reward_head(model: Any, task: int, seed: int | None = None) -> RewardHead:
    """
    A reward head for ``task`` with no samples, as the model's settings say: a copy of the model's
    ``RewardHead`` instance, or the named head with kappa, the shared features, the similarity's width (the
    heads of ``SIMILARITY_HEAD_NAMES``) and the head kwargs; a ``"thompson"`` head draws from ``head_seed``
    unless the head kwargs give its ``seed``.

    :param model: the model
    :param task: the task
    :param seed: the run's seed, that of a ``"thompson"`` head's draws (None: the model's ``seed``)
    :return: the head
    """
    if isinstance(model.reward_head, RewardHead):
        return copy.deepcopy(model.reward_head)
    kwargs = dict(model.reward_head_kwargs)
    if model.reward_head == "known":
        return make_reward_head("known", task=task, reward_fn=known_reward_fn(model), **kwargs)
    if model.reward_head == "thompson":
        kwargs.setdefault("seed", head_seed(model.seed if seed is None else seed, task))
    low, high = state_box(model)
    return make_reward_head(
        model.reward_head,
        task=task,
        features=model.features,
        state_space=spaces.Box(low, high, dtype=np.float64),
        kappa=model.kappa,
        sigma=similarity_width(model, low, high) if model.reward_head in SIMILARITY_HEAD_NAMES else 0.2,
        similarity=model.similarity,
        **kwargs,
    )


def new_task_learner(model: Any, task: int, seed: int | None = None) -> TaskLearner:
    """
    The learning state of ``task`` with no samples, as the model's settings say: its reward head
    (``new_reward_head``), the model's ``update_ratio`` and ``first_fit``.

    :param model: the model
    :param task: the task
    :param seed: the run's seed (None: the model's), see ``new_reward_head``
    :return: the learner
    """
    return TaskLearner(
        task, new_reward_head(model, task, seed), model.update_ratio, first_fit=model.first_fit
    )
