"""Discrete setting: per-cell mean rewards and the UCB-style CI of eq. 10 on a discretisation of the states.

The discretisation is any cell function, states (n, d) -> cell ids (n,) in 0..n_cells-1, given by the user,
or ``GridCells``: a regular grid of cells over the state Box (on the maze's (0, 5)^2 with 5 cells per
dimension, cell 5 (ceil(x) - 1) + (ceil(y) - 1), the maze's task index of the cell's task).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from sb3_trlsd.reward_heads.base import (
    DEFAULT_W_FLOOR,
    RewardHead,
    check_positive,
    confidence_width,
)

__all__ = ["CellFn", "GridCells", "TabularRewardHead"]

CellFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GridCells:
    """
    A regular grid of ``n_per_dim`` cells per dimension over the box [low, high], as a cell function.

    Cell boundaries belong to the lower cell, as the paper's i = ceil(x) does on the maze, and states
    outside the box fall in the nearest border cell. Cell ids are row-major, the first dimension varying
    slowest: with d dimensions, id = sum_k index_k * n_per_dim^(d - 1 - k).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: cells per dimension (>= 1)
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: int = 5

    def __post_init__(self) -> None:
        low = tuple(float(v) for v in np.atleast_1d(self.low))
        high = tuple(float(v) for v in np.atleast_1d(self.high))
        if len(low) != len(high) or not np.all(np.isfinite(low + high)) or not np.all(np.less(low, high)):
            raise ValueError(
                f"the cells' box must be finite with low < high in every dimension, got {low}, {high}: "
                "bound the state Box, or give the tabular head a cell_fn and n_cells"
            )
        if not (isinstance(self.n_per_dim, (int, np.integer)) and self.n_per_dim >= 1):
            raise ValueError(f"cells_per_dim must be an integer >= 1, got {self.n_per_dim!r}")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def n_cells(self) -> int:
        """n_per_dim ** d."""
        return int(self.n_per_dim ** len(self.low))

    def corner_cells(self) -> tuple[int, ...]:
        """The 2^d cells at the corners of the box (on the maze: 0, 4, 20, 24), sorted."""
        dims = len(self.low)
        last = self.n_per_dim - 1
        corners = np.array(np.meshgrid(*[[0, last]] * dims, indexing="ij")).reshape(dims, -1).T
        return tuple(sorted({int(index) for index in self._flat_index(corners)}))

    def _flat_index(self, indices: np.ndarray) -> np.ndarray:
        strides = self.n_per_dim ** np.arange(len(self.low) - 1, -1, -1)
        return indices @ strides

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        :param states: (n, d)
        :return: cell ids (n,) in 0..n_cells-1
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        low, high = np.array(self.low), np.array(self.high)
        scaled = (states - low) / (high - low) * self.n_per_dim  # in (0, n_per_dim] inside the box
        indices = np.clip(np.ceil(scaled), 1, self.n_per_dim).astype(np.int64) - 1
        return self._flat_index(indices)


