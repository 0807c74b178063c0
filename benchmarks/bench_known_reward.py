"""With the reward known, does TRLSD act on it from the first step? The library's defaults on the maze.

The paper's Figure 1: with the reward known, "the agent immediately follows a rational policy and heads
towards the reward slot". Each run: 25,000 random source transitions (rewards discarded), then 1,000 online
steps on a task drawn at random, with ``TRLSD("LinearPolicy", maze, reward_head="known")`` and the library's
defaults, against the same runs with ``exploration_initial_eps=0`` (greedy throughout, the paper's policy)
and ``exploration_initial_eps=1`` (the learnt heads' epsilon-greedy start). Printed: the mean expected reward
over online steps [0, 1000) and [500, 1000), mean ± standard error over runs. Usage::

    python benchmarks/bench_known_reward.py [--runs 20] [--workers 2]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd_envs import MAZE_ID, N_TASKS
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.runner import run_online
from sb3_trlsd_lab.paper.reporting import mean_and_standard_error

VARIANTS = {  # label -> TRLSD settings over reward_head="known" and the defaults
    "defaults": {},
    "greedy throughout (exploration_initial_eps=0)": {"exploration_initial_eps": 0.0},
    "epsilon-greedy start (exploration_initial_eps=1)": {"exploration_initial_eps": 1.0},
}


def known_reward_run(variant: str, seed: int) -> np.ndarray:
    """The expected reward of each of the 1,000 online steps of one run (its task drawn by its seed)."""
    task = int(np.random.default_rng(seed).integers(N_TASKS))
    env = gym.make(MAZE_ID, task=task)
    model = TRLSD("LinearPolicy", env, reward_head="known", seed=seed, **VARIANTS[variant])
    source = collect_transitions(gym.make(MAZE_ID, task=(task + 1) % N_TASKS), 25_000, seed=seed + 1)
    model.load_transitions(source, keep_rewards=False)
    return run_online(model, env, 1_000, seed).rewards


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="runs per variant (the same seeds and tasks)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    args = parser.parse_args()
    jobs = [((variant, seed), {}) for variant in VARIANTS for seed in range(args.runs)]
    rewards = run_jobs(known_reward_run, jobs, workers=args.workers, description="known-reward runs")
    print(f"maze, reward_head='known', {args.runs} runs per variant (tasks drawn at random, same seeds)\n")
    print("| exploration | reward [0, 1000) | reward [500, 1000) |")
    print("|---|---|---|")
    for i, variant in enumerate(VARIANTS):
        runs = np.stack(rewards[i * args.runs : (i + 1) * args.runs])
        whole = mean_and_standard_error(runs.mean(axis=1))
        late = mean_and_standard_error(runs[:, 500:].mean(axis=1))
        print(f"| {variant} | {whole[0]:.3f} ± {whole[1]:.3f} | {late[0]:.3f} ± {late[1]:.3f} |")


if __name__ == "__main__":
    main()
