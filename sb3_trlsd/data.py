"""Transition sets: collected with a random policy, saved to and loaded from ``.npz`` files.

A transition here is the paper's xi_tau = <tau, s, a, r, s'> (section 2) plus the two flags SB3
keeps: whether the trajectory was truncated after it (a reset: learners bootstrap through it) or
terminated (an absorbing state: they do not).
"""

from __future__ import annotations

import os
import zipfile
import zlib
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, RecordEpisodeStatistics, TimeLimit
from stable_baselines3.common.monitor import Monitor
from tqdm.auto import tqdm

from sb3_trlsd.atomic_files import atomic_write
from sb3_trlsd.observations import split_observation, state_space_of

if TYPE_CHECKING:
    from minari import MinariDataset
    from stable_baselines3.common.buffers import ReplayBuffer

__all__ = ["Transitions", "as_flags", "collect_transitions", "load_npz_arrays"]

# dtype kinds (numpy's ``dtype.kind``) a loaded file may hold, per field, and how to name them.
LOADED_KINDS = {
    "states": ("iuf", "real numbers"),
    "actions": ("iu", "integers"),
    "next_states": ("iuf", "real numbers"),
    "rewards": ("iuf", "real numbers"),
    "tasks": ("iu", "integers"),
    "truncations": ("b", "booleans"),
    "terminations": ("b", "booleans"),
}


def as_flags(name: str, values: object) -> np.ndarray:
    """
    Flags (a trajectory's truncation or termination) as booleans: booleans as they are, numbers only when
    each is 0 or 1 (2 would be stored as a done of 2, 0.5 fail inside numpy's bitwise operations).

    :param name: the argument's name, for the error
    :param values: one flag or an array of them
    :return: a boolean array of ``values``' shape
    :raises ValueError: naming the argument and the values that are neither
    """
    array = np.asarray(values)
    if array.dtype == bool:
        return array
    if array.dtype.kind in "iuf" and np.all((array == 0) | (array == 1)):
        return array.astype(bool)
    bad = np.unique(array[~((array == 0) | (array == 1))]) if array.dtype.kind in "iuf" else array.dtype
    raise ValueError(
        f"{name} must be booleans (True / False, or 0 / 1), got {bad}: pass whether each transition "
        "ended its trajectory"
    )


