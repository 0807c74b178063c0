"""
What ``reproduce beyond`` (``beyond.py``) reports from its runs: each method's bootstrap statistics (the mean
and IQM per window, the fraction of the known-reward level), P(method > eq. 9) and its figure
``beyond_improvement.png``, each curve's entry of ``beyond.json``, and the study's Markdown table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd_lab.execution.protocols import Protocol
from sb3_trlsd_lab.execution.runner import RunRecord
from sb3_trlsd_lab.paper.figures import protocol_title, transfer_results, write_improvement_figure
from sb3_trlsd_lab.paper.known_reward import KNOWN
from sb3_trlsd_lab.stats.bootstrap import aggregate_intervals, independent_bootstrap_ci, interval_cell
from sb3_trlsd_lab.stats.statistics import mean_ratio, scores_by_task
from sb3_trlsd_lab.studies.tuning import REFERENCE, window_scores

__all__ = [
    "GOAL_FRACTION",
    "Curve",
    "best_against_goal",
    "curve_label",
    "method_statistics",
    "study_results",
    "table",
    "verdict",
]

Curve = tuple[str, str, str, str]  # (label, maze, Q, method) of each curve
GOAL_FRACTION = 0.8  # the study's goal: 80% of the known-reward level over the last 500 online transitions


def curve_label(maze: str, policy: str, method: str) -> str:
    """The name of a curve: ``"<maze>, <Q>: <method>"``."""
    return f"{maze}, {policy}: {method}"


def method_statistics(
    records: Sequence[RunRecord],
    windows: Sequence[tuple[int, int]],
    window: tuple[int, int],
    known: Sequence[RunRecord],
    seed: int,
) -> dict[str, Any]:
    """
    The bootstrap statistics of one method's runs: per window, the mean and IQM of the runs' averages with
    their 95% stratified intervals (strata: the tasks, ``scores_by_task``); over ``window``, the fraction of
    the known-reward level with its interval (each side resampled on its own).

    :param records: the method's runs
    :param windows: the windows of the intervals
    :param window: the selection window
    :param known: the known reward's runs, the reference level
    :param seed: seed of the resamples
    :return: ``{"intervals": {window: {"IQM": ..., "mean": ...}}, "fraction_of_known": ...}``, intervals as
        ``{"point", "low", "high"}``
    """
    intervals = {
        f"[{start}, {stop})": aggregate_intervals(
            _task_scores(records, (start, stop)), ("IQM", "mean"), seed=seed
        )
        for start, stop in windows
    }
    scores, level = _task_scores(records, window), _task_scores(known, window)
    fraction = independent_bootstrap_ci(mean_ratio, [scores, level], seed=seed)
    return {"intervals": intervals, "fraction_of_known": _interval(fraction)}


def _task_scores(records: Sequence[RunRecord], window: tuple[int, int]) -> np.ndarray:
    """The runs' averages over ``window`` as a score matrix, a column per target task."""
    return scores_by_task(
        window_scores(records, window), np.array([int(record.tasks[0]) for record in records])
    )


def _interval(values: tuple[float, float, float]) -> dict[str, float | None]:
    """(point, low, high) as JSON, a value that is not finite (a ratio to a zero level) as None."""
    return {
        key: float(value) if np.isfinite(value) else None
        for key, value in zip(("point", "low", "high"), values, strict=True)
    }


def _write_improvement(
    out: Path,
    records: Mapping[str, Sequence[RunRecord]],
    rows: Sequence[Curve],
    window: tuple[int, int],
    seed: int,
    protocol: Protocol,
) -> dict[tuple[str, str], tuple[float, float, float]]:
    """
    ``beyond_improvement.png``: P(method > eq. 9) of each method with the same maze and Q, over ``window``
    (nothing when eq. 9 is the only method).

    :param rows: (label, maze, Q, method) of each curve
    :return: (label, eq. 9's label) -> (point, low, high)
    """
    pairs = [
        (label, curve_label(maze, policy, REFERENCE))
        for label, maze, policy, method in rows
        if method not in (REFERENCE, KNOWN.label)
    ]
    if not pairs:
        return {}
    return write_improvement_figure(
        out / "beyond_improvement.png",
        {label: _task_scores(records[label], window) for label, *_ in rows},
        pairs,
        protocol_title(
            f"P(method > {REFERENCE}) over transitions [{window[0]}, {window[1]}), with 95% stratified "
            "bootstrap intervals",
            protocol,
        ),
        seed=seed,
    )


def study_results(
    out: Path,
    records: Mapping[str, Sequence[RunRecord]],
    rows: Sequence[Curve],
    tuning: Mapping[str, Mapping[str, Any]],
    windows: Sequence[tuple[int, int]],
    window: tuple[int, int],
    seed: int,
    *,
    protocol: Protocol,
) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """
    Each curve's entry of the JSON: its window means (``transfer_results``), maze, Q and method, its
    ``method_statistics`` against the known reward of the linear Q on the same maze, the configuration its
    tuning selected, and P(method > eq. 9), drawn in ``beyond_improvement.png``.

    :param out: the output directory
    :param records: curve label -> its runs
    :param rows: (label, maze, Q, method) of each curve
    :param tuning: maze -> ``tune``'s result on it
    :param windows: the windows of the intervals
    :param window: the selection window
    :param seed: seed of the resamples
    :param protocol: the protocol of the runs, named in the figure's title
    :return: the entries by label, and the files written (``beyond_improvement.png``, or none)
    """
    results = transfer_results(records, windows)
    for label, maze, policy, method in rows:
        known = records[curve_label(maze, "linear Q", KNOWN.label)]
        results[label].update({"maze": maze, "q": policy, "method": method})
        results[label].update(method_statistics(records[label], windows, window, known, seed))
        if method in tuning[maze]:
            results[label]["configuration"] = tuning[maze][method]["selected"]
    improvement = _write_improvement(out, records, rows, window, seed, protocol)
    for (label, _), interval in improvement.items():
        results[label]["p_improvement"] = _interval(interval)
    for entry in results.values():
        entry["verdict"] = verdict(entry)
    return results, ["beyond_improvement.png"] if improvement else []


