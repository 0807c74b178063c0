"""Task-conditioned greedy Q policies: one Q-function per task, chosen by ``obs["task"]``.

``LinearPolicy`` is the paper's: Q_tau(s, a) = theta_tau,a . Phi(s) on Gaussian RBF features (eq. 3, 11),
fitted in closed form by Fitted-Q Iteration. ``MlpPolicy`` swaps the linear map for a small network per
task, fitted by fitted iterations. Both act greedily: the exploration comes from the optimistic rewards
they are fitted on, not from the policy.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule

from sb3_trlsd.arrays import GrowableArray
from sb3_trlsd.buffers import state_space_of
from sb3_trlsd.data import Transitions
from sb3_trlsd.features import RBFGrid
from sb3_trlsd.fqi import LinearFQISolver, fit_mlp_fqi, linear_q_values, make_q_network

__all__ = ["FitStats", "LinearPolicy", "MlpPolicy", "TaskQPolicy"]


@dataclass(frozen=True)
class FitStats:
    """What one Fitted-Q Iteration refit of a task's Q-function did."""

    iterations: int
    bellman_residual: float


class TaskQPolicy(BasePolicy):
    """
    Base of the task-conditioned greedy Q policies.

    :param observation_space: a Box of states (one task) or a ``{"state": Box, "task": Discrete}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: learning-rate schedule (used by the MLP's regression steps only)
    """

    default_max_iterations: int  # fitted iterations of a refit when TRLSD's fqi_max_iterations is None

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, lr_schedule: Schedule):
        super().__init__(observation_space, action_space)
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"action_space must be Discrete, got {action_space}")
        self.state_space = state_space_of(observation_space)
        self.n_actions = int(action_space.n)
        task_space = observation_space["task"] if isinstance(observation_space, spaces.Dict) else None
        self.n_tasks = int(task_space.n) if task_space is not None else 1
        self.lr_schedule = lr_schedule
        # Which tasks have had their Q fitted at least once; a buffer so that it is saved with the weights.
        self.register_buffer("fitted", th.zeros(self.n_tasks, dtype=th.bool))

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "lr_schedule": self.lr_schedule}

    def split_observation(self, observation: PyTorchObs) -> tuple[np.ndarray, np.ndarray]:
        """States (n, d) as float64 and tasks (n,) of a batched observation tensor."""
        if isinstance(observation, dict):
            states = observation["state"]
            tasks = observation["task"].cpu().numpy().reshape(-1).astype(np.int64)
        else:
            assert isinstance(observation, th.Tensor)
            states = observation
            tasks = np.zeros(len(observation), dtype=np.int64)
        return states.cpu().numpy().reshape(len(tasks), -1).astype(np.float64), tasks

    def q_values(self, states: np.ndarray, tasks: np.ndarray | int) -> np.ndarray:
        """
        Q_tau(s, .) for a batch of states, each with its task.

        :param states: (n, d)
        :param tasks: (n,) task indices, or one task for all states
        :return: (n, n_actions)
        """
        states = np.asarray(states, dtype=np.float64).reshape(-1, self.state_space.shape[0])
        tasks = np.broadcast_to(np.asarray(tasks, dtype=np.int64), (len(states),))
        if tasks.size and (tasks.min() < 0 or tasks.max() >= self.n_tasks):
            raise ValueError(f"tasks must be in 0..{self.n_tasks - 1}, got {np.unique(tasks)}")
        q = np.zeros((len(states), self.n_actions))
        for task in np.unique(tasks):
            rows = tasks == task
            q[rows] = self._task_q_values(states[rows], int(task))
        return q

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        states, tasks = self.split_observation(observation)
        # Greedy whatever `deterministic` says: optimism, not dithering, drives the exploration.
        return th.as_tensor(self.q_values(states, tasks).argmax(axis=1), device=self.device)

    def fit(
        self,
        task: int,
        transitions: Transitions,
        gamma: float,
        max_iterations: int | None = None,
        tol: float = 1e-4,
    ) -> FitStats:
        """
        Fit Q_task on transitions whose rewards are already those of ``task`` (see
        ``SharedDynamicsReplayBuffer.relabelled``), warm-started from its current parameters.

        :param task: the task whose Q-function is refitted
        :param transitions: the relabelled transition set
        :param gamma: discount factor
        :param max_iterations: cap on the fitted iterations (None: ``default_max_iterations``)
        :param tol: relative stopping tolerance of the linear solver (the MLP runs all its iterations)
        :return: iterations and final Bellman residual
        """
        iterations = self.default_max_iterations if max_iterations is None else max_iterations
        stats = self._fit(task, transitions, gamma, iterations, tol)
        self.fitted[task] = True
        return stats

    @abstractmethod
    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray: ...

    @abstractmethod
    def _fit(
        self, task: int, transitions: Transitions, gamma: float, max_iterations: int, tol: float
    ) -> FitStats: ...


