"""
What ``sb3-trlsd reproduce`` can run: the paper's figures (section 4, Figures 1-8, one module each of
``sb3_trlsd_lab.paper``) and the studies beyond the paper (``sb3_trlsd_lab.studies``), by name, and
``reproduce``, which runs one of them. Each figure writes ``figN.csv`` (curves), ``figN.png`` and
``figN.json`` (aggregates, policy updates, wall time, parameters, seed, version). A study (``STUDIES``:
``beyond``, the comparison of confidence bounds) runs the same way, with options of its own.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["FIGURES", "STUDIES", "STUDY_OPTIONS", "reproduce"]

# Figure -> (module, function(out, how: Reproduction) -> summary).
# Imported on use, so that listing the figures (the command line's help) does not load torch and SB3.
FIGURES: dict[str, tuple[str, str]] = {
    "fig1": ("sb3_trlsd_lab.paper.known_reward", "reproduce"),
    "fig2": ("sb3_trlsd_lab.paper.trajectories", "reproduce_fig2"),
    "fig3": ("sb3_trlsd_lab.paper.trajectories", "reproduce_fig3"),
    "fig4": ("sb3_trlsd_lab.paper.trajectories", "reproduce_fig4"),
    "fig5": ("sb3_trlsd_lab.paper.transfer", "reproduce"),
    "fig6": ("sb3_trlsd_lab.paper.corners", "reproduce"),
    "fig7": ("sb3_trlsd_lab.paper.sensitivity", "reproduce"),
    "fig8": ("sb3_trlsd_lab.paper.multitask", "reproduce"),
}
# Study -> (module, function(out, how, **options) -> summary, function(summary) -> its Markdown table).
STUDIES: dict[str, tuple[str, str, str]] = {"beyond": ("sb3_trlsd_lab.studies.beyond", "reproduce", "table")}
# Study -> the keyword arguments of its function that ``reproduce`` passes on as ``options``.
STUDY_OPTIONS: dict[str, tuple[str, ...]] = {"beyond": ("tuning_runs", "mlp_runs", "mazes")}


def reproduce(
    figure: str,
    out: str | Path,
    runs: int | None = None,
    seed: int = 0,
    workers: int = 1,
    cache: str | Path | None = None,
    backend: str = "loky",
    address: str | None = None,
    protocol: str | None = None,
    options: Mapping[str, Any] | None = None,
) -> dict:
    """
    Run one figure's experiment (or a study's) and write its CSV, PNG and JSON to ``out``.

    :param figure: ``"fig1"`` .. ``"fig8"``, or a study of ``STUDIES``
    :param out: output directory (created if needed)
    :param runs: runs per method (None: the paper's size)
    :param seed: seed of the first run; run r uses ``seed + r``
    :param workers: processes the runs are spread over (with Ray: CPUs of the local cluster it starts)
    :param cache: directory where finished runs are kept, and reused when the same runs are asked of the
        same code again (a killed reproduction resumes there); None: every run is run, none is kept.
        Figures 2-4 (one short run each) do not use it.
    :param backend: ``"loky"`` (processes of this machine) or ``"ray"`` (tasks of a Ray cluster, with the
        extra ``sb3-trlsd[cluster]``); the kept runs stay on this machine either way
    :param address: (ray) the cluster to join: ``"auto"``, ``"host:port"`` or ``"ray://host:port"``; None:
        start a local one
    :param protocol: the name of the choices the paper leaves open (``protocols.PRESETS``; None:
        ``protocols.DEFAULT_PROTOCOL``, the study's best-supported ``no-restarts``)
    :param options: a study's own options (``STUDY_OPTIONS``, e.g. ``{"tuning_runs": 100}`` for ``beyond``)
    :return: the figure's JSON summary
    """
    if figure not in FIGURES and figure not in STUDIES:
        raise ValueError(f"figure must be one of {', '.join([*FIGURES, *STUDIES])}, got {figure!r}")
    options = dict(options or {})
    unknown = sorted(set(options) - set(STUDY_OPTIONS.get(figure, ())))
    if unknown:
        raise ValueError(
            f"{figure} takes no option {', '.join(unknown)} (options: "
            + "; ".join(f"{name}: {', '.join(names)}" for name, names in STUDY_OPTIONS.items())
            + ")"
        )
    if runs is not None and runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    from sb3_trlsd_lab.execution.backends import Backend
    from sb3_trlsd_lab.execution.protocols import DEFAULT_PROTOCOL, protocol_named
    from sb3_trlsd_lab.paper.reproduction import Reproduction

    how = Reproduction(
        runs=runs,
        seed=seed,
        workers=workers,
        cache=None if cache is None else Path(cache),
        backend=Backend(backend, address),
        protocol=protocol_named(DEFAULT_PROTOCOL if protocol is None else protocol),
    )
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    module, function = FIGURES[figure] if figure in FIGURES else STUDIES[figure][:2]
    run = getattr(importlib.import_module(module), function)
    return run(out, how, **options)
