"""
The suite's runs and report: ``runs`` runs of each method on a family's held-out evaluation weights, spread
over processes by ``run_jobs``, aggregated as mean ± standard error and a 95% stratified bootstrap interval
of the mean, and written as ``mo_suite_<family>.csv`` (one row per run), ``.json`` (the aggregates, sizes,
weights and timings) and ``.png`` (a bar per method with its interval).

Run r targets evaluation weight r (modulo their number) with seed ``seed + r``; its source transitions are
collected with seed ``SOURCE_SEED + seed + r``, the same for every method, under one of two protocols
(``sources.py``): a random policy under the source weights (``mo_suite_<family>``), or the replay buffer of
a DQN trained on them (``mo_suite_trained_<family>``; each run's DQN is trained once, for all its methods).
A run's score is the mean scalar reward w . r_vec per online step. ``protocol_table`` sets the two
protocols side by side.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd.atomic_files import atomic_write
from sb3_trlsd_lab.benchmarks.mo_suite.families import Family, collect_source, family_named
from sb3_trlsd_lab.benchmarks.mo_suite.peers import METHODS, PeerResult, run_method
from sb3_trlsd_lab.benchmarks.mo_suite.sources import SOURCE_POLICIES, trained_source
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.paper.figures import new_figure, save_figure
from sb3_trlsd_lab.paper.reporting import mean_and_standard_error, summary, write_json
from sb3_trlsd_lab.stats.bootstrap import paired_bootstrap_ci, stratified_bootstrap_ci
from sb3_trlsd_lab.stats.statistics import aggregate_mean, mean_ratio

__all__ = [
    "DEFAULT_RUNS",
    "PROTOCOL_METHODS",
    "SOURCE_SEED",
    "family_scale",
    "goal_table",
    "protocol_table",
    "run_suite",
    "suite_name",
    "suite_run",
    "suite_table",
    "trained_source_runs",
]

DEFAULT_RUNS = 20
SOURCE_SEED = 10_000
# Each TRLSD method -> the level it is measured against, above the random policy's: the same agent given the
# source's true rewards.
REFERENCES = {"trlsd": "trlsd-reward-given", "trlsd-mlp": "trlsd-mlp-reward-given"}
# The methods ``protocol_table`` compares under the two source protocols.
PROTOCOL_METHODS = ("trlsd", "dqn", "dqn-finetuned", "sf-gpi", "random")


def suite_name(family_name: str, source_policy: str = "random") -> str:
    """A family's file stem under a protocol: ``mo_suite_<family>``, or ``mo_suite_trained_<family>``."""
    return (
        f"mo_suite_{family_name}" if source_policy == "random" else f"mo_suite_{source_policy}_{family_name}"
    )


def _row(run: int, task: int, run_seed: int, result: PeerResult, n_online: int) -> dict[str, Any]:
    """A run's row: task, score, seconds, online ms per step, updates and reward curve."""
    return {
        "run": run,
        "task": task,
        "seed": run_seed,
        "score": float(result.rewards.mean()),
        "seconds": result.seconds,
        "online_ms_per_step": 1000.0 * result.online_seconds / n_online,
        "updates": result.updates,
        "rewards": result.rewards.tolist(),
    }


