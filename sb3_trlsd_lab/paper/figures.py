"""Drawing and writing shared by the figures: curves of transfer runs, and maze snapshots."""

from __future__ import annotations

import textwrap
import time
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd.atomic_files import atomic_path
from sb3_trlsd_envs import task_cell
from sb3_trlsd_envs.dynamics import DEFAULT_WALLS
from sb3_trlsd_lab.execution.protocols import Protocol, protocol_record
from sb3_trlsd_lab.execution.runner import RunRecord, Snapshot
from sb3_trlsd_lab.paper.reporting import (
    mean_and_standard_error,
    plot_curves,
    plot_probability_of_improvement,
    source_sets_of,
    summary,
    window_means,
    write_curves_csv,
    write_json,
)
from sb3_trlsd_lab.stats.bootstrap import improvement_intervals

__all__ = [
    "curves_of",
    "draw_snapshot",
    "new_figure",
    "protocol_title",
    "save_figure",
    "transfer_results",
    "update_counts",
    "write_curves_figure",
    "write_improvement_figure",
    "write_transfer_figure",
]

CURVE_SMOOTHING = 20  # transitions of the moving average drawn (the CSV keeps every transition)


class Described(typing.Protocol):
    """A method of a figure (a ``runner.Method``, a benchmark's ``Contender``): its settings, for the JSON."""

    def parameters(self) -> dict[str, Any]:
        """The settings that tell it from the other methods."""


def new_figure(n_panels: int, width: float = 5.5, height: float = 4.2) -> tuple[Any, list[Any]]:
    """A matplotlib figure with ``n_panels`` side by side (the Agg backend: no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width * n_panels, height), dpi=110)
    FigureCanvasAgg(figure)
    return figure, [figure.add_subplot(1, n_panels, i + 1) for i in range(n_panels)]


def protocol_title(title: str, protocol: Protocol) -> str:
    """
    A figure's title that names the protocol it ran under (its preset's name, ``"custom"`` for choices no
    preset has, as the JSON records it): a figure under one protocol must not pass for another's.

    :param title: what the figure shows
    :param protocol: the choices the figure's runs made
    """
    return f"{title} (protocol: {protocol_record(protocol)['name']})"


def save_figure(figure: Any, path: Path, title: str) -> None:
    """Title the figure (wrapped to its width) and write it as a PNG, whole or not at all."""
    figure.suptitle(textwrap.fill(title, width=int(11 * figure.get_figwidth())))
    figure.tight_layout()
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format=Path(path).suffix.lstrip(".") or None)


def draw_snapshot(ax: Any, snapshot: Snapshot, task: int, title: str) -> None:
    """A snapshot in the style of the paper's Figures 1-4: R^ in green, trajectory in blue, policy in red."""
    from sb3_trlsd_envs.rendering import draw_maze

    draw_maze(
        ax,
        DEFAULT_WALLS,
        target_cells=[task_cell(task)],
        trajectory=snapshot.trajectory,
        state_values=snapshot.reward_estimate,
        policy=snapshot.policy,
        title=title,
    )


def update_counts(records: Sequence[RunRecord]) -> dict[str, float]:
    """Mean and standard error of the policy updates per run."""
    mean, se = mean_and_standard_error(np.array([[record.policy_updates] for record in records]))
    return {"mean": float(mean[0]), "se": float(se[0])}


