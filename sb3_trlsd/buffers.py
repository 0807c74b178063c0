"""The replay buffer shared by every task: it keeps each transition with its task and relabels rewards.

Section 2 of the paper: any transition xi_tau' = <tau', s, a, r, s'> collected on a task tau' serves a
target task tau once its reward is replaced by the target's reward proxy,
psi(xi_tau') = <tau, s, a, R~_tau(s), s'>. The buffer does that relabelling the way SB3's
``HerReplayBuffer`` relabels goals, through a reward head it is given; it knows nothing about how the
relabelled set is then used (Fitted-Q Iteration, in ``TRLSD``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_trlsd.data import Transitions
from sb3_trlsd.reward_heads import RewardHead, RewardTracker

__all__ = ["SharedDynamicsReplayBuffer", "state_space_of"]


def state_space_of(observation_space: spaces.Space) -> spaces.Box:
    """
    The Box holding the state: the observation space itself, or its ``"state"`` entry for the
    ``{"state", "task"}`` Dict observations of multi-task envs.

    :raises ValueError: for any other observation space
    """
    if isinstance(observation_space, spaces.Dict) and isinstance(
        observation_space.spaces.get("state"), spaces.Box
    ):
        state_space = observation_space["state"]
        task_space = observation_space.spaces.get("task")
        if not isinstance(task_space, spaces.Discrete) or len(observation_space.spaces) != 2:
            raise ValueError(
                "observation_space must be a Box or a Dict with exactly a 'state' Box and a 'task' Discrete, "
                f"got {observation_space}"
            )
    elif isinstance(observation_space, spaces.Box):
        state_space = observation_space
    else:
        raise ValueError(
            "observation_space must be a Box or a Dict with a 'state' Box and a 'task' Discrete, "
            f"got {observation_space}"
        )
    assert isinstance(state_space, spaces.Box)
    if len(state_space.shape) != 1:
        raise ValueError(f"the state Box must be one-dimensional (a vector), got shape {state_space.shape}")
    return state_space


class SharedDynamicsReplayBuffer(ReplayBuffer):
    """
    Replay buffer of every transition of every task, with its task and its observed reward, that hands
    out the whole set (or a batch) relabelled for a target task.

    Observations are stored as their state only: with ``{"state", "task"}`` Dict observations the task goes
    to its own array, with a plain Box observation every transition belongs to task 0. Transitions loaded
    from elsewhere may come without their rewards (the paper discards the source rewards): those rows are
    used for the dynamics only, never to fit a reward head.

    :param buffer_size: Max number of transitions
    :param observation_space: the env's observation space (Box, or Dict with ``state`` and ``task``)
    :param action_space: the env's (Discrete) action space
    :param device: PyTorch device for sampled batches
    :param n_envs: number of parallel environments
    :param optimize_memory_usage: not supported (next states are kept apart), must be False
    :param handle_timeout_termination: keep truncations apart from terminations so that learners
        bootstrap through them
    """

    tasks: np.ndarray
    has_reward: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ):
        if optimize_memory_usage:
            raise ValueError("SharedDynamicsReplayBuffer does not support optimize_memory_usage=True")
        super().__init__(
            buffer_size,
            state_space_of(observation_space),
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.tasks = np.zeros((self.buffer_size, self.n_envs), dtype=np.int64)
        self.has_reward = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        # Rows are numbered in insertion order; n_overwritten counts rows lost to wrap-around, which
        # invalidates the incremental relabelling caches below.
        self.n_added = 0
        self.n_overwritten = 0
        self._trackers: dict[int, tuple[RewardHead, RewardTracker, int]] = {}

    def __getstate__(self) -> dict[str, Any]:
        # The relabelling caches hold references to reward heads and are rebuilt on demand.
        state = self.__dict__.copy()
        state["_trackers"] = {}
        return state

    # ----------------------------------------------------------------- storing
    def add(
        self,
        obs: np.ndarray | dict[str, np.ndarray],
        next_obs: np.ndarray | dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of the ``n_envs`` envs, as SB3's ``collect_rollouts`` calls it."""
        if isinstance(obs, dict):
            tasks = np.asarray(obs["task"]).reshape(self.n_envs)
            obs, next_obs = obs["state"], next_obs["state"]  # type: ignore[index]
        else:
            tasks = np.zeros(self.n_envs, dtype=np.int64)
        self._before_write(1)
        self.tasks[self.pos] = tasks
        self.has_reward[self.pos] = True
        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[arg-type]
        self.n_added += 1

    def add_transitions(self, transitions: Transitions, keep_rewards: bool = False) -> None:
        """
        Append transitions collected elsewhere (e.g. by ``collect_transitions`` on other tasks).

        :param transitions: the transitions to append
        :param keep_rewards: keep their rewards for fitting reward heads; False (the paper's setting)
            keeps them for the dynamics only
        """
        if self.n_envs != 1:
            raise ValueError("add_transitions needs a buffer with n_envs=1")
        if transitions.state_dim != self.obs_shape[0]:
            raise ValueError(
                f"transitions have states of dimension {transitions.state_dim}, "
                f"the env's states have dimension {self.obs_shape[0]}"
            )
        assert isinstance(self.action_space, spaces.Discrete)
        if (
            transitions.actions.min(initial=0) < 0
            or transitions.actions.max(initial=0) >= self.action_space.n
        ):
            raise ValueError(f"transitions have actions outside the env's action space {self.action_space}")
        # Written in chunks that stop at the end of the ring.
        start = 0
        while start < len(transitions):
            stop = min(len(transitions), start + self.buffer_size - self.pos)
            rows = slice(self.pos, self.pos + stop - start)
            chunk = slice(start, stop)
            self._before_write(stop - start)
            self.observations[rows, 0] = transitions.states[chunk]
            self.next_observations[rows, 0] = transitions.next_states[chunk]
            self.actions[rows, 0, 0] = transitions.actions[chunk]
            self.rewards[rows, 0] = transitions.rewards[chunk] if keep_rewards else 0.0
            self.has_reward[rows, 0] = keep_rewards
            self.tasks[rows, 0] = transitions.tasks[chunk]
            self.dones[rows, 0] = transitions.truncations[chunk] | transitions.terminations[chunk]
            self.timeouts[rows, 0] = transitions.truncations[chunk] & ~transitions.terminations[chunk]
            self.n_added += stop - start
            self.pos += stop - start
            if self.pos == self.buffer_size:
                self.full, self.pos = True, 0
            start = stop

    def _before_write(self, n_rows: int) -> None:
        if self.full:
            self.n_overwritten += n_rows
            self._trackers.clear()

    # ----------------------------------------------------------------- reading
    def _flat(self, array: np.ndarray) -> np.ndarray:
        """The valid rows of a (buffer_size, n_envs, ...) array as (n, ...), oldest first."""
        array = np.concatenate([array[self.pos :], array[: self.pos]]) if self.full else array[: self.pos]
        return array.reshape(-1, *array.shape[2:])

    def transitions(self) -> Transitions:
        """Every stored transition, oldest first, with its observed reward (0 where it was discarded)."""
        terminated = self._flat(self.dones).astype(bool)
        if self.handle_timeout_termination:
            truncated = self._flat(self.timeouts).astype(bool)
        else:
            truncated = np.zeros_like(terminated)
        return Transitions(
            states=self._flat(self.observations).astype(np.float64),
            actions=self._flat(self.actions)[:, 0].astype(np.int64),
            next_states=self._flat(self.next_observations).astype(np.float64),
            rewards=self._flat(self.rewards).astype(np.float64),
            tasks=self._flat(self.tasks),
            truncations=truncated,
            terminations=terminated & ~truncated,
        )

    def task_samples(self, task: int) -> tuple[np.ndarray, np.ndarray]:
        """
        The start states and observed rewards of the transitions of ``task`` whose reward was kept:
        the sample set Xi_tau a reward head is fitted on.

        :return: states (m, d) and rewards (m,)
        """
        mask = (self._flat(self.tasks) == task) & self._flat(self.has_reward)
        return self._flat(self.observations)[mask].astype(np.float64), self._flat(self.rewards)[mask].astype(
            np.float64
        )

    def relabelled_rewards(self, task: int, head: RewardHead) -> np.ndarray:
        """
        R~_tau(s) at the start state of every stored transition, oldest first (Psi of section 2).

        Kept incrementally per task: between two calls only the new transitions and the head's new
        samples are folded in (see ``RewardHead.tracker``).

        :param task: the target task tau
        :param head: the reward head of tau
        :return: rewards (n,)
        """
        cached = self._trackers.get(task)
        if cached is None or cached[0] is not head or cached[2] != self.n_overwritten:
            states = self._flat(self.observations).astype(np.float64)
            tracker = head.tracker(states)
        else:
            tracker = cached[1]
            n_tracked = tracker.n_states
            n_stored = self.size() * self.n_envs
            if n_stored > n_tracked:
                tracker.extend(self._flat(self.observations)[n_tracked:].astype(np.float64))
        self._trackers[task] = (head, tracker, self.n_overwritten)
        return tracker.optimistic()

    def relabelled(self, task: int, head: RewardHead) -> Transitions:
        """Every stored transition cast on ``task``: rewards replaced by ``head``'s R~ (psi, section 2)."""
        transitions = self.transitions()
        return Transitions(
            states=transitions.states,
            actions=transitions.actions,
            next_states=transitions.next_states,
            rewards=self.relabelled_rewards(task, head),
            tasks=np.full(len(transitions), task, dtype=np.int64),
            truncations=transitions.truncations,
            terminations=transitions.terminations,
        )

    def sample_relabelled(self, batch_size: int, task: int, head: RewardHead) -> ReplayBufferSamples:
        """
        A uniformly sampled batch whose rewards are ``head``'s R~ for ``task``, the way
        ``HerReplayBuffer`` relabels goals at sample time. Observations are the raw states (no
        ``VecNormalize``: the reward head is defined on raw states).
        """
        samples = self.sample(batch_size)
        states = samples.observations.cpu().numpy().astype(np.float64)
        rewards = head.optimistic(states).astype(np.float32).reshape(-1, 1)
        return samples._replace(rewards=self.to_torch(rewards))
