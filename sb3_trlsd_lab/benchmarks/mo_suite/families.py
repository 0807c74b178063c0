"""
Multi-objective Gymnasium environments (MO-Gymnasium) as TRLSD task families.

An MO-Gymnasium env pays a reward vector r_vec; a weight vector w makes it the task whose scalar reward is
w . r_vec, and every task shares the env's dynamics. A family here is one such env with seeded weight
vectors split into three disjoint sets: the SOURCE weights, under which a random policy collects the
source transitions, the TUNING target weights (kept apart for choosing settings), and the held-out
EVALUATION target weights the suite scores on. ``ScalarisedTasks`` shows the env as TRLSD wants it:
``{"state": Box, "task": Discrete(n_tasks)}`` observations (integers where the env's are), tasks ordered
source, tuning, evaluation, and the reward w_task . r_vec (the vector in ``info["vector_reward"]``).

The weights are drawn uniformly on the simplex (a Dirichlet(1, ..., 1) draw), so each objective's weight is
in [0, 1] and the weights add up to 1: a component the env pays as a cost (fuel, time, damage) stays a
cost under every task.
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_trlsd.data import Transitions

__all__ = [
    "FAMILIES",
    "Family",
    "ScalarisedTasks",
    "SourceSet",
    "WeightSplit",
    "collect_source",
    "family_named",
    "family_weights",
    "make_env",
    "reward_bound",
]

SPLITS = ("source", "tuning", "evaluation")


@dataclass(frozen=True)
class Family:
    """
    One MO-Gymnasium env as a task family, with its budget.

    :param name: the suite's name of the family (the env's id)
    :param env_id: MO-Gymnasium's id of the env
    :param episode_steps: the time limit of an episode (the env's registered one)
    :param state_low: lower corner of the range the states really take, given to TRLSD (and to the
        relabelling buffer) as ``state_bounds``; None: the env's own Box
    :param state_high: its upper corner
    :param bounds_note: why the bounds are given (None: the env's Box is used as it is)
    :param n_source: random source transitions, split evenly over the source weights
    :param n_online: online transitions on the target task
    :param n_source_weights: weight vectors the source transitions are collected under
    :param n_tuning_weights: target weight vectors kept for tuning
    :param n_evaluation_weights: held-out target weight vectors the suite scores on
    :param weight_seed: seed of the weight vectors
    :param requires: the module the env needs beyond MO-Gymnasium (None: none)
    """

    name: str
    env_id: str
    episode_steps: int
    state_low: tuple[float, ...] | None = None
    state_high: tuple[float, ...] | None = None
    bounds_note: str | None = None
    n_source: int = 20_000
    n_online: int = 1_000
    n_source_weights: int = 4
    n_tuning_weights: int = 4
    n_evaluation_weights: int = 10
    weight_seed: int = 0
    requires: str | None = None

    @property
    def n_tasks(self) -> int:
        """Tasks of the family's env: its source, tuning and evaluation weights."""
        return self.n_source_weights + self.n_tuning_weights + self.n_evaluation_weights

    @property
    def state_bounds(self) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """``(low, high)`` for TRLSD's ``state_bounds``, or None to use the env's Box."""
        if self.state_low is None or self.state_high is None:
            return None
        return self.state_low, self.state_high

    def tasks_of(self, split: str) -> np.ndarray:
        """
        The task indices of a split of the weights.

        :param split: ``"source"``, ``"tuning"`` or ``"evaluation"``
        """
        if split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        sizes = [self.n_source_weights, self.n_tuning_weights, self.n_evaluation_weights]
        start = sum(sizes[: SPLITS.index(split)])
        return np.arange(start, start + sizes[SPLITS.index(split)])

    def parameters(self) -> dict[str, Any]:
        """The family as a JSON-friendly dict."""
        return {
            "env_id": self.env_id,
            "episode_steps": self.episode_steps,
            "state_bounds": None if self.state_bounds is None else [list(b) for b in self.state_bounds],
            "bounds_note": self.bounds_note,
            "source_transitions": self.n_source,
            "online_transitions": self.n_online,
            "weights": {split: family_weights(self)[self.tasks_of(split)].tolist() for split in SPLITS},
        }


# Integer grid observations are given their cells' real range: the envs declare looser boxes (a flag in
# 0..13 on the four rooms) and TRLSD's features are fractions of the box.
FAMILIES: dict[str, Family] = {
    family.name: family
    for family in (
        Family(
            "four-room-v0",
            "four-room-v0",
            episode_steps=200,
            state_low=(0.0,) * 14,
            state_high=(12.0, 12.0) + (1.0,) * 12,
            bounds_note="(row, col) in 0..12 and 12 collected flags in {0, 1} (the env: 0..13)",
        ),
        Family("minecart-v0", "minecart-v0", episode_steps=1_000),
        Family(
            "resource-gathering-v0",
            "resource-gathering-v0",
            episode_steps=100,
            state_low=(0.0, 0.0, 0.0, 0.0),
            state_high=(4.0, 4.0, 1.0, 1.0),
            bounds_note="(row, col) in 0..4, gold and gem carried in {0, 1}; the env declares 0..5 for all",
        ),
        Family(
            "deep-sea-treasure-v0",
            "deep-sea-treasure-v0",
            episode_steps=100,
            state_low=(0.0, 0.0),
            state_high=(10.0, 10.0),
            bounds_note="(row, col) in 0..10; the env declares 0..11",
        ),
        Family("mo-mountaincar-v0", "mo-mountaincar-v0", episode_steps=200),
        Family(
            "mo-reacher-v5",
            "mo-reacher-v5",
            episode_steps=50,
            state_low=(-1.0, -1.0, -1.0, -1.0, -5.0, -3.5),
            state_high=(1.0, 1.0, 1.0, 1.0, 5.0, 3.5),
            bounds_note="cos and sin of the two joints in [-1, 1]; the joint speeds (x 0.1) are unbounded: "
            "the bounds hold all but 0.03% of the suite's 20 random sources' steps, which reach "
            "[-7.1, 5.8] and [-3.9, 3.8] (a run warns once of the states outside)",
            requires="mujoco",
        ),
    )
}


def family_named(name: str) -> Family:
    """
    The family of the suite called ``name``.

    :raises ValueError: naming the families
    """
    if name not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {name!r}")
    return FAMILIES[name]


def available(family: Family) -> bool:
    """Whether the family's env can be made here (MO-Gymnasium and the module it needs import)."""
    for module in ("mo_gymnasium", family.requires):
        if module is None:
            continue
        try:
            importlib.import_module(module)
        except ImportError:
            return False
    return True


@dataclass(frozen=True)
class WeightSplit:
    """The weight vectors of a family, by split: (n, k) each, k the env's objectives."""

    source: np.ndarray
    tuning: np.ndarray
    evaluation: np.ndarray


def simplex_weights(n: int, k: int, seed: int) -> np.ndarray:
    """
    ``n`` weight vectors drawn uniformly on the simplex of dimension ``k`` (Dirichlet(1, ..., 1)).

    :return: (n, k), each row non-negative and adding up to 1
    """
    return np.random.default_rng(seed).dirichlet(np.ones(k), size=n)


@functools.cache
def reward_dimension(family: Family) -> int:
    """k, the length of the env's reward vector."""
    return int(np.prod(_reward_space(_mo_env(family)).shape))


def family_weights(family: Family) -> np.ndarray:
    """
    Every task's weight vector, (n_tasks, k): the source, then tuning, then evaluation weights (see
    ``Family.tasks_of``), drawn at once with the family's seed, so the three sets never share a vector.
    """
    return simplex_weights(family.n_tasks, reward_dimension(family), family.weight_seed)


def weight_split(family: Family) -> WeightSplit:
    """The family's weights by split."""
    weights = family_weights(family)
    return WeightSplit(*(weights[family.tasks_of(split)] for split in SPLITS))


def reward_bound(reward_space: spaces.Box, weights: np.ndarray) -> float:
    """
    The largest scalar reward w . r_vec over the box of reward vectors, for a weight vector w.

    :param reward_space: the env's Box of reward vectors
    :param weights: w, (k,)
    """
    low, high = np.asarray(reward_space.low, np.float64), np.asarray(reward_space.high, np.float64)
    return float(np.sum(np.maximum(weights * low, weights * high)))


def _mo_env(family: Family) -> gym.Env:
    import mo_gymnasium

    return mo_gymnasium.make(family.env_id, max_episode_steps=family.episode_steps)


def _reward_space(env: gym.Env) -> spaces.Box:
    """The space of an MO-Gymnasium env's reward vector."""
    space = getattr(env.unwrapped, "reward_space", None)
    if not isinstance(space, spaces.Box):
        raise ValueError(
            f"expected an MO-Gymnasium env with a Box reward_space, got {type(env.unwrapped).__name__}"
        )
    return space


def scalarised_tasks(env: gym.Env) -> ScalarisedTasks:
    """The ``ScalarisedTasks`` under ``env``'s wrappers (a ValueError for any other env)."""
    if not isinstance(env.unwrapped, ScalarisedTasks):
        raise ValueError(f"expected ScalarisedTasks under the wrappers, got {type(env.unwrapped).__name__}")
    return env.unwrapped


class ScalarisedTasks(gym.Env):
    """
    ## Description
    An MO-Gymnasium env seen as a family of tasks sharing its dynamics: task i pays w_i . r_vec.

    ## Action Space
    The env's Discrete actions.

    ## Observation Space
    ``{"state": Box, "task": Discrete(n_tasks)}``: the env's observation in the env's own Box, as integers
    where the env's Box is of integers (a grid's cells, which ``TRLSD``'s default features read), else as
    float64, and the task being solved.

    ## Starting State
    The env's.

    ## Rewards
    ``weights[task] @ r_vec``; ``info["vector_reward"]`` holds r_vec.

    ## Episode End
    The env's termination, and its time limit (a truncation).

    ## Arguments
    :param env: the MO-Gymnasium env, with its time limit
    :param weights: one weight vector per task, (n_tasks, k)
    :param task: the task to solve, an index into ``weights``
    """

    metadata = {"render_modes": []}

    def __init__(self, env: gym.Env, weights: np.ndarray, task: int = 0) -> None:
        weights = np.asarray(weights, dtype=np.float64)
        reward_space = _reward_space(env)
        if weights.ndim != 2 or weights.shape[1] != int(np.prod(reward_space.shape)):
            raise ValueError(
                f"weights must be (n_tasks, {int(np.prod(reward_space.shape))}), got shape {weights.shape}"
            )
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"the env's actions must be Discrete, got {env.action_space}")
        box = env.observation_space
        if not isinstance(box, spaces.Box):
            raise ValueError(f"the env's observations must be a Box, got {box}")
        self.env = env
        self.weights = weights
        self.reward_space = reward_space
        dtype = box.dtype if np.issubdtype(box.dtype, np.integer) else np.dtype(np.float64)
        self.state_dtype = dtype
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(box.low.astype(dtype), box.high.astype(dtype), dtype=dtype),
                "task": spaces.Discrete(len(weights)),
            }
        )
        self.action_space: spaces.Discrete = env.action_space
        self.task = 0
        self.set_task(task)

    def set_task(self, task: int) -> None:
        """Solve ``task`` from the next step on."""
        if not 0 <= int(task) < len(self.weights):
            raise ValueError(f"task must be in 0..{len(self.weights) - 1}, got {task}")
        self.task = int(task)

    def _observation(self, state: np.ndarray) -> dict[str, Any]:
        return {"state": np.asarray(state, dtype=self.state_dtype), "task": self.task}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Reset the env (seeded with ``seed``)."""
        super().reset(seed=seed)
        state, info = self.env.reset(seed=seed, options=options)
        return self._observation(state), info

    def step(self, action: int) -> tuple[dict[str, Any], SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env; the reward is the task's scalarisation of its reward vector."""
        state, vector, terminated, truncated, info = self.env.step(int(action))
        vector = np.asarray(vector, dtype=np.float64)
        info = {**info, "vector_reward": vector}
        reward = float(self.weights[self.task] @ vector)
        return self._observation(state), reward, bool(terminated), bool(truncated), info

    def close(self) -> None:
        """Close the env."""
        self.env.close()


