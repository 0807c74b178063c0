"""Transfer on the maze with the ``TRLSD`` class itself: optimistic vs non-optimistic vs no transfer.

The setting of the paper's Figure 5 (section 4): 25,000 random source transitions with their rewards
discarded, then 1,000 online transitions on a target task, run ``--runs`` times over the 25 tasks in turn.
"Known reward" is Figure 1's setting (CI = 0, the policy fitted once); "no transfer" is the same
algorithm without the source transitions, with and without optimism.
Prints, per method, the mean expected reward E[R_tau(s_t)] of the visited states over all 1,000
transitions and over the last 500, with standard errors, the mean number of policy updates, and the
seconds per run. Usage::

    python benchmarks/bench_transfer.py --runs 50 --workers 2
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import gymnasium as gym
import numpy as np
from threadpoolctl import threadpool_limits

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd_envs.maze import N_TASKS, expected_reward

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"
METHODS = {
    "known reward": {"transfer": True, "kappa": 0.0, "reward_head": "known"},
    "optimistic (ridge, kappa=0.1)": {"transfer": True, "kappa": 0.1},
    "non-optimistic (kappa=0)": {"transfer": True, "kappa": 0.0},
    "no transfer, optimistic (kappa=0.1)": {"transfer": False, "kappa": 0.1},
    "no transfer, non-optimistic (kappa=0)": {"transfer": False, "kappa": 0.0},
}


def run_once(method: str, run: int, n_source: int, n_online: int) -> tuple[np.ndarray, int, float]:
    """One run: the expected reward at each online step, the number of policy updates, and the wall time."""
    # The products of a run are small: BLAS threads would only fight the other workers for the cores.
    with threadpool_limits(1):
        return _run_once(method, run, n_source, n_online)


def _run_once(method: str, run: int, n_source: int, n_online: int) -> tuple[np.ndarray, int, float]:
    start = time.perf_counter()
    settings = METHODS[method]
    task = run % N_TASKS
    model = TRLSD(
        "LinearPolicy",
        gym.make(MAZE_ID, task=task),
        reward_head=settings.get("reward_head", "ridge"),
        kappa=settings["kappa"],
        sigma=0.04,  # 0.2 on the maze (a fraction of its 5 x 5 box)
        seed=run,
    )
    if settings["transfer"]:
        source = collect_transitions(gym.make(MAZE_ID, task=(run * 7) % N_TASKS), n_source, seed=10_000 + run)
        model.load_transitions(source, keep_rewards=False)
    model.learn(total_timesteps=n_online)
    # The online transitions are the newest rows of the shared buffer.
    online_states = model.replay_buffer.transitions().states[-n_online:]
    return (
        expected_reward(online_states, task),
        model.policy_updates.get(task, 0),
        time.perf_counter() - start,
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=50, help="runs per method (tasks in turn)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--source", type=int, default=25_000, help="random source transitions")
    parser.add_argument("--online", type=int, default=1_000, help="online transitions on the target task")
    parser.add_argument(
        "--methods", nargs="+", choices=list(METHODS), default=list(METHODS), help="methods to run"
    )
    args = parser.parse_args()

    print(f"{args.runs} runs per method, {args.source} source and {args.online} online transitions\n")
    print("| method | mean reward [0, 1000) | mean reward [500, 1000) | policy updates | s / run |")
    print("|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for method in args.methods:
            jobs = [pool.submit(run_once, method, run, args.source, args.online) for run in range(args.runs)]
            results = [job.result() for job in jobs]
            rewards = np.stack([r[0] for r in results])
            updates = np.array([r[1] for r in results])
            seconds = np.mean([r[2] for r in results])
            whole, last = rewards.mean(axis=1), rewards[:, args.online // 2 :].mean(axis=1)
            sem = np.sqrt(args.runs)
            print(
                f"| {method} | {whole.mean():.3f} ± {whole.std(ddof=1) / sem:.3f} "
                f"| {last.mean():.3f} ± {last.std(ddof=1) / sem:.3f} "
                f"| {updates.mean():.1f} | {seconds:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
