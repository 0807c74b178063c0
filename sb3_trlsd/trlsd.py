"""TRLSD: transfer reinforcement learning with shared dynamics, as an SB3 off-policy algorithm."""

from __future__ import annotations

import copy
import dataclasses
import os
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import Any, ClassVar, TypeVar

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import HParam, Image, TensorBoardOutputFormat
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer, state_space_of
from sb3_trlsd.data import Transitions, collect_transitions
from sb3_trlsd.features import RBFGrid
from sb3_trlsd.pictures import task_picture
from sb3_trlsd.policies import LinearPolicy, MlpPolicy, TaskQPolicy
from sb3_trlsd.reward_heads import REWARD_HEAD_NAMES, RewardHead, make_reward_head

__all__ = ["TRLSD"]

SelfTRLSD = TypeVar("SelfTRLSD", bound="TRLSD")
UncertaintyFn = Callable[[np.ndarray], np.ndarray]
PICTURE_TRAIL = 50  # states of a task's latest trajectory drawn in its TensorBoard picture


class TRLSD(OffPolicyAlgorithm):
    """
    Transfer Reinforcement Learning with Shared Dynamics (TRLSD).

    Paper: Laroche & Barlier, "Transfer Reinforcement Learning with Shared Dynamics", AAAI 2017.
    Every transition of every task goes to one shared replay buffer; for a target task, the rewards of
    the whole buffer are replaced by an optimistic reward proxy R~ = R^ + CI learnt from that task's own
    samples (section 3), and the task's Q-function is refitted on that relabelled set by Fitted-Q
    Iteration (Algorithm 1). A task's Q is refitted at its first step and then whenever the confidence
    interval at an encountered state has been divided by ``update_ratio`` since its last refit.

    Defaults are the paper's (section 4) where it gives them: kappa and sigma of the continuous setting,
    ``update_ratio=2``, lambda = 1 for the reward regression, 5x5 RBFs of width 0.2. The paper does not
    give the discount factor: ``gamma=0.9`` makes the maze's reward cell worth reaching from anywhere in the
    5x5 grid (its effective horizon of ~10 steps covers the longest path around the walls) while keeping
    the fixed-point iterations of FQI short.

    :param policy: ``"LinearPolicy"`` (the paper's linear Q on RBF features) or ``"MlpPolicy"``
    :param env: the environment (Gymnasium env, VecEnv with one env, or registered id); observations are a
        state Box, or a ``{"state": Box, "task": Discrete}`` Dict for several tasks
    :param gamma: discount factor
    :param reward_head: how R~ is learnt: ``"ridge"`` (continuous setting, eq. 9), ``"tabular"`` (the
        maze's 25 cells, eq. 10), ``"corners"`` (tabular with the prior that only the 4 corner cells are
        rewarded), ``"known"`` (the true expected reward, CI = 0), or a ``RewardHead`` instance copied for
        each task
    :param kappa: optimism (eq. 9, 10); 0 is the non-optimistic method of Atkeson & Santamaria
    :param sigma: width of the similarity of eq. 6 / 7 in the neighbouring weight W (eq. 8)
    :param similarity: ``"state"`` (eq. 6, on states) or ``"features"`` (eq. 7, on RBF features)
    :param update_ratio: a task's Q is refitted when the CI at an encountered state has been divided by
        this since the last refit (> 1)
    :param fqi_max_iterations: cap on Fitted-Q iterations per refit (None: the policy's own default)
    :param fqi_tol: Fitted-Q stops when the parameters move by less than this, relative to their scale
        (default 1e-4: half the iterations of 1e-6 from a warm start, and the same greedy actions in practice)
    :param rbf_per_dim: RBF centres per state dimension for the features Phi (policy and ridge head)
    :param rbf_sigma: width of the RBF features (eq. 11)
    :param reward_fn: ``reward_fn(states, task)``, the expected reward for the ``"known"`` head; by default
        the env's ``expected_reward`` method
    :param reward_head_kwargs: extra arguments of the reward heads (e.g. ``w_floor``, ``r_max``)
    :param source_transitions: source set loaded (rewards discarded) at the start of the first ``learn``:
        a number of transitions to collect with a random policy from a copy of the env (``gym.make`` of
        its spec; the paper's 25,000), or the path of a ``.npz`` saved by ``Transitions.save``; None: none
        (``load_transitions`` does the same by hand). This is how a config file gives the source data.
    :param source_seed: seed of the collection of ``source_transitions`` (None: ``seed``)
    :param log_picture_every: with TensorBoard on the maze, log a picture of a task (R^, its bonus, the
        greedy policy, the latest trajectory) at its first refit and then every this many of its refits;
        0 disables it
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
    features: RBFGrid
    reward_heads: dict[int, RewardHead]
    policy_updates: dict[int, int]

    def __init__(
        self,
        policy: str | type[TaskQPolicy],
        env: GymEnv | str | None,
        gamma: float = 0.9,
        reward_head: str | RewardHead = "ridge",
        kappa: float = 0.1,
        sigma: float = 0.2,
        similarity: str = "state",
        update_ratio: float = 2.0,
        fqi_max_iterations: int | None = None,
        fqi_tol: float = 1e-4,
        rbf_per_dim: int = 5,
        rbf_sigma: float = 0.2,
        reward_fn: Callable[[np.ndarray, int], np.ndarray] | None = None,
        reward_head_kwargs: dict[str, Any] | None = None,
        source_transitions: int | str | os.PathLike | None = None,
        source_seed: int | None = None,
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
        if isinstance(policy, str):
            if policy not in self.policy_aliases:
                raise ValueError(
                    f"policy must be one of {sorted(self.policy_aliases)} or a policy class, got {policy!r}"
                )
            # Resolved here: SB3 would otherwise ask for "MultiInputPolicy" on Dict observations.
            policy = self.policy_aliases[policy]  # type: ignore[assignment]
        super().__init__(
            policy=policy,
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
        self.fqi_max_iterations = fqi_max_iterations
        self.fqi_tol = fqi_tol
        self.rbf_per_dim = rbf_per_dim
        self.rbf_sigma = rbf_sigma
        self.reward_fn = reward_fn
        self.reward_head_kwargs = dict(reward_head_kwargs or {})
        self.source_transitions = source_transitions
        self.source_seed = source_seed
        self.log_picture_every = log_picture_every
        self._source_loaded = False
        self.reward_heads = {}
        self.policy_updates = {}
        # Refits waiting for the next training round, and each task's uncertainty as of its last refit.
        self._due_tasks: set[int] = set()
        self._uncertainty_at_refit: dict[int, UncertaintyFn] = {}
        self._check_arguments()
        if _init_setup_model:
            self._setup_model()

    def _check_arguments(self) -> None:
        """Reject bad settings at construction, naming the argument."""
        # load() builds the model without an env first: the spaces are checked once they are known.
        action_space = getattr(self, "action_space", None)
        if action_space is not None and not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"TRLSD needs a Discrete action space (env), got {action_space}")
        observation_space = getattr(self, "observation_space", None)
        if observation_space is not None:
            state_space_of(observation_space)
        if not isinstance(self.reward_head, RewardHead) and self.reward_head not in REWARD_HEAD_NAMES:
            raise ValueError(
                f"reward_head must be one of {sorted(REWARD_HEAD_NAMES)} or a RewardHead instance, "
                f"got {self.reward_head!r}"
            )
        if self.kappa < 0:
            raise ValueError(f"kappa must be >= 0 (0 is the non-optimistic method), got {self.kappa}")
        if self.sigma <= 0:
            raise ValueError(f"sigma must be > 0, got {self.sigma}")
        if self.similarity not in ("state", "features"):
            raise ValueError(f"similarity must be 'state' or 'features', got {self.similarity!r}")
        if self.update_ratio <= 1:
            raise ValueError(
                f"update_ratio must be > 1 (the CI must shrink to trigger a refit), got {self.update_ratio}"
            )
        if not 0 < self.gamma < 1:
            raise ValueError(f"gamma must be in (0, 1), got {self.gamma}")
        if self.fqi_max_iterations is not None and self.fqi_max_iterations < 1:
            raise ValueError(f"fqi_max_iterations must be >= 1 or None, got {self.fqi_max_iterations}")
        source = self.source_transitions
        if isinstance(source, bool) or not (
            source is None
            or isinstance(source, (str, os.PathLike))
            or (isinstance(source, int) and source >= 1)
        ):
            raise ValueError(
                f"source_transitions must be None, a number >= 1 or the path of a .npz, got {source!r}"
            )
        if not isinstance(self.log_picture_every, int) or self.log_picture_every < 0:
            raise ValueError(f"log_picture_every must be an integer >= 0, got {self.log_picture_every!r}")

    def _setup_model(self) -> None:
        if self.replay_buffer_class is None:
            self.replay_buffer_class = SharedDynamicsReplayBuffer
        if not issubclass(self.replay_buffer_class, SharedDynamicsReplayBuffer):
            raise ValueError(
                "replay_buffer_class must be a SharedDynamicsReplayBuffer subclass, "
                f"got {self.replay_buffer_class}"
            )
        if issubclass(self.policy_class, LinearPolicy):
            self.policy_kwargs.setdefault("rbf_per_dim", self.rbf_per_dim)
            self.policy_kwargs.setdefault("rbf_sigma", self.rbf_sigma)
        super()._setup_model()
        self.features = RBFGrid.for_box(
            state_space_of(self.observation_space), self.rbf_per_dim, self.rbf_sigma
        )
        self._online_trail = {}

    def _excluded_save_params(self) -> list[str]:
        # Rebuilt by _setup_model.
        return [*super()._excluded_save_params(), "features", "_online_trail"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy"], []

    # ------------------------------------------------------------- reward heads
    def reward_head_of(self, task: int) -> RewardHead:
        """The reward head of ``task``, created (with no samples) the first time it is asked for."""
        task = int(task)
        if task not in self.reward_heads:
            self.reward_heads[task] = self._new_reward_head(task)
        return self.reward_heads[task]

    def _new_reward_head(self, task: int) -> RewardHead:
        if isinstance(self.reward_head, RewardHead):
            return copy.deepcopy(self.reward_head)
        reward_fn = None
        if self.reward_head == "known":
            base_fn = self.reward_fn
            if base_fn is None:
                assert self.env is not None, (
                    "the 'known' reward head needs reward_fn or an env with expected_reward"
                )
                base_fn = self.env.get_attr("expected_reward", indices=0)[0]
            reward_fn = partial(base_fn, task=task)
        return make_reward_head(
            self.reward_head,
            features=self.features,
            kappa=self.kappa,
            sigma=self.sigma,
            similarity=self.similarity,
            reward_fn=reward_fn,
            **self.reward_head_kwargs,
        )

    # --------------------------------------------------------------- transitions
    def load_transitions(self, data: Transitions | str | os.PathLike, keep_rewards: bool = False) -> None:
        """
        Add transitions collected elsewhere to the shared buffer (the paper's source set Xi).

        :param data: transitions (see ``collect_transitions``) or the path of a ``.npz`` saved from them
        :param keep_rewards: also fit each task's reward head on the rewards of its transitions; False
            (the paper's setting) uses them for the dynamics only
        """
        transitions = data if isinstance(data, Transitions) else Transitions.load(data)
        n_tasks = self.policy.n_tasks
        if transitions.tasks.min(initial=0) < 0 or transitions.tasks.max(initial=0) >= n_tasks:
            raise ValueError(f"transitions have tasks outside the env's 0..{n_tasks - 1}")
        self.replay_buffer.add_transitions(transitions, keep_rewards=keep_rewards)
        if keep_rewards:
            for task in np.unique(transitions.tasks):
                rows = transitions.tasks == task
                self.reward_head_of(task).update(transitions.states[rows], transitions.rewards[rows])
        # New dynamics data: every fitted task is refitted at the next training round.
        self._due_tasks.update(int(task) for task in np.flatnonzero(self.policy.fitted.cpu().numpy()))

    def _load_source_transitions(self) -> None:
        """Load the ``source_transitions`` of the constructor into the shared buffer, once."""
        if self.source_transitions is None or self._source_loaded:
            return
        if isinstance(self.source_transitions, int):
            assert self.env is not None, "source_transitions needs an env"
            spec = self.env.get_attr("spec", indices=0)[0]
            if spec is None:
                raise ValueError(
                    "source_transitions=<number> collects them from a copy of the env made with gym.make, "
                    "but this env has no spec: pass the path of a saved .npz instead"
                )
            # The spec without the wrappers added after gym.make (SB3's Monitor cannot be recreated).
            source_env = gym.make(dataclasses.replace(spec, additional_wrappers=()))
            seed = self.source_seed if self.source_seed is not None else self.seed
            data = collect_transitions(source_env, self.source_transitions, seed=seed)
            source_env.close()
        else:
            data = Transitions.load(self.source_transitions)
        self.load_transitions(data, keep_rewards=False)
        self._source_loaded = True

    # ------------------------------------------------------------ online loop
    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # A task's Q is fitted at its first step, before the policy acts on it.
        if self.num_timesteps >= learning_starts and self._last_obs is not None:
            tasks = self._last_obs["task"] if isinstance(self._last_obs, dict) else [0]
            for task in np.unique(tasks):
                if not self.policy.fitted[task]:
                    self.update_policy(int(task))
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def _on_step(self) -> None:
        """Feed the transition just stored to its task's reward head and check the refit trigger."""
        buffer = self.replay_buffer
        row = (buffer.pos - 1) % buffer.buffer_size
        for state, reward, task, done in zip(
            buffer.observations[row], buffer.rewards[row], buffer.tasks[row], buffer.dones[row], strict=True
        ):
            self._observe_reward(state, reward, int(task))
            trail = self._online_trail.setdefault(int(task), deque(maxlen=PICTURE_TRAIL))
            trail.append(np.asarray(state, dtype=np.float64))
            if done:
                trail.append(np.full(np.shape(state), np.nan))  # the blue line breaks at resets

    def _observe_reward(self, state: np.ndarray, reward: float, task: int) -> None:
        """Update the reward head of ``task`` with one online sample and mark the task due if it triggers."""
        state = np.asarray(state, dtype=np.float64).reshape(1, -1)
        head = self.reward_head_of(task)
        head.update(state, np.array([reward], dtype=np.float64))
        uncertainty_at_refit = self._uncertainty_at_refit.get(task)
        if uncertainty_at_refit is not None:
            # Section 3: refit once the CI at an encountered state has been divided by update_ratio.
            # The ratio is taken on the kappa-free uncertainty, so that kappa = 0 triggers the same way.
            then, now = uncertainty_at_refit(state)[0], head.uncertainty(state)[0]
            if then > 0 and then >= self.update_ratio * now:
                self._due_tasks.add(task)
        if getattr(self, "_logger", None) is not None:
            self.logger.record("reward/target_samples", head.n_samples)

    def act(self, obs: dict[str, np.ndarray] | np.ndarray) -> int:
        """
        The action ``learn`` takes from one observation: the task's Q is fitted first if it never was, then
        the greedy action. With ``add_online_transition``, it drives TRLSD from a loop of one's own (the
        experiments' fast path) with the same result as ``learn``, without SB3's rollout machinery.

        :param obs: one observation of the env (not batched)
        :return: the action
        """
        state, task = (obs["state"], int(obs["task"])) if isinstance(obs, dict) else (obs, 0)
        if not self.policy.fitted[task]:
            self.update_policy(task)
        return int(self.policy.q_values(np.asarray(state)[None], task)[0].argmax())

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
        (with the precision SB3 stores it), feed it to its task's reward head, and refit the tasks whose
        trigger fired. See ``act``.

        :param obs: observation before the step (not batched)
        :param action: action taken
        :param reward: reward received
        :param next_obs: observation after the step (before any reset)
        :param terminated: the step reached an absorbing state
        :param truncated: the trajectory was cut (no absorbing state: FQI bootstraps through it)
        """
        batched = (
            {key: np.asarray(value)[None] for key, value in obs.items()}
            if isinstance(obs, dict)
            else obs[None]
        )
        next_batched = (
            {key: np.asarray(value)[None] for key, value in next_obs.items()}
            if isinstance(next_obs, dict)
            else next_obs[None]
        )
        self.replay_buffer.add(
            batched,
            next_batched,
            np.array([[action]]),
            np.array([reward]),
            np.array([terminated or truncated]),
            [{"TimeLimit.truncated": truncated and not terminated}],
        )
        self.num_timesteps += 1
        self._on_step()
        self.train(gradient_steps=1, batch_size=0)

    def train(self, gradient_steps: int, batch_size: int) -> None:
        """Refit the Q-function of every task whose trigger fired since the last round."""
        for task in sorted(self._due_tasks):
            self.update_policy(task)
        self._due_tasks.clear()

    def update_policy(self, task: int) -> None:
        """
        Recompute the policy of ``task`` now: relabel the whole shared buffer with the task's reward proxy R~
        (Algorithm 1, psi) and fit its Q-function on it by Fitted-Q Iteration. ``learn`` calls this at a
        task's first step and whenever its refit trigger fires; call it directly to learn offline from
        transitions loaded with ``keep_rewards=True`` (or with the ``"known"`` reward head).

        :param task: the task index
        """
        task = int(task)
        if not 0 <= task < self.policy.n_tasks:
            raise ValueError(f"task must be in 0..{self.policy.n_tasks - 1}, got {task}")
        head = self.reward_head_of(task)
        transitions = self.replay_buffer.relabelled(task, head)
        stats = self.policy.fit(task, transitions, self.gamma, self.fqi_max_iterations, self.fqi_tol)
        self._uncertainty_at_refit[task] = head.frozen_uncertainty()
        self.policy_updates[task] = self.policy_updates.get(task, 0) + 1
        self._n_updates += 1
        if getattr(self, "_logger", None) is None:
            return  # called outside learn(): no logger configured yet
        self.logger.record("train/policy_updates", sum(self.policy_updates.values()))
        self.logger.record("train/fqi_iterations", stats.iterations)
        self.logger.record("train/bellman_residual", stats.bellman_residual)
        if len(transitions):
            # The optimism actually applied: mean of R~ - R^ over the relabelled set.
            optimism = transitions.rewards - head.estimate(transitions.states)
            self.logger.record("reward/ci_mean", float(np.mean(optimism)))
        if self._picture_due(task):
            trail = np.array(self._online_trail.get(task, ()), dtype=np.float64).reshape(-1, 2)
            self.logger.record(
                f"pictures/task_{task}",
                Image(task_picture(self, task, trail), "HWC"),
                exclude=("stdout", "log", "json", "csv"),
            )

    def _picture_due(self, task: int) -> bool:
        """A picture at a task's first refit, then every ``log_picture_every`` (TensorBoard on the maze)."""
        updates = self.policy_updates[task]
        if not self.log_picture_every or (updates != 1 and updates % self.log_picture_every):
            return False
        if not any(isinstance(output, TensorBoardOutputFormat) for output in self.logger.output_formats):
            return False
        return self.env is not None and self.env.has_attr("walls") and self.features.centres.shape[1] == 2

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
        self.logger.record(
            "hparams",
            HParam(self.hyperparameters(), {"rollout/ep_rew_mean": 0.0, "train/policy_updates": 0.0}),
            exclude=("stdout", "log", "json", "csv"),
        )
        return total_timesteps, callback

    def hyperparameters(self) -> dict[str, int | float | str | bool]:
        """The settings of this run, as TensorBoard's HParams tab shows them."""
        settings = {
            "algorithm": type(self).__name__,
            "policy": self.policy_class.__name__,
            "gamma": self.gamma,
            "reward_head": self.reward_head
            if isinstance(self.reward_head, str)
            else type(self.reward_head).__name__,
            "kappa": self.kappa,
            "sigma": self.sigma,
            "similarity": self.similarity,
            "update_ratio": self.update_ratio,
            "fqi_max_iterations": self.fqi_max_iterations,
            "fqi_tol": self.fqi_tol,
            "rbf_per_dim": self.rbf_per_dim,
            "rbf_sigma": self.rbf_sigma,
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
        self._load_source_transitions()
        super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
        # SB3 dumps the logs every log_interval episodes: a run's last values (and pictures) are kept too.
        self.dump_logs()
        return self
