"""Gaussian RBF features and the similarity of eq. 6 (eq. 7 is eq. 6 on features), vectorised over batches.

States and features are float64 arrays with one row per point: states (n, d), features phi (n, k).
Distances that overflow (states beyond ~1e150) count as infinite, so their similarity is 0, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces

__all__ = ["RBFGrid", "gaussian_similarity", "grid_centres", "squared_distances"]


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    ||a_i - b_j||^2 for all pairs, by the expansion |a|^2 + |b|^2 - 2 a.b (one matrix product).

    Both sets are first centred on the mean of ``b``: the expansion cancels catastrophically for points far
    from the origin and close to each other, and centring brings them near it. Rounding can still leave
    small negatives, clipped at 0.

    :param a: points (n, d)
    :param b: points (m, d)
    :return: (n, m), the transpose of a C-contiguous (m, n) array
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        centre = b.mean(axis=0) if len(b) else np.zeros(b.shape[1])
        a, b = a - centre, b - centre
        a_norms, b_norms = np.einsum("ij,ij->i", a, a), np.einsum("ij,ij->i", b, b)  # (n,), (m,)
        # Built as (m, n), in place: long rows and no (n, m) temporaries, and row sums of the returned
        # transpose (the kernel sums of eq. 8, with m << n samples) add contiguous columns.
        distances = b @ a.T
        distances *= -2.0
        distances += a_norms[None, :]
        distances += b_norms[:, None]
    if max(a_norms.max(initial=0.0), b_norms.max(initial=0.0)) > 1e300:
        # inf - inf only happens between overflowing points: treat them as infinitely far.
        distances[np.isnan(distances)] = np.inf
    return np.maximum(distances, 0.0, out=distances).T


def gaussian_similarity(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """
    S_S(a_i, b_j) = exp(-||a_i - b_j||^2 / (2 sigma^2)) (eq. 6).

    :param a: states (n, d)
    :param b: states (m, d)
    :param sigma: width of the Gaussian (> 0)
    :return: (n, m), in [0, 1]
    """
    exponent = squared_distances(a, b)  # (n, m), turned into the similarity in place
    with np.errstate(over="ignore"):  # a huge finite distance over 2 sigma^2 is inf: similarity 0
        exponent *= -1.0 / (2.0 * sigma**2)
    return np.exp(exponent, out=exponent)  # eq. 6


def grid_centres(low: np.ndarray, high: np.ndarray, n_per_dim: int) -> np.ndarray:
    """
    Centres of the cells of a regular grid with ``n_per_dim`` cells per dimension over the box
    [low, high]; on the maze (0, 5)^2 with 5 per dimension they are the paper's s_ij = (i - 0.5, j - 0.5).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: cells per dimension
    :return: (n_per_dim ** d, d), the first coordinate varying slowest: on the maze, s_ij is row
        5 (i - 1) + (j - 1), the maze's task index
    """
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    axes = [
        lo + (np.arange(n_per_dim) + 0.5) * (hi - lo) / n_per_dim for lo, hi in zip(low, high, strict=True)
    ]
    # indexing="ij" makes the first axis vary slowest once flattened.
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low))


@dataclass(frozen=True)
class RBFGrid:
    """
    Gaussian RBF features Phi(s) on a regular grid of centres over a box (eq. 11); the paper's are
    ``RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.2)``.

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: centres per dimension
    :param sigma: width of each RBF (> 0)
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: int = 5
    sigma: float = 0.2
    centres: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError(f"sigma must be > 0 (the width of the RBFs), got {self.sigma}")
        if self.n_per_dim < 1:
            raise ValueError(f"n_per_dim must be an integer >= 1, got {self.n_per_dim}")
        low = tuple(float(v) for v in np.atleast_1d(self.low))
        high = tuple(float(v) for v in np.atleast_1d(self.high))
        if len(low) != len(high) or not np.all(np.isfinite(low + high)) or not np.all(np.less(low, high)):
            raise ValueError(f"low and high must be finite, of one length, low < high; got {low}, {high}")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "centres", grid_centres(np.array(low), np.array(high), self.n_per_dim))

    @classmethod
    def for_box(cls, box: spaces.Box, n_per_dim: int = 5, sigma: float = 0.2) -> RBFGrid:
        """
        The grid over a Box space.

        :param box: the state space (finite bounds)
        :param n_per_dim: centres per dimension
        :param sigma: width of each RBF
        :return: the grid
        """
        return cls(tuple(box.low.astype(float)), tuple(box.high.astype(float)), n_per_dim, sigma)

    @property
    def n_features(self) -> int:
        """k, the number of centres."""
        return len(self.centres)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        Phi(s): phi_ij(s) = S_S(s, s_ij) for each centre s_ij (eq. 11), i.e.
        ``gaussian_similarity(states, self.centres, self.sigma)``.

        On a grid the Gaussian factorises over the dimensions, so it takes n_per_dim exponentials per
        dimension instead of one per centre.

        :param states: states (n, d)
        :return: (n, n_features)
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        phi = np.ones((len(states), 1))
        for dim, (low, high) in enumerate(zip(self.low, self.high, strict=True)):
            centres = low + (np.arange(self.n_per_dim) + 0.5) * (high - low) / self.n_per_dim
            with np.errstate(over="ignore"):  # (n, n_per_dim)
                factor = np.exp(-((states[:, dim : dim + 1] - centres) ** 2) / (2.0 * self.sigma**2))
            # Outer product, the first dimension varying slowest as in grid_centres (eq. 11 factorised).
            phi = (phi[:, :, None] * factor[:, None, :]).reshape(len(states), phi.shape[1] * self.n_per_dim)
        return phi
