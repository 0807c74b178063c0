"""Algorithm 1 online, over R runs at once: the one copy of TRLSD's control logic.

An ``Engine`` holds R runs, each with its shared buffer and its task learners (reward head, refit trigger,
relabelling), and the Q-functions of every run and task (``q_functions.py``). Whoever drives it steps envs
and calls, for a batch of transitions, each with its run:

- ``act(runs, states, tasks)``: a task's Q is fitted before its first action (under
  ``first_fit="first_step"``), then the greedy action argmax_a Q_run,tau(s, a) (eq. 3), replaced by a
  uniformly random one with the task's exploration rate (``Exploration``: epsilon-greedy over a task's first
  online steps; none in the paper);
- ``observe(runs, ...)``: each transition goes to its run's buffer (at once, or held back until the run's
  next refit) and its reward to its task's learner, whose trigger may fire (section 3);
- ``refit_due()``: the tasks whose trigger fired are refitted by Fitted-Q Iteration on their run's buffer
  relabelled with their reward proxy R~ (Algorithm 1, psi), all in one call of the Q-functions' fit.

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

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions
from sb3_trlsd.fqi import FQIResult, targets_rule_cap
from sb3_trlsd.q_functions import QFunctions
from sb3_trlsd.task_learner import TaskLearner

__all__ = [
    "TIE_BREAKS",
    "Engine",
    "Exploration",
    "NewLearner",
    "RefitHook",
    "Run",
    "explore_rng",
    "greedy_actions",
    "tie_rng",
]

# How the greedy action of equal Q-values is taken while learning: the first such action, or one of them at
# random (a Q that is 0 everywhere, before any reward was seen with kappa = 0, then acts at random instead of
# repeating action 0).
TIE_BREAKS = ("random", "first")
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


def _run_rng(seed: int | None, stream: int) -> np.random.Generator:
    """A generator of its own for each ``stream`` of a run, derived from the run's seed (or fresh entropy)."""
    if seed is None:
        return np.random.default_rng()
    return np.random.default_rng(np.random.SeedSequence([int(seed) % 2**64, stream]))


def tie_rng(seed: int | None) -> np.random.Generator:
    """
    The generator of a run's random tie-breaks, derived from the run's seed (fresh entropy without one).

    :param seed: the run's seed (a model's ``seed``)
    """
    return _run_rng(seed, 5)


def explore_rng(seed: int | None) -> np.random.Generator:
    """
    The generator of a run's exploratory actions, derived from the run's seed (fresh entropy without one).

    :param seed: the run's seed (a model's ``seed``)
    """
    return _run_rng(seed, 7)


@dataclass(frozen=True)
class Exploration:
    """
    Epsilon-greedy behaviour while learning, per task: over a task's first ``steps`` online samples the
    rate falls linearly from ``initial_eps`` to ``final_eps``, and stays at ``final_eps`` after; a step
    takes a uniformly random action with that probability, else the greedy one.

    :param initial_eps: the rate at a task's first online step, in [0, 1]
    :param final_eps: the rate from its ``steps``-th on, in [0, 1]
    :param steps: the online samples of a task over which the rate falls (0: ``final_eps`` from the start)
    """

    initial_eps: float = 0.0
    final_eps: float = 0.0
    steps: int = 0

    def rate(self, samples: int) -> float:
        """
        The exploration rate of a task with ``samples`` online samples so far.

        :param samples: the task's online samples (>= 0)
        """
        if samples >= self.steps:
            return self.final_eps
        return self.initial_eps + (self.final_eps - self.initial_eps) * samples / self.steps

    @property
    def explores(self) -> bool:
        """Whether any step may be exploratory."""
        return self.initial_eps > 0 or self.final_eps > 0


def greedy_actions(
    q_values: np.ndarray, rngs: Sequence[np.random.Generator | None] | None = None
) -> np.ndarray:
    """
    argmax_a Q(s, a) of each state (eq. 3), a tie taken at random with the state's generator (None: the
    first tied action). A draw is made for each state with a tie, in order, and for no other: the same
    states give the same draws whichever way they are batched.

    :param q_values: (n, n_actions)
    :param rngs: one generator (or None) per state; None: no random tie-break
    :return: actions (n,)
    """
    actions = q_values.argmax(axis=1)
    if rngs is None:
        return actions
    tied = q_values == q_values[np.arange(len(q_values)), actions][:, None]
    for i in np.flatnonzero(tied.sum(axis=1) > 1):
        rng = rngs[int(i)]
        if rng is not None:
            choices = np.flatnonzero(tied[i])
            actions[i] = choices[rng.integers(len(choices))]
    return actions


@dataclass
class Run:
    """
    One run's learning state apart from its Q-functions.

    :param buffer: the run's shared buffer, every transition of every task
    :param learners: its task learners by task, created the first time a task is met
    :param pending: online transitions not yet written to the buffer (rows are read only at refits, so the
        engine writes a batch of them at once), as (state, action, reward, next state, task, truncated,
        terminated)
    :param ties: the generator of its greedy actions' random tie-breaks (None: the first tied action)
    :param explore: the generator of its exploratory actions (None: none, whatever the engine's
        ``Exploration``)
    """

    buffer: SharedDynamicsReplayBuffer
    learners: dict[int, TaskLearner] = field(default_factory=dict)
    pending: list[tuple] = field(default_factory=list)
    ties: np.random.Generator | None = None
    explore: np.random.Generator | None = None

    @property
    def n_rows(self) -> int:
        """The run's transitions, written or held back."""
        return self.buffer.size() + len(self.pending)

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

    def observe(
        self,
        runs: np.ndarray,
        states: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_states: np.ndarray,
        tasks: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        store: bool = True,
    ) -> None:
        """
        Take in transitions, each of its run: store it (unless the caller did), and feed its task's learner
        its reward (which may make the task due for a refit).

        :param runs: the run of each transition, (n,)
        :param states: start states, (n, d)
        :param actions: (n,)
        :param rewards: (n,); stored, and learnt from, in float32 as an SB3 buffer stores them
        :param next_states: (n, d)
        :param tasks: (n,)
        :param terminated: whether each next state is absorbing, (n,)
        :param truncated: whether each trajectory was cut there, (n,)
        :param store: hold the transitions for their run's buffer (False: the caller stored them already)
        """
        rewards = np.asarray(rewards).astype(np.float32).astype(np.float64)
        for i, run_index in enumerate(runs):
            run = self.runs[run_index]
            if store:
                run.pending.append(
                    (states[i], actions[i], rewards[i], next_states[i], tasks[i], truncated[i], terminated[i])
                )
            learner = self.learner(run_index, tasks[i])
            learner.observe(states[i], int(actions[i]), next_states[i], float(rewards[i]), n_rows=run.n_rows)

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

    def _refit(self, pairs: Sequence[tuple[int, int]]) -> list[FQIResult]:
        for run in sorted({run for run, _ in pairs}):
            self.runs[run].write_pending()
        buffers = [run.buffer for run in self.runs]
        rewards = [self.learner(run, task).relabelled_rewards(buffers[run]) for run, task in pairs]
        results = self.q_functions.fit(
            pairs, buffers, rewards, self.gamma, self.max_iterations, self.tol, self.stop_rule, self.solver
        )
        for (run, task), result, task_rewards in zip(pairs, results, rewards, strict=True):
            learner = self.learner(run, task)
            learner.refitted(n_rows=self.runs[run].n_rows)
            if self.on_refit is not None:
                self.on_refit(run, learner, result, task_rewards)
        return results
