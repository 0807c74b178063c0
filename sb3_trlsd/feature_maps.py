"""Feature maps Phi(s): what the linear policy and the ridge reward heads share, in normalised coordinates.

Every map sees a state through its state box [low, high] mapped to the unit cube: its widths are fractions
of the box, so a copy of an env whose states are scaled by 10 gets the same features as the original, and
the defaults mean the same thing on any env. Per-dimension widths are allowed.

- ``RBFGrid``: Gaussian RBFs at the centres of a regular grid (the paper's eq. 11; on the maze, 5 x 5
  centres of width 0.2, i.e. 0.04 of the box). Its size, n_per_dim ** d, grows exponentially with the
  dimension d: the map for low dimension.
- ``RandomFourierFeatures``: sqrt(2 / m) cos(W u / sigma + b), W ~ N(0, I), b ~ U(0, 2 pi) (Rahimi & Recht,
  "Random features for large-scale kernel machines", NeurIPS 2007). Their inner products approximate the
  same Gaussian kernel exp(-||u - u'||^2 / 2 sigma^2) as the RBF grid's, with a size m chosen freely (by
  default ``FOURIER_FEATURES_PER_DIM`` * d, linear in d). We pick them over tile coding because they keep
  the paper's Gaussian kernel (the features of eq. 11 and the similarity of eq. 7) in any dimension, where
  tile coding's tilings are themselves exponential in d unless hashed or split into stripes, and because a
  linear FQI fit on them is a kernel (ridge) regression approximated with m features, the setting of
  kernel-based FQI (Ormoneit & Sen 2002; Farahmand et al. 2009).

``make_feature_map`` chooses by dimension (``"auto"``: the grid while it has at most ``MAX_GRID_FEATURES``
features, else Fourier features) and refuses, before allocating, any map whose Gram matrices would take
more than ``MEMORY_BOUND_BYTES``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sb3_trlsd.features import grid_axes, grid_centres

__all__ = [
    "FEATURE_MAPS",
    "FOURIER_FEATURES_PER_DIM",
    "MAX_GRID_FEATURES",
    "MEMORY_BOUND_BYTES",
    "FeatureMap",
    "RBFGrid",
    "RandomFourierFeatures",
    "check_feature_memory",
    "default_kernel_width",
    "make_feature_map",
]

FEATURE_MAPS = ("auto", "rbf", "fourier")
MAX_GRID_FEATURES = 125  # "auto" keeps the RBF grid up to 5 ** 3 centres
FOURIER_FEATURES_PER_DIM = 50
MEMORY_BOUND_BYTES = 2**30  # the Gram matrices (and their inverses) of a feature map, at most 1 GiB
Widths = float | Sequence[float] | np.ndarray


def _box(low: Sequence[float], high: Sequence[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    low_t = tuple(float(v) for v in np.atleast_1d(low))
    high_t = tuple(float(v) for v in np.atleast_1d(high))
    if (
        len(low_t) != len(high_t)
        or not np.all(np.isfinite(low_t + high_t))
        or not np.all(np.less(low_t, high_t))
    ):
        raise ValueError(f"low and high must be finite, of one length, low < high; got {low_t}, {high_t}")
    return low_t, high_t


def _widths(name: str, sigma: Widths, dims: int) -> tuple[float, ...]:
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


def default_kernel_width(dims: int) -> float:
    """
    A Gaussian width in unit-cube coordinates that covers the same share of the cube in every dimension as
    0.04 does in two (the paper's 0.2 on the 5 x 5 maze): (w sqrt(2 pi))^d = (0.04 sqrt(2 pi))^2 ~ 1%, so
    w = 0.04 (0.04 sqrt(2 pi))^(2 / d - 1). Without it, a width fit for 2-D leaves almost every state of a
    6-D cube with no neighbour.

    :param dims: d
    :return: 0.04 for d = 2 (exactly), 0.126 for d = 4, 0.185 for d = 6
    """
    return float(0.04 * (0.04 * np.sqrt(2.0 * np.pi)) ** (2.0 / dims - 1.0))


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


@dataclass(frozen=True)
class RBFGrid(FeatureMap):
    """
    Gaussian RBF features Phi(s) on a regular grid of centres over a box (eq. 11); the paper's are
    ``RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)`` (width 0.2 on the maze).

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param n_per_dim: centres per dimension
    :param sigma: width of each RBF as a fraction of the box, one number or one per dimension (> 0)
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    n_per_dim: int = 5
    sigma: Widths = 0.04
    centres: np.ndarray = field(init=False, repr=False, compare=False)
    widths: tuple[float, ...] = field(init=False, repr=False, compare=False)  # in state units, (d,)
    axes: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)  # centres per dimension

    def __post_init__(self) -> None:
        if not (isinstance(self.n_per_dim, (int, np.integer)) and self.n_per_dim >= 1):
            raise ValueError(f"n_per_dim (rbf_per_dim) must be an integer >= 1, got {self.n_per_dim!r}")
        low, high = _box(self.low, self.high)
        sigma = _widths("sigma (rbf_sigma, the width of the RBFs)", self.sigma, len(low))
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "sigma", sigma[0] if len(set(sigma)) == 1 else sigma)
        object.__setattr__(
            self, "widths", tuple(s * (h - lo) for s, lo, h in zip(sigma, low, high, strict=True))
        )
        object.__setattr__(self, "centres", grid_centres(np.array(low), np.array(high), self.n_per_dim))
        object.__setattr__(self, "axes", tuple(grid_axes(np.array(low), np.array(high), self.n_per_dim)))

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
            with np.errstate(over="ignore"):  # (n, n_per_dim)
                factor = np.exp(-((states[:, dim : dim + 1] - centres) ** 2) / (2.0 * width**2))
            # Outer product, the first dimension varying slowest as in grid_centres (eq. 11 factorised).
            phi = (phi[:, :, None] * factor[:, None, :]).reshape(len(states), phi.shape[1] * self.n_per_dim)
        return phi


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
        low, high = _box(self.low, self.high)
        sigma = np.array(_widths("sigma (rbf_sigma, the kernel width)", self.sigma, len(low)))
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


