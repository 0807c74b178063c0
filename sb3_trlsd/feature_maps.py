"""Feature maps Phi(s): what the linear policy and the ridge reward heads share, in normalised coordinates.

Every map sees a state through its state box [low, high] mapped to the unit cube: its widths are fractions
of the box, so a copy of an env whose states are scaled by 10 gets the same features as the original, and
the defaults mean the same thing on any env. Counts of centres and widths may differ by dimension.

- ``RBFGrid``: Gaussian RBFs at the centres of a regular grid (the paper's eq. 11; on the maze, 5 x 5
  centres of width 0.2, i.e. 0.04 of the box). Its size, the product of its counts per dimension, grows
  exponentially with the dimension d: the map for low dimension.
- ``AdditiveRBF``: a row of Gaussians along each dimension, side by side; its size, their sum, grows
  linearly with d. Q is then a sum of one function per dimension: enough to rank the actions where each
  moves the state along its own dimensions towards a goal, blind to how the dimensions interact (a wall
  across the diagonal of a grid-world, say), which the grid sees at low d.
- ``RandomFourierFeatures``: sqrt(2 / m) cos(W u / sigma + b), W ~ N(0, I), b ~ U(0, 2 pi) (Rahimi & Recht,
  "Random features for large-scale kernel machines", NeurIPS 2007). Their inner products approximate the
  same Gaussian kernel exp(-||u - u'||^2 / 2 sigma^2) as the RBF grid's, with a size m chosen freely: a
  linear FQI fit on them is a kernel (ridge) regression approximated with m features, the setting of
  kernel-based FQI (Ormoneit & Sen 2002; Farahmand et al. 2009).

Which map a setting gives, with how many centres and how wide, is ``sb3_trlsd.feature_choice``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = [
    "AdditiveRBF",
    "Counts",
    "FeatureMap",
    "Features",
    "RBFGrid",
    "RandomFourierFeatures",
    "Widths",
    "check_box",
    "check_counts",
    "check_widths",
    "grid_axes",
    "grid_centres",
    "is_count",
]

Widths = float | Sequence[float] | np.ndarray
Counts = int | Sequence[int]


def check_box(
    low: Sequence[float] | np.ndarray, high: Sequence[float] | np.ndarray
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    low_t = tuple(float(v) for v in np.atleast_1d(low))
    high_t = tuple(float(v) for v in np.atleast_1d(high))
    if (
        len(low_t) != len(high_t)
        or not np.all(np.isfinite(low_t + high_t))
        or not np.all(np.less(low_t, high_t))
    ):
        raise ValueError(f"low and high must be finite, of one length, low < high; got {low_t}, {high_t}")
    return low_t, high_t


def is_count(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and bool(value >= 1)


def check_counts(name: str, n_per_dim: Counts, dims: int) -> tuple[int, ...]:
    """Counts as one integer >= 1 per dimension (a single integer for all)."""
    counts: tuple[int | np.integer, ...] = ()
    if isinstance(n_per_dim, (int, np.integer)):
        counts = (n_per_dim,) * dims
    elif isinstance(n_per_dim, (Sequence, np.ndarray)) and not isinstance(n_per_dim, str):
        counts = tuple(n_per_dim)
    if len(counts) != dims or not all(is_count(n) for n in counts):
        raise ValueError(
            f"{name} must be an integer >= 1 or {dims} of them (one per state dimension), got {n_per_dim!r}"
        )
    return tuple(int(n) for n in counts)


def check_widths(name: str, sigma: Widths, dims: int) -> tuple[float, ...]:
    """Widths as one positive finite number per dimension (a single number for all)."""
    widths = (
        np.broadcast_to(np.asarray(sigma, dtype=np.float64), (dims,))
        if np.ndim(sigma) == 0
        else np.asarray(sigma, dtype=np.float64)
    )
    if widths.shape != (dims,) or not np.all(np.isfinite(widths)) or not np.all(widths > 0):
        raise ValueError(
            f"{name} must be a number > 0 or {dims} of them (one per state dimension), got {sigma!r}"
        )
    return tuple(float(w) for w in widths)


def grid_centres(low: np.ndarray, high: np.ndarray, n_per_dim: int | Sequence[int]) -> np.ndarray:
    """
    Centres of the cells of a regular grid with ``n_per_dim`` cells per dimension over the box
    [low, high]; on the maze (0, 5)^2 with 5 per dimension they are the paper's s_ij = (i - 0.5, j - 0.5).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: cells per dimension, one number for all or one per dimension
    :return: (prod n_per_dim, d), the first coordinate varying slowest: on the maze, s_ij is row
        5 (i - 1) + (j - 1), the maze's task index
    """
    # indexing="ij" makes the first axis vary slowest once flattened.
    axes = grid_axes(low, high, n_per_dim)
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))


def grid_axes(low: np.ndarray, high: np.ndarray, n_per_dim: int | Sequence[int]) -> list[np.ndarray]:
    """
    The cell centres of a regular grid along each dimension (``grid_centres`` is their product).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: cells per dimension, one number for all or one per dimension
    :return: d arrays, of shape (n_per_dim[i],) for dimension i
    """
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    counts = np.broadcast_to(np.asarray(n_per_dim), low.shape)
    return [
        lo + (np.arange(n) + 0.5) * (hi - lo) / n
        for lo, hi, n in zip(low, high, counts.tolist(), strict=True)
    ]


class Features(Protocol):
    """Phi, states (n, d) -> features (n, k), with its width k: what a linear Q is fitted on."""

    @property
    def n_features(self) -> int:
        """k."""

    def __call__(self, states: np.ndarray, /) -> np.ndarray:
        """
        :param states: (n, d)
        :return: Phi(states), (n, n_features)
        """


class FeatureMap(ABC):
    """Phi, states (n, d) -> features (n, k), over a state box [low, high] seen as the unit cube."""

    low: tuple[float, ...]
    high: tuple[float, ...]

    @property
    @abstractmethod
    def n_features(self) -> int:
        """k."""

    @abstractmethod
    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        :param states: (n, d)
        :return: Phi(states), (n, n_features)
        """


