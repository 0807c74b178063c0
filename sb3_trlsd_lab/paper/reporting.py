"""What every figure writes: a CSV of its curves, a PNG in the paper's style and a JSON summary."""

from __future__ import annotations

import csv
import json
import platform
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd.atomic_files import atomic_write
from sb3_trlsd.version import __version__
from sb3_trlsd_lab.stats.bootstrap import aggregate_intervals, interval_cell

__all__ = [
    "intervals_table",
    "mean_and_standard_error",
    "moving_average",
    "plot_curves",
    "plot_probability_of_improvement",
    "results_table",
    "source_sets_of",
    "summary",
    "window_intervals",
    "window_means",
    "write_curves_csv",
    "write_json",
]


def mean_and_standard_error(
    values: np.ndarray, clusters: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """
    Mean over runs and its standard error (0 with a single run).

    Runs that started from the same source set are not independent: with ``clusters`` (the source set of
    each run), the standard error is that of the mean of the clusters' means, std(cluster means) /
    sqrt(clusters), which counts each source set once (the cluster-robust standard error for clusters of
    equal size; they differ by one run at most here).

    :param values: (runs, ...) one row per run
    :param clusters: (runs,) the cluster of each run, or None for independent runs
    :return: mean and standard error, each of shape values.shape[1:]
    """
    values = np.asarray(values, dtype=np.float64)
    if clusters is not None and len(np.unique(clusters)) >= 2:
        clusters = np.asarray(clusters)
        means = np.stack([values[clusters == cluster].mean(axis=0) for cluster in np.unique(clusters)])
        return values.mean(axis=0), means.std(axis=0, ddof=1) / np.sqrt(len(means))
    n_runs = len(values)
    if n_runs < 2:
        return values.mean(axis=0), np.zeros(values.shape[1:])
    return values.mean(axis=0), values.std(axis=0, ddof=1) / np.sqrt(n_runs)


def source_sets_of(records: Sequence[Any]) -> np.ndarray | None:
    """The source set of each run (``RunRecord.source_set``), or None if a run had one of its own."""
    sets = [record.source_set for record in records]
    return None if any(source_set is None for source_set in sets) else np.array(sets)


def window_means(
    values: np.ndarray, windows: Sequence[tuple[int, int]], clusters: np.ndarray | None = None
) -> dict[str, dict[str, float]]:
    """
    The reward averaged over each window of steps ``[start, stop)``, its mean and standard error over runs
    (over source sets with ``clusters``: see ``mean_and_standard_error``, and then also ``se_runs``, the
    standard error as if the runs were independent).

    :param values: (runs, steps)
    :param windows: ``(start, stop)`` pairs
    :param clusters: (runs,) the source set of each run, or None
    :return: ``{"[start, stop)": {"mean": ..., "se": ...}}``
    """
    out = {}
    for start, stop in windows:
        window = _window_average(values, start, stop)
        mean, se = mean_and_standard_error(window, clusters)
        out[f"[{start}, {stop})"] = {"mean": float(mean), "se": float(se)}
        if clusters is not None:
            out[f"[{start}, {stop})"]["se_runs"] = float(mean_and_standard_error(window)[1])
    return out


def _window_average(values: np.ndarray, start: int, stop: int) -> np.ndarray:
    """(runs,) each run's reward averaged over the steps ``[start, stop)`` of (runs, steps) values."""
    return np.asarray(values)[:, start:stop].mean(axis=1)


def window_intervals(
    values: np.ndarray,
    windows: Sequence[tuple[int, int]],
    clusters: np.ndarray | None = None,
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[str, dict[str, str]]:
    """
    Table cells of each window: the mean ± standard error of ``window_means`` next to the mean and the IQM
    of the runs' averages over the window, with their stratified bootstrap intervals as rliable computes
    them (``bootstrap.aggregate_intervals``; the bootstrap resamples runs, not source sets).

    :param values: (runs, steps)
    :param windows: ``(start, stop)`` pairs
    :param clusters: (runs,) the source set of each run, or None (for the standard error only)
    :param reps: bootstrap resamples
    :param confidence: of the intervals, in (0, 1)
    :param seed: seed of the resamples
    :return: ``{"[start, stop)": {"mean ± se": ..., "mean [95% CI]": ..., "IQM [95% CI]": ...}}``
    """
    means = window_means(values, windows, clusters)
    level = f"{100 * confidence:g}% CI"
    out = {}
    for start, stop in windows:
        key = f"[{start}, {stop})"
        intervals = aggregate_intervals(
            _window_average(values, start, stop), ("mean", "IQM"), reps=reps, confidence=confidence, seed=seed
        )
        out[key] = {"mean ± se": _cell(means[key])}
        for name, interval in intervals.items():
            out[key][f"{name} [{level}]"] = interval_cell(
                interval["point"], interval["low"], interval["high"]
            )
    return out


def intervals_table(
    curves: Mapping[str, np.ndarray],
    windows: Sequence[tuple[int, int]],
    clusters: Mapping[str, np.ndarray | None] | None = None,
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> str:
    """
    A Markdown table with one row per method and window: mean ± se, then the mean and the IQM with their
    stratified bootstrap intervals (``window_intervals``).

    :param curves: method -> (runs, steps) values
    :param windows: ``(start, stop)`` pairs
    :param clusters: method -> (runs,) the source set of each run, or None; None: independent runs
    :param reps: bootstrap resamples
    :param confidence: of the intervals, in (0, 1)
    :param seed: seed of the resamples
    :return: the table
    """
    clusters = clusters or {}
    rows = {
        method: window_intervals(
            values, windows, clusters.get(method), reps=reps, confidence=confidence, seed=seed
        )
        for method, values in curves.items()
    }
    columns = list(
        dict.fromkeys(column for cells in rows.values() for row in cells.values() for column in row)
    )
    lines = ["| method | window | " + " | ".join(columns) + " |", "|---" * (len(columns) + 2) + "|"]
    for method, cells in rows.items():
        for window, row in cells.items():
            lines.append(f"| {method} | {window} | " + " | ".join(row[column] for column in columns) + " |")
    return "\n".join(lines)


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average along the last axis (shorter windows at the start), same shape."""
    values = np.asarray(values, dtype=np.float64)
    if window <= 1:
        return values
    cumulative = np.cumsum(values, axis=-1)
    shifted = np.zeros_like(cumulative)
    shifted[..., window:] = cumulative[..., :-window]
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (cumulative - shifted) / counts


def write_curves_csv(path: Path, x_name: str, curves: Mapping[str, np.ndarray]) -> None:
    """
    One row per (x, method): ``x_name, method, mean, se, runs``.

    :param path: the CSV file
    :param x_name: name of the x column (``transition``, ``episode``, ...), x = 0, 1, ...
    :param curves: method -> (runs, points) values
    """
    with atomic_write(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow([x_name, "method", "mean", "se", "runs"])
        for method, values in curves.items():
            mean, se = mean_and_standard_error(values)
            for x, (m, s) in enumerate(zip(mean, se, strict=True)):
                writer.writerow([x, method, f"{m:.6g}", f"{s:.6g}", len(values)])


def plot_curves(
    ax: Any,
    curves: Mapping[str, np.ndarray],
    *,
    smooth: int = 1,
    xlabel: str = "transitions",
    ylabel: str = "average reward",
    colors: Mapping[str, str] | None = None,
    x: np.ndarray | None = None,
    marker: str | None = None,
) -> None:
    """
    Mean curves with a band of one standard error, as in the paper's Figures 5, 6 and 8.

    :param ax: matplotlib Axes
    :param curves: label -> (runs, points) values
    :param smooth: each run is first averaged over a trailing window of this many points
    :param xlabel: x axis label
    :param ylabel: y axis label
    :param colors: label -> matplotlib color, to keep a method's color across panels (default: cycle)
    :param x: abscissa of the points (default: 0, 1, ...)
    :param marker: matplotlib marker of the points (default: none)
    """
    for label, values in curves.items():
        mean, se = mean_and_standard_error(moving_average(values, smooth))
        abscissa = np.arange(len(mean)) if x is None else np.asarray(x)
        color = None if colors is None else colors.get(label)
        (line,) = ax.plot(
            abscissa, mean, label=f"{label} ({len(values)} runs)", linewidth=1.5, color=color, marker=marker
        )
        ax.fill_between(abscissa, mean - se, mean + se, color=line.get_color(), alpha=0.25, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel + (f" (moving average over {smooth})" if smooth > 1 else ""))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def plot_probability_of_improvement(
    ax: Any,
    intervals: Mapping[tuple[str, str], tuple[float, float, float]],
    *,
    xlabel: str = "P(X > Y)",
    colors: Sequence[str] | None = None,
) -> None:
    """
    P(X > Y) of each pair as a horizontal interval with a tick at its point, X named on the left and Y on
    the right, the first pair at the bottom, as rliable's ``plot_utils.plot_probability_of_improvement``
    draws it (in matplotlib's color cycle rather than seaborn's colorblind palette).

    :param ax: matplotlib Axes
    :param intervals: (X, Y) -> (point, low, high), e.g. from ``bootstrap.improvement_intervals``
    :param xlabel: x axis label
    :param colors: one matplotlib color per pair (default: cycle)
    """
    height = 0.6  # rliable's interval_height
    for index, (point, low, high) in enumerate(intervals.values()):
        color = f"C{index}" if colors is None else colors[index]
        ax.barh(y=index, width=high - low, height=height, left=low, color=color, alpha=0.75)
        ax.vlines(
            x=point, ymin=index - 7.5 * height / 16, ymax=index + 6 * height / 16, color="k", alpha=0.85
        )
    # A twin axis names Y on the right; only the bottom spine is kept, labels above the ticks (rliable's).
    right = ax.twinx()
    sides = (
        (ax, [x for x, _ in intervals], "X", (-0.2, 1.0)),
        (right, [y for _, y in intervals], "Y", (1.14, 1.12)),
    )
    for axis, names, label, coordinates in sides:
        axis.set_ylim(-0.5, len(intervals) - 0.5)
        axis.set_yticks(range(len(intervals)), names)
        axis.set_ylabel(f"Algorithm {label}", fontweight="bold", rotation="horizontal")
        axis.yaxis.set_label_coords(*coordinates)
        axis.tick_params(length=0.1, width=0.1)
        for spine in ("left", "right", "top"):
            axis.spines[spine].set_visible(False)
    ax.set_xlabel(xlabel)
    ax.grid(True, axis="x", alpha=0.2)


def summary(figure: str, parameters: Mapping[str, Any], seed: int, seconds: float, **results: Any) -> dict:
    """The JSON summary of a figure: what was run, how long it took, and its aggregates."""
    return {
        "figure": figure,
        "package_version": __version__,
        "python": platform.python_version(),
        "seed": seed,
        "wall_time_seconds": round(seconds, 2),
        "parameters": dict(parameters),
        **results,
    }


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` as indented JSON, whole or not at all (``atomic_write``)."""
    with atomic_write(path, "w") as file:
        json.dump(data, file, indent=2)
        file.write("\n")


def _cell(value: Any) -> str:
    if isinstance(value, Mapping) and {"mean", "se"} <= set(value):
        return f"{value['mean']:.3f} ± {value['se']:.3f}"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def _flatten(entry: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """
    {"reward": {"[0, 100)": {"mean", "se"}}} -> {"reward [0, 100)": {"mean", "se"}}; a cell keeps its
    ``se_runs`` (the standard error as if runs of one source set were independent) out of the table.
    """
    flat = {}
    for key, value in entry.items():
        name = f"{prefix} {key}".strip()
        if isinstance(value, Mapping) and not {"mean", "se"} <= set(value) <= {"mean", "se", "se_runs"}:
            flat.update(_flatten(value, name))
        else:
            flat[name] = value
    return flat


def results_table(data: Mapping[str, Any]) -> str:
    """
    A figure's JSON results as a Markdown table: one row per method (or setting), mean ± standard error.

    :param data: a figure's summary (``results`` maps each method to its aggregates)
    :return: the table
    """
    results = data["results"]
    if not all(isinstance(entry, Mapping) for entry in results.values()):
        results = {data["figure"]: results}  # a single run's aggregates (Figures 2-4)
    rows = {label: _flatten(entry) for label, entry in results.items()}
    columns = list(dict.fromkeys(column for row in rows.values() for column in row))
    header = [column.replace("_", " ") for column in columns]
    lines = ["| method | " + " | ".join(header) + " |", "|---" * (len(columns) + 1) + "|"]
    for label, row in rows.items():
        lines.append(f"| {label} | " + " | ".join(_cell(row.get(column, "")) for column in columns) + " |")
    return "\n".join(lines)
