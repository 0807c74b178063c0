"""The shared buffer's transitions as a Q-function's fit consumes them, grown with the new rows only.

Every task is fitted on the same transitions (with its own relabelled rewards), so one ``FitRows`` serves
all of them. It is handed the rows the buffer gained since the previous refit (the engine reads them once),
and is cleared when the buffer has lost rows (wrap-around, reset, another buffer).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np
import torch as th

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.data import Transitions
from sb3_trlsd.fqi import LinearFQISolver, PolicyMoments

__all__ = ["FitRows", "LinearFitRows", "TransitionRows"]


class FitRows(ABC):
    """Rows of the shared buffer in the form one kind of Q-function fits on."""

    @property
    @abstractmethod
    def n_transitions(self) -> int:
        """The rows held, in the buffer's order."""

    def extend(self, rows: Transitions) -> None:
        """
        Append rows, in the buffer's order.

        :param rows: the rows
        """
        if len(rows):
            self._extend(rows)

    def clear(self) -> None:
        """Drop every row (the buffer lost rows: the next ``extend`` holds them all again)."""
        self._clear()

    @abstractmethod
    def _clear(self) -> None:
        """Drop every row."""

    @abstractmethod
    def _extend(self, rows: Transitions) -> None:
        """Append rows."""


class LinearFitRows(FitRows):
    """
    The rows as linear FQI keeps them: features Phi(s), Phi(s') and per-action Gram factorisations, in a
    ``LinearFQISolver``, and each task's ``PolicyMoments`` over them (policy iteration's warm start).

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
        self._policy_moments: dict[int, PolicyMoments] = {}

    @property
    def n_transitions(self) -> int:
        return self.solver.n_transitions

    def policy_moments(self, task: int) -> PolicyMoments:
        """The cross moments of ``task``'s Q over these rows, kept from one of its fits to the next."""
        return self._policy_moments.setdefault(int(task), PolicyMoments())

    def _clear(self) -> None:
        n_features, n_actions, ridge, dtype = self._solver_settings
        self.solver = LinearFQISolver(n_features, n_actions, ridge=ridge, dtype=dtype)
        self._policy_moments = {}

    def _extend(self, rows: Transitions) -> None:
        self.solver.extend(
            self.features(rows.states), rows.actions, self.features(rows.next_states), rows.terminations
        )


class TransitionRows(FitRows):
    """
    The rows as a network's Fitted-Q takes them (``fit_mlp_fqi``): float32 network inputs of s and s', the
    actions and whether s' is absorbing, converted once as they arrive. ``tensors`` shares their memory, so
    a refit rebuilds nothing from the buffer's arrays.

    :param inputs: the network input of states, (n, d) -> (n, input_dim) (e.g. states rescaled to [-1, 1])
    :param input_dim: the width of the inputs
    """

    def __init__(self, inputs: Callable[[np.ndarray], np.ndarray], input_dim: int):
        self.inputs = inputs
        self.input_dim = input_dim
        self._clear()

    @property
    def n_transitions(self) -> int:
        return len(self._actions)

    def _clear(self) -> None:
        self._inputs = GrowableArray(self.input_dim, np.float32)
        self._next_inputs = GrowableArray(self.input_dim, np.float32)
        self._actions = GrowableArray(1, np.int64)
        self._terminated = GrowableArray(1, bool)

    def _extend(self, rows: Transitions) -> None:
        self._inputs.append(self.inputs(rows.states))
        self._next_inputs.append(self.inputs(rows.next_states))
        self._actions.append(rows.actions)
        self._terminated.append(rows.terminations)

    def tensors(self) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """
        The rows as CPU tensors that share the stored arrays (valid until the next ``sync``).

        :return: inputs of s (n, input_dim) float32, actions (n,) int64, inputs of s' (n, input_dim) float32,
            terminated (n,) bool
        """
        return (
            th.from_numpy(self._inputs.view()),
            th.from_numpy(self._actions.view()[:, 0]),
            th.from_numpy(self._next_inputs.view()),
            th.from_numpy(self._terminated.view()[:, 0]),
        )
