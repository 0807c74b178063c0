"""Seconds per run of Figure 5's optimistic continuous setting: the experiments' fast path next to a
straightforward numpy implementation of the same algorithm, in the same process, and the time of Figure 5.

The straightforward version refits everything at every policy update: RBF features of all 26,000
transitions, the ridge reward regression, every kernel sum W(s) of eq. 8, the per-action Gram matrices,
and FQI from theta = 0. It acts on the same env with the same seeds and the same trigger (section 3), so
its runs are comparable (the mean rewards are printed next to each other as a sanity check), but not
identical: a cold FQI start stops at a slightly different theta.

The fast path (``sb3_trlsd.experiments.runner.transfer_run``) is ``TRLSD`` itself driven without SB3's
rollout machinery: features and per-action Grams kept across refits, kernel sums folded in as samples
arrive, FQI warm-started. Nothing about time is asserted. Usage::

    python benchmarks/bench_reproduce.py [--runs 5] [--full-fig5 --workers 2]

``--full-fig5`` also runs the whole Figure 5 at the paper's size (500 runs of each of its 6 methods) and
prints its wall time; otherwise that time is estimated from the seconds per run measured here.
"""

from __future__ import annotations

import argparse
import inspect
import tempfile
import time

import gymnasium as gym
import numpy as np
from threadpoolctl import threadpool_limits

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd.experiments import reproduce
from sb3_trlsd.experiments.runner import Method, transfer_run
from sb3_trlsd.experiments.transfer import DEFAULT_RUNS, METHODS
from sb3_trlsd.features import gaussian_similarity, grid_centres
from sb3_trlsd_envs import MAZE_ID, expected_reward

GAMMA, KAPPA, SIGMA, RBF_SIGMA, UPDATE_RATIO, RIDGE = 0.9, 0.1, 0.2, 0.2, 2.0, 1e-3
TOL = inspect.signature(TRLSD).parameters["fqi_tol"].default  # the same stopping rule as the fast path


def rbf_features(states: np.ndarray, centres: np.ndarray, sigma: float) -> np.ndarray:
    """phi_ij(s) = exp(-||s - s_ij||^2 / 2 sigma^2) for every centre (eq. 11), one exponential per centre."""
    return gaussian_similarity(states, centres, sigma)


def straightforward_run(
    task: int, seed: int, n_source: int = 25_000, n_online: int = 1_000
) -> tuple[float, int]:
    """One optimistic continuous run, refitting everything at every update: (mean reward, updates)."""
    env = gym.make(MAZE_ID, task=task)
    source_env = gym.make(MAZE_ID, task=(task + 1 + seed) % 25)
    source = collect_transitions(source_env, n_source, seed=seed + 1)
    states, actions, next_states = list(source.states), list(source.actions), list(source.next_states)
    centres = grid_centres(np.zeros(2), np.full(2, 5.0), 5)
    samples, sample_rewards = [], []
    theta = np.zeros((4, 25))
    uncertainty_at_update = None
    updates, rewards = 0, []

    def uncertainty(points: np.ndarray) -> np.ndarray:
        # sqrt(log |Xi_tau| / W_tau(s)) (eq. 8-9 without kappa), every kernel sum from scratch
        if not samples:
            return np.full(len(points), np.inf)
        distances = ((points[:, None, :] - np.array(samples)[None]) ** 2).sum(axis=-1)
        weights = np.exp(-distances / (2 * SIGMA**2)).sum(axis=1)
        return np.sqrt(np.log(max(len(samples), 2)) / np.maximum(weights, 1e-6))

    def update() -> np.ndarray:
        s, a, s2 = np.array(states), np.array(actions), np.array(next_states)
        phi, next_phi = rbf_features(s, centres, RBF_SIGMA), rbf_features(s2, centres, RBF_SIGMA)
        if samples:
            x = rbf_features(np.array(samples), centres, RBF_SIGMA)
            w = np.linalg.solve(x.T @ x + np.eye(25), x.T @ np.array(sample_rewards))  # ridge, lambda = 1
            r = phi @ w + KAPPA * uncertainty(s)
        else:
            r = np.full(len(s), KAPPA * np.sqrt(np.log(2) / 1e-6))
        high = max(r.max(), 0) / (1 - GAMMA)
        new = np.zeros((4, 25))
        for _ in range(500):
            y = r + GAMMA * np.clip((next_phi @ new.T).max(axis=1), min(r.min(), 0) / (1 - GAMMA), high)
            previous = new.copy()
            for action in range(4):
                rows = a == action
                new[action] = np.linalg.solve(
                    phi[rows].T @ phi[rows] + RIDGE * np.eye(25), phi[rows].T @ y[rows]
                )
            if np.abs(new - previous).max() <= TOL * (1 + np.abs(new).max()):
                break
        return new

    obs, _ = env.reset(seed=seed)
    for step in range(n_online):
        state = obs["state"].astype(np.float64)
        if step == 0:
            theta, uncertainty_at_update, updates = update(), list(samples), 1
        action = int((rbf_features(state[None], centres, RBF_SIGMA) @ theta.T).argmax())
        next_obs, reward, terminated, truncated, _ = env.step(action)
        rewards.append(expected_reward(state[None], task)[0])
        states.append(state)
        actions.append(action)
        next_states.append(next_obs["state"].astype(np.float64))
        samples.append(state)
        sample_rewards.append(float(np.float32(reward)))
        then = _uncertainty_with(uncertainty_at_update, state)
        if then > 0 and then >= UPDATE_RATIO * uncertainty(state[None])[0]:
            theta, uncertainty_at_update, updates = update(), list(samples), updates + 1
        obs = env.reset()[0] if terminated or truncated else next_obs
    return float(np.mean(rewards)), updates


