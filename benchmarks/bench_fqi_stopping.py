"""Iterations, time and accuracy of linear FQI's stopping rules, on the maze and off it.

Three synthetic sets of transitions, no env (uniform states, random actions, deterministic moves plus noise,
a reward bump, gamma 0.9, no terminal transition), fitted with float32 features as ``TRLSD``'s
``LinearPolicy`` fits them:

- maze: the paper's size, 26,000 rows on (0, 5)^2, moves of 1 (noise sd 0.5 along, 0.25 across), its 5 x 5
  RBFs of width 0.2; reward 1 in cell (1, 1);
- rbf-2d: 20,000 rows on the unit square, moves of 0.05 (noise sd 0.01), 10 x 10 RBFs of width 0.1, which
  overlap (Gram matrices' condition number ~1e6); reward bump exp(-|s - (0.8, 0.8)|^2 / 0.02);
- fourier-7d: 20,000 rows on the unit 7-cube, 6 actions moving 0.05 along random directions, the 350
  random Fourier features of ``make_feature_map("auto", ...)``; the same bump on the first two coordinates.

For each, a cold fit (theta0 = 0) and a warm refit (from the cold fit, rewards moved by 1 % noise) by
the ``"theta"`` rule (the default) at tol 1e-4 and the ``"targets"`` rule at 1e-4 and 1e-5, cap 500. The
distance is max |max_a Q(s', a) - max_a Q*(s', a)| over the rows relative to the return scale (high - low of
``return_bounds``), Q* from a float64 fit run to a targets change of 1e-9. Prints a Markdown table (median
of ``--repeats`` timings); nothing about time is asserted. Usage::

    python benchmarks/bench_fqi_stopping.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from sb3_trlsd.feature_choice import make_feature_map
from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.fqi import FQICapWarning, LinearFQISolver, return_bounds

GAMMA, TOL, CAP = 0.9, 1e-4, 500
MOVES = np.array([[0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])


def maze(rng: np.random.Generator):
    n = 26_000
    states, actions = rng.uniform(0, 5, size=(n, 2)), rng.integers(4, size=n)
    moves = MOVES[actions]
    noise = rng.normal(size=(n, 2)) * np.where(moves != 0, 0.5, 0.25)
    next_states = np.clip(states + moves + noise, 1e-6, 5 - 1e-6)
    grid = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)
    rewards = ((states[:, 0] < 1) & (states[:, 1] < 1)).astype(float)
    return grid(states), actions, rewards, grid(next_states), 4


def bump(states: np.ndarray) -> np.ndarray:
    return np.exp(-np.sum((states[:, :2] - 0.8) ** 2, axis=1) / (2 * 0.1**2))


def rbf_2d(rng: np.random.Generator):
    n = 20_000
    states, actions = rng.uniform(size=(n, 2)), rng.integers(4, size=n)
    next_states = np.clip(states + 0.05 * MOVES[actions] + 0.01 * rng.normal(size=(n, 2)), 0, 1)
    grid = RBFGrid(low=(0, 0), high=(1, 1), n_per_dim=10, sigma=0.1)
    return grid(states), actions, bump(states), grid(next_states), 4


def fourier_7d(rng: np.random.Generator):
    n, d, n_actions = 20_000, 7, 6
    states, actions = rng.uniform(size=(n, d)), rng.integers(n_actions, size=n)
    directions = rng.normal(size=(n_actions, d))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    next_states = np.clip(states + 0.05 * directions[actions] + 0.01 * rng.normal(size=(n, d)), 0, 1)
    features = make_feature_map("auto", (0,) * d, (1,) * d, n_actions=n_actions)
    return features(states), actions, bump(states), features(next_states), n_actions


def solver_of(phi, actions, next_phi, n_actions, dtype) -> LinearFQISolver:
    solver = LinearFQISolver(phi.shape[1], n_actions, dtype=dtype)
    solver.extend(phi, actions, next_phi, np.zeros(len(phi), bool))
    return solver


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats (median reported)")
    args = parser.parse_args()
    warnings.simplefilter("ignore", FQICapWarning)  # the table's "converged" column says it
    print(f"gamma {GAMMA}, cap {CAP}, float32 features, median of {args.repeats}")
    print("| case | fit | rule, tol | iterations | converged | ms per fit | vs theta | distance to Q* |")
    print("|---|---|---|---|---|---|---|---|")
    for name, make in (("maze", maze), ("rbf-2d", rbf_2d), ("fourier-7d", fourier_7d)):
        rng = np.random.default_rng(0)
        phi, actions, rewards, next_phi, n_actions = make(rng)
        moved = rewards + 0.01 * rng.normal(size=len(rewards))
        solver = solver_of(phi, actions, next_phi, n_actions, np.float32)
        exact = solver_of(phi, actions, next_phi, n_actions, np.float64)
        cold = solver.fit(rewards, gamma=GAMMA, tol=TOL, max_iterations=CAP, stop_rule="targets").theta
        for fit, fit_rewards, theta0 in (("cold", rewards, None), ("warm", moved, cold)):
            reference = exact.fit(
                fit_rewards, gamma=GAMMA, tol=1e-9, max_iterations=3000, stop_rule="targets"
            )
            v_star = (next_phi @ reference.theta.T).max(axis=1)
            low, high = return_bounds(fit_rewards, GAMMA)
            seconds = {}
            for rule, tol in (("theta", TOL), ("targets", TOL), ("targets", TOL / 10)):
                times = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    result = solver.fit(
                        fit_rewards, gamma=GAMMA, theta0=theta0, tol=tol, max_iterations=CAP, stop_rule=rule
                    )
                    times.append(time.perf_counter() - start)
                seconds[rule, tol] = float(np.median(times))
                distance = np.abs((next_phi @ result.theta.T).max(axis=1) - v_star).max() / (high - low)
                converged = "yes" if result.converged else "no"
                print(
                    f"| {name} | {fit} | {rule} {tol:g} | {result.iterations} | {converged} "
                    f"| {seconds[rule, tol] * 1e3:.0f} | {seconds[rule, tol] / seconds['theta', TOL]:.2f}x "
                    f"| {distance:.1e} |"
                )


if __name__ == "__main__":
    main()
