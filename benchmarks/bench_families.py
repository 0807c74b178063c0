"""Do the new task families learn? TRLSD with its default arguments against a random policy.

For each family: 25,000 random source transitions of one task (rewards discarded, as in the paper), then
``TRLSD("LinearPolicy", target, seed=run)`` with every other argument at its default learns a different
target task online for ``--online`` transitions. Run r targets task r (modulo the family's tasks) and
takes its source from task r + 1. Prints, per family, the mean expected reward E[R_task(s_t)] of the
visited states over the online phase and over its second half, for TRLSD and for a uniformly random
policy on the same target task, per run and on average, and the seconds per run. Usage::

    python benchmarks/bench_families.py --runs 2 --online 2000 --workers 2
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import gymnasium as gym
import numpy as np
from threadpoolctl import threadpool_limits

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd_envs import FOUR_ROOMS_ID, GOAL_CARTPOLE_ID

FAMILIES = (FOUR_ROOMS_ID, GOAL_CARTPOLE_ID)


class ExpectedRewards(gym.Wrapper):
    """Records E[R_task(s_t)] of the state each step starts from (the noise-free reward of the step)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.expected: list[float] = []

    def step(self, action):
        unwrapped = self.env.unwrapped
        self.expected.append(float(unwrapped.expected_reward(unwrapped.state[None])[0]))
        return self.env.step(action)


def target_env(family: str, run: int) -> ExpectedRewards:
    n_tasks = gym.make(family).observation_space["task"].n
    return ExpectedRewards(gym.make(family, task=run % n_tasks))


def random_policy(family: str, run: int, n_online: int) -> np.ndarray:
    """Expected rewards of a uniformly random policy on the target task of ``run``."""
    env = target_env(family, run)
    env.reset(seed=run)
    env.action_space.seed(run)
    while len(env.expected) < n_online:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    return np.array(env.expected)


def trlsd(family: str, run: int, n_source: int, n_online: int) -> tuple[np.ndarray, float]:
    """Expected rewards of TRLSD's online phase on the target task of ``run``, and its wall time."""
    # The products of a run are small: BLAS threads would only fight the other workers for the cores.
    with threadpool_limits(1):
        start = time.perf_counter()
        env = target_env(family, run)
        n_tasks = env.observation_space["task"].n
        source = collect_transitions(gym.make(family, task=(run + 1) % n_tasks), n_source, seed=10_000 + run)
        model = TRLSD("LinearPolicy", env, seed=run)
        model.load_transitions(source, keep_rewards=False)
        model.learn(total_timesteps=n_online)
        return np.array(env.expected[:n_online]), time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=2, help="runs per family (target tasks in turn)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--source", type=int, default=25_000, help="random source transitions")
    parser.add_argument("--online", type=int, default=2_000, help="online transitions on the target task")
    parser.add_argument("--families", nargs="+", choices=FAMILIES, default=list(FAMILIES), help="env ids")
    args = parser.parse_args()

    print(f"{args.runs} runs per family, {args.source} source and {args.online} online transitions\n")
    print("| family | run (task) | TRLSD, all | TRLSD, 2nd half | random, all | random, 2nd half | s / run |")
    print("|---|---|---|---|---|---|---|")
    half = args.online // 2
    with ProcessPoolExecutor(args.workers) as pool:
        for family in args.families:
            jobs = [pool.submit(trlsd, family, run, args.source, args.online) for run in range(args.runs)]
            learnt, baseline = [], []
            for run, job in enumerate(jobs):
                rewards, seconds = job.result()
                random_rewards = random_policy(family, run, args.online)
                learnt.append(rewards)
                baseline.append(random_rewards)
                print(
                    f"| {family} | {run} | {rewards.mean():.3f} | {rewards[half:].mean():.3f} "
                    f"| {random_rewards.mean():.3f} | {random_rewards[half:].mean():.3f} | {seconds:.0f} |",
                    flush=True,
                )
            learnt_mean, baseline_mean = np.mean(learnt, axis=0), np.mean(baseline, axis=0)
            print(
                f"| {family} | mean | {learnt_mean.mean():.3f} | {learnt_mean[half:].mean():.3f} "
                f"| {baseline_mean.mean():.3f} | {baseline_mean[half:].mean():.3f} | |",
                flush=True,
            )


if __name__ == "__main__":
    main()