def make_env(family: Family, task: int) -> ScalarisedTasks:
    """
    The family's env solving ``task`` (an index of ``family_weights``), with the family's time limit.

    :param family: the family
    :param task: the task
    """
    return ScalarisedTasks(_mo_env(family), family_weights(family), task)


@dataclass(frozen=True)
class SourceSet:
    """
    Source transitions with the reward vectors the env paid for them.

    :param transitions: the transitions, rewards scalarised by their source task's weights
    :param vector_rewards: r_vec of each transition, (n, k)
    :param dqn_parameters: the parameters of the DQN that collected them (a trained source), None for a
        random policy's
    """

    transitions: Transitions
    vector_rewards: np.ndarray
    dqn_parameters: dict[str, np.ndarray] | None = None


def collect_source(family: Family, n: int, seed: int) -> SourceSet:
    """
    ``n`` transitions of a uniformly random policy, split evenly over the source weights: each source task
    collects its share in episodes of its own, the first reset of each seeded from ``seed``.

    :param family: the family
    :param n: transitions
    :param seed: seed of the resets and of the random actions
    :return: the transitions, tasks in ``family.tasks_of("source")``
    """
    tasks = family.tasks_of("source")
    shares = np.diff(np.linspace(0, n, len(tasks) + 1).round().astype(int))
    rng = np.random.default_rng(seed)
    env = make_env(family, int(tasks[0]))
    columns: dict[str, list[Any]] = {name: [] for name in ("s", "a", "s2", "r", "tau", "trunc", "term", "v")}
    for task, share in zip(tasks, shares, strict=True):
        env.set_task(int(task))
        obs, _ = env.reset(seed=int(rng.integers(2**31)))
        for step in range(share):
            action = int(rng.integers(env.action_space.n))
            next_obs, reward, terminated, truncated, info = env.step(action)
            truncated = truncated or step == share - 1  # the share ends: a reset, not an absorbing state
            for name, value in zip(
                columns,
                (obs["state"], action, next_obs["state"], reward, task, truncated, terminated),
                strict=False,
            ):
                columns[name].append(value)
            columns["v"].append(info["vector_reward"])
            obs = env.reset()[0] if terminated or truncated else next_obs
    env.close()
    transitions = Transitions(
        states=np.array(columns["s"], dtype=np.float64),
        actions=np.array(columns["a"], dtype=np.int64),
        next_states=np.array(columns["s2"], dtype=np.float64),
        rewards=np.array(columns["r"], dtype=np.float64),
        tasks=np.array(columns["tau"], dtype=np.int64),
        truncations=np.array(columns["trunc"], dtype=bool),
        terminations=np.array(columns["term"], dtype=bool),
    )
    return SourceSet(transitions, np.array(columns["v"], dtype=np.float64))
