"""
The methods of the suite, each run on a family's target task with the same source transitions, online
budget and seed, and each measured the same way: the scalar reward w_task . r_vec the env pays at each
online step (``StepRewards``), whatever loop drives the env.

- ``random``: a uniformly random policy.
- ``dqn``: SB3's DQN online only (``DQN_SETTINGS`` of the maze benchmark, the same for every family).
- ``dqn-relabelling``: DQN whose buffer is TRLSD's ``RelabellingReplayBuffer`` with the source loaded
  (rewards discarded), relabelled by a ridge head (kappa = 0.1) capped at the largest scalar reward the
  reward box allows; 4 gradient steps per env step and a target update every 100 steps, as
  ``benchmarks/bench_relabelling_dqn.py``.
- ``dqn-zero-source``: DQN with the source in its buffer, rewards zeroed.
- ``dqn-finetuned``: the source's DQN learning the target: what a user with a DQN trained on other tasks
  would try instead of TRLSD. Under the trained protocol (``sources.py``), the DQN that collected the source,
  its Q-networks and its buffer (the source rows with their source rewards and tasks); under the random
  protocol, a DQN trained offline on the random rows and their source rewards for as many gradient steps
  (``sources.offline_parameters``), with those rows in its buffer. It then learns online as ``dqn`` does
  (the same ``DQN_SETTINGS``: SB3's ``learn`` starts its exploration schedule again, as a second ``learn``
  call does); the target task's one-hot input is new to its network.
- ``sf-gpi``: successor features of the source tasks' policies with GPI (``sf_gpi.py``), on Fourier features
  of its own (``SF_FEATURE_WIDTH``). It is given the
  source transitions' reward VECTORS and the source weights, and sees the reward vector of each online
  step: more than any other method here.
- ``trlsd``: ``TRLSD("LinearPolicy", env, seed=...)`` with its defaults (``state_bounds`` where the family
  gives them), the source loaded with its rewards discarded, driven by ``act`` / ``add_online_transition``.
- ``trlsd-reward-given``: the same TRLSD given the TRUE target rewards w_target . r_vec of every source
  transition as samples of its reward head, with kappa = 0: what TRLSD reaches when the reward is as well
  known as its head can know it (the same features, reward timing and Fitted-Q), the level TRLSD is
  measured against.
- ``trlsd-mlp`` and ``trlsd-mlp-reward-given``: the same two with ``TRLSD("MlpPolicy", ...)``, TRLSD's small
  network Q fitted by Fitted-Q on the same relabelled rows: the other Q-class a user can pick, measured on the
  same runs.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from stable_baselines3 import DQN

from sb3_trlsd import RelabellingReplayBuffer
from sb3_trlsd.feature_choice import make_feature_map
from sb3_trlsd.observations import check_action_space, state_space_of
from sb3_trlsd.trlsd import TRLSD
from sb3_trlsd_lab.benchmarks.baselines import DQN_SETTINGS, fill_replay_buffer, one_torch_thread
from sb3_trlsd_lab.benchmarks.mo_suite.families import (
    Family,
    ScalarisedTasks,
    SourceSet,
    family_weights,
    make_env,
    reward_bound,
    scalarised_tasks,
)
from sb3_trlsd_lab.benchmarks.mo_suite.sf_gpi import SuccessorFeaturesGPI
from sb3_trlsd_lab.benchmarks.mo_suite.sources import load_dqn_parameters, offline_parameters, restore_rows
from sb3_trlsd_lab.execution.runner import run_online

__all__ = [
    "METHODS",
    "SETTABLE",
    "PeerResult",
    "Run",
    "StepRewards",
    "run_method",
    "trlsd_method",
    "trlsd_reward_given_method",
]

GAMMA = 0.9  # TRLSD's default discount, and DQN_SETTINGS': every method optimises the same return
RELABELLING_SETTINGS: dict[str, Any] = {"gradient_steps": 4, "target_update_interval": 100}
RELABELLING_KAPPA = 0.1
# SF+GPI's features: Fourier features of width 0.15 of the box (the paper's 5 x 5 RBFs of width 0.04 of the
# box leave most cells of a grid world with features near 0, and LSTD's successor features with them),
# 50 per state dimension up to 300, which keeps LSTD's system (|A| * 300)^2 quick to solve.
SF_FEATURE_WIDTH = 0.15
SF_FEATURES_PER_DIM = 50
SF_MAX_FEATURES = 300


@dataclass
class PeerResult:
    """
    One run of one method.

    :param rewards: the scalar reward of each online step, (n_online,)
    :param seconds: wall time of the run, source collection excluded
    :param online_seconds: wall time of the online steps alone (TRLSD: its refits included)
    :param updates: TRLSD's refits, DQN's gradient steps, SF+GPI's source policies (0 at random)
    """

    rewards: np.ndarray
    seconds: float
    online_seconds: float
    updates: int


class StepRewards(gym.Wrapper):
    """Records the scalar reward of every step, and keeps the last reward vector for the loops that use it."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rewards: list[float] = []
        self.vector_reward: np.ndarray | None = None

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step, and record the reward."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.rewards.append(float(reward))
        self.vector_reward = info["vector_reward"]
        return obs, reward, terminated, truncated, info


