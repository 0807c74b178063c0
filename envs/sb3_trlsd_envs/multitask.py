"""What the task families beyond the maze share: naming their tasks, scheduling a task per trajectory,
rewarding the state a step starts from, checking their arguments, and stepping many random trajectories
at once for ``random_transitions``."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

__all__ = [
    "TASK_SCHEDULES",
    "TaskFamilyEnv",
    "TaskSchedule",
    "check_non_negative",
    "check_render_mode",
    "random_rollouts",
]

TASK_SCHEDULES = ("fixed", "round_robin", "random")
StepFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def check_task(task: Any, n_tasks: int) -> int:
    """
    A task index, validated.

    :param task: an integer in ``0..n_tasks - 1`` (a 0-d array too)
    :param n_tasks: the family's number of tasks
    :return: the index as an ``int``
    :raises ValueError: naming ``task`` for anything else
    """
    if isinstance(task, np.ndarray) and task.ndim == 0:
        task = task.item()
    if isinstance(task, (int, np.integer)) and not isinstance(task, bool) and 0 <= task < n_tasks:
        return int(task)
    raise ValueError(f"task must be an index in 0..{n_tasks - 1}, got {task!r}")


def check_non_negative(**values: float) -> None:
    """Raise a ValueError naming the first argument that is not a number >= 0 (NaN included)."""
    for name, value in values.items():
        if not value >= 0:
            raise ValueError(f"{name} must be >= 0, got {value}")


def check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    """Raise a ValueError naming ``render_mode`` unless it is None or one of ``metadata["render_modes"]``."""
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}"
        )


def warn_no_render_mode() -> None:
    """What ``render`` says without a render mode, as Gymnasium's own envs do (then it returns None)."""
    gym.logger.warn(
        'You are calling render method without specifying any render mode; pass render_mode="rgb_array" at '
        "initialization"
    )


def trajectory_lengths(
    rng: np.random.Generator, termination_prob: float, n_transitions: int, cap: int
) -> tuple[np.ndarray, np.ndarray]:
    """
    Lengths of the trajectories that make up ``n_transitions`` transitions.

    :param rng: random generator
    :param termination_prob: probability of a reset after each step (lengths are geometric)
    :param n_transitions: total length
    :param cap: time limit of a trajectory
    :return: the drawn lengths, and the same with the last one cut so that they sum to ``n_transitions``
    """
    lengths: list[int] = []
    while sum(lengths) < n_transitions:
        drawn = rng.geometric(termination_prob, size=64) if termination_prob > 0 else [cap] * 64
        lengths.extend(int(min(length, cap)) for length in drawn)
    ends = np.cumsum(lengths)
    n_trajectories = int(np.searchsorted(ends, n_transitions) + 1)
    full_lengths = np.array(lengths[:n_trajectories])
    cut_lengths = full_lengths.copy()
    cut_lengths[-1] -= int(ends[n_trajectories - 1]) - n_transitions
    return full_lengths, cut_lengths


