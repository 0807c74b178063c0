"""
Figure 1: the reward is known (CI = 0). From the 25,000 random source transitions alone, FQI gives a
rational policy at once: the agent heads for the reward cell from its first step.
"""

from __future__ import annotations

import time
from pathlib import Path

from sb3_trlsd_envs import N_TASKS
from sb3_trlsd_lab.execution.batches import transfer_runs
from sb3_trlsd_lab.execution.runner import Method, transfer_run
from sb3_trlsd_lab.paper.figures import protocol_title, write_transfer_figure
from sb3_trlsd_lab.paper.reproduction import Reproduction

DEFAULT_RUNS = 100  # the paper gives no count for Figure 1: 4 runs of each of the 25 tasks
TITLE = "Figure 1: known reward (CI = 0), 25,000 random source transitions"
PICTURE_TASK = 4  # tau_15, the bottom-left corner cell
PICTURE_STEP = 30
KNOWN = Method("known reward", reward_head="known", kappa=0.0)


def reproduce(out: Path, how: Reproduction) -> dict:
    """
    Curves of the 25 tasks with the known reward, next to one trajectory as in the paper's Figure 1 (the
    trajectory's run, a short one, is not cached).

    :param out: the output directory
    :param how: runs, seed, workers, cache, backend and protocol
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    records = transfer_runs([KNOWN], range(N_TASKS), runs, how.seed, how.workers, **how.run_options())
    picture = transfer_run(KNOWN, PICTURE_TASK, how.seed, snapshot_at=[PICTURE_STEP], protocol=how.protocol)
    return write_transfer_figure(
        out,
        "fig1",
        protocol_title(TITLE, how.protocol),
        [KNOWN],
        records,
        [(0, 100), (0, 1000), (500, 1000)],
        {"tasks": "all 25 in turn", "runs": runs, **how.recorded()},
        how.seed,
        started,
        picture=(picture.snapshots[0], PICTURE_TASK, f"tau_15, first {PICTURE_STEP} transitions"),
    )
