"""Greedy policies of linear FQI on each feature map, on point-goal envs of several shapes, scales and dims.

Each env is a box with 2 d actions, a step of +-``step[i]`` along dimension i with Gaussian noise (sd a
fifth of the step), clipped into the box; the reward of a goal g is the Gaussian bump
exp(-sum_i ((s'_i - g_i) / rho_i)^2 / 2) of the state reached, nothing is terminal. For each map: 25,000
uniform random transitions (the paper's source set), linear FQI (``LinearFQISolver``, the library's
defaults) on the known reward of each of ``--goals`` goals, then the greedy policy from 100 uniform starts
for 80 steps. Its discounted return J is reported as the share of the way from the random policy's to a
one-step-lookahead oracle's (the action whose mean next state has the largest reward): 1 is the oracle, 0
random. Also shown: the number of features k and the time of one cold fit.

The envs: ``square`` (10 x 10, steps 0.5), ``floor`` (20 m x 5 m, the same steps in metres), ``mixed4``
(sides 1, 10, 100 and 0.1, steps and goals a share of each), ``cube6`` and ``cube8``. Point-goal tasks
without obstacles suit additive features (each action moves one dimension towards the goal, whatever the
others); an env whose Q depends on how the dimensions interact (walls) would favour the grid more.

Measured (seed 0, 3 goals; quality, k; "-": not run; fits capped at 200 iterations, which the Fourier
features and the narrower grids in 4-D reach)::

    map                              square      floor       mixed4      cube6       cube8
    "paper"                          0.69   25   0.32   25   0.04  200  -0.00  300  -0.00  400
    rbf 5/dim, sigma 0.2 of the box  0.93   25   0.88   25   -           -           -
    rbf "cube" <= 150, overlap 1.0   0.88  144   0.93  144   0.36  144   -           -
    rbf "cube" <= 150, overlap 1.5   0.99  144   0.99  144   0.92  144   -           -
    rbf "cube" <= 150, overlap 2.0   1.00  144   0.99  144   0.88  144   -           -
    rbf "box" <= 150, overlap 1.0    0.88  144   0.89  150   0.19  144   -           -
    rbf 2/dim, overlap 1.0           -           -           -           0.06   64   0.14  256
    additive <= 150, overlap 1.0     0.97  150   0.97  150   -           0.68  150   0.40  150
    additive <= 150, overlap 1.5     0.98  150   0.97  150   0.83  150   0.67  150   0.39  150
    additive <= 150, overlap 2.0     0.98  150   0.98  150   -           0.69  150   0.37  150
    additive 8/dim, overlap 1.5      0.99   16   0.98   16   0.88   32   0.72   48   0.43   64
    fourier m <= 150, sigma default  -0.04 100   -0.01 100   0.12  150   0.00  150   0.00  150
    fourier m <= 150, sigma 0.3      0.70  100   0.56  100   0.63  150   0.26  150   0.04  150
    fourier m <= 150, sigma 0.5      0.32  100   0.47  100   0.61  150   0.33  150   0.61  150
    fourier m <= 150, sigma 1.0      -           -           -           0.31  150   0.28  150

``make_feature_map("auto", ...)`` is the "rbf cube <= 64, overlap 1.5" map up to 3-D (8 x 8 in 2-D: within
0.02 of the "<= 150" row on square, floor and mixed4 at a third to a tenth of its fit's time, 2 goals)
and the "additive 8/dim" row from 4-D on (as many per dimension as 64 features allow beyond 8-D).

Usage::

    nice -n 10 python benchmarks/bench_feature_maps.py [--goals 3] [--envs square floor mixed4 cube8]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from sb3_trlsd.feature_choice import make_feature_map
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.fqi import LinearFQISolver

GAMMA = 0.95
N_TRANSITIONS, N_STARTS, HORIZON = 25_000, 100, 80
MAX_ITERATIONS = 200  # gamma^200 ~ 4e-5: enough for the greedy policy; the cap a slow fit reaches


@dataclass(frozen=True)
class PointGoal:
    """A point-goal env: box [low, high], steps per dimension, reward widths rho per dimension."""

    low: np.ndarray
    high: np.ndarray
    step: np.ndarray
    rho: np.ndarray

    @property
    def dims(self) -> int:
        return len(self.low)

    @property
    def moves(self) -> np.ndarray:
        """(2 d, d): +step_i, then -step_i, for each dimension i."""
        eye = np.eye(self.dims) * self.step
        return np.concatenate([eye, -eye])

    def next_states(self, states: np.ndarray, actions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        noise = rng.standard_normal(states.shape) * self.step / 5
        return np.clip(states + self.moves[actions] + noise, self.low, self.high)

    def reward(self, states: np.ndarray, goal: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * (((states - goal) / self.rho) ** 2).sum(-1))

    def uniform(self, n: int, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        span = self.high - self.low
        return rng.uniform(self.low + margin * span, self.high - margin * span, size=(n, self.dims))


def cube_env(dims: int, side: float = 1.0) -> PointGoal:
    low, high = np.zeros(dims), np.full(dims, side)
    return PointGoal(low, high, 0.06 * (high - low), 0.12 * (high - low) * np.sqrt(dims / 2))


ENVS = {
    # A 10 x 10 square in its own units: steps of 0.5, a goal of radius ~0.75.
    "square": PointGoal(np.zeros(2), np.full(2, 10.0), np.full(2, 0.5), np.full(2, 0.75)),
    # A 20 m x 5 m floor: the same steps and goals in metres, a 4:1 box.
    "floor": PointGoal(np.zeros(2), np.array([20.0, 5.0]), np.full(2, 0.5), np.full(2, 0.75)),
    # Four dimensions of unrelated units and scales (1, 10, 100, 0.1): steps and goals a share of each side.
    "mixed4": PointGoal(
        np.array([0.0, -5.0, 0.0, 0.0]),
        np.array([1.0, 5.0, 100.0, 0.1]),
        0.06 * np.array([1.0, 10.0, 100.0, 0.1]),
        0.17 * np.array([1.0, 10.0, 100.0, 0.1]),
    ),
    "cube6": cube_env(6, side=2.0),
    "cube8": cube_env(8),
}


def candidate_maps(env: PointGoal) -> dict[str, dict]:
    """make_feature_map arguments by label: today's maps, then the candidates (a grid only up to 4-D)."""
    maps = {
        "paper": {"kind": "paper"},
        "auto": {"kind": "auto"},
    }
    if env.dims <= 4:
        maps |= {
            "rbf 5/dim, sigma 0.2": {"kind": "rbf", "rbf_per_dim": 5, "rbf_sigma": 0.2},
            **{
                f"rbf cube<=150, overlap {c}": {
                    "kind": "rbf",
                    "rbf_per_dim": "cube",
                    "max_features": 150,
                    "rbf_overlap": c,
                }
                for c in (1.0, 1.5, 2.0)
            },
            "rbf cube<=64, overlap 1.5": {
                "kind": "rbf",
                "rbf_per_dim": "cube",
                "max_features": 64,
                "rbf_overlap": 1.5,
            },
            "rbf box<=150, overlap 1.0": {
                "kind": "rbf",
                "rbf_per_dim": "box",
                "max_features": 150,
                "rbf_overlap": 1.0,
            },
        }
    else:
        maps["rbf 2/dim, overlap 1.0"] = {"kind": "rbf", "rbf_per_dim": 2, "rbf_overlap": 1.0}
    maps |= {
        **{
            f"additive cube<=150, overlap {c}": {"kind": "additive", "max_features": 150, "rbf_overlap": c}
            for c in (1.0, 1.5, 2.0)
        },
        "additive 8/dim, overlap 1.5": {"kind": "additive", "rbf_per_dim": 8, "rbf_overlap": 1.5},
        "fourier m<=150": {"kind": "fourier", "max_features": 150},
        "fourier m<=150, sigma 0.3": {"kind": "fourier", "max_features": 150, "rbf_sigma": 0.3},
        "fourier m<=150, sigma 0.5": {"kind": "fourier", "max_features": 150, "rbf_sigma": 0.5},
        "fourier m<=150, sigma 1.0": {"kind": "fourier", "max_features": 150, "rbf_sigma": 1.0},
    }
    return maps


