"""
Figure 8: multi-task learning without source data. The 25 tasks in turns, one trajectory of 50
transitions per task per turn, 20 turns (25,000 transitions); every transition serves every task. The
non-optimistic method against the optimistic continuous setting with the similarity on states (eq. 6)
and on features (eq. 7). The paper: near solved after 300 episodes, both similarities alike, far above
the non-optimistic method.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from envs import N_TASKS
from sb3_trlsd.experiments.figures import new_figure, save_figure, update_counts
from sb3_trlsd.experiments.reporting import (
    mean_and_standard_error,
    plot_curves,
    summary,
    write_curves_csv,
    write_json,
)
from sb3_trlsd.experiments.runner import Method, multitask_run, run_jobs

DEFAULT_RUNS = 200  # paper: 200 runs
TURNS = 20
EPISODE_STEPS = 50
NEAR_SOLVED = 0.9  # near solved: a turn's reward reaches this fraction of the last turn's
METHODS = [
    Method("non-optimistic (kappa=0)", kappa=0.0),
    Method("similarity on states (eq. 6)"),
    Method("similarity on features (eq. 7)", similarity="features"),
]


def near_solved_episode(episode_rewards: np.ndarray) -> int:
    """
    The number of episodes after which the mean reward of a whole turn (25 episodes, one per task, so that
    easy and hard tasks weigh the same) first reaches ``NEAR_SOLVED`` times that of the last turn.

    :param episode_rewards: (runs, episodes) average reward of each episode
    :return: episodes played by the end of that turn
    """
    turns = episode_rewards.mean(axis=0).reshape(-1, N_TASKS).mean(axis=1)
    first = int(np.argmax(turns >= NEAR_SOLVED * turns[-1]))
    return (first + 1) * N_TASKS


def reproduce(out: Path, runs: int | None, seed: int, workers: int, cache: Path | None = None) -> dict:
    """
    Reward per episode of each method, and when each is near solved.

    :param cache: directory of finished runs, reused and completed (see ``run_jobs``); None: no cache
    """
    started = time.perf_counter()
    runs = runs or DEFAULT_RUNS
    jobs = [((method, seed + run, TURNS, EPISODE_STEPS), {}) for method in METHODS for run in range(runs)]
    records = run_jobs(
        multitask_run, jobs, workers, description=f"{len(METHODS)} methods x {runs} runs", cache=cache
    )
    episodes = {
        method.label: np.stack(
            [
                record.rewards.reshape(-1, EPISODE_STEPS).mean(axis=1)
                for record in records[i * runs : (i + 1) * runs]
            ]
        )
        for i, method in enumerate(METHODS)
    }
    write_curves_csv(out / "fig8.csv", "episode", episodes)
    figure, (ax,) = new_figure(1, width=7.0)
    plot_curves(ax, episodes, xlabel="episodes (50 transitions each, the 25 tasks in turn)")
    save_figure(figure, out / "fig8.png", "Figure 8: multi-task learning of the 25 tasks, no source data")

    results = {}
    for i, method in enumerate(METHODS):
        values = episodes[method.label]
        last_turn, last_se = mean_and_standard_error(values[:, -N_TASKS:].mean(axis=1))
        results[method.label] = {
            "near_solved_after_episodes": near_solved_episode(values),
            "last_turn_reward": {"mean": float(last_turn), "se": float(last_se)},
            "reward_first_300_episodes": float(values[:, :300].mean()),
            "policy_updates": update_counts(records[i * runs : (i + 1) * runs]),
            "seconds_per_run": float(np.mean([r.seconds for r in records[i * runs : (i + 1) * runs]])),
            "runs": runs,
        }
    data = summary(
        "fig8",
        {
            "turns": TURNS,
            "episode_steps": EPISODE_STEPS,
            "runs": runs,
            "methods": [m.parameters() for m in METHODS],
        },
        seed,
        time.perf_counter() - started,
        results=results,
    )
    write_json(out / "fig8.json", data)
    return data