def suite_run(
    family_name: str,
    method: str,
    run: int,
    seed: int,
    split: str,
    n_source: int,
    n_online: int,
    settings: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """
    Run ``run`` of ``method`` on a family (a module-level function of its arguments alone, for the workers
    and the run cache).

    :param family_name: a key of ``FAMILIES``
    :param method: a key of ``METHODS``
    :param run: the run's index: its target weight and seed
    :param seed: the suite's seed
    :param split: the weights targeted, ``"evaluation"`` (or ``"tuning"``)
    :param n_source: random source transitions
    :param n_online: online transitions
    :param settings: the methods of ``peers.SETTABLE`` only: TRLSD's keyword arguments other than its
        defaults (a candidate of the tuning protocol)
    :return: the run's row: task, score, seconds, online ms per step, updates and reward curve (the source:
        a random policy's; ``trained_source_runs`` for the other protocol)
    """
    family = family_named(family_name)
    targets = family.tasks_of(split)
    task = int(targets[run % len(targets)])
    run_seed = seed + run
    source = None
    if METHODS[method][1]:
        source = collect_source(family, n_source, SOURCE_SEED + run_seed)
    result: PeerResult = run_method(method, family, task, run_seed, source, n_online, settings)
    return _row(run, task, run_seed, result, n_online)


def trained_source_runs(
    family_name: str,
    methods: Sequence[str],
    run: int,
    seed: int,
    split: str,
    n_source: int,
    n_online: int,
) -> list[dict[str, Any]]:
    """
    Run ``run`` of each of ``methods`` over the trained protocol's source: the replay buffer of a DQN trained
    on the source weights for ``n_source`` steps (``sources.trained_source``, seed ``SOURCE_SEED + seed +
    run``), trained once for all of them (a module-level function of its arguments alone, for the workers
    and the run cache, which keeps the run of every method at once).

    :param family_name: a key of ``FAMILIES``
    :param methods: keys of ``METHODS`` that take a source
    :param run: the run's index: its target weight and seed
    :param seed: the suite's seed
    :param split: the weights targeted, ``"evaluation"`` (or ``"tuning"``)
    :param n_source: the source DQN's steps: the source's rows
    :param n_online: online transitions
    :return: each method's row, as ``suite_run``'s
    """
    family = family_named(family_name)
    targets = family.tasks_of(split)
    task = int(targets[run % len(targets)])
    run_seed = seed + run
    source = trained_source(family, n_source, SOURCE_SEED + run_seed)
    return [
        _row(run, task, run_seed, run_method(method, family, task, run_seed, source, n_online), n_online)
        for method in methods
    ]


def aggregate(rows: Sequence[Mapping[str, Any]], seed: int = 0) -> dict[str, Any]:
    """
    A method's runs on one family: mean ± standard error of the scores, the 95% bootstrap interval of their
    mean (runs resampled as one stratum: the target weights are a random draw too), seconds per run and ms
    per online step.

    :param rows: the runs' rows (``suite_run``)
    :param seed: seed of the resamples
    """
    scores = np.array([row["score"] for row in rows])
    mean, se = mean_and_standard_error(scores)
    _, low, high = stratified_bootstrap_ci(scores, aggregate_mean, seed=seed)
    return {
        "score": {"mean": float(mean), "se": float(se)},
        "ci95": [low, high],
        "seconds_per_run": float(np.mean([row["seconds"] for row in rows])),
        "online_ms_per_step": float(np.mean([row["online_ms_per_step"] for row in rows])),
        "updates": float(np.mean([row["updates"] for row in rows])),
        "runs": len(rows),
    }


def paired_gain(rows: Sequence[Mapping[str, Any]], floor: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """
    Mean ± standard error of a method's score minus another's (the random policy's, or DQN's) on the same
    run (the same target weight and seed): the scale of the rewards changes with the weights, and the
    pairing removes it.
    """
    gains = np.array([row["score"] - other["score"] for row, other in zip(rows, floor, strict=True)])
    mean, se = mean_and_standard_error(gains)
    return {"mean": float(mean), "se": float(se)}


def family_scale(means: np.ndarray, standard_errors: np.ndarray) -> float:
    """
    What a family's gains are divided by before the tuning protocol (``benchmarks/tune_suite.py``) averages
    them over families: the range of the candidates' mean gains on it, or twice their median standard error
    where that is larger (a family where the candidates tie within the noise, e.g. all below random, would
    otherwise decide the mean by its noise).

    :param means: each candidate's mean gain on the family, (n_candidates,)
    :param standard_errors: their standard errors, (n_candidates,)
    :return: the scale, > 0 (1 when every gain and error is 0)
    """
    return float(max(np.ptp(means), 2.0 * np.median(standard_errors))) or 1.0


def reference_fraction(results: Mapping[str, Mapping[str, Any]], method: str) -> float | None:
    """
    (TRLSD - random) / (reward given - random): how much of the reward-given level's gain over a random
    policy a TRLSD method reaches (None without the three methods, or no gain to share).

    :param method: a key of ``REFERENCES``
    """
    reference = REFERENCES[method]
    if not {method, reference, "random"} <= set(results):
        return None
    floor = results["random"]["score"]["mean"]
    gain = results[reference]["score"]["mean"] - floor
    if gain <= 0:
        return None
    return (results[method]["score"]["mean"] - floor) / gain


def fraction_interval(
    by_method: Mapping[str, Sequence[Mapping[str, Any]]], method: str, seed: int = 0
) -> list[float] | None:
    """
    The 95% paired bootstrap interval of ``reference_fraction``: the runs resampled together, a run's three
    scores (the method's, its reference's, the random policy's) kept as one (None without the three).

    :param by_method: each method's runs' rows (``suite_run``), run i of every method the same run
    :param method: a key of ``REFERENCES``
    :param seed: seed of the resamples
    """
    names = (method, REFERENCES[method], "random")
    if not set(names) <= set(by_method):
        return None
    columns = [np.array([row["score"] for row in by_method[name]]) for name in names]

    def share(scores: np.ndarray, reference: np.ndarray, floor: np.ndarray) -> np.ndarray:
        # Each run's gains as one task's column: (..., n_runs) -> (..., n_runs, 1).
        return mean_ratio((scores - floor)[..., None], (reference - floor)[..., None])

    _, low, high = paired_bootstrap_ci(share, columns, seed=seed)
    return [low, high]


def goals(
    results: Mapping[str, Mapping[str, Any]],
    by_method: Mapping[str, Sequence[Mapping[str, Any]]],
    seed: int = 0,
) -> dict[str, dict[str, Any]]:
    """
    Each TRLSD method of the run against its goals: its score minus DQN's on the same runs, and its
    fraction of the reward-given level with that fraction's paired bootstrap interval (the methods of
    ``REFERENCES`` that ran beside DQN).
    """
    table = {}
    for method in REFERENCES:
        if not {method, "dqn"} <= set(by_method):
            continue
        fraction = reference_fraction(results, method)
        table[method] = {
            "minus_dqn": paired_gain(by_method[method], by_method["dqn"]),
            "fraction_of_reward_given": fraction,
            "fraction_ci95": None if fraction is None else fraction_interval(by_method, method, seed),
        }
    return table


def write_rows(path: Path, rows: Mapping[str, Sequence[Mapping[str, Any]]]) -> None:
    """One CSV row per run: method, run, task, seed, score, seconds, online ms per step, updates."""
    columns = ["run", "task", "seed", "score", "seconds", "online_ms_per_step", "updates"]
    with atomic_write(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["method", *columns])
        for method, runs in rows.items():
            for row in runs:
                writer.writerow([method, *(row[column] for column in columns)])


def plot_bars(path: Path, title: str, results: Mapping[str, Mapping[str, Any]]) -> None:
    """A bar per method: its mean score, with its 95% bootstrap interval."""
    figure, (ax,) = new_figure(1, width=8.0, height=1.4 + 0.45 * len(results))
    labels = [METHODS[method][0] for method in results]
    means = np.array([entry["score"]["mean"] for entry in results.values()])
    intervals = np.array([entry["ci95"] for entry in results.values()])
    positions = np.arange(len(results))[::-1]
    ax.barh(positions, means, color=[f"C{i}" for i in range(len(results))], alpha=0.8)
    ax.errorbar(
        means,
        positions,
        xerr=np.abs(intervals.T - means),
        fmt="none",
        ecolor="black",
        capsize=3,
    )
    ax.set_yticks(positions, labels)
    ax.axvline(0.0, color="grey", linewidth=0.5)
    ax.set_xlabel("mean reward per online step (95% bootstrap interval)")
    save_figure(figure, path, title)


def run_suite(
    family_name: str,
    out: Path,
    runs: int = DEFAULT_RUNS,
    seed: int = 0,
    workers: int = 1,
    methods: Sequence[str] | None = None,
    cache: Path | None = None,
    split: str = "evaluation",
    n_source: int | None = None,
    n_online: int | None = None,
    source_policy: str = "random",
) -> dict[str, Any]:
    """
    ``runs`` runs of each method on a family; write ``suite_name(family, source_policy)`` ``.csv``, ``.json``
    and ``.png``.

    :param family_name: a key of ``FAMILIES``
    :param out: output directory (created if needed)
    :param runs: runs per method
    :param seed: seed of the first run
    :param workers: processes
    :param methods: keys of ``METHODS`` (None: all)
    :param cache: directory of finished runs, reused and completed (None: none)
    :param split: the target weights, ``"evaluation"`` or ``"tuning"``
    :param n_source: source transitions (None: the family's); under ``"trained"``, the source DQN's steps
    :param n_online: online transitions (None: the family's)
    :param source_policy: the source protocol, ``"random"`` or ``"trained"`` (``sources.SOURCE_POLICIES``)
    :return: the JSON summary
    """
    family: Family = family_named(family_name)
    methods = list(METHODS) if methods is None else list(methods)
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise ValueError(f"methods must be among {', '.join(METHODS)}, got {unknown}")
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    if source_policy not in SOURCE_POLICIES:
        raise ValueError(f"source_policy must be one of {', '.join(SOURCE_POLICIES)}, got {source_policy!r}")
    family.tasks_of(split)  # refused before anything runs
    started = time.perf_counter()
    n_source = family.n_source if n_source is None else n_source
    n_online = family.n_online if n_online is None else n_online
    # Under the trained protocol, the methods without a source are the random protocol's runs (one cache).
    sourced = [method for method in methods if METHODS[method][1]] if source_policy == "trained" else []
    plain = [method for method in methods if method not in sourced]
    label = f"{family.name} ({source_policy} source)"
    rows = run_jobs(
        suite_run,
        [
            ((family.name, method, run, seed, split, n_source, n_online), {})
            for method in plain
            for run in range(runs)
        ],
        workers,
        description=f"{label}: {len(plain)} methods x {runs} runs",
        cache=cache,
    )
    by_method = {method: rows[i * runs : (i + 1) * runs] for i, method in enumerate(plain)}
    if sourced:
        per_run = run_jobs(
            trained_source_runs,
            [((family.name, sourced, run, seed, split, n_source, n_online), {}) for run in range(runs)],
            workers,
            description=f"{label}: a source DQN and {len(sourced)} methods x {runs} runs",
            cache=cache,
        )
        by_method.update({method: [rows[i] for rows in per_run] for i, method in enumerate(sourced)})
    by_method = {method: by_method[method] for method in methods}
    results = {method: aggregate(method_rows, seed) for method, method_rows in by_method.items()}
    if "random" in by_method:
        for method, entry in results.items():
            entry["gain_over_random"] = paired_gain(by_method[method], by_method["random"])
    out.mkdir(parents=True, exist_ok=True)
    name = suite_name(family.name, source_policy)
    write_rows(out / f"{name}.csv", by_method)
    source = "random" if source_policy == "random" else "trained DQN's"
    title = (
        f"{family.env_id}: {n_source:,} {source} source transitions, {n_online:,} online steps, "
        f"{runs} runs on held-out weights ({split})"
    )
    plot_bars(out / f"{name}.png", title, results)
    data = summary(
        name,
        {
            "family": family.name,
            **family.parameters(),
            "source_transitions": n_source,
            "source_policy": source_policy,
            "online_transitions": n_online,
            "runs": runs,
            "split": split,
            "score": "mean scalar reward w . r_vec per online step",
            "methods": {method: METHODS[method][0] for method in methods},
        },
        seed,
        time.perf_counter() - started,
        results=results,
        goals=goals(results, by_method, seed),
    )
    write_json(out / f"{name}.json", data)
    return data


def suite_table(datas: Sequence[Mapping[str, Any]]) -> str:
    """
    The Markdown table of the suite's summaries: one row per family and method, mean ± standard error,
    bootstrap interval, gain over the random policy on the same runs, seconds per run and ms per online step.
    """
    lines = [
        "| family | method | score (mean ± SE) | 95% bootstrap | gain over random (paired) | s/run | ms/step "
        "| runs |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for data in datas:
        family = data["parameters"]["family"]
        for method, entry in data["results"].items():
            low, high = entry["ci95"]
            gain = entry.get("gain_over_random")
            gain_cell = "" if gain is None else f"{gain['mean']:+.3f} ± {gain['se']:.3f}"
            lines.append(
                f"| {family} | {data['parameters']['methods'][method]} | {entry['score']['mean']:.3f} ± "
                f"{entry['score']['se']:.3f} | [{low:.3f}, {high:.3f}] | {gain_cell} | "
                f"{entry['seconds_per_run']:.1f} | "
                f"{entry['online_ms_per_step']:.2f} | {entry['runs']} |"
            )
    return "\n".join(lines)


def goal_table(datas: Sequence[Mapping[str, Any]]) -> str:
    """
    The Markdown table of the TRLSD methods against their goals, one row per family and method: its gain
    over random (paired), its score minus DQN's (paired) in standard errors, and its fraction of the
    reward-given level's gain over random, with its 95% paired bootstrap interval where the summary has one;
    each with whether it holds (above random by 2 SE, ahead of DQN by 2 SE, at least 70%).
    """
    lines = [
        "| family | method | gain over random | above random | minus DQN | ahead of DQN by 2 SE "
        "| fraction of reward-given [95% bootstrap] | >= 70% |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for data in datas:
        for method, goal in data.get("goals", {}).items():
            gain = data["results"][method].get("gain_over_random")
            if gain is None:
                continue
            versus, fraction = goal["minus_dqn"], goal["fraction_of_reward_given"]
            lines.append(
                f"| {data['parameters']['family']} | {data['parameters']['methods'][method]} | "
                f"{gain['mean']:+.3f} ± {gain['se']:.3f} | {_yes(gain['mean'] > 2 * gain['se'])} | "
                f"{versus['mean']:+.3f} ± {versus['se']:.3f} | {_yes(versus['mean'] > 2 * versus['se'])} | "
                f"{_fraction_cell(fraction, goal.get('fraction_ci95'))} | "
                f"{'n/a' if fraction is None else _yes(fraction >= 0.7)} |"
            )
    return "\n".join(lines)


def protocol_table(datas: Sequence[Mapping[str, Any]], methods: Sequence[str] = PROTOCOL_METHODS) -> str:
    """
    The Markdown table of the two source protocols side by side: one row per family and method of
    ``methods``, its score (mean ± standard error) and its gain over the random policy on the same runs
    (paired), over a random policy's source and over a trained DQN's; a cell is empty where that protocol's
    summary is not among ``datas`` or lacks the method.

    :param datas: summaries of ``run_suite`` under either protocol (their ``source_policy`` tells which)
    :param methods: the methods, in their rows' order
    """
    by_family: dict[str, dict[str, Mapping[str, Any]]] = {}
    for data in datas:
        parameters = data["parameters"]
        by_family.setdefault(parameters["family"], {})[parameters.get("source_policy", "random")] = data
    header = "| family | method |" + "".join(
        f" {policy} source: score | {policy} source: gain over random |" for policy in SOURCE_POLICIES
    )
    lines = [header, "|---|---|" + "---|---|" * len(SOURCE_POLICIES)]
    for family, protocols in by_family.items():
        for method in methods:
            cells = []
            for policy in SOURCE_POLICIES:
                entry = protocols.get(policy, {}).get("results", {}).get(method)
                if entry is None:
                    cells += ["", ""]
                    continue
                gain = entry.get("gain_over_random")
                cells.append(f"{entry['score']['mean']:.3f} ± {entry['score']['se']:.3f}")
                cells.append("" if gain is None else f"{gain['mean']:+.3f} ± {gain['se']:.3f}")
            if any(cells):
                lines.append(f"| {family} | {METHODS[method][0]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fraction_cell(fraction: float | None, interval: Sequence[float] | None) -> str:
    if fraction is None:
        return "n/a"
    return f"{fraction:.0%}" if interval is None else f"{fraction:.0%} [{interval[0]:.0%}, {interval[1]:.0%}]"


def _yes(holds: bool) -> str:
    return "yes" if holds else "**no**"
