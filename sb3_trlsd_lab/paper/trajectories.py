"""
Figures 2, 3 and 4: what one run looks like after a few numbers of transitions: the reward estimate R^
in green, the last transitions in blue, the greedy policy at each cell centre in red.

- Figure 2, continuous setting (ridge head): after 15, 150 and 650 transitions; exploration first,
  then exploitation, with detours through the less visited places.
- Figure 3, discrete setting (tabular head on the 25 cells): the first 50 transitions.
- Figure 4, corners prior (rewards only in the 4 corner cells): after 15, 30 and 60 transitions;
  exploration goes straight for the corners.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sb3_trlsd_lab.execution.runner import Method, transfer_run
from sb3_trlsd_lab.paper.figures import draw_snapshot, new_figure, protocol_title, save_figure
from sb3_trlsd_lab.paper.reporting import summary, write_curves_csv, write_json
from sb3_trlsd_lab.paper.reproduction import Reproduction

TASK = 4  # tau_15, a corner (Figure 4's prior allows only corners)
SETTINGS = {  # name: (title, method, snapshot steps)
    "fig2": ("Figure 2: continuous setting", Method("continuous (ridge)"), (15, 150, 650)),
    "fig3": ("Figure 3: discrete setting", Method("discrete (tabular)", reward_head="tabular"), (50,)),
    "fig4": ("Figure 4: corners prior", Method("corners prior", reward_head="corners"), (15, 30, 60)),
}


def _reproduce(name: str, out: Path, how: Reproduction) -> dict:
    started = time.perf_counter()
    title, method, steps = SETTINGS[name]
    record = transfer_run(
        method, TASK, how.seed, n_online=max(steps), snapshot_at=steps, protocol=how.protocol
    )
    figure, axes = new_figure(len(steps), width=4.2, height=4.5)
    for ax, snapshot in zip(axes, record.snapshots, strict=True):
        draw_snapshot(ax, snapshot, TASK, f"after {snapshot.step} transitions")
    title = f"{title}, target tau_15 (green: R^, red: greedy policy)"
    save_figure(figure, out / f"{name}.png", protocol_title(title, how.protocol))
    write_curves_csv(out / f"{name}.csv", "transition", {method.label: record.rewards[None]})
    data = summary(
        name,
        {"method": method.parameters(), "task": "tau_15", "snapshots_after": list(steps), **how.recorded()},
        how.seed,
        time.perf_counter() - started,
        results={
            "policy_updates": record.policy_updates,
            "reward_per_snapshot_interval": _interval_rewards(record.rewards, steps),
        },
    )
    write_json(out / f"{name}.json", data)
    return data


def _interval_rewards(rewards: np.ndarray, steps: Sequence[int]) -> dict[str, float]:
    bounds = [0, *steps]
    return {f"[{a}, {b})": float(rewards[a:b].mean()) for a, b in itertools.pairwise(bounds)}


def reproduce_fig2(out: Path, how: Reproduction) -> dict:
    """Figure 2 (one short run: the runs, workers, cache and backend of ``how`` do not apply)."""
    return _reproduce("fig2", out, how)


def reproduce_fig3(out: Path, how: Reproduction) -> dict:
    """Figure 3 (one short run: the runs, workers, cache and backend of ``how`` do not apply)."""
    return _reproduce("fig3", out, how)


def reproduce_fig4(out: Path, how: Reproduction) -> dict:
    """Figure 4 (one short run: the runs, workers, cache and backend of ``how`` do not apply)."""
    return _reproduce("fig4", out, how)
