"""Time of one linear FQI refit and of one relabelling, next to naive versions, on a synthetic maze-like set.

The size of one refit in the paper's transfer experiments: 26,000 transitions (25,000 source + 1,000
online), 25 RBF features x 4 actions = 100 features, 1,000 samples of the target task. The transitions are
synthetic (no env, no walls): uniform states in (0, 5)^2, uniform random actions, next state = state + the
action's unit move + Gaussian noise (sd 0.25 across, 0.5 along the move, as in the paper), clipped into
the square; no transition is terminal (the paper's trajectory resets are truncations). The last 1,000 are
the target task tau_11's samples, with rewards 1{cell (1, 1)} + N(0, 1) (eq. 12).

- FQI: ``fit_linear_fqi`` (per-action Gram matrices factored once, only the targets recomputed) against
  ``numpy.linalg.lstsq`` on the whole (n, 100) design matrix of eq. 3-4 at every iteration, for the same
  number of iterations from the same start, both with the bootstrap clip of ``bellman_targets``. Also
  shown: a warm refit with ``LinearFQISolver`` after a change of rewards, the algorithm's steady state, and
  the same refit as ``TRLSD``'s ``LinearPolicy`` runs it (float32 features, ``TRLSD``'s default ``fqi_tol``).
- Relabelling: the ridge head's tracker after 10 new target samples (it folds in only those) against the
  head evaluated from scratch on the 26,000 states (every kernel sum W(s) of eq. 8 over all samples).

Asserts that both versions of each agree (a correctness check); prints medians of ``--repeats`` runs
(``time.perf_counter``) and their ratios, nothing about time is asserted. Usage::

    python benchmarks/bench_fqi.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import inspect
import time
from collections.abc import Callable

import numpy as np

from sb3_trlsd import TRLSD
from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.fqi import LinearFQISolver, bellman_targets, fit_linear_fqi, linear_q_values, return_bounds
from sb3_trlsd.reward_heads import GridCells, RidgeRewardHead

GAMMA = 0.9
COLD_TOL = 1e-6  # the cold and float64 fits below stop at 1e-6, as this benchmark always measured them
MAZE_CELLS = GridCells((0, 0), (5, 5), 5)
N_TRANSITIONS, N_TARGET, N_NEW = 26_000, 1_000, 10
# NORTH, WEST, SOUTH, EAST as in the paper (NORTH decreases y).
MOVES = np.array([[0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])


def median_seconds(function: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def synthetic_transitions(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States (n, 2), actions (n,), next states (n, 2) of the wall-less maze."""
    states = rng.uniform(0, 5, size=(n, 2))
    actions = rng.integers(4, size=n)
    moves = MOVES[actions]
    # sd 0.5 along the move, 0.25 across it
    noise = rng.normal(size=(n, 2)) * np.where(moves != 0, 0.5, 0.25)
    next_states = np.clip(states + moves + noise, 1e-6, 5 - 1e-6)
    return states, actions, next_states


