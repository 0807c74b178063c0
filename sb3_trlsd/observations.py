"""What TRLSD reads from an observation: a state vector, and the task it belongs to.

An env with one task observes its state as a Box; a multi-task env as a ``{"state": Box, "task":
Discrete}`` Dict, its tasks numbered from 0. Everything that unpacks an observation goes through
``split_observation``, which refuses states that are not finite; ``StateBoxMonitor`` warns, once, of
states found outside the box TRLSD's features and similarities are taken relative to.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

__all__ = [
    "MAX_BOX_SIDE",
    "StateBoxMonitor",
    "StateOutsideBoxWarning",
    "WideStateBoxWarning",
    "check_action_space",
    "outside_box_message",
    "read_observation",
    "split_observation",
    "state_space_of",
    "states_outside",
    "task_count_of",
    "wide_box_message",
]


def state_space_of(observation_space: spaces.Space) -> spaces.Box:
    """
    The Box holding the state: the observation space itself, or its ``"state"`` entry for the
    ``{"state", "task"}`` Dict observations of multi-task envs.

    :raises ValueError: for any other observation space, a ``"task"`` Discrete not starting at 0, or a
        state Box that is not a vector of at least one number
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
        if task_space.start != 0:
            # Tasks index the reward heads, Q-functions and source data: one numbering, from 0, everywhere.
            raise ValueError(
                f"the 'task' Discrete must number its tasks from 0, got {task_space}: "
                f"wrap the env so that its tasks are 0..{task_space.n - 1} (gymnasium.wrappers."
                f"TransformObservation subtracting {task_space.start} from the task, with a 'task' "
                f"Discrete({task_space.n}))"
            )
    elif isinstance(observation_space, spaces.Box):
        state_space = observation_space
    else:
        hint = ""
        if isinstance(observation_space, spaces.Discrete):  # a tabular env's state index
            first, last = int(observation_space.start), int(observation_space.start + observation_space.n - 1)
            hint = (
                ": give the state index as a Box of integers, on which the default features are one per "
                "state (gymnasium.wrappers.TransformObservation(env, lambda s: np.array([s]), "
                f"Box({first}, {last}, (1,), np.int64)))"
            )
        raise ValueError(
            "observation_space must be a Box or a Dict with a 'state' Box and a 'task' Discrete, "
            f"got {observation_space}{hint}"
        )
    assert isinstance(state_space, spaces.Box)
    if len(state_space.shape) != 1:
        raise ValueError(
            f"the state Box must be one-dimensional (a vector), got shape {state_space.shape}: flatten it "
            "(gymnasium.wrappers.FlattenObservation)"
        )
    if state_space.shape[0] == 0:
        raise ValueError(
            "the state Box must have at least one dimension, got shape (0,): TRLSD learns a task's reward "
            "and Q as functions of the state; give the env a state of at least one number"
        )
    return state_space


def task_count_of(observation_space: spaces.Space) -> int:
    """The number of tasks: the ``"task"`` Discrete's size, 1 for a plain Box observation."""
    state_space_of(observation_space)
    if isinstance(observation_space, spaces.Dict):
        task_space = observation_space["task"]
        assert isinstance(task_space, spaces.Discrete)  # state_space_of refuses any other
        return int(task_space.n)
    return 1


def check_action_space(action_space: spaces.Space) -> int:
    """
    The number of actions of a Discrete action space whose actions are 0..n-1, the indices TRLSD's
    Q-functions return (a ``Discrete(n, start=k)`` would be sent actions outside it).

    :param action_space: the env's action space
    :return: n
    :raises ValueError: for a space that is not Discrete, or one not starting at 0
    """
    if not isinstance(action_space, spaces.Discrete):
        raise ValueError(f"action_space must be Discrete, got {action_space}")
    if action_space.start != 0:
        raise ValueError(
            f"action_space must number its actions from 0, got {action_space}: "
            f"wrap the env so that its actions are 0..{action_space.n - 1} (gymnasium.wrappers."
            f"TransformAction(env, lambda action: action + {action_space.start}, Discrete({action_space.n})))"
        )
    return int(action_space.n)


