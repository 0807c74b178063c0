"""The Q-functions of the runs an ``Engine`` steps: one per run and task, evaluated and refitted by batch.

``PolicyQFunctions`` are those of one run, held by a ``TaskQPolicy`` (the linear Q or the MLP): what ``TRLSD``
saves with the policy. ``LinearRunsQFunctions`` are the linear Q of R runs (theta of shape (R, tasks, actions,
k) on one feature map), refitted together by ``fit_linear_fqi_runs``: runs that start from the same source
transitions share those rows, and the products of eq. 4 over them are matrix-matrix products for all runs.
Both fit a run's Q on the rows of its shared buffer, relabelled for the task (the rewards come in the
buffer's order, oldest first); the engine hands them the rows each run's buffer gained since its last read
(``extend``) before it fits.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.fit_rows import FitRows, LinearFitRows
from sb3_trlsd.fqi import FQIResult, PolicyMoments, fit_linear_fqi_runs
from sb3_trlsd.policies import LinearPolicy, TaskQPolicy

__all__ = ["LinearRunsQFunctions", "PolicyQFunctions", "QFunctions"]


class QFunctions(Protocol):
    """The Q-function of every (run, task) of an engine."""

    default_max_iterations: int  # fitted iterations of a refit when no cap is set
    default_solver: str  # how a refit reaches Fitted-Q's fixed point when no solver is set

    def q_values(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """
        Q of each state's run and task.

        :param runs: the run of each state, (n,)
        :param states: (n, d)
        :param tasks: the task of each state, (n,)
        :return: (n, n_actions)
        """
        ...

    def extend(self, run: int, rows: Transitions, restart: bool) -> None:
        """
        Take the rows a run's buffer gained since the last call (the engine's one read of it).

        :param run: the run
        :param rows: the new rows, oldest first
        :param restart: the buffer lost rows: ``rows`` are all of them, the earlier ones are gone
        """
        ...

    def fit(
        self,
        pairs: Sequence[tuple[int, int]],
        rewards: Sequence[np.ndarray],
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> list[FQIResult]:
        """
        Refit the Q of each ``(run, task)`` on its run's rows with those rewards, from its parameters now.

        :param pairs: the (run, task) pairs
        :param rewards: each pair's relabelled rewards, one per row of its run, oldest first
        :param gamma: discount factor
        :param max_iterations: cap on the fitted iterations
        :param tol: relative stopping tolerance
        :param stop_rule: the stopping rule, one of ``sb3_trlsd.fqi.STOP_RULES``
        :param solver: how the fixed point is reached, one of ``sb3_trlsd.fqi.SOLVERS``
        :return: one result per pair
        """
        ...


class PolicyQFunctions:
    """
    The Q-functions of one run, those of a ``TaskQPolicy`` (each refit is the policy's ``fit``).

    :param policy: the policy
    """

    def __init__(self, policy: TaskQPolicy):
        self.policy = policy
        self.default_max_iterations = policy.default_max_iterations
        self.default_solver = policy.default_solver
        self.rows: FitRows = policy.new_fit_rows()  # the buffer's rows as the Q-function fits on them

    def q_values(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        assert not np.any(runs), "a policy holds the Q-functions of one run"
        return self.policy.q_values(states, tasks)

    def extend(self, run: int, rows: Transitions, restart: bool) -> None:
        assert run == 0, "a policy holds the Q-functions of one run"
        if restart:
            self.rows.clear()
        self.rows.extend(rows)

    def fit(
        self,
        pairs: Sequence[tuple[int, int]],
        rewards: Sequence[np.ndarray],
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> list[FQIResult]:
        results = []
        for (run, task), task_rewards in zip(pairs, rewards, strict=True):
            assert run == 0, "a policy holds the Q-functions of one run"
            results.append(
                self.policy.fit(task, self.rows, task_rewards, gamma, max_iterations, tol, stop_rule, solver)
            )
        return results


class LinearRunsQFunctions:
    """
    The linear Q of R runs, Q_r,tau(s, a) = theta[r, tau, a] . Phi(s) (eq. 3), refitted together.

    The first ``n_shared`` rows of every run's buffer are the same transitions (a source set every run starts
    from): they are kept once, sorted by action, and every refit shares their products. The rows after them
    are each run's own.

    :param policy: a ``LinearPolicy`` whose features and Fitted-Q settings (ridge, precision) every run takes
    :param buffers: each run's shared buffer, indexed by run
    :param n_shared: the first rows every buffer holds alike (0: none)
    """

    def __init__(
        self, policy: LinearPolicy, buffers: Sequence[SharedDynamicsReplayBuffer], n_shared: int = 0
    ):
        self.features = policy.features
        self.default_max_iterations = policy.default_max_iterations
        self.default_solver = policy.default_solver
        self.theta = np.zeros((len(buffers), *policy.theta.shape))
        self.own_rows: list[LinearFitRows] = [policy.new_fit_rows() for _ in buffers]
        self.n_shared = int(n_shared)
        self.shared_rows: LinearFitRows | None = None
        self.shared_order = np.zeros(0, dtype=np.int64)
        if self.n_shared:
            # Sorted by action, each action's rows are a range the iterations slice; the shared part of a
            # fit's rewards follows that order (``shared_order``).
            rows = buffers[0].transitions().take(np.arange(self.n_shared))
            self.shared_order = np.argsort(rows.actions, kind="stable")
            self.shared_rows = policy.new_fit_rows()
            self.shared_rows.extend(rows.take(self.shared_order))
        self._rows_seen = [0] * len(buffers)  # rows of each run taken so far, the shared ones included
        # Policy iteration's cross moments of each (run, task)'s Q, kept between its refits.
        self.policy_moments: dict[tuple[int, int], PolicyMoments] = {}

    def q_values(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        phi = self.features(np.asarray(states, dtype=np.float64))  # (n, k)
        return np.einsum("nk,nak->na", phi, self.theta[runs, tasks])

    def extend(self, run: int, rows: Transitions, restart: bool) -> None:
        # A run's first rows are the shared ones, kept once for every run: its own rows come after them.
        assert not (restart and self._rows_seen[run]), "a run of a batch keeps every row: it never wraps"
        first_own = max(0, self.n_shared - self._rows_seen[run])  # rows before it are shared ones
        self._rows_seen[run] += len(rows)
        self.own_rows[run].extend(rows if first_own == 0 else rows.take(np.arange(first_own, len(rows))))

    def fit(
        self,
        pairs: Sequence[tuple[int, int]],
        rewards: Sequence[np.ndarray],
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> list[FQIResult]:
        fit = functools.partial(
            fit_linear_fqi_runs,
            gamma=gamma,
            max_iterations=max_iterations,
            tol=tol,
            stop_rule=stop_rule,
            solver=solver,
        )
        theta0 = [self.theta[run, task] for run, task in pairs]
        moments = [self.policy_moments.setdefault(pair, PolicyMoments()) for pair in pairs]
        if self.shared_rows is not None:
            # The shared rows are every run's: one fit, its products over them shared by all pairs.
            shared, order = self.shared_rows.solver, self.shared_order
            reordered = [np.concatenate([r[: self.n_shared][order], r[self.n_shared :]]) for r in rewards]
            own = [self.own_rows[run].solver for run, _ in pairs]
            results = fit(shared, own, reordered, theta0=theta0, policy_moments=moments)
        else:
            # Without shared rows, runs share no products: a fit per run, over its tasks due now.
            results_of: dict[int, FQIResult] = {}
            for run in sorted({run for run, _ in pairs}):
                mine = [i for i, (other, _) in enumerate(pairs) if other == run]
                fitted = fit(
                    self.own_rows[run].solver,
                    [None] * len(mine),
                    [rewards[i] for i in mine],
                    theta0=[theta0[i] for i in mine],
                    policy_moments=[moments[i] for i in mine],
                )
                results_of.update(zip(mine, fitted, strict=True))
            results = [results_of[i] for i in range(len(pairs))]
        for (run, task), result in zip(pairs, results, strict=True):
            assert result.theta is not None
            self.theta[run, task] = result.theta
        return results