class TabularRewardHead(RewardHead):
    """
    Per-cell mean rewards and the UCB-style CI of eq. 10: R^(s) = mean reward of the samples in the cell of
    s, CI(s) = kappa sqrt(log|Xi_tau| / N_tau(s)) with N_tau(s) the samples of that cell.

    Eq. 10 is undefined in a cell with no sample (N = 0), and the paper does not say what R~ is there. By
    default N is floored at ``w_floor``: a bonus so large (~263 for kappa = 0.1 and 1,000 samples) that every
    unvisited cell outranks every visited one, UCB's "try each arm once" (``reward_heads.base``). With
    ``unvisited_value``, R~ of an allowed unvisited cell is that value instead (R^ is 0 there, so the bonus is
    the value): R-MAX's "an unknown state is worth the largest reward" (Brafman & Tennenholtz, cited by the
    paper) with the reward bound, 1 on the maze; visited cells keep eq. 10, and may outrank it.

    :param cell_fn: states (n, d) -> cell ids (n,) in 0..n_cells-1 (e.g. a ``GridCells``)
    :param n_cells: number of cells, >= 1
    :param kappa: optimism (eq. 10), >= 0
    :param allowed_cells: cells where the reward may be non-zero (expert knowledge); elsewhere R^ = 0 and
        there is no bonus. None: every cell
    :param w_floor: floor on the count N_tau(s) of an unvisited cell, > 0 (see ``reward_heads.base``)
    :param r_max: optional cap on R~
    :param unvisited_value: R~ of an allowed cell with no sample when kappa > 0 (None: eq. 10 with N floored
        at ``w_floor``), finite
    """

    def __init__(
        self,
        cell_fn: CellFn,
        n_cells: int,
        kappa: float = 0.1,
        allowed_cells: Iterable[int] | None = None,
        w_floor: float = DEFAULT_W_FLOOR,
        r_max: float | None = None,
        unvisited_value: float | None = None,
    ):
        super().__init__(kappa, r_max)
        if unvisited_value is not None and not np.isfinite(unvisited_value):
            raise ValueError(
                "unvisited_value must be a finite number or None (eq. 10 with the floor), "
                f"got {unvisited_value}"
            )
        self.unvisited_value = None if unvisited_value is None else float(unvisited_value)
        if not callable(cell_fn):
            raise ValueError(f"cell_fn must be a function of states (n, d) -> cell ids (n,), got {cell_fn!r}")
        if not (isinstance(n_cells, (int, np.integer)) and n_cells >= 1):
            raise ValueError(f"n_cells must be an integer >= 1, got {n_cells!r}")
        self.cell_fn = cell_fn
        self.n_cells = int(n_cells)
        self.w_floor = check_positive("w_floor", w_floor, "the floor of the cell count N")
        self.allowed = np.ones(self.n_cells, dtype=bool)
        if allowed_cells is not None:
            allowed = np.asarray(list(allowed_cells), dtype=np.int64)
            if np.any((allowed < 0) | (allowed >= self.n_cells)):
                raise ValueError(f"allowed_cells must be cell ids in 0..{self.n_cells - 1}, got {allowed}")
            self.allowed[:] = False
            self.allowed[allowed] = True
        self.counts = np.zeros(self.n_cells)  # N_tau per cell
        self.sums = np.zeros(self.n_cells)  # sum of rewards per cell

    def _repr_items(self) -> list[str]:
        return [*super()._repr_items(), f"n_cells={self.n_cells}", f"allowed={int(self.allowed.sum())}"]

    def cells(self, states: np.ndarray) -> np.ndarray:
        """
        The cell of each state.

        :param states: (n, d)
        :return: cell ids (n,)
        """
        states = np.asarray(states, dtype=np.float64)
        cells = np.asarray(self.cell_fn(states))
        if cells.shape != (len(states),) or not np.issubdtype(cells.dtype, np.integer):
            raise ValueError(
                f"cell_fn must return one integer cell id per state, shape ({len(states)},), "
                f"got shape {cells.shape} of {cells.dtype}"
            )
        if len(cells) and (cells.min() < 0 or cells.max() >= self.n_cells):
            raise ValueError(
                f"cell_fn must return cell ids in 0..{self.n_cells - 1}, got {cells.min()}..{cells.max()}"
            )
        return cells.astype(np.int64, copy=False)

    def _update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        cells = self.cells(states)
        self.counts += np.bincount(cells, minlength=self.n_cells)
        self.sums += np.bincount(cells, weights=rewards, minlength=self.n_cells)

    def update(self, states: np.ndarray, rewards: np.ndarray) -> None:
        # The cells are checked before anything is counted, so that a bad cell_fn leaves the head unchanged.
        checked_states, _ = self.check_samples(states, rewards)
        self.cells(checked_states)
        super().update(states, rewards)

    def cell_means(self) -> np.ndarray:
        """R^ per cell: the mean reward of its samples, 0 where it has none or is not allowed, (n_cells,)."""
        means = np.divide(self.sums, self.counts, out=np.zeros(self.n_cells), where=self.counts > 0)
        return np.where(self.allowed, means, 0.0)

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return self.cell_means()[self.cells(states)]

    def snapshot(self) -> tuple[np.ndarray, int]:
        # The counts are n_cells floats: copying them is the cheap snapshot.
        return self.counts.copy(), self.n_samples

    def uncertainty_as_of(self, snapshot: tuple[np.ndarray, int], states: np.ndarray) -> np.ndarray:
        counts, n_samples = snapshot
        per_cell = confidence_width(self.log_count(n_samples), counts, self.w_floor)  # eq. 10 / kappa
        return np.where(self.allowed, per_cell, 0.0)[self.cells(states)]

    def uncertainty(self, states: np.ndarray) -> np.ndarray:
        # The live counts, not a copy: this runs at every step.
        return self.uncertainty_as_of((self.counts, self.n_samples), states)

    def bonus(self, states: np.ndarray) -> np.ndarray:
        bonus = super().bonus(states)
        if self.unvisited_value is None or self.kappa == 0:
            return bonus
        cells = self.cells(states)
        unvisited = (self.counts[cells] == 0) & self.allowed[cells]
        return np.where(unvisited, self.unvisited_value, bonus)  # R^ = 0 there: R~ = unvisited_value