def _checked_rbf_fields(
    rbf: RBFGrid | AdditiveRBF,
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...]]:
    """
    Check an RBF map's box, counts and widths, store them normalised (one count or width when all agree)
    with the widths in state units, and return the box and the counts per dimension.
    """
    low, high = check_box(rbf.low, rbf.high)
    counts = check_counts("n_per_dim (rbf_per_dim)", rbf.n_per_dim, len(low))
    sigma = check_widths("sigma (rbf_sigma, the width of the RBFs)", rbf.sigma, len(low))
    object.__setattr__(rbf, "low", low)
    object.__setattr__(rbf, "high", high)
    object.__setattr__(rbf, "n_per_dim", counts[0] if len(set(counts)) == 1 else counts)
    object.__setattr__(rbf, "sigma", sigma[0] if len(set(sigma)) == 1 else sigma)
    object.__setattr__(rbf, "widths", tuple(w * (h - lo) for w, lo, h in zip(sigma, low, high, strict=True)))
    return low, high, counts


@dataclass(frozen=True)
class RBFGrid(FeatureMap):
    """
    Gaussian RBF features Phi(s) on a regular grid of centres over a box (eq. 11); the paper's are
    ``RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)`` (width 0.2 on the maze).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: centres per dimension, one number for all or one per dimension (e.g. ``(20, 5)`` on
        a 20 m x 5 m floor); the grid has their product
    :param sigma: width of each RBF as a fraction of the box, one number or one per dimension (> 0)
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: Counts = 5
    sigma: Widths = 0.04
    centres: np.ndarray = field(init=False, repr=False, compare=False)
    widths: tuple[float, ...] = field(init=False, repr=False, compare=False)  # in state units, (d,)
    axes: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)  # centres per dimension

    def __post_init__(self) -> None:
        low, high, counts = _checked_rbf_fields(self)
        object.__setattr__(self, "centres", grid_centres(np.array(low), np.array(high), counts))
        object.__setattr__(self, "axes", tuple(grid_axes(np.array(low), np.array(high), counts)))

    @property
    def counts(self) -> tuple[int, ...]:
        """The number of centres along each dimension, (d,)."""
        return tuple(len(axis) for axis in self.axes)

    @property
    def n_features(self) -> int:
        """k, the number of centres."""
        return len(self.centres)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        Phi(s): phi_ij(s) = exp(-sum_d (s_d - c_ij,d)^2 / (2 w_d^2)) for each centre c_ij (eq. 11), with w_d
        the width in state units. On a grid the Gaussian factorises over the dimensions, so it takes
        n_per_dim exponentials per dimension instead of one per centre.

        :param states: states (n, d)
        :return: (n, n_features)
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        phi = np.ones((len(states), 1))
        for dim, (centres, width) in enumerate(zip(self.axes, self.widths, strict=True)):
            with np.errstate(over="ignore"):  # (n, n_per_dim[dim])
                factor = np.exp(-((states[:, dim : dim + 1] - centres) ** 2) / (2.0 * width**2))
            # Outer product, the first dimension varying slowest as in grid_centres (eq. 11 factorised).
            phi = (phi[:, :, None] * factor[:, None, :]).reshape(len(states), phi.shape[1] * len(centres))
        return phi


@dataclass(frozen=True)
class AdditiveRBF(FeatureMap):
    """
    Gaussian RBF features of each state dimension on its own, side by side: dimension i has ``n_per_dim[i]``
    Gaussians of s_i at the cell centres of a regular grid along it, so there are sum_i n_per_dim[i]
    features, linear in the dimension d where the grid's product is exponential. A linear function of them
    is a sum of one function per dimension (a generalised additive model): it follows how Q changes along
    each dimension, not how the dimensions interact.

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: Gaussians per dimension, one number for all or one per dimension
    :param sigma: width of each Gaussian as a fraction of the box, one number or one per dimension (> 0)
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: Counts = 10
    sigma: Widths = 0.07
    widths: tuple[float, ...] = field(init=False, repr=False, compare=False)  # in state units, (d,)
    axes: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)  # centres per dimension

    def __post_init__(self) -> None:
        low, high, counts = _checked_rbf_fields(self)
        object.__setattr__(self, "axes", tuple(grid_axes(np.array(low), np.array(high), counts)))

    @property
    def counts(self) -> tuple[int, ...]:
        """The number of Gaussians of each dimension, (d,)."""
        return tuple(len(axis) for axis in self.axes)

    @property
    def n_features(self) -> int:
        """k = sum_i n_per_dim[i]."""
        return sum(self.counts)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        Phi(s) = [exp(-(s_i - c_i,j)^2 / (2 w_i^2))]_(i, j), dimension by dimension (the first dimension's
        first), with w_i the width in state units.

        :param states: states (n, d)
        :return: (n, n_features)
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        blocks = []
        for dim, (centres, width) in enumerate(zip(self.axes, self.widths, strict=True)):
            with np.errstate(over="ignore"):
                blocks.append(np.exp(-((states[:, dim : dim + 1] - centres) ** 2) / (2.0 * width**2)))
        return np.concatenate(blocks, axis=1)


