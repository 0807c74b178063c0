"""
What the protocol study has run (``sb3-trlsd claims DIR ... --runs``): one row per preset, one column per
figure, each cell the figure's wall time, the earlier column whose runs it reads again, or "not run".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from sb3_trlsd_lab.execution.protocols import AS_BUILT_NAME, PRESETS
from sb3_trlsd_lab.studies.claims import FigureResults, earlier_same_runs

__all__ = ["STUDY_FIGURES", "runs_table"]

STUDY_FIGURES = ("fig5", "fig6", "fig7", "fig8")  # the figures whose claims the study checks


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min"


def runs_table(
    columns: Sequence[tuple[str, Mapping[str, FigureResults]]],
    wall_times: Sequence[Mapping[str, float]],
    figures: Sequence[str] = STUDY_FIGURES,
) -> str:
    """
    A Markdown table of what ran under each preset: a figure's wall time, "NAME's runs" where its results
    are an earlier column's (the same runs read again from the cache, ``claims.earlier_same_runs``), or
    "not run". Every preset of ``PRESETS`` has a row, in its order (today's, ``as-built``, only when given),
    so the presets not yet run show as such.

    :param columns: (protocol name, figure -> results) per directory, in the order given
    :param wall_times: per column, figure -> seconds (``claims.load_wall_times``)
    :param figures: the table's columns
    :return: the table
    """
    given = {name: index for index, (name, _) in enumerate(columns)}
    same_as = earlier_same_runs(columns)
    lines = [
        "| preset | " + " | ".join(f"Figure {figure.removeprefix('fig')}" for figure in figures) + " |",
        "|" + "---|" * (len(figures) + 1),
    ]
    for name in PRESETS:
        if name == AS_BUILT_NAME and name not in given:
            continue
        cells = []
        for figure in figures:
            index = given.get(name)
            if index is None or figure not in columns[index][1]:
                cells.append("not run")
            elif same_as[index][figure] is not None:
                cells.append(f"`{same_as[index][figure]}`'s runs")
            elif figure in wall_times[index]:
                cells.append(_minutes(wall_times[index][figure]))
            else:
                cells.append("ran (no wall time kept)")
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)
