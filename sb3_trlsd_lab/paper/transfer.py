"""
Figure 5: the 25 tasks, 1,000 online transitions after 25,000 random source transitions, 500 runs (20 per
task). No transfer, non-optimistic (kappa = 0, Atkeson & Santamaria), and the optimistic continuous
(ridge head) and discrete (tabular head) settings with ``update_ratio`` 2 and 1.2.
"""

from __future__ import annotations

import time
from pathlib import Path

from sb3_trlsd_envs import N_TASKS
from sb3_trlsd_lab.execution.batches import transfer_runs
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.figures import protocol_title, write_transfer_figure
from sb3_trlsd_lab.paper.reproduction import Reproduction

DEFAULT_RUNS = 500  # paper: 500 independent runs, 20 per task
TITLE = "Figure 5: 25 tasks, 25,000 random source transitions, then 1,000 online"
METHODS = [
    Method("no transfer", transfer=False),
    Method("non-optimistic (kappa=0)", kappa=0.0),
    Method("continuous, ratio 2"),
    Method("discrete, ratio 2", reward_head="tabular"),
    Method("continuous, ratio 1.2", update_ratio=1.2),
    Method("discrete, ratio 1.2", reward_head="tabular", update_ratio=1.2),
]
WINDOWS = [(0, 100), (0, 1000), (500, 1000)]


def reproduce(out: Path, how: Reproduction, methods: list[Method] = METHODS) -> dict:
    """
    Curves of every method over the 25 tasks, in two panels: update ratio 2, and 1.2.

    :param out: the output directory
    :param how: runs, seed, workers, cache, backend and protocol
    :param methods: the curves (the paper's by default)
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    records = transfer_runs(methods, range(N_TASKS), runs, how.seed, how.workers, **how.run_options())
    ratio_2 = [m.label for m in methods if m.update_ratio == 2.0]
    ratio_12 = [m.label for m in methods if m.update_ratio != 2.0]
    return write_transfer_figure(
        out,
        "fig5",
        protocol_title(TITLE, how.protocol),
        methods,
        records,
        WINDOWS,
        {"tasks": "all 25 in turn", "runs": runs, **how.recorded()},
        how.seed,
        started,
        panels=[("update ratio 2", ratio_2), ("update ratio 1.2", ratio_12)] if ratio_12 else None,
    )
