"""Gaussian RBF features and similarity measures (paper, eq. 3, 6, 7, 11), vectorised over batches."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces

__all__ = [
    "RBFGrid",
    "feature_similarity",
    "gaussian_similarity",
    "grid_centres",
    "rbf_features",
    "squared_distances",
    "state_action_features",
]


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """||a_i - b_j||^2 for all pairs: (n, d), (m, d) -> (n, m), clipped at 0 against rounding."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    distances = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2.0 * a @ b.T
    return np.maximum(distances, 0.0)


def gaussian_similarity(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """S_S(a_i, b_j) = exp(-||a_i - b_j||^2 / (2 sigma^2)) (eq. 6): (n, d), (m, d) -> (n, m)."""
    return np.exp(-squared_distances(a, b) / (2.0 * sigma**2))


def feature_similarity(phi_a: np.ndarray, phi_b: np.ndarray, sigma: float) -> np.ndarray:
    """S_Phi (eq. 7): the similarity of eq. 6 between feature vectors, (n, k), (m, k) -> (n, m)."""
    return gaussian_similarity(phi_a, phi_b, sigma)


def grid_centres(low: np.ndarray, high: np.ndarray, n_per_dim: int) -> np.ndarray:
    """
    Centres of the cells of a regular grid with ``n_per_dim`` cells per dimension over the box
    [low, high]; on the maze (0, 5)^2 with 5 per dimension they are the paper's (i - 0.5, j - 0.5).

    :return: (n_per_dim ** d, d), the first coordinate varying slowest (index 5 (i - 1) + (j - 1) on the maze)
    """
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    axes = [
        lo + (np.arange(n_per_dim) + 0.5) * (hi - lo) / n_per_dim for lo, hi in zip(low, high, strict=True)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low))


def rbf_features(states: np.ndarray, centres: np.ndarray, sigma: float) -> np.ndarray:
    """phi_ij(s) = S_S(s, s_ij) (eq. 11): states (n, d), centres (k, d) -> (n, k)."""
    return gaussian_similarity(states, centres, sigma)


def state_action_features(phi: np.ndarray, actions: np.ndarray, n_actions: int) -> np.ndarray:
    """
    Phi(s, a) = {1_{a = a'} Phi(s)}_{a'} (eq. 3): phi (n, k), actions (n,) -> (n, k * n_actions), block a'
    holding phi on the rows whose action is a'.
    """
    n, k = phi.shape
    blocks = np.zeros((n, n_actions, k))
    blocks[np.arange(n), np.asarray(actions, dtype=np.int64)] = phi
    return blocks.reshape(n, n_actions * k)


@dataclass(frozen=True)
class RBFGrid:
    """
    Gaussian RBF features on a regular grid of centres over a box (eq. 11).

    :param low: lower corner of the box, shape (d,)
    :param high: upper corner of the box, shape (d,)
    :param n_per_dim: centres per dimension
    :param sigma: width of each RBF
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: int = 5
    sigma: float = 0.2
    centres: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError(f"sigma must be > 0, got {self.sigma}")
        if self.n_per_dim < 1:
            raise ValueError(f"n_per_dim must be >= 1, got {self.n_per_dim}")
        object.__setattr__(self, "low", tuple(float(v) for v in np.atleast_1d(self.low)))
        object.__setattr__(self, "high", tuple(float(v) for v in np.atleast_1d(self.high)))
        object.__setattr__(
            self, "centres", grid_centres(np.array(self.low), np.array(self.high), self.n_per_dim)
        )

    @classmethod
    def for_box(cls, box: spaces.Box, n_per_dim: int = 5, sigma: float = 0.2) -> RBFGrid:
        """The grid over a Box space (finite bounds)."""
        return cls(tuple(box.low.astype(float)), tuple(box.high.astype(float)), n_per_dim, sigma)

    @property
    def n_features(self) -> int:
        return len(self.centres)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """
        Phi(s) for states (n, d) -> (n, n_features), equal to ``rbf_features(states, centres, sigma)``.

        On a grid the Gaussian factorises over the dimensions, so it takes n_per_dim exponentials per
        dimension instead of one per centre.
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, len(self.low))
        phi = np.ones((len(states), 1))
        for dim, (low, high) in enumerate(zip(self.low, self.high, strict=True)):
            centres = low + (np.arange(self.n_per_dim) + 0.5) * (high - low) / self.n_per_dim
            # (n, n_per_dim)
            factor = np.exp(-((states[:, dim : dim + 1] - centres) ** 2) / (2.0 * self.sigma**2))
            # Outer product, the first dimension varying slowest as in grid_centres.
            phi = (phi[:, :, None] * factor[:, None, :]).reshape(len(states), phi.shape[1] * self.n_per_dim)
        return phi
