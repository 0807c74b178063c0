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
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.callbacks import TaskView, has_tensorboard, log_hyperparameters, log_task_picture
from sb3_trlsd.config import LearnerBuilder, TRLSDConfig, check_discount
from sb3_trlsd.engine import Engine, Run, explore_rng, tie_rng
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.foreign_data import TransitionSource, rows_to_store
from sb3_trlsd.fqi import FQIResult
from sb3_trlsd.observations import StateBoxMonitor, check_action_space, split_observation, state_space_of
from sb3_trlsd.persistence import BUFFER_ROWS, empty_rows, read_replay_buffer
from sb3_trlsd.policies import LinearPolicy, MlpPolicy, TaskQPolicy
from sb3_trlsd.q_functions import PolicyQFunctions
from sb3_trlsd.reward_heads import KnownRewardHead, RewardFn, RewardHead
from sb3_trlsd.reward_timing import staying_inputs
from sb3_trlsd.source_data import check_source_transitions, source_transitions_of
from sb3_trlsd.task_learner import TaskLearner

__all__ = ["TRLSD", "UNFITTED_TASK"]

SelfTRLSD = TypeVar("SelfTRLSD", bound="TRLSD")
UNFITTED_TASK = (
    "task {task} has never been fitted: its Q-function is 0 and predict returns action 0 for every state; "
    "learn on it first, or call model.update_policy({task})"
)
# Settings of the features Phi that belong to TRLSD (which shares Phi between the policy and the heads).
FEATURE_SETTINGS = ("features", "rbf_per_dim", "rbf_sigma", "rbf_overlap", "max_features", "state_bounds")


class _SingleTaskReward:
    """A Box-observation env's ``expected_reward(states)`` seen as ``reward_fn(states, task)`` (one task)."""

    def __init__(self, expected_reward: Callable[[np.ndarray], np.ndarray]):
        self.expected_reward = expected_reward

    def __call__(self, states: np.ndarray, task: int) -> np.ndarray:
        return self.expected_reward(states)


