"""The replay buffer shared by every task: each transition with its task, and nothing task-specific.

Section 2 of the paper: any transition xi_tau' = <tau', s, a, r, s'> collected on a task tau' serves a
target task tau once its reward is replaced by the target's reward proxy,
psi(xi_tau') = <tau, s, a, R~_tau(s), s'>. The buffer keeps the transitions; whoever relabels them (a
task's ``TaskLearner``) or fits on them (the Q-function's fit rows) reads the rows added since its last
read through a ``BufferCursor``, so that a refit costs only the new rows.
"""

from __future__ import annotations

import secrets
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_trlsd.data import Transitions, as_flags
from sb3_trlsd.observations import split_observation, state_space_of, task_count_of

__all__ = ["STORED_FIELDS", "BufferCursor", "BufferFullWarning", "SharedDynamicsReplayBuffer"]

# The per-row arrays of the buffer, in the column order of ``packed_rows``.
STORED_FIELDS = (
    "observations",
    "next_observations",
    "actions",
    "rewards",
    "dones",
    "timeouts",
    "tasks",
    "has_reward",
)


class BufferFullWarning(UserWarning):
    """
    The shared buffer is full and its ring starts replacing its oldest rows, which Fitted-Q then no longer
    sees (source rows included). Warned once per buffer; a larger ``buffer_size`` keeps every row.
    """


@dataclass
class BufferCursor:
    """
    How far a reader of the buffer has read: the buffer's epoch then, and the rows read (in insertion order).

    :param epoch: the buffer's ``epoch`` at the last read (None: never read)
    :param n_read: rows read so far
    """

    epoch: int | None = None
    n_read: int = 0


