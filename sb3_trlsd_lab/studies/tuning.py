"""
The tuning protocol of ``reproduce beyond`` (``beyond.py``), fixed before any run: each method's grid of 8
configurations (``GRIDS``; the module docstring of ``beyond.py`` says why these), the seeds of the tuning
runs, disjoint from the evaluation's (``tuning_seeds``, ``evaluation_seeds``), and the selection rule
(``selection_window``, ``select_configuration``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from sb3_trlsd_lab.execution.batches import SOURCE_SETS, batch_runs, run_source_seed, source_seed
from sb3_trlsd_lab.execution.runner import Method, RunRecord

__all__ = [
    "DEFAULT_RUNS",
    "DEFAULT_TUNING_RUNS",
    "GRIDS",
    "REFERENCE",
    "SELECTION_TRANSITIONS",
    "TUNING_BATCH_RUNS",
    "TUNING_SEED_OFFSET",
    "UPDATE_RATIOS",
    "check_sizes",
    "evaluation_seeds",
    "method_grid",
    "select_configuration",
    "selection_window",
    "tuning_seeds",
    "tuning_source_sets",
    "window_scores",
]

DEFAULT_RUNS = 500  # evaluation runs per method: Figure 5's size
DEFAULT_TUNING_RUNS = 100  # tuning runs per configuration (the budget)
TUNING_SEED_OFFSET = 1_000_000  # tuning run r has seed seed + TUNING_SEED_OFFSET + r
# The tuning's runs go in batches of 25 (one run per task; 4 batches at the default 100 runs) rather than
# in the evaluation's 20 batches: the selection compares configurations on the same runs and source sets
# (paired), takes no standard error over source sets, and a batch of 25 runs in lockstep costs about half
# per run what a batch of 5 does.
TUNING_BATCH_RUNS = 25
SELECTION_TRANSITIONS = 500  # the selection metric: the reward over the last 500 online transitions
UPDATE_RATIOS = (2.0, 1.2)  # the paper's two (Figure 5)
REFERENCE = "eq. 9"  # the method the others are compared with head to head


def method_grid(name: str, reward_head: str, kappas: Sequence[float]) -> tuple[Method, ...]:
    """The 8 configurations of a method: ``kappas`` times ``UPDATE_RATIOS``."""
    return tuple(
        Method(
            f"{name}, kappa={kappa:g}, ratio {ratio:g}",
            reward_head=reward_head,
            kappa=kappa,
            update_ratio=ratio,
        )
        for ratio in UPDATE_RATIOS
        for kappa in kappas
    )


# Method -> its configurations, in grid order (see the module docstring for why these).
GRIDS: dict[str, tuple[Method, ...]] = {
    REFERENCE: method_grid(REFERENCE, "ridge", (0.01, 0.03, 0.1, 0.3)),
    "OFUL": method_grid("OFUL", "ridge_posterior", (0.3, 1.0, 3.0, 10.0)),
    "Thompson": method_grid("Thompson", "thompson", (0.3, 1.0, 3.0, 10.0)),
    "Bernstein": method_grid("Bernstein", "bernstein", (0.003, 0.01, 0.03, 0.1)),
}


def check_sizes(runs: int, tuning_runs: int, mlp_runs: int) -> None:
    """
    Refuse sizes the protocol cannot take, naming them.

    :raises ValueError: unless runs and tuning_runs are >= 1, mlp_runs >= 0 and at most runs, and the
        evaluation runs stay below ``TUNING_SEED_OFFSET`` (their seeds would reach the tuning's)
    """
    for name, value, minimum in (
        ("runs", runs, 1),
        ("tuning_runs", tuning_runs, 1),
        ("mlp_runs", mlp_runs, 0),
    ):
        if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= minimum):
            raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if mlp_runs > runs:
        raise ValueError(
            f"mlp_runs must be at most runs ({runs}): the MLP's runs are the first of them, got {mlp_runs}"
        )
    if runs > TUNING_SEED_OFFSET:
        raise ValueError(
            f"runs must be at most {TUNING_SEED_OFFSET} (further, evaluation seeds would be tuning seeds), "
            f"got {runs}"
        )


def _seeds(first: int, runs: int, per_run_sources: bool, source_sets: int) -> dict[str, list[int]]:
    """
    The seeds of ``transfer_runs(..., runs, first, ..., source_sets=source_sets)``: of its runs, and of its
    source sets.
    """
    run_seeds = [first + run for run in range(runs)]
    if per_run_sources:
        sources = [run_source_seed(seed) for seed in run_seeds]
    else:
        sources = [source_seed(first, batch) for batch in range(len(batch_runs(runs, source_sets)))]
    return {"runs": run_seeds, "source_sets": sources}


def evaluation_seeds(seed: int, runs: int, per_run_sources: bool = False) -> dict[str, list[int]]:
    """
    The seeds of the evaluation runs (those of Figure 5 with the same seed): run r's, ``seed + r``, and those
    of the source sets.

    :param seed: the reproduction's seed
    :param runs: the evaluation runs per method
    :param per_run_sources: a source set per run (the protocol's ``source_sets="per_run"``)
    :return: ``{"runs": [...], "source_sets": [...]}``
    """
    return _seeds(seed, runs, per_run_sources, SOURCE_SETS)


def tuning_seeds(seed: int, tuning_runs: int, per_run_sources: bool = False) -> dict[str, list[int]]:
    """
    The seeds of the tuning runs: run r's, ``seed + TUNING_SEED_OFFSET + r``, and those of the source sets
    drawn from them (``tuning_source_sets``), disjoint from the evaluation's (``reproduce`` checks it).

    :param seed: the reproduction's seed
    :param tuning_runs: the tuning runs per configuration
    :param per_run_sources: a source set per run (the protocol's ``source_sets="per_run"``)
    :return: ``{"runs": [...], "source_sets": [...]}``
    """
    return _seeds(seed + TUNING_SEED_OFFSET, tuning_runs, per_run_sources, tuning_source_sets(tuning_runs))


def tuning_source_sets(tuning_runs: int) -> int:
    """The tuning's batches, one source set each, ``TUNING_BATCH_RUNS`` runs each (the last fewer)."""
    return max(1, -(-tuning_runs // TUNING_BATCH_RUNS))


def selection_window(n_online: int) -> tuple[int, int]:
    """The window of the selection metric: the last ``SELECTION_TRANSITIONS`` online transitions (or all)."""
    return max(0, n_online - SELECTION_TRANSITIONS), n_online


def window_scores(records: Sequence[RunRecord], window: tuple[int, int]) -> np.ndarray:
    """Each run's expected reward averaged over the transitions ``[start, stop)``, (runs,)."""
    start, stop = window
    return np.array([record.rewards[start:stop].mean() for record in records])


def select_configuration(scores: Mapping[str, float]) -> str:
    """
    The configuration with the highest tuning score, the first in order among equals.

    :param scores: configuration label -> its score, in grid order
    :return: the label
    """
    if not scores:
        raise ValueError("scores must name at least one configuration")
    return max(scores, key=lambda label: scores[label])  # max keeps the first of equal scores