class TaskSchedule:
    """
    The tasks an env serves and which one each trajectory gets.

    :param n_tasks: the family's number of tasks
    :param task: one task index (default 0); or
    :param tasks: several, a list of indices or ``"all"``
    :param schedule: ``"fixed"`` (the first task), ``"round_robin"`` (in turn, one trajectory each) or
        ``"random"`` (uniform among ``tasks``, for each trajectory)
    :raises ValueError: naming ``task``, ``tasks`` or ``task_schedule``
    """

    def __init__(
        self,
        n_tasks: int,
        task: int | None = None,
        tasks: str | Sequence[int] | None = None,
        schedule: str = "fixed",
    ):
        if task is not None and tasks is not None:
            raise ValueError("pass either task or tasks, not both")
        if schedule not in TASK_SCHEDULES:
            raise ValueError(f"task_schedule must be one of {TASK_SCHEDULES}, got {schedule!r}")
        if isinstance(tasks, str) and tasks != "all":
            raise ValueError(f"tasks must be 'all' or a list of task indices, got {tasks!r}")
        if tasks is None:
            tasks = [0 if task is None else task]
        self.tasks = tuple(range(n_tasks)) if tasks == "all" else tuple(check_task(t, n_tasks) for t in tasks)
        if not self.tasks:
            raise ValueError("tasks must name at least one task")
        self.n_tasks = n_tasks
        self.schedule = schedule
        self._n_scheduled = 0  # trajectories whose task the round robin chose

    def check(self, task: Any) -> int:
        """``task`` as an index of the family, or a ValueError naming ``task``."""
        return check_task(task, self.n_tasks)

    def next_task(self, np_random: np.random.Generator, seed: int | None, options: dict | None) -> int:
        """
        The task of a new trajectory, as ``reset(seed=seed, options=options)`` asks for it.

        A seeded reset restarts the round robin (same seed, same trajectory); ``options={"task": t}`` forces
        any of the family's tasks for this trajectory without taking a turn of the round robin.
        """
        if seed is not None:
            self._n_scheduled = 0
        if options and options.get("task") is not None:
            return self.check(options["task"])
        if self.schedule == "random":
            return self.tasks[int(np_random.integers(len(self.tasks)))]
        if self.schedule == "round_robin":
            self._n_scheduled += 1
            return self.tasks[(self._n_scheduled - 1) % len(self.tasks)]
        return self.tasks[0]

    def draw(self, rng: np.random.Generator, n_trajectories: int, first: int = 0) -> np.ndarray:
        """The tasks of trajectories ``first .. first + n_trajectories - 1`` of a run that starts afresh."""
        tasks = np.asarray(self.tasks)
        if self.schedule == "random":
            return tasks[rng.integers(len(tasks), size=n_trajectories)]
        if self.schedule == "round_robin":
            return tasks[(first + np.arange(n_trajectories)) % len(tasks)]
        return np.full(n_trajectories, tasks[0])


def random_rollouts(
    rng: np.random.Generator, starts: np.ndarray, max_lengths: np.ndarray, step: StepFn, n_actions: int
) -> dict[str, np.ndarray]:
    """
    Trajectories of a uniformly random policy, all stepped at once.

    Trajectory k starts from ``starts[k]`` and runs until it terminates or has made ``max_lengths[k]``
    steps. Actions are drawn from ``rng`` one time step at a time, for the trajectories still running.

    :param rng: random generator of the actions (``step`` may use it too)
    :param starts: (k, d) start states
    :param max_lengths: (k,) the most steps each trajectory makes
    :param step: ``step(states (m, d), actions (m,)) -> (next_states (m, d), terminated (m,))``
    :param n_actions: actions are drawn uniformly in ``0..n_actions - 1``
    :return: ``states``, ``actions``, ``next_states``, ``terminations`` (one row per transition, trajectory
        after trajectory, in time order within each) and ``trajectories`` (the index k of each row)
    """
    assert len(starts) == len(max_lengths) and np.min(max_lengths, initial=1) >= 1, "no empty trajectories"
    running, states = np.arange(len(starts)), np.asarray(starts, dtype=np.float64)
    steps: list[tuple[np.ndarray, ...]] = []
    for time in range(int(np.max(max_lengths, initial=0))):
        below_cap = max_lengths[running] > time
        running, states = running[below_cap], states[below_cap]
        if not len(running):
            break
        actions = rng.integers(n_actions, size=len(running))
        next_states, terminated = step(states, actions)
        steps.append((running, actions, states, next_states, terminated))
        running, states = running[~terminated], next_states[~terminated]
    columns = [np.concatenate(column) for column in zip(*steps, strict=True)]
    # Rows were added time step after time step; a stable sort by trajectory keeps their time order.
    order = np.argsort(columns[0], kind="stable")
    names = ("trajectories", "actions", "states", "next_states", "terminations")
    return {name: column[order] for name, column in zip(names, columns, strict=True)}


