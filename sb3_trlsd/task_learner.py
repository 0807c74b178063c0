"""Everything incremental about one task, owned in one place (paper, Algorithm 1 and section 3).

A ``TaskLearner`` holds a task's reward head (its samples Xi_tau, R^ and the uncertainty of eq. 9-10), the
uncertainty as of the task's last refit (the trigger of section 3 compares the current one with it), the
refit count, whether a refit is due, and the relabelling of the shared buffer for the task, psi: R~_tau at
the start state of every stored transition, kept up to date with only the rows and samples added since the
last refit. The Q-function itself (and its warm start, the current parameters) is the policy's; the
buffer's rows as the Q-function's fit consumes them are shared by all tasks (``fit_rows.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_trlsd.buffers import BufferCursor, SharedDynamicsReplayBuffer
from sb3_trlsd.reward_heads import RewardHead, RewardTracker

__all__ = ["TaskLearner"]


class TaskLearner:
    """
    One task's learning state.

    :param task: the task index
    :param head: the task's reward head (its own samples only)
    :param update_ratio: the task is due for a refit once the uncertainty at an encountered state has been
        divided by this since its last refit (> 1)
    """

    def __init__(self, task: int, head: RewardHead, update_ratio: float):
        if not update_ratio > 1:
            raise ValueError(
                f"update_ratio must be > 1 (the CI must shrink to trigger a refit), got {update_ratio}"
            )
        self.task = int(task)
        self.head = head
        self.update_ratio = float(update_ratio)
        self.refits = 0
        self.due = False
        self.uncertainty_at_refit: Any = None  # head.snapshot() at the last refit; None before the first
        self.rows_at_refit = 0  # rows of the shared buffer at the last refit
        # Derived from the head and the buffer, rebuilt after loading: not saved.
        self._relabelling: RewardTracker | None = None
        self._cursor = BufferCursor()

    def __repr__(self) -> str:
        return f"TaskLearner(task={self.task}, refits={self.refits}, due={self.due}, head={self.head!r})"

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_relabelling"], state["_cursor"] = None, BufferCursor()
        return state

    @property
    def fitted(self) -> bool:
        """Whether the task's Q-function was fitted at least once."""
        return self.refits > 0

    def observe(self, state: np.ndarray, reward: float, n_rows: int) -> None:
        """
        Add one online sample of the task to its reward head, and mark the task due if the trigger fires:
        section 3 refits once the CI at an encountered state has been divided by ``update_ratio`` since the
        last refit. The ratio is taken on the kappa-free uncertainty, so that kappa = 0 triggers the same way.
        A head without uncertainty (the known reward) has nothing to divide: it refits when the shared buffer
        has grown by ``update_ratio`` since the last refit, so that new dynamics data reaches its policy. A
        head may have a rule of its own (``RewardHead.refit_due``: the OFUL head's is determinant doubling).

        :param state: the transition's start state (d,)
        :param reward: the reward observed there
        :param n_rows: the rows of the shared buffer now
        """
        state = np.asarray(state, dtype=np.float64).reshape(1, -1)
        self.head.update(state, np.array([reward], dtype=np.float64))
        if not self.fitted or self.due:
            return
        if not self.head.has_uncertainty:
            self.due = n_rows >= self.update_ratio * max(self.rows_at_refit, 1)
            return
        self.due = self.head.refit_due(self.uncertainty_at_refit, state, self.update_ratio)

    def relabelled_rewards(self, buffer: SharedDynamicsReplayBuffer) -> np.ndarray:
        """
        R~_tau at the start state of every transition of the buffer, oldest first (Psi of section 2); between
        two calls only the new rows and the head's new samples are folded in.

        :param buffer: the shared buffer
        :return: rewards (n,)
        """
        if self._relabelling is None:
            self._cursor = BufferCursor()
        rows, restart = buffer.read_new(self._cursor)
        if restart or self._relabelling is None:
            self._relabelling = self.head.tracker(rows.states)
        else:
            self._relabelling.extend(rows.states)
        return self._relabelling.optimistic()

    def refitted(self, n_rows: int) -> None:
        """
        Record a refit of the task's Q-function: the trigger now compares with the uncertainty of now.

        :param n_rows: the rows of the shared buffer it was fitted on
        """
        self.uncertainty_at_refit = self.head.snapshot()
        self.rows_at_refit = int(n_rows)
        self.refits += 1
        self.due = False
