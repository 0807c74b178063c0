"""
Aggregates of runs and the probability of improvement, as ``rliable`` computes them (Agarwal et al., "Deep
Reinforcement Learning at the Edge of the Statistical Precipice", NeurIPS 2021): the point estimators, on
one score matrix or on a batch of resamples. Their confidence intervals are ``bootstrap.py``'s.

A score matrix is (n_runs, n_tasks): one row per run, one column per task (a stratum of the bootstrap); a
1-D array is the runs of a single task. The aggregates reduce the last two axes, so that one call takes a
whole batch of resamples (reps, n_runs, n_tasks).

rliable's definitions and where they are (github.com/google-research/rliable: ``rliable/metrics.py``, as of
commit 06ab799):

- IQM, ``rliable/metrics.py::aggregate_iqm``: ``scipy.stats.trim_mean(scores, 0.25, axis=None)``, the mean
  of the middle half of all runs x tasks taken together (int(n / 4) scores cut at each end).
- mean and median, ``aggregate_mean`` and ``aggregate_median``: the mean and the median over tasks of each
  task's mean over runs.
- optimality gap, ``aggregate_optimality_gap``: ``gamma - mean(minimum(scores, gamma))``, gamma = 1.
- probability of improvement, ``probability_of_improvement``: for each task, the Mann-Whitney U of X's runs
  against Y's divided by n_x * n_y, that is P(X > Y) + P(X = Y) / 2 over all pairs of runs, averaged over
  tasks (rliable sets a task whose two columns are equal to 0.5, which this formula gives too).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.stats

__all__ = [
    "AGGREGATES",
    "Statistic",
    "aggregate_mean",
    "aggregate_median",
    "interquartile_mean",
    "mean_ratio",
    "optimality_gap",
    "probability_of_improvement",
    "score_matrix",
    "scores_by_task",
]

# A statistic maps score matrices (..., n_runs, n_tasks) to an array of shape (...)
Statistic = Callable[[np.ndarray], np.ndarray]


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
