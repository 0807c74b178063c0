"""Algorithm 1 online, over R runs at once: the one copy of TRLSD's control logic.

An ``Engine`` holds R runs, each with its shared buffer and its task learners (reward head, refit trigger,
relabelling), and the Q-functions of every run and task (``q_functions.py``). Whoever drives it steps envs
and calls, for a batch of transitions, each with its run:

- ``act(runs, states, tasks)``: a task's Q is fitted before its first action (under
  ``first_fit="first_step"``), then the greedy action argmax_a Q_run,tau(s, a) (eq. 3), replaced by a
  uniformly random one with the task's exploration rate (``Exploration``: epsilon-greedy over a task's first
  online steps; none in the paper);
- ``step(runs, ...)``: what follows an env step, in one place: each transition is stored in its run's buffer
  (at once, or held back until the run's next refit), its reward goes to its task's learner, whose trigger
  may fire (section 3); it returns the tasks now due;
- ``refit_due()``: the tasks whose trigger fired are refitted by Fitted-Q Iteration on their run's buffer
  relabelled with their reward proxy R~ (Algorithm 1, psi), all in one call of the Q-functions' fit.

A refit reads the rows its run's buffer gained since the previous one once, through the run's one cursor
(``RunRows``), and hands them to the Q-functions and to the learners' relabelling.

``TRLSD`` drives it with one run (its ``n_envs`` envs all feeding it) from SB3's rollout and from
``act``/``add_online_transition``; the experiments drive R runs of one method in lockstep. A run of a batch
takes the actions and refits of a ``TRLSD`` model driven alone with the same seed and source set, up to the
order of floating-point sums.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from threadpoolctl import ThreadpoolController

from sb3_trlsd.action_choice import Exploration, greedy_actions
from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.buffers import BufferCursor, SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.fqi import FQIResult, check_finite_fit, targets_rule_cap
from sb3_trlsd.q_functions import QFunctions
from sb3_trlsd.reward_timing import rewarded_inputs
from sb3_trlsd.task_learner import TaskLearner

__all__ = ["Engine", "NewLearner", "RefitHook", "Run", "RunRows"]

# A refit's BLAS calls run on this many threads: its products are thin (rows x k features, k at most a few
# hundred with the feature maps' budgets) and its solves small (k x k), where more threads cost more than
# they give on 2 cores (docs/speed.rst).
REFIT_BLAS_THREADS = 1


@cache
def blas_controller() -> ThreadpoolController:
    """The process's BLAS libraries, inspected once."""
    return ThreadpoolController()


# (run, task) -> a fresh learning state of that task in that run
NewLearner = Callable[[int, int], TaskLearner]
# Called after each refit with the run, the task's learner, the fit's result and the rewards it fitted on.
RefitHook = Callable[[int, TaskLearner, FQIResult, np.ndarray], None]


class RunRows:
    """
    What a run's refits have read of its buffer, through its one cursor: the rewarded inputs of every row
    (``reward_timing``'s, the same for every task of the run), which the tasks' relabellings share.

    :param reward_timing: what of a transition its reward belongs to (``sb3_trlsd.reward_timing``)
    """

    def __init__(self, reward_timing: str):
        self.reward_timing = reward_timing
        self.cursor = BufferCursor()
        self.inputs: GrowableArray | None = None  # (n, p) rewarded inputs of the rows read
        self.generation = 0  # grows whenever the rows start over (the buffer lost rows)

    def __getstate__(self) -> dict[str, object]:
        # Derived from the buffer: a copied or loaded run reads it again from the start.
        return {"reward_timing": self.reward_timing}

    def __setstate__(self, state: dict[str, str]) -> None:
        self.__init__(state["reward_timing"])  # type: ignore[misc]

    def read(self, buffer: SharedDynamicsReplayBuffer) -> tuple[Transitions, bool]:
        """
        The rows ``buffer`` gained since the last read, their inputs kept.

        :return: the new rows, oldest first, and whether the rows start over (every row is then returned)
        """
        rows, restart = buffer.read_new(self.cursor)
        inputs = rewarded_inputs(rows.states, rows.actions, rows.next_states, self.reward_timing)
        if restart or self.inputs is None:
            self.inputs = GrowableArray(inputs.shape[1])
            self.generation += 1
        self.inputs.append(inputs)
        return rows, restart