class TRLSD(OffPolicyAlgorithm):
    """
    Transfer Reinforcement Learning with Shared Dynamics (TRLSD).

    Paper: Laroche & Barlier, "Transfer Reinforcement Learning with Shared Dynamics", AAAI 2017.
    Every transition of every task goes to one shared buffer; for a target task, the buffer's rewards are
    replaced by an optimistic proxy R~ = R^ + CI learnt from that task's own samples (section 3), and its Q
    is refitted on that relabelled set by Fitted-Q Iteration (Algorithm 1): at its first step (or after its
    first sample, ``first_fit``), then whenever the CI at an encountered state has been divided by
    ``update_ratio``. The settings of the learning are a ``TRLSDConfig`` (``model.config``); each task's
    learning state is a ``TaskLearner`` (``task_learner``); the online loop is an ``Engine`` of one run that
    SB3's rollout drives (all ``n_envs`` envs feed the one shared buffer and the one learner per task), and
    so do ``act`` and ``add_online_transition`` from a loop of one's own. ``save``/``load`` keep the buffer's
    rows, so that a loaded model goes on learning as an uninterrupted one would.

    Defaults are meant for any family of tasks, not one env's units: ``update_ratio=2`` and lambda = 1 for the
    reward regression are the paper's (section 4); the features (``"auto"``), Fitted-Q's stopping rule
    (``"targets"``), ``refit_growth=0.1``, the reward timing, the exploration schedule and the reward head
    (posterior draws over a source) were chosen on the tuning weights of the MO-Gymnasium suite
    (``benchmarks/tune_suite.py``, see the docs' benchmarks page). The paper's own settings (kappa 0.1, its
    5x5 RBFs of width 0.2, refits as soon as the trigger fires, the greedy policy throughout) are what
    ``sb3-trlsd reproduce`` and the maze's zoo configs give. The paper does not give the discount factor:
    ``gamma=0.9`` makes the maze's reward cell worth reaching from anywhere (its effective horizon of ~10
    steps covers the longest path around the walls) and keeps FQI short.

    :param policy: ``"LinearPolicy"`` (the paper's linear Q on RBF features) or ``"MlpPolicy"``
    :param env: the environment (Gymnasium env, VecEnv of any number of envs, or registered id); observations
        are a state Box, or a ``{"state": Box, "task": Discrete}`` Dict for several tasks
    :param gamma: discount factor
    :param reward_head: ``"ridge"`` (eq. 9), ``"tabular"`` (per-cell means, eq. 10, on a grid over the state
        box or a ``cell_fn``), ``"corners"`` (only the grid's corner cells pay), ``"known"`` (CI = 0); other
        confidence bounds (``sb3_trlsd.reward_heads``): ``"ridge_posterior"`` (OFUL / LinUCB's kappa
        sqrt(phi^T A^-1 phi) on the shared features, refitted when det A has grown by ``update_ratio``),
        ``"thompson"`` (the default: posterior draws of the ridge weights of scale kappa, one per refit,
        seeded by ``seed`` and the task) or ``"bernstein"`` (UCB-V's kernel-weighted empirical-Bernstein
        bound, eq. 6 of width ``sigma``); or a ``RewardHead`` copied for each task
    :param kappa: optimism (eq. 9, 10), in the env's reward units, and for ``"thompson"`` the posterior
        scale, by default in units of the largest absolute reward seen (its ``kappa_scale="observed"``). 0 is
        the non-optimistic method of Atkeson & Santamaria; the paper's continuous setting uses 0.1 on rewards
        in [0, 1]. None: the head's (``sb3_trlsd.config.head_defaults``), 0.01 for ``"thompson"`` and 0 for
        the others
    :param sigma: width of the similarity in W (eq. 8): for eq. 6 a fraction of the state box, one or one per
        dimension (None: ``default_kernel_width(d)``, 0.04 in 2-D: the paper's 0.2 on the maze); for eq. 7
        a distance between feature vectors (None: 0.2)
    :param similarity: ``"state"`` (eq. 6, on states) or ``"features"`` (eq. 7, on RBF features)
    :param update_ratio: refit a task when the CI at an encountered state has been divided by this (> 1)
    :param first_fit: when a task's Q is first fitted (the paper does not say): ``"first_step"``, before its
        first action, on the optimism of a head with no sample; ``"first_sample"``, once its first sample is
        in (its first action is the unfitted Q's argmax)
    :param refit_growth: once the trigger has fired, a task's refit waits until its samples have grown by this
        fraction since its last refit: refits are then at most ~1 / refit_growth + ln(n) / ln(1 +
        refit_growth) over n samples (rarely-switching optimism's lazy updates), so their cost per step
        falls as a run goes on; 0 refits as soon as the trigger fires (the paper's Algorithm 1)
    :param optimism: where the shared buffer is relabelled with the optimistic R~ rather than the estimate
        R^: ``"always"`` (the paper), or ``"with_source"``, once the buffer holds rows the task did not
        collect itself (a source, other tasks' rows); None: the head's, ``"with_source"`` for
        ``"thompson"`` and ``"always"`` for the others. Fitted-Q sees the buffer's rows only, so optimism
        reaches the Q-function through the rows it relabels: learning from scratch, a bonus or a posterior
        draw values the rows visited against unvisited ones left at 0 and keeps the greedy policy among the
        visited, where R^ (0 everywhere before a reward) leaves it to the tie-break and exploration
    :param tie_break: the action taken among equal Q-values while learning (``learn``, ``act``, ``predict``
        with ``deterministic=False``): ``"random"``, one of them drawn with a generator seeded by ``seed``
        (a Q that is 0 everywhere, as before any reward is seen with kappa = 0, then explores at random
        instead of repeating action 0), or ``"first"`` (the paper's reproduction). ``predict`` with
        ``deterministic=True`` takes the first
    :param exploration_initial_eps: epsilon-greedy while learning (``learn``, ``act``; ``predict`` stays
        greedy), per task: the probability of a uniformly random action at a task's first online step. A
        greedy policy on a Q that no reward supports yet is deterministic all the same and can walk into a
        wall and stay there; random steps spread a new task's first samples instead. None: 1 for the heads
        that learn the reward, 0 for a head with nothing to learn (``"known"``, or a ``RewardHead`` without
        uncertainty), which acts greedily from its first step (``sb3_trlsd.config.head_defaults``); a value
        given wins. 0 with ``exploration_final_eps=0`` is the paper's greedy policy (its reproduction)
    :param exploration_final_eps: the probability once the task has ``exploration_steps`` online samples
    :param exploration_steps: a task's online samples over which the probability falls linearly from
        ``exploration_initial_eps`` to ``exploration_final_eps``. The schedule counts each task's own samples,
        not the ``total_timesteps`` of ``learn`` (SB3's DQN's ``exploration_fraction``): TRLSD meets new
        tasks as it goes, and ``act`` knows no budget
    :param fqi_max_iterations: cap on Fitted-Q iterations per refit (None: the policy's own default, 500
        linear and 200 MLP, and under ``fqi_stop="targets"`` at most ``sb3_trlsd.fqi.targets_rule_cap(gamma,
        fqi_tol)``, three times what a gamma-contraction needs: 198 at gamma 0.9)
    :param fqi_tol: Fitted-Q's relative stopping tolerance (see ``fqi_stop``; None: 1e-3 on the targets,
        1e-4 on theta)
    :param fqi_stop: Fitted-Q's stopping rule: ``"targets"``, once the Bellman targets move by less than
        ``fqi_tol`` of the return scale (what the next fit can still change on the data); ``"theta"``, once
        the parameters move by less than ``fqi_tol`` of their scale (the paper's reproduction: with float32
        features, directions of theta the data does not see may never settle). A refit that reaches
        ``fqi_max_iterations`` first warns (``sb3_trlsd.fqi.FQICapWarning``)
    :param feature_map: Phi, shared by the linear policy and the feature heads: ``"auto"`` (on a Box of
        integers with at most 125 points, ``"lattice"``; else a grid of RBFs 1.5 spacings wide, counts from
        the box under ``max_features``, while every dimension gets at least 3 centres; else a row of RBFs per
        dimension, added), ``"lattice"`` (one RBF per integer point of the box, half a spacing wide: a
        grid-world's cells), ``"paper"`` (eq. 11: the grid up to 125 centres, a fifth of the spacing wide,
        else Fourier features), ``"rbf"``, ``"additive"``, ``"fourier"``, or a ``FeatureMap`` (see
        ``sb3_trlsd.feature_choice.make_feature_map``)
    :param rbf_per_dim: RBF centres per state dimension: one integer, one per dimension, or ``"cube"`` (the
        same count in every dimension) / ``"box"`` (counts proportional to the box's sides, in its units)
        under ``max_features``; None: the feature map's default (``"cube"``; 5 for ``"paper"``)
    :param rbf_sigma: width of the features, a fraction of the state box (one, or one per dimension); None:
        ``rbf_overlap`` spacings of the centres, ``default_kernel_width(d)`` for Fourier features
    :param rbf_overlap: width of the RBFs in spacings of their centres (None: 1.5, the paper's 0.2 for
        ``"paper"``); not with ``rbf_sigma``
    :param max_features: the feature map's budget (None: 64, 125 for ``"paper"``)
    :param fourier_features: the number of Fourier features (None: 50 per state dimension)
    :param state_bounds: ``(low, high)`` of the states for an unbounded Box (None: the Box's, finite)
    :param reward_fn: ``reward_fn(states (n, d), task) -> (n,)``, the expected reward for the ``"known"``
        head; by default the env's ``expected_reward``. Not saved: give it again to ``load``
    :param reward_head_kwargs: extra arguments of the named reward heads (e.g. ``w_floor``, ``r_max``;
        ``ridge`` of the linear-posterior heads, ``seed`` and ``kappa_scale`` of ``"thompson"``
        (``"observed"``, its default here: kappa in units of the largest absolute reward seen; ``"reward"``:
        in the env's reward units), ``reward_range`` of
        ``"bernstein"``); one the head does not take is refused (``reward_heads.head_arguments``)
    :param reward_timing: what of a transition its reward belongs to, which the reward heads learn and
        relabel at: ``"start_state"`` (the paper's R_tau(s)), ``"next_state"`` (the state it arrives at:
        e.g. a goal paid on arrival), ``"transition"`` (the pair (s, s'), whose features are Phi(s) and
        Phi(s') side by side: a reward paid the first time a place is reached, say), ``"step"`` ((s, a, s'),
        the action's one-hot code between them: a cost per action too) or ``"auto"`` (the env's
        ``metadata["reward_timing"]`` where it declares one, as this package's envs do, else ``"step"``,
        Gymnasium's r(s, a, s'), for the heads that can learn it and ``"next_state"`` for the ``"known"``
        and tabular heads)
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
        self.config = TRLSDConfig(
            reward_head=reward_head,
            kappa=kappa,
            sigma=sigma,
            similarity=similarity,
            update_ratio=update_ratio,
            first_fit=first_fit,
            refit_growth=refit_growth,
            optimism=optimism,
            tie_break=tie_break,
            exploration_initial_eps=exploration_initial_eps,
            exploration_final_eps=exploration_final_eps,
            exploration_steps=exploration_steps,
            fqi_max_iterations=fqi_max_iterations,
            fqi_tol=fqi_tol,
            fqi_stop=fqi_stop,
            feature_map=feature_map,
            rbf_per_dim=rbf_per_dim,
            rbf_sigma=rbf_sigma,
            rbf_overlap=rbf_overlap,
            max_features=max_features,
            fourier_features=fourier_features,
            state_bounds=state_bounds,
            reward_head_kwargs=reward_head_kwargs or {},
            reward_timing=reward_timing,
        )
        check_source_transitions(source_transitions)
        if isinstance(log_picture_every, bool) or not (
            isinstance(log_picture_every, (int, np.integer)) and log_picture_every >= 0
        ):
            raise ValueError(f"log_picture_every must be an integer >= 0, got {log_picture_every!r}")
        shadowed = sorted(set(policy_kwargs or {}) & set(FEATURE_SETTINGS))
        if shadowed:
            raise ValueError(
                f"policy_kwargs may not set {shadowed}: the features are TRLSD's, shared by the policy and "
                "the reward heads; give feature_map, rbf_per_dim, rbf_sigma or state_bounds to TRLSD(...)"
            )
        check_discount(gamma)
        super().__init__(
            # Resolved here: SB3 would otherwise ask for "MultiInputPolicy" on Dict observations.
            policy=_policy_class(policy, self.policy_aliases),
            # None when ``load`` makes the model, as for SB3's own algorithms (OffPolicyAlgorithm's annotation
            # leaves None out; BaseAlgorithm takes it)
            env=env,  # type: ignore[arg-type]
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            # A copy: the features are added to it, and the caller's dict may build another model.
            policy_kwargs=dict(policy_kwargs or {}),
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
        # One feature map Phi, for the linear policy and the feature heads.
        self.features = self._builder.features
        if linear_q:
            self.policy_kwargs["features"] = self.features
        elif issubclass(self.policy_class, MlpPolicy):
            self.policy_kwargs["state_bounds"] = (self._builder.low, self._builder.high)
        super()._setup_model()
        self._buffer_rows = empty_rows()  # the buffer's rows, during save and load only
        self._warned_unfitted: set[int] = set()
        self._state_box = StateBoxMonitor(self._builder.low, self._builder.high)
        self.engine = self._new_engine()

    def _new_engine(self) -> Engine:
        """The engine of this model's one run: its shared buffer, task learners and policy."""
        if not hasattr(self, "_ties"):  # a loaded model draws on from where it was saved
            self._ties = tie_rng(self.seed)
        if not hasattr(self, "_explore"):
            self._explore = explore_rng(self.seed)
        ties = self._ties if self.config.tie_break == "random" else None
        return Engine(
            [Run(self.replay_buffer, self.task_learners, ties=ties, explore=self._explore)],
            PolicyQFunctions(self.policy),
            lambda run, task: self.new_task_learner(task),
            gamma=self.gamma,
            max_iterations=self.config.fqi_max_iterations,
            tol=self.config.fqi_tolerance,
            stop_rule=self.config.fqi_stop,
            on_refit=self._log_refit,
            exploration=self.config.exploration,
        )

    # ------------------------------------------------------------- task learners
    def _known_reward_fn(self) -> RewardFn | None:
        """The model's ``reward_fn``, else the env's ``expected_reward`` (None without either)."""
        if self.reward_fn is not None:
            return self.reward_fn
        env = self.env
        if env is None or not env.has_attr("expected_reward"):
            return None
        method = env.get_attr("expected_reward", indices=0)[0]
        return method if isinstance(self.observation_space, spaces.Dict) else _SingleTaskReward(method)

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
        :raises ValueError: for rows that do not fit the env, or whose rewards belong to no task of it
        """
        for transitions, rewarded in rows_to_store(
            data, task, keep_rewards, self.observation_space, self.action_space
        ):
            self._state_box.check(np.concatenate([transitions.states, transitions.next_states]), stacklevel=2)
            self.replay_buffer.add_transitions(transitions, keep_rewards=rewarded)
            if rewarded:
                for row_task in np.unique(transitions.tasks):
                    rows = transitions.tasks == row_task
                    learner = self.task_learner(row_task)
                    inputs = learner.inputs(
                        transitions.states[rows], transitions.actions[rows], transitions.next_states[rows]
                    )
                    learner.head.update(inputs, transitions.rewards[rows])
        # New dynamics data: every fitted task is refitted at the next training round.
        for learner in self.task_learners.values():
            learner.due = learner.due or learner.fitted

    # ------------------------------------------------------ the online loop (SB3)
    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # Before learning_starts, SB3's uniformly random actions; then the engine's: a task's Q is fitted at
        # its first step (unless ``first_fit`` waits), the greedy action, and the task's exploration.
        if self.num_timesteps < learning_starts or self._last_obs is None:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        obs, state_dim = self._last_obs, self.replay_buffer.obs_shape[0]
        states, tasks = split_observation(obs, state_dim, require_finite=True)
        self._state_box.check(states, stacklevel=4)
        actions = self.engine.act(np.zeros(len(tasks), dtype=np.int64), states, tasks)
        return actions, actions

    def _on_step(self) -> None:
        """Feed the transitions just stored (one row per env) to the engine: their tasks' learners."""
        self._observe_stored(self.n_envs)

    def _observe_stored(self, n_rows: int) -> None:
        """Feed the last ``n_rows`` rows of the shared buffer to the engine, as its one run's transitions."""
        buffer = self.replay_buffer
        rows = (buffer.pos - np.arange(n_rows, 0, -1)) % buffer.buffer_size
        tasks = buffer.tasks[rows, 0]
        timeouts = buffer.timeouts[rows, 0].astype(bool)
        self._state_box.check(buffer.next_observations[rows, 0], stacklevel=4)
        self.engine.observe(
            np.zeros(n_rows, dtype=np.int64),
            buffer.observations[rows, 0],
            buffer.actions[rows, 0, 0],
            buffer.rewards[rows, 0],
            buffer.next_observations[rows, 0],
            tasks,
            buffer.dones[rows, 0].astype(bool) & ~timeouts,
            timeouts,
            store=False,
        )
        if getattr(self, "_logger", None) is not None:
            self.logger.record("reward/target_samples", self.task_learner(tasks[-1]).head.n_samples)

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
        states, tasks = split_observation(obs, self.replay_buffer.obs_shape[0], require_finite=True)
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
        self._observe_stored(1)
        self.engine.refit_due()

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
        """
        What a refit writes to the logger (nothing outside ``learn``, before SB3 made one):
        ``train/policy_updates``, ``train/fqi_iterations``, ``train/bellman_residual``, ``reward/ci_mean``
        (the optimism applied, mean of R~ - R^ over the relabelled set, when the logger writes somewhere),
        and the task's picture when one is due.
        """
        self._n_updates += 1
        if getattr(self, "_logger", None) is None:
            return
        self.logger.record("train/policy_updates", sum(self.policy_updates.values()))
        self.logger.record("train/fqi_iterations", result.iterations)
        self.logger.record("train/bellman_residual", result.bellman_residual)
        if len(rewards) and self.logger.output_formats:
            stored = self.replay_buffer.transitions()
            inputs = learner.inputs(stored.states, stored.actions, stored.next_states)
            estimates = learner.head.estimate(inputs)
            self.logger.record("reward/ci_mean", float(np.mean(rewards - estimates)))
        every = self.log_picture_every
        due = every and (learner.refits == 1 or learner.refits % every == 0)
        if due and has_tensorboard(self.logger):
            view = TaskView(
                task=learner.task,
                estimate=lambda states: self._staying(learner, learner.head.estimate, states),
                bonus=lambda states: self._staying(learner, learner.head.bonus, states),
                q_values=lambda states: self.policy.q_values(states, learner.task),
                trajectory=self.replay_buffer.recent_states(learner.task, 50),
            )
            log_task_picture(self.logger, self.env, view, self.num_timesteps)

    def _staying(
        self, learner: TaskLearner, values: Callable[[np.ndarray], np.ndarray], states: np.ndarray
    ) -> np.ndarray:
        """A head's ``values`` (estimate or bonus) of staying at ``states``, averaged over the actions."""
        assert isinstance(self.action_space, spaces.Discrete)
        inputs = staying_inputs(states, learner.reward_timing, int(self.action_space.n))
        return np.mean([values(rows) for rows in inputs], axis=0)

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
        """SB3's ``save``, with the shared buffer's rows in the zip (so that ``load`` can go on learning)."""
        self._buffer_rows = th.as_tensor(self.replay_buffer.packed_rows())
        try:
            super().save(path, exclude=exclude, include=include)
        finally:
            self._buffer_rows = empty_rows()

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
        """SB3's ``load``; the shared buffer comes back with its rows, the known heads with reward_fn."""
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        rows = model._buffer_rows
        if len(rows):
            model.replay_buffer.restore_packed_rows(rows.numpy())
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
        settings: dict[str, Any] = {
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

    def _load_source_once(self) -> None:
        """
        Before ``learn``: load the source set into the shared buffer the first time (rewards discarded), and
        warn when the buffer is empty although the model learnt before (a model saved without its rows).
        """
        if self.source_transitions is not None and not self._source_loaded:
            source = source_transitions_of(
                self.source_transitions,
                self.source_env,
                self.env,
                self.seed if self.source_seed is None else self.source_seed,
            )
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

    def learn(
        self: SelfTRLSD,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "TRLSD",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfTRLSD:
        self._load_source_once()
        super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
        # SB3 dumps the logs every log_interval episodes: a run's last values are kept too.
        self.dump_logs()
        return self

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
        states, tasks = split_observation(observation, self.replay_buffer.obs_shape[0], require_finite=True)
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
    The policy class of ``policy``: a class as it is, or the class of a name among ``aliases``.

    :raises ValueError: for an unknown name
    """
    if not isinstance(policy, str):
        return policy
    if policy not in aliases:
        raise ValueError(f"policy must be one of {sorted(aliases)} or a policy class, got {policy!r}")
    return aliases[policy]