def _reaches_goal(fraction: Mapping[str, float | None]) -> bool | None:
    """True when the fraction's 95% interval lies at or above ``GOAL_FRACTION``, False below, else None."""
    if fraction["low"] is not None and fraction["low"] >= GOAL_FRACTION:
        return True
    if fraction["high"] is not None and fraction["high"] < GOAL_FRACTION:
        return False
    return None


def verdict(entry: Mapping[str, Any]) -> str:
    """
    A curve's verdict, read from its 95% intervals: against eq. 9, "beats" when P(method > eq. 9)'s interval
    lies above 1/2, "below" when under it, "no clear difference" when it holds 1/2; against
    ``GOAL_FRACTION`` of the known-reward level, "reaches" when the fraction's interval lies at or above it,
    "misses" when below, "within its interval" when it holds it. The known reward has no verdict ("").

    :param entry: the curve's entry of the JSON (``study_results``)
    """
    if entry["method"] == KNOWN.label:
        return ""
    parts = []
    improvement = entry.get("p_improvement")
    if improvement and improvement["low"] is not None and improvement["high"] is not None:
        if improvement["low"] > 0.5:
            parts.append(f"beats {REFERENCE}")
        elif improvement["high"] < 0.5:
            parts.append(f"below {REFERENCE}")
        else:
            parts.append(f"no clear difference from {REFERENCE}")
    fraction = entry["fraction_of_known"]
    if None not in fraction.values():
        goal = f"{GOAL_FRACTION:.0%} goal"
        reached = _reaches_goal(fraction)
        if reached:
            parts.append(f"reaches the {goal}")
        elif reached is False:
            parts.append(f"misses the {goal} by {GOAL_FRACTION - fraction['point']:.1%} of the known level")
        else:
            parts.append(f"the {goal} within its interval")
    return "; ".join(parts)


def best_against_goal(results: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """
    On each maze, the curve (any Q, the known reward aside) with the highest fraction of the known-reward
    level over the selection window, and that fraction against ``GOAL_FRACTION``.

    :param results: the JSON's curves (``study_results``)
    :return: maze -> ``{"curve", "fraction_of_known", "goal", "reached", "missed_by"}``; ``reached`` is
        True when the fraction's 95% interval lies at or above the goal, False when below, None when it
        holds it; ``missed_by`` is the goal less the point (<= 0 when the point reaches it)
    """
    best: dict[str, dict[str, Any]] = {}
    for label, entry in results.items():
        fraction = entry["fraction_of_known"]
        if entry["method"] == KNOWN.label or fraction["point"] is None:
            continue
        if entry["maze"] in best and best[entry["maze"]]["fraction_of_known"]["point"] >= fraction["point"]:
            continue
        best[entry["maze"]] = {
            "curve": label,
            "fraction_of_known": dict(fraction),
            "goal": GOAL_FRACTION,
            "reached": _reaches_goal(fraction),
            "missed_by": GOAL_FRACTION - fraction["point"],
        }
    return best


def _cell(interval: Mapping[str, float | None] | None) -> str:
    if not interval or interval["point"] is None:
        return ""
    if interval["low"] is None or interval["high"] is None:
        return f"{interval['point']:.3f}"
    return interval_cell(interval["point"], interval["low"], interval["high"])


def table(data: Mapping[str, Any]) -> str:
    """
    The study's JSON as a Markdown table: a row per maze, Q and method, over the selection window.

    :param data: ``reproduce``'s summary
    :return: the table
    """
    window = data["parameters"]["selection"]["window"]
    columns = [
        "maze, Q",
        "method",
        "selected configuration",
        "tuning score",
        f"reward {window}",
        "mean [95% CI]",
        "IQM [95% CI]",
        "fraction of known",
        f"P(X > {REFERENCE}) [95% CI]",
        "verdict",
        "policy updates",
        "seconds per run",
        "runs",
    ]
    lines = ["| " + " | ".join(columns) + " |", "|---" * len(columns) + "|"]
    for entry in data["results"].values():
        tuned = data["tuning"][entry["maze"]].get(entry["method"])
        reward = entry["reward"][window]
        intervals = entry["intervals"][window]
        cells = [
            f"{entry['maze']}, {entry['q']}",
            entry["method"],
            entry.get("configuration", ""),
            "" if tuned is None else f"{tuned['score']:.3f}",
            f"{reward['mean']:.3f} ± {reward['se']:.3f}",
            _cell(intervals["mean"]),
            _cell(intervals["IQM"]),
            _cell(entry["fraction_of_known"]),
            _cell(entry.get("p_improvement")),
            entry.get("verdict", ""),
            f"{entry['policy_updates']['mean']:.1f}",
            f"{entry['seconds_per_run']:.3g}",
            str(entry["runs"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    for maze, best in data.get("goal", {}).items():
        fraction = _cell(best["fraction_of_known"])
        outcome = {True: "reached", False: "missed", None: "within the interval"}[best["reached"]]
        lines.append(
            f"\n{maze}: the best, {best['curve']}, reaches {fraction} of the known-reward level: the "
            f"{best['goal']:.0%} goal {outcome}"
            + (f" (by {best['missed_by']:.1%} of the known level)" if best["reached"] is False else "")
            + "."
        )
    return "\n".join(lines)
