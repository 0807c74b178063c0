"""
Transitions from wherever a user kept them: SB3 replay buffers (``ReplayBuffer``, ``DictReplayBuffer``, and
TRLSD's own ``SharedDynamicsReplayBuffer`` and ``RelabellingReplayBuffer``), the ``.pkl`` files of
``save_replay_buffer``, Minari datasets, and ``Transitions`` (or their ``.npz``); and which task each row
belongs to.

A row's task is, in this order: the ``task=`` given, the ``"task"`` of its observation (a
``{"state", "task"}`` Dict), its ``Transitions.tasks`` entry. A row with none of these (a Box observation)
is *unlabelled*: it is stored under task 0, and its reward belongs to no task TRLSD knows, so
``keep_rewards=True`` on it warns (a single-task env: its rewards will be learnt as the env's) or is refused
(a multi-task env: which task's head would learn them?). ``task_rows`` holds that rule.
"""

from __future__ import annotations

import os
import pickle
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Union

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.save_util import load_from_pkl

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.observations import check_action_space, state_space_of, task_count_of

if TYPE_CHECKING:
    from minari import MinariDataset

__all__ = [
    "ACCEPTED",
    "ForeignRows",
    "TransitionSource",
    "minari_transitions",
    "read_rows",
    "replay_buffer_transitions",
    "rows_to_store",
]

TransitionSource = Union[
    Transitions, str, os.PathLike, ReplayBuffer, "MinariDataset", Sequence["TransitionSource"]
]
ACCEPTED = (
    "Transitions, the path of a Transitions .npz or of a save_replay_buffer .pkl, an SB3 ReplayBuffer or "
    "DictReplayBuffer (TRLSD's SharedDynamicsReplayBuffer and RelabellingReplayBuffer too), a "
    "minari.MinariDataset or the id of a local one, or a list of these"
)
UNLABELLED_REWARDS = (
    "keep_rewards=True: {n} of these rows carry no task (their observations have no 'task'), so their "
    "rewards will be learnt as the rewards of this env's task. If they were collected under another reward "
    "(another task of the same dynamics), load them with keep_rewards=False, which uses them for the "
    "dynamics only; give task=0 to say that they are this task's"
)


@dataclass(frozen=True)
class ForeignRows:
    """
    Transitions read from elsewhere, with what is known of each row.

    :param transitions: the rows (unlabelled rows under task 0)
    :param labelled: whether the row's task is known (``task=``, its observation's, its ``Transitions``
        entry), shape (n,)
    :param rewarded: whether the row's reward was observed (False: a TRLSD buffer's row whose reward was
        discarded, stored as 0), shape (n,)
    :param action_counts: the sizes of the action spaces the rows were collected in, where known
    """

    transitions: Transitions
    labelled: np.ndarray
    rewarded: np.ndarray
    action_counts: tuple[int, ...] = ()


def warn_user(message: str) -> None:
    """Warn, pointing at the first caller outside this package (the user's line that loaded the rows)."""
    package = os.path.dirname(__file__) + os.sep
    frame, level = sys._getframe(1), 2
    while frame.f_back is not None and frame.f_code.co_filename.startswith(package):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, stacklevel=level)


def check_task(task: int | None) -> None:
    """:raises ValueError: unless ``task`` is None or an integer >= 0"""
    if task is not None and (isinstance(task, bool) or not isinstance(task, (int, np.integer)) or task < 0):
        raise ValueError(f"task must be None (the rows' own task) or a task index >= 0, got {task!r}")


def _labelled(transitions: Transitions, has_tasks: bool, task: int | None) -> tuple[Transitions, np.ndarray]:
    """The rows with ``task`` written over their tasks when given, and which of them are labelled."""
    n = len(transitions)
    if task is not None:
        return replace(transitions, tasks=np.full(n, int(task), dtype=np.int64)), np.ones(n, dtype=bool)
    return transitions, np.full(n, has_tasks, dtype=bool)


def _concatenate(parts: Sequence[Transitions]) -> Transitions:
    names = [field.name for field in fields(Transitions)]
    return Transitions(**{name: np.concatenate([getattr(part, name) for part in parts]) for name in names})


