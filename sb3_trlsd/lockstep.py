"""Runs of TRLSD's online phase stepped in lockstep: R runs of one method, one vectorised step for all.

A ``Lockstep`` holds R runs of the same settings (a ``TRLSD`` model's), each with its own buffer, task
learners (``TaskLearner``: reward heads, trigger, relabelling) and linear Q parameters, and steps them
together: one feature evaluation and one product pick every run's greedy action, the envs move as one
vectorised call (an ``EnvBatch``), and the refits of every run whose trigger fired at a step are one call
of ``fit_linear_fqi_runs``. Runs that start from the same source transitions share their rows in that fit:
the products of eq. 4 over the source are matrix-matrix products for all of them.

The algorithm is TRLSD's own, not a copy: the same ``TaskLearner`` (eq. 5-10 and the trigger of section 3),
the same buffer class and the same Fitted-Q function (``LinearFQISolver.fit`` is ``fit_linear_fqi_runs``
with one run). A run of a batch takes the actions and refits of a ``TRLSD`` model driven alone with the same
seed and source set (``tests/test_lockstep.py``), up to the order of floating-point sums.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from sb3_trlsd.buffers import BufferCursor, SharedDynamicsReplayBuffer
from sb3_trlsd.builders import new_task_learner
from sb3_trlsd.data import Transitions
from sb3_trlsd.fit_rows import LinearFitRows
from sb3_trlsd.fqi import fit_linear_fqi_runs
from sb3_trlsd.policies import LinearPolicy
from sb3_trlsd.task_learner import TaskLearner
from sb3_trlsd.trlsd import TRLSD

__all__ = ["EnvBatch", "Lockstep", "LockstepRecord"]


class EnvBatch(Protocol):
    """One env per run, stepped together. States are (R, d) arrays as the envs observe them (float32)."""

    def reset(self, runs: Sequence[int], seeds: Sequence[int | None]) -> tuple[np.ndarray, np.ndarray]:
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


class _Run:
    """One run's learning state: its buffer, task learners, own fit rows and Q parameters."""

    def __init__(self, model: TRLSD, buffer_size: int, source: Transitions | None, n_tasks: int):
        self.buffer = model.replay_buffer_class(
            buffer_size, model.observation_space, model.action_space, device="cpu", n_envs=1
        )
        assert isinstance(self.buffer, SharedDynamicsReplayBuffer)
        if source is not None:
            self.buffer.add_transitions(source, keep_rewards=False)
        self.own_rows: LinearFitRows = model.policy.new_fit_rows()  # online rows, in the FQI's form
        self.own_cursor = BufferCursor(self.buffer.epoch, self.buffer.n_added)
        self.learners: dict[int, TaskLearner] = {}
        self.theta = np.zeros((n_tasks, model.policy.n_actions, model.features.n_features))
        self.pending: list[tuple] = []  # online rows not yet written to the buffer

    @property
    def n_rows(self) -> int:
        """The run's rows, written or held back (what ``TRLSD``'s buffer would hold)."""
        return self.buffer.size() + len(self.pending)

    def write_pending(self) -> None:
        """Write the online rows held back since the last refit: rows are read only at refits."""
        if not self.pending:
            return
        states, actions, rewards, next_states, tasks, truncated, terminated = map(
            np.array, zip(*self.pending, strict=True)
        )
        self.buffer.add_transitions(
            Transitions(states, actions, next_states, rewards, tasks, truncated, terminated),
            keep_rewards=True,
        )
        self.pending.clear()
        rows, restart = self.buffer.read_new(self.own_cursor)
        assert not restart, "a lockstep run's buffer holds every row: it never wraps around"
        self.own_rows.extend(rows)


