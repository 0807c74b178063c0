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

from sb3_trlsd_envs import N_TASKS
from sb3_trlsd_lab.execution.batches import batch_runs, multitask_batch
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.figures import new_figure, protocol_title, save_figure, update_counts
from sb3_trlsd_lab.paper.reporting import (
    mean_and_standard_error,
    plot_curves,
    summary,
    write_curves_csv,
    write_json,
)
from sb3_trlsd_lab.paper.reproduction import Reproduction

DEFAULT_RUNS = 200  # paper: 200 runs
TURNS = 20
EPISODE_STEPS = 50
NEAR_SOLVED = 0.9  # near solved: a turn's reward reaches this fraction of the last turn's
TITLE = "Figure 8: multi-task learning of the 25 tasks, no source data"
METHODS = [
    Method("non-optimistic (kappa=0)", kappa=0.0),
    Method("similarity on states (eq. 6)"),
    Method("similarity on features (eq. 7)", similarity="features"),
]


def turn_rewards(episode_rewards: np.ndarray) -> np.ndarray:
    """
    The average reward of each turn of each run: a turn is 25 episodes, one per task, so that easy and hard
    tasks weigh the same in it.

    :param episode_rewards: (runs, episodes) average reward of each episode, a whole number of turns
    :return: (runs, turns)
    """
    runs, episodes = episode_rewards.shape
    return episode_rewards.reshape(runs, episodes // N_TASKS, N_TASKS).mean(axis=2)


def near_solved_episode(episode_rewards: np.ndarray) -> int:
    """
    The number of episodes after which the mean reward of a whole turn (see ``turn_rewards``) first reaches
    ``NEAR_SOLVED`` times that of the last turn.

    :param episode_rewards: (runs, episodes) average reward of each episode
    :return: episodes played by the end of that turn
    """
    turns = turn_rewards(episode_rewards).mean(axis=0)
    first = int(np.argmax(turns >= NEAR_SOLVED * turns[-1]))
    return (first + 1) * N_TASKS


def turn_curves(turns: dict[str, np.ndarray]) -> dict[str, dict[str, list[float]]]:
    """
    The curves of the right panel of ``draw_figure``, for the JSON summary.

    :param turns: label -> (runs, turns) average reward of each turn
    :return: label -> {"mean": [...], "se": [...]}, one value per turn
    """
    curves = {}
    for label, values in turns.items():
        mean, se = mean_and_standard_error(values)
        curves[label] = {"mean": mean.round(4).tolist(), "se": se.round(4).tolist()}
    return curves


def draw_figure(
    path: Path,
    episodes: dict[str, np.ndarray],
    turns: dict[str, np.ndarray],
    near_solved: dict[str, int],
    title: str = TITLE,
) -> None:
    """
    The paper's Figure 8, the reward of each episode, and beside it the reward of each turn (each task
    once), which the alternation of easy and hard tasks does not blur, with each method's near-solved point.

    :param path: the PNG written
    :param episodes: label -> (runs, episodes) average reward of each episode
    :param turns: label -> (runs, turns) average reward of each turn
    :param near_solved: label -> episodes after which the method is near solved
    :param title: the figure's title
    """
    colors = {label: f"C{index}" for index, label in enumerate(episodes)}
    figure, (by_episode, by_turn) = new_figure(2, width=6.0)
    plot_curves(
        by_episode, episodes, xlabel="episodes (50 transitions each, the 25 tasks in turn)", colors=colors
    )
    by_episode.set_title("each episode (the paper's figure)")
    end_of_turns = N_TASKS * np.arange(1, next(iter(turns.values())).shape[1] + 1)
    plot_curves(
        by_turn, turns, xlabel="episodes, at the end of each turn", colors=colors, x=end_of_turns, marker="."
    )
    for label, episode in near_solved.items():
        by_turn.axvline(episode, color=colors[label], linestyle=":", linewidth=1.2)
    by_turn.set_title(f"each turn (25 episodes); dotted: near solved ({NEAR_SOLVED:.0%} of the last)")
    save_figure(figure, path, title)


def reproduce(out: Path, how: Reproduction) -> dict:
    """
    Reward per episode of each method, and when each is near solved.

    :param out: the output directory
    :param how: runs, seed, workers, cache, backend and protocol
    """
    started = time.perf_counter()
    runs = how.runs_or(DEFAULT_RUNS)
    # Batches of runs stepped in lockstep; without a source, their runs share nothing and stay independent.
    batches = batch_runs(runs)
    jobs = [
        (
            (method, tuple(how.seed + run for run in batch), TURNS, EPISODE_STEPS),
            {"protocol": how.protocol.reaching(method.reward_head, multitask=True)},
        )
        for method in METHODS
        for batch in batches
    ]
    batch_records = run_jobs(
        multitask_batch,
        jobs,
        how.workers,
        description=f"{len(METHODS)} methods x {runs} runs, in batches",
        cache=how.cache,
        backend=how.backend,
    )
    records = [record for batch in batch_records for record in batch]
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
    turns = {label: turn_rewards(values) for label, values in episodes.items()}
    near_solved = {label: near_solved_episode(values) for label, values in episodes.items()}
    draw_figure(out / "fig8.png", episodes, turns, near_solved, protocol_title(TITLE, how.protocol))

    results = {}
    for i, method in enumerate(METHODS):
        values = episodes[method.label]
        last_turn, last_se = mean_and_standard_error(turns[method.label][:, -1])
        results[method.label] = {
            "near_solved_after_episodes": near_solved[method.label],
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
            **how.recorded(),
        },
        how.seed,
        time.perf_counter() - started,
        results=results,
        turn_rewards=turn_curves(turns),
    )
    write_json(out / "fig8.json", data)
    return data
