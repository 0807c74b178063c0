"""
The paper's claims about Figures 5-8, each checked on a figure's JSON: what the protocol study
(``sb3-trlsd claims DIR ...``) tabulates, one column per directory of figures (one per protocol).

A claim compares two aggregates of a figure (a method's reward over a window, its policy updates, its
last turn's reward) or one against a bound the paper states. A comparison's difference is measured in
standard errors of the difference, sqrt(se_a^2 + se_b^2) with each se as the figure's JSON gives it (over
the source sets' means for Figures 5-7, over runs for Figure 8). The methods of a figure share their tasks,
seeds and source sets, so that is conservative: a paired standard error would be smaller. A claim that one
aggregate is above another holds when it is by more than ``SIGNIFICANT`` standard errors; a claim that two
are alike holds when they differ by less.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CLAIMS",
    "SIGNIFICANT",
    "Claim",
    "Verdict",
    "claims_table",
    "earlier_same_runs",
    "evaluate_claims",
    "load_figures",
    "load_wall_times",
]

SIGNIFICANT = 2.0  # standard errors of the difference

FigureResults = Mapping[str, Any]  # a figure JSON's "results": method label -> aggregates


@dataclass(frozen=True)
class Verdict:
    """
    A claim checked on one figure.

    :param measured: the numbers, in words
    :param holds: whether the claim holds
    :param z: the difference in standard errors of the difference (None for a claim against a bound)
    """

    measured: str
    holds: bool
    z: float | None = None

    def cell(self) -> str:
        """The verdict as a table cell."""
        return f"{self.measured}: {'holds' if self.holds else '**does not hold**'}"


@dataclass(frozen=True)
class Claim:
    """
    One claim of the paper about one figure.

    :param figure: ``"fig5"`` ... ``"fig8"``
    :param text: the claim, in the paper's words where possible
    :param check: the figure's results -> the verdict
    """

    figure: str
    text: str
    check: Callable[[FigureResults], Verdict]


def _aggregate(results: FigureResults, method: str, *path: str) -> tuple[float, float]:
    """Mean and standard error of one aggregate of a method, e.g. ``("reward", "[500, 1000)")``."""
    entry: Any = results[method]
    for key in path:
        entry = entry[key]
    return float(entry["mean"]), float(entry["se"])


def above(higher: str, lower: str, *path: str) -> Callable[[FigureResults], Verdict]:
    """The claim that method ``higher`` is above method ``lower`` on the aggregate at ``path``."""

    def check(results: FigureResults) -> Verdict:
        (a, se_a), (b, se_b) = _aggregate(results, higher, *path), _aggregate(results, lower, *path)
        z = (a - b) / max(float(np.hypot(se_a, se_b)), 1e-12)
        return Verdict(f"{a:.3f} against {b:.3f} ({z:+.1f} SE)", bool(z > SIGNIFICANT), z)

    return check


def alike(first: str, second: str, *path: str) -> Callable[[FigureResults], Verdict]:
    """The claim that two methods are alike on the aggregate at ``path``."""

    def check(results: FigureResults) -> Verdict:
        (a, se_a), (b, se_b) = _aggregate(results, first, *path), _aggregate(results, second, *path)
        z = (a - b) / max(float(np.hypot(se_a, se_b)), 1e-12)
        return Verdict(f"{a:.3f} against {b:.3f} ({z:+.1f} SE)", bool(abs(z) < SIGNIFICANT), z)

    return check


def above_all(higher: Sequence[str], lower: str, *path: str) -> Callable[[FigureResults], Verdict]:
    """The claim that every method of ``higher`` is above ``lower``: the least of the differences."""

    def check(results: FigureResults) -> Verdict:
        verdicts = [above(method, lower, *path)(results) for method in higher]
        worst = min(verdicts, key=lambda verdict: np.inf if verdict.z is None else verdict.z)
        measured = worst.measured if len(verdicts) == 1 else f"least of {len(verdicts)}: {worst.measured}"
        return Verdict(measured, all(verdict.holds for verdict in verdicts), worst.z)

    return check


def updates_near(method: str, target: float, tolerance: float) -> Callable[[FigureResults], Verdict]:
    """The claim that a method makes about ``target`` policy updates (within ``tolerance``, a fraction)."""

    def check(results: FigureResults) -> Verdict:
        updates, _ = _aggregate(results, method, "policy_updates")
        near = abs(updates - target) <= tolerance * target
        return Verdict(f"{updates:.1f} updates (paper: ~{target:g})", bool(near))

    return check


def solved_by(methods: Sequence[str], episodes: int) -> Callable[[FigureResults], Verdict]:
    """The claim that every method is near solved (Figure 8's criterion) after ``episodes`` episodes."""

    def check(results: FigureResults) -> Verdict:
        found = [int(results[method]["near_solved_after_episodes"]) for method in methods]
        return Verdict(
            f"{', '.join(map(str, found))} episodes (paper: {episodes})",
            all(n <= episodes for n in found),
        )

    return check


def more_sensitive(
    first: Sequence[str], second: Sequence[str], *path: str
) -> Callable[[FigureResults], Verdict]:
    """
    The claim that the aggregate varies more over the methods ``first`` than over ``second`` (Figure 7's
    kappa against sigma): the range (best - worst) of each, the difference in standard errors of the four
    aggregates at the ends.
    """

    def spread(results: FigureResults, methods: Sequence[str]) -> tuple[float, float]:
        values = [_aggregate(results, method, *path) for method in methods]
        best, worst = max(values), min(values)
        return best[0] - worst[0], float(np.hypot(best[1], worst[1]))

    def check(results: FigureResults) -> Verdict:
        (a, se_a), (b, se_b) = spread(results, first), spread(results, second)
        z = (a - b) / max(float(np.hypot(se_a, se_b)), 1e-12)
        return Verdict(f"range {a:.3f} against {b:.3f} ({z:+.1f} SE)", bool(z > SIGNIFICANT), z)

    return check


FIRST_100, FIRST_1000, LAST_500 = "[0, 100)", "[0, 1000)", "[500, 1000)"
KAPPA_0, CONTINUOUS_2, DISCRETE_2 = "non-optimistic (kappa=0)", "continuous, ratio 2", "discrete, ratio 2"
CONTINUOUS_12, DISCRETE_12, NO_TRANSFER = "continuous, ratio 1.2", "discrete, ratio 1.2", "no transfer"
CORNERS_2, CORNERS_105 = "corners prior, ratio 2", "corners prior, ratio 1.05"
EQ6, EQ7 = "similarity on states (eq. 6)", "similarity on features (eq. 7)"
KAPPAS = ("kappa=0.01", "kappa=0.03", "kappa=0.1", "kappa=0.3", "kappa=1")
SIGMAS = ("sigma=0.05", "sigma=0.1", "sigma=0.2", "sigma=0.5", "sigma=1")

CLAIMS = (
    Claim(
        "fig5",
        "no transfer is useless in 1,000 transitions (below every transfer method)",
        above_all(
            (KAPPA_0, CONTINUOUS_2, DISCRETE_2, CONTINUOUS_12, DISCRETE_12), NO_TRANSFER, "reward", FIRST_1000
        ),
    ),
    Claim(
        "fig5",
        "non-optimistic is better at the very beginning (transitions 0-99, against continuous ratio 2)",
        above(KAPPA_0, CONTINUOUS_2, "reward", FIRST_100),
    ),
    Claim(
        "fig5",
        "non-optimistic regularly fails to converge (last 500, below continuous ratio 2)",
        above(CONTINUOUS_2, KAPPA_0, "reward", LAST_500),
    ),
    Claim(
        "fig5",
        "... and below continuous ratio 1.2 (last 500)",
        above(CONTINUOUS_12, KAPPA_0, "reward", LAST_500),
    ),
    Claim(
        "fig5",
        "continuous dominates discrete at ratio 2 (transitions 0-999)",
        above(CONTINUOUS_2, DISCRETE_2, "reward", FIRST_1000),
    ),
    Claim("fig5", "continuous makes ~80 policy updates at ratio 2", updates_near(CONTINUOUS_2, 80, 0.25)),
    Claim("fig5", "discrete makes ~40 policy updates at ratio 2", updates_near(DISCRETE_2, 40, 0.25)),
    Claim(
        "fig5",
        "at ratio 1.2 the continuous and discrete curves become similar (transitions 0-999)",
        alike(CONTINUOUS_12, DISCRETE_12, "reward", FIRST_1000),
    ),
    Claim(
        "fig6",
        "the corners prior boosts early convergence (transitions 0-99, ratio 2)",
        above(CORNERS_2, CONTINUOUS_2, "reward", FIRST_100),
    ),
    Claim(
        "fig6",
        "the corners prior makes ~10 updates at ratio 2 (paper: fewer than 10)",
        updates_near(CORNERS_2, 10, 0.25),
    ),
    Claim(
        "fig6",
        "... which impairs its online learning (last 500, below ratio 1.05)",
        above(CORNERS_105, CORNERS_2, "reward", LAST_500),
    ),
    Claim("fig6", "the corners prior reaches ~50 updates at ratio 1.05", updates_near(CORNERS_105, 50, 0.25)),
    Claim(
        "fig7",
        "efficiency is much more sensitive to kappa than to sigma (transitions 0-999)",
        more_sensitive(KAPPAS, SIGMAS, "reward", FIRST_1000),
    ),
    Claim("fig8", "the 25 tasks are near solved after 300 episodes", solved_by((KAPPA_0, EQ6, EQ7), 300)),
    Claim(
        "fig8",
        "both similarities are almost equally efficient (last turn)",
        alike(EQ6, EQ7, "last_turn_reward"),
    ),
    Claim(
        "fig8",
        "both similarities significantly outperform the non-optimistic setting (last turn)",
        above_all((EQ6, EQ7), KAPPA_0, "last_turn_reward"),
    ),
)


def load_figures(directory: Path) -> tuple[str, dict[str, FigureResults]]:
    """
    The figures' results in a directory of ``figN.json`` files, and the protocol they ran under (the
    JSON's record; a JSON from before protocols were recorded ran under today's, ``as-built``).

    :param directory: where ``sb3-trlsd reproduce ... --out`` wrote them
    :return: protocol name, figure -> results
    """
    figures, names = {}, set()
    for path in sorted(Path(directory).glob("fig*.json")):
        data = json.loads(path.read_text())
        figures[data["figure"]] = data["results"]
        names.add(data.get("parameters", {}).get("protocol", {}).get("name", "as-built"))
    if len(names) > 1:
        raise ValueError(f"{directory} holds figures of several protocols: {sorted(names)}")
    return (names.pop() if names else "none"), figures


def load_wall_times(directory: Path) -> dict[str, float]:
    """
    Each figure's wall time in a directory of ``figN.json`` files, as ``reproduce`` measured it.

    :param directory: where ``sb3-trlsd reproduce ... --out`` wrote them
    :return: figure -> seconds (a figure whose JSON has no wall time is left out)
    """
    times = {}
    for path in sorted(Path(directory).glob("fig*.json")):
        data = json.loads(path.read_text())
        if "wall_time_seconds" in data:
            times[data["figure"]] = float(data["wall_time_seconds"])
    return times


def evaluate_claims(figures: Mapping[str, FigureResults]) -> list[Verdict | None]:
    """Every claim of ``CLAIMS`` checked on the figures given (None where its figure is missing)."""
    return [claim.check(figures[claim.figure]) if claim.figure in figures else None for claim in CLAIMS]


def same_runs(name: str) -> str:
    """The cell of a figure whose results are the column ``name``'s: the same runs, not a second test."""
    return f"as {name} (the same runs)"


def _without_timings(value: Any) -> Any:
    """A figure's results without their seconds, which differ between two reproductions of the same runs."""
    if isinstance(value, Mapping):
        return {key: _without_timings(item) for key, item in value.items() if key != "seconds_per_run"}
    return value


def earlier_same_runs(
    columns: Sequence[tuple[str, Mapping[str, FigureResults]]],
) -> list[dict[str, str | None]]:
    """
    For each column and figure, the first earlier column whose figure has exactly its results (timings
    aside): the same runs, kept once and read again, or None for runs of its own.

    :param columns: (protocol name, figure -> results) per column
    :return: per column, figure -> the earlier column's name or None
    """
    untimed = [
        {figure: _without_timings(results) for figure, results in figures.items()} for _, figures in columns
    ]
    return [
        {
            figure: next(
                (
                    earlier_name
                    for (earlier_name, _), earlier in zip(columns[:index], untimed[:index], strict=True)
                    if earlier.get(figure) == results
                ),
                None,
            )
            for figure, results in untimed[index].items()
        }
        for index in range(len(columns))
    ]


def claims_table(columns: Sequence[tuple[str, Mapping[str, FigureResults]]]) -> str:
    """
    A Markdown table: one row per claim, one column per (protocol, figures). Where a protocol's figure has
    exactly the results of an earlier column's (today's, ``as-built``, when it is the first), its cells say
    so instead of repeating them: the protocol reaches none of that figure's runs beyond the other's, which
    were kept once (``Protocol.reaching``), e.g. a combination of presets under which a figure runs as under
    one of them.

    :param columns: (protocol name, figure -> results) per column
    :return: the table
    """
    header = ["figure", "paper's claim", *(name for name, _ in columns)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    verdicts = [evaluate_claims(figures) for _, figures in columns]
    same_as = earlier_same_runs(columns)
    for row, claim in enumerate(CLAIMS):
        cells = [claim.figure, claim.text]
        for column_verdicts, column_same_as in zip(verdicts, same_as, strict=True):
            verdict = column_verdicts[row]
            earlier_name = column_same_as.get(claim.figure)
            if verdict is None:
                cells.append("")
            else:
                cells.append(verdict.cell() if earlier_name is None else same_runs(earlier_name))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