def _spaces_of(observation_space: spaces.Space, action_space: spaces.Space, origin: str) -> tuple[int, int]:
    """The state dimension and the number of actions of a source's spaces; errors name the source."""
    try:
        return state_space_of(observation_space).shape[0], check_action_space(action_space)
    except ValueError as error:
        raise ValueError(f"{origin}: {error}") from error


# ------------------------------------------------------------------------------------ SB3 replay buffers
def _valid_rows(buffer: ReplayBuffer) -> np.ndarray:
    """The buffer's rows holding a transition, oldest first."""
    if not buffer.full:
        return np.arange(buffer.pos)
    rows = (buffer.pos + np.arange(buffer.buffer_size)) % buffer.buffer_size
    # With optimize_memory_usage, the oldest row's observation was overwritten by the newest next one.
    return rows[1:] if buffer.optimize_memory_usage else rows


def _sb3_rows(buffer: ReplayBuffer, task: int | None) -> ForeignRows:
    """
    An SB3 ``ReplayBuffer`` or ``DictReplayBuffer`` as rows: each env's transitions in turn, oldest first.
    Time limits (``timeouts``) stay truncations; the last row of each env, whose episode the buffer leaves
    unfinished, is marked truncated (the rows after it are another trajectory's).
    """
    origin = f"the {type(buffer).__name__}"
    dim, n_actions = _spaces_of(buffer.observation_space, buffer.action_space, origin)
    dict_observations = isinstance(buffer, DictReplayBuffer)
    rows = _valid_rows(buffer)
    next_rows = (rows + 1) % buffer.buffer_size
    parts = []
    dropped = 0
    for env in range(buffer.n_envs):
        if dict_observations:
            states = buffer.observations["state"][rows, env]
            next_states = buffer.next_observations["state"][rows, env]
            tasks = buffer.observations["task"][rows, env].reshape(-1)
        else:
            states = buffer.observations[rows, env]
            tasks = np.zeros(len(rows), dtype=np.int64)
            if buffer.optimize_memory_usage:
                next_states = buffer.observations[next_rows, env]
            else:
                next_states = buffer.next_observations[rows, env]
        if states.shape[1:] != (dim,):
            raise ValueError(f"{origin} holds states of shape {states.shape[1:]}, its space says ({dim},)")
        dones = buffer.dones[rows, env].astype(bool)
        timeouts = buffer.timeouts[rows, env].astype(bool) & dones
        kept = np.ones(len(rows), dtype=bool)
        if buffer.optimize_memory_usage:
            # The observation after an episode's last step is the next episode's first: its next is lost.
            kept = ~dones
            dropped += int(np.count_nonzero(dones))
        truncations = timeouts.copy()
        if len(rows):
            truncations[-1] |= not dones[-1]
        part = Transitions(
            states=states.astype(np.float64),
            actions=buffer.actions[rows, env].reshape(len(rows), -1)[:, 0].astype(np.int64),
            next_states=next_states.astype(np.float64),
            rewards=buffer.rewards[rows, env].astype(np.float64),
            tasks=tasks.astype(np.int64),
            truncations=truncations,
            terminations=dones & ~timeouts,
        )
        parts.append(part.take(kept))
    transitions = _concatenate(parts)
    if dropped:
        warn_user(
            f"{origin} was made with optimize_memory_usage=True, which keeps no next observation for an "
            f"episode's last step (the row after it holds the next episode's first) and cannot tell time "
            f"limits from terminations: its {dropped} episode-ending rows are left out. A buffer made with "
            "optimize_memory_usage=False keeps them"
        )
    elif not buffer.handle_timeout_termination and transitions.terminations.any():
        warn_user(
            f"{origin} was made with handle_timeout_termination=False: it cannot tell time limits from "
            f"terminations, so its {int(transitions.terminations.sum())} episode ends are read as "
            "terminations (absorbing states, no bootstrap), as SB3 learns from them"
        )
    transitions, labelled = _labelled(transitions, dict_observations, task)
    return ForeignRows(transitions, labelled, np.ones(len(transitions), dtype=bool), (n_actions,))


def _trlsd_buffer_rows(buffer: SharedDynamicsReplayBuffer, task: int | None) -> ForeignRows:
    """A TRLSD buffer's rows, oldest first: its tasks are labels when it holds several tasks."""
    transitions = buffer.transitions()
    rewarded = buffer._flat(buffer.has_reward).astype(bool)
    transitions, labelled = _labelled(transitions, buffer.n_tasks > 1, task)
    assert isinstance(buffer.action_space, spaces.Discrete)
    return ForeignRows(transitions, labelled, rewarded, (int(buffer.action_space.n),))