# A method's run: (env, family, source, seed, n_online) -> (updates, seconds of the online steps).
Run = Callable[[StepRewards, Family, SourceSet | None, int, int], tuple[int, float]]


def _random(
    env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
) -> tuple[int, float]:
    start = time.perf_counter()
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(n_online):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    return 0, time.perf_counter() - start


def _dqn(fill: Callable[[DQN, SourceSet, int], None] | None) -> Run:
    """DQN with ``DQN_SETTINGS``, its buffer filled by ``fill`` (None: empty)."""

    def run(
        env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
    ) -> tuple[int, float]:
        task = scalarised_tasks(env).task
        settings = _relabelling_settings(family, task) if fill is _relabelled else {}
        with one_torch_thread():
            model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **{**DQN_SETTINGS, **settings})
            if fill is not None:
                assert source is not None
                fill(model, source, task)
            start = time.perf_counter()
            model.learn(total_timesteps=n_online)
        return int(model._n_updates), time.perf_counter() - start

    return run


def _dqn_finetuned(
    env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
) -> tuple[int, float]:
    assert source is not None
    parameters = source.dqn_parameters
    if parameters is None:  # a random policy's rows: the DQN is trained on them offline first
        parameters = offline_parameters(family, source, seed)
    size = max(DQN_SETTINGS["buffer_size"], len(source.transitions) + n_online)
    with one_torch_thread():
        model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **{**DQN_SETTINGS, "buffer_size": size})
        load_dqn_parameters(model, parameters)
        restore_rows(model, source.transitions)
        start = time.perf_counter()
        model.learn(total_timesteps=n_online)
    return int(model._n_updates), time.perf_counter() - start


def _zero_rewards(model: DQN, source: SourceSet, task: int) -> None:
    fill_replay_buffer(model, source.transitions, task)


def _relabelled(model: DQN, source: SourceSet, task: int) -> None:
    assert isinstance(model.replay_buffer, RelabellingReplayBuffer)
    model.replay_buffer.load_transitions(source.transitions)


def _relabelling_settings(family: Family, task: int) -> dict[str, Any]:
    env = make_env(family, task)
    bound = reward_bound(env.reward_space, family_weights(family)[task])
    env.close()
    return {
        **RELABELLING_SETTINGS,
        "replay_buffer_class": RelabellingReplayBuffer,
        "replay_buffer_kwargs": {
            "reward_head": "ridge",
            "kappa": RELABELLING_KAPPA,
            "state_bounds": family.state_bounds,
            "reward_head_kwargs": {"r_max": bound},
        },
    }


def _sf_gpi(
    env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
) -> tuple[int, float]:
    assert source is not None
    space = state_space_of(env.observation_space)
    low, high = family.state_bounds or (space.low, space.high)
    features = make_feature_map(
        "fourier",
        low,
        high,
        rbf_sigma=SF_FEATURE_WIDTH,
        fourier_features=min(SF_FEATURES_PER_DIM * len(low), SF_MAX_FEATURES),
        seed=seed,
        n_actions=check_action_space(env.action_space),
    )
    data = source.transitions
    agent = SuccessorFeaturesGPI.from_source(
        features,
        data.states,
        data.actions,
        source.vector_rewards,
        data.next_states,
        data.terminations,
        family_weights(family)[family.tasks_of("source")],
        n_actions=check_action_space(env.action_space),
        gamma=GAMMA,
        seed=seed,
    )
    start = time.perf_counter()
    obs, _ = env.reset(seed=seed)
    for _ in range(n_online):
        obs, reward, terminated, truncated, _ = env.step(agent.act(obs["state"]))
        assert env.vector_reward is not None
        agent.observe(env.vector_reward, float(reward))
        if terminated or truncated:
            obs, _ = env.reset()
    return len(agent.thetas), time.perf_counter() - start


def _trlsd_online(model: TRLSD, env: StepRewards, seed: int, n_online: int) -> tuple[int, float]:
    """TRLSD online through the lab's loop (``run_online``): its refits and the seconds of its steps."""
    record = run_online(model, env, n_online, seed, expected_rewards=False)
    return record.policy_updates, record.seconds