@dataclass(frozen=True)
class Transitions:
    """
    A batch of transitions of one or several tasks sharing the same dynamics.

    :param states: start states s, shape (n, d)
    :param actions: discrete actions a, shape (n,)
    :param next_states: states s' reached, shape (n, d)
    :param rewards: observed rewards r, shape (n,)
    :param tasks: task index tau of the trajectory each transition belongs to, shape (n,)
    :param truncations: the trajectory was reset after this transition (bootstrap through it), shape (n,)
    :param terminations: s' is absorbing (no bootstrap), shape (n,); all False on the maze
    """

    states: np.ndarray
    actions: np.ndarray
    next_states: np.ndarray
    rewards: np.ndarray
    tasks: np.ndarray
    truncations: np.ndarray
    terminations: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.actions)
        for field in fields(self):
            value = np.asarray(getattr(self, field.name))
            if value.dtype == object:
                raise ValueError(f"Transitions.{field.name} must be a numeric array, got dtype object")
            object.__setattr__(self, field.name, value)
            if len(value) != n:
                raise ValueError(
                    f"Transitions.{field.name} has {len(value)} rows but actions has {n}: "
                    "every array must hold one row per transition"
                )
        if self.states.ndim != 2 or self.next_states.shape != self.states.shape:
            raise ValueError(
                "Transitions.states and next_states must both have shape (n, state_dim), "
                f"got {self.states.shape} and {self.next_states.shape}"
            )
        for name in ("actions", "rewards", "tasks", "truncations", "terminations"):
            if getattr(self, name).ndim != 1:
                raise ValueError(f"Transitions.{name} must have shape (n,), got {getattr(self, name).shape}")
        for name in ("truncations", "terminations"):
            object.__setattr__(self, name, as_flags(f"Transitions.{name}", getattr(self, name)))
        if not np.issubdtype(self.actions.dtype, np.integer) or not np.issubdtype(
            self.tasks.dtype, np.integer
        ):
            raise ValueError("Transitions.actions and tasks must be integer arrays")
        for name in ("states", "next_states", "rewards"):
            if not np.all(np.isfinite(getattr(self, name))):
                readable = name.replace("_", " ")
                raise ValueError(
                    f"Transitions.{name} contains NaN or infinite values: the {readable} must be finite"
                )

    def take(self, rows: np.ndarray) -> Transitions:
        """
        The transitions of the given rows, in that order (e.g. a permutation).

        :param rows: row indices or a boolean mask
        """
        return Transitions(**{field.name: getattr(self, field.name)[rows] for field in fields(self)})

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def state_dim(self) -> int:
        return self.states.shape[1]

    def save(self, path: str | os.PathLike) -> None:
        """
        Save the transitions as an uncompressed ``.npz`` file (one array per field), written whole or not
        at all: through a temporary file that replaces an earlier one only once complete.

        :param path: destination file; ``.npz`` is appended if it is missing, as numpy does
        :raises ValueError: when ``path`` is a folder
        """
        target = os.fspath(path)
        target = target if target.endswith(".npz") else f"{target}.npz"
        if os.path.isdir(target):
            raise ValueError(f"path {target!r} is a folder, not a file to save the transitions to")
        with atomic_write(target, "wb") as file:
            np.savez(file, **{field.name: getattr(self, field.name) for field in fields(self)})

    @classmethod
    def load(cls, path: str | os.PathLike) -> Transitions:
        """
        Load transitions saved by :meth:`save`.

        :param path: a ``.npz`` file written by :meth:`save`
        :return: the transitions, validated
        :raises ValueError: naming the file, if it is not a readable ``.npz`` file, lacks a field, or holds
            arrays of the wrong kind or of inconsistent shapes
        """
        arrays = load_npz_arrays(path)
        names = [field.name for field in fields(cls)]
        missing = sorted(set(names) - set(arrays))
        if missing:
            raise ValueError(
                f"{os.fspath(path)!r} is not a transitions file: it lacks the arrays {missing} "
                f"(expected {names})"
            )
        for name, (kinds, expected) in LOADED_KINDS.items():
            if arrays[name].dtype.kind not in kinds:
                raise ValueError(
                    f"{os.fspath(path)!r} is not a valid transitions file: its array {name!r} has dtype "
                    f"{arrays[name].dtype}, expected {expected}"
                )
        try:
            return cls(**{name: arrays[name] for name in names})
        except ValueError as error:
            raise ValueError(f"{os.fspath(path)!r} is not a valid transitions file: {error}") from error

    @classmethod
    def from_replay_buffer(cls, buffer: ReplayBuffer, task: int | None = None) -> Transitions:
        """
        The transitions an SB3 replay buffer holds (``model.replay_buffer``, or SB3's ``load_from_pkl`` of a
        ``save_replay_buffer`` file): a ``ReplayBuffer`` of any ``n_envs``, with ``optimize_memory_usage`` or
        not, a ``DictReplayBuffer`` of ``{"state", "task"}`` observations, or TRLSD's own buffers. Each env's
        rows come in turn, oldest first; time limits stay truncations (see ``sb3_trlsd.foreign_data``).

        :param buffer: the buffer
        :param task: the task every row was collected on; None: each row's observed task, which a buffer of
            Box observations does not have (then give it)
        :return: the transitions
        :raises ValueError: for a buffer of other spaces, or of Box observations without ``task``
        """
        from sb3_trlsd.foreign_data import replay_buffer_transitions  # it imports this module

        return replay_buffer_transitions(buffer, task)

    @classmethod
    def from_minari(cls, dataset: MinariDataset, task: int | None = None) -> Transitions:
        """
        The transitions of a Minari dataset's episodes (``minari.load_dataset(id)``), in order: its
        observations a state Box or a ``{"state", "task"}`` Dict, its actions Discrete.

        :param dataset: the dataset
        :param task: the task every row was collected on; None: each row's observed task, which a dataset of
            Box observations does not have (then give it)
        :return: the transitions
        :raises ValueError: for a dataset of other spaces, or of Box observations without ``task``
        """
        from sb3_trlsd.foreign_data import minari_transitions  # it imports this module

        return minari_transitions(dataset, task)