def replay_buffer_rows(buffer: ReplayBuffer, task: int | None = None) -> ForeignRows:
    """
    The rows of an SB3 replay buffer: a ``ReplayBuffer`` (any ``n_envs``, ``optimize_memory_usage`` or not)
    or a ``DictReplayBuffer`` of ``{"state", "task"}`` observations, or a TRLSD buffer.

    :param buffer: the buffer
    :param task: the task of every row (None: the observations' own, where they carry one)
    :raises ValueError: for a buffer whose spaces are not a state Box (or ``{"state", "task"}`` Dict) and
        Discrete actions
    """
    check_task(task)
    if isinstance(buffer, SharedDynamicsReplayBuffer):
        return _trlsd_buffer_rows(buffer, task)
    return _sb3_rows(buffer, task)


def _require_labels(rows: ForeignRows, origin: str) -> Transitions:
    if not rows.labelled.all():
        raise ValueError(
            f"{origin}'s observations carry no task (a Box observation), and Transitions need one per row: "
            "say which task they were collected on with task=k (on a single-task env, 0 if their rewards are "
            "the target's own, any other index if they come from another task)"
        )
    return rows.transitions


def replay_buffer_transitions(buffer: ReplayBuffer, task: int | None = None) -> Transitions:
    """
    ``Transitions.from_replay_buffer``: the transitions of an SB3 replay buffer (``replay_buffer_rows``),
    every row labelled with a task.

    :raises ValueError: when the observations carry no task and ``task`` is None
    """
    if not isinstance(buffer, ReplayBuffer):
        raise TypeError(f"expected an SB3 ReplayBuffer or DictReplayBuffer, got {type(buffer).__name__}")
    return _require_labels(replay_buffer_rows(buffer, task), f"the {type(buffer).__name__}")


# ---------------------------------------------------------------------------------------------- Minari
def _is_minari_dataset(data: object) -> bool:
    # Whoever holds a MinariDataset has imported minari: the check imports nothing.
    minari = sys.modules.get("minari")
    return minari is not None and isinstance(data, minari.MinariDataset)


def minari_rows(dataset: MinariDataset, task: int | None = None) -> ForeignRows:
    """
    The rows of a Minari dataset's episodes, in order. An episode of n steps has n + 1 observations; its
    ``terminations`` and ``truncations`` are per step, and an episode that ends with neither (cut by the end
    of the collection) is marked truncated at its last step.

    :param dataset: a ``minari.MinariDataset`` whose observations are a state Box or a ``{"state", "task"}``
        Dict and whose actions are Discrete
    :param task: the task of every row (None: the observations' own, where they carry one)
    """
    check_task(task)
    origin = f"the Minari dataset {dataset.id!r}"
    dim, n_actions = _spaces_of(dataset.observation_space, dataset.action_space, origin)
    dict_observations = isinstance(dataset.observation_space, spaces.Dict)
    parts = []
    for episode in dataset.iterate_episodes():
        n = len(episode.actions)
        observations = episode.observations
        states = np.asarray(observations["state"] if dict_observations else observations)
        if states.shape != (n + 1, dim):
            raise ValueError(
                f"{origin}: episode {episode.id} has {n} actions and observations of shape {states.shape}, "
                f"expected ({n + 1}, {dim}) (one more observation than actions)"
            )
        if n == 0:
            continue
        tasks = (
            np.asarray(observations["task"]).reshape(-1)[:-1] if dict_observations else np.zeros(n, np.int64)
        )
        terminations = np.asarray(episode.terminations, dtype=bool)
        truncations = np.asarray(episode.truncations, dtype=bool) & ~terminations
        truncations[-1] |= not terminations[-1]
        parts.append(
            Transitions(
                states=states[:-1].astype(np.float64),
                actions=np.asarray(episode.actions).reshape(n, -1)[:, 0].astype(np.int64),
                next_states=states[1:].astype(np.float64),
                rewards=np.asarray(episode.rewards, dtype=np.float64).reshape(-1),
                tasks=tasks.astype(np.int64),
                truncations=truncations,
                terminations=terminations,
            )
        )
    if not parts:
        raise ValueError(f"{origin} holds no transition")
    transitions, labelled = _labelled(_concatenate(parts), dict_observations, task)
    return ForeignRows(transitions, labelled, np.ones(len(transitions), dtype=bool), (n_actions,))