class LinearPolicy(TaskQPolicy):
    """
    Linear Q on Gaussian RBF features: Q_tau(s, a) = theta[tau, a] . Phi(s) (eq. 3, 11).

    :param observation_space: a Box of states or a ``{"state", "task"}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: unused (the fit is in closed form), kept for SB3's policy signature
    :param rbf_per_dim: RBF centres per state dimension, at the centres of a regular grid over the state Box
        (5 on the maze: the paper's 5x5 centres at (i - 0.5, j - 0.5))
    :param rbf_sigma: width of the RBFs (eq. 11: 0.2)
    :param fqi_ridge: Tikhonov regularisation of each per-action least-squares projection of eq. 4, which
        keeps it well posed where an RBF has (almost) no samples
    :param fqi_dtype: precision of the features the Fitted-Q iterations read, ``"float32"`` (default: half
        the memory to stream per iteration, ~1e-6 relative rounding in theta) or ``"float64"``; theta stays
        float64
    """

    # Cold fits take ~130 iterations to reach the default tolerance with gamma = 0.9; warm ones far fewer.
    default_max_iterations = 500

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        rbf_per_dim: int = 5,
        rbf_sigma: float = 0.2,
        fqi_ridge: float = 1e-3,
        fqi_dtype: str = "float32",
    ):
        super().__init__(observation_space, action_space, lr_schedule)
        if not np.all(np.isfinite(self.state_space.low)) or not np.all(np.isfinite(self.state_space.high)):
            raise ValueError(
                "LinearPolicy places its RBF grid over the state Box, whose bounds must be finite"
            )
        self.rbf_per_dim = rbf_per_dim
        self.rbf_sigma = rbf_sigma
        self.fqi_ridge = fqi_ridge
        self.fqi_dtype = fqi_dtype
        self.features = RBFGrid.for_box(self.state_space, n_per_dim=rbf_per_dim, sigma=rbf_sigma)
        # The relabelled set only grows between refits (and is the same for every task): one solver keeps
        # the features and per-action Gram factorisations of the rows it has seen, and ``_held`` those rows
        # (s, a, s', terminated) to recognise them.
        self._solver = LinearFQISolver(
            self.features.n_features, self.n_actions, ridge=fqi_ridge, dtype=fqi_dtype
        )
        self._held = GrowableArray(2 * self.state_space.shape[0] + 2)
        self.register_buffer(
            "theta", th.zeros(self.n_tasks, self.n_actions, self.features.n_features, dtype=th.float64)
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            rbf_per_dim=self.rbf_per_dim,
            rbf_sigma=self.rbf_sigma,
            fqi_ridge=self.fqi_ridge,
            fqi_dtype=self.fqi_dtype,
        )
        return data

    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray:
        return linear_q_values(self.features(states), self.theta[task].cpu().numpy())

    def solver_for(self, transitions: Transitions) -> LinearFQISolver:
        """
        The FQI solver holding exactly these transitions, extended with their new rows when they extend
        the rows it holds (a replay buffer that has not wrapped around), rebuilt otherwise.

        :param transitions: the relabelled transition set (its rewards are not used here)
        :return: the solver, whose ``fit`` takes the rewards of these transitions in their order
        """
        rows = np.column_stack(
            [transitions.states, transitions.actions, transitions.next_states, transitions.terminations]
        ).astype(np.float64)
        held = len(self._held)
        if len(rows) < held or not np.array_equal(rows[:held], self._held.view()):
            self._solver = LinearFQISolver(
                self.features.n_features, self.n_actions, ridge=self.fqi_ridge, dtype=self.fqi_dtype
            )
            self._held, held = GrowableArray(rows.shape[1]), 0
        if len(rows) > held:
            self._solver.extend(
                self.features(transitions.states[held:]),
                transitions.actions[held:],
                self.features(transitions.next_states[held:]),
                transitions.terminations[held:],
            )
            self._held.append(rows[held:])
        return self._solver

    def _fit(
        self, task: int, transitions: Transitions, gamma: float, max_iterations: int, tol: float
    ) -> FitStats:
        result = self.solver_for(transitions).fit(
            transitions.rewards,
            gamma=gamma,
            theta0=self.theta[task].cpu().numpy(),
            max_iterations=max_iterations,
            tol=tol,
        )
        self.theta[task] = th.as_tensor(result.theta, device=self.theta.device)
        return FitStats(result.iterations, result.bellman_residual)


