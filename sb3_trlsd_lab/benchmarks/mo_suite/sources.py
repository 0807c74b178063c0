"""
The suite's two source protocols: where the source transitions every method of a run learns from come from.

- ``random`` (``families.collect_source``): a uniformly random policy's, split evenly over the source weights.
- ``trained`` (``trained_source``): the replay buffer of SB3's DQN trained on the source weights, one drawn at
  the start of each episode, for as many steps as the random source has rows (``DQN_SETTINGS``, the suite's
  DQN), read with ``Transitions.from_replay_buffer``: the source a user who trained a DQN on other tasks has.
  Its Q-network's parameters come with it, which the fine-tuned DQN starts from.

Under the random protocol the fine-tuned DQN starts from ``offline_parameters``: a DQN trained offline on the
random rows and their source rewards, for as many gradient steps as the trained protocol's DQN takes online.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.logger import configure

from sb3_trlsd.data import Transitions
from sb3_trlsd_lab.benchmarks.baselines import DQN_SETTINGS, one_torch_thread
from sb3_trlsd_lab.benchmarks.mo_suite.families import (
    Family,
    ScalarisedTasks,
    SourceSet,
    collect_source,
    family_weights,
    make_env,
    scalarised_tasks,
)

__all__ = [
    "SOURCE_POLICIES",
    "SourceTasks",
    "dqn_parameters",
    "load_dqn_parameters",
    "offline_parameters",
    "restore_rows",
    "source_of",
    "source_updates",
    "trained_source",
]

SOURCE_POLICIES = ("random", "trained")


def source_updates(n_steps: int) -> int:
    """The gradient steps DQN takes in ``n_steps`` env steps with ``DQN_SETTINGS`` (one a step after the first
    ``learning_starts``), the budget of the offline pretraining too."""
    every = DQN_SETTINGS["train_freq"]
    return max(0, n_steps - DQN_SETTINGS["learning_starts"]) // every * DQN_SETTINGS["gradient_steps"]


class SourceTasks(gym.Wrapper):
    """
    A family's env solving a source task drawn uniformly at each reset; it keeps every step's reward vector.

    :param env: the family's env
    :param tasks: the source tasks
    :param seed: seed of the draws
    """

    def __init__(self, env: ScalarisedTasks, tasks: np.ndarray, seed: int) -> None:
        super().__init__(env)
        self.tasks = np.asarray(tasks)
        self.rng = np.random.default_rng(seed)
        self.vector_rewards: list[np.ndarray] = []

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        """Draw the next episode's source task, then reset."""
        scalarised_tasks(self.env).set_task(int(self.rng.choice(self.tasks)))
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        """Step, keeping the reward vector."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.vector_rewards.append(info["vector_reward"])
        return obs, reward, terminated, truncated, info


def dqn_parameters(model: DQN) -> dict[str, np.ndarray]:
    """The policy's parameters (online and target Q-networks) as arrays."""
    return {name: tensor.detach().cpu().numpy().copy() for name, tensor in model.policy.state_dict().items()}


def load_dqn_parameters(model: DQN, parameters: dict[str, np.ndarray]) -> None:
    """Put ``dqn_parameters``' arrays back in a DQN of the same architecture."""
    model.policy.load_state_dict({name: th.as_tensor(value) for name, value in parameters.items()})


def trained_source(family: Family, n_steps: int, seed: int) -> SourceSet:
    """
    The replay buffer of ``DQN("MultiInputPolicy", ...)`` with ``DQN_SETTINGS`` trained for ``n_steps`` steps
    on the family's source weights (one drawn at each episode's start), as a source set with the reward
    vectors the env paid and the DQN's parameters.

    :param family: the family
    :param n_steps: env steps: the source's rows
    :param seed: the DQN's seed and that of the source tasks' draws
    """
    tasks = family.tasks_of("source")
    env = SourceTasks(make_env(family, int(tasks[0])), tasks, seed)
    settings = {**DQN_SETTINGS, "buffer_size": max(DQN_SETTINGS["buffer_size"], n_steps)}
    with one_torch_thread():
        model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **settings)
        model.learn(total_timesteps=n_steps)
    assert model.replay_buffer is not None
    transitions = Transitions.from_replay_buffer(model.replay_buffer)
    vectors = np.array(env.vector_rewards[: len(transitions)], dtype=np.float64)
    # The buffer holds every step in order (one env, no row overwritten): row i is step i.
    scalar = np.sum(family_weights(family)[transitions.tasks] * vectors, axis=1)
    assert len(transitions) == n_steps and np.allclose(transitions.rewards, scalar, rtol=1e-5, atol=1e-5)
    env.close()
    return SourceSet(transitions, vectors, dqn_parameters(model))


def restore_rows(model: DQN, rows: Transitions) -> None:
    """
    Add ``rows`` to a DQN's (Dict) replay buffer as collected: their rewards and tasks, a truncation as SB3
    stores a time limit (``done`` with ``TimeLimit.truncated``), a termination as absorbing.
    """
    buffer = model.replay_buffer
    assert isinstance(buffer, DictReplayBuffer), "a DQN on Dict observations has SB3's DictReplayBuffer"
    for row in range(len(rows)):
        terminated, truncated = bool(rows.terminations[row]), bool(rows.truncations[row])
        task = rows.tasks[row : row + 1]
        buffer.add(
            {"state": rows.states[row : row + 1], "task": task},
            {"state": rows.next_states[row : row + 1], "task": task},
            rows.actions[row : row + 1],
            rows.rewards[row : row + 1],
            np.array([terminated or truncated]),
            [{"TimeLimit.truncated": truncated and not terminated}],
        )


def offline_parameters(family: Family, source: SourceSet, seed: int) -> dict[str, np.ndarray]:
    """
    A DQN's parameters after training offline on the source rows with their source rewards: ``DQN_SETTINGS``'
    minibatches and target updates, for the gradient steps DQN takes online over as many env steps as the
    source has rows (``source_updates``).

    :param family: the family
    :param source: the source set
    :param seed: the DQN's seed
    """
    env = make_env(family, int(family.tasks_of("source")[0]))
    settings = {**DQN_SETTINGS, "buffer_size": max(DQN_SETTINGS["buffer_size"], len(source.transitions))}
    with one_torch_thread():
        model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **settings)
        model.set_logger(configure(None, []))
        restore_rows(model, source.transitions)
        for _ in range(source_updates(len(source.transitions))):
            model.train(gradient_steps=1, batch_size=DQN_SETTINGS["batch_size"])
            model._on_step()  # DQN's target update, every target_update_interval steps
    env.close()
    return dqn_parameters(model)


def source_of(family: Family, policy: str, n: int, seed: int) -> SourceSet:
    """
    The source set of a run under a protocol.

    :param family: the family
    :param policy: one of ``SOURCE_POLICIES``
    :param n: the source's rows
    :param seed: the seed of the collection (or of the DQN)
    :raises ValueError: for another protocol
    """
    if policy == "random":
        return collect_source(family, n, seed)
    if policy == "trained":
        return trained_source(family, n, seed)
    raise ValueError(f"source_policy must be one of {', '.join(SOURCE_POLICIES)}, got {policy!r}")
