"""Why does kappa = 0 keep up with optimism on the maze? Take away its sources of exploration and see.

The paper reports that the non-optimistic method (kappa = 0, Atkeson & Santamaria) "fails to converge",
but on our maze it collects about as much reward as the optimistic ridge head (Figure 5). Hypothesis:
with kappa = 0 the greedy policy on the ridge estimate R^ explores anyway, for two reasons the maze gives it:
- R^ is built from noisy rewards (N(0, 1) on every cell, eq. 12): cells visited once carry random bumps
  of R^, the greedy policy runs to the positive ones, new samples flatten them, and it moves on, a
  perturbed-reward exploration (as in Thompson sampling);
- every step ends the trajectory with probability 0.02 and restarts it at a uniformly random state:
  about 20 free restarts in 1,000 transitions, from which even a fixed greedy policy crosses new cells.
Without noise R^ is exactly 0 outside the target cell until the agent has been there, so all actions
tie; without restarts too, nothing brings it there. Optimism depends on neither.

This runs Figure 5's setting (25,000 random source transitions, 1,000 online transitions, tasks in turn,
the same seeds for every method) with the target env's noise and restarts taken away. Usage::

    python benchmarks/bench_exploration.py --runs 50 --workers 2
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_trlsd_envs import N_TASKS
from sb3_trlsd_lab.execution.batches import transfer_runs
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.reporting import mean_and_standard_error

SETTINGS = {  # name -> keyword arguments of the target task's env
    "paper": {},
    "noise 0.1": {"reward_noise_std": 0.1},
    "noise 0": {"reward_noise_std": 0.0},
    "no restarts": {"termination_prob": 0.0},
    "noise 0, no restarts": {"reward_noise_std": 0.0, "termination_prob": 0.0},
}
METHODS = [
    Method("optimistic (ridge, kappa=0.1)"),
    Method("non-optimistic (kappa=0)", kappa=0.0),
]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=50, help="runs per method and setting (tasks in turn)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first run")
    parser.add_argument(
        "--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS), help="target env settings"
    )
    args = parser.parse_args()

    print(f"{args.runs} runs per method and setting, seed {args.seed}\n")
    print("| target env | method | mean reward [0, 1000) | mean reward [500, 1000) | policy updates |")
    print("|---|---|---|---|---|")
    for setting in args.settings:
        records = transfer_runs(
            METHODS, range(N_TASKS), args.runs, args.seed, args.workers, env_kwargs=SETTINGS[setting]
        )
        for method in METHODS:
            runs = records[method.label]
            whole = mean_and_standard_error(np.array([r.rewards.mean() for r in runs]))
            last = mean_and_standard_error(np.array([r.rewards[len(r.rewards) // 2 :].mean() for r in runs]))
            updates = np.mean([r.policy_updates for r in runs])
            print(
                f"| {setting} | {method.label} | {whole[0]:.3f} ± {whole[1]:.3f} "
                f"| {last[0]:.3f} ± {last[1]:.3f} | {updates:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