def trlsd_method(policy: str = "LinearPolicy", **settings: Any) -> Run:
    """
    TRLSD with its defaults but ``settings`` (keyword arguments of ``TRLSD``), the family's state bounds and
    the source loaded with its rewards discarded (a suite's method, or a candidate of the tuning protocol).

    :param policy: TRLSD's policy, ``"LinearPolicy"`` or ``"MlpPolicy"``
    """

    def run(
        env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
    ) -> tuple[int, float]:
        assert source is not None
        model = TRLSD(policy, env, seed=seed, state_bounds=family.state_bounds, **settings)
        model.load_transitions(source.transitions, keep_rewards=False)
        return _trlsd_online(model, env, seed, n_online)

    return run


def trlsd_reward_given_method(policy: str = "LinearPolicy", **settings: Any) -> Run:
    """
    TRLSD with kappa = 0 and its defaults but ``settings``, its target head fitted before the first step on
    the true target rewards of every source transition: the reference level (or a tuning candidate's).

    :param policy: TRLSD's policy, ``"LinearPolicy"`` or ``"MlpPolicy"``
    """

    def run(
        env: StepRewards, family: Family, source: SourceSet | None, seed: int, n_online: int
    ) -> tuple[int, float]:
        assert source is not None
        task = scalarised_tasks(env).task
        model = TRLSD(policy, env, seed=seed, state_bounds=family.state_bounds, **{"kappa": 0.0, **settings})
        data = source.transitions
        true_rewards = source.vector_rewards @ family_weights(family)[task]
        model.load_transitions(
            replace(data, rewards=true_rewards, tasks=np.full_like(data.tasks, task)), keep_rewards=True
        )
        return _trlsd_online(model, env, seed, n_online)

    return run


# The methods that take TRLSD's settings (a tuning candidate's), and how.
SETTABLE: dict[str, Callable[..., Run]] = {
    "trlsd": trlsd_method,
    "trlsd-reward-given": trlsd_reward_given_method,
    "trlsd-mlp": functools.partial(trlsd_method, "MlpPolicy"),
    "trlsd-mlp-reward-given": functools.partial(trlsd_reward_given_method, "MlpPolicy"),
}

# Method -> (label, whether it needs the source, its run).
METHODS: dict[str, tuple[str, bool, Run]] = {
    "trlsd": ("TRLSD (defaults)", True, SETTABLE["trlsd"]()),
    "trlsd-reward-given": ("TRLSD given the source's true rewards", True, SETTABLE["trlsd-reward-given"]()),
    "trlsd-mlp": ("TRLSD, MlpPolicy (defaults)", True, SETTABLE["trlsd-mlp"]()),
    "trlsd-mlp-reward-given": (
        "TRLSD, MlpPolicy, given the source's true rewards",
        True,
        SETTABLE["trlsd-mlp-reward-given"](),
    ),
    "sf-gpi": ("SF + GPI (sees the reward vectors)", True, _sf_gpi),
    "dqn-relabelling": ("DQN + relabelling buffer", True, _dqn(_relabelled)),
    "dqn-zero-source": ("DQN, source with zero reward", True, _dqn(_zero_rewards)),
    "dqn-finetuned": ("DQN fine-tuned from the source's DQN", True, _dqn_finetuned),
    "dqn": ("DQN (online only)", False, _dqn(None)),
    "random": ("random policy", False, _random),
}


def run_method(
    method: str,
    family: Family,
    task: int,
    seed: int,
    source: SourceSet | None,
    n_online: int,
    settings: Mapping[str, Any] | None = None,
) -> PeerResult:
    """
    One run of ``method`` on ``family``'s ``task``.

    :param method: a key of ``METHODS``
    :param family: the family
    :param task: the target task, an index of ``family_weights``
    :param seed: the run's seed (the model's, and that of the env's first reset)
    :param source: the source transitions (ignored by the methods without source)
    :param n_online: online transitions
    :param settings: the methods of ``SETTABLE`` only: keyword arguments of ``TRLSD`` other than its defaults
    :return: the run's rewards and timings
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    _, needs_source, run = METHODS[method]
    if settings:
        if method not in SETTABLE:
            raise ValueError(
                f"settings are TRLSD's: give them with one of {', '.join(SETTABLE)}, not {method!r}"
            )
        run = SETTABLE[method](**settings)
    if needs_source and source is None:
        raise ValueError(f"method {method!r} needs the source transitions")
    start = time.perf_counter()
    env = StepRewards(make_env(family, task))
    updates, online_seconds = run(env, family, source, seed, n_online)
    seconds = time.perf_counter() - start
    env.close()
    rewards = np.array(env.rewards[:n_online])
    assert len(rewards) == n_online, f"{method} made {len(rewards)} steps, not {n_online}"
    assert isinstance(env.unwrapped, ScalarisedTasks)
    return PeerResult(rewards, seconds, online_seconds, updates)