@dataclass
class Run:
    """
    One run's learning state apart from its Q-functions.

    :param buffer: the run's shared buffer, every transition of every task
    :param learners: its task learners by task, created the first time a task is met
    :param rows: what its refits have read of the buffer
    :param hold_back: hold its online transitions back until its next refit, and write them then in one
        call (rows are read only at refits); False writes each at once (a model's buffer, which its user
        may read)
    :param ties: the generator of its greedy actions' random tie-breaks (None: the first tied action)
    :param explore: the generator of its exploratory actions (None: none, whatever the engine's
        ``Exploration``)
    """

    buffer: SharedDynamicsReplayBuffer
    rows: RunRows
    learners: dict[int, TaskLearner] = field(default_factory=dict)
    hold_back: bool = False
    ties: np.random.Generator | None = None
    explore: np.random.Generator | None = None
    # online transitions held back, in order: (state, action, reward, next state, task, truncated, terminated)
    pending: list[tuple[np.ndarray, int, float, np.ndarray, int, bool, bool]] = field(default_factory=list)

    @property
    def n_rows(self) -> int:
        """The run's transitions, written or held back."""
        return self.buffer.size() + len(self.pending)

    def store(
        self,
        states: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_states: np.ndarray,
        tasks: np.ndarray,
        truncated: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """
        Store online transitions with their rewards: at once (validated first: a bad one raises a
        ValueError and stores nothing), or held back until the next ``write_pending`` (``hold_back``).
        """
        if self.hold_back:
            self.pending.extend(
                zip(states, actions, rewards, next_states, tasks, truncated, terminated, strict=True)
            )
            return
        self.buffer.add_transitions(
            Transitions(states, actions, next_states, rewards, tasks, truncated, terminated),
            keep_rewards=True,
        )

    def write_pending(self) -> None:
        """Write the transitions held back to the buffer, in their order."""
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


class Engine:
    """
    Algorithm 1 over R runs (see the module's docstring).

    :param runs: the runs
    :param q_functions: the Q-function of every run and task
    :param new_learner: makes the learning state of a task the first time its run meets it
    :param gamma: discount factor of the Fitted-Q refits
    :param max_iterations: cap on the Fitted-Q iterations of a refit (None: the Q-functions' default, and
        under the ``"targets"`` rule at most ``targets_rule_cap(gamma, tol)``)
    :param tol: relative stopping tolerance of the Fitted-Q iterations
    :param stop_rule: the Fitted-Q iterations' stopping rule, one of ``sb3_trlsd.fqi.STOP_RULES``
    :param on_refit: called after each refit (e.g. to log it)
    :param exploration: the epsilon-greedy behaviour of ``act`` (default: none, the greedy policy)
    :param solver: how a refit reaches Fitted-Q's fixed point, one of ``sb3_trlsd.fqi.SOLVERS`` (None: the
        Q-functions' default)
    """

    def __init__(
        self,
        runs: Sequence[Run],
        q_functions: QFunctions,
        new_learner: NewLearner,
        gamma: float,
        max_iterations: int | None,
        tol: float,
        stop_rule: str,
        on_refit: RefitHook | None = None,
        exploration: Exploration | None = None,
        solver: str | None = None,
    ):
        self.runs = list(runs)
        self.exploration = exploration or Exploration()
        self.q_functions = q_functions
        self.new_learner = new_learner
        self.gamma = gamma
        if max_iterations is None:
            max_iterations = q_functions.default_max_iterations
            if stop_rule == "targets":
                max_iterations = min(max_iterations, targets_rule_cap(gamma, tol))
        self.max_iterations = max_iterations
        self.tol = tol
        self.stop_rule = stop_rule
        self.solver = q_functions.default_solver if solver is None else solver
        self.on_refit = on_refit

    def learner(self, run: int, task: int) -> TaskLearner:
        """The learning state of ``task`` in ``run``, created (no samples) the first time it is asked for."""
        learners = self.runs[run].learners
        task = int(task)
        if task not in learners:
            learners[task] = self.new_learner(run, task)
        return learners[task]

    def fit_first(self, runs: np.ndarray, tasks: np.ndarray) -> list[tuple[int, int]]:
        """
        Fit the tasks about to act that must be fitted before acting (their first step under
        ``first_fit="first_step"``).

        :param runs: the run of each state about to act, (n,)
        :param tasks: its task, (n,)
        :return: the (run, task) pairs fitted, in order
        """
        pairs = sorted({(int(run), int(task)) for run, task in zip(runs, tasks, strict=True)})
        due = [(run, task) for run, task in pairs if self.learner(run, task).fit_before_acting]
        self.refit(due)
        return due

    def greedy(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """
        The greedy action of each state under its run's Q of its task: argmax_a Q(s, a) (eq. 3), ties taken
        by its run's ``ties``.

        :return: actions (n,)
        """
        q_values = self.q_functions.q_values(runs, states, tasks)
        return greedy_actions(q_values, [self.runs[run].ties for run in runs])

    def behave(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """
        The actions TRLSD takes once the tasks are fitted: ``greedy``, each replaced by a uniformly random
        action with its task's exploration rate (``Exploration.rate`` of the task's online samples), drawn
        with its run's ``explore`` generator: one draw for each state whose rate is above 0, in order, and a
        second for each that explores.

        :param runs: the run of each state, (n,)
        :param states: (n, d)
        :param tasks: the task of each state, (n,)
        :return: actions (n,)
        """
        q_values = self.q_functions.q_values(runs, states, tasks)
        actions = greedy_actions(q_values, [self.runs[run].ties for run in runs])
        if not self.exploration.explores:
            return actions
        for i, (run, task) in enumerate(zip(runs, tasks, strict=True)):
            rng = self.runs[run].explore
            rate = self.exploration.rate(self.learner(run, task).samples)
            if rng is not None and rate > 0 and rng.random() < rate:
                actions[i] = rng.integers(q_values.shape[1])
        return actions

    def act(self, runs: np.ndarray, states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """
        The actions TRLSD takes: the tasks that must be are fitted first (``fit_first``), then ``behave``.

        :param runs: the run of each state, (n,)
        :param states: (n, d)
        :param tasks: the task of each state, (n,)
        :return: actions (n,)
        """
        self.fit_first(runs, tasks)
        return self.behave(runs, states, tasks)

    def step(
        self,
        runs: np.ndarray,
        states: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_states: np.ndarray,
        tasks: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> list[tuple[int, int]]:
        """
        What follows an env step, for a batch of transitions each of its run: store each in its run's buffer
        (validated first: a bad one raises a ValueError before anything of the step is stored or learnt),
        then feed its reward to its task's learner, whose refit trigger may fire. The learners see each
        transition with the precision its buffer stores it (float32 states and rewards, as SB3's buffers).

        :param runs: the run of each transition, (n,)
        :param states: start states, (n, d)
        :param actions: (n,)
        :param rewards: (n,)
        :param next_states: (n, d)
        :param tasks: (n,)
        :param terminated: whether each next state is absorbing, (n,)
        :param truncated: whether each trajectory was cut there, (n,)
        :return: the (run, task) pairs now due for a refit, in order (``due``)
        """
        runs, actions, tasks = np.asarray(runs), np.asarray(actions), np.asarray(tasks)
        terminated, truncated = np.asarray(terminated, dtype=bool), np.asarray(truncated, dtype=bool)
        rewards = np.asarray(rewards, dtype=np.float64).astype(np.float32).astype(np.float64)
        for run_index in np.unique(runs):
            rows = runs == run_index
            self.runs[run_index].store(
                states[rows], actions[rows], rewards[rows], next_states[rows], tasks[rows],
                truncated[rows], terminated[rows],
            )  # fmt: skip
        # What the learners see of a state is the state as the buffers store it (float32 for a float Box).
        stored = self.runs[int(runs[0])].buffer.observations.dtype if len(runs) else np.float64
        states, next_states = np.asarray(states).astype(stored), np.asarray(next_states).astype(stored)
        for i, run_index in enumerate(runs):
            run = self.runs[run_index]
            learner = self.learner(run_index, tasks[i])
            learner.observe(
                states[i],
                int(actions[i]),
                next_states[i],
                float(rewards[i]),
                n_rows=run.n_rows,
                ended=bool(terminated[i] or truncated[i]),
            )
        return self.due()

    def load(self, run: int, transitions: Transitions, keep_rewards: bool) -> None:
        """
        Add transitions collected elsewhere to a run's buffer (the paper's source set Xi); with
        ``keep_rewards``, each task's learner also learns the rewards of its transitions. Every fitted task of
        the run is then due: its Q has new dynamics data to be refitted on.

        :param run: the run
        :param transitions: the transitions
        :param keep_rewards: learn their rewards too (False, the paper's setting: the dynamics only)
        :raises ValueError: when they do not fit in the buffer beside its rows, or do not fit its env
        """
        target = self.runs[run]
        target.write_pending()
        target.buffer.check_room(len(transitions))
        target.buffer.add_transitions(transitions, keep_rewards=keep_rewards)
        if keep_rewards:
            for task in np.unique(transitions.tasks):
                rows = transitions.tasks == task
                self.learner(run, int(task)).learn(
                    transitions.states[rows],
                    transitions.actions[rows],
                    transitions.next_states[rows],
                    transitions.rewards[rows],
                )
        for learner in target.learners.values():
            learner.due = learner.due or learner.fitted

    def exploration_rate(self, run: int, task: int) -> float:
        """The probability of an exploratory action at the next step of ``task`` in ``run``."""
        return self.exploration.rate(self.learner(run, task).samples)

    def due(self) -> list[tuple[int, int]]:
        """The (run, task) pairs whose refit is due, in order."""
        return [
            (index, task)
            for index, run in enumerate(self.runs)
            for task, learner in sorted(run.learners.items())
            if learner.due
        ]

    def refit_due(self) -> list[tuple[int, int]]:
        """
        Refit every task whose trigger fired (``due``).

        :return: the (run, task) pairs refitted, in order
        """
        pairs = self.due()
        self.refit(pairs)
        return pairs

    def refit(self, pairs: Sequence[tuple[int, int]]) -> list[FQIResult]:
        """
        Refit the Q of each ``(run, task)`` now: its run's buffer relabelled with the task's reward proxy R~
        (Algorithm 1, psi), then Fitted-Q Iteration from the current parameters, all pairs in one call, with
        BLAS on ``REFIT_BLAS_THREADS`` threads.

        :param pairs: the (run, task) pairs
        :return: the fit of each pair
        """
        if not pairs:
            return []
        with blas_controller().limit(limits=REFIT_BLAS_THREADS, user_api="blas"):
            return self._refit(pairs)

    def relabelled_rewards(self, run: int, task: int) -> np.ndarray:
        """
        R~ of ``task`` at every row of ``run``'s buffer, oldest first (Algorithm 1, psi): the rewards its next
        refit would fit on.

        :param run: the run
        :param task: the task
        :return: rewards (n,)
        """
        self._read_new_rows(run)
        rows = self.runs[run].rows
        assert rows.inputs is not None, "read above"
        return self.learner(run, task).relabelled_rewards(rows.inputs.view(), rows.generation)

    def _read_new_rows(self, run_index: int) -> None:
        """The run's one read of the rows its buffer gained: to its Q-functions, and kept for its tasks."""
        run = self.runs[run_index]
        run.write_pending()
        new_rows, restart = run.rows.read(run.buffer)
        self.q_functions.extend(run_index, new_rows, restart)

    def _refit(self, pairs: Sequence[tuple[int, int]]) -> list[FQIResult]:
        rewards = []
        for run, task in pairs:
            task_rewards = self.relabelled_rewards(run, task)
            check_finite_fit(task, task_rewards, self.gamma)
            rewards.append(task_rewards)
        fit_settings = (self.gamma, self.max_iterations, self.tol, self.stop_rule, self.solver)
        results = self.q_functions.fit(pairs, rewards, *fit_settings)
        for (run, task), result, task_rewards in zip(pairs, results, rewards, strict=True):
            check_finite_fit(task, task_rewards, self.gamma, result)
            learner = self.learner(run, task)
            learner.refitted(n_rows=self.runs[run].n_rows)
            if self.on_refit is not None:
                self.on_refit(run, learner, result, task_rewards)
        return results
