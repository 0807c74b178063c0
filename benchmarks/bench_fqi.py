"""Time of one linear FQI refit and of one relabelling, next to naive versions in the same run.

The size of one refit in the paper's transfer experiments: 26,000 transitions (25,000 source + 1,000
online), 25 RBF features x 4 actions = 100 features, 1,000 samples of the target task.

- FQI: ``fit_linear_fqi`` (per-action Gram matrices factored once, targets only recomputed) against
  ``numpy.linalg.lstsq`` on the whole (n, 100) design matrix of eq. 3-4 at every iteration, for the same
  number of iterations, from the same start.
- Relabelling: the ridge head's tracker after 10 new target samples (it folds in only those) against
  recomputing every kernel sum W(s) of eq. 8 from the 1,010 samples.

Asserts that both versions agree; prints medians of ``--repeats`` runs and their ratios. Usage::

    python benchmarks/bench_fqi.py
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

from envs import MAZE_ID
from sb3_trlsd import RBFGrid, RidgeRewardHead, collect_transitions
from sb3_trlsd.features import gaussian_similarity, state_action_features
from sb3_trlsd.fqi import bellman_targets, fit_linear_fqi, linear_q_values, return_bounds

GAMMA = 0.9


def median_seconds(function: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def naive_linear_fqi(phi, actions, rewards, next_phi, n_actions, iterations) -> np.ndarray:
    """Eq. 4 as written: least squares on the whole block design matrix X = Phi(s, a), each time anew."""
    design = state_action_features(phi, actions, n_actions)  # (n, n_actions * k)
    theta = np.zeros((n_actions, phi.shape[1]))
    bounds = return_bounds(rewards, GAMMA)
    for _ in range(iterations):
        targets = bellman_targets(
            rewards, linear_q_values(next_phi, theta), np.zeros(len(rewards), bool), GAMMA, bounds
        )
        theta = np.linalg.lstsq(design, targets, rcond=None)[0].reshape(n_actions, -1)
    return theta


def naive_relabel(head: RidgeRewardHead, sample_states: np.ndarray, states: np.ndarray) -> np.ndarray:
    """R~ with every kernel sum recomputed from all samples."""
    weights = gaussian_similarity(states, sample_states, head.sigma).sum(axis=1)
    width = np.sqrt(np.log(len(sample_states)) / np.maximum(weights, head.w_floor))
    return head.estimate(states) + head.kappa * width


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats (median reported)")
    args = parser.parse_args()

    data = collect_transitions(gym.make(MAZE_ID, task=(1, 1)), n_transitions=26_000, seed=0)
    grid = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.2)
    phi, next_phi = grid(data.states), grid(data.next_states)
    target = data.states[-1_010:]
    head = RidgeRewardHead(grid, kappa=0.1, sigma=0.2)
    head.update(target[:1_000], data.rewards[-1_010:-10])
    rewards = head.optimistic(data.states)

    # Tiny ridge so that both solve the same least-squares problem.
    fit = fit_linear_fqi(
        phi, data.actions, rewards, next_phi, data.terminations, n_actions=4, gamma=GAMMA, ridge=1e-9
    )
    naive_theta = naive_linear_fqi(phi, data.actions, rewards, next_phi, 4, fit.iterations)
    assert np.allclose(fit.theta, naive_theta, rtol=1e-5, atol=1e-6 * np.abs(naive_theta).max())
    fqi_seconds = median_seconds(
        lambda: fit_linear_fqi(
            phi, data.actions, rewards, next_phi, data.terminations, n_actions=4, gamma=GAMMA, ridge=1e-9
        ),
        args.repeats,
    )
    naive_fqi_seconds = median_seconds(
        lambda: naive_linear_fqi(phi, data.actions, rewards, next_phi, 4, fit.iterations), args.repeats
    )

    def relabel_after_ten_new_samples() -> tuple[np.ndarray, float]:
        """A tracker that has seen 1,000 samples relabels after 10 more: (rewards, seconds)."""
        fresh = RidgeRewardHead(grid, kappa=0.1, sigma=0.2)
        fresh.update(target[:1_000], data.rewards[-1_010:-10])
        tracker = fresh.tracker(data.states)
        fresh.update(target[1_000:], data.rewards[-10:])
        start = time.perf_counter()
        relabelled = tracker.optimistic()
        return relabelled, time.perf_counter() - start

    incremental, _ = relabel_after_ten_new_samples()
    head.update(target[1_000:], data.rewards[-10:])
    assert np.allclose(incremental, naive_relabel(head, target, data.states), rtol=1e-9)
    relabel_seconds = float(np.median([relabel_after_ten_new_samples()[1] for _ in range(args.repeats)]))
    naive_relabel_seconds = median_seconds(lambda: naive_relabel(head, target, data.states), args.repeats)

    print(
        f"26,000 transitions, 100 features (25 RBF x 4 actions), 1,010 target samples, {args.repeats} repeats"
    )
    print("| step | sb3-trlsd | naive | speed-up |")
    print("|---|---|---|---|")
    print(
        f"| one linear FQI refit ({fit.iterations} iterations) | {fqi_seconds * 1e3:.1f} ms "
        f"| {naive_fqi_seconds * 1e3:.1f} ms | {naive_fqi_seconds / fqi_seconds:.1f}x |"
    )
    print(
        f"| one relabelling after 10 new samples | {relabel_seconds * 1e3:.2f} ms "
        f"| {naive_relabel_seconds * 1e3:.1f} ms | {naive_relabel_seconds / relabel_seconds:.1f}x |"
    )


if __name__ == "__main__":
    main()
