"""Why posterior draws of the reward (``reward_head="thompson"``) explore over a source and not without one.

Fitted-Q is fitted on the buffer's rows only: a reward head's optimism reaches the Q-function through the
rows it relabels. Over a source that covers the dynamics, the draws make unvisited places plausible
rewards and the greedy policy goes to try them. Learning from scratch, the buffer holds only what the
agent has visited: the draws give those rows small rewards of either sign, the rows it has not visited
stay at Fitted-Q's initial 0, and the greedy policy stays among the visited rows whose draw is positive.
The ridge head without optimism gives every row exactly 0 until a reward is met, every
action ties, and the random tie-break walks the grid; the bonus of eq. 9 (``"ridge_posterior"``) is
positive on every row, largest on the rows seen least. ``optimism="with_source"`` relabels with the draws
only once the buffer holds rows the task did not collect, and R^ until then: the defaults, with draws
in units of the largest reward seen.

This runs each head on a W x H grid of integers (reward 1 on the far corner, the start in the other,
30-step episodes, ``learn(600)``), with no source or with random transitions over the whole grid (their
rewards discarded), and prints the steps paid to the greedy policy in one 30-step episode after learning,
per seed. A comparison, not a test. Usage::

    python benchmarks/bench_reward_heads.py [--seeds 8] [--grid 6 4] [--source 1000]
"""

from __future__ import annotations

import argparse
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback

from sb3_trlsd import TRLSD, Transitions
from sb3_trlsd_lab.execution.protocols import paper_relabelling

MOVES = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])
DRAWS_IN_REWARD_UNITS = paper_relabelling("thompson")
HEADS: dict[str, dict[str, Any]] = {  # name -> TRLSD settings
    "ridge, kappa = 0": {"reward_head": "ridge"},
    "ridge_posterior, kappa = 0.003": {"reward_head": "ridge_posterior", "kappa": 0.003},
    "thompson, kappa = 0.003": {**DRAWS_IN_REWARD_UNITS, "kappa": 0.003},
    "thompson, kappa = 0.003, redrawn each episode": {**DRAWS_IN_REWARD_UNITS, "kappa": 0.003},
    "thompson, kappa = 0.01 of the largest reward, optimism with_source (the defaults)": {},
}


class Grid(gym.Env):
    """A W x H grid whose states are a Box of integers, from (0, 0), the reward 1 on the far corner."""

    action_space = spaces.Discrete(4)

    def __init__(self, width: int, height: int):
        self.corner = np.array([width - 1, height - 1])
        self.observation_space = spaces.Box(0, self.corner, dtype=np.int64)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.cell = np.zeros(2, dtype=np.int64)
        return self.cell.copy(), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.cell = np.clip(self.cell + MOVES[action], 0, self.corner)
        return self.cell.copy(), float(np.all(self.cell == self.corner)), False, False, {}


class RedrawEachEpisode(BaseCallback):
    """A new draw of the reward and a refit at the end of each episode, as PSRL draws once per episode."""

    def _on_step(self) -> bool:
        if self.locals["dones"][0]:
            self.model.task_learner(0).head.resample()
            self.model.update_policy(0)
        return True


def random_source(corner: np.ndarray, n: int, seed: int) -> Transitions:
    """n random transitions from uniformly random cells, rewards 0 (the buffer discards them anyway)."""
    rng = np.random.default_rng(seed)
    states = rng.integers(0, corner + 1, size=(n, 2))
    actions = rng.integers(0, 4, size=n)
    next_states = np.clip(states + MOVES[actions], 0, corner)
    zeros = np.zeros(n, dtype=bool)
    return Transitions(states, actions, next_states, np.zeros(n), np.zeros(n, dtype=np.int64), zeros, zeros)


def paid_steps(head: str, grid: tuple[int, int], n_source: int, seed: int, steps: int) -> int:
    """Steps paid to the greedy policy in one 30-step episode after ``learn(steps)``."""
    env = Grid(*grid)
    model = TRLSD("LinearPolicy", gym.wrappers.TimeLimit(env, 30), seed=seed, **HEADS[head])
    if n_source:
        model.load_transitions(random_source(env.corner, n_source, seed))
    model.learn(steps, callback=RedrawEachEpisode() if "redrawn" in head else None)
    state, _ = env.reset()
    paid = 0
    for _ in range(30):
        action, _ = model.predict(state, deterministic=True)
        state, reward, *_ = env.step(int(action))
        paid += int(reward)
    return paid


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=8, help="seeds 0..N-1 per head and source")
    parser.add_argument("--grid", type=int, nargs=2, default=(6, 4), metavar=("W", "H"), help="grid size")
    parser.add_argument("--source", type=int, default=1000, help="random source transitions")
    parser.add_argument("--steps", type=int, default=600, help="online steps")
    args = parser.parse_args()

    grid = tuple(args.grid)
    print(
        f"{grid[0]} x {grid[1]} grid, learn({args.steps}); steps paid in 30 to the greedy policy, seeds 0-"
        f"{args.seeds - 1}\n"
    )
    print("| head | source | paid steps per seed | seeds that reach the corner |")
    print("|---|---|---|---|")
    for head in HEADS:
        for n_source in (0, args.source):
            paid = [paid_steps(head, grid, n_source, seed, args.steps) for seed in range(args.seeds)]
            reached = sum(p > 0 for p in paid)
            source = f"{n_source} random transitions" if n_source else "none"
            print(
                f"| {head} | {source} | {' '.join(map(str, paid))} | {reached} of {args.seeds} |", flush=True
            )


if __name__ == "__main__":
    main()
