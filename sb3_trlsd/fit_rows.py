"""The shared buffer's transitions as a Q-function's fit consumes them, grown with the new rows only.

Every task is fitted on the same transitions (with its own relabelled rewards), so one ``FitRows`` serves
all of them. It reads the buffer through a cursor: a refit folds in the rows added since the previous one,
and starts over only when the buffer has lost rows (wrap-around, reset, another buffer).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.buffers import BufferCursor, SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.fqi import LinearFQISolver

__all__ = ["FitRows", "LinearFitRows", "TransitionRows"]


class FitRows(ABC):
    """Rows of the shared buffer in the form one kind of Q-function fits on."""

    def __init__(self) -> None:
        self._cursor = BufferCursor()

    @property
    @abstractmethod
    def n_transitions(self) -> int:
        """The rows held, in the buffer's order."""

    def sync(self, buffer: SharedDynamicsReplayBuffer) -> None:
        """
        Hold exactly the buffer's rows: append the new ones, or start over when the buffer lost rows.

        :param buffer: the shared buffer
        """
        rows, restart = buffer.read_new(self._cursor)
        if restart:
            self._clear()
        if len(rows):
            self._extend(rows)
        assert self.n_transitions == buffer.size() * buffer.n_envs

    @abstractmethod
    def _clear(self) -> None:
        """Drop every row."""

    @abstractmethod
    def _extend(self, rows: Transitions) -> None:
        """Append rows."""


class LinearFitRows(FitRows):
    """
    The rows as linear FQI keeps them: features Phi(s), Phi(s') and per-action Gram factorisations, in a
    ``LinearFQISolver``.

    :param features: Phi, states (n, d) -> (n, k)
    :param n_features: k
    :param n_actions: number of actions
    :param ridge: Tikhonov regularisation of each per-action projection
    :param dtype: storage precision of the features (see ``LinearFQISolver``)
    """

    def __init__(
        self,
        features: Callable[[np.ndarray], np.ndarray],
        n_features: int,
        n_actions: int,
        ridge: float,
        dtype: str,
    ):
        self.features = features
        self._solver_settings = (n_features, n_actions, ridge, dtype)
        self.solver = LinearFQISolver(n_features, n_actions, ridge=ridge, dtype=dtype)
        super().__init__()

    @property
    def n_transitions(self) -> int:
        return self.solver.n_transitions

    def _clear(self) -> None:
        n_features, n_actions, ridge, dtype = self._solver_settings
        self.solver = LinearFQISolver(n_features, n_actions, ridge=ridge, dtype=dtype)

    def _extend(self, rows: Transitions) -> None:
        self.solver.extend(
            self.features(rows.states), rows.actions, self.features(rows.next_states), rows.terminations
        )


class TransitionRows(FitRows):
    """The rows as arrays of states, actions, next states and terminations (what the MLP's FQI takes)."""

    def __init__(self, state_dim: int):
        self.state_dim = state_dim
        self._rows = GrowableArray(2 * state_dim + 2)  # [s, a, s', terminated]
        super().__init__()

    @property
    def n_transitions(self) -> int:
        return len(self._rows)

    def _clear(self) -> None:
        self._rows = GrowableArray(2 * self.state_dim + 2)

    def _extend(self, rows: Transitions) -> None:
        self._rows.append(np.column_stack([rows.states, rows.actions, rows.next_states, rows.terminations]))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:return: states (n, d), actions (n,), next states (n, d), terminated (n,)"""
        rows, d = self._rows.view(), self.state_dim
        return rows[:, :d], rows[:, d].astype(np.int64), rows[:, d + 1 : 2 * d + 1], rows[:, -1].astype(bool)
