"""
``sb3-trlsd benchmark``: TRLSD with its default arguments against SB3's DQN on each task family, with the
same online budget, target tasks, source transitions and seeds for every method.

Run r targets task r (modulo the family's tasks) with seed ``seed + r``; its 25,000 random source
transitions are drawn on task r + 1. TRLSD loads them with their rewards discarded (the paper's setting)
and learns online through ``run_online``; DQN learns from scratch, or with them in its replay buffer,
rewards zeroed (what a user without a reward model can do); a uniformly random policy is the floor, and
the cart-pole has a row of TRLSD given the true reward (``FAMILY_METHODS``). Every method is measured by
the mean expected reward E[R_task(s_t)] of the states it visits online. Writes
``benchmark_<family>.csv`` (curves), ``.png`` and ``.json`` (aggregates, seconds per run, sizes, version).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_trlsd.data import collect_transitions
from sb3_trlsd.observations import task_count_of
from sb3_trlsd.trlsd import TRLSD
from sb3_trlsd_envs import FOUR_ROOMS_ID, GOAL_CARTPOLE_ID, MAZE_ID
from sb3_trlsd_lab.benchmarks.baselines import DQN_SETTINGS, ExpectedRewards, dqn_rewards, random_rewards
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.runner import RunRecord, run_online
from sb3_trlsd_lab.paper.figures import write_transfer_figure

__all__ = ["FAMILIES", "FAMILY_METHODS", "METHODS", "Contender", "benchmark", "benchmark_run"]

# Family -> (env id, online transitions): the paper's 1,000 on the maze; 2,000 in the four rooms (a goal is
# more steps away, moves of 1/8 of the square against 1/5, through doorways) and on the cart-pole (a policy
# must learn to keep the pole up before it can walk the cart to the target).
FAMILIES: dict[str, tuple[str, int]] = {
    "maze": (MAZE_ID, 1_000),
    "four-rooms": (FOUR_ROOMS_ID, 2_000),
    "goal-cartpole": (GOAL_CARTPOLE_ID, 2_000),
}
SOURCE_TRANSITIONS = 25_000  # the paper's random source set, for every family
DEFAULT_RUNS = 20
SOURCE_SEED = 10_000  # the source of run r is collected with seed SOURCE_SEED + seed + r
KINDS = ("trlsd", "dqn", "random")


@dataclass(frozen=True)
class Contender:
    """
    One row of the benchmark.

    :param label: name in the plots, files and tables
    :param kind: ``"trlsd"`` (driven by ``run_online``), ``"dqn"`` (``DQN_SETTINGS``, ``learn``) or
        ``"random"`` (a uniformly random policy)
    :param source: start from the source transitions (TRLSD: rewards discarded; DQN: rewards zeroed)
    :param trlsd_kwargs: arguments of ``TRLSD`` besides the policy, env and seed (none: its defaults)
    """

    label: str
    kind: str
    source: bool = True
    trlsd_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {self.kind!r}")

    def parameters(self) -> dict[str, Any]:
        """The contender as a JSON-friendly dict, with DQN's settings for a DQN."""
        return {**asdict(self), **({"dqn": DQN_SETTINGS} if self.kind == "dqn" else {})}


METHODS = [
    Contender("TRLSD", "trlsd"),
    Contender("DQN", "dqn", source=False),
    Contender("DQN, source in buffer", "dqn"),
    Contender("random policy", "random", source=False),
]
# Rows of one family only: on the cart-pole, what TRLSD reaches when the reward is not what it has to learn
# (the true expected reward, CI = 0) and its linear Q is on a grid of RBFs instead of Fourier features.
FAMILY_METHODS: dict[str, list[Contender]] = {
    "goal-cartpole": [
        Contender(
            "TRLSD, known reward, RBF 0.1",
            "trlsd",
            trlsd_kwargs={"reward_head": "known", "feature_map": "rbf", "rbf_sigma": 0.1},
        )
    ],
}


