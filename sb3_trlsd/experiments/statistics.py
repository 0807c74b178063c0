"""
Aggregates of runs with stratified bootstrap confidence intervals, and the probability of improvement, as
``rliable`` computes them (Agarwal et al., "Deep Reinforcement Learning at the Edge of the Statistical
Precipice", NeurIPS 2021). They are written here because rliable's bootstrap comes from ``arch``, which does
not import with the pandas this package is installed with.

A score matrix is (n_runs, n_tasks): one row per run, one column per task (a stratum of the bootstrap); a
1-D array is the runs of a single task. The aggregates reduce the last two axes, so that one call takes a
whole batch of resamples (reps, n_runs, n_tasks).

rliable's definitions and where they are (github.com/google-research/rliable: ``rliable/metrics.py``, and
for the bootstrap ``library.py`` as of commit 06ab799):

- IQM, ``rliable/metrics.py::aggregate_iqm``: ``scipy.stats.trim_mean(scores, 0.25, axis=None)``, the mean
  of the middle half of all runs x tasks taken together (int(n / 4) scores cut at each end).
- mean and median, ``aggregate_mean`` and ``aggregate_median``: the mean and the median over tasks of each
  task's mean over runs.
- optimality gap, ``aggregate_optimality_gap``: ``gamma - mean(minimum(scores, gamma))``, gamma = 1.
- probability of improvement, ``probability_of_improvement``: for each task, the Mann-Whitney U of X's runs
  against Y's divided by n_x * n_y, that is P(X > Y) + P(X = Y) / 2 over all pairs of runs, averaged over
  tasks (rliable sets a task whose two columns are equal to 0.5, which this formula gives too).
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
import scipy.stats

__all__ = [
    "AGGREGATES",
    "aggregate_intervals",
    "aggregate_mean",
    "aggregate_median",
    "improvement_intervals",
    "independent_bootstrap_ci",
    "interquartile_mean",
    "interval_cell",
    "mean_ratio",
    "optimality_gap",
    "probability_of_improvement",
    "probability_of_improvement_ci",
    "score_matrix",
    "scores_by_task",
    "stratified_bootstrap_ci",
]

# A statistic maps score matrices (..., n_runs, n_tasks) to an array of shape (...)
Statistic = Callable[[np.ndarray], np.ndarray]

# Resampled scores held in memory at once (float64): 32 MB
CHUNK_ELEMENTS = 1 << 22


def score_matrix(scores: np.ndarray, name: str = "scores") -> np.ndarray:
    """
    Check scores and give them as score matrices.

    :param scores: (..., n_runs, n_tasks) scores, or (n_runs,) the runs of one task
    :param name: what the error messages call the argument
    :return: float64 scores with at least two axes, runs on the second to last, tasks on the last
    """
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim == 1:
        scores = scores[:, None]
    if scores.ndim < 2:
        raise ValueError(f"{name} must be an array of (n_runs, n_tasks) scores or (n_runs,), got a scalar")
    if scores.shape[-2] == 0 or scores.shape[-1] == 0:
        raise ValueError(f"{name} must hold at least one run of one task, got shape {scores.shape}")
    if not np.isfinite(scores).all():
        raise ValueError(f"{name} must be finite, got {np.count_nonzero(~np.isfinite(scores))} NaN or inf")
    return scores


def interquartile_mean(scores: np.ndarray) -> np.ndarray:
    """
    The interquartile mean (IQM): the mean of the middle half of all runs and tasks taken together, the
    25 % trimmed mean (rliable's ``aggregate_iqm``).

    :param scores: (..., n_runs, n_tasks) or (n_runs,)
    :return: (...) one IQM per score matrix
    """
    scores = score_matrix(scores)
    flat = scores.reshape(*scores.shape[:-2], -1)
    return np.asarray(scipy.stats.trim_mean(flat, 0.25, axis=-1))


def aggregate_mean(scores: np.ndarray) -> np.ndarray:
    """
    The mean over tasks of each task's mean over runs (rliable's ``aggregate_mean``).

    :param scores: (..., n_runs, n_tasks) or (n_runs,)
    :return: (...)
    """
    return score_matrix(scores).mean(axis=-2).mean(axis=-1)


def aggregate_median(scores: np.ndarray) -> np.ndarray:
    """
    The median over tasks of each task's mean over runs (rliable's ``aggregate_median``).

    :param scores: (..., n_runs, n_tasks) or (n_runs,)
    :return: (...)
    """
    return np.median(score_matrix(scores).mean(axis=-2), axis=-1)


def optimality_gap(scores: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """
    How far the runs fall short of ``gamma`` on average, scores above it counting as ``gamma`` (rliable's
    ``aggregate_optimality_gap``).

    :param scores: (..., n_runs, n_tasks) or (n_runs,)
    :param gamma: the score deemed optimal
    :return: (...) ``gamma - mean(minimum(scores, gamma))``
    """
    return gamma - np.minimum(score_matrix(scores), gamma).mean(axis=(-2, -1))


AGGREGATES: dict[str, Statistic] = {
    "IQM": interquartile_mean,
    "mean": aggregate_mean,
    "median": aggregate_median,
    "optimality gap": optimality_gap,
}


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """
    P(X > Y): the probability that a run of X scores above a run of Y on the same task, a tie counting one
    half, averaged over tasks (rliable's ``probability_of_improvement``).

    :param x: (..., n_runs_x, n_tasks) or (n_runs_x,)
    :param y: (..., n_runs_y, n_tasks) or (n_runs_y,), the same tasks in the same order
    :return: (...)
    """
    x, y = score_matrix(x, "x"), score_matrix(y, "y")
    if x.shape[-1] != y.shape[-1] or x.shape[:-2] != y.shape[:-2]:
        raise ValueError(f"x and y must have the same tasks (last axis), got shapes {x.shape} and {y.shape}")
    n_x, n_y = x.shape[-2], y.shape[-2]
    # Average ranks in the pooled runs of each task: a tie shares its ranks, so counts one half. Runs on
    # the last axis, contiguous, rank twice as fast.
    pooled = np.ascontiguousarray(np.swapaxes(np.concatenate([x, y], axis=-2), -1, -2))
    ranks = scipy.stats.rankdata(pooled, axis=-1)  # (..., n_tasks, n_runs_x + n_runs_y)
    u_statistic = ranks[..., :n_x].sum(axis=-1) - n_x * (n_x + 1) / 2  # (..., n_tasks) Mann-Whitney U
    return (u_statistic / (n_x * n_y)).mean(axis=-1)


def scores_by_task(scores: np.ndarray, tasks: np.ndarray) -> np.ndarray:
    """
    The runs' scores as a score matrix with a column per task, the strata of the bootstrap: (n, n_tasks)
    when every task has the same n runs (column t: task t's runs in their order, tasks sorted), else the runs
    as a single stratum (n_runs,).

    :param scores: one score per run, (n_runs,)
    :param tasks: the task of each run, (n_runs,)
    :return: (n, n_tasks) or (n_runs,)
    """
    scores, tasks = np.asarray(scores, dtype=np.float64), np.asarray(tasks)
    if scores.shape != tasks.shape or scores.ndim != 1:
        raise ValueError(f"scores and tasks must be (n_runs,) each, got {scores.shape} and {tasks.shape}")
    names, counts = np.unique(tasks, return_counts=True)
    if len(names) < 2 or np.any(counts != counts[0]):
        return scores
    return np.stack([scores[tasks == task] for task in names], axis=1)


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
    :param statistic: maps score matrices (..., n_runs, n_tasks) to (...), as the aggregates above do
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


def mean_ratio(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """
    The ratio of the aggregate means, mean(X) / mean(Y) (e.g. a method's reward as a fraction of a reference
    level): infinite or NaN where mean(Y) = 0.

    :param x: (..., n_runs_x, n_tasks) or (n_runs_x,)
    :param y: (..., n_runs_y, n_tasks_y) or (n_runs_y,), any tasks
    :return: (...)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return aggregate_mean(x) / aggregate_mean(y)


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
    if not isinstance(reps, (int, np.integer)) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    rng = np.random.default_rng(seed)
    per_rep = sum(matrix.size for matrix in matrices)
    estimates = []
    for n in _chunks(reps, max(1, CHUNK_ELEMENTS // per_rep)):
        batch = statistic(*(_resample(matrix, n, rng) for matrix in matrices))
        if np.shape(batch) != (n,):
            raise ValueError(
                f"statistic must map score matrices (..., n_runs, n_tasks) to (...), got shape "
                f"{np.shape(batch)} from a batch of {n}"
            )
        estimates.append(batch)
    alpha = (1.0 - confidence) / 2
    with np.errstate(invalid="ignore"):  # a ratio's estimates may be infinite: its interval then is too
        low, high = np.percentile(np.concatenate(estimates), [100 * alpha, 100 * (1 - alpha)])
    return float(statistic(*matrices)), float(low), float(high)


def _resample(scores: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, n_runs, n_tasks) resamples: cell [r, i, t] is ``scores[j, t]`` with j drawn from task t's runs."""
    n_runs, n_tasks = scores.shape
    rows = rng.integers(0, n_runs, size=(n, n_runs, n_tasks))
    return scores[rows, np.arange(n_tasks)]


def _chunks(total: int, size: int) -> Iterator[int]:
    """Sizes of consecutive chunks of at most ``size`` that add up to ``total``."""
    for start in range(0, total, size):
        yield min(size, total - start)