def target_rewards(states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Eq. 12 for tau_11: 1 + N(0, 1) in cell (1, 1), N(0, 1) elsewhere."""
    return (MAZE_CELLS(states) == 0) + rng.normal(size=len(states))


def state_action_features(phi: np.ndarray, actions: np.ndarray, n_actions: int) -> np.ndarray:
    """Phi(s, a) of eq. 3 as written: block a holds Phi(s) on the rows whose action is a, zeros elsewhere."""
    n, k = phi.shape
    blocks = np.zeros((n, n_actions, k))
    blocks[np.arange(n), actions] = phi
    return blocks.reshape(n, n_actions * k)


def naive_linear_fqi(phi, actions, rewards, next_phi, n_actions, iterations) -> np.ndarray:
    """Eq. 4 as written: least squares on the whole block design matrix X = Phi(s, a), each time anew."""
    design = state_action_features(phi, actions, n_actions)  # (n, n_actions * k)
    theta = np.zeros((n_actions, phi.shape[1]))
    bounds = return_bounds(rewards, GAMMA)
    for _ in range(iterations):
        next_q = linear_q_values(next_phi, theta)
        targets = bellman_targets(rewards, next_q, np.zeros(len(rewards), bool), GAMMA, bounds)
        theta = np.linalg.lstsq(design, targets, rcond=None)[0].reshape(n_actions, -1)
    return theta


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats (median reported)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)

    states, actions, next_states = synthetic_transitions(N_TRANSITIONS, rng)
    terminated = np.zeros(N_TRANSITIONS, bool)
    grid = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)  # width 0.2 on the maze
    phi, next_phi = grid(states), grid(next_states)
    head = RidgeRewardHead(grid, kappa=0.1, sigma=0.2)
    target = states[-N_TARGET:]
    head.update(target, target_rewards(target, rng))
    rewards = head.optimistic(states)

    # (a) vs (b). A tiny ridge, so that both solve the same least-squares problem.
    def ours() -> np.ndarray:
        return fit_linear_fqi(
            phi, actions, rewards, next_phi, terminated, n_actions=4, gamma=GAMMA, ridge=1e-9, tol=COLD_TOL
        ).theta

    fit = fit_linear_fqi(
        phi, actions, rewards, next_phi, terminated, n_actions=4, gamma=GAMMA, ridge=1e-9, tol=COLD_TOL
    )
    naive_theta = naive_linear_fqi(phi, actions, rewards, next_phi, 4, fit.iterations)
    assert np.allclose(fit.theta, naive_theta, rtol=1e-6, atol=1e-8 * np.abs(naive_theta).max())
    fqi_seconds = median_seconds(ours, args.repeats)
    naive_fqi_seconds = median_seconds(
        lambda: naive_linear_fqi(phi, actions, rewards, next_phi, 4, fit.iterations), args.repeats
    )

    # The steady state: the solver holds the transitions; a refit after new samples changed the rewards.
    solver = LinearFQISolver(grid.n_features, 4, ridge=1e-9)
    solver.extend(phi, actions, next_phi, terminated)
    previous = solver.fit(rewards, gamma=GAMMA, tol=COLD_TOL)
    shifted = RidgeRewardHead(grid, kappa=0.1, sigma=0.2)
    extra = rng.uniform(0, 5, size=(N_NEW, 2))
    shifted.update(np.vstack([target, extra]), target_rewards(np.vstack([target, extra]), rng))
    new_rewards = shifted.optimistic(states)
    warm = solver.fit(new_rewards, gamma=GAMMA, theta0=previous.theta, tol=COLD_TOL)
    warm_seconds = median_seconds(
        lambda: solver.fit(new_rewards, gamma=GAMMA, theta0=previous.theta, tol=COLD_TOL), args.repeats
    )

    # The same refit as TRLSD's LinearPolicy does it: float32 features, TRLSD's default tolerance.
    tol = inspect.signature(TRLSD).parameters["fqi_tol"].default
    policy_solver = LinearFQISolver(grid.n_features, 4, ridge=1e-9, dtype=np.float32)
    policy_solver.extend(phi, actions, next_phi, terminated)
    policy_previous = policy_solver.fit(rewards, gamma=GAMMA, tol=tol)
    policy_warm = policy_solver.fit(new_rewards, gamma=GAMMA, theta0=policy_previous.theta, tol=tol)
    policy_warm_seconds = median_seconds(
        lambda: policy_solver.fit(new_rewards, gamma=GAMMA, theta0=policy_previous.theta, tol=tol),
        args.repeats,
    )

    # (c) vs (d): each repeat adds 10 target samples, then relabels the 26,000 start states.
    tracker = head.tracker(states)
    tracker.optimistic()
    relabel_times = []
    for _ in range(args.repeats):
        new = rng.uniform(0, 5, size=(N_NEW, 2))
        head.update(new, target_rewards(new, rng))
        start = time.perf_counter()
        relabelled = tracker.optimistic()
        relabel_times.append(time.perf_counter() - start)
    relabel_seconds = float(np.median(relabel_times))
    assert np.allclose(relabelled, head.optimistic(states), rtol=1e-10)
    naive_relabel_seconds = median_seconds(lambda: head.optimistic(states), args.repeats)

    print(
        f"{N_TRANSITIONS:,} synthetic transitions, 100 features (25 RBF x 4 actions), "
        f"{N_TARGET:,} target samples, gamma {GAMMA}, median of {args.repeats}"
    )
    print("| step | sb3-trlsd | naive | speed-up |")
    print("|---|---|---|---|")
    print(
        f"| one cold linear FQI fit ({fit.iterations} iterations) | {fqi_seconds * 1e3:.1f} ms "
        f"| {naive_fqi_seconds * 1e3:.0f} ms (lstsq) | {naive_fqi_seconds / fqi_seconds:.0f}x |"
    )
    print(
        f"| warm LinearFQISolver refit, rewards changed ({warm.iterations} iterations) "
        f"| {warm_seconds * 1e3:.1f} ms | | |"
    )
    print(
        f"| the same refit as TRLSD does it: float32 features, tol {tol:g} ({policy_warm.iterations} "
        f"iterations) | {policy_warm_seconds * 1e3:.1f} ms | | |"
    )
    print(
        f"| one relabelling after {N_NEW} new samples | {relabel_seconds * 1e3:.2f} ms "
        f"| {naive_relabel_seconds * 1e3:.1f} ms (from scratch) "
        f"| {naive_relabel_seconds / relabel_seconds:.0f}x |"
    )


if __name__ == "__main__":
    main()
