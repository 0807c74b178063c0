"""
Beyond the paper: eq. 9 against other confidence bounds, each given the same tuning budget, then
evaluated in Figure 5's setting (the 25 tasks in turn, 25,000 random source transitions, 1,000 online), with
the linear Q and (``mlp_runs``) the MLP Q, on the paper's maze and on its variant whose reward noise differs
by cell (``CELL_NOISE_STDS``), where a bound that weighs how much neighbours agree can matter.

The protocol, fixed before any run:

1. Tuning. Each method has a grid of 8 configurations (``GRIDS``); each configuration runs on
   ``tuning_runs`` runs (100 by default) whose seeds are disjoint from the evaluation's: run r of the tuning
   has seed ``seed + TUNING_SEED_OFFSET + r`` and its source sets are drawn from that seed
   (``tuning_seeds``), while evaluation run r has seed ``seed + r``. Every configuration of every method sees
   the same tuning runs (tasks, source sets, env seeds), in batches of ``TUNING_BATCH_RUNS`` (25) stepped in
   lockstep, each on a source set of its own (``tuning_source_sets``). Each maze is tuned for itself.
2. Selection. The metric, fixed in advance: the mean over the tuning runs of each run's expected reward
   E[R_tau(s_t)] over the last 500 online transitions (``selection_window``), the window of the issue's goal;
   the highest wins, the first in grid order among equals (``select_configuration``). The MLP Q takes the
   configuration the linear Q selected: tuning it too would cost 8 x 4 x ``tuning_runs`` MLP runs (~10 s
   each).
3. Evaluation. Each method's selected configuration on ``runs`` runs (500, Figure 5's size) with the linear
   Q, batched in lockstep as Figure 5's runs (20 source sets shared by every method), and on ``mlp_runs``
   with the MLP Q (one run at a time); the known reward (Figure 1's method, CI = 0) on the same runs with
   the linear Q is the reference level.
4. Statistics (``beyond_report.py``, with ``statistics.py`` and ``bootstrap.py``, as rliable computes
   them): for each method the reward over each window as mean +- standard error over the source sets, and
   the mean and IQM of the runs' window averages with 95% stratified bootstrap intervals (strata: the 25
   tasks); over the last 500 transitions, the fraction of the known-reward level (of the linear Q on the
   same maze) and P(method > eq. 9) with their intervals.

Why these grids: every method gets kappa (the scale of its bonus, or of its draws) at four values a factor
~sqrt(10) apart, a span of 30 around the value where its bonus is about eq. 9's at kappa = 0.1, times the
update ratio at the paper's two values, 2 and 1.2 (Figure 5); for the linear-posterior heads the ratio is the
factor det A must grow by, their refit rule. The match was measured on heads fed 20, 100 and 500 samples of
the maze (half in its corner [0, 2]^2, half uniform): at the samples, OFUL's width sqrt(phi^T A^-1 phi) is
12-15 times smaller than eq. 9's sqrt(log|Xi| / W), the Bernstein bound 3-5 times larger. Widths stay at the
paper's (sigma = 0.2 for eq. 9 and Bernstein; the 5x5 RBFs of width 0.2 for the ridge regressions), the
best of Figure 7.

- eq. 9 (``"ridge"``): kappa in {0.01, 0.03, 0.1, 0.3}, Figure 7's working range (kappa = 1 fails there).
- OFUL (``"ridge_posterior"``): beta in {0.3, 1, 3, 10}, around 1.2-1.5, the match of eq. 9's 0.1.
- Thompson (``"thompson"``): the posterior scale v in {0.3, 1, 3, 10}, on OFUL's posterior (the same match);
  1 is the Bayesian posterior under the maze's unit noise.
- Bernstein (``"bernstein"``): kappa in {0.003, 0.01, 0.03, 0.1}, around 0.02-0.03, the match of eq. 9's 0.1
  (UCB-V's own constant, 1, would be 30-50 times eq. 9's optimism).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sb3_trlsd_envs import CELL_NOISE_STDS, N_TASKS
from sb3_trlsd_lab.execution.batches import SOURCE_SETS, transfer_runs
from sb3_trlsd_lab.execution.runner import ONLINE_TRANSITIONS, SOURCE_TRANSITIONS, Method, RunRecord
from sb3_trlsd_lab.paper.figures import curves_of, protocol_title, write_curves_figure
from sb3_trlsd_lab.paper.known_reward import KNOWN
from sb3_trlsd_lab.paper.reporting import summary, write_json
from sb3_trlsd_lab.paper.reproduction import Reproduction
from sb3_trlsd_lab.studies.beyond_report import Curve, best_against_goal, curve_label, study_results, table
from sb3_trlsd_lab.studies.tuning import (
    DEFAULT_RUNS,
    DEFAULT_TUNING_RUNS,
    GRIDS,
    REFERENCE,
    SELECTION_TRANSITIONS,
    TUNING_SEED_OFFSET,
    check_sizes,
    evaluation_seeds,
    select_configuration,
    selection_window,
    tuning_seeds,
    tuning_source_sets,
    window_scores,
)

# ``table`` is beyond_report.py's, named here by the ``STUDIES`` registry.
__all__ = [
    "GRIDS",
    "MAZES",
    "TUNING_SEED_OFFSET",
    "check_sizes",
    "check_study",
    "evaluation_seeds",
    "mazes_named",
    "reproduce",
    "select_configuration",
    "selection_window",
    "table",
    "tune",
    "tuning_seeds",
    "window_scores",
]

POLICIES = {"linear Q": "LinearPolicy", "MLP Q": "MlpPolicy"}
# Each maze and the keyword arguments of its env.
MAZES: dict[str, dict[str, Any]] = {
    "paper maze": {},
    "noise by cell": {"reward_noise_std": CELL_NOISE_STDS},
}


def mazes_named(names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """
    The mazes of ``MAZES`` named, in ``MAZES``'s order, each name as written there or with dashes for its
    spaces (``"noise-by-cell"``, as the command line takes it).

    :raises ValueError: for a name ``MAZES`` does not have, or none
    """
    wanted = {name.replace("-", " ") for name in names}
    unknown = sorted(wanted - set(MAZES))
    if unknown or not wanted:
        raise ValueError(
            f"mazes must be among {', '.join(name.replace(' ', '-') for name in MAZES)}, got {list(names)}"
        )
    return {name: kwargs for name, kwargs in MAZES.items() if name in wanted}


# ------------------------------------------------------------------------------------------ the protocol
def tune(
    grids: Mapping[str, Sequence[Method]], records: Mapping[str, Sequence[RunRecord]], window: tuple[int, int]
) -> dict[str, dict[str, Any]]:
    """
    Each method's tuning: the score of each configuration (the mean of its ``window_scores``) and the one
    selected.

    :param grids: method -> its configurations
    :param records: configuration label -> its tuning runs
    :param window: the selection window
    :return: method -> ``{"scores": {label: score}, "selected": label, "score": its score, "configuration":
        its parameters}``
    """
    tuning = {}
    for name, configurations in grids.items():
        scores = {c.label: float(window_scores(records[c.label], window).mean()) for c in configurations}
        selected = select_configuration(scores)
        chosen = next(c for c in configurations if c.label == selected)
        tuning[name] = {
            "scores": scores,
            "selected": selected,
            "score": scores[selected],
            "configuration": chosen.parameters(),
        }
    return tuning


def _selected_method(grids: Mapping[str, Sequence[Method]], name: str, label: str, policy: str) -> Method:
    """The configuration ``label`` of method ``name``, under the method's name, with the given Q."""
    chosen = next(c for c in grids[name] if c.label == label)
    return dataclasses.replace(chosen, label=name, policy=policy)


