"""Everything incremental about one task, owned in one place (paper, Algorithm 1 and section 3).

A ``TaskLearner`` holds a task's reward head (its samples Xi_tau, R^ and the uncertainty of eq. 9-10), the
uncertainty as of the task's last refit (the trigger of section 3 compares the current one with it), the
refit count, whether a refit is due, and the relabelling of the shared buffer for the task, psi: R~_tau at
the rewarded input of every stored transition, kept up to date with only the rows and samples added since
the last refit. The Q-function itself (and its warm start, the current parameters) is the policy's; the
buffer's rows, as the engine reads them once per refit, are shared by all tasks (``engine.RunRows``).

Feeding the head its rewards (``learn``) and relabelling rows for the task (psi: ``relabel``, or
``relabelled_rewards`` over every row, kept up to date) are written here once, for ``TRLSD``'s engine and for
the ``RelabellingReplayBuffer`` alike.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from sb3_trlsd.reward_heads import RewardHead, RewardTracker
from sb3_trlsd.reward_timing import REWARD_TIMINGS, rewarded_inputs

__all__ = ["FIRST_FIT_RULES", "OPTIMISM_RULES", "TRAIL_LENGTH", "TaskLearner"]

# When a task's Q-function is first fitted (the paper does not say): before its first action, on R~ of no
# sample (the optimism of an empty head); or once its first sample (and reward) is in, acting before that
# with the unfitted Q (every action ties: the policy's argmax takes the first).
FIRST_FIT_RULES = ("first_step", "first_sample")

# Where the buffer is relabelled with the optimistic R~ rather than the estimate R^: always (the paper), or
# once the buffer holds rows the task did not collect online (a source, other tasks' rows). Fitted-Q sees
# the buffer's rows only: with none but the task's own, a bonus or a draw values the rows it visited against
# unvisited ones left at 0, which keeps the greedy policy among the visited.
OPTIMISM_RULES = ("always", "with_source")
TRAIL_LENGTH = 50  # the task's latest online states a learner keeps (its picture's trajectory)


class TaskLearner:
    """
    One task's learning state.

    :param task: the task index
    :param head: the task's reward head (its own samples only)
    :param update_ratio: the task is due for a refit once the uncertainty at an encountered state has been
        divided by this since its last refit (> 1)
    :param first_fit: when the task is first fitted, one of ``FIRST_FIT_RULES``: ``"first_step"`` (before
        its first action, see ``fit_before_acting``) or ``"first_sample"`` (due once its first sample is in)
    :param reward_timing: what of a transition its reward belongs to, one of ``REWARD_TIMINGS``: the head
        learns, and relabels the buffer, at that input (``rewarded_inputs``)
    :param refit_growth: once the trigger has fired, the refit waits until the task's samples have grown by
        this fraction since its last refit (at least one new sample); 0 refits as soon as it fires (the
        paper). Refits are then at most about 1 / refit_growth + ln(n) / ln(1 + refit_growth) over n samples,
        the lazy updates of rarely-switching optimism (Abbasi-Yadkori et al., 2011)
    :param optimism: where the buffer is relabelled with R~ rather than R^, one of ``OPTIMISM_RULES``:
        ``"always"`` (the paper) or ``"with_source"`` (once the buffer holds rows the task did not collect)
    """

    def __init__(
        self,
        task: int,
        head: RewardHead,
        update_ratio: float,
        first_fit: str = "first_step",
        reward_timing: str = "start_state",
        refit_growth: float = 0.0,
        optimism: str = "always",
    ):
        if not update_ratio > 1:
            raise ValueError(
                f"update_ratio must be > 1 (the CI must shrink to trigger a refit), got {update_ratio}"
            )
        if first_fit not in FIRST_FIT_RULES:
            raise ValueError(f"first_fit must be one of {list(FIRST_FIT_RULES)}, got {first_fit!r}")
        if reward_timing not in REWARD_TIMINGS:
            raise ValueError(f"reward_timing must be one of {list(REWARD_TIMINGS)}, got {reward_timing!r}")
        if not (np.isfinite(refit_growth) and refit_growth >= 0):
            raise ValueError(f"refit_growth must be >= 0 (a fraction of the samples), got {refit_growth}")
        if optimism not in OPTIMISM_RULES:
            raise ValueError(f"optimism must be one of {list(OPTIMISM_RULES)}, got {optimism!r}")
        self.optimism = optimism
        self.refit_growth = float(refit_growth)
        self.first_fit = first_fit
        self.reward_timing = reward_timing
        self.task = int(task)
        self.head = head
        self.update_ratio = float(update_ratio)
        self.refits = 0
        self.due = False
        self.triggered = False  # the trigger fired since the last refit (the refit may wait: refit_growth)
        self.samples = 0  # online samples of the task
        self.samples_at_refit = 0
        self.uncertainty_at_refit: Any = None  # head.snapshot() at the last refit; None before the first
        self.rows_at_refit = 0  # rows of the shared buffer at the last refit
        # The latest online start states, each with whether its trajectory ended there.
        self.trail: deque[tuple[np.ndarray, bool]] = deque(maxlen=TRAIL_LENGTH)
        # Derived from the head and the run's rows, rebuilt after loading: not saved.
        self._relabelling: RewardTracker | None = None
        self._generation = 0  # of the run's rows the relabelling tracks

    def __repr__(self) -> str:
        return f"TaskLearner(task={self.task}, refits={self.refits}, due={self.due}, head={self.head!r})"

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_relabelling"], state["_generation"] = None, 0
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.__dict__.setdefault("trail", deque(maxlen=TRAIL_LENGTH))

    @property
    def fitted(self) -> bool:
        """Whether the task's Q-function was fitted at least once."""
        return self.refits > 0

    @property
    def fit_before_acting(self) -> bool:
        """Whether the task's Q-function must be fitted before its next action (its first, by default)."""
        return not self.fitted and self.first_fit == "first_step"

    def observe(
        self,
        state: np.ndarray,
        action: int,
        next_state: np.ndarray,
        reward: float,
        n_rows: int,
        ended: bool = False,
    ) -> None:
        """
        Add one online sample of the task to its reward head (the reward at the transition's start state,
        next state, both, or the whole step, as ``reward_timing`` says), and mark the task due if the trigger
        fires: section 3 refits once the CI at an encountered state has been divided by ``update_ratio``
        since the last refit. The ratio is taken on the kappa-free uncertainty, so that kappa = 0 triggers
        the same way. A head without uncertainty (the known reward) has nothing to divide: it refits when the
        shared buffer has grown by ``update_ratio`` since the last refit, so that new dynamics data reaches
        its policy. A head may have a rule of its own (``RewardHead.refit_due``: the OFUL head's is
        determinant doubling). A task never fitted is due after this sample under the ``"first_sample"`` rule
        (and waits for its first step under ``"first_step"``). Once the trigger has fired, the refit waits
        for ``refit_growth``.

        :param state: the transition's start state (d,)
        :param action: the action taken
        :param next_state: the state it arrived at (d,)
        :param reward: the reward observed for it
        :param n_rows: the rows of the shared buffer now
        :param ended: the trajectory ended with it (kept with the task's ``trail``)
        """
        rewarded = self.learn(
            np.asarray(state, dtype=np.float64).reshape(1, -1),
            np.array([action]),
            np.asarray(next_state, dtype=np.float64).reshape(1, -1),
            np.array([reward], dtype=np.float64),
        )
        self.trail.append((np.asarray(state, dtype=np.float64).copy(), bool(ended)))
        self.samples += 1
        if not self.fitted:
            self.due = self.due or self.first_fit == "first_sample"
            return
        if self.due:
            return
        if not self.triggered:
            if not self.head.has_uncertainty:
                self.triggered = n_rows >= self.update_ratio * max(self.rows_at_refit, 1)
            else:
                self.triggered = self.head.refit_due(self.uncertainty_at_refit, rewarded, self.update_ratio)
        new_samples = self.samples - self.samples_at_refit
        self.due = self.triggered and new_samples >= max(1.0, self.refit_growth * self.samples_at_refit)

    def inputs(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> np.ndarray:
        """
        What the task's head sees of transitions from ``states`` to ``next_states`` by ``actions``
        (``rewarded_inputs`` at its ``reward_timing``).

        :param states: start states (n, d)
        :param actions: action indices (n,)
        :param next_states: next states (n, d)
        :return: (n, d), (n, 2d) for the ``"transition"`` timing, (n, 2d + 1) for ``"step"``
        """
        return rewarded_inputs(states, actions, next_states, self.reward_timing)

    def learn(
        self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray, rewards: np.ndarray
    ) -> np.ndarray:
        """
        Teach the task's head the rewards of transitions of the task, at their rewarded inputs (``inputs``).

        :param states: start states (n, d)
        :param actions: (n,)
        :param next_states: (n, d)
        :param rewards: the rewards observed for them (n,)
        :return: the rewarded inputs, (n, p)
        """
        rewarded = self.inputs(states, actions, next_states)
        self.head.update(rewarded, np.asarray(rewards, dtype=np.float64))
        return rewarded

    def relabel(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> np.ndarray:
        """
        psi of section 2 on rows the task did not collect: R~_tau = R^_tau + CI_tau (eq. 5) at their rewarded
        inputs, the head as it is now.

        :param states: start states (n, d)
        :param actions: (n,)
        :param next_states: (n, d)
        :return: rewards (n,)
        """
        return self.head.optimistic(self.inputs(states, actions, next_states))

    def relabelled_rewards(self, inputs: np.ndarray, generation: int) -> np.ndarray:
        """
        R~_tau at every row of the run's buffer, oldest first (psi of section 2, over the whole set); between
        two calls only the new rows and the head's new samples are folded in. Under
        ``optimism="with_source"``, R^_tau while every row of the buffer is one of the task's own samples.

        :param inputs: the rewarded inputs of the run's rows, (n, p), a view that only grows between calls of
            one ``generation``
        :param generation: changes when the rows start over (the buffer lost rows)
        :return: rewards (n,)
        """
        if self._relabelling is None or generation != self._generation:
            self._relabelling = self.head.tracker(inputs)
            self._generation = generation
        elif len(inputs) > self._relabelling.n_states:
            self._relabelling.extend(inputs[self._relabelling.n_states :])
        if self.optimism == "with_source" and self._relabelling.n_states <= self.samples:
            return self._relabelling.estimate()
        return self._relabelling.optimistic()

    def bonus_mean(self, rewards: np.ndarray) -> float:
        """
        The optimism a refit applied: the mean of R~ - R^ over the rows it relabelled (its ``rewards``, those
        of the last ``relabelled_rewards``), from what the relabelling keeps (no row is read again).

        :param rewards: the rewards of the last ``relabelled_rewards``
        """
        if self._relabelling is None or not len(rewards):
            return 0.0
        return float(np.mean(rewards - self._relabelling.estimate()))

    def recent_states(self) -> np.ndarray:
        """
        The task's latest online start states (its ``trail``), with a row of NaN after each end of a
        trajectory, where a drawn line must break.

        :return: (t, d)
        """
        rows = []
        for state, ended in self.trail:
            rows.append(state)
            if ended:
                rows.append(np.full(len(state), np.nan))
        return np.array(rows)

    def refitted(self, n_rows: int) -> None:
        """
        Record a refit of the task's Q-function: the trigger now compares with the uncertainty of now.

        :param n_rows: the rows of the shared buffer it was fitted on
        """
        self.uncertainty_at_refit = self.head.snapshot()
        self.rows_at_refit = int(n_rows)
        self.samples_at_refit = self.samples
        self.refits += 1
        self.due = self.triggered = False
