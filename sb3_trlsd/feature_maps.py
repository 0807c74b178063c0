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
  same Gaussian kernel exp(-||u - u'||^2 / 2 sigma^2) as the RBF grid's, with a size m chosen freely (by
  default ``FOURIER_FEATURES_PER_DIM`` * d, linear in d): a linear FQI fit on them is a kernel (ridge)
  regression approximated with m features, the setting of kernel-based FQI (Ormoneit & Sen 2002;
  Farahmand et al. 2009). With a few hundred features, they approximate the kernel too coarsely for a
  greedy policy from 4 dimensions on (``benchmarks/bench_feature_maps.py``).

``make_feature_map`` builds them by name: ``"auto"`` (the grid, widths of ``ADAPTIVE_OVERLAP`` spacings, while
it has 3 centres a dimension within ``ADAPTIVE_MAX_FEATURES``; else ``AdditiveRBF``), ``"paper"`` (the grid
while it has at most ``MAX_GRID_FEATURES`` centres, each of a fifth of the spacing wide as on the maze, else
Fourier features), ``"lattice"`` (for states on an integer lattice, a grid-world's cells: one RBF per lattice
point, the grid while it has at most ``MAX_GRID_FEATURES`` points, else added) or one map; ``grid_counts``
chooses counts per dimension under a budget, ``spacing_widths`` widths from the spacing. It refuses, before
allocating, any map whose Gram matrices would take more than ``MEMORY_BOUND_BYTES``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = [
    "ADAPTIVE_MAX_FEATURES",
    "ADAPTIVE_OVERLAP",
    "ADDITIVE_PER_DIM",
    "FEATURE_MAPS",
    "FOURIER_FEATURES_PER_DIM",
    "LATTICE_OVERLAP",
    "MAX_GRID_FEATURES",
    "MEMORY_BOUND_BYTES",
    "PAPER_OVERLAP",
    "AdditiveRBF",
    "FeatureMap",
    "Features",
    "RBFGrid",
    "RandomFourierFeatures",
    "check_feature_memory",
    "default_kernel_width",
    "grid_axes",
    "grid_centres",
    "grid_counts",
    "make_feature_map",
    "spacing_widths",
]

FEATURE_MAPS = ("auto", "paper", "rbf", "fourier", "additive", "lattice")
GRID_SHAPES = ("cube", "box")
MAX_GRID_FEATURES = 125  # "paper" keeps the RBF grid up to 5 ** 3 centres
FOURIER_FEATURES_PER_DIM = 50
MEMORY_BOUND_BYTES = 2**30  # the Gram matrices (and their inverses) of a feature map, at most 1 GiB
PAPER_OVERLAP = 0.2  # the paper's RBF width on the maze, 0.2 maze units, is a fifth of its grid's spacing
ADAPTIVE_OVERLAP = 1.5  # "auto" and "additive": widths of 1.5 spacings (benchmarks/bench_feature_maps.py)
# "auto": the grid while it has at least 3 centres a dimension within this (8 x 8 in 2-D, 4 x 4 x 4 in 3-D):
# within 0.02 of the quality of 150 on the point-goal benchmark, at a third to a tenth of the fit's time.
ADAPTIVE_MAX_FEATURES = 64
ADDITIVE_PER_DIM = 8  # "additive": Gaussians per dimension, while they fit the budget
# "lattice": one RBF per point of an integer lattice, half the spacing wide (tuned: see the benchmarks page),
# a grid up to MAX_GRID_FEATURES points, else added.
LATTICE_OVERLAP = 0.5
Widths = float | Sequence[float] | np.ndarray
Counts = int | Sequence[int]


def _box(
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


def _is_count(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and bool(value >= 1)


def _counts(name: str, n_per_dim: Counts, dims: int) -> tuple[int, ...]:
    """Counts as one integer >= 1 per dimension (a single integer for all)."""
    counts: tuple[int | np.integer, ...] = ()
    if isinstance(n_per_dim, (int, np.integer)):
        counts = (n_per_dim,) * dims
    elif isinstance(n_per_dim, (Sequence, np.ndarray)) and not isinstance(n_per_dim, str):
        counts = tuple(n_per_dim)
    if len(counts) != dims or not all(_is_count(n) for n in counts):
        raise ValueError(
            f"{name} must be an integer >= 1 or {dims} of them (one per state dimension), got {n_per_dim!r}"
        )
    return tuple(int(n) for n in counts)


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


def grid_counts(
    low: Sequence[float],
    high: Sequence[float],
    budget: int,
    *,
    shape: str = "cube",
    minimum: int = 2,
    additive: bool = False,
) -> tuple[int, ...]:
    """
    Centres per dimension of a grid over the box [low, high] with at most ``budget`` centres, spaced as
    evenly as the shape allows: starting from ``minimum`` in every dimension, the dimension of the coarsest
    spacing gets one more centre while the grid stays within the budget.

    What "evenly" means depends on whether the dimensions share a unit. ``"cube"`` spaces the centres evenly
    in the unit cube the box maps to (counts that differ by at most one): the only choice that does not
    depend on the units of the state, e.g. a position in metres next to a velocity in m/s, and the one that
    gives a copy of an env whose states are rescaled dimension by dimension the same features. ``"box"``
    spaces them evenly in the env's own units, the counts proportional to the sides of the box: on a 20 m x
    5 m floor, four times as many centres along its length, cells close to square in metres. It is only
    meaningful when every dimension has the same unit, which the box alone cannot tell, so the caller asks
    for it.

    :param low: lower corner of the box, (d,)
    :param high: upper corner of the box, (d,)
    :param budget: the most centres of the grid (their product; their sum with ``additive``)
    :param shape: ``"cube"`` (the same count in every dimension, within one) or ``"box"`` (counts
        proportional to the sides of the box in its units)
    :param minimum: the fewest centres in any dimension (>= 1)
    :param additive: count for ``AdditiveRBF`` (the budget bounds the sum of the counts)
    :return: the counts, (d,)
    """
    low_t, high_t = _box(low, high)
    if shape not in GRID_SHAPES:
        raise ValueError(f"shape (rbf_per_dim) must be one of {list(GRID_SHAPES)}, got {shape!r}")
    if not _is_count(minimum):
        raise ValueError(f"minimum must be an integer >= 1, got {minimum!r}")
    dims = len(low_t)
    size = sum if additive else math.prod
    if not (_is_count(budget) and size([minimum] * dims) <= budget):
        raise ValueError(
            f"the budget of features (max_features) must be an integer >= {size([minimum] * dims)} "
            f"({minimum} centres in each of {dims} dimensions), got {budget!r}"
        )
    sides = np.subtract(high_t, low_t) if shape == "box" else np.ones(dims)
    counts = [minimum] * dims
    while True:
        coarsest = int(np.argmax(sides / np.array(counts)))  # the first of equal spacings
        counts[coarsest] += 1
        if size(counts) > budget:
            counts[coarsest] -= 1
            return tuple(counts)


def spacing_widths(counts: Sequence[int], overlap: float) -> tuple[float, ...]:
    """
    Widths tied to the spacing of the centres: ``overlap`` times the spacing 1 / n_i of dimension i, as
    fractions of the box. With overlap 0.2 they are the paper's (0.04 of the box for 5 centres); from about
    0.5 on, neighbouring RBFs overlap (they cross at exp(-1 / (8 overlap^2)) of their peak: 0.6 at 0.7), so
    the features do not vanish between the centres.

    :param counts: centres per dimension, (d,)
    :param overlap: the width in units of the spacing (> 0)
    :return: the widths, (d,)
    """
    return tuple(_overlap(overlap) / int(n) for n in counts)


def _check_overlap(kind: str, rbf_overlap: float, rbf_sigma: Widths | None) -> None:
    """An ``rbf_overlap`` that a map of ``kind`` can take, given with no ``rbf_sigma``, or a ValueError."""
    if rbf_sigma is not None:
        raise ValueError("give rbf_sigma (a fraction of the box) or rbf_overlap (of the spacing), not both")
    if kind == "fourier":
        raise ValueError("rbf_overlap is the width of RBFs in their spacing; Fourier features take rbf_sigma")
    _overlap(rbf_overlap)


def _overlap(overlap: float) -> float:
    if not (isinstance(overlap, (int, float, np.number)) and np.isfinite(overlap) and overlap > 0):
        raise ValueError(
            f"rbf_overlap (the width in units of the spacing) must be a number > 0, got {overlap!r}"
        )
    return float(overlap)


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
    low, high = _box(rbf.low, rbf.high)
    counts = _counts("n_per_dim (rbf_per_dim)", rbf.n_per_dim, len(low))
    sigma = _widths("sigma (rbf_sigma, the width of the RBFs)", rbf.sigma, len(low))
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
    low: Sequence[float] | np.ndarray,
    high: Sequence[float] | np.ndarray,
    *,
    rbf_per_dim: Counts | str | None = None,
    rbf_sigma: Widths | None = None,
    rbf_overlap: float | None = None,
    max_features: int | None = None,
    fourier_features: int | None = None,
    seed: int = 0,
    n_actions: int = 1,
    n_tasks: int = 1,
    integer_states: bool = False,
) -> FeatureMap:
    """
    A feature map over the box [low, high] by name, with defaults that do not depend on the box's units,
    refused before it is built if its Gram matrices would not fit (``check_feature_memory``).

    :param kind: ``"rbf"`` (an ``RBFGrid``), ``"fourier"`` (``RandomFourierFeatures``), ``"additive"``
        (``AdditiveRBF``), ``"paper"`` (the grid while it has at most ``max_features`` centres, else Fourier
        features), ``"auto"`` (``"lattice"`` for ``integer_states`` whose lattice has at most
        ``max_features`` points, default ``MAX_GRID_FEATURES``, when neither counts nor widths are given;
        else a grid of ``ADAPTIVE_OVERLAP`` widths, counts from the box under ``max_features``, while every
        dimension gets at least 3 centres; else ``AdditiveRBF``) or
        ``"lattice"`` (states on the integer points of the box, whose bounds must then be integers: one RBF
        at each, ``LATTICE_OVERLAP`` of the unit spacing wide unless ``rbf_overlap`` says otherwise; the
        grid while it has at most ``max_features`` points (default ``MAX_GRID_FEATURES``), else added)
    :param low: lower corner of the state box, (d,)
    :param high: upper corner, (d,)
    :param rbf_per_dim: centres per dimension of the grid (or Gaussians per dimension of ``"additive"``):
        one integer, one per dimension, or ``"cube"`` / ``"box"`` for counts from ``grid_counts`` under
        ``max_features`` (the same in every dimension / proportional to the box's sides in its units).
        None: 5 for ``"rbf"`` and ``"paper"``, ``"cube"`` for ``"additive"`` and ``"auto"`` (``"additive"``:
        ``ADDITIVE_PER_DIM`` a dimension unless ``max_features`` is given)
    :param rbf_sigma: width as a fraction of the box, one or one per dimension; None: ``rbf_overlap`` times
        the spacing of the centres for the RBF maps, ``default_kernel_width(d)`` for Fourier features
    :param rbf_overlap: width of the RBFs in units of the spacing of their centres (``spacing_widths``),
        when ``rbf_sigma`` is None; None: ``PAPER_OVERLAP`` (0.2, the paper's) for ``"rbf"`` and ``"paper"``,
        ``ADAPTIVE_OVERLAP`` for ``"additive"`` and ``"auto"``
    :param max_features: the budget of features of counts from ``grid_counts`` and of the choice of
        ``"auto"`` and ``"paper"``, and the cap of the default number of Fourier features; None:
        ``MAX_GRID_FEATURES`` (125), ``ADAPTIVE_MAX_FEATURES`` (64) for ``"additive"`` and ``"auto"``
    :param fourier_features: m of the Fourier features; None: ``FOURIER_FEATURES_PER_DIM`` * d (at most
        ``max_features`` when it is given)
    :param seed: seed of the Fourier features
    :param n_actions: actions of the env (one Gram matrix each)
    :param n_tasks: tasks of the env (one ridge head each)
    :param integer_states: whether the states are integers (a Box of an integer dtype), which ``"auto"``
        reads
    :return: the map
    """
    if kind not in FEATURE_MAPS:
        raise ValueError(f"feature_map must be one of {list(FEATURE_MAPS)} or a FeatureMap, got {kind!r}")
    low_t, high_t = _box(low, high)
    dims = len(low_t)
    if max_features is not None and not _is_count(max_features):
        raise ValueError(f"max_features must be an integer >= 1 or None, got {max_features!r}")
    if kind == "auto" and integer_states:
        kind = _auto_on_integers(low_t, high_t, max_features, rbf_per_dim, rbf_sigma)
    if kind == "lattice":
        return _lattice(low_t, high_t, rbf_per_dim, rbf_sigma, rbf_overlap, max_features, n_actions, n_tasks)
    new_defaults = kind in ("additive", "auto")
    budget = max_features or (ADAPTIVE_MAX_FEATURES if new_defaults else MAX_GRID_FEATURES)
    if rbf_overlap is not None:
        _check_overlap(kind, rbf_overlap, rbf_sigma)
    if rbf_per_dim is None:
        rbf_per_dim = "cube" if new_defaults else 5
    shape = "cube"
    counts: tuple[int, ...] | None = None  # from the budget, in the shape, unless given
    if isinstance(rbf_per_dim, str):
        if rbf_per_dim not in GRID_SHAPES:
            raise ValueError(
                f"rbf_per_dim must be an integer >= 1, one per dimension or one of {list(GRID_SHAPES)}, "
                f"got {rbf_per_dim!r}"
            )
        shape = rbf_per_dim
    else:
        counts = _counts("rbf_per_dim", rbf_per_dim, dims)
    fewest = 3 if kind == "auto" else 2  # centres per dimension of a grid of counts from the budget
    if kind in ("auto", "paper"):
        fits = fewest**dims <= budget if counts is None else math.prod(counts) <= budget
        kind = "rbf" if fits else "additive" if kind == "auto" else "fourier"
    if kind == "fourier":
        return _fourier_features(
            low_t, high_t, rbf_sigma, fourier_features, max_features, seed, n_actions, n_tasks
        )
    if counts is None and kind == "additive":
        # ADDITIVE_PER_DIM a dimension, unless a budget is given: more are no better (the benchmark).
        per_dim_budget = budget if max_features else min(budget, ADDITIVE_PER_DIM * dims)
        counts = grid_counts(low_t, high_t, per_dim_budget, shape=shape, additive=True)
    elif counts is None:
        counts = grid_counts(low_t, high_t, budget, shape=shape, minimum=fewest)
    n_features = math.prod(counts) if kind == "rbf" else sum(counts)
    check_feature_memory(
        n_features,
        n_actions,
        n_tasks,
        f"feature_map={kind!r} with rbf_per_dim={rbf_per_dim!r} on a {dims}-D state",
    )
    if rbf_sigma is None:
        overlap = rbf_overlap or (ADAPTIVE_OVERLAP if new_defaults else PAPER_OVERLAP)
        rbf_sigma = spacing_widths(counts, overlap)
    n_per_dim = counts[0] if len(set(counts)) == 1 else counts
    return (RBFGrid if kind == "rbf" else AdditiveRBF)(low_t, high_t, n_per_dim, rbf_sigma)


def _fourier_features(
    low: tuple[float, ...],
    high: tuple[float, ...],
    sigma: Widths | None,
    m: int | None,
    max_features: int | None,
    seed: int,
    n_actions: int,
    n_tasks: int,
) -> RandomFourierFeatures:
    """``make_feature_map``'s Fourier features: m = 50 d (at most ``max_features``) of the default width."""
    dims = len(low)
    if m is None:
        m = FOURIER_FEATURES_PER_DIM * dims
        m = m if max_features is None else min(m, max_features)
    if not (isinstance(m, (int, np.integer)) and m >= 1):
        raise ValueError(f"fourier_features must be an integer >= 1, got {m!r}")
    check_feature_memory(m, n_actions, n_tasks, f"feature_map='fourier' with fourier_features={m}")
    return RandomFourierFeatures(low, high, m, default_kernel_width(dims) if sigma is None else sigma, seed)


def _lattice_counts(low: tuple[float, ...], high: tuple[float, ...]) -> tuple[int, ...] | None:
    """The integer points of [low, high] along each dimension, or None when a bound is not an integer."""
    if not all(float(v).is_integer() for v in low + high):
        return None
    return tuple(int(h - lo) + 1 for lo, h in zip(low, high, strict=True))


def _auto_on_integers(
    low: tuple[float, ...],
    high: tuple[float, ...],
    max_features: int | None,
    rbf_per_dim: Counts | str | None,
    rbf_sigma: Widths | None,
) -> str:
    """
    ``"auto"`` on integer states: ``"lattice"`` for integer bounds with at most the budget of lattice
    points and no counts or widths given, else ``"auto"`` as on any states.
    """
    counts = _lattice_counts(low, high)
    if rbf_per_dim is not None or rbf_sigma is not None or counts is None:
        return "auto"
    return "lattice" if math.prod(counts) <= (max_features or MAX_GRID_FEATURES) else "auto"


def _lattice(
    low: tuple[float, ...],
    high: tuple[float, ...],
    rbf_per_dim: Counts | str | None,
    rbf_sigma: Widths | None,
    rbf_overlap: float | None,
    max_features: int | None,
    n_actions: int,
    n_tasks: int,
) -> FeatureMap:
    """``make_feature_map``'s ``"lattice"``: an RBF at each integer point of [low, high]."""
    if rbf_per_dim is not None or rbf_sigma is not None:
        raise ValueError(
            "feature_map='lattice' takes its centres (one per integer point of the state box) and widths "
            "(rbf_overlap of the unit spacing) from the box: leave rbf_per_dim and rbf_sigma unset"
        )
    counts = _lattice_counts(low, high)
    if counts is None:
        raise ValueError(
            f"feature_map='lattice' needs integer state bounds (the lattice's first and last points), got "
            f"low {list(low)} and high {list(high)}: give state_bounds=(low, high) with integers"
        )
    grid = math.prod(counts) <= (max_features or MAX_GRID_FEATURES)
    n_features = math.prod(counts) if grid else sum(counts)
    check_feature_memory(n_features, n_actions, n_tasks, f"feature_map='lattice' on {counts} lattice points")
    # The box one half spacing wider on each side puts the cell centres of the grid on the lattice points.
    box_low, box_high = tuple(v - 0.5 for v in low), tuple(v + 0.5 for v in high)
    widths = spacing_widths(counts, LATTICE_OVERLAP if rbf_overlap is None else rbf_overlap)
    n_per_dim = counts[0] if len(set(counts)) == 1 else counts
    return (RBFGrid if grid else AdditiveRBF)(box_low, box_high, n_per_dim, widths)