def split_observation(
    obs: Any, state_dim: int, *, task_count: int | None = None, require_finite: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """
    The states and tasks of an observation, single or batched, as numpy arrays (torch tensors accepted).

    :param obs: a Box observation (d,) or (n, d), or a ``{"state", "task"}`` Dict of them
    :param state_dim: d
    :param task_count: the number of tasks, to check the tasks against (None: not checked)
    :param require_finite: refuse states with a NaN or an infinite value (to act on one, or learn from it,
        would give an arbitrary action or Q-function). False for a caller that checks them itself.
    :return: states (n, d) float64 and tasks (n,) int64 (all 0 for a Box observation)
    :raises ValueError: for tasks that are not integers (or not in 0..task_count-1), a count of tasks that
        does not match the states', or (with ``require_finite``) states that are not finite
    """
    if isinstance(obs, dict):
        states = _states_of(_as_array(obs["state"]), state_dim)
        tasks = _as_array(obs["task"]).reshape(-1)
        if len(tasks) == 1 and len(states) > 1:  # one task for a batch of states
            tasks = np.repeat(tasks, len(states))
    else:
        states = _states_of(_as_array(obs), state_dim)
        tasks = np.zeros(len(states), dtype=np.int64)
    if len(tasks) != len(states):
        raise ValueError(f"an observation has {len(states)} states but {len(tasks)} tasks")
    if np.any(tasks != np.round(tasks)):
        raise ValueError(f"tasks must be integers, got {tasks}")
    if task_count is not None and np.any((tasks < 0) | (tasks >= task_count)):
        raise ValueError(f"tasks must be in 0..{task_count - 1}, got {np.unique(tasks)}")
    states = states.astype(np.float64)
    finite = np.isfinite(states)
    if require_finite and not finite.all():
        dimensions = np.flatnonzero(~finite.all(axis=0))
        raise ValueError(
            f"states must be finite: {np.count_nonzero(~finite.all(axis=1))} of {len(states)} state(s) have "
            f"{states[~finite][0]} in dimension(s) {dimensions.tolist()}; TRLSD can neither act on nor learn "
            "from them: check the env's observations"
        )
    return states, tasks.astype(np.int64)


def read_observation(obs: Any, observation_space: spaces.Space) -> tuple[np.ndarray, np.ndarray]:
    """
    ``split_observation`` of an observation that TRLSD acts on, checked against the env's observation
    space: a Dict space's observations must be ``{"state", "task"}`` dicts, their tasks in its ``"task"``
    Discrete, and the states finite.

    :param obs: an observation (d,) or a batch (n, d), or a ``{"state", "task"}`` Dict of them
    :param observation_space: the env's observation space
    :return: states (n, d) float64 and tasks (n,) int64
    :raises ValueError: naming what does not fit the space, and what to pass instead
    """
    state_dim = state_space_of(observation_space).shape[0]
    n_tasks = task_count_of(observation_space)
    if isinstance(observation_space, spaces.Dict) and not isinstance(obs, dict):
        raise ValueError(
            f"the observation must be a {{'state': ..., 'task': ...}} dict, as the env's Dict observation "
            f"space gives, got a {type(obs).__name__} of shape {np.shape(_as_array(obs))}: pass "
            "{'state': states, 'task': tasks}"
        )
    states, tasks = split_observation(obs, state_dim, require_finite=True)
    if np.any((tasks < 0) | (tasks >= n_tasks)):
        raise ValueError(
            f"the observation's tasks must be in 0..{n_tasks - 1} (the observation space's 'task' "
            f"Discrete({n_tasks})), got {np.unique(tasks[(tasks < 0) | (tasks >= n_tasks)])}: an env (or a "
            "caller) gives a task outside its observation space; make its 'task' Discrete hold every task"
        )
    return states, tasks


class StateOutsideBoxWarning(UserWarning):
    """
    A state was found outside the box TRLSD's features and similarities are taken relative to (the state
    Box's bounds, or ``state_bounds``). Filter it with ``warnings.filterwarnings("ignore",
    category=StateOutsideBoxWarning)``.
    """


def states_outside(states: np.ndarray, low: np.ndarray, high: np.ndarray) -> dict[int, float]:
    """
    The dimensions in which some state lies outside the box [low, high], each with its value furthest
    outside. A state within float32 rounding of a bound counts as inside (observations are often float32).

    :param states: (n, d)
    :param low: (d,) lower bounds of the box
    :param high: (d,) upper bounds of the box
    :return: ``{dimension: value}``, empty when every state is in the box
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, len(low))
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    if not len(states):
        return {}
    rounding = 4 * np.finfo(np.float32).eps
    lowest, highest = states.min(axis=0), states.max(axis=0)
    below = low * (1 + np.where(low > 0, -rounding, rounding)) - lowest  # > 0: that far below the box
    above = highest - high * (1 + np.where(high > 0, rounding, -rounding))
    return {
        int(dimension): float(
            lowest[dimension] if below[dimension] >= above[dimension] else highest[dimension]
        )
        for dimension in np.flatnonzero((below > 0) | (above > 0))
    }


def outside_box_message(outside: dict[int, float], low: np.ndarray, high: np.ndarray) -> str:
    """
    The warning for states found outside the box: each dimension, its value and its bounds, and what to do.

    :param outside: ``states_outside``'s result (not empty)
    :param low: (d,) lower bounds of the box
    :param high: (d,) upper bounds of the box
    """
    found = ", ".join(
        f"dimension {dimension}: {value:.6g} (box [{low[dimension]:.6g}, {high[dimension]:.6g}])"
        for dimension, value in outside.items()
    )
    return (
        f"states outside the state box were found ({found}). TRLSD's features and similarities are taken "
        "relative to the box, the state Box's bounds or state_bounds: outside it they extrapolate. Give "
        "state_bounds=(low, high) with the range the states really take, or wrap the env so that its states "
        "stay in its Box (gymnasium.wrappers.TransformObservation with np.clip). Warned once."
    )


class WideStateBoxWarning(UserWarning):
    """
    The state Box is so wide (a side beyond ``MAX_BOX_SIDE``) that TRLSD's features and similarities, taken
    relative to it, cannot tell states of ordinary scale apart. Give ``state_bounds``.
    """


# Beyond this side, in the env's units, a Box is most likely a stand-in for an unbounded dimension
# (Gymnasium's envs use +-float32 max, 3.4e38): states within +-1e3 of each other span less than a thousandth
# of it, where features and similarities of widths a few hundredths of the box (the defaults) differ by well
# under 1%; at 3.4e38 they are equal to float64's precision, and so is Q at every state.
MAX_BOX_SIDE = 1e6


def wide_box_message(dimensions: Sequence[int], low: np.ndarray, high: np.ndarray) -> str:
    """
    The warning for a state Box whose side exceeds ``MAX_BOX_SIDE`` in ``dimensions``: the sides, and what
    to give instead.

    :param dimensions: the dimensions too wide
    :param low: (d,) lower bounds of the box
    :param high: (d,) upper bounds of the box
    """
    found = ", ".join(f"dimension {d}: [{low[d]:.3g}, {high[d]:.3g}]" for d in dimensions)
    return (
        f"the state Box is wider than {MAX_BOX_SIDE:.0e} in {found}: TRLSD takes its features and "
        "similarities relative to the box, so states of ordinary scale all sit near its centre with the same "
        "features, and Q is the same at every state; give state_bounds=(low, high) with the range the states "
        "really take"
    )


class StateBoxMonitor:
    """
    Warns (``StateOutsideBoxWarning``), the first time only, of states found outside the box [low, high].
    One per model: the warning is not repeated however many states are checked, nor lost to the
    ``warnings`` module's own registry (each message names other values).

    :param low: (d,) lower bounds of the box
    :param high: (d,) upper bounds of the box
    """

    def __init__(self, low: np.ndarray, high: np.ndarray) -> None:
        self.low = np.asarray(low, dtype=np.float64)
        self.high = np.asarray(high, dtype=np.float64)
        self.warned = False

    def check(self, states: np.ndarray, stacklevel: int = 1) -> None:
        """
        Warn if some of ``states`` lie outside the box, unless this monitor warned already.

        :param states: (n, d)
        :param stacklevel: where the warning points: 1 at the caller of ``check``, 2 at its caller, ...
        """
        if self.warned:
            return
        outside = states_outside(states, self.low, self.high)
        if outside:
            self.warned = True
            warnings.warn(
                outside_box_message(outside, self.low, self.high),
                StateOutsideBoxWarning,
                stacklevel=stacklevel + 1,
            )


def _states_of(states: np.ndarray, state_dim: int) -> np.ndarray:
    """
    States of shape (d,) or (n, d) (or a scalar, when d = 1) as (n, d); any other shape is refused, which
    reshaping would cut into states.
    """
    vector_or_batch = states.ndim in (1, 2) and states.shape[-1] == state_dim
    if not (vector_or_batch or (states.ndim == 0 and state_dim == 1)):
        raise ValueError(
            f"unexpected state shape {states.shape}: the state Box is ({state_dim},), so a state is "
            f"({state_dim},) and a batch of them (n, {state_dim})"
        )
    return states.reshape(-1, state_dim)


def _as_array(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()
    return np.asarray(value)