@dataclass(frozen=True)
class RandomFourierFeatures(FeatureMap):
    """
    Random Fourier features of the Gaussian kernel of width ``sigma`` on the unit cube (Rahimi & Recht 2007):
    Phi(s) = sqrt(2 / m) cos(W (u / sigma) + b), u the state in unit-cube coordinates.

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_features: m
    :param sigma: kernel width as a fraction of the box, one number or one per dimension (> 0)
    :param seed: seed of W and b
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    m: int = 100
    sigma: Widths = 0.2
    seed: int = 0
    frequencies: np.ndarray = field(init=False, repr=False, compare=False)  # W / sigma / (high - low), (m, d)
    phases: np.ndarray = field(init=False, repr=False, compare=False)  # b, (m,)

    def __post_init__(self) -> None:
        if not (isinstance(self.m, (int, np.integer)) and self.m >= 1):
            raise ValueError(f"the number of Fourier features must be an integer >= 1, got {self.m!r}")
        low, high = check_box(self.low, self.high)
        sigma = np.array(check_widths("sigma (rbf_sigma, the kernel width)", self.sigma, len(low)))
        rng = np.random.default_rng(self.seed)
        weights = rng.standard_normal((self.m, len(low)))
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "frequencies", weights / (sigma * (np.array(high) - np.array(low))))
        object.__setattr__(self, "phases", rng.uniform(0.0, 2.0 * np.pi, self.m))

    @property
    def n_features(self) -> int:
        return int(self.m)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        projections = (states - np.array(self.low)) @ self.frequencies.T + self.phases  # (n, m)
        return np.sqrt(2.0 / self.m) * np.cos(projections)