def minari_transitions(dataset: MinariDataset, task: int | None = None) -> Transitions:
    """
    ``Transitions.from_minari``: the transitions of a Minari dataset (``minari_rows``), every row labelled
    with a task.

    :raises ValueError: when the observations carry no task and ``task`` is None
    """
    if not _is_minari_dataset(dataset):
        raise TypeError(f"expected a minari.MinariDataset, got {type(dataset).__name__}")
    return _require_labels(minari_rows(dataset, task), f"the Minari dataset {dataset.id!r}")


def _minari_dataset(dataset_id: str) -> MinariDataset | None:
    """The local Minari dataset of that id (nothing is downloaded), None when there is none."""
    try:
        import minari
    except ImportError:
        return None
    try:
        return minari.load_dataset(dataset_id)
    except (FileNotFoundError, ValueError):
        return None


# ------------------------------------------------------------------------------------------- dispatch
def _path_rows(path: str | os.PathLike, task: int | None) -> ForeignRows:
    """A file's rows (a ``.pkl`` of ``save_replay_buffer``, else a ``Transitions`` .npz), or a Minari id's."""
    name = os.fspath(path)
    file = Path(name)
    pickled = file.suffix == ".pkl" or (not file.exists() and Path(f"{name}.pkl").is_file())
    if pickled:
        try:
            buffer = load_from_pkl(name)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError) as error:
            raise ValueError(f"cannot read a replay buffer from {name!r}: {error}") from error
        if not isinstance(buffer, ReplayBuffer):
            raise ValueError(f"{name!r} holds a {type(buffer).__name__}, not an SB3 replay buffer")
        return replay_buffer_rows(buffer, task)
    if file.exists():
        transitions, labelled = _labelled(Transitions.load(name), True, task)
        return ForeignRows(transitions, labelled, np.ones(len(transitions), dtype=bool))
    dataset = _minari_dataset(name) if isinstance(path, str) else None
    if dataset is None:
        minari_hint = "" if "minari" in sys.modules else " (Minari ids need pip install 'sb3-trlsd[minari]')"
        raise ValueError(
            f"{name!r} is neither a file nor the id of a local Minari dataset{minari_hint}; transitions can "
            f"be {ACCEPTED}"
        )
    return minari_rows(dataset, task)


def read_rows(data: TransitionSource, task: int | None = None) -> ForeignRows:
    """
    The rows of any source of transitions TRLSD takes (``ACCEPTED``). A ``.pkl`` is unpickled (SB3's
    ``load_from_pkl``), which runs the code it names: load only files you made.

    :param data: the source, or a list of sources (concatenated in order)
    :param task: the task of every row (None: each row's own, where it has one)
    :raises TypeError: for any other kind of object, listing the accepted ones
    """
    check_task(task)
    if isinstance(data, Transitions):
        transitions, labelled = _labelled(data, True, task)
        return ForeignRows(transitions, labelled, np.ones(len(transitions), dtype=bool))
    if isinstance(data, (str, os.PathLike)):
        return _path_rows(data, task)
    if isinstance(data, ReplayBuffer):
        return replay_buffer_rows(data, task)
    if _is_minari_dataset(data):
        return minari_rows(data, task)
    if isinstance(data, (list, tuple)):
        if not data:
            raise ValueError("an empty list holds no transitions")
        parts = [read_rows(part, task) for part in data]
        return ForeignRows(
            _concatenate([part.transitions for part in parts]),
            np.concatenate([part.labelled for part in parts]),
            np.concatenate([part.rewarded for part in parts]),
            tuple(count for part in parts for count in part.action_counts),
        )
    hint = ""
    if hasattr(data, "replay_buffer"):
        hint = " (an SB3 model: give its buffer, model.replay_buffer)"
    raise TypeError(f"transitions can be {ACCEPTED}; got {type(data).__name__}{hint}")


