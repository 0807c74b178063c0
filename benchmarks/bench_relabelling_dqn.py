"""DQN with TRLSD's relabelling buffer against DQN alone and DQN given the source with zero rewards.

One target task of the maze (``--task``, default the centre cell tau_33), ``--runs`` runs; run r has the seed
``--seed`` + r and its own 25,000 random source transitions, drawn on task ``task + 1 + r`` (modulo 25),
their rewards discarded. Every method gets the same online budget (``--steps``) and the same DQN settings,
``DQN_SETTINGS`` of the benchmark of task families with ``--gradient-steps`` and
``--target-update-interval`` (4 and 100: more rounds of Q-iteration than ``DQN_SETTINGS``' 1 and 250 give):

- DQN + relabelling (tabular / ridge): ``RelabellingReplayBuffer`` with the source loaded, R~ capped at
  ``--r-max``, optimism ``--kappa``; the tabular head averages the rewards per cell of the maze (the paper's
  discrete setting, eq. 10), the ridge one regresses them on 5 x 5 RBFs (eq. 8-9);
- DQN: from scratch;
- DQN, zero-reward source: the source added to DQN's own buffer with reward 0 (``fill_replay_buffer``).

Prints, per method, the mean expected reward E[R_tau(s_t)] of the visited states over the last half of the
budget and over all of it, and of the greedy policy after it (200 runs of 30 steps), each with its
standard error over the runs, and the CPU seconds per run. Asserts nothing about time. Usage::

    python benchmarks/bench_relabelling_dqn.py --runs 6 --steps 1500
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
from stable_baselines3 import DQN

from sb3_trlsd import RelabellingReplayBuffer, Transitions, collect_transitions, dqn_q_values
from sb3_trlsd_envs.evaluation import greedy_expected_rewards
from sb3_trlsd_envs.maze import N_TASKS
from sb3_trlsd_lab.benchmarks.baselines import (
    DQN_SETTINGS,
    ExpectedRewards,
    fill_replay_buffer,
    one_torch_thread,
)

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"
N_SOURCE = 25_000  # the paper's source set
METHODS = ("DQN + relabelling (tabular)", "DQN + relabelling (ridge)", "DQN", "DQN, zero-reward source")


def run_once(
    method: str, seed: int, source: Transitions, args: argparse.Namespace
) -> tuple[np.ndarray, float]:
    """
    One run of ``method``.

    :return: the expected reward of each online step's state, (steps,), and of the greedy policy after them
    """
    env = ExpectedRewards(gym.make(MAZE_ID, task=args.task))
    settings = {
        **DQN_SETTINGS,
        "gradient_steps": args.gradient_steps,
        "target_update_interval": args.target_update_interval,
    }
    if method.startswith("DQN + relabelling"):
        settings["replay_buffer_class"] = RelabellingReplayBuffer
        settings["replay_buffer_kwargs"] = {
            "reward_head": "tabular" if "tabular" in method else "ridge",
            "kappa": args.kappa,
            "reward_head_kwargs": {"r_max": args.r_max},
            "reward_timing": "start_state",  # the maze pays for the state a step starts from
        }
    with one_torch_thread():
        model = DQN("MultiInputPolicy", env, seed=seed, device="cpu", **settings)
        if isinstance(model.replay_buffer, RelabellingReplayBuffer):
            model.replay_buffer.load_transitions(source)
        elif method == "DQN, zero-reward source":
            fill_replay_buffer(model, source, args.task)
        model.learn(total_timesteps=args.steps)
        greedy = greedy_expected_rewards(
            dqn_q_values(model), np.full(200, args.task), n_steps=30, rng=np.random.default_rng(seed)
        )
    return np.array(env.expected[: args.steps]), float(greedy.mean())


def mean_and_error(values: list[float]) -> str:
    """Mean ± standard error of the mean; the mean alone, marked, for a single run (no error to give)."""
    array = np.asarray(values)
    if len(array) < 2:
        return f"{array.mean():.3f} (one run)"
    return f"{array.mean():.3f} ± {array.std(ddof=1) / np.sqrt(len(array)):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=6, help="runs per method (seeds seed..seed+runs-1)")
    parser.add_argument("--steps", type=int, default=1_500, help="online transitions per run")
    parser.add_argument("--task", type=int, default=12, help="the target task's index (12: the centre cell)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first run")
    parser.add_argument("--gradient-steps", type=int, default=4, help="DQN's gradient steps per env step")
    parser.add_argument("--target-update-interval", type=int, default=100, help="env steps between updates")
    parser.add_argument("--kappa", type=float, default=0.1, help="optimism of the reward heads (eq. 9, 10)")
    parser.add_argument("--r-max", type=float, default=1.0, help="cap on the relabelled reward R~")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS, metavar="METHOD")
    args = parser.parse_args()

    results: dict[str, dict[str, list[float]]] = {
        m: {"last": [], "all": [], "greedy": [], "cpu": []} for m in args.methods
    }
    for run in range(args.runs):
        seed = args.seed + run
        source_env = gym.make(MAZE_ID, task=(args.task + 1 + run) % N_TASKS)
        source = collect_transitions(source_env, N_SOURCE, seed=10_000 + seed)
        for method in args.methods:
            start = time.process_time()
            visited, greedy = run_once(method, seed, source, args)
            row = results[method]
            row["cpu"].append(time.process_time() - start)
            row["last"].append(float(visited[args.steps // 2 :].mean()))
            row["all"].append(float(visited.mean()))
            row["greedy"].append(greedy)
            print(f"run {run} {method}: greedy {greedy:.3f}, last half {row['last'][-1]:.3f}", flush=True)

    half = args.steps // 2
    print(
        f"\ntask {args.task}, {args.runs} runs, {args.steps} online steps, {N_SOURCE:,} source transitions, "
        f"gradient_steps={args.gradient_steps}, target_update_interval={args.target_update_interval}, "
        f"kappa={args.kappa}, r_max={args.r_max}\n"
    )
    print(f"| method | reward [{half}, {args.steps}) | reward [0, {args.steps}) | greedy after | CPU s/run |")
    print("|---|---|---|---|---|")
    for method, row in results.items():
        print(
            f"| {method} | {mean_and_error(row['last'])} | {mean_and_error(row['all'])} | "
            f"{mean_and_error(row['greedy'])} | {np.mean(row['cpu']):.1f} |"
        )


if __name__ == "__main__":
    main()