# ------------------------------------------------------------------------------------------- the study
def check_study(grids: Mapping[str, Sequence[Method]], mazes: Mapping[str, Mapping[str, Any]]) -> None:
    """
    Refuse grids without ``REFERENCE``, with an empty method, named as the reference level, or with two
    configurations of one label (the tuning runs them together), and an empty set of mazes.

    :raises ValueError: saying which
    """
    labels = [configuration.label for grid in grids.values() for configuration in grid]
    if REFERENCE not in grids or any(not grid for grid in grids.values()) or KNOWN.label in grids:
        raise ValueError(
            f"grids must give configurations to every method, {REFERENCE!r} included and "
            f"{KNOWN.label!r} (the reference level) not: got {list(grids)}"
        )
    if len(set(labels)) != len(labels):
        raise ValueError(f"grids must label each configuration its own way, got {labels}")
    if not mazes:
        raise ValueError("mazes must name at least one maze")


def _disjoint_seeds(how: Reproduction, runs: int, tuning_runs: int) -> dict[str, dict[str, list[int]]]:
    """The seeds of the evaluation and of the tuning, checked disjoint (runs and source sets)."""
    per_run = how.protocol.source_sets == "per_run"
    seeds = {
        "evaluation": evaluation_seeds(how.seed, runs, per_run),
        "tuning": tuning_seeds(how.seed, tuning_runs, per_run),
    }
    for kind in ("runs", "source_sets"):
        if not set(seeds["evaluation"][kind]).isdisjoint(seeds["tuning"][kind]):
            raise ValueError(f"the tuning's {kind} seeds meet the evaluation's: give another seed")
    return seeds


