"""
Figure 6: the 4 corner tasks (tau_11, tau_15, tau_51, tau_55). The continuous setting against the
discrete one with the prior that only the corner cells can be rewarded, with ``update_ratio`` 2 (fewer
than 10 updates: online learning suffers) and 1.05 (about 50 updates).
"""

from __future__ import annotations

import time
from pathlib import Path

from sb3_trlsd_envs import CORNER_TASKS
from sb3_trlsd_lab.execution.batches import transfer_runs
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.figures import protocol_title, write_transfer_figure
from sb3_trlsd_lab.paper.reproduction import Reproduction

DEFAULT_RUNS = 200  # the paper gives no count for Figure 6: 50 runs of each corner
TITLE = "Figure 6: corner tasks, the corners prior against the continuous setting"
METHODS = [
    Method("continuous, ratio 2"),
    Method("corners prior, ratio 2", reward_head="corners"),
    Method("continuous, ratio 1.05", update_ratio=1.05),
    Method("corners prior, ratio 1.05", reward_head="corners", update_ratio=1.05),
]


def reproduce(out: Path, how: Reproduction) -> dict:
    """
    Curves of the corner tasks, one panel per update ratio.

    :param out: the output directory
    :param how: runs, seed, workers, cache, backend and protocol
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    records = transfer_runs(METHODS, CORNER_TASKS, runs, how.seed, how.workers, **how.run_options())
    return write_transfer_figure(
        out,
        "fig6",
        protocol_title(TITLE, how.protocol),
        METHODS,
        records,
        [(0, 100), (0, 200), (0, 1000), (500, 1000)],
        {"tasks": "the 4 corners in turn", "runs": runs, **how.recorded()},
        how.seed,
        started,
        panels=[
            ("update ratio 2", [m.label for m in METHODS[:2]]),
            ("update ratio 1.05", [m.label for m in METHODS[2:]]),
        ],
    )
