"""Arrays that grow by appending rows, and features cached over a growing array of states."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["GrowableArray", "PrefixFeatureCache"]


class GrowableArray:
    """Rows appended in amortised O(1) (capacity doubling) with a view on the rows stored so far."""

    def __init__(self, width: int):
        self._data = np.zeros((16, width))
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def append(self, rows: np.ndarray) -> None:
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, self._data.shape[1])
        needed = self._size + len(rows)
        if needed > len(self._data):
            grown = np.zeros((max(needed, 2 * len(self._data)), self._data.shape[1]))
            grown[: self._size] = self._data[: self._size]
            self._data = grown
        self._data[self._size : needed] = rows
        self._size = needed

    def view(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        return self._data[start : self._size if stop is None else stop]


class PrefixFeatureCache:
    """
    Features of an array of states that grows by appending rows between calls (a replay buffer's): the
    rows already seen are recognised by value and only the new ones are computed.

    :param features: states (n, d) -> features (n, k)
    """

    def __init__(self, features: Callable[[np.ndarray], np.ndarray]):
        self.features = features
        self._states: GrowableArray | None = None
        self._phi: GrowableArray | None = None

    def __call__(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        cached = 0 if self._states is None else len(self._states)
        grown = self._states is not None and len(states) >= cached
        if not grown or not np.array_equal(states[:cached], self._states.view()):
            phi = self.features(states)
            self._states, self._phi = GrowableArray(states.shape[1]), GrowableArray(phi.shape[1])
            self._states.append(states)
            self._phi.append(phi)
        elif len(states) > cached:
            assert self._phi is not None
            self._phi.append(self.features(states[cached:]))
            self._states.append(states[cached:])
        assert self._phi is not None
        return self._phi.view()