def benchmark_run(
    family: str, contender: Contender, run: int, seed: int, n_source: int, n_online: int
) -> RunRecord:
    """
    Run ``run`` of ``contender`` on ``family``: target task ``run`` modulo its tasks, seed ``seed + run``.

    :param family: a key of ``FAMILIES``
    :param contender: the method
    :param run: the run's index
    :param seed: the benchmark's seed
    :param n_source: random source transitions, drawn on task ``run + 1`` (unused without source)
    :param n_online: online transitions on the target task
    :return: the record; ``policy_updates`` counts TRLSD's refits, DQN's gradient steps (0 at random)
    """
    start = time.perf_counter()
    env_id = FAMILIES[family][0]
    n_tasks = task_count_of(gym.make(env_id).observation_space)
    env = ExpectedRewards(gym.make(env_id, task=run % n_tasks))
    run_seed = seed + run
    source = None
    if contender.source and n_source:
        source_env = gym.make(env_id, task=(run + 1) % n_tasks)
        source = collect_transitions(source_env, n_source, seed=SOURCE_SEED + run_seed)
    if contender.kind == "trlsd":
        model = TRLSD("LinearPolicy", env, seed=run_seed, **contender.trlsd_kwargs)
        if source is not None:
            model.load_transitions(source, keep_rewards=False)
        record = run_online(model, env, n_online, run_seed)
    else:
        if contender.kind == "dqn":
            rewards, updates = dqn_rewards(env, run_seed, n_online, source)
        else:
            rewards, updates = random_rewards(env, run_seed, n_online), 0
        tasks = np.full(n_online, run % n_tasks, dtype=np.int64)
        record = RunRecord(rewards=rewards, tasks=tasks, policy_updates=updates, seconds=0.0)
    record.seconds = time.perf_counter() - start
    return record


def benchmark(
    family: str,
    out: Path,
    runs: int = DEFAULT_RUNS,
    seed: int = 0,
    workers: int = 1,
    cache: Path | None = None,
    methods: list[Contender] | None = None,
    n_source: int | None = None,
    n_online: int | None = None,
) -> dict:
    """
    ``runs`` runs of each method on ``family``; write ``benchmark_<family>.csv``, ``.png`` and ``.json``.

    :param family: a key of ``FAMILIES``
    :param out: output directory (created if needed)
    :param runs: runs per method
    :param seed: seed of the first run; run r uses ``seed + r``
    :param workers: processes the runs are spread over
    :param cache: directory of finished runs, reused and completed (see ``run_jobs``); None: no cache
    :param methods: the rows (None: ``METHODS`` and the family's ``FAMILY_METHODS``)
    :param n_source: random source transitions (None: ``SOURCE_TRANSITIONS``)
    :param n_online: online transitions (None: the family's budget in ``FAMILIES``)
    :return: the JSON summary
    """
    if family not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {family!r}")
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    started = time.perf_counter()
    env_id, budget = FAMILIES[family]
    methods = [*METHODS, *FAMILY_METHODS.get(family, [])] if methods is None else methods
    # The sizes are resolved here, not in the workers, so that a cached run's key holds them.
    n_source = SOURCE_TRANSITIONS if n_source is None else n_source
    n_online = budget if n_online is None else n_online
    jobs: list[tuple[tuple, dict[str, Any]]] = [
        ((family, method, run, seed, n_source, n_online), {}) for method in methods for run in range(runs)
    ]
    records = run_jobs(
        benchmark_run,
        jobs,
        workers,
        description=f"{family}: {len(methods)} methods x {runs} runs",
        cache=cache,
    )
    out.mkdir(parents=True, exist_ok=True)
    return write_transfer_figure(
        out,
        f"benchmark_{family}",
        f"{env_id}: {n_source:,} random source transitions, then {n_online:,} online on the target task",
        methods,
        {method.label: records[i * runs : (i + 1) * runs] for i, method in enumerate(methods)},
        [(0, n_online), (n_online // 2, n_online)],
        {
            "family": family,
            "env_id": env_id,
            "runs": runs,
            "source_transitions": n_source,
            "online_transitions": n_online,
            "tasks": "run r targets task r, its source drawn on task r + 1",
        },
        seed,
        started,
    )
