"""Arrays that grow by appending rows."""

from __future__ import annotations

import numpy as np

__all__ = ["GrowableArray"]


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
