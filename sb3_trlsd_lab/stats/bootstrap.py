"""
Stratified bootstrap confidence intervals of the aggregates of ``statistics.py`` and of the probability of
improvement, as ``rliable`` computes them (Agarwal et al., NeurIPS 2021). They are written here because
rliable's bootstrap comes from ``arch``, which does not import with the pandas this package is installed
with.

rliable's bootstrap and where it is (github.com/google-research/rliable: ``library.py`` as of commit
06ab799):

- stratified bootstrap, ``library.py::StratifiedBootstrap.update_indices``: every cell of a resample draws a
  run with replacement from its own column (task), independently of the others;
  ``StratifiedIndependentBootstrap`` resamples X and Y so, each on its own, for the probability of
  improvement.
- interval, ``library.py::get_interval_estimates`` (method ``"percentile"``, confidence 0.95): arch's
  ``IIDBootstrap.conf_int``, whose percentile interval is ``np.percentile(estimates, [100 alpha,
  100 (1 - alpha)])`` with alpha = (1 - confidence) / 2 (linear interpolation); the point is the statistic
  of the data itself.

Differences:

- The resamples come from ``np.random.default_rng(seed)``, drawn a batch at a time, so a seed does not give
  rliable's numbers, only the same distribution (rliable draws each resample in a loop with NumPy's legacy
  API; in the version read, from the global ``np.random`` whatever ``random_state`` it is given).
- 2,000 resamples by default (rliable's ``get_interval_estimates``: 50,000; its performance profiles: 2,000).
- Only the percentile interval, and resampling of runs only (rliable's default ``task_bootstrap=False``).
- Runs that share a source set are not independent; this bootstrap, like rliable's, resamples runs, so its
  interval can be narrower than one that resamples source sets (``reporting.mean_and_standard_error`` with
  clusters counts each source set once).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence

import numpy as np

from sb3_trlsd_lab.stats.statistics import AGGREGATES, Statistic, probability_of_improvement, score_matrix

__all__ = [
    "aggregate_intervals",
    "improvement_intervals",
    "independent_bootstrap_ci",
    "interval_cell",
    "paired_bootstrap_ci",
    "probability_of_improvement_ci",
    "stratified_bootstrap_ci",
]

# Resampled scores held in memory at once (float64): 32 MB
CHUNK_ELEMENTS = 1 << 22


def stratified_bootstrap_ci(
    scores: np.ndarray,
    statistic: Statistic,
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """
    A statistic of the scores and its percentile interval over resamples of the runs within each task
    (rliable's ``get_interval_estimates`` with ``StratifiedBootstrap``).

    :param scores: (n_runs, n_tasks) or (n_runs,)
    :param statistic: maps score matrices (..., n_runs, n_tasks) to (...), as the aggregates of
        ``statistics.py`` do
    :param reps: bootstrap resamples
    :param confidence: probability that the interval covers the statistic, in (0, 1)
    :param seed: seed of the resamples
    :return: (point, low, high)
    """
    return independent_bootstrap_ci(
        statistic, [_one_matrix(scores, "scores")], reps=reps, confidence=confidence, seed=seed
    )


def probability_of_improvement_ci(
    x: np.ndarray,
    y: np.ndarray,
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """
    P(X > Y) and its percentile interval over resamples of X's and Y's runs, each within each task and
    independently of the other (rliable's ``StratifiedIndependentBootstrap``).

    :param x: (n_runs_x, n_tasks) or (n_runs_x,)
    :param y: (n_runs_y, n_tasks) or (n_runs_y,)
    :param reps: bootstrap resamples
    :param confidence: probability that the interval covers P(X > Y), in (0, 1)
    :param seed: seed of the resamples
    :return: (point, low, high)
    """
    x, y = _one_matrix(x, "x"), _one_matrix(y, "y")
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x and y must have the same tasks (columns), got shapes {x.shape} and {y.shape}")
    return independent_bootstrap_ci(
        probability_of_improvement, [x, y], reps=reps, confidence=confidence, seed=seed
    )


def improvement_intervals(
    scores: Mapping[str, np.ndarray],
    pairs: Sequence[tuple[str, str]],
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[tuple[str, str], tuple[float, float, float]]:
    """
    P(X > Y) with its interval for each pair of methods compared head to head.

    :param scores: method -> (n_runs, n_tasks) or (n_runs,) scores, the same tasks for all
    :param pairs: (X, Y) names of ``scores``
    :param reps: bootstrap resamples
    :param confidence: of the intervals, in (0, 1)
    :param seed: seed of the resamples of every pair
    :return: (X, Y) -> (point, low, high)
    """
    unknown = sorted({name for pair in pairs for name in pair} - set(scores))
    if unknown:
        raise ValueError(f"pairs name methods that scores does not have: {unknown}; it has {sorted(scores)}")
    return {
        (x, y): probability_of_improvement_ci(
            scores[x], scores[y], reps=reps, confidence=confidence, seed=seed
        )
        for x, y in pairs
    }


def aggregate_intervals(
    scores: np.ndarray,
    aggregates: Sequence[str] = ("IQM", "mean"),
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[str, dict[str, float]]:
    """
    Aggregates of the scores with their stratified bootstrap intervals, every aggregate over the same
    resamples (as rliable computes several in one ``get_interval_estimates``).

    :param scores: (n_runs, n_tasks) or (n_runs,), e.g. each run's average reward over a window
    :param aggregates: names in ``AGGREGATES``
    :param reps: bootstrap resamples
    :param confidence: of the intervals, in (0, 1)
    :param seed: seed of the resamples
    :return: ``{aggregate: {"point": ..., "low": ..., "high": ...}}``
    """
    unknown = [name for name in aggregates if name not in AGGREGATES]
    if unknown:
        raise ValueError(f"aggregates must be among {list(AGGREGATES)}, got {unknown}")
    out = {}
    for name in aggregates:
        point, low, high = stratified_bootstrap_ci(
            scores, AGGREGATES[name], reps=reps, confidence=confidence, seed=seed
        )
        out[name] = {"point": point, "low": low, "high": high}
    return out


def interval_cell(point: float, low: float, high: float, digits: int = 3) -> str:
    """A table cell ``point [low, high]``, e.g. ``0.754 [0.701, 0.802]``."""
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _one_matrix(scores: np.ndarray, name: str) -> np.ndarray:
    """A single (n_runs, n_tasks) score matrix, checked."""
    scores = score_matrix(scores, name)
    if scores.ndim != 2:
        raise ValueError(
            f"{name} must be one (n_runs, n_tasks) score matrix or (n_runs,), got {scores.shape}"
        )
    return scores


def independent_bootstrap_ci(
    statistic: Callable[..., np.ndarray],
    matrices: Sequence[np.ndarray],
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """
    ``statistic(*matrices)`` and its percentile interval over resamples of each matrix's runs within each of
    its tasks, independently of the other matrices (rliable's ``StratifiedIndependentBootstrap``; with one
    matrix, its ``StratifiedBootstrap``). E.g. ``mean_ratio`` of a method's scores and a reference level's.

    :param statistic: maps one batch of resamples of each matrix, (reps, n_runs, n_tasks) each, to (reps,)
    :param matrices: the score matrices, (n_runs, n_tasks) or (n_runs,) each
    :param reps: bootstrap resamples
    :param confidence: probability that the interval covers the statistic, in (0, 1)
    :param seed: seed of the resamples
    :return: (point, low, high)
    """
    matrices = [_one_matrix(matrix, f"matrices[{index}]") for index, matrix in enumerate(matrices)]
    return _percentile_interval(
        statistic,
        matrices,
        lambda n, rng: [_resample(matrix, n, rng) for matrix in matrices],
        reps=reps,
        confidence=confidence,
        seed=seed,
    )


def paired_bootstrap_ci(
    statistic: Callable[..., np.ndarray],
    columns: Sequence[np.ndarray],
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """
    ``statistic(*columns)`` and its percentile interval over resamples of the runs, one draw of runs for
    every column: each column holds one method's score of each run, and a run's scores stay together (the
    same target and seed for every method), as a paired difference needs. E.g. a share of a reference's gain
    over a floor, ``mean(x - floor) / mean(reference - floor)``.

    :param statistic: maps one batch of resamples of each column, (reps, n_runs) each, to (reps,)
    :param columns: each method's scores, (n_runs,) each, run i of every column the same run
    :param reps: bootstrap resamples
    :param confidence: probability that the interval covers the statistic, in (0, 1)
    :param seed: seed of the resamples
    :return: (point, low, high)
    """
    shapes = [np.shape(column) for column in columns]
    if not shapes or len(set(shapes)) != 1 or len(shapes[0]) != 1 or shapes[0][0] == 0:
        raise ValueError(f"columns must be (n_runs,) arrays of one length, n_runs >= 1, got shapes {shapes}")
    table = np.column_stack([np.asarray(column, dtype=np.float64) for column in columns])

    def resample(n: int, rng: np.random.Generator) -> list[np.ndarray]:
        rows = table[rng.integers(0, len(table), size=(n, len(table)))]  # (n, n_runs, n_columns)
        return [rows[..., j] for j in range(table.shape[1])]

    return _percentile_interval(
        statistic, list(table.T), resample, reps=reps, confidence=confidence, seed=seed
    )


def _percentile_interval(
    statistic: Callable[..., np.ndarray],
    data: Sequence[np.ndarray],
    resample: Callable[[int, np.random.Generator], Sequence[np.ndarray]],
    *,
    reps: int,
    confidence: float,
    seed: int,
) -> tuple[float, float, float]:
    """The statistic of ``data`` and its percentile interval over ``reps`` resamples drawn by ``resample``."""
    if not isinstance(reps, (int, np.integer)) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    rng = np.random.default_rng(seed)
    per_rep = sum(np.size(array) for array in data)
    estimates = []
    for n in _chunks(reps, max(1, CHUNK_ELEMENTS // per_rep)):
        batch = statistic(*resample(n, rng))
        if np.shape(batch) != (n,):
            raise ValueError(
                f"statistic must map a batch of resamples (..., n_runs[, n_tasks]) to (...), got shape "
                f"{np.shape(batch)} from a batch of {n}"
            )
        estimates.append(batch)
    alpha = (1.0 - confidence) / 2
    with np.errstate(invalid="ignore"):  # a ratio's estimates may be infinite: its interval then is too
        low, high = np.percentile(np.concatenate(estimates), [100 * alpha, 100 * (1 - alpha)])
    return float(statistic(*data)), float(low), float(high)


def _resample(scores: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, n_runs, n_tasks) resamples: cell [r, i, t] is ``scores[j, t]`` with j drawn from task t's runs."""
    n_runs, n_tasks = scores.shape
    rows = rng.integers(0, n_runs, size=(n, n_runs, n_tasks))
    return scores[rows, np.arange(n_tasks)]


def _chunks(total: int, size: int) -> Iterator[int]:
    """Sizes of consecutive chunks of at most ``size`` that add up to ``total``."""
    for start in range(0, total, size):
        yield min(size, total - start)
