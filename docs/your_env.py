"""TRLSD on a task family of your own: the README's "Use it on your env" example, runnable as it is.

A point moves on a 100 m x 100 m field (not the maze's units: TRLSD's defaults are fractions of the state
box); nine tasks share the dynamics and differ only by which disc pays. Random transitions collected on
task 0 (their rewards discarded) teach TRLSD the dynamics; it then learns task 8 online::

    python docs/your_env.py [--source 25000] [--steps 1000] [--seed 0]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_trlsd import TRLSD, collect_transitions

MOVES = 10.0 * np.array([[0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])  # 10 m north, west, south, east
GOALS = np.array([[x, y] for x in (20.0, 50.0, 80.0) for y in (20.0, 50.0, 80.0)])  # one disc per task


class PointGoals(gym.Env):
    """A point on [0, 100]^2 moved 10 m per step with N(0, 3 m) noise; task k pays 1 within 10 m of goal k."""

    def __init__(self, task: int = 0, goal_radius: float = 10.0):
        self.task, self.goal_radius = task, goal_radius
        # What TRLSD needs: a bounded state Box (or state_bounds=), a task index, Discrete actions.
        self.observation_space = spaces.Dict(
            {"state": spaces.Box(0.0, 100.0, (2,), np.float32), "task": spaces.Discrete(len(GOALS))}
        )
        self.action_space = spaces.Discrete(len(MOVES))

    def expected_reward(self, states: np.ndarray, task: int) -> np.ndarray:
        """E[R_task(s)] for (n, 2) states: optional, used by reward_head="known" and to evaluate."""
        return (np.linalg.norm(np.asarray(states) - GOALS[task], axis=1) <= self.goal_radius).astype(float)

    def _observation(self) -> dict:
        return {"state": self.state.astype(np.float32), "task": self.task}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.state = self.np_random.uniform(0.0, 100.0, 2)
        return self._observation(), {}

    def step(self, action: int):
        reward = float(self.expected_reward(self.state[None], self.task)[0])  # the reward of the start state
        move = MOVES[action] + self.np_random.normal(0.0, 3.0, 2)
        self.state = np.clip(self.state + move, 0.0, 100.0)
        truncated = bool(self.np_random.random() < 0.02)  # random restarts, as in the paper's maze
        return self._observation(), reward, False, truncated, {}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--source", type=int, default=25_000, help="random source transitions of task 0")
    parser.add_argument("--steps", type=int, default=1_000, help="online transitions on task 8")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    source = collect_transitions(PointGoals(task=0), args.source, seed=args.seed)
    target = PointGoals(task=8)
    model = TRLSD("LinearPolicy", target, seed=args.seed)  # every setting at its default
    model.load_transitions(source, keep_rewards=False)  # the dynamics only, as in the paper
    model.learn(total_timesteps=args.steps)

    online = model.replay_buffer.transitions(start=args.source)
    trlsd_reward = target.expected_reward(online.states, 8).mean()
    random_states = collect_transitions(PointGoals(task=8), args.steps, seed=args.seed + 1).states
    random_reward = target.expected_reward(random_states, 8).mean()
    features = f"{type(model.features).__name__} ({model.features.n_features})"
    print(f"features: {features}; refits: {model.policy_updates[8]}")
    print(f"mean reward over {args.steps} transitions: TRLSD {trlsd_reward:.3f}, random {random_reward:.3f}")


if __name__ == "__main__":
    main()
