"""Arrays that grow by appending rows."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["GrowableArray", "GrowableColumns"]


class GrowableArray:
    """
    Rows appended in amortised O(1) (capacity doubling) with a view on the rows stored so far.

    :param width: the row width
    :param dtype: the storage type (float64 by default)
    """

    def __init__(self, width: int, dtype: npt.DTypeLike = np.float64):
        self._data = np.zeros((16, width), dtype=dtype)
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def append(self, rows: np.ndarray) -> None:
        rows = np.asarray(rows, dtype=self._data.dtype).reshape(-1, self._data.shape[1])
        needed = self._size + len(rows)
        if needed > len(self._data):
            grown = np.zeros((max(needed, 2 * len(self._data)), self._data.shape[1]), self._data.dtype)
            grown[: self._size] = self._data[: self._size]
            self._data = grown
        self._data[self._size : needed] = rows
        self._size = needed

    def view(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        return self._data[start : self._size if stop is None else stop]


class GrowableColumns:
    """
    Columns appended in amortised O(1) (capacity doubling) to a (height, capacity) array, with a view on the
    columns stored so far: each row of the view is contiguous, as BLAS wants the right operand of
    ``matrix @ columns``.
    """

    def __init__(self, height: int, dtype: npt.DTypeLike = np.float64):
        self._data = np.zeros((height, 16), dtype=dtype)
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def append(self, columns: np.ndarray) -> None:
        """Append the columns of ``columns``, (height, m) (a (m,) array when the height is 1)."""
        columns = np.asarray(columns).reshape(self._data.shape[0], -1)
        needed = self._size + columns.shape[1]
        if needed > self._data.shape[1]:
            grown = np.zeros((self._data.shape[0], max(needed, 2 * self._data.shape[1])), self._data.dtype)
            grown[:, : self._size] = self._data[:, : self._size]
            self._data = grown
        self._data[:, self._size : needed] = columns
        self._size = needed

    def view(self) -> np.ndarray:
        """The stored columns, (height, size)."""
        return self._data[:, : self._size]
