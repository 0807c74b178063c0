"""
The figures' runs in batches: each method's runs split into ``SOURCE_SETS`` batches of consecutive runs
(one method, different tasks and seeds), stepped in lockstep (``sb3_trlsd_lab.execution.lockstep``) with
TRLSD's own task learners and Fitted-Q function; the runs of a transfer batch share one source set, drawn from
``source_seed(seed, b)``, so every method sees the same tasks, source sets and env seeds (under a protocol
with ``source_sets="per_run"``, each run draws its own, from ``run_source_seed``). A run of a batch takes the
actions of that run alone (``runner.py``) on the same source set (``tests/test_lockstep.py``). The choices
the paper leaves open come with the ``protocol`` of each call (``sb3_trlsd_lab.execution.protocols``).
``run_jobs`` (``sb3_trlsd_lab.execution.jobs``) spreads the batches over processes and, given a cache
directory, keeps the finished ones there to resume a killed reproduction.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_trlsd.data import Transitions, collect_transitions
from sb3_trlsd_envs import MAZE_ID, N_TASKS
from sb3_trlsd_envs.evaluation import task_family_of
from sb3_trlsd_lab.execution.backends import LOKY, Backend
from sb3_trlsd_lab.execution.env_batches import env_batch
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.lockstep import Lockstep
from sb3_trlsd_lab.execution.protocols import AS_BUILT, Protocol
from sb3_trlsd_lab.execution.runner import (
    ONLINE_TRANSITIONS,
    SOURCE_TRANSITIONS,
    Method,
    RunRecord,
    multitask_env,
    run_online,
    target_env,
)

__all__ = [
    "SOURCE_SETS",
    "batch_runs",
    "multitask_batch",
    "run_source_seed",
    "source_seed",
    "transfer_batch",
    "transfer_runs",
]

# Distinct source sets per method of a figure: its runs go in this many batches of consecutive runs, each
# batch stepped in lockstep on its own source set; standard errors are taken over the batches' means.
SOURCE_SETS = 20


def transfer_runs(
    methods: Sequence[Method],
    tasks: Sequence[int],
    runs: int,
    seed: int,
    workers: int,
    n_source: int | None = None,
    n_online: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    cache: Path | None = None,
    backend: Backend = LOKY,
    protocol: Protocol = AS_BUILT,
    source_sets: int = SOURCE_SETS,
) -> dict[str, list[RunRecord]]:
    """
    ``runs`` transfer runs of each method, run ``r`` on ``tasks[r % len(tasks)]`` with seed ``seed + r``, in
    ``source_sets`` batches of consecutive runs (``batch_runs``), batch b on the source set of
    ``source_seed(seed, b)``: every method sees the same tasks, source transitions and env seeds (common
    random numbers), so that their differences are not blurred by the luck of the draw.

    :param n_source: random source transitions (None: ``SOURCE_TRANSITIONS``)
    :param n_online: online transitions (None: ``ONLINE_TRANSITIONS``)
    :param env_kwargs: keyword arguments of the target task's env, over the protocol's (paper's settings by
        default)
    :param cache: directory of finished runs, see ``run_jobs`` (None: none)
    :param backend: where the runs go, see ``run_jobs``
    :param protocol: the choices the paper leaves open (a kept run is kept under those that reach it:
        ``Protocol.reaching``)
    :param source_sets: the batches (fewer with fewer runs): the more, the more honest the standard errors
        over them; the fewer, the larger each batch and the faster its lockstep
    :return: method label -> its runs' records
    """
    # The sizes are resolved here, not in the workers, so that a cached batch's key holds them.
    n_source = SOURCE_TRANSITIONS if n_source is None else n_source
    n_online = ONLINE_TRANSITIONS if n_online is None else n_online
    batches = batch_runs(runs, source_sets)
    jobs = [
        (
            (
                method,
                tuple(tasks[run % len(tasks)] for run in batch),
                tuple(seed + run for run in batch),
                source_seed(seed, b),
                n_source,
                n_online,
            ),
            {"env_kwargs": env_kwargs, "source_set": b, "protocol": protocol.reaching(method.reward_head)},
        )
        for method in methods
        for b, batch in enumerate(batches)
    ]
    results = run_jobs(
        transfer_batch,
        jobs,
        workers,
        description=f"{len(methods)} methods x {runs} runs, in batches",
        cache=cache,
        backend=backend,
    )
    return {
        method.label: [
            record for batch in results[i * len(batches) : (i + 1) * len(batches)] for record in batch
        ]
        for i, method in enumerate(methods)
    }


def batch_runs(runs: int, source_sets: int = SOURCE_SETS) -> list[range]:
    """
    Runs 0..runs-1 split into at most ``source_sets`` batches of consecutive runs, of sizes differing by one.

    :param runs: the runs
    :param source_sets: the batches wanted (fewer with fewer runs)
    :return: the runs of each batch
    """
    n_batches = max(1, min(source_sets, runs))
    bounds = np.linspace(0, runs, n_batches + 1).round().astype(int)
    return [range(start, stop) for start, stop in itertools.pairwise(bounds) if stop > start]


def source_seed(seed: int, batch: int) -> int:
    """The seed of batch ``batch``'s source set in a figure of seed ``seed`` (distinct from the run seeds)."""
    return int(np.random.SeedSequence([seed, batch, 1]).generate_state(1)[0])