def load_npz_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """
    Every array of an ``.npz`` file, read at once, nothing unpickled (``allow_pickle=False``).

    :param path: the file
    :return: its arrays by name
    :raises OSError: if the file cannot be opened (missing, a directory, not readable)
    :raises ValueError: naming the file, if it is not an ``.npz`` file of arrays or is truncated or damaged
    """
    name = os.fspath(path)
    try:
        archive = np.load(path, allow_pickle=False)
    except (EOFError, zipfile.BadZipFile) as error:
        raise ValueError(
            f"{name!r} is not a readable .npz file, it is empty, truncated or damaged "
            f"({type(error).__name__}: {error})"
        ) from error
    except ValueError as error:  # neither a zip nor an .npy: numpy would have to unpickle it
        raise ValueError(
            f"{name!r} is not an .npz file: neither a zip of arrays nor an array (pickles are not loaded)"
        ) from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{name!r} holds one array (an .npy file), not an .npz file of named arrays")
    with archive:
        arrays = {}
        for key in archive.files:
            try:
                arrays[key] = archive[key]
            except (EOFError, ValueError, zipfile.BadZipFile, zlib.error) as error:
                raise ValueError(
                    f"{name!r}: its array {key!r} cannot be read, the file is damaged or the array holds "
                    f"Python objects ({type(error).__name__}: {error})"
                ) from error
    return arrays


# Wrappers that pass observations, actions and rewards through unchanged: with only these around it, an env's
# own vectorised sampler gives the transitions that stepping it would. Any other wrapper is stepped through.
TRANSPARENT_WRAPPERS = (TimeLimit, OrderEnforcing, PassiveEnvChecker, RecordEpisodeStatistics, Monitor)


def own_sampler(env: gym.Env) -> Any:
    """
    The env's ``random_transitions(n, seed, max_episode_steps)`` if it has one and no wrapper around it
    changes what it observes or receives (an observation wrapper would be bypassed), else None.
    """
    while isinstance(env, gym.Wrapper):
        if not isinstance(env, TRANSPARENT_WRAPPERS):
            return None
        env = env.env
    return getattr(env, "random_transitions", None)


def collect_transitions(
    env: gym.Env, n_transitions: int, seed: int | None = None, progress_bar: bool = False
) -> Transitions:
    """
    Collect transitions with a uniformly random policy, resetting the env whenever a trajectory ends.

    This is how the paper builds its source set Xi (section 4: 25,000 transitions, 2% termination,
    uniform reset); the rewards of the env's task are kept, ``TRLSD.load_transitions`` decides whether
    to use them. An env whose unwrapped object has a ``random_transitions(n, seed, max_episode_steps)``
    method (the maze) samples them itself, all trajectories at once, unless a wrapper that may change what
    it observes or receives is around it (see ``TRANSPARENT_WRAPPERS``); any other env is stepped one
    transition at a time, through its wrappers.

    :param env: a Gymnasium env with a Discrete action space and a Box (or ``{"state", "task"}`` Dict)
        observation space
    :param n_transitions: how many transitions to collect
    :param seed: seeds the env's reset and the random policy
    :param progress_bar: show a tqdm progress bar
    :return: the collected transitions
    """
    if n_transitions < 1:
        raise ValueError(f"n_transitions must be a positive integer, got {n_transitions}")
    if not isinstance(env.action_space, spaces.Discrete):
        raise ValueError(f"collect_transitions needs a Discrete action space, got {env.action_space}")
    sampler = own_sampler(env)
    if sampler is not None:
        # The env steps all its random trajectories at once (e.g. the maze): same process, much faster.
        max_steps = env.spec.max_episode_steps if env.spec is not None else None
        return Transitions(**sampler(n_transitions, seed=seed, max_episode_steps=max_steps))
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    dim = state_space_of(env.observation_space).shape[0]
    state, task = (value[0] for value in split_observation(obs, dim))
    columns: dict[str, list] = {field.name: [] for field in fields(Transitions)}
    for _ in tqdm(range(n_transitions), disable=not progress_bar, desc="collecting transitions"):
        action = env.action_space.sample()
        obs, reward, terminated, truncated, _ = env.step(action)
        next_state = split_observation(obs, dim)[0][0]
        for name, value in (
            ("states", state),
            ("actions", action),
            ("next_states", next_state),
            ("rewards", reward),
            ("tasks", task),
            ("truncations", truncated and not terminated),
            ("terminations", terminated),
        ):
            columns[name].append(value)
        if terminated or truncated:
            obs, _ = env.reset()
        state, task = (value[0] for value in split_observation(obs, dim))
    return Transitions(
        states=np.asarray(columns["states"], dtype=np.float64),
        actions=np.asarray(columns["actions"], dtype=np.int64),
        next_states=np.asarray(columns["next_states"], dtype=np.float64),
        rewards=np.asarray(columns["rewards"], dtype=np.float64),
        tasks=np.asarray(columns["tasks"], dtype=np.int64),
        truncations=np.asarray(columns["truncations"], dtype=bool),
        terminations=np.asarray(columns["terminations"], dtype=bool),
    )