# ------------------------------------------------------------------------------------ task labels
def task_rows(rows: ForeignRows, keep_rewards: bool, n_tasks: int) -> tuple[Transitions, np.ndarray]:
    """
    The rows as a model of ``n_tasks`` tasks stores them, and whether each teaches its task's head.

    - A single-task env (a Box observation) stores every row as task 0. With ``keep_rewards``, rows of
      another task are refused (their rewards are not this task's) and unlabelled rows warn once.
    - A multi-task env stores each row under its task, which must be one of its own; unlabelled rows go under
      task 0. With ``keep_rewards``, unlabelled rows are refused (no head is theirs).
    - Rows whose reward was discarded (``rewarded`` False) never teach a head.

    :param rows: the rows read (``read_rows``)
    :param keep_rewards: whether the rows' rewards are to be learnt
    :param n_tasks: the model's number of tasks
    :return: the rows to store, and whether each keeps its reward, (n,)
    :raises ValueError: as above, saying what to do instead
    """
    transitions, labelled = rows.transitions, rows.labelled
    labels = np.unique(transitions.tasks[labelled])
    if keep_rewards and n_tasks == 1 and np.any(labels != 0):
        raise ValueError(
            f"keep_rewards=True would learn the rewards of task(s) {labels[labels != 0].tolist()} as this "
            "env's: an env of Box observations has one task, 0. Load rows of another task with "
            "keep_rewards=False (their dynamics only), or with task=0 if their rewards are this task's"
        )
    if keep_rewards and n_tasks > 1 and not labelled.all():
        raise ValueError(
            f"keep_rewards=True needs each row's task, and {int(np.count_nonzero(~labelled))} of these rows "
            f"carry none (their observations have no 'task'): give task=k, the task of this env "
            f"(0..{n_tasks - 1}) whose rewards they are, or keep_rewards=False"
        )
    if n_tasks > 1 and np.any(labels >= n_tasks):
        raise ValueError(
            f"tasks must be in 0..{n_tasks - 1} (the env's tasks), got {labels[labels >= n_tasks].tolist()}: "
            "give task=k to load them as task k's"
        )
    if keep_rewards and n_tasks == 1 and not labelled.all():
        warn_user(UNLABELLED_REWARDS.format(n=int(np.count_nonzero(~labelled))))
    if n_tasks == 1:
        transitions = replace(transitions, tasks=np.zeros(len(transitions), dtype=np.int64))
    return transitions, keep_rewards & rows.rewarded


def rows_to_store(
    data: TransitionSource,
    task: int | None,
    keep_rewards: bool,
    observation_space: spaces.Space,
    action_space: spaces.Space,
) -> list[tuple[Transitions, bool]]:
    """
    What ``TRLSD.load_transitions`` stores: the rows of ``data`` checked against the model's spaces and
    labelled by ``task_rows``, in runs of consecutive rows that keep their rewards or not.

    :param data: any of ``ACCEPTED``
    :param task: the task of every row (None: each row's own, where it has one)
    :param keep_rewards: whether their rewards teach their tasks' heads
    :param observation_space: the model's observation space
    :param action_space: the model's action space
    :return: ``(rows, keep their rewards)`` in order
    :raises ValueError: for rows that do not fit the model (state dimension, actions, tasks)
    """
    rows = read_rows(data, task)
    dim = state_space_of(observation_space).shape[0]
    n_actions = check_action_space(action_space)
    transitions = rows.transitions
    foreign = sorted(set(rows.action_counts) - {n_actions})
    if foreign:
        raise ValueError(
            f"the transitions were collected with {foreign[0]} actions, this model's env has {n_actions}: "
            "they come from another env"
        )
    if transitions.state_dim != dim:
        raise ValueError(
            f"the transitions' states have {transitions.state_dim} dimension(s), this model's env {dim}: "
            "they come from another env"
        )
    if len(transitions) and (transitions.actions.min() < 0 or transitions.actions.max() >= n_actions):
        raise ValueError(
            f"the transitions' actions range over {transitions.actions.min()}..{transitions.actions.max()}, "
            f"this model's env has {n_actions} (0..{n_actions - 1}): they come from another env"
        )
    transitions, kept = task_rows(rows, keep_rewards, task_count_of(observation_space))
    if len(transitions) == 0:
        return []
    bounds = np.flatnonzero(np.diff(kept.astype(np.int8))) + 1
    starts, stops = np.concatenate([[0], bounds]), np.concatenate([bounds, [len(transitions)]])
    return [(transitions.take(np.arange(a, b)), bool(kept[a])) for a, b in zip(starts, stops, strict=True)]