def run_source_seed(run_seed: int) -> int:
    """The seed of the source set of the run of seed ``run_seed`` when each run has one of its own."""
    return int(np.random.SeedSequence([run_seed, 2]).generate_state(1)[0])


def _source_set(method: Method, n_source: int, seed: int) -> Transitions | None:
    """The random source transitions of a batch (None without transfer)."""
    if not (method.transfer and n_source):
        return None
    return collect_transitions(gym.make(MAZE_ID, task=0), n_source, seed=seed)


def _records(
    envs: Sequence[gym.Env], lockstep_records: Sequence, seconds: float, source_set: int | None
) -> list[RunRecord]:
    """The runs of a lockstep batch as ``RunRecord``: expected rewards of the visited states by task."""
    records = []
    for env, run in zip(envs, lockstep_records, strict=True):
        rewards = np.empty(len(run.tasks))
        for task in np.unique(run.tasks):
            rewards[run.tasks == task] = task_family_of(env).expected_reward(
                run.states[run.tasks == task], int(task)
            )
        records.append(
            RunRecord(
                rewards=rewards,
                tasks=run.tasks,
                policy_updates=len(run.refit_steps),
                seconds=seconds / len(envs),
                source_set=source_set,
            )
        )
    return records


def transfer_batch(
    method: Method,
    tasks: Sequence[int],
    seeds: Sequence[int],
    source_seed: int,
    n_source: int,
    n_online: int,
    env_kwargs: dict[str, Any] | None = None,
    source_set: int | None = None,
    protocol: Protocol = AS_BUILT,
) -> list[RunRecord]:
    """
    Transfer runs of one method that share one source set (Figures 1, 5-7): ``n_source`` random
    transitions, their rewards discarded, then ``n_online`` online transitions, run r on ``tasks[r]`` with
    its env seeded by ``seeds[r]``; stepped in lockstep for the linear Q, one after the other (``run_online``
    on the same source set) for another policy. Under a protocol with a source set per run, run r draws its
    own from ``run_source_seed(seeds[r])`` and is stepped alone.

    :param source_seed: seed of the source set
    :param env_kwargs: keyword arguments of the target tasks' envs, over the protocol's (paper's settings
        by default)
    :param source_set: the batch's index, kept in the records (None in those of runs with their own)
    :param protocol: the choices the paper leaves open
    :return: one record per run
    """
    start = time.perf_counter()
    if len(tasks) != len(seeds):
        raise ValueError(f"one seed per task: {len(tasks)} tasks, {len(seeds)} seeds")
    envs = [target_env(task, protocol, env_kwargs) for task in tasks]
    if protocol.source_sets == "per_run":
        sources = [_source_set(method, n_source, run_source_seed(seed)) for seed in seeds]
        groups, source_set = [[run] for run in range(len(envs))], None
    else:
        sources = [_source_set(method, n_source, source_seed)] * len(envs)
        groups = [list(range(len(envs)))]
    if method.policy != "LinearPolicy":
        records = []
        for env, seed, source in zip(envs, seeds, sources, strict=True):
            model = method.make_model(env, seed, protocol)
            if source is not None:
                model.load_transitions(source, keep_rewards=False)
            records.append(run_online(model, env, n_online, seed))
            records[-1].source_set = source_set
        return records
    runs = []
    for group in groups:  # the runs of one source set, stepped together
        group_envs = [envs[run] for run in group]
        model = method.make_model(group_envs[0], seeds[group[0]], protocol)
        lockstep = Lockstep(model, env_batch(group_envs), len(group), sources[group[0]], n_online)
        runs += lockstep.run([seeds[run] for run in group])
    return _records(envs, runs, time.perf_counter() - start, source_set)


def multitask_batch(
    method: Method,
    seeds: Sequence[int],
    n_turns: int = 20,
    episode_steps: int = 50,
    source_set: int | None = None,
    protocol: Protocol = AS_BUILT,
) -> list[RunRecord]:
    """
    Runs of the multi-task experiment (Figure 8, see ``multitask_run``) stepped in lockstep, one per seed.

    :param method: how TRLSD learns (its ``transfer`` is ignored: there is no source)
    :param seeds: the runs' seeds
    :param n_turns: turns over the 25 tasks
    :param episode_steps: transitions per trajectory
    :param source_set: the batch's index, kept in the records
    :param protocol: the choices the paper leaves open
    :return: one record per run, ``n_turns * 25 * episode_steps`` transitions each
    """
    start = time.perf_counter()
    envs = [multitask_env(episode_steps, protocol) for _ in seeds]
    lockstep = Lockstep(
        method.make_model(envs[0], seeds[0], protocol),
        env_batch(envs),
        len(envs),
        None,
        n_turns * N_TASKS * episode_steps,
    )
    runs = lockstep.run(seeds)
    return _records(envs, runs, time.perf_counter() - start, source_set)
