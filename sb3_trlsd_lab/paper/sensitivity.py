"""
Figure 7: sensitivity of the continuous setting to kappa (at sigma = 0.2) and to sigma (at kappa = 0.1):
the reward averaged over transitions [0, 100), [0, 200), [0, 500), [0, 1000) and [500, 1000). The paper
finds the best values depend on the horizon, and kappa matters much more than sigma.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from sb3_trlsd_envs import N_TASKS
from sb3_trlsd_lab.execution.batches import transfer_runs
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.figures import new_figure, protocol_title, save_figure, update_counts
from sb3_trlsd_lab.paper.reporting import (
    source_sets_of,
    summary,
    window_means,
    write_curves_csv,
    write_json,
)
from sb3_trlsd_lab.paper.reproduction import Reproduction

DEFAULT_RUNS = 100  # runs per parameter value (the paper does not say; Figure 5 uses 500)
KAPPAS = (0.01, 0.03, 0.1, 0.3, 1.0)
SIGMAS = (0.05, 0.1, 0.2, 0.5, 1.0)
WINDOWS = [(0, 100), (0, 200), (0, 500), (0, 1000), (500, 1000)]


def reproduce(out: Path, how: Reproduction) -> dict:
    """
    Window averages against kappa and against sigma, with standard-error bars.

    :param out: the output directory
    :param how: runs, seed, workers, cache, backend and protocol
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    sweeps = {
        "kappa": [Method(f"kappa={kappa:g}", kappa=kappa) for kappa in KAPPAS],
        "sigma": [Method(f"sigma={sigma:g}", sigma=sigma) for sigma in SIGMAS if sigma != 0.2],
    }
    methods = sweeps["kappa"] + sweeps["sigma"]
    records = transfer_runs(methods, range(N_TASKS), runs, how.seed, how.workers, **how.run_options())
    # kappa = 0.1, sigma = 0.2 is the same method in both sweeps: run once, shown in both.
    records["sigma=0.2"] = records["kappa=0.1"]
    curves = {label: np.stack([record.rewards for record in runs]) for label, runs in records.items()}
    write_curves_csv(out / "fig7.csv", "transition", curves)
    windows = {
        label: window_means(values, WINDOWS, source_sets_of(records[label]))
        for label, values in curves.items()
    }

    figure, axes = new_figure(2)
    for ax, (parameter, values) in zip(axes, (("kappa", KAPPAS), ("sigma", SIGMAS)), strict=True):
        for start, stop in WINDOWS:
            key = f"[{start}, {stop})"
            means = [windows[f"{parameter}={value:g}"][key]["mean"] for value in values]
            errors = [windows[f"{parameter}={value:g}"][key]["se"] for value in values]
            ax.errorbar(values, means, yerr=errors, marker="o", capsize=3, label=f"transitions {key}")
        ax.set_xscale("log")
        ax.set_xlabel(parameter + (" (sigma = 0.2)" if parameter == "kappa" else " (kappa = 0.1)"))
        ax.set_ylabel("average reward")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    title = f"Figure 7: sensitivity of the continuous setting ({runs} runs per value)"
    save_figure(figure, out / "fig7.png", protocol_title(title, how.protocol))

    results = {
        label: {"reward": windows[label], "policy_updates": update_counts(records[label])} for label in curves
    }
    data = summary(
        "fig7",
        {
            "kappas": KAPPAS,
            "sigmas": SIGMAS,
            "runs": runs,
            "methods": [m.parameters() for m in methods],
            **how.recorded(),
        },
        how.seed,
        time.perf_counter() - started,
        results=results,
    )
    write_json(out / "fig7.json", data)
    return data
