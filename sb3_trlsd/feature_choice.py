"""Which feature map a setting gives: ``make_feature_map`` by name, with its budgets, counts and widths.

``make_feature_map`` builds the maps of ``sb3_trlsd.feature_maps`` by name: ``"auto"`` (the grid, widths of
``ADAPTIVE_OVERLAP`` spacings, while it has 3 centres a dimension within ``ADAPTIVE_MAX_FEATURES``; else
``AdditiveRBF``), ``"paper"`` (the grid while it has at most ``MAX_GRID_FEATURES`` centres, each of a fifth
of the spacing wide as on the maze, else Fourier features), ``"lattice"`` (for states on an integer lattice,
a grid-world's cells: one RBF per lattice point, the grid while it has at most ``MAX_GRID_FEATURES`` points,
else added) or one map; ``grid_counts`` chooses counts per dimension under a budget, ``spacing_widths``
widths from the spacing. It refuses, before allocating, any map whose Gram matrices would take more than
``MEMORY_BOUND_BYTES``. Fourier features are ``FOURIER_FEATURES_PER_DIM`` * d by default, linear in d; with
a few hundred of them they approximate the kernel too coarsely for a greedy policy from 4 dimensions on
(``benchmarks/bench_feature_maps.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sb3_trlsd.feature_maps import (
    AdditiveRBF,
    Counts,
    FeatureMap,
    RandomFourierFeatures,
    RBFGrid,
    Widths,
    check_box,
    check_counts,
    is_count,
)

__all__ = [
    "ADAPTIVE_MAX_FEATURES",
    "ADAPTIVE_OVERLAP",
    "ADDITIVE_PER_DIM",
    "FEATURE_MAPS",
    "FOURIER_FEATURES_PER_DIM",
    "GRID_SHAPES",
    "LATTICE_OVERLAP",
    "MAX_GRID_FEATURES",
    "MEMORY_BOUND_BYTES",
    "PAPER_OVERLAP",
    "check_feature_memory",
    "default_kernel_width",
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
    low_t, high_t = check_box(low, high)
    if shape not in GRID_SHAPES:
        raise ValueError(f"shape (rbf_per_dim) must be one of {list(GRID_SHAPES)}, got {shape!r}")
    if not is_count(minimum):
        raise ValueError(f"minimum must be an integer >= 1, got {minimum!r}")
    dims = len(low_t)
    size = sum if additive else math.prod
    if not (is_count(budget) and size([minimum] * dims) <= budget):
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
    low_t, high_t = check_box(low, high)
    dims = len(low_t)
    if max_features is not None and not is_count(max_features):
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
        counts = check_counts("rbf_per_dim", rbf_per_dim, dims)
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
