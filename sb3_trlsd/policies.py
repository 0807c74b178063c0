"""Task-conditioned greedy Q policies: one Q-function per task, chosen by ``obs["task"]``.

``LinearPolicy`` is the paper's: Q_tau(s, a) = theta_tau,a . Phi(s) on the features Phi that TRLSD builds
once and shares with its reward heads (eq. 3, 11), fitted in closed form by Fitted-Q Iteration.
``MlpPolicy`` swaps the linear map for a small network per task, fitted by fitted iterations. Both act
greedily: the exploration comes from the optimistic rewards they are fitted on, not from the policy. A
policy holds Q-functions only: the transitions it is fitted on come as ``FitRows`` (``fit_rows.py``).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule

from sb3_trlsd.feature_maps import Features
from sb3_trlsd.fit_rows import FitRows, LinearFitRows, TransitionRows
from sb3_trlsd.fqi import (
    DEFAULT_LINEAR_ITERATIONS,
    DEFAULT_MLP_ITERATIONS,
    DEFAULT_RIDGE,
    DEFAULT_SOLVER,
    DEFAULT_STOP_RULE,
    DEFAULT_TOL,
    FQIResult,
    fit_mlp_fqi,
    linear_q_values,
    make_q_network,
)
from sb3_trlsd.observations import check_action_space, split_observation, state_space_of, task_count_of

__all__ = ["LinearPolicy", "MlpPolicy", "TaskQPolicy"]


class TaskQPolicy(BasePolicy):
    """
    Base of the task-conditioned greedy Q policies.

    :param observation_space: a Box of states (one task) or a ``{"state": Box, "task": Discrete}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: learning-rate schedule (used by the MLP's regression steps only)
    """

    default_max_iterations: int  # fitted iterations of a refit when TRLSD's fqi_max_iterations is None
    default_solver: str  # how a refit reaches Fitted-Q's fixed point when TRLSD's fqi_solver is None

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, lr_schedule: Schedule):
        super().__init__(observation_space, action_space)
        self.n_actions = check_action_space(action_space)
        self.state_space = state_space_of(observation_space)
        self.n_tasks = task_count_of(observation_space)
        self.lr_schedule = lr_schedule

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "lr_schedule": self.lr_schedule}

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
        states, tasks = split_observation(observation, self.state_space.shape[0])
        # Greedy whatever `deterministic` says: optimism, not dithering, drives the exploration.
        return th.as_tensor(self.q_values(states, tasks).argmax(axis=1), device=self.device)

    def fit(
        self,
        task: int,
        rows: FitRows,
        rewards: np.ndarray,
        gamma: float,
        max_iterations: int | None = None,
        tol: float = DEFAULT_TOL,
        stop_rule: str = DEFAULT_STOP_RULE,
        solver: str | None = None,
    ) -> FQIResult:
        """
        Fit Q_task on the rows with the rewards of ``task`` (R~_task at each row's start state, in the rows'
        order), warm-started from its current parameters.

        :param task: the task whose Q-function is refitted
        :param rows: the transitions, from ``new_fit_rows`` synced with the buffer
        :param rewards: the relabelled rewards, (rows.n_transitions,)
        :param gamma: discount factor
        :param max_iterations: cap on the fitted iterations (None: ``default_max_iterations``)
        :param tol: relative stopping tolerance of the fitted iterations
        :param stop_rule: their stopping rule, one of ``sb3_trlsd.fqi.STOP_RULES``
        :param solver: how the fixed point is reached, one of ``sb3_trlsd.fqi.SOLVERS`` (None:
            ``default_solver``)
        :return: iterations and final Bellman residual
        """
        iterations = self.default_max_iterations if max_iterations is None else max_iterations
        rewards = np.asarray(rewards, dtype=np.float64)
        solver = self.default_solver if solver is None else solver
        return self._fit(task, rows, rewards, gamma, iterations, tol, stop_rule, solver)

    @abstractmethod
    def new_fit_rows(self) -> FitRows:
        """An empty ``FitRows`` of the form this policy fits on."""

    @abstractmethod
    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray: ...

    @abstractmethod
    def _fit(
        self,
        task: int,
        rows: FitRows,
        rewards: np.ndarray,
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> FQIResult: ...


class LinearPolicy(TaskQPolicy):
    """
    Linear Q on features: Q_tau(s, a) = theta[tau, a] . Phi(s) (eq. 3, 11).

    :param observation_space: a Box of states or a ``{"state", "task"}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: unused (the fit is in closed form), kept for SB3's policy signature
    :param features: Phi, states (n, d) -> (n, k), with an ``n_features`` attribute: ``TRLSD`` passes the
        ``FeatureMap`` it shares with its reward heads (see ``TRLSD(feature_map=..., rbf_per_dim=...)``)
    :param fqi_ridge: Tikhonov regularisation of each per-action least-squares projection of eq. 4, which
        keeps it well posed where a feature has (almost) no samples
    :param fqi_dtype: precision of the features the Fitted-Q iterations read, ``"float32"`` (default: half
        the memory to stream per iteration, ~1e-6 relative rounding in theta) or ``"float64"``; theta stays
        float64
    """

    default_max_iterations = DEFAULT_LINEAR_ITERATIONS
    default_solver = DEFAULT_SOLVER
    theta: th.Tensor  # (n_tasks, n_actions, k) float64, a buffer: saved with the policy's state dict

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        features: Features | None = None,
        fqi_ridge: float = DEFAULT_RIDGE,
        fqi_dtype: str = "float32",
    ):
        super().__init__(observation_space, action_space, lr_schedule)
        if features is None or not isinstance(getattr(features, "n_features", None), int):
            raise ValueError(
                "LinearPolicy needs features (Phi with an n_features attribute, a FeatureMap); "
                "TRLSD builds them from its feature_map, rbf_per_dim and rbf_sigma"
            )
        self.features = features
        self.fqi_ridge = fqi_ridge
        self.fqi_dtype = fqi_dtype
        self.register_buffer(
            "theta", th.zeros(self.n_tasks, self.n_actions, features.n_features, dtype=th.float64)
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(features=self.features, fqi_ridge=self.fqi_ridge, fqi_dtype=self.fqi_dtype)
        return data

    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray:
        return linear_q_values(self.features(states), self.theta[task].cpu().numpy())

    def new_fit_rows(self) -> LinearFitRows:
        return LinearFitRows(
            self.features,
            self.features.n_features,
            self.n_actions,
            ridge=self.fqi_ridge,
            dtype=self.fqi_dtype,
        )

    def _fit(
        self,
        task: int,
        rows: FitRows,
        rewards: np.ndarray,
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> FQIResult:
        assert isinstance(rows, LinearFitRows)
        result = rows.solver.fit(
            rewards,
            gamma=gamma,
            theta0=self.theta[task].cpu().numpy(),
            max_iterations=max_iterations,
            tol=tol,
            stop_rule=stop_rule,
            solver=solver,
            policy_moments=rows.policy_moments(task),
        )
        assert result.theta is not None
        self.theta[task] = th.as_tensor(result.theta, device=self.theta.device)
        return result


class MlpPolicy(TaskQPolicy):
    """
    A small network Q_tau(s, .) per task, one output per action, on states rescaled to [-1, 1], refitted by
    ``fit_mlp_fqi``: a few Adam epochs on the hidden layers, then linear FQI of the output layer on their
    features, over the whole relabelled set. Each refit starts from the task's network and Adam state as the
    previous one left them (both saved with the policy).

    :param observation_space: a Box of states (finite bounds) or a ``{"state", "task"}`` Dict
    :param action_space: a Discrete action space
    :param lr_schedule: Adam learning rate of the hidden layers' gradient steps
    :param net_arch: hidden layer sizes (the output layer is linear in the last one's features)
    :param epochs_per_fit: epochs of Adam steps on the hidden layers per refit (0: fixed random features)
    :param batch_size: minibatch size of those steps
    :param fqi_ridge: Tikhonov regularisation of the output layer's per-action projections (see
        ``LinearPolicy``)
    :param state_bounds: ``(low, high)`` the states are rescaled by (None: the state Box's; TRLSD passes its
        ``state_bounds`` or the Box's)
    """

    default_max_iterations = DEFAULT_MLP_ITERATIONS
    # The output layer's features change at every refit: policy iteration would rebuild its cross moments
    # over every row each time (k^2 per row, as many as ~k fitted iterations cost).
    default_solver = "iterations"

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: tuple[int, ...] | list[int] = (64, 64),
        epochs_per_fit: int = 1,
        batch_size: int = 2048,
        fqi_ridge: float = DEFAULT_RIDGE,
        state_bounds: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        super().__init__(observation_space, action_space, lr_schedule)
        self.net_arch = tuple(net_arch)
        self.epochs_per_fit = epochs_per_fit
        self.batch_size = batch_size
        self.fqi_ridge = fqi_ridge
        self.state_bounds = state_bounds
        bounds = (self.state_space.low, self.state_space.high) if state_bounds is None else state_bounds
        low, high = (np.asarray(bound, dtype=np.float64) for bound in bounds)
        if not np.all(np.isfinite(low)) or not np.all(np.isfinite(high)):
            raise ValueError(
                "MlpPolicy rescales states by the state Box, whose bounds must be finite: give state_bounds"
            )
        self.state_centre, self.state_half_width = (high + low) / 2, (high - low) / 2
        self.q_networks = th.nn.ModuleList(
            make_q_network(self.state_space.shape[0], self.n_actions, hidden=self.net_arch)
            for _ in range(self.n_tasks)
        )
        # One Adam for every network: a refit steps only its task's parameters (the others have no gradient),
        # each parameter with its own moments and step count.
        self.optimizer = th.optim.Adam(self.parameters(), lr=lr_schedule(1.0))
        # The minibatch order, seeded from the global generator (which TRLSD's seed sets) and saved.
        self.generator = th.Generator().manual_seed(int(th.randint(2**62, ())))

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            epochs_per_fit=self.epochs_per_fit,
            batch_size=self.batch_size,
            fqi_ridge=self.fqi_ridge,
            state_bounds=self.state_bounds,
        )
        return data

    def get_extra_state(self) -> dict[str, Any]:
        """Adam's state and the minibatch generator's go into the policy's ``state_dict``: a loaded model
        refits as this one would."""
        return {"optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state()}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])

    def _inputs(self, states: np.ndarray) -> np.ndarray:
        return (states - self.state_centre) / self.state_half_width

    def q_network(self, task: int) -> th.nn.Sequential:
        """The network of Q_task, inputs (n, d) -> (n, n_actions) (``make_q_network``'s)."""
        network = self.q_networks[task]
        assert isinstance(network, th.nn.Sequential)
        return network

    def _task_q_values(self, states: np.ndarray, task: int) -> np.ndarray:
        inputs = th.as_tensor(self._inputs(states), dtype=th.float32, device=self.device)
        with th.no_grad():
            return self.q_network(task)(inputs).cpu().numpy().astype(np.float64)

    def new_fit_rows(self) -> TransitionRows:
        return TransitionRows(self._inputs, self.state_space.shape[0])

    def _fit(
        self,
        task: int,
        rows: FitRows,
        rewards: np.ndarray,
        gamma: float,
        max_iterations: int,
        tol: float,
        stop_rule: str,
        solver: str,
    ) -> FQIResult:
        assert isinstance(rows, TransitionRows)
        inputs, actions, next_inputs, terminated = rows.tensors()
        return fit_mlp_fqi(
            inputs,
            actions,
            rewards,
            next_inputs,
            terminated,
            network=self.q_network(task),
            gamma=gamma,
            optimizer=self.optimizer,
            max_iterations=max_iterations,
            tol=tol,
            epochs=self.epochs_per_fit,
            batch_size=self.batch_size,
            ridge=self.fqi_ridge,
            generator=self.generator,
            stop_rule=stop_rule,
            solver=solver,
        )