class SharedDynamicsReplayBuffer(ReplayBuffer):
    """
    Replay buffer of every transition of every task, with its task and its observed reward.

    Observations are stored as their state only: with ``{"state", "task"}`` Dict observations the task goes
    to its own array, with a plain Box observation every transition belongs to task 0. Transitions loaded
    from elsewhere may come without their rewards (the paper discards the source rewards): ``has_reward``
    marks the rows whose reward was observed. Everything is validated before it is stored: a transition
    with a non-finite value, the wrong shape or a task out of range raises a ValueError and leaves the
    buffer as it was.

    :param buffer_size: Max number of transitions
    :param observation_space: the env's observation space (Box, or Dict with ``state`` and ``task``)
    :param action_space: the env's (Discrete) action space
    :param device: PyTorch device for sampled batches
    :param n_envs: number of parallel environments, whose steps are stored as consecutive rows
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
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"SharedDynamicsReplayBuffer needs a Discrete action space, got {action_space}")
        if not (isinstance(n_envs, (int, np.integer)) and n_envs >= 1):
            raise ValueError(f"n_envs must be an integer >= 1, got {n_envs!r}")
        if isinstance(buffer_size, bool) or not (
            isinstance(buffer_size, (int, np.integer)) and buffer_size >= 1
        ):
            # SB3 would make a buffer of 0 or less a buffer of one row, silently.
            raise ValueError(
                f"buffer_size must be an integer >= 1 (rows of the shared buffer), got {buffer_size!r}"
            )
        # One column of rows: a step of n_envs envs is n_envs consecutive rows, so that transitions loaded
        # from elsewhere, and any number of envs, share one ring of buffer_size rows.
        super().__init__(
            buffer_size,
            state_space_of(observation_space),
            action_space,
            device=device,
            n_envs=1,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.n_tasks = task_count_of(observation_space)
        self.tasks = np.zeros((self.buffer_size, self.n_envs), dtype=np.int64)
        self.has_reward = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        self.n_added = 0  # rows ever added since the epoch began, in insertion order
        self.epoch = secrets.randbits(62)  # changes whenever rows are lost (wrap-around, reset)
        self.warned_full = False

    def __setstate__(self, state: dict[str, Any]) -> None:
        # A buffer read back from disk is a new buffer for the cursors of the model that loads it.
        self.__dict__.update(state)
        self.epoch = secrets.randbits(62)

    def reset(self) -> None:
        super().reset()
        self.n_added = 0
        self.epoch = secrets.randbits(62)

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
        """
        Store one step of the envs, as SB3's ``collect_rollouts`` calls it (validated first): one row per env,
        in the envs' order.
        """
        dim = self.obs_shape[0]
        states, tasks = split_observation(obs, dim)
        next_states, _ = split_observation(next_obs, dim)
        actions = np.asarray(action).reshape(-1)
        rewards = np.asarray(reward, dtype=np.float64).reshape(-1)
        self._check_rows(states, next_states, actions, rewards, tasks, expected_rows=len(states))
        dones = as_flags("done", np.asarray(done).reshape(-1))
        if len(dones) != len(states) or len(infos) != len(states):
            raise ValueError(
                f"expected one done and one info per env ({len(states)}), got {len(dones)}, {len(infos)}"
            )
        for i in range(len(states)):
            self._before_write(1)
            self.tasks[self.pos] = tasks[i]
            self.has_reward[self.pos] = True
            super().add(
                states[i : i + 1],
                next_states[i : i + 1],
                actions[i : i + 1],
                rewards[i : i + 1],
                dones[i : i + 1],
                infos[i : i + 1],
            )
            self.n_added += 1

    def add_transitions(self, transitions: Transitions, keep_rewards: bool = False) -> None:
        """
        Append transitions collected elsewhere (e.g. by ``collect_transitions`` on other tasks). Once the
        ring is full they replace the oldest rows, as SB3's buffers do (see ``check_room``).

        :param transitions: the transitions to append
        :param keep_rewards: keep their rewards (``has_reward``); False (the paper's setting) stores 0
        :raises ValueError: for more transitions than ``buffer_size`` (the first would be overwritten by the
            last), or rows that do not fit the env
        """
        self._check_rows(
            transitions.states,
            transitions.next_states,
            transitions.actions,
            transitions.rewards,
            transitions.tasks,
            expected_rows=len(transitions),
        )
        if len(transitions) > self.buffer_size:
            raise ValueError(
                f"{len(transitions)} transitions do not fit a shared buffer of "
                f"buffer_size={self.buffer_size}: the first {len(transitions) - self.buffer_size} would be "
                f"overwritten by the last; make the buffer with buffer_size >= {len(transitions)}"
            )
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

    def _check_rows(
        self,
        states: np.ndarray,
        next_states: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        tasks: np.ndarray,
        expected_rows: int,
    ) -> None:
        """A ValueError naming what is wrong, before anything is written."""
        dim = self.obs_shape[0]
        for name, value in (("state", states), ("next state", next_states)):
            if np.shape(value) != (expected_rows, dim):
                raise ValueError(
                    f"{name}s must have shape ({expected_rows}, {dim}) (the env's state dimension is {dim}), "
                    f"got {np.shape(value)}"
                )
            if not np.all(np.isfinite(value)):
                bad = np.asarray(value)[~np.isfinite(value).all(axis=1)]
                raise ValueError(f"a {name} is not finite (NaN or inf): {bad[:3]}")
            self._check_integer_states(name, np.asarray(value))
        if np.shape(rewards) != (expected_rows,) or np.shape(actions) != (expected_rows,):
            raise ValueError(
                f"expected {expected_rows} rewards and actions, got {np.shape(rewards)}, {np.shape(actions)}"
            )
        if not np.all(np.isfinite(rewards)):
            raise ValueError(
                f"a reward is not finite (NaN or inf): {np.asarray(rewards)[~np.isfinite(rewards)][:3]}"
            )
        assert isinstance(self.action_space, spaces.Discrete)
        if len(actions) and (
            np.any(actions != np.round(actions)) or actions.min() < 0 or actions.max() >= self.action_space.n
        ):
            raise ValueError(
                f"actions must be integers in 0..{self.action_space.n - 1}, got {np.unique(actions)}"
            )
        if len(tasks) and (tasks.min() < 0 or tasks.max() >= self.n_tasks):
            raise ValueError(
                f"tasks must be in 0..{self.n_tasks - 1} (the env's tasks), got {np.unique(tasks)}"
            )

    def _check_integer_states(self, name: str, states: np.ndarray) -> None:
        """On a Box of integers, states that the Box's dtype stores as they are, or a ValueError."""
        dtype = np.dtype(self.observation_space.dtype)
        if not np.issubdtype(dtype, np.integer):
            return
        fractional = states != np.round(states)
        if fractional.any():
            raise ValueError(
                f"{name}s must be integers on this env's state Box of dtype {dtype}, which would store "
                f"{float(states[fractional][0])} as {np.trunc(states[fractional][0]):.0f}: round the states "
                "(np.rint) before they are stored, or give the env a float Box to keep them"
            )
        limits = np.iinfo(dtype)
        if states.size and (states.min() < limits.min or states.max() > limits.max):
            raise ValueError(
                f"{name}s must fit the state Box's dtype {dtype} ({limits.min}..{limits.max}), got values "
                f"from {states.min()} to {states.max()}: give the env a wider dtype"
            )

    def check_room(self, n_rows: int) -> None:
        """
        Refuse ``n_rows`` new rows that would replace stored ones (loaded transitions must not push out a
        source set, nor be pushed out, silently).

        :param n_rows: the rows about to be added
        :raises ValueError: naming the sizes and the ``buffer_size`` that holds them all
        """
        if self.size() + n_rows > self.buffer_size:
            raise ValueError(
                f"{n_rows} transitions do not fit the shared buffer next to its {self.size()} rows: "
                f"buffer_size={self.buffer_size} has room for {self.buffer_size - self.size()}, and the ring "
                f"would drop the oldest rows; make the model with buffer_size >= {self.size() + n_rows} "
                "(plus the online steps to come)"
            )

    def _before_write(self, n_rows: int) -> None:
        if self.full:
            # Rows are about to be lost: every cursor must start over.
            self.epoch = secrets.randbits(62)
            if not getattr(self, "warned_full", False):
                self.warned_full = True
                warnings.warn(
                    f"the shared buffer is full (buffer_size={self.buffer_size}): from now on each new row "
                    "replaces its oldest one, a source row included, and Fitted-Q no longer sees it; make "
                    "the model with a larger buffer_size to keep every row. Warned once.",
                    BufferFullWarning,
                    stacklevel=3,
                )

    # ----------------------------------------------------------------- reading
    def _flat(self, array: np.ndarray) -> np.ndarray:
        """The valid rows of a (buffer_size, 1, ...) array as (n, ...), oldest first."""
        array = np.concatenate([array[self.pos :], array[: self.pos]]) if self.full else array[: self.pos]
        return array.reshape(-1, *array.shape[2:])

    def transitions(self, start: int = 0) -> Transitions:
        """
        The stored transitions, oldest first, with their observed rewards (0 where they were discarded).

        :param start: the first row (0: all of them)
        """
        terminated = self._flat(self.dones)[start:].astype(bool)
        if self.handle_timeout_termination:
            truncated = self._flat(self.timeouts)[start:].astype(bool)
        else:
            truncated = np.zeros_like(terminated)
        return Transitions(
            states=self._flat(self.observations)[start:].astype(np.float64),
            actions=self._flat(self.actions)[start:, 0].astype(np.int64),
            next_states=self._flat(self.next_observations)[start:].astype(np.float64),
            rewards=self._flat(self.rewards)[start:].astype(np.float64),
            tasks=self._flat(self.tasks)[start:],
            truncations=truncated,
            terminations=terminated & ~truncated,
        )

    def read_new(self, cursor: BufferCursor) -> tuple[Transitions, bool]:
        """
        The rows a reader has not read yet, and move its cursor past them.

        :param cursor: the reader's cursor, updated in place
        :return: the new rows (oldest first) and whether the reader must start over (the rows it read
            before are gone: the buffer wrapped around, was reset, or is another buffer); then every row
            is returned
        """
        n_stored = self.size()
        restart = cursor.epoch != self.epoch or cursor.n_read > self.n_added
        first = 0 if restart else n_stored - (self.n_added - cursor.n_read)
        cursor.epoch, cursor.n_read = self.epoch, self.n_added
        return self.transitions(first), restart

    def recent_states(self, task: int, n_states: int) -> np.ndarray:
        """
        The start states of the latest ``n_states`` transitions of ``task`` whose reward was observed (its
        online trajectory), with a row of NaN after each reset, where a drawn line must break.

        :return: (t, d)
        """
        rows = np.flatnonzero((self._flat(self.tasks) == task) & self._flat(self.has_reward))[-n_states:]
        states = self._flat(self.observations)[rows].astype(np.float64)
        breaks = self._flat(self.dones)[rows].astype(bool)
        out = []
        for state, done in zip(states, breaks, strict=True):
            out.append(state)
            if done:
                out.append(np.full(len(state), np.nan))
        return np.array(out).reshape(-1, self.obs_shape[0])

    # ------------------------------------------------------------ saving rows
    def packed_rows(self) -> np.ndarray:
        """
        Every stored row, oldest first, as one float64 array (float32 states, integer actions and tasks,
        and flags are all exact in float64): columns state (d), next state (d), action, reward, done,
        timeout, task, has_reward. ``restore_packed_rows`` takes it back.

        :return: (n, 2 d + 6)
        """
        n = self.size()
        if not n:  # reshape(0, -1) cannot tell the columns of no row
            return np.zeros((0, 2 * self.obs_shape[0] + 6))
        columns = [
            self._flat(getattr(self, name)).reshape(n, -1).astype(np.float64) for name in STORED_FIELDS
        ]
        return np.concatenate(columns, axis=1)

    def restore_packed_rows(self, rows: np.ndarray) -> None:
        """
        Empty the buffer and store the rows of ``packed_rows`` back, oldest first.

        :param rows: (n, 2 d + 6)
        :raises ValueError: when the rows do not fit this buffer (size, state dimension, tasks, actions)
        """
        d = self.obs_shape[0]
        rows = np.asarray(rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] != 2 * d + 6:
            raise ValueError(
                f"packed rows must have shape (n, {2 * d + 6}) for states of dimension {d}, got {rows.shape}"
            )
        n = len(rows)
        if n > self.buffer_size:
            raise ValueError(f"{n} rows do not fit a buffer of size {self.buffer_size}")
        columns = dict(
            zip(STORED_FIELDS, np.split(rows, np.cumsum([d, d, 1, 1, 1, 1, 1]), axis=1), strict=True)
        )
        self._check_rows(
            columns["observations"],
            columns["next_observations"],
            columns["actions"][:, 0],
            columns["rewards"][:, 0],
            columns["tasks"][:, 0].astype(np.int64),
            expected_rows=n,
        )
        self.reset()
        for name in STORED_FIELDS:
            target = getattr(self, name)
            target[:n] = columns[name].reshape(n, *target.shape[1:]).astype(target.dtype)
        self.pos, self.full = n % self.buffer_size, n == self.buffer_size
        self.n_added = n