class Lockstep:
    """
    R runs of TRLSD's online phase with the settings of ``model``, stepped together.

    Each run starts with the ``source`` transitions in its buffer (their rewards discarded), and acts as
    ``TRLSD.act``/``TRLSD.add_online_transition`` do: a task's Q is fitted at its first step, the greedy
    action is taken, the transition feeds its task's learner, and the tasks whose trigger fired are refitted.

    :param model: a ``TRLSD`` model with the ``LinearPolicy`` whose settings (reward head, kappa, sigma,
        update ratio, gamma, features, Fitted-Q settings) every run takes; its own buffer and learners are not
        used. Runs share its feature map
    :param envs: the runs' envs, one per run
    :param n_runs: the runs
    :param source: the transitions every run starts from, or None
    :param n_steps: online transitions per run (the buffers are sized for them)
    """

    def __init__(self, model: TRLSD, envs: EnvBatch, n_runs: int, source: Transitions | None, n_steps: int):
        if not isinstance(model.policy, LinearPolicy):
            raise ValueError(
                f"runs in lockstep fit the linear Q (LinearPolicy), got {type(model.policy).__name__}: "
                "drive other policies one run at a time (sb3_trlsd.experiments.runner.run_online)"
            )
        if n_runs < 1:
            raise ValueError(f"n_runs must be >= 1, got {n_runs}")
        self.model, self.envs, self.n_steps = model, envs, int(n_steps)
        self.n_tasks, self.state_dim = model.policy.n_tasks, model.replay_buffer.obs_shape[0]
        buffer_size = (0 if source is None else len(source)) + max(self.n_steps, 1)
        self.runs = [_Run(model, buffer_size, source, self.n_tasks) for _ in range(n_runs)]
        self.seeds: list[int | None] = [model.seed] * n_runs  # each run's, as ``run`` is given them
        self.shared_rows: LinearFitRows | None = None  # the source's rows, in the FQI's form
        self.n_source = 0 if source is None else len(source)
        if source is not None:
            # Sorted by action, each action's rows are a range the iterations slice; the source rewards of a
            # fit follow that order (``source_order``).
            rows = self.runs[0].buffer.transitions()
            self.source_order = np.argsort(rows.actions, kind="stable")
            self.shared_rows = model.policy.new_fit_rows()
            self.shared_rows.extend(rows.take(self.source_order))

    def learner(self, run: int, task: int) -> TaskLearner:
        """
        The learning state of ``task`` in ``run``, created (no samples) the first time it is asked for, as a
        ``TRLSD`` model of the run's seed creates it (a seeded head draws from that seed).
        """
        learners = self.runs[run].learners
        if task not in learners:
            learners[task] = new_task_learner(self.model, task, seed=self.seeds[run])
        return learners[task]

    def refit(self, pairs: Sequence[tuple[int, int]]) -> None:
        """
        Refit the Q of each ``(run, task)`` on its run's relabelled buffer (``TRLSD.update_policy``), all in
        one ``fit_linear_fqi_runs``.
        """
        if not pairs:
            return
        for run in {run for run, _ in pairs}:
            self.runs[run].write_pending()
        rewards = [self.learner(run, task).relabelled_rewards(self.runs[run].buffer) for run, task in pairs]
        model = self.model
        settings = {
            "gamma": model.gamma,
            "max_iterations": model.fqi_max_iterations or model.policy.default_max_iterations,
            "tol": model.fqi_tol,
        }
        theta0 = [self.runs[run].theta[task] for run, task in pairs]
        if self.shared_rows is not None:
            # The source's rows are every run's: one fit, its products over them shared by all pairs.
            own = [self.runs[run].own_rows.solver for run, _ in pairs]
            order = self.source_order
            rewards = [np.concatenate([r[: self.n_source][order], r[self.n_source :]]) for r in rewards]
            results = fit_linear_fqi_runs(self.shared_rows.solver, own, rewards, theta0=theta0, **settings)
        else:
            # Without a source, runs share no row: a fit per run, over the tasks of that run due now.
            results = [None] * len(pairs)
            for run in sorted({run for run, _ in pairs}):
                mine = [i for i, (other, _) in enumerate(pairs) if other == run]
                fitted = fit_linear_fqi_runs(
                    self.runs[run].own_rows.solver,
                    [None] * len(mine),
                    [rewards[i] for i in mine],
                    theta0=[theta0[i] for i in mine],
                    **settings,
                )
                for i, result in zip(mine, fitted, strict=True):
                    results[i] = result
        for (run, task), result in zip(pairs, results, strict=True):
            assert result.theta is not None
            self.runs[run].theta[task] = result.theta
            self.learner(run, task).refitted(n_rows=self.runs[run].buffer.size())

    def greedy_actions(self, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """Each run's greedy action: argmax_a theta[task, a] . Phi(s) (eq. 3), for all runs at once."""
        phi = self.model.features(np.asarray(states, dtype=np.float64))  # (R, k)
        theta = np.stack([run.theta[task] for run, task in zip(self.runs, tasks, strict=True)])  # (R, A, k)
        return np.einsum("rk,rak->ra", phi, theta).argmax(axis=1)

    def run(self, seeds: Sequence[int]) -> list[LockstepRecord]:
        """
        ``n_steps`` online transitions of every run, the env of run r first reset with ``seeds[r]``.

        :return: one record per run
        """
        n_runs = len(self.runs)
        if len(seeds) != n_runs:
            raise ValueError(f"one seed per run: {n_runs} runs, got {len(seeds)} seeds")
        self.seeds = list(seeds)
        everyone = np.arange(n_runs)
        states, tasks = self.envs.reset(everyone, list(seeds))
        records = [
            LockstepRecord(
                states=np.empty((self.n_steps, self.state_dim)),
                tasks=np.empty(self.n_steps, dtype=np.int64),
                actions=np.empty(self.n_steps, dtype=np.int64),
            )
            for _ in range(n_runs)
        ]
        for step in range(self.n_steps):
            # A task's Q is fitted at its first step, before its run acts on it (unless first_fit waits).
            first_fits = [
                (r, int(t)) for r, t in enumerate(tasks) if self.learner(r, int(t)).fit_before_acting
            ]
            self._refit_and_record(first_fits, records, step)
            actions = self.greedy_actions(states, tasks)
            next_states, rewards, terminated, truncated = self.envs.step(actions)
            # As the buffer stores them: the reward in float32, as SB3's buffer does.
            rewards = rewards.astype(np.float32).astype(np.float64)
            due = []
            for r, run in enumerate(self.runs):
                record = records[r]
                record.states[step], record.tasks[step], record.actions[step] = (
                    states[r],
                    tasks[r],
                    actions[r],
                )
                run.pending.append(
                    (states[r], actions[r], rewards[r], next_states[r], tasks[r], truncated[r], terminated[r])
                )
                self.learner(r, int(tasks[r])).observe(states[r], rewards[r], n_rows=run.n_rows)
                due += [(r, task) for task, learner in sorted(run.learners.items()) if learner.due]
            self._refit_and_record(due, records, step + 1)
            states = next_states
            ended = np.flatnonzero(terminated | truncated)
            if len(ended):
                states = states.copy()
                tasks = tasks.copy()
                states[ended], tasks[ended] = self.envs.reset(ended, [None] * len(ended))
        return records

    def _refit_and_record(
        self, pairs: list[tuple[int, int]], records: list[LockstepRecord], step: int
    ) -> None:
        self.refit(pairs)
        for run, task in pairs:
            records[run].refit_steps.append((step, task))
