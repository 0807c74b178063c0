"""
TRLSD: transfer reinforcement learning with shared dynamics, as an SB3 off-policy algorithm. This module is
the SB3 glue: the constructor makes the settings a ``TRLSDConfig``; SB3's rollout hooks, ``act``,
``add_online_transition`` and ``update_policy`` drive the ``Engine`` of Algorithm 1 with one run;
``save``/``load`` keep the shared buffer's rows; ``learn`` loads the source set once and writes the HParams.
"""

from __future__ import annotations

import io
import os
import pathlib
import warnings
from collections.abc import Callable, Iterable, Sequence
from typing import Any, ClassVar, TypeVar

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule, TrainFreq

from sb3_trlsd.action_choice import explore_rng, tie_rng
from sb3_trlsd.atomic_files import save_file
from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.config import LearnerBuilder, TRLSDConfig, check_algorithm_settings
from sb3_trlsd.data import as_flags
from sb3_trlsd.engine import Engine, Run, RunRows
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.foreign_data import TransitionSource, rows_to_store
from sb3_trlsd.fqi import FQIResult
from sb3_trlsd.observations import (
    StateBoxMonitor,
    check_action_space,
    read_observation,
    split_observation,
    state_space_of,
)
from sb3_trlsd.persistence import BUFFER_ROWS, check_model_zip, empty_rows, read_replay_buffer
from sb3_trlsd.policies import LinearPolicy, MlpPolicy, TaskQPolicy
from sb3_trlsd.q_functions import PolicyQFunctions
from sb3_trlsd.reward_heads import KnownRewardHead, RewardFn, RewardHead, env_reward_fn
from sb3_trlsd.source_data import check_source_transitions, source_transitions_of
from sb3_trlsd.task_learner import TaskLearner
from sb3_trlsd.training_log import (
    log_hyperparameters,
    log_task_picture,
    picture_due,
    record_refit,
    record_step,
    task_view,
)

__all__ = ["TRLSD", "UNFITTED_TASK"]

SelfTRLSD = TypeVar("SelfTRLSD", bound="TRLSD")
UNFITTED_TASK = (
    "task {task} has never been fitted: its Q-function is 0 and predict returns action 0 for every state; "
    "learn on it first, or call model.update_policy({task})"
)


class _EngineStep:
    """Where SB3's ``_store_transition`` writes a step of the envs, in place of a replay buffer's ``add``."""

    def __init__(self, add: Callable[[Any, Any, np.ndarray, np.ndarray, np.ndarray, list[dict]], None]):
        self.add = add