def reproduce(
    out: Path,
    how: Reproduction,
    *,
    tuning_runs: int = DEFAULT_TUNING_RUNS,
    mlp_runs: int = 0,
    grids: Mapping[str, Sequence[Method]] | None = None,
    mazes: Mapping[str, Mapping[str, Any]] | Sequence[str] | None = None,
    n_source: int | None = None,
    n_online: int | None = None,
) -> dict:
    """
    Tune each method on its grid, evaluate the selected configurations next to the known reward, and write
    ``beyond.csv`` (the curves), ``beyond.png`` (a panel per maze and Q), ``beyond_improvement.png``
    (P(method > eq. 9)) and ``beyond.json`` (grids, seeds, tuning, aggregates); see the module docstring.

    :param out: the output directory
    :param how: evaluation runs per method (default 500), seed, workers, cache, backend and protocol
    :param tuning_runs: runs per configuration of the tuning
    :param mlp_runs: evaluation runs per method with the MLP Q (0: none), at most ``runs``
    :param grids: method -> its configurations, ``REFERENCE`` among them (None: ``GRIDS``)
    :param mazes: maze name -> the keyword arguments of its env, or names of ``MAZES`` (``mazes_named``;
        one maze per sitting, the JSONs side by side); None: ``MAZES``
    :param n_source: random source transitions per run (None: the paper's 25,000)
    :param n_online: online transitions per run (None: the paper's 1,000)
    :return: the JSON summary
    :raises ValueError: for sizes ``check_sizes`` refuses or grids without ``REFERENCE``, before any run
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    check_sizes(runs, tuning_runs, mlp_runs)
    grids = GRIDS if grids is None else grids
    if mazes is None:
        mazes = MAZES
    elif not isinstance(mazes, Mapping):
        mazes = mazes_named(mazes)
    check_study(grids, mazes)
    n_source = SOURCE_TRANSITIONS if n_source is None else n_source
    n_online = ONLINE_TRANSITIONS if n_online is None else n_online
    seeds = _disjoint_seeds(how, runs, tuning_runs)
    window = selection_window(n_online)
    windows = [(0, max(1, n_online // 10)), (0, n_online), window]  # Figure 5's at the paper's size

    def runs_of(
        methods: Sequence[Method], count: int, first_seed: int, maze: str, source_sets: int
    ) -> dict[str, list[RunRecord]]:
        return transfer_runs(
            methods,
            range(N_TASKS),
            count,
            first_seed,
            how.workers,
            n_source=n_source,
            n_online=n_online,
            env_kwargs=dict(mazes[maze]),
            source_sets=source_sets,
            **how.run_options(),
        )

    tuning: dict[str, dict[str, Any]] = {}
    records: dict[str, list[RunRecord]] = {}
    rows: list[Curve] = []  # (label, maze, Q, method) of each curve
    for maze in mazes:
        configurations = [configuration for grid in grids.values() for configuration in grid]
        first_tuning_run = seeds["tuning"]["runs"][0]
        tuned = runs_of(configurations, tuning_runs, first_tuning_run, maze, tuning_source_sets(tuning_runs))
        tuning[maze] = tune(grids, tuned, window)
        for policy, count in (("linear Q", runs), ("MLP Q", mlp_runs)):
            if not count:
                continue
            methods = [
                _selected_method(grids, name, tuning[maze][name]["selected"], POLICIES[policy])
                for name in grids
            ]
            if policy == "linear Q":
                methods.append(KNOWN)  # the reference level
            found = runs_of(methods, count, how.seed, maze, SOURCE_SETS)
            for method in methods:
                label = curve_label(maze, policy, method.label)
                records[label] = found[method.label]
                rows.append((label, maze, policy, method.label))

    panels = [
        (f"{maze}, {policy}", [label for label, m, q, _ in rows if (m, q) == (maze, policy)])
        for maze, policy in dict.fromkeys((maze, policy) for _, maze, policy, _ in rows)
    ]
    title = (
        f"Beyond the paper: each method tuned on {tuning_runs} runs per configuration, evaluated on {runs}"
    )
    write_curves_figure(
        out,
        "beyond",
        protocol_title(title, how.protocol),
        curves_of(records),
        panels,
        legend={label: method for label, _, _, method in rows},
    )
    results, figures = study_results(
        out, records, rows, tuning, windows, window, how.seed, protocol=how.protocol
    )
    files = ["beyond.png", "beyond.csv", "beyond.json", *figures]

    parameters = {
        "tasks": "all 25 in turn",
        "runs": runs,
        "tuning_runs": tuning_runs,
        "mlp_runs": mlp_runs,
        "n_source": n_source,
        "n_online": n_online,
        "mazes": {maze: dict(kwargs) for maze, kwargs in mazes.items()},
        "selection": {
            "metric": "mean over the tuning runs of the expected reward over the last "
            f"{SELECTION_TRANSITIONS} online transitions; the first in grid order among equals",
            "window": f"[{window[0]}, {window[1]})",
            "mlp": "the configuration the linear Q selected",
        },
        "reference": REFERENCE,
        "fraction_of_known": "mean over the selection window as a fraction of the known reward's (linear Q, "
        "same maze and runs)",
        "strata": "the target tasks (one column each when they have equal runs, else the runs as one)",
        "seeds": {
            kind: {
                "first_run": found["runs"][0],
                "last_run": found["runs"][-1],
                "source_sets": found["source_sets"],
            }
            for kind, found in seeds.items()
        },
        **how.recorded(),
    }
    data = summary(
        "beyond",
        parameters,
        how.seed,
        time.perf_counter() - started,
        grids={name: [configuration.parameters() for configuration in grid] for name, grid in grids.items()},
        tuning=tuning,
        results=results,
        goal=best_against_goal(results),
        files=[str(out / name) for name in files],
    )
    write_json(out / "beyond.json", data)
    return data