def check_feature_memory(n_features: int, n_actions: int, n_tasks: int, settings: str) -> None:
    """
    Refuse, before anything is allocated, a map whose Gram matrices would not fit: per action two k x k
    (the FQI projection and its inverse) and one per task for a ridge head, in float64.

    :param n_features: k
    :param n_actions: number of actions
    :param n_tasks: number of tasks (ridge heads)
    :param settings: the settings that chose k, named in the error
    :raises ValueError: when they would take more than ``MEMORY_BOUND_BYTES``
    """
    needed = (2 * n_actions + n_tasks) * n_features**2 * 8
    if needed > MEMORY_BOUND_BYTES:
        raise ValueError(
            f"{settings} gives {n_features:,} features, whose Gram matrices would take "
            f"{needed / 2**30:.1f} GiB (the bound is {MEMORY_BOUND_BYTES / 2**30:.0f} GiB): use "
            "feature_map='fourier' (its size grows linearly with the state dimension) or fewer rbf_per_dim, "
            "or the MlpPolicy with a tabular or known reward head"
        )


def make_feature_map(
    kind: str,
    low: Sequence[float],
    high: Sequence[float],
    *,
    rbf_per_dim: int = 5,
    rbf_sigma: Widths | None = None,
    fourier_features: int | None = None,
    seed: int = 0,
    n_actions: int = 1,
    n_tasks: int = 1,
) -> FeatureMap:
    """
    A feature map over the box [low, high] by name, with defaults that do not depend on the box's units,
    refused before it is built if its Gram matrices would not fit (``check_feature_memory``).

    :param kind: ``"rbf"``, ``"fourier"`` or ``"auto"`` (the grid up to ``MAX_GRID_FEATURES`` centres)
    :param low: lower corner of the state box, (d,)
    :param high: upper corner, (d,)
    :param rbf_per_dim: centres per dimension of the grid
    :param rbf_sigma: width as a fraction of the box; None: 0.2 / rbf_per_dim for the grid (the paper's on
        the maze: a fifth of the spacing), ``default_kernel_width(d)`` for Fourier features
    :param fourier_features: m of the Fourier features; None: ``FOURIER_FEATURES_PER_DIM`` * d
    :param seed: seed of the Fourier features
    :param n_actions: actions of the env (one Gram matrix each)
    :param n_tasks: tasks of the env (one ridge head each)
    :return: the map
    """
    if kind not in FEATURE_MAPS:
        raise ValueError(f"feature_map must be one of {list(FEATURE_MAPS)} or a FeatureMap, got {kind!r}")
    if not (isinstance(rbf_per_dim, (int, np.integer)) and rbf_per_dim >= 1):
        raise ValueError(f"rbf_per_dim must be an integer >= 1, got {rbf_per_dim!r}")
    dims = len(np.atleast_1d(low))
    if kind == "auto":
        kind = "rbf" if rbf_per_dim**dims <= MAX_GRID_FEATURES else "fourier"
    if kind == "rbf":
        check_feature_memory(
            rbf_per_dim**dims,
            n_actions,
            n_tasks,
            f"feature_map='rbf' with rbf_per_dim={rbf_per_dim} on a {dims}-D state",
        )
        return RBFGrid(
            tuple(low), tuple(high), rbf_per_dim, 0.2 / rbf_per_dim if rbf_sigma is None else rbf_sigma
        )
    m = FOURIER_FEATURES_PER_DIM * dims if fourier_features is None else fourier_features
    if not (isinstance(m, (int, np.integer)) and m >= 1):
        raise ValueError(f"fourier_features must be an integer >= 1, got {m!r}")
    check_feature_memory(m, n_actions, n_tasks, f"feature_map='fourier' with fourier_features={m}")
    return RandomFourierFeatures(
        tuple(low), tuple(high), m, default_kernel_width(dims) if rbf_sigma is None else rbf_sigma, seed
    )