class TRLSD(OffPolicyAlgorithm):
    """
    Transfer Reinforcement Learning with Shared Dynamics (TRLSD).

    Paper: Laroche & Barlier, "Transfer Reinforcement Learning with Shared Dynamics", AAAI 2017.
    Every transition of every task goes to one shared buffer; for a target task, the buffer's rewards are
    replaced by an optimistic proxy R~ = R^ + CI learnt from that task's own samples (section 3), and its Q
    is refitted on that relabelled set by Fitted-Q Iteration (Algorithm 1): at its first step, then whenever
    the CI at an encountered state has been divided by ``update_ratio``. The learning's settings are a
    ``TRLSDConfig`` (``model.config``), which says what each one means; each task's learning state is a
    ``TaskLearner`` (``task_learner``); the online loop is an ``Engine`` of one run, which SB3's rollout
    drives (all ``n_envs`` envs feed the one shared buffer) and so do ``act`` and ``add_online_transition``
    from a loop of one's own. ``save``/``load`` keep the buffer's rows: a loaded model goes on learning as an
    uninterrupted one would.

    The defaults are meant for any family of tasks, not one env's units (docs: TRLSD and its parameters, and
    the benchmarks page for how they were chosen); ``update_ratio=2`` and lambda = 1 of the reward
    regression are the paper's. The paper's own settings are what ``sb3-trlsd reproduce`` and the maze's Zoo
    configs give.
    The paper does not give the discount factor: ``gamma=0.9`` makes the maze's reward cell worth reaching
    from anywhere and keeps Fitted-Q short.

    :param policy: ``"LinearPolicy"`` (the paper's linear Q on RBF features) or ``"MlpPolicy"``
    :param env: the environment (Gymnasium env, VecEnv of any number of envs, or registered id); observations
        are a state Box, or a ``{"state": Box, "task": Discrete}`` Dict for several tasks
    :param gamma: discount factor
    :param reward_head: the reward head R~ = R^ + CI (default: posterior draws, ``"thompson"``)
    :param kappa: optimism of the CI (eq. 9, 10); None: the head's
    :param sigma: width of the similarity in W (eq. 8)
    :param similarity: ``"state"`` (eq. 6) or ``"features"`` (eq. 7)
    :param update_ratio: refit a task when the CI at an encountered state has been divided by this (> 1)
    :param first_fit: when a task's Q is first fitted: ``"first_step"`` or ``"first_sample"``
    :param refit_growth: once the trigger fired, a refit waits for the task's samples to grow by this fraction
    :param optimism: where the buffer is relabelled with R~ rather than R^; None: the head's
    :param tie_break: the action among equal Q-values while learning: ``"random"`` or ``"first"``
    :param exploration_initial_eps: epsilon-greedy at a task's first online step; None: the head's
    :param exploration_final_eps: epsilon once a task has ``exploration_steps`` online samples
    :param exploration_steps: a task's online samples over which epsilon falls linearly
    :param fqi_max_iterations: cap on Fitted-Q iterations per refit (None: the policy's, and the rule's)
    :param fqi_tol: Fitted-Q's relative stopping tolerance (None: the rule's)
    :param fqi_stop: Fitted-Q's stopping rule: ``"targets"`` or ``"theta"``
    :param feature_map: Phi, shared by the linear Q and the feature heads (default ``"auto"``)
    :param rbf_per_dim: RBF centres per state dimension
    :param rbf_sigma: width of the features, a fraction of the state box
    :param rbf_overlap: width of the RBFs in spacings of their centres
    :param max_features: the feature map's budget
    :param fourier_features: the number of Fourier features
    :param fqi_solver: how a refit reaches Fitted-Q's fixed point: ``"iterations"`` or ``"policy_iteration"``
        (None: the policy's, ``"iterations"``)
    :param state_bounds: ``(low, high)`` of the states for an unbounded Box (None: the Box's, finite)
    :param reward_fn: ``reward_fn(states (n, d), task) -> (n,)``, the expected reward for the ``"known"``
        head; by default the env's ``expected_reward``. Not saved: give it again to ``load``
    :param reward_head_kwargs: extra arguments of the named reward heads
    :param reward_timing: what of a transition its reward belongs to (``"auto"``: the env's, else the step)
    :param source_transitions: source set loaded (rewards discarded) at the first ``learn``: a number of
        random transitions (the paper's 25,000) from ``source_env``, the path of a ``Transitions`` .npz or of
        a ``save_replay_buffer`` .pkl (unpickled: load only files you made), or the id of a local Minari
        dataset (see ``load_transitions``)
    :param source_seed: seed of the collection of ``source_transitions`` (None: ``seed``)
    :param source_env: an env (or a function making one) to collect them from; None: a copy of the env as
        given, its wrappers kept
    :param log_picture_every: with TensorBoard and an env that draws tasks (``task_picture``), a picture at a
        task's first refit and every this many refits; 0: none
    :param learning_rate: learning rate of the MLP policy's regression steps (unused by the linear one)
    :param buffer_size: size of the shared replay buffer
    :param learning_starts: steps of uniformly random actions before the first refit
    :param train_freq: refit the tasks that are due every ``train_freq`` steps (or ``(n, "episode")``)
    :param gradient_steps: 0 disables the refits; any positive value refits each due task once per round
    :param replay_buffer_class: a ``SharedDynamicsReplayBuffer`` subclass (default: that class)
    :param replay_buffer_kwargs: keyword arguments of the replay buffer
    :param policy_kwargs: keyword arguments of the policy
    :param stats_window_size: window of the rollout logging
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param verbose: 0 no output, 1 info, 2 debug
    :param seed: seed of the pseudo random generators
    :param device: PyTorch device (the linear fit runs in numpy on the CPU)
    :param _init_setup_model: whether or not to build the model on creation
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "LinearPolicy": LinearPolicy,
        "MlpPolicy": MlpPolicy,
    }
    policy: TaskQPolicy
    replay_buffer: SharedDynamicsReplayBuffer
    config: TRLSDConfig
    engine: Engine
    _builder: LearnerBuilder
    features: FeatureMap | None
    task_learners: dict[int, TaskLearner]

    def __init__(
        self,
        policy: str | type[TaskQPolicy],
        env: GymEnv | str | None,
        gamma: float = 0.9,
        reward_head: str | RewardHead = "thompson",
        kappa: float | None = None,
        sigma: float | Sequence[float] | None = None,
        similarity: str = "state",
        update_ratio: float = 2.0,
        first_fit: str = "first_step",
        refit_growth: float = 0.1,
        optimism: str | None = None,
        tie_break: str = "random",
        exploration_initial_eps: float | None = None,
        exploration_final_eps: float = 0.0,
        exploration_steps: int = 500,
        fqi_max_iterations: int | None = None,
        fqi_tol: float | None = None,
        fqi_stop: str = "targets",
        fqi_solver: str | None = None,
        feature_map: str | FeatureMap = "auto",
        rbf_per_dim: int | Sequence[int] | str | None = None,
        rbf_sigma: float | Sequence[float] | None = None,
        rbf_overlap: float | None = None,
        max_features: int | None = None,
        fourier_features: int | None = None,
        state_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
        reward_fn: RewardFn | None = None,
        reward_head_kwargs: dict[str, Any] | None = None,
        reward_timing: str = "auto",
        source_transitions: int | str | os.PathLike | None = None,
        source_seed: int | None = None,
        source_env: gym.Env | Callable[[], gym.Env] | None = None,
        log_picture_every: int = 10,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 1_000_000,
        learning_starts: int = 0,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        replay_buffer_class: type[SharedDynamicsReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "cpu",
        _init_setup_model: bool = True,
    ):
        # The settings are checked first: a bad one is named before any env is built.
        self.config = TRLSDConfig.of(locals())
        check_source_transitions(source_transitions)
        check_algorithm_settings(
            gamma, buffer_size, learning_starts, train_freq, seed, source_transitions, log_picture_every,
            policy_kwargs,
        )  # fmt: skip
        if env is None and _init_setup_model:
            raise ValueError(
                "env must be an env, a VecEnv or a registered env id to build the model, got None (None is "
                "for TRLSD.load, which makes the model with _init_setup_model=False)"
            )
        super().__init__(
            # Resolved here: SB3 would otherwise ask for "MultiInputPolicy" on Dict observations.
            policy=_policy_class(policy, self.policy_aliases),
            env=env,  # type: ignore[arg-type]  # None when load makes the model, as for SB3's algorithms
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=dict(policy_kwargs or {}),  # a copy: the features are added to it
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            support_multi_env=True,
        )
        self.reward_fn = reward_fn
        self.source_transitions = source_transitions
        self.source_seed = source_seed
        self.source_env = source_env
        self.log_picture_every = log_picture_every
        self._source_loaded = False
        self.task_learners = {}
        self.reward_timing: str | None = None  # the config's, resolved on the env (see TRLSDConfig)
        # load() builds the model without an env first: the spaces are checked once they are known.
        if getattr(self, "action_space", None) is not None:
            check_action_space(self.action_space)
        if getattr(self, "observation_space", None) is not None:
            state_space_of(self.observation_space)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if self.replay_buffer_class is None:
            self.replay_buffer_class = SharedDynamicsReplayBuffer
        if not issubclass(self.replay_buffer_class, SharedDynamicsReplayBuffer):
            raise ValueError(
                "replay_buffer_class must be a SharedDynamicsReplayBuffer subclass, "
                f"got {self.replay_buffer_class}"
            )
        assert isinstance(self.action_space, spaces.Discrete)
        linear_q = issubclass(self.policy_class, LinearPolicy)
        if self.env is not None:  # a model loaded without its env keeps the timing it was made with
            metadata = self.env.get_attr("metadata", indices=0)[0] or {}
            self.reward_timing = self.config.timing_for(metadata.get("reward_timing"))
        self._builder = self.config.builder(
            self.observation_space,
            int(self.action_space.n),
            linear_q=linear_q,
            seed=self.seed,
            env_reward_timing=self.reward_timing,
        )
        self.features = self._builder.features  # one Phi, for the linear policy and the feature heads
        if linear_q:
            self.policy_kwargs["features"] = self.features
        elif issubclass(self.policy_class, MlpPolicy):
            self.policy_kwargs["state_bounds"] = (self._builder.low, self._builder.high)
        super()._setup_model()
        self._buffer_rows = empty_rows()  # the buffer's rows, during save and load only
        self._warned_unfitted: set[int] = set()
        self._state_box = StateBoxMonitor(self._builder.low, self._builder.high)
        if not hasattr(self, "_ties"):  # a loaded model draws on from where it was saved
            self._ties = tie_rng(self.seed)
            self._explore = explore_rng(self.seed)
        run = Run(
            self.replay_buffer,
            RunRows(self._builder.reward_timing),
            self.task_learners,
            ties=self._ties if self.config.tie_break == "random" else None,
            explore=self._explore,
        )
        self.engine = Engine(
            [run],
            PolicyQFunctions(self.policy),
            lambda run, task: self.new_task_learner(task),
            gamma=self.gamma,
            max_iterations=self.config.fqi_max_iterations,
            tol=self.config.fqi_tolerance,
            stop_rule=self.config.fqi_stop,
            on_refit=self._log_refit,
            exploration=self.config.exploration,
            solver=self.config.fqi_solver,
        )

    # ------------------------------------------------------------- task learners
    def new_task_learner(self, task: int, seed: int | None = None) -> TaskLearner:
        """
        A learning state of ``task`` with no samples, as this model's settings make it: for runs driven
        beside the model (``task_learner`` is the model's own).

        :param task: the task
        :param seed: the run's seed, of a ``"thompson"`` head's draws (None: the model's)
        :return: the learner
        """
        reward_fn = self._known_reward_fn() if self.config.reward_head == "known" else None
        return self._builder.new_task_learner(
            task, reward_fn=reward_fn, seed=self.seed if seed is None else seed
        )

    def task_learner(self, task: int) -> TaskLearner:
        """
        The learning state of ``task``: its reward head (``.head``), refit trigger and refit count; created
        (with no samples) the first time it is asked for.
        """
        task = int(task)
        if not 0 <= task < self.policy.n_tasks:
            raise ValueError(f"task must be in 0..{self.policy.n_tasks - 1}, got {task}")
        return self.engine.learner(0, task)

    @property
    def policy_updates(self) -> dict[int, int]:
        """The refits of every task seen so far (its first fit included)."""
        return {task: learner.refits for task, learner in self.task_learners.items()}

    def _known_reward_fn(self) -> RewardFn | None:
        """The model's ``reward_fn``, else the env's ``expected_reward`` (None without either)."""
        several_tasks = isinstance(self.observation_space, spaces.Dict)
        return self.reward_fn or env_reward_fn(self.env, several_tasks)

    # --------------------------------------------------------------- transitions
    def load_transitions(
        self, data: TransitionSource, keep_rewards: bool = False, task: int | None = None
    ) -> None:
        """
        Add transitions collected elsewhere to the shared buffer (the paper's source set Xi): ``Transitions``
        (see ``collect_transitions``) or the path of their ``.npz``; an SB3 replay buffer (``ReplayBuffer`` of
        any ``n_envs``, ``DictReplayBuffer``, TRLSD's own), e.g. ``dqn.replay_buffer``, or the path of a
        ``save_replay_buffer`` ``.pkl``; a ``minari.MinariDataset`` or the id of a local one; or a list of
        these. A ``.pkl`` is unpickled, which runs the code it names: load only files you made.

        Each row's task is ``task`` if given, else its observation's (a ``{"state", "task"}`` Dict) or its
        ``Transitions.tasks`` entry; rows of Box observations carry none. With ``keep_rewards``, a row teaches
        its task's head: on a single-task env (Box observations) rows of another task are refused and rows
        without a task warn that their rewards will be learnt as this task's; on a multi-task env rows without
        a task are refused (give ``task``). See ``sb3_trlsd.foreign_data``.

        :param data: the transitions, in any of the forms above
        :param keep_rewards: also fit each task's reward head on the rewards of its transitions; False
            (the paper's setting) uses them for the dynamics only
        :param task: the task the rows were collected on (None: each row's own, where it has one)
        :raises TypeError: for another kind of ``data``, listing the accepted ones
        :raises ValueError: for rows that do not fit the env or the buffer beside its rows
            (``buffer_size``), or whose rewards belong to no task of it
        """
        for transitions, rewarded in rows_to_store(
            data, task, keep_rewards, self.observation_space, self.action_space
        ):
            self._state_box.check(np.concatenate([transitions.states, transitions.next_states]), stacklevel=2)
            self.engine.load(0, transitions, rewarded)

    # ------------------------------------------------------ the online loop (SB3)
    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # Before learning_starts, SB3's uniformly random actions; then the engine's.
        if self.num_timesteps < learning_starts or self._last_obs is None:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        states, tasks = read_observation(self._last_obs, self.observation_space)
        self._state_box.check(states, stacklevel=4)
        actions = self.engine.act(np.zeros(len(tasks), dtype=np.int64), states, tasks)
        return actions, actions

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        # SB3 makes the step's transitions (terminal observations, VecNormalize's originals) and hands them to
        # the engine's step, which stores them in the shared buffer and feeds the task learners.
        engine_step = _EngineStep(self._online_step)
        super()._store_transition(engine_step, buffer_action, new_obs, reward, dones, infos)  # type: ignore[arg-type]

    def train(self, gradient_steps: int, batch_size: int) -> None:
        """
        One training round: refit the Q-function of every task whose trigger fired since the last round.
        Fitted-Q Iteration fits on the whole relabelled buffer, so there are no minibatches: SB3 calls this
        only when ``gradient_steps > 0``, and ``batch_size`` has no use here.
        """
        self.engine.refit_due()

    # ------------------------------------------------- the online loop (one's own)
    def act(self, obs: dict[str, np.ndarray] | np.ndarray) -> int:
        """
        The action ``learn`` takes from one observation: the task's Q is fitted first if it never was (under
        ``first_fit="first_step"``), then the greedy action. With ``add_online_transition``, it drives TRLSD
        from a loop of one's own with the same result as ``learn``, without SB3's rollout machinery.

        :param obs: one observation of the env (not batched)
        :return: the action
        """
        states, tasks = read_observation(obs, self.observation_space)
        self._state_box.check(states, stacklevel=2)
        return int(self.engine.act(np.zeros(1, dtype=np.int64), states[:1], tasks[:1])[0])

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
        Do with one online transition what ``learn`` does after an env step: the engine's step (store it in
        the shared buffer with the precision SB3 stores it, feed it to its task's learner), then refit the
        tasks whose trigger fired. A transition with a non-finite value, a wrong shape or a task out of range
        raises a ValueError and leaves the model as it was. See ``act``.

        :param obs: observation before the step (not batched)
        :param action: action taken
        :param reward: reward received
        :param next_obs: observation after the step (before any reset)
        :param terminated: the step reached an absorbing state
        :param truncated: the trajectory was cut (no absorbing state: FQI bootstraps through it)
        """
        ended, cut = bool(as_flags("terminated", terminated)), bool(as_flags("truncated", truncated))
        info = {"TimeLimit.truncated": cut and not ended}
        self._online_step(
            obs, next_obs, np.array([action]), np.array([reward]), np.array([ended or cut]), [info]
        )
        self.num_timesteps += 1
        self.engine.refit_due()

    def _online_step(
        self,
        obs: dict[str, np.ndarray] | np.ndarray,
        next_obs: dict[str, np.ndarray] | np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """A step of the envs (a row per env: SB3's ``add`` arguments) as the engine's step of the one run."""
        states, tasks = read_observation(obs, self.observation_space)
        # Its values are checked with the row's, by the buffer (a ValueError naming the next state).
        next_states, _ = split_observation(next_obs, states.shape[1])
        done = as_flags("done", np.asarray(dones).reshape(-1))
        if len(done) != len(states) or len(infos) != len(states):
            raise ValueError(
                f"expected one done and one info per env ({len(states)}), got {len(done)}, {len(infos)}"
            )
        timeouts = np.array([bool(info.get("TimeLimit.truncated", False)) for info in infos])
        truncated = done & timeouts if self.replay_buffer.handle_timeout_termination else np.zeros_like(done)
        runs = np.zeros(len(states), dtype=np.int64)
        actions, rewards = np.asarray(actions).reshape(-1), np.asarray(rewards).reshape(-1)
        self.engine.step(runs, states, actions, rewards, next_states, tasks, done & ~truncated, truncated)
        self._state_box.check(next_states, stacklevel=4)
        if getattr(self, "_logger", None) is not None:
            task = int(tasks[-1])
            record_step(self.logger, self.task_learner(task), self.engine.exploration_rate(0, task))

    def update_policy(self, task: int) -> None:
        """
        Recompute the policy of ``task`` now: relabel the whole shared buffer with the task's reward proxy R~
        (Algorithm 1, psi) and fit its Q-function on it by Fitted-Q Iteration. ``learn`` calls this at a
        task's first fit (``first_fit``) and whenever its refit trigger fires; call it directly to learn
        offline from transitions loaded with ``keep_rewards=True`` (or with the ``"known"`` reward head).

        :param task: the task index
        """
        self.task_learner(task)  # checks the task
        self.engine.refit([(0, int(task))])

    def _log_refit(self, run: int, learner: TaskLearner, result: FQIResult, rewards: np.ndarray) -> None:
        """A refit's scalars and, when one is due, the task's picture (nothing before SB3 made a logger)."""
        self._n_updates += 1
        if getattr(self, "_logger", None) is None:
            return
        record_refit(self.logger, learner, result, rewards, sum(self.policy_updates.values()))
        if picture_due(learner, self.log_picture_every):
            view = task_view(learner, self.policy.q_values, self.policy.n_actions)
            log_task_picture(self.logger, self.env, view, self.num_timesteps)

    # ------------------------------------------------------------- save and load
    def _excluded_save_params(self) -> list[str]:
        # Rebuilt by _setup_model, or not saved on purpose (a reward_fn is often an env's method).
        derived = ["features", "engine", "_builder", "_state_box", "_warned_unfitted", "reward_fn"]
        return [*super()._excluded_save_params(), *derived]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy"], [BUFFER_ROWS]

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """
        SB3's ``save``, with the shared buffer's rows in the zip (so that ``load`` can go on learning), and
        written whole or not at all: to a path (``.zip`` added when it has no suffix), through a temporary
        file that replaces the earlier one only once complete, so that a failed save leaves it loadable.

        :raises ValueError: when ``path`` is a folder
        """
        self._buffer_rows = th.as_tensor(self.replay_buffer.packed_rows())
        try:
            with save_file(path, ".zip") as file:
                super().save(file, exclude=exclude, include=include)
        finally:
            self._buffer_rows = empty_rows()

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """
        SB3's ``save_replay_buffer``, written whole or not at all (see ``save``; ``.pkl`` added to a path
        without a suffix).

        :raises ValueError: when ``path`` is a folder
        """
        with save_file(path, ".pkl") as file:
            super().save_replay_buffer(file)

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfTRLSD],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfTRLSD:
        """
        SB3's ``load``; the shared buffer comes back with its rows, the known heads with reward_fn.

        :raises ValueError: naming the file, when it is not a whole zip of ``TRLSD.save`` (cut short,
            damaged, or lacking one of ``MODEL_ENTRIES``)
        """
        check_model_zip(path)
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        if len(model._buffer_rows):
            model.replay_buffer.restore_packed_rows(model._buffer_rows.numpy())
        model._buffer_rows = empty_rows()
        reward_fn = model._known_reward_fn()
        for learner in model.task_learners.values():
            head = learner.head
            if isinstance(head, KnownRewardHead) and head.reward_fn is None and reward_fn is not None:
                head.bind(reward_fn)
        return model

    def load_replay_buffer(
        self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True
    ) -> None:
        """
        Load a buffer saved by ``save_replay_buffer``: a ``SharedDynamicsReplayBuffer`` of this env's layout.

        :raises ValueError: naming the file, when it cannot be read or holds another kind of buffer
        """
        buffer = read_replay_buffer(path, self.replay_buffer, self.verbose)
        buffer.device = self.device
        self.replay_buffer = buffer
        self.engine.runs[0].buffer = buffer

    # ------------------------------------------------------ learn and predict
    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        total_timesteps, callback = super()._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        log_hyperparameters(self.logger, self.hyperparameters(), self.num_timesteps)
        return total_timesteps, callback

    def hyperparameters(self) -> dict[str, int | float | str | bool]:
        """The settings of this run, as TensorBoard's HParams tab shows them."""
        settings: dict[str, object] = {
            "algorithm": type(self).__name__,
            "policy": self.policy_class.__name__,
            "gamma": self.gamma,
            **self.config.hyperparameters(),
            "n_features": getattr(self.features, "n_features", 0),
            "source_transitions": self.source_transitions,
            "seed": self.seed,
        }
        return {
            key: value if isinstance(value, (int, float, bool)) else str(value)
            for key, value in settings.items()
        }

    def learn(
        self: SelfTRLSD,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "TRLSD",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfTRLSD:
        """
        SB3's ``learn``, the source set loaded first (``source_transitions``). A learn that raises (an env
        failing inside ``step``, say) leaves the next one to start from a reset of the env: the step it broke
        off may have moved the env on, and SB3's last observation paired with the next one would store a
        transition that never happened.

        :raises ValueError: when ``train_freq`` is more than ``total_timesteps``: SB3 collects a whole
            ``train_freq`` (of steps, or of episodes of at least one step) before it looks at
            ``total_timesteps``, so learn would run on past it
        """
        assert isinstance(self.train_freq, TrainFreq)  # made one by _setup_model
        frequency, unit = self.train_freq.frequency, self.train_freq.unit.value
        if frequency > total_timesteps:
            raise ValueError(
                f"train_freq={frequency} {unit}s is more than total_timesteps={total_timesteps}: SB3 "
                "collects a whole train_freq before it stops, so learn would run on past total_timesteps; "
                f"make the model with train_freq <= {total_timesteps}"
            )
        self._load_source_once()
        try:
            super().learn(
                total_timesteps=total_timesteps,
                callback=callback,
                log_interval=log_interval,
                tb_log_name=tb_log_name,
                reset_num_timesteps=reset_num_timesteps,
                progress_bar=progress_bar,
            )
        except BaseException:
            self._last_obs = None  # SB3's _setup_learn resets the env on None
            raise
        self.dump_logs()  # SB3 dumps every log_interval episodes: a run's last values are kept too
        return self

    def _load_source_once(self) -> None:
        """
        Before ``learn``: load the source set into the shared buffer the first time (rewards discarded), and
        warn when the buffer is empty although the model learnt before (a model saved without its rows).
        """
        if self.source_transitions is not None and not self._source_loaded:
            seed = self.seed if self.source_seed is None else self.source_seed
            source = source_transitions_of(self.source_transitions, self.source_env, self.env, seed)
            self.load_transitions(source, keep_rewards=False)
            self._source_loaded = True
        learnt_before = self._source_loaded or any(learner.fitted for learner in self.task_learners.values())
        if self.replay_buffer.size() == 0 and learnt_before:
            warnings.warn(
                "the shared buffer is empty although this model has learnt before (a model saved without "
                "its buffer rows): restore it with model.load_replay_buffer(path) (saved by "
                "save_replay_buffer) or model.load_transitions(...) before learn",
                stacklevel=3,
            )

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        SB3's ``predict``: the greedy action of each observation's task, equal Q-values broken by
        ``tie_break`` unless ``deterministic`` (then the first). A task whose Q-function was never fitted is
        warned about, once per task.
        """
        states, tasks = read_observation(observation, self.observation_space)
        self._state_box.check(states, stacklevel=2)
        for task in np.unique(tasks):
            learner = self.task_learners.get(int(task))
            if (learner is None or not learner.fitted) and int(task) not in self._warned_unfitted:
                self._warned_unfitted.add(int(task))
                warnings.warn(UNFITTED_TASK.format(task=task), stacklevel=2)
        if deterministic or self.config.tie_break == "first":
            return super().predict(observation, state, episode_start, deterministic)
        actions = self.engine.greedy(np.zeros(len(states), dtype=np.int64), states, tasks)
        _, vectorized = self.policy.obs_to_tensor(observation)
        return (actions if vectorized else actions.squeeze(axis=0)), state


def _policy_class(policy: str | type[TaskQPolicy], aliases: dict[str, type[BasePolicy]]) -> type[BasePolicy]:
    """
    The policy class of ``policy``: a ``TaskQPolicy`` subclass as it is, or the class of a name among
    ``aliases``.

    :raises ValueError: for an unknown name, or anything else (another class, a number)
    """
    if isinstance(policy, type) and issubclass(policy, TaskQPolicy):
        return policy
    if not isinstance(policy, str) or policy not in aliases:
        raise ValueError(f"policy must be one of {sorted(aliases)} or a TaskQPolicy subclass, got {policy!r}")
    return aliases[policy]
