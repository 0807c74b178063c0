"""TRLSD's relabelling as a replay buffer that any SB3 off-policy algorithm with Discrete actions can take.

Section 2 of the paper: a transition xi_tau' = <tau', s, a, r, s'> of any task serves a target task tau once
its reward is replaced by the target's optimistic proxy, psi(xi_tau') = <tau, s, a, R~_tau(s), s'>, with
R~_tau = R^_tau + CI_tau learnt from tau's own samples (eq. 5-10). ``RelabellingReplayBuffer`` applies psi
at sample time, the way SB3's ``HerReplayBuffer`` replaces goals: DQN, QR-DQN or any other learner that
samples minibatches then fits its own Q-function on the relabelled rows instead of TRLSD's FQI.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Protocol

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import DictReplayBufferSamples, ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.config import TRLSDConfig
from sb3_trlsd.data import Transitions
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.observations import split_observation
from sb3_trlsd.reward_heads import RewardFn, RewardHead
from sb3_trlsd.task_learner import TaskLearner

__all__ = ["RelabellingReplayBuffer", "dqn_q_values"]


class RelabellingReplayBuffer(SharedDynamicsReplayBuffer):
    """
    Replay buffer of online transitions and of source transitions whose rewards are unknown, the latter
    relabelled at sample time with a reward head learnt from the online rewards (Laroche & Barlier,
    "Transfer Reinforcement Learning with Shared Dynamics", AAAI 2017, section 2 and eq. 5-10).

    Each task of the observations has a reward head (``"ridge"``: eq. 8-9 on the feature map Phi;
    ``"tabular"``: eq. 10 on a grid of cells), which learns from every online transition of its task as
    ``add`` stores it: the reward observed for the transition, at what of it the reward belongs to
    (``reward_timing``: the whole step (s, a, s') by default, the next state, the start state s of the paper's
    R_tau(s), or the pair (s, s')).
    A sampled source row is served to one of the tasks seen online (drawn uniformly when there are several:
    its observation's ``"task"`` becomes that task) with the reward R~_tau = R^_tau + CI_tau of that task's
    head as it is now (``kappa=0``: the plain estimate R^). Online rows keep their observed reward by default,
    as HER keeps its real transitions: the head only stands in for rewards nobody observed.
    ``relabel_online_rows=True`` relabels them with their own task's head, as TRLSD's FQI sees its whole
    buffer.

    Rows live in one ring of ``buffer_size`` rows, source and online alike (as in any SB3 buffer, the
    oldest go first once it is full): give it room for the source rows and the online budget. The heads
    keep what they learnt when rows leave the ring. Observations are a state Box (a single task, task 0)
    or a ``{"state": Box, "task": Discrete}`` Dict; the state Box must be bounded, or ``state_bounds``
    given, because features and similarity widths are fractions of the state box (as in ``TRLSD``).

    Defaults: the ridge head with kappa = 0 (the estimate R^ alone; the learner's own exploration explores),
    the feature map and similarity widths from the state box, as ``TRLSD``'s. With ``kappa > 0`` the bonus far
    from any online sample is large (up to kappa * sqrt(log|Xi_tau| / w_floor), see ``reward_heads.base``): a
    deep Q-learner fits such targets slowly, so cap R~ at a known bound of the reward with
    ``reward_head_kwargs={"r_max": ...}``. The relabelled rows are many (the paper's 25,000 source rows): DQN
    gains from more gradient steps per env step and more frequent target updates than for its own few rows
    (``benchmarks/bench_relabelling_dqn.py``).

    Usage, with DQN on the maze (QR-DQN and the other off-policy algorithms take it the same way)::

        import gymnasium as gym
        from stable_baselines3 import DQN
        from sb3_trlsd import RelabellingReplayBuffer, collect_transitions

        source = collect_transitions(gym.make("TRLSD/SharedDynamicsMaze-v0", task=(3, 3)), 25_000, seed=0)
        model = DQN(
            "MultiInputPolicy",
            gym.make("TRLSD/SharedDynamicsMaze-v0", task=(1, 1)),
            buffer_size=50_000,  # the source rows and every online one
            gradient_steps=4,
            target_update_interval=100,
            replay_buffer_class=RelabellingReplayBuffer,
            replay_buffer_kwargs={  # the maze pays for the state a step starts from
                "reward_head": "tabular",
                "reward_head_kwargs": {"r_max": 1.0},
                "reward_timing": "start_state",
            },
            seed=0,
        )
        model.replay_buffer.load_transitions(source)  # their rewards are discarded
        model.learn(total_timesteps=1_500)
        model.save_replay_buffer("buffer.pkl")  # the rows and the heads
        model.load_replay_buffer("buffer.pkl")

    :param buffer_size: Max number of transitions, source and online
    :param observation_space: the env's observation space (Box, or Dict with ``state`` and ``task``)
    :param action_space: the env's (Discrete) action space
    :param device: PyTorch device for sampled batches
    :param n_envs: number of parallel environments, whose steps are stored as consecutive rows
    :param optimize_memory_usage: not supported (next states are kept apart), must be False
    :param handle_timeout_termination: keep truncations apart from terminations so that learners
        bootstrap through them
    :param reward_head: any of ``TRLSD``'s: ``"ridge"`` (eq. 9), ``"tabular"`` (eq. 10 on a grid over the
        state box, or a ``cell_fn`` in ``reward_head_kwargs``), ``"corners"`` (only the grid's corner cells
        pay), ``"known"`` (``reward_fn``: the source rows get the known reward), ``"ridge_posterior"``,
        ``"thompson"``, ``"bernstein"``; or a ``RewardHead`` copied for each task (then ``kappa``, ``sigma``,
        ``similarity`` and the feature map arguments are not used)
    :param kappa: optimism (eq. 9, 10); 0 relabels with the estimate R^ alone (None: the head's, 0 for
        every head but ``"thompson"``, whose posterior scale is 0.01 of the largest reward seen)
    :param sigma: width of the ridge head's similarity (eq. 8): for eq. 6 a fraction of the state box (None:
        ``default_kernel_width(d)``, 0.04 in 2-D, the paper's 0.2 on the maze); for eq. 7 a distance between
        feature vectors (None: 0.2)
    :param similarity: ``"state"`` (eq. 6) or ``"features"`` (eq. 7)
    :param feature_map: Phi of the feature heads: a name of ``FEATURE_MAPS`` (``"auto"``, ``"lattice"``,
        ``"rbf"``, ...: see ``TRLSD``) or a ``FeatureMap``
    :param rbf_per_dim: RBF centres per state dimension of the grid (see ``TRLSD``)
    :param rbf_sigma: width of the features, a fraction of the state box (see ``TRLSD``)
    :param rbf_overlap: width of the RBFs in spacings of their centres (see ``TRLSD``)
    :param max_features: the feature map's budget (see ``TRLSD``)
    :param fourier_features: the number of Fourier features (see ``TRLSD``)
    :param state_bounds: ``(low, high)`` of the states for an unbounded Box (None: the Box's, finite)
    :param reward_head_kwargs: further arguments of the heads (``r_max``, ``w_floor``, ``ridge``; ``cell_fn``,
        ``n_cells``, ``cells_per_dim`` for the tabular ones)
    :param reward_fn: ``reward_fn(states, task) -> (n,)``, the expected reward of the ``"known"`` head
    :param seed: seed of the Fourier features and of the ``"thompson"`` heads' draws
    :param reward_timing: what of a transition its reward belongs to, which the heads learn and relabel
        at: ``"step"`` ((s, a, s'), Gymnasium's r(s, a, s')), ``"next_state"`` (the state it arrives at),
        ``"start_state"`` (the paper's R_tau(s), and this package's envs') or ``"transition"`` (the pair
        (s, s')); ``"auto"`` (a buffer sees no env) is ``"step"`` for the heads that can learn it and
        ``"next_state"`` for the others, as ``TRLSD``'s on an env that declares nothing
    :param relabel_online_rows: relabel the online rows too (False: they keep their observed reward)
    """

    learners: list[TaskLearner]
    features: FeatureMap | None

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        reward_head: str | RewardHead = "ridge",
        kappa: float | None = None,
        sigma: float | Sequence[float] | None = None,
        similarity: str = "state",
        feature_map: str | FeatureMap = "auto",
        rbf_per_dim: int | Sequence[int] | str | None = None,
        rbf_sigma: float | Sequence[float] | None = None,
        rbf_overlap: float | None = None,
        max_features: int | None = None,
        fourier_features: int | None = None,
        state_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
        reward_head_kwargs: dict[str, Any] | None = None,
        reward_fn: RewardFn | None = None,
        seed: int | None = None,
        reward_timing: str = "auto",
        relabel_online_rows: bool = False,
    ):
        # TRLSD's settings of the relabelling, checked (and named) before anything is built.
        self.config = TRLSDConfig.of(locals())
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.dict_observations = isinstance(observation_space, spaces.Dict)
        self.relabel_online_rows = bool(relabel_online_rows)
        assert isinstance(action_space, spaces.Discrete)
        builder = self.config.builder(observation_space, int(action_space.n), linear_q=False, seed=seed)
        self.reward_timing = builder.reward_timing
        self.features = builder.features
        # One learner per task: its head learns the task's online rewards and relabels the rows served to it.
        self.learners = [builder.new_task_learner(task, reward_fn=reward_fn) for task in range(self.n_tasks)]

    @property
    def reward_heads(self) -> list[RewardHead]:
        """Each task's reward head, learnt from the task's online rewards."""
        return [learner.head for learner in self.learners]

    # ----------------------------------------------------------------- storing
    def add(
        self,
        obs: np.ndarray | dict[str, np.ndarray],
        next_obs: np.ndarray | dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of the envs (validated first), and teach each task's head its rewards."""
        super().add(obs, next_obs, action, reward, done, infos)
        states, tasks = split_observation(obs, self.obs_shape[0])
        next_states, _ = split_observation(next_obs, self.obs_shape[0])
        actions, rewards = np.asarray(action).reshape(-1), np.asarray(reward, dtype=np.float64).reshape(-1)
        for task in np.unique(tasks):
            rows = tasks == task
            self.learners[task].learn(states[rows], actions[rows], next_states[rows], rewards[rows])

    def load_transitions(self, transitions: Transitions) -> None:
        """
        Add source transitions, of any tasks sharing the env's dynamics, their rewards discarded (the paper's
        setting): they are relabelled whenever they are sampled. With Box observations (one task) their
        tasks are not kept either: every row is task 0's.

        :param transitions: e.g. from ``collect_transitions`` on other tasks
        :raises ValueError: if they would overwrite stored rows (``buffer_size`` too small), or do not fit
            the env (state dimension, actions, tasks of a Dict observation)
        """
        if self.size() + len(transitions) > self.buffer_size:
            raise ValueError(
                f"{len(transitions)} source transitions do not fit next to the {self.size()} stored rows of "
                f"a buffer of size {self.buffer_size}: give the algorithm a larger buffer_size"
            )
        if not self.dict_observations:
            transitions = replace(transitions, tasks=np.zeros_like(transitions.tasks))
        self.add_transitions(transitions, keep_rewards=False)

    # ----------------------------------------------------------------- sampling
    def online_tasks(self) -> np.ndarray:
        """The tasks whose head has learnt from online rewards: those a source row may be served to, (m,)."""
        return np.array(
            [task for task, learner in enumerate(self.learners) if learner.head.n_samples > 0], dtype=int
        )

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> ReplayBufferSamples | DictReplayBufferSamples:
        # As SB3's buffers, draw from numpy's global generator: the one set_random_seed seeds.
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))  # noqa: NPY002
        states = self.observations[batch_inds, env_indices]  # (B, d)
        next_states = self.next_observations[batch_inds, env_indices]  # (B, d)
        tasks = self.tasks[batch_inds, env_indices].copy()  # (B,)
        rewards = self.rewards[batch_inds, env_indices].copy()  # (B,), float32
        source = ~self.has_reward[batch_inds, env_indices]  # (B,)
        actions = self.actions[batch_inds, env_indices]  # (B, 1)
        if source.any():
            targets = self.online_tasks()
            if not len(targets):
                raise RuntimeError(
                    "a source transition was sampled before any online one: its reward is relabelled for the "
                    "tasks seen online, so add an online transition first (learning_starts >= 1)"
                )
            drawn = np.random.randint(len(targets), size=int(source.sum()))  # noqa: NPY002
            tasks[source] = targets[drawn]  # psi: <tau', s, a, ?, s'> -> <tau, s, a, R~_tau(s), s'>
        relabelled = np.ones_like(source) if self.relabel_online_rows else source
        for task in np.unique(tasks[relabelled]):
            rows = relabelled & (tasks == task)
            # psi, eq. 5: R~ = R^ + CI
            rewards[rows] = self.learners[task].relabel(states[rows], actions[rows, 0], next_states[rows])
        # Only terminations stop the bootstrap, not the resets after a truncation.
        dones = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        rewards_column = self.to_torch(self._normalize_reward(rewards.reshape(-1, 1), env))
        actions_column = self.to_torch(actions)
        if self.dict_observations:
            observations = self._normalize_obs({"state": states, "task": tasks[:, None]}, env)
            next_observations = self._normalize_obs({"state": next_states, "task": tasks[:, None]}, env)
            assert isinstance(observations, dict) and isinstance(next_observations, dict)
            return DictReplayBufferSamples(
                observations={key: self.to_torch(value) for key, value in observations.items()},
                actions=actions_column,
                next_observations={key: self.to_torch(value) for key, value in next_observations.items()},
                dones=self.to_torch(dones.reshape(-1, 1)),
                rewards=rewards_column,
            )
        observations_array = self._normalize_obs(states, env)
        next_observations_array = self._normalize_obs(next_states, env)
        assert isinstance(observations_array, np.ndarray) and isinstance(next_observations_array, np.ndarray)
        return ReplayBufferSamples(
            observations=self.to_torch(observations_array),
            actions=actions_column,
            next_observations=self.to_torch(next_observations_array),
            dones=self.to_torch(dones.reshape(-1, 1)),
            rewards=rewards_column,
        )


class QNetworkPolicy(Protocol):
    """A policy with a Q-network of one output per action (SB3's ``DQNPolicy``)."""

    @property
    def q_net(self) -> th.nn.Module: ...


class QNetworkModel(Protocol):
    """An SB3 model whose policy has a ``q_net`` (SB3's ``DQN``)."""

    @property
    def device(self) -> th.device: ...

    @property
    def policy(self) -> QNetworkPolicy: ...


def dqn_q_values(model: QNetworkModel) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """
    ``q_values(states, tasks)`` of a DQN (or any SB3 model whose policy has a ``q_net``) on a multi-task
    env's ``{"state", "task"}`` observations: the form ``greedy_expected_rewards`` and the experiments'
    evaluations take, so a DQN trained with a ``RelabellingReplayBuffer`` is scored as TRLSD is.

    :param model: a trained SB3 model with ``policy.q_net``
    :return: a function of ``(n, d)`` states and ``(n,)`` task indices giving their ``(n, n_actions)`` values
    """

    def q_values(states: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        observations = {
            "state": th.as_tensor(states, dtype=th.float32, device=model.device),
            "task": th.as_tensor(np.asarray(tasks)[:, None], device=model.device),
        }
        with th.no_grad():
            return model.policy.q_net(observations).cpu().numpy()

    return q_values