def _uncertainty_with(samples: list[np.ndarray], state: np.ndarray) -> float:
    """The kappa-free uncertainty at ``state`` given the samples of the last update."""
    if not samples:
        return np.inf
    weights = np.exp(-((np.array(samples) - state) ** 2).sum(axis=1) / (2 * SIGMA**2)).sum()
    return float(np.sqrt(np.log(max(len(samples), 2)) / max(weights, 1e-6)))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=5, help="runs of each implementation (tasks in turn)")
    parser.add_argument("--full-fig5", action="store_true", help="also run the whole Figure 5 and time it")
    parser.add_argument("--workers", type=int, default=2, help="processes for --full-fig5")
    args = parser.parse_args()

    method = Method("continuous, ratio 2")
    fast, naive = [], []
    with threadpool_limits(1):  # as in the experiments' workers
        for run in range(args.runs):
            task = (run * 7) % 25
            start = time.perf_counter()
            record = transfer_run(method, task, seed=run)
            fast.append((time.perf_counter() - start, record.rewards.mean(), record.policy_updates))
            start = time.perf_counter()
            reward, updates = straightforward_run(task, seed=run)
            naive.append((time.perf_counter() - start, reward, updates))
    fast_s, naive_s = np.mean([f[0] for f in fast]), np.mean([n[0] for n in naive])
    print(f"Figure 5, optimistic continuous setting, {args.runs} runs each, 25,000 + 1,000 transitions\n")
    print("| implementation | s / run | mean reward | policy updates |")
    print("|---|---|---|---|")
    for name, rows in (("sb3-trlsd fast path", fast), ("straightforward numpy", naive)):
        print(
            f"| {name} | {np.mean([r[0] for r in rows]):.2f} | {np.mean([r[1] for r in rows]):.3f} "
            f"| {np.mean([r[2] for r in rows]):.1f} |"
        )
    print(f"\nspeed-up: {naive_s / fast_s:.1f}x")
    n_runs = DEFAULT_RUNS * len(METHODS)
    if args.full_fig5:
        with tempfile.TemporaryDirectory() as out:
            data = reproduce("fig5", out, workers=args.workers)
        print(
            f"full Figure 5 ({n_runs} runs, {args.workers} workers): {data['wall_time_seconds'] / 60:.1f} min"
        )
    else:
        print(
            f"full Figure 5 ({n_runs} runs) estimated at {fast_s * n_runs / args.workers / 60:.0f} min with "
            f"{args.workers} workers if every run cost an optimistic continuous one (--full-fig5 measures it)"
        )


if __name__ == "__main__":
    main()
