"""
Runs of ``TRLSD`` on the maze, one at a time, as the paper's section 4 sets them up: the reference the
batches of ``batches.py`` are checked against, and the path of the runs that draw pictures (Figures 1-4) or
fit the MLP.

A run drives a ``TRLSD`` model through ``TRLSD.act`` and ``TRLSD.add_online_transition`` from a plain loop
over the env (``run_online``, the lab's one such loop: the benchmarks drive TRLSD through it too), and takes
the same actions as ``model.learn`` with the same seed (``tests/test_experiments.py``) without SB3's rollout
machinery (vectorised env, monitor, logger, torch predict), which costs as much as the refits on the maze.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_trlsd.data import collect_transitions
from sb3_trlsd.observations import split_observation, state_space_of
from sb3_trlsd.trlsd import TRLSD
from sb3_trlsd_envs import MAZE_ID, N_TASKS
from sb3_trlsd_envs.dynamics import MAZE_SIZE
from sb3_trlsd_envs.evaluation import task_family_of
from sb3_trlsd_envs.pictures import greedy_policy_grid, state_grid
from sb3_trlsd_lab.execution.protocols import AS_BUILT, Protocol, paper_relabelling

__all__ = [
    "Method",
    "RunRecord",
    "Snapshot",
    "multitask_env",
    "multitask_run",
    "run_online",
    "target_env",
    "transfer_run",
]

SOURCE_TRANSITIONS = 25_000  # paper, section 4: random transitions before the target task
ONLINE_TRANSITIONS = 1_000  # paper, section 4: online transitions on the target task
SNAPSHOT_GRID = 50  # R^ of a snapshot is drawn on a SNAPSHOT_GRID x SNAPSHOT_GRID grid of states
SNAPSHOT_TRAIL = 50  # a snapshot's trajectory: the transitions since the previous one, at most this many


@dataclass(frozen=True)
class Method:
    """
    One curve of a figure: how TRLSD learns the target task.

    :param label: name in the plots and files
    :param reward_head: ``"ridge"`` (continuous), ``"tabular"`` (discrete), ``"corners"``, ``"known"``, or a
        head with another confidence bound: ``"ridge_posterior"`` (OFUL), ``"thompson"``, ``"bernstein"``
    :param kappa: optimism (0: non-optimistic); the scale of the bonus or of the draws for the other bounds
    :param sigma: similarity width of the ridge head's W (eq. 8) and of the Bernstein head's weights, in the
        paper's units: maze units for eq. 6 (TRLSD takes a fraction of the state box: sigma / 5), feature
        space for eq. 7
    :param similarity: ``"state"`` (eq. 6) or ``"features"`` (eq. 7)
    :param update_ratio: refit when the CI at an encountered state has been divided by this
    :param transfer: start from the random source transitions (False: "no transfer")
    :param policy: the Q-function, a name of ``TRLSD.policy_aliases``: ``"LinearPolicy"`` (the paper's linear
        Q on 5x5 RBFs) or ``"MlpPolicy"``
    :param reward_head_kwargs: further arguments of the head (e.g. ``reward_range`` of ``"bernstein"``), over
        the protocol's
    """

    label: str
    reward_head: str = "ridge"
    kappa: float = 0.1
    sigma: float = 0.2
    similarity: str = "state"
    update_ratio: float = 2.0
    transfer: bool = True
    policy: str = "LinearPolicy"
    reward_head_kwargs: Mapping[str, Any] = field(default_factory=dict)

    def parameters(self) -> dict[str, Any]:
        """The method as a JSON-friendly dict."""
        return asdict(self)

    def make_model(self, env: gym.Env, seed: int, protocol: Protocol = AS_BUILT) -> TRLSD:
        """
        A TRLSD model of this method on ``env``.

        :param env: the env
        :param seed: the model's seed
        :param protocol: the choices the paper leaves open (gamma, first fit, the heads' edge cases)
        """
        settings = protocol.model_kwargs(self.reward_head)
        relabelling = paper_relabelling(self.reward_head)
        head_kwargs = {**relabelling.pop("reward_head_kwargs"), **settings["reward_head_kwargs"]}
        settings["reward_head_kwargs"] = {**head_kwargs, **self.reward_head_kwargs}
        return TRLSD(
            self.policy,
            env,
            kappa=self.kappa,
            **relabelling,
            sigma=self.sigma / MAZE_SIZE if self.similarity == "state" else self.sigma,
            similarity=self.similarity,
            update_ratio=self.update_ratio,
            seed=seed,
            **settings,
        )


@dataclass
class Snapshot:
    """What a run looked like after ``step`` transitions (the paper's Figures 1-4)."""

    step: int
    reward_estimate: np.ndarray  # R^ on a grid of states, (SNAPSHOT_GRID, SNAPSHOT_GRID), row = y
    policy: np.ndarray  # greedy action at each cell centre, (5, 5) indexed [i - 1, j - 1]
    trajectory: np.ndarray  # the last states visited, (t, 2)


@dataclass
class RunRecord:
    """
    One run's outcome.

    :param rewards: E[R_task(s_t)] of the state each online transition starts from, (n_steps,)
    :param tasks: the task of each online transition, (n_steps,)
    :param policy_updates: refits of the target task(s) during the online phase, the first one included
    :param seconds: wall time of the run (of a batch: its wall time divided by its runs)
    :param snapshots: pictures asked for with ``snapshot_at``
    :param source_set: the batch whose source set the run started from (None: a run of its own)
    """

    rewards: np.ndarray
    tasks: np.ndarray
    policy_updates: int
    seconds: float
    snapshots: list[Snapshot] = field(default_factory=list)
    source_set: int | None = None


def snapshot(model: TRLSD, task: int, step: int, trajectory: np.ndarray) -> Snapshot:
    """The reward estimate and greedy policy of ``task`` after ``step`` transitions, with a trajectory."""
    estimate = model.task_learner(task).head.estimate(state_grid(SNAPSHOT_GRID))
    return Snapshot(
        step=step,
        reward_estimate=estimate.reshape(SNAPSHOT_GRID, SNAPSHOT_GRID),
        policy=greedy_policy_grid(model.policy.q_values, task),
        trajectory=trajectory.copy(),
    )


def _broken_at_resets(states: np.ndarray, new_trajectory: np.ndarray, start: int, stop: int) -> np.ndarray:
    """states[start:stop] with a row of NaN before each reset, where a drawn line must break."""
    rows = []
    for t in range(start, stop):
        if new_trajectory[t] and t > start:
            rows.append(np.full(states.shape[1], np.nan))
        rows.append(states[t])
    return np.array(rows)


def run_online(
    model: TRLSD,
    env: gym.Env,
    n_steps: int,
    seed: int,
    snapshot_at: Iterable[int] = (),
    expected_rewards: bool = True,
) -> RunRecord:
    """
    The lab's one loop that drives a TRLSD model online, as ``model.learn(n_steps)`` would: reset with
    ``seed``, act (a task fitted at its first step), step the env, hand the transition to the model (its
    engine's step: store, feed the task's learner, refit the tasks that trigger), reset after the end of each
    trajectory.

    :param model: the model (``learning_starts=0``, ``train_freq=1``, its defaults)
    :param env: the env the model was built on (stepped here directly), with a state Box or
        ``{"state", "task"}`` Dict observations
    :param n_steps: online transitions
    :param seed: seed of the env's first reset (``learn`` uses the model's seed)
    :param snapshot_at: steps after which to take a ``Snapshot`` of the first task (the maze only)
    :param expected_rewards: record the noise-free expected reward of each visited state (an env of this
        package's families: ``env.unwrapped.expected_reward(states, task)``); False: the rewards observed
    :return: the record
    """
    snapshot_steps = sorted(set(snapshot_at))
    trail_starts = {  # each snapshot draws the states since the previous one, at most SNAPSHOT_TRAIL
        step: max(previous, step - SNAPSHOT_TRAIL)
        for previous, step in itertools.pairwise([0, *snapshot_steps])
    }
    updates_before = sum(model.policy_updates.values())
    state_dim = state_space_of(env.observation_space).shape[0]
    states = np.empty((n_steps + 1, state_dim))
    tasks = np.empty(n_steps, dtype=np.int64)
    observed = np.empty(n_steps)
    new_trajectory = np.zeros(n_steps + 1, dtype=bool)  # states[t] starts a trajectory after a reset
    snapshots = []
    start = time.perf_counter()
    obs, _ = env.reset(seed=seed)
    for step in range(n_steps):
        (states[step],), (tasks[step],) = split_observation(obs, state_dim)
        if step in trail_starts:
            trail = _broken_at_resets(states, new_trajectory, trail_starts[step], step + 1)
            snapshots.append(snapshot(model, int(tasks[0]), step, trail))
        action = model.act(obs)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        observed[step] = float(reward)
        model.add_online_transition(obs, action, float(reward), next_obs, terminated, truncated)
        if terminated or truncated:
            obs, _ = env.reset()
            new_trajectory[step + 1] = True
        else:
            obs = next_obs
    states[n_steps] = split_observation(obs, state_dim)[0][0]
    seconds = time.perf_counter() - start
    if n_steps in trail_starts:
        trail = _broken_at_resets(states, new_trajectory, trail_starts[n_steps], n_steps + 1)
        snapshots.append(snapshot(model, int(tasks[0]), n_steps, trail))
    rewards = observed
    if expected_rewards:
        rewards = np.empty(n_steps)
        family = task_family_of(env)
        for task in np.unique(tasks):
            rewards[tasks == task] = family.expected_reward(states[:n_steps][tasks == task], int(task))
    return RunRecord(
        rewards=rewards,
        tasks=tasks,
        policy_updates=sum(model.policy_updates.values()) - updates_before,
        seconds=seconds,
        snapshots=snapshots,
    )


def transfer_run(
    method: Method,
    task: int,
    seed: int,
    n_source: int | None = None,
    n_online: int | None = None,
    snapshot_at: Sequence[int] = (),
    env_kwargs: dict[str, Any] | None = None,
    protocol: Protocol = AS_BUILT,
) -> RunRecord:
    """
    One run of the paper's transfer experiments (Figures 1-7): ``n_source`` random transitions, their
    rewards discarded, then ``n_online`` online transitions on ``task``.

    The source transitions are drawn on another task (it does not matter: their rewards are discarded),
    seeded by ``seed`` too, so that a run is reproducible from its seed alone.

    :param method: how TRLSD learns
    :param task: target task index 0..24
    :param seed: the run's seed
    :param n_source: random source transitions, ignored without transfer (None: ``SOURCE_TRANSITIONS``)
    :param n_online: online transitions (None: ``ONLINE_TRANSITIONS``)
    :param snapshot_at: steps after which to take pictures
    :param env_kwargs: keyword arguments of the target task's env (e.g. ``reward_noise_std``), over the
        protocol's; paper's settings by default
    :param protocol: the choices the paper leaves open (its ``source_sets`` does not apply: a run alone has
        a source set of its own)
    :return: the record
    """
    start = time.perf_counter()
    n_source = SOURCE_TRANSITIONS if n_source is None else n_source
    n_online = ONLINE_TRANSITIONS if n_online is None else n_online
    env = target_env(task, protocol, env_kwargs)
    model = method.make_model(env, seed, protocol)
    if method.transfer and n_source:
        source_env = gym.make(MAZE_ID, task=(task + 1 + seed) % 25)
        model.load_transitions(collect_transitions(source_env, n_source, seed=seed + 1), keep_rewards=False)
    record = run_online(model, env, n_online, seed, snapshot_at)
    record.seconds = time.perf_counter() - start
    return record


def multitask_run(
    method: Method, seed: int, n_turns: int = 20, episode_steps: int = 50, protocol: Protocol = AS_BUILT
) -> RunRecord:
    """
    One run of the multi-task experiment (Figure 8): the 25 tasks in turn, one trajectory of
    ``episode_steps`` transitions per task per turn, no source data.

    :param method: how TRLSD learns (its ``transfer`` is ignored: there is no source)
    :param seed: the run's seed
    :param n_turns: turns over the 25 tasks
    :param episode_steps: transitions per trajectory
    :param protocol: the choices the paper leaves open
    :return: the record, ``n_turns * 25 * episode_steps`` transitions
    """
    env = multitask_env(episode_steps, protocol)
    model = method.make_model(env, seed, protocol)
    return run_online(model, env, n_turns * N_TASKS * episode_steps, seed)


def target_env(task: int, protocol: Protocol = AS_BUILT, env_kwargs: dict[str, Any] | None = None) -> gym.Env:
    """
    The maze of a transfer run's online phase on ``task``.

    :param task: the target task index 0..24
    :param protocol: the choices the paper leaves open (its online restarts)
    :param env_kwargs: further keyword arguments of the maze, over the protocol's
    """
    return gym.make(MAZE_ID, task=task, **(protocol.target_env_kwargs() | (env_kwargs or {})))


def multitask_env(episode_steps: int, protocol: Protocol = AS_BUILT) -> gym.Env:
    """
    The maze of Figure 8: the 25 tasks in turn, trajectories of ``episode_steps`` without restarts, each
    starting where the protocol's ``multitask_start`` says.
    """
    return gym.make(
        MAZE_ID,
        tasks="all",
        task_schedule="round_robin",
        termination_prob=0.0,
        max_episode_steps=episode_steps,
        **protocol.multitask_env_kwargs(),
    )