class MlpPolicy(TaskQPolicy):
    """
    A small network Q_tau(s, .) per task, one output per action, on states rescaled to [-1, 1].

    :param observation_space: a Box of states (finite bounds) or a ``{"state", "task"}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: Adam learning rate of the regression steps
    :param net_arch: hidden layer sizes
    :param epochs_per_iteration: regression epochs on the targets of each fitted iteration
    :param batch_size: minibatch size of the regression
    """

    # Each fitted iteration is a few epochs of regression, so a refit runs a bounded number of them.
    default_max_iterations = 20

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: tuple[int, ...] | list[int] = (64, 64),
        epochs_per_iteration: int = 2,
        batch_size: int = 512,
    ):
        super().__init__(observation_space, action_space, lr_schedule)
        self.net_arch = tuple(net_arch)
        self.epochs_per_iteration = epochs_per_iteration
        self.batch_size = batch_size
        low, high = self.state_space.low.astype(np.float64), self.state_space.high.astype(np.float64)
        if not np.all(np.isfinite(low)) or not np.all(np.isfinite(high)):
            raise ValueError("MlpPolicy rescales states by the state Box, whose bounds must be finite")
        self.state_centre, self.state_half_width = (high + low) / 2, (high - low) / 2
        self.q_networks = th.nn.ModuleList(
            make_q_network(self.state_space.shape[0], self.n_actions, hidden=self.net_arch)
            for _ in range(self.n_tasks)
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            epochs_per_iteration=self.epochs_per_iteration,
            batch_size=self.batch_size,
        )
        return data

    def _inputs(self, states: np.ndarray) -> np.ndarray:
        return (states - self.state_centre) / self.state_half_width

    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray:
        inputs = th.as_tensor(self._inputs(states), dtype=th.float32, device=self.device)
        with th.no_grad():
            return self.q_networks[task](inputs).cpu().numpy().astype(np.float64)

    def _fit(
        self, task: int, transitions: Transitions, gamma: float, max_iterations: int, tol: float
    ) -> FitStats:
        result = fit_mlp_fqi(
            self._inputs(transitions.states),
            transitions.actions,
            transitions.rewards,
            self._inputs(transitions.next_states),
            transitions.terminations,
            network=self.q_networks[task],
            gamma=gamma,
            iterations=max_iterations,
            epochs_per_iteration=self.epochs_per_iteration,
            batch_size=self.batch_size,
            learning_rate=self.lr_schedule(1.0),
        )
        return FitStats(result.iterations, result.bellman_residual)
