"""Runs of TRLSD's online phase stepped in lockstep: R runs of one method, one vectorised step for all.

A ``Lockstep`` drives TRLSD's ``Engine`` with R runs of the same settings (a ``TRLSD`` model's), each with
its own buffer and task learners, their linear Q refitted together (``LinearRunsQFunctions``: runs that
start from the same source transitions share those rows in each fit). What it adds to the engine is what a
batch adds: the envs moving as one vectorised call (an ``EnvBatch``) and what each run did (its record).
A run of a batch takes the actions and refits of a ``TRLSD`` model driven alone with the same seed and
source set (``tests/test_lockstep.py``), up to the order of floating-point sums.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from sb3_trlsd.action_choice import explore_rng, tie_rng
from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.engine import Engine, Run, RunRows
from sb3_trlsd.fqi import FQIResult
from sb3_trlsd.policies import LinearPolicy
from sb3_trlsd.q_functions import LinearRunsQFunctions
from sb3_trlsd.task_learner import TaskLearner
from sb3_trlsd.trlsd import TRLSD

__all__ = ["EnvBatch", "Lockstep", "LockstepRecord"]


class EnvBatch(Protocol):
    """One env per run, stepped together. States are (R, d) arrays as the envs observe them (float32)."""

    def reset(
        self, runs: Sequence[int] | np.ndarray, seeds: Sequence[int | None]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reset the given runs' envs (seeded, or not with None): their states (m, d) and tasks (m,)."""
        ...

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step every env: next states (R, d), rewards (R,), terminated (R,), truncated (R,)."""
        ...


@dataclass
class LockstepRecord:
    """
    What one run of a ``Lockstep`` did online.

    :param states: the state each online transition starts from, (n_steps, d)
    :param tasks: the task of each online transition, (n_steps,)
    :param actions: the action of each, (n_steps,)
    :param refit_steps: the step of each refit, its first fit included (a refit after the transition of
        step t counts as t + 1: it comes before the action of step t + 1), in order, with its task
    """

    states: np.ndarray
    tasks: np.ndarray
    actions: np.ndarray
    refit_steps: list[tuple[int, int]] = field(default_factory=list)


class Lockstep:
    """
    R runs of TRLSD's online phase with the settings of ``model``, stepped together by one ``Engine``.

    Each run starts with the ``source`` transitions in its buffer (their rewards discarded), and acts as
    ``TRLSD.act``/``TRLSD.add_online_transition`` do: a task's Q is fitted at its first step, the greedy
    action is taken (or an exploratory one, ``Engine.behave``), the transition feeds its task's learner,
    and the tasks whose trigger fired are refitted.

    :param model: a ``TRLSD`` model with the ``LinearPolicy`` whose settings (``model.config``, gamma, the
        policy's features and Fitted-Q settings) every run takes; its own buffer and learners are not used
    :param envs: the runs' envs, one per run
    :param n_runs: the runs
    :param source: the transitions every run starts from, or None
    :param n_steps: online transitions per run (the buffers are sized for them)
    """

    def __init__(self, model: TRLSD, envs: EnvBatch, n_runs: int, source: Transitions | None, n_steps: int):
        if not isinstance(model.policy, LinearPolicy):
            raise ValueError(
                f"runs in lockstep fit the linear Q (LinearPolicy), got {type(model.policy).__name__}: "
                "drive other policies one run at a time (sb3_trlsd_lab.execution.runner.run_online)"
            )
        if n_runs < 1:
            raise ValueError(f"n_runs must be >= 1, got {n_runs}")
        self.model, self.envs, self.n_steps = model, envs, int(n_steps)
        self.state_dim = model.replay_buffer.obs_shape[0]
        n_source = 0 if source is None else len(source)
        buffer_class = model.replay_buffer_class
        assert buffer_class is not None and issubclass(buffer_class, SharedDynamicsReplayBuffer)
        buffers = []
        for _ in range(n_runs):
            buffer = buffer_class(
                n_source + max(self.n_steps, 1),
                model.observation_space,
                model.action_space,
                device="cpu",
                n_envs=1,
            )
            if source is not None:
                buffer.add_transitions(source, keep_rewards=False)
            buffers.append(buffer)
        self.seeds: list[int | None] = [model.seed] * n_runs  # each run's, as ``run`` is given them
        assert model.reward_timing is not None, "resolved on the model's env"
        self.records: list[LockstepRecord] = []
        self.step = 0  # the step a refit counts for (see ``LockstepRecord.refit_steps``)
        self.engine = Engine(
            [Run(buffer, RunRows(model.reward_timing), hold_back=True) for buffer in buffers],
            LinearRunsQFunctions(model.policy, buffers, n_shared=n_source),
            lambda run, task: model.new_task_learner(task, seed=self.seeds[run]),
            gamma=model.gamma,
            max_iterations=model.config.fqi_max_iterations,
            tol=model.config.fqi_tolerance,
            stop_rule=model.config.fqi_stop,
            solver=model.config.fqi_solver,
            exploration=model.config.exploration,
            on_refit=self._record_refit,
        )

    def _record_refit(self, run: int, learner: TaskLearner, result: FQIResult, rewards: np.ndarray) -> None:
        self.records[run].refit_steps.append((self.step, learner.task))

    def run(self, seeds: Sequence[int]) -> list[LockstepRecord]:
        """
        ``n_steps`` online transitions of every run, the env of run r first reset with ``seeds[r]``.

        :return: one record per run
        """
        n_runs = len(self.engine.runs)
        if len(seeds) != n_runs:
            raise ValueError(f"one seed per run: {n_runs} runs, got {len(seeds)} seeds")
        self.seeds = list(seeds)
        for run, seed in zip(self.engine.runs, seeds, strict=True):
            run.ties = tie_rng(seed) if self.model.config.tie_break == "random" else None
            run.explore = explore_rng(seed)
        everyone = np.arange(n_runs)
        states, tasks = self.envs.reset(everyone, list(seeds))
        self.records = [
            LockstepRecord(
                states=np.empty((self.n_steps, self.state_dim)),
                tasks=np.empty(self.n_steps, dtype=np.int64),
                actions=np.empty(self.n_steps, dtype=np.int64),
            )
            for _ in range(n_runs)
        ]
        for step in range(self.n_steps):
            self.step = step  # a first fit comes before the action of its step
            actions = self.engine.act(everyone, states, tasks)
            next_states, rewards, terminated, truncated = self.envs.step(actions)
            for record, state, task, action in zip(self.records, states, tasks, actions, strict=True):
                record.states[step], record.tasks[step], record.actions[step] = state, task, action
            self.step = step + 1  # a refit after the transition of step t comes before the action of t + 1
            self.engine.step(everyone, states, actions, rewards, next_states, tasks, terminated, truncated)
            self.engine.refit_due()
            states = next_states
            ended = np.flatnonzero(terminated | truncated)
            if len(ended):
                states = states.copy()
                tasks = tasks.copy()
                states[ended], tasks[ended] = self.envs.reset(ended, [None] * len(ended))
        return self.records
