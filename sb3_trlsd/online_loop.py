"""
Algorithm 1's online loop, as a mixin of ``TRLSD``: a task's Q is fitted before the task first acts (under
``first_fit="first_step"``), each stored transition goes to its task's learner (reward head and refit
trigger), and the tasks whose trigger fired are refitted by Fitted-Q Iteration on the shared buffer
relabelled with their reward proxy R~. SB3's rollout drives it through ``_sample_action``, ``_on_step``
and ``train``; ``act`` and ``add_online_transition`` drive the same loop from a loop of one's own.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from stable_baselines3.common.noise import ActionNoise

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.callbacks import log_refit
from sb3_trlsd.fit_rows import FitRows
from sb3_trlsd.observations import split_observation
from sb3_trlsd.policies import TaskQPolicy
from sb3_trlsd.task_learner import TaskLearner

__all__ = ["TRLSDOnlineLoop"]


class TRLSDOnlineLoop:
    """
    A mixin of ``TRLSD`` (listed before ``OffPolicyAlgorithm``, whose ``_sample_action``, ``_on_step`` and
    ``train`` it overrides): the online loop of Algorithm 1 on the model's task learners (``task_learner``),
    shared buffer and policy.
    """

    replay_buffer: SharedDynamicsReplayBuffer
    policy: TaskQPolicy
    task_learners: dict[int, TaskLearner]
    task_learner: Callable[[int], TaskLearner]
    gamma: float
    fqi_max_iterations: int | None
    fqi_tol: float
    num_timesteps: int
    _last_obs: np.ndarray | dict[str, np.ndarray] | None
    _n_updates: int
    _fit_rows: FitRows
    _warned_unfitted: set[int]

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # A task's Q is fitted at its first step, before the policy acts on it (unless ``first_fit`` waits).
        if self.num_timesteps >= learning_starts and self._last_obs is not None:
            _, tasks = split_observation(self._last_obs, self.replay_buffer.obs_shape[0])
            for task in np.unique(tasks):
                learner = self.task_learner(task)
                if learner.fit_before_acting:
                    self.update_policy(int(task))
                elif not learner.fitted:  # acting before the first fit is first_fit's rule: no warning
                    self._warned_unfitted.add(int(task))
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def _on_step(self) -> None:
        """Feed the transition just stored to its task's learner (reward head and refit trigger)."""
        buffer = self.replay_buffer
        row = (buffer.pos - 1) % buffer.buffer_size
        for state, reward, task in zip(
            buffer.observations[row], buffer.rewards[row], buffer.tasks[row], strict=True
        ):
            learner = self.task_learner(task)
            learner.observe(state, float(reward), n_rows=buffer.size() * buffer.n_envs)
            if getattr(self, "_logger", None) is not None:
                self.logger.record("reward/target_samples", learner.head.n_samples)

    def act(self, obs: dict[str, np.ndarray] | np.ndarray) -> int:
        """
        The action ``learn`` takes from one observation: the task's Q is fitted first if it never was (under
        ``first_fit="first_step"``), then the greedy action. With ``add_online_transition``, it drives TRLSD
        from a loop of one's own (the experiments' fast path) with the same result as ``learn``, without SB3's
        rollout machinery.

        :param obs: one observation of the env (not batched)
        :return: the action
        """
        states, tasks = split_observation(obs, self.replay_buffer.obs_shape[0])
        task = int(tasks[0])
        if self.task_learner(task).fit_before_acting:
            self.update_policy(task)
        return int(self.policy.q_values(states, task)[0].argmax())

    def add_online_transition(
        self,
        obs: dict[str, np.ndarray] | np.ndarray,
        action: int,
        reward: float,
        next_obs: dict[str, np.ndarray] | np.ndarray,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """
        Do with one online transition what ``learn`` does after an env step: store it in the shared buffer
        (with the precision SB3 stores it), feed it to its task's learner, and refit the tasks whose trigger
        fired. A transition with a non-finite value, a wrong shape or a task out of range raises a
        ValueError and leaves the model as it was. See ``act``.

        :param obs: observation before the step (not batched)
        :param action: action taken
        :param reward: reward received
        :param next_obs: observation after the step (before any reset)
        :param terminated: the step reached an absorbing state
        :param truncated: the trajectory was cut (no absorbing state: FQI bootstraps through it)
        """
        self.replay_buffer.add(
            obs,
            next_obs,
            np.array([[action]]),
            np.array([reward], dtype=np.float64),
            np.array([terminated or truncated]),
            [{"TimeLimit.truncated": truncated and not terminated}],
        )
        self.num_timesteps += 1
        self._on_step()
        self._refit_due_tasks()

    def train(self, gradient_steps: int, batch_size: int) -> None:
        """
        One training round: refit the Q-function of every task whose trigger fired since the last round.
        Fitted-Q Iteration fits on the whole relabelled buffer, so there are no minibatches: SB3 calls this
        only when ``gradient_steps > 0``, and ``batch_size`` has no use here.
        """
        self._refit_due_tasks()

    def _refit_due_tasks(self) -> None:
        for task in sorted(task for task, learner in self.task_learners.items() if learner.due):
            self.update_policy(task)

    def update_policy(self, task: int) -> None:
        """
        Recompute the policy of ``task`` now: relabel the whole shared buffer with the task's reward proxy R~
        (Algorithm 1, psi) and fit its Q-function on it by Fitted-Q Iteration. ``learn`` calls this at a
        task's first fit (``first_fit``) and whenever its refit trigger fires; call it directly to learn
        offline from transitions loaded with ``keep_rewards=True`` (or with the ``"known"`` reward head).

        :param task: the task index
        """
        learner = self.task_learner(task)
        rewards = learner.relabelled_rewards(self.replay_buffer)  # psi: R~_tau at every stored start state
        self._fit_rows.sync(self.replay_buffer)
        result = self.policy.fit(
            learner.task, self._fit_rows, rewards, self.gamma, self.fqi_max_iterations, self.fqi_tol
        )
        learner.refitted(n_rows=self._fit_rows.n_transitions)
        self._n_updates += 1
        log_refit(self, learner, result, rewards)