def write_improvement_figure(
    path: Path,
    scores: Mapping[str, np.ndarray],
    pairs: Sequence[tuple[str, str]],
    title: str,
    *,
    reps: int = 2_000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[tuple[str, str], tuple[float, float, float]]:
    """
    Write a PNG of P(X > Y) for head-to-head comparisons, with stratified bootstrap intervals, as rliable
    draws them (``bootstrap.improvement_intervals``, ``reporting.plot_probability_of_improvement``).

    :param path: the PNG file
    :param scores: method -> (runs, tasks) or (runs,) scores, e.g. each run's average reward over a window
    :param pairs: (X, Y) method names
    :param title: the figure's title
    :param reps: bootstrap resamples
    :param confidence: of the intervals, in (0, 1)
    :param seed: seed of the resamples
    :return: (X, Y) -> (point, low, high)
    """
    intervals = improvement_intervals(scores, pairs, reps=reps, confidence=confidence, seed=seed)
    figure, (ax,) = new_figure(1, width=6.0, height=1.6 + 0.45 * len(pairs))
    plot_probability_of_improvement(ax, intervals)
    save_figure(figure, path, title)
    return intervals


def curves_of(records: Mapping[str, Sequence[RunRecord]]) -> dict[str, np.ndarray]:
    """Each method's runs as one array of rewards, (runs, transitions)."""
    return {label: np.stack([record.rewards for record in runs]) for label, runs in records.items()}


def transfer_results(
    records: Mapping[str, Sequence[RunRecord]], windows: Sequence[tuple[int, int]]
) -> dict[str, dict[str, Any]]:
    """
    The aggregates of each method's transfer runs: the reward over ``windows`` (mean, standard error over
    source sets, ``se_runs``), the policy updates, the seconds per run and the runs.

    :return: method label -> its aggregates
    """
    curves = curves_of(records)
    return {
        label: {
            "reward": window_means(curves[label], windows, source_sets_of(runs)),
            "policy_updates": update_counts(runs),
            "seconds_per_run": float(np.mean([record.seconds for record in runs])),
            "runs": len(runs),
        }
        for label, runs in records.items()
    }


def write_curves_figure(
    out: Path,
    name: str,
    title: str,
    curves: Mapping[str, np.ndarray],
    panels: Sequence[tuple[str, Sequence[str]]] | None = None,
    picture: tuple[Snapshot, int, str] | None = None,
    legend: Mapping[str, str] | None = None,
) -> None:
    """
    Write ``name``.csv (per-transition curves) and ``name``.png (the curves, one panel per group of methods).

    :param curves: method label -> (runs, transitions) rewards
    :param panels: (panel title, method labels) of each panel; one panel with every method if None
    :param picture: (snapshot, task, title) drawn in a first panel, if given
    :param legend: method label -> its name in the legend (default: the label); a name has one color in
        every panel
    """
    write_curves_csv(out / f"{name}.csv", "transition", curves)
    panels = panels or [("", list(curves))]
    legend = legend or {}
    names = {label: legend.get(label, label) for label in curves}
    figure, axes = new_figure(len(panels) + (picture is not None))
    if picture is not None:
        draw_snapshot(axes.pop(0), *picture)
    # One color per name, in all panels.
    colors = {name: f"C{index}" for index, name in enumerate(dict.fromkeys(names.values()))}
    for ax, (panel_title, labels) in zip(axes, panels, strict=True):
        plot_curves(
            ax, {names[label]: curves[label] for label in labels}, smooth=CURVE_SMOOTHING, colors=colors
        )
        ax.set_title(panel_title)
    save_figure(figure, out / f"{name}.png", title)


def write_transfer_figure(
    out: Path,
    name: str,
    title: str,
    methods: Sequence[Described],
    records: Mapping[str, Sequence[RunRecord]],
    windows: Sequence[tuple[int, int]],
    parameters: Mapping[str, Any],
    seed: int,
    started: float,
    panels: Sequence[tuple[str, Sequence[str]]] | None = None,
    picture: tuple[Snapshot, int, str] | None = None,
) -> dict:
    """
    Write ``name``.csv (per-transition curves), ``name``.png (the curves, one panel per group of methods)
    and ``name``.json (reward over ``windows``, policy updates, seconds per run) for transfer runs.

    :param panels: (panel title, method labels) of each panel; one panel with every method if None
    :param picture: (snapshot, task, title) drawn in a first panel, if given
    :return: the JSON summary
    """
    write_curves_figure(out, name, title, curves_of(records), panels, picture)
    data = summary(
        name,
        {**parameters, "methods": [method.parameters() for method in methods]},
        seed,
        time.perf_counter() - started,
        results=transfer_results(records, windows),
    )
    write_json(out / f"{name}.json", data)
    return data