class TaskFamilyEnv(gym.Env):
    """
    A family of tasks sharing one dynamics: each trajectory gets a task from its schedule, and a step's
    reward is drawn for the state s_t it starts from, ``expected_reward(s_t) + N(0, reward_noise_std)``,
    before the move. Observations are ``{"state": ..., "task": index}``.

    A family sets ``action_meaning``, ``metadata``, the spaces, and implements ``expected_reward``,
    ``state`` (the dynamics' state), ``_start`` (a new trajectory's state), ``_move`` (apply an action),
    ``_observed_state``, ``_info`` and ``_render``.

    :param n_tasks: the family's number of tasks
    :param task: the task index (default 0); or
    :param tasks: several, a list or ``"all"``
    :param task_schedule: ``"fixed"``, ``"round_robin"`` or ``"random"`` (see :class:`TaskSchedule`)
    :param reward_noise_std: standard deviation of the reward noise
    :param render_mode: None or one of ``metadata["render_modes"]``
    """

    action_meaning: ClassVar[str]  # what a valid action is, for the error on an invalid one
    state: np.ndarray

    def __init__(
        self,
        n_tasks: int,
        task: int | None = None,
        tasks: str | Sequence[int] | None = None,
        task_schedule: str = "fixed",
        reward_noise_std: float = 0.0,
        render_mode: str | None = None,
    ):
        self.schedule = TaskSchedule(n_tasks, task, tasks, task_schedule)
        check_non_negative(reward_noise_std=reward_noise_std)
        check_render_mode(render_mode, self.metadata)
        self.tasks, self.task_schedule = self.schedule.tasks, task_schedule
        self.reward_noise_std = reward_noise_std
        self.render_mode = render_mode
        self.task = self.schedule.tasks[0]

    def expected_reward(self, states: np.ndarray, task: int | None = None) -> np.ndarray:
        """Noise-free E[R_task(s)] for an ``(n, d)`` array of states (default: the current task)."""
        raise NotImplementedError

    def _start(self) -> None:
        """Draw the state of a new trajectory from ``self.np_random``."""
        raise NotImplementedError

    def _move(self, action: int) -> tuple[bool, bool]:
        """Apply a valid action to the state; return ``terminated, truncated``."""
        raise NotImplementedError

    def _observed_state(self) -> np.ndarray:
        raise NotImplementedError

    def _info(self) -> dict[str, Any]:
        raise NotImplementedError

    def _render(self) -> np.ndarray:
        raise NotImplementedError

    def _observation(self) -> dict[str, Any]:
        return {"state": self._observed_state(), "task": self.task}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """
        Start a trajectory with the task its schedule gives.

        :param seed: reseeds ``self.np_random`` and restarts the round robin
        :param options: ``{"task": index}`` forces the task of this trajectory
        :return: the observation and ``info``
        """
        super().reset(seed=seed)
        self.task = self.schedule.next_task(self.np_random, seed, options)
        self._start()
        return self._observation(), self._info()

    def step(self, action):
        """
        Act, rewarding the state the action starts from.

        :param action: see ``action_meaning``
        :return: observation, reward, ``terminated``, ``truncated``, ``info``
        :raises ValueError: naming the action when it is not in the action space
        """
        if not self.action_space.contains(action):
            raise ValueError(f"action must be {self.action_meaning}, got {action!r}")
        reward = self.expected_reward(self.state[None])[0] + self.reward_noise_std * self.np_random.normal()
        terminated, truncated = self._move(int(action))
        return self._observation(), float(reward), terminated, truncated, self._info()

    def render(self):
        """The picture of ``render_mode="rgb_array"``; without a render mode, a warning and None."""
        if self.render_mode is None:
            warn_no_render_mode()
            return None
        return self._render()
