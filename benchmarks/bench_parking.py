"""Where the online steps go: how long each method stays in one state, on the MO-Gymnasium suite's families.

A greedy policy on a Q-function that is nearly flat (no reward met yet, or one small reward smoothed away)
is deterministic all the same: in a grid world it can walk into a wall and stay there, every step the
same state. This runs the suite's methods on the tuning weights (the suite's sources, seeds and budget)
and prints, per family and method, the mean over runs of: the score (mean reward per online step), the
share of the online steps spent in the state visited most, and the number of distinct states visited
(exact states: on the continuous families each step is a new state unless the agent is stuck). A
diagnosis, not a test: nothing is asserted. Usage::

    python benchmarks/bench_parking.py [--families four-room-v0 ...] [--runs 8] [--workers 2]
"""

from __future__ import annotations

import argparse
from collections import Counter
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_trlsd_lab.benchmarks.mo_suite.families import FAMILIES, collect_source, family_named, make_env
from sb3_trlsd_lab.benchmarks.mo_suite.peers import METHODS, SETTABLE, StepRewards
from sb3_trlsd_lab.benchmarks.mo_suite.suite import SOURCE_SEED
from sb3_trlsd_lab.execution.jobs import run_jobs

# (label, method of the suite, TRLSD settings other than its defaults)
VARIANTS: list[tuple[str, str, dict[str, Any]]] = [
    ("TRLSD (defaults)", "trlsd", {}),
    ("TRLSD, greedy throughout", "trlsd", {"exploration_initial_eps": 0.0}),
    ("TRLSD, reward_timing='transition'", "trlsd", {"reward_timing": "transition"}),
    ("TRLSD given the source's true rewards", "trlsd-reward-given", {}),
    ("TRLSD, MlpPolicy (defaults)", "trlsd-mlp", {}),
    ("DQN (online only)", "dqn", {}),
    ("random policy", "random", {}),
]


class StateLog(gym.Wrapper):
    """Records the state each step arrives at."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.states: list[tuple[float, ...]] = []

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.states.append(tuple(np.asarray(obs["state"], dtype=np.float64).tolist()))
        return obs, reward, terminated, truncated, info


def parking_run(family_name: str, variant: int, run: int) -> dict[str, float]:
    """Run ``run`` of ``VARIANTS[variant]`` on the family's tuning weights: its score and where it went."""
    _, method, settings = VARIANTS[variant]
    family = family_named(family_name)
    targets = family.tasks_of("tuning")
    task = int(targets[run % len(targets)])
    source = collect_source(family, family.n_source, SOURCE_SEED + run) if METHODS[method][1] else None
    logged = StateLog(make_env(family, task))
    env = StepRewards(logged)
    play = SETTABLE[method](**settings) if settings else METHODS[method][2]
    play(env, family, source, run, family.n_online)
    env.close()
    states = logged.states[: family.n_online]
    return {
        "score": float(np.mean(env.rewards[: family.n_online])),
        "parked": Counter(states).most_common(1)[0][1] / len(states),
        "distinct": float(len(set(states))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--families", nargs="+", default=["four-room-v0"], choices=list(FAMILIES))
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    jobs = [
        ((name, variant, run), {})
        for name in args.families
        for variant in range(len(VARIANTS))
        for run in range(args.runs)
    ]
    rows = run_jobs(parking_run, jobs, args.workers, description="parking runs")
    print(f"{'family':<24}{'method':<40}{'score':>10}{'steps in one state':>20}{'distinct states':>17}")
    for i, (name, variant, _) in enumerate(job for job, _ in jobs[:: args.runs]):
        runs = rows[i * args.runs : (i + 1) * args.runs]
        score, parked, distinct = (np.mean([r[key] for r in runs]) for key in ("score", "parked", "distinct"))
        print(f"{name:<24}{VARIANTS[variant][0]:<40}{score:>10.4f}{parked:>20.0%}{distinct:>17.1f}")


if __name__ == "__main__":
    main()