def rollout(env: PointGoal, goal: np.ndarray, choose, starts: np.ndarray, seed: int) -> float:
    """Mean discounted return of a policy choose(states, rng) -> actions from the starts."""
    rng = np.random.default_rng(seed)
    states, total = starts.copy(), np.zeros(len(starts))
    for t in range(HORIZON):
        states = env.next_states(states, choose(states, rng), rng)
        total += GAMMA**t * env.reward(states, goal)
    return float(total.mean())


def evaluate(env: PointGoal, kwargs: dict, goals: np.ndarray, seed: int) -> tuple[float, int, float, float]:
    """Mean normalised return over the goals, k, median seconds and mean iterations of a cold fit."""
    kwargs = dict(kwargs)
    features: FeatureMap = make_feature_map(
        kwargs.pop("kind"), env.low, env.high, n_actions=2 * env.dims, **kwargs
    )
    rng = np.random.default_rng(seed)
    states = env.uniform(N_TRANSITIONS, rng)
    actions = rng.integers(2 * env.dims, size=N_TRANSITIONS)
    next_states = env.next_states(states, actions, rng)
    solver = LinearFQISolver(features.n_features, 2 * env.dims)
    solver.extend(features(states), actions, features(next_states), np.zeros(N_TRANSITIONS, dtype=bool))
    scores, seconds, iterations = [], [], []
    for g, goal in enumerate(goals):
        start = time.perf_counter()
        result = solver.fit(env.reward(next_states, goal), gamma=GAMMA, max_iterations=MAX_ITERATIONS)
        seconds.append(time.perf_counter() - start)
        iterations.append(result.iterations)
        theta = result.theta
        policies = (
            lambda s, _, theta=theta: np.argmax(features(s) @ theta.T, axis=1),  # greedy
            lambda s, _, goal=goal: np.argmax(env.reward(s[:, None, :] + env.moves[None], goal), axis=1),
            lambda s, rng: rng.integers(2 * env.dims, size=len(s)),  # uniform random
        )
        starts = env.uniform(N_STARTS, np.random.default_rng(seed + 100 + g))
        greedy, oracle, uniform = (rollout(env, goal, p, starts, seed + 200 + g) for p in policies)
        scores.append((greedy - uniform) / (oracle - uniform))
    return float(np.mean(scores)), features.n_features, float(np.median(seconds)), float(np.mean(iterations))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--goals", type=int, default=3)
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("--maps", nargs="*", default=None, help="labels of the maps (default: all)")
    args = parser.parse_args()
    for name in args.envs:
        env = ENVS[name]
        goals = env.uniform(args.goals, np.random.default_rng(7), margin=0.1)
        print(f"\n{name}: {env.dims}-D box {env.low.tolist()} .. {env.high.tolist()}, {2 * env.dims} actions")
        for label, kwargs in candidate_maps(env).items():
            if args.maps and label not in args.maps:
                continue
            try:
                score, k, seconds, iterations = evaluate(env, kwargs, goals, seed=0)
            except ValueError as error:
                print(f"  {label:34s} refused: {error}")
                continue
            print(
                f"  {label:34s} quality {score:6.3f}  k {k:4d}  fit {1000 * seconds:7.1f} ms"
                f" ({iterations:3.0f} iterations)",
                flush=True,
            )


if __name__ == "__main__":
    main()
