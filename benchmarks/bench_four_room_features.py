"""What four-room asks of a linear Q: features of where the agent is times which shapes are left.

Four-room (MO-Gymnasium's ``four-room-v0``) pays for a shape the first time the agent steps on its cell: the
value of a cell depends on which of the 12 shapes are still there, and a linear Q on features that add the
position's part and the flags' part (the defaults' on these 14 dimensions) cannot say so: its greedy policy
walks to one spot and stays, even given the true rewards. This runs TRLSD given the source's true rewards
(the suite's reference) on the tuning weights, with the suite's sources, seeds and budget, under the
default features and under ``PositionTimesShapesLeft``: an RBF per cell of the 13 x 13 grid plus a coarser
7 x 7 grid of the position times each shape's "not collected yet" flag (757 features). Printed per variant:
the score (mean reward per online step), its gain over the random policy on the same runs (paired), the
score over the second half of the online steps (after the epsilon-greedy span) and ms per online step. A
diagnosis, not a test: nothing is asserted. Usage::

    python benchmarks/bench_four_room_features.py [--runs 4] [--workers 2]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np

from sb3_trlsd.feature_maps import FeatureMap, RBFGrid
from sb3_trlsd_lab.benchmarks.mo_suite.families import family_named
from sb3_trlsd_lab.benchmarks.mo_suite.suite import suite_run
from sb3_trlsd_lab.execution.jobs import run_jobs

FAMILY = "four-room-v0"


@dataclass(frozen=True)
class PositionTimesShapesLeft(FeatureMap):
    """
    Phi of four-room's states (row, col, 12 collected flags): an RBF per cell of the grid (half a cell
    wide), then each shape's ``1 - flag`` times a coarser grid of RBFs of the position.

    :param low: lower corner of the state box, (14,)
    :param high: its upper corner, (14,)
    :param coarse: centres per dimension of the grid multiplied by the flags
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    coarse: int = 7
    cells: RBFGrid = field(init=False, repr=False)
    areas: RBFGrid = field(init=False, repr=False)

    def __post_init__(self) -> None:
        corner, size = (self.low[0], self.low[1]), (self.high[0], self.high[1])
        n_cells = int(self.high[0] - self.low[0]) + 1
        object.__setattr__(self, "cells", RBFGrid(corner, size, n_cells, 0.5 / n_cells))
        object.__setattr__(self, "areas", RBFGrid(corner, size, self.coarse, 0.7 / self.coarse))

    @property
    def n_features(self) -> int:
        return self.cells.n_features + self.areas.n_features * (len(self.low) - 2)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        position, left = states[:, :2], 1.0 - states[:, 2:]
        areas = self.areas(position)
        products = (areas[:, :, None] * left[:, None, :]).reshape(len(states), -1)
        return np.concatenate([self.cells(position), products], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    family = family_named(FAMILY)
    assert family.state_low is not None and family.state_high is not None
    features = PositionTimesShapesLeft(family.state_low, family.state_high)
    variants = [
        ("random policy", "random", None),
        ("given the true rewards, default features", "trlsd-reward-given", {}),
        (
            f"given the true rewards, position x shapes left ({features.n_features})",
            "trlsd-reward-given",
            {"feature_map": features},
        ),
    ]
    jobs = [
        (
            (FAMILY, method, run, 0, "tuning", family.n_source, family.n_online),
            {} if settings is None else {"settings": settings},
        )
        for _, method, settings in variants
        for run in range(args.runs)
    ]
    rows = run_jobs(suite_run, jobs, args.workers, description="four-room runs")
    by_variant = [rows[i * args.runs : (i + 1) * args.runs] for i in range(len(variants))]
    floor = np.array([row["score"] for row in by_variant[0]])
    print(f"{'variant':<58}{'score':>8}{'gain over random':>22}{'2nd half':>10}{'ms/step':>9}")
    for (label, _, _), runs in zip(variants, by_variant, strict=True):
        scores = np.array([row["score"] for row in runs])
        gain = scores - floor
        se = gain.std(ddof=1) / np.sqrt(len(gain)) if len(gain) > 1 else 0.0
        half = np.mean([np.mean(row["rewards"][len(row["rewards"]) // 2 :]) for row in runs])
        ms = np.mean([row["online_ms_per_step"] for row in runs])
        cell = f"{gain.mean():+.4f} ± {se:.4f}"
        print(f"{label:<58}{scores.mean():>8.4f}{cell:>22}{half:>10.4f}{ms:>9.1f}")


if __name__ == "__main__":
    main()
