"""
TRLSD: transfer reinforcement learning with shared dynamics, as an SB3 off-policy algorithm: its settings,
its model (policy, shared buffer and feature map) and its task learners. Its online loop is
``online_loop.py``'s, what it adds to SB3's interface ``sb3_interface.py``'s.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.builders import new_task_learner, shared_features, state_box
from sb3_trlsd.data import Transitions
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.fqi import DEFAULT_TOL
from sb3_trlsd.online_loop import TRLSDOnlineLoop
from sb3_trlsd.persistence import empty_rows
from sb3_trlsd.policies import LinearPolicy, MlpPolicy, TaskQPolicy
from sb3_trlsd.reward_heads import RewardFn, RewardHead
from sb3_trlsd.sb3_interface import TRLSDInterface
from sb3_trlsd.settings import check_arguments, resolve_policy
from sb3_trlsd.task_learner import TaskLearner

__all__ = ["TRLSD"]


class TRLSD(TRLSDInterface, TRLSDOnlineLoop, OffPolicyAlgorithm):
    """
    Transfer Reinforcement Learning with Shared Dynamics (TRLSD).

    Paper: Laroche & Barlier, "Transfer Reinforcement Learning with Shared Dynamics", AAAI 2017.
    Every transition of every task goes to one shared buffer; for a target task, the buffer's rewards are
    replaced by an optimistic proxy R~ = R^ + CI learnt from that task's own samples (section 3), and its Q
    is refitted on that relabelled set by Fitted-Q Iteration (Algorithm 1): at its first step (or after its
    first sample, ``first_fit``), then whenever the CI at an encountered state has been divided by
    ``update_ratio``. Each task's learning state is a ``TaskLearner``; ``TRLSDOnlineLoop`` runs the online
    loop (``act``, ``add_online_transition``, ``train``, ``update_policy``); ``TRLSDInterface`` adds SB3's
    save/load (with the buffer's rows), learn and predict.

    Defaults are the paper's (section 4) where it gives them: kappa and sigma of the continuous setting,
    ``update_ratio=2``, lambda = 1 for the reward regression, 5x5 RBFs of width 0.2. The paper does not
    give the discount factor: ``gamma=0.9`` makes the maze's reward cell worth reaching from anywhere
    (its effective horizon of ~10 steps covers the longest path around the walls) and keeps FQI short.

    :param policy: ``"LinearPolicy"`` (the paper's linear Q on RBF features) or ``"MlpPolicy"``
    :param env: the environment (Gymnasium env, VecEnv with one env, or registered id); observations are a
        state Box, or a ``{"state": Box, "task": Discrete}`` Dict for several tasks
    :param gamma: discount factor
    :param reward_head: ``"ridge"`` (eq. 9), ``"tabular"`` (per-cell means, eq. 10, on a grid over the state
        box or a ``cell_fn``), ``"corners"`` (only the grid's corner cells pay), ``"known"`` (CI = 0); other
        confidence bounds (``sb3_trlsd.reward_heads``): ``"ridge_posterior"`` (OFUL / LinUCB's kappa
        sqrt(phi^T A^-1 phi) on the shared features, refitted when det A has grown by ``update_ratio``),
        ``"thompson"`` (posterior draws of the ridge weights of scale kappa, one per refit, seeded by ``seed``
        and the task) or ``"bernstein"`` (UCB-V's kernel-weighted empirical-Bernstein bound, eq. 6 of width
        ``sigma``); or a ``RewardHead`` copied for each task
    :param kappa: optimism (eq. 9, 10); 0 is the non-optimistic method of Atkeson & Santamaria
    :param sigma: width of the similarity in W (eq. 8): for eq. 6 a fraction of the state box, one or one per
        dimension (None: ``default_kernel_width(d)``, 0.04 in 2-D: the paper's 0.2 on the maze); for eq. 7
        a distance between feature vectors (None: 0.2)
    :param similarity: ``"state"`` (eq. 6, on states) or ``"features"`` (eq. 7, on RBF features)
    :param update_ratio: refit a task when the CI at an encountered state has been divided by this (> 1)
    :param first_fit: when a task's Q is first fitted (the paper does not say): ``"first_step"``, before its
        first action, on the optimism of a head with no sample; ``"first_sample"``, once its first sample is
        in (its first action is the unfitted Q's argmax)
    :param fqi_max_iterations: cap on Fitted-Q iterations per refit (None: the policy's own default)
    :param fqi_tol: Fitted-Q stops when the parameters move by less than this, relative to their scale
    :param feature_map: Phi, shared by the linear policy and the ridge heads: ``"rbf"`` (eq. 11's grid),
        ``"fourier"`` (linear in the dimension), ``"auto"`` (the grid up to 125 centres) or a ``FeatureMap``
    :param rbf_per_dim: RBF centres per state dimension of the grid
    :param rbf_sigma: width of the features, a fraction of the state box (one, or one per dimension); None:
        a fifth of the grid's spacing (the paper's 0.2 on the maze), ``default_kernel_width(d)`` for Fourier
    :param fourier_features: the number of Fourier features (None: 50 per state dimension)
    :param state_bounds: ``(low, high)`` of the states for an unbounded Box (None: the Box's, finite)
    :param reward_fn: ``reward_fn(states (n, d), task) -> (n,)``, the expected reward for the ``"known"``
        head; by default the env's ``expected_reward``. Not saved: give it again to ``load``
    :param reward_head_kwargs: extra arguments of the named reward heads (e.g. ``w_floor``, ``r_max``;
        ``ridge`` of the linear-posterior heads, ``seed`` of ``"thompson"``, ``reward_range`` of
        ``"bernstein"``)
    :param source_transitions: source set loaded (rewards discarded) at the first ``learn``: a number of
        random transitions (the paper's 25,000) from ``source_env``, or the path of a ``Transitions`` .npz
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
    features: FeatureMap | None
    task_learners: dict[int, TaskLearner]

    def __init__(
        self,
        policy: str | type[TaskQPolicy],
        env: GymEnv | str | None,
        gamma: float = 0.9,
        reward_head: str | RewardHead = "ridge",
        kappa: float = 0.1,
        sigma: float | Sequence[float] | None = None,
        similarity: str = "state",
        update_ratio: float = 2.0,
        first_fit: str = "first_step",
        fqi_max_iterations: int | None = None,
        fqi_tol: float = DEFAULT_TOL,
        feature_map: str | FeatureMap = "auto",
        rbf_per_dim: int = 5,
        rbf_sigma: float | Sequence[float] | None = None,
        fourier_features: int | None = None,
        state_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
        reward_fn: RewardFn | None = None,
        reward_head_kwargs: dict[str, Any] | None = None,
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
        super().__init__(
            # Resolved here: SB3 would otherwise ask for "MultiInputPolicy" on Dict observations.
            policy=resolve_policy(policy, self.policy_aliases),
            env=env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            support_multi_env=False,
        )
        self.reward_head = reward_head
        self.kappa = kappa
        self.sigma = sigma
        self.similarity = similarity
        self.update_ratio = update_ratio
        self.first_fit = first_fit
        self.fqi_max_iterations = fqi_max_iterations
        self.fqi_tol = fqi_tol
        self.feature_map = feature_map
        self.rbf_per_dim = rbf_per_dim
        self.rbf_sigma = rbf_sigma
        self.fourier_features = fourier_features
        self.state_bounds = state_bounds
        self.reward_fn = reward_fn
        self.reward_head_kwargs = dict(reward_head_kwargs or {})
        self.source_transitions = source_transitions
        self.source_seed = source_seed
        self.source_env = source_env
        self.log_picture_every = log_picture_every
        self._source_loaded = False
        self.task_learners = {}
        check_arguments(self)
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
        # One feature map Phi, for the linear policy and the ridge heads.
        self.features = shared_features(self)
        if issubclass(self.policy_class, LinearPolicy):
            self.policy_kwargs["features"] = self.features
        elif issubclass(self.policy_class, MlpPolicy):
            self.policy_kwargs["state_bounds"] = state_box(self)
        super()._setup_model()
        self._fit_rows = self.policy.new_fit_rows()  # the buffer's rows as the Q-function fits on them
        self._buffer_rows = empty_rows()  # the buffer's rows, during save and load only
        self._warned_unfitted: set[int] = set()

    # ------------------------------------------------------------- task learners
    def task_learner(self, task: int) -> TaskLearner:
        """The learning state of ``task``, created (with no samples) the first time it is asked for."""
        task = int(task)
        if not 0 <= task < self.policy.n_tasks:
            raise ValueError(f"task must be in 0..{self.policy.n_tasks - 1}, got {task}")
        if task not in self.task_learners:
            self.task_learners[task] = new_task_learner(self, task)
        return self.task_learners[task]

    def reward_head_of(self, task: int) -> RewardHead:
        """The reward head of ``task`` (see ``task_learner``)."""
        return self.task_learner(task).head

    @property
    def reward_heads(self) -> dict[int, RewardHead]:
        """The reward head of every task seen so far."""
        return {task: learner.head for task, learner in self.task_learners.items()}

    @property
    def policy_updates(self) -> dict[int, int]:
        """The refits of every task seen so far (its first fit included)."""
        return {task: learner.refits for task, learner in self.task_learners.items()}

    # --------------------------------------------------------------- transitions
    def load_transitions(self, data: Transitions | str | os.PathLike, keep_rewards: bool = False) -> None:
        """
        Add transitions collected elsewhere to the shared buffer (the paper's source set Xi).

        :param data: transitions (see ``collect_transitions``) or the path of a ``.npz`` saved from them
        :param keep_rewards: also fit each task's reward head on the rewards of its transitions; False
            (the paper's setting) uses them for the dynamics only
        """
        transitions = data if isinstance(data, Transitions) else Transitions.load(data)
        self.replay_buffer.add_transitions(transitions, keep_rewards=keep_rewards)
        if keep_rewards:
            for task in np.unique(transitions.tasks):
                rows = transitions.tasks == task
                self.task_learner(task).head.update(transitions.states[rows], transitions.rewards[rows])
        # New dynamics data: every fitted task is refitted at the next training round.
        for learner in self.task_learners.values():
            learner.due = learner.due or learner.fitted
