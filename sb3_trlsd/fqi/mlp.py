"""Fitted-Q Iteration with a small network (paper, section 3: "or a small MLP"), warm-started across refits.

Gradient steps alone are a slow way to fit Fitted-Q's regressions here: a refit changes the optimistic
rewards near the states just visited, a few hundred of the ~26,000 rows, and minibatch steps move the
network there a few rows at a time. On the maze, 2,000 Adam steps of 512 rows per refit (~2 s) learnt
well; a quarter to a sixteenth of that gradient work lost half to nearly all of the reward over 8 runs
(``benchmarks/bench_mlp.py`` measures the 2,000 steps). So the network's output layer, linear in its last
hidden features h(s), is fitted as linear FQI is (eq. 3-4, ``LinearFQISolver``, in closed form over every
row at once), while one Adam epoch per refit adapts h (LS-DQN: Levine et al. 2017, "Shallow Updates for
Deep Reinforcement Learning", fit a DQN's last layer this way).
"""

from __future__ import annotations

import numpy as np
import torch as th

from sb3_trlsd.fqi.linear import LinearFQISolver
from sb3_trlsd.fqi.targets import (
    DEFAULT_MLP_ITERATIONS,
    DEFAULT_RIDGE,
    DEFAULT_SOLVER,
    DEFAULT_STOP_RULE,
    DEFAULT_TOL,
    FQIResult,
    return_bounds,
)

__all__ = ["fit_mlp_fqi", "make_q_network"]

TensorLike = th.Tensor | np.ndarray


def make_q_network(input_dim: int, n_actions: int, hidden: tuple[int, ...] = (64, 64)) -> th.nn.Sequential:
    """
    A small MLP Q(s, .) with one output per action (ReLU hidden layers). The output layer starts at zero:
    Q = 0 until the first fit, as the linear policy's.

    :param input_dim: d, the width of the inputs
    :param n_actions: number of actions (outputs)
    :param hidden: hidden layer sizes (at least one layer)
    :return: the network, (n, d) -> (n, n_actions); ``network[:-1]`` gives the hidden features h(s)
    """
    if not hidden:
        raise ValueError("hidden must give at least one hidden layer (the features the output layer reads)")
    layers: list[th.nn.Module] = []
    width = input_dim
    for size in hidden:
        layers += [th.nn.Linear(width, size), th.nn.ReLU()]
        width = size
    output = th.nn.Linear(width, n_actions)
    th.nn.init.zeros_(output.weight)
    th.nn.init.zeros_(output.bias)
    return th.nn.Sequential(*layers, output)


def _features(hidden: th.nn.Module, inputs: th.Tensor) -> np.ndarray:
    """Phi(s) = [h(s), 1], (n, k + 1) float64: the output layer is linear in it."""
    with th.no_grad():
        h = hidden(inputs).cpu().numpy()
    phi = np.ones((len(h), h.shape[1] + 1))
    phi[:, :-1] = h
    return phi


def fit_mlp_fqi(
    inputs: TensorLike,
    actions: TensorLike,
    rewards: np.ndarray,
    next_inputs: TensorLike,
    terminated: TensorLike,
    *,
    network: th.nn.Sequential,
    gamma: float,
    optimizer: th.optim.Optimizer | None = None,
    max_iterations: int = DEFAULT_MLP_ITERATIONS,
    tol: float = DEFAULT_TOL,
    epochs: int = 1,
    batch_size: int = 2048,
    learning_rate: float = 1e-3,
    ridge: float = DEFAULT_RIDGE,
    generator: th.Generator | None = None,
    stop_rule: str = DEFAULT_STOP_RULE,
    solver: str = DEFAULT_SOLVER,
) -> FQIResult:
    """
    Fitted-Q Iteration with a network whose last layer is linear, trained in place from its current weights:

    1. the hidden layers learn: ``epochs`` epochs of shuffled minibatch Adam steps regress Q(s, a) on the
       targets y = r + gamma max_a' Q(s', a') of the current network (eq. 1, bootstrap clipped as in
       ``bellman_targets``), frozen under ``torch.no_grad``. The loss is divided by the squared largest
       return of ``return_bounds``, so that a kept ``optimizer``'s moments stay in scale as the optimistic
       rewards shrink;
    2. the fitted iterations: linear FQI of the output layer on the features Phi(s) = [h(s), 1] of the
       hidden layers, Q(s, a) = theta_a . Phi(s) (eq. 3-4, ``LinearFQISolver`` in float64, by ``solver``),
       warm-started from the current output layer. The iterations stop by ``stop_rule``, or after
       ``max_iterations`` (with an ``FQICapWarning``).

    Deterministic given the network's weights, the optimizer's state and ``generator``.

    :param inputs: network inputs of s, (n, d); float32 tensors are taken as they are (no copy)
    :param actions: a, (n,) integers
    :param rewards: r, (n,)
    :param next_inputs: network inputs of s', (n, d)
    :param terminated: s' is absorbing, (n,) bool; truncations (terminated False) bootstrap
    :param network: Q network, a ``Sequential`` ending with its ``Linear`` output (``make_q_network``),
        trained in place
    :param gamma: discount factor in [0, 1)
    :param optimizer: optimizer of ``network``'s parameters, kept by the caller to warm-start its state across
        fits (None: a new Adam with ``learning_rate``)
    :param max_iterations: cap on the fitted iterations (>= 1)
    :param tol: relative tolerance of the stopping rule (>= 0)
    :param epochs: epochs of gradient steps on the hidden layers per fit (>= 0; 0 keeps the features)
    :param batch_size: minibatch size of the gradient steps (>= 1)
    :param learning_rate: learning rate of the Adam made when ``optimizer`` is None (> 0)
    :param ridge: Tikhonov regularisation of the output layer's per-action projections (> 0)
    :param generator: CPU torch generator of the minibatch shuffling (global RNG if None)
    :param stop_rule: stopping rule of the fitted iterations, ``"theta"`` (default) or ``"targets"`` (see
        ``fit_linear_fqi_runs``)
    :param solver: how the output layer's fixed point is reached, one of ``SOLVERS`` (see
        ``fit_linear_fqi_runs``)
    :return: the fitted iterations run, the RMS Bellman residual of the final Q and whether the stopping rule
        was met
    """
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    if not (max_iterations >= 1 and tol >= 0 and epochs >= 0 and batch_size >= 1 and learning_rate > 0):
        raise ValueError(
            "max_iterations, batch_size must be >= 1, tol, epochs >= 0, learning_rate > 0; got "
            f"{max_iterations}, {batch_size}, {tol}, {epochs}, {learning_rate}"
        )
    output = network[-1]
    assert isinstance(output, th.nn.Linear), "the network must end with its linear output layer"
    rewards = np.asarray(rewards, dtype=np.float64)
    if not len(rewards):
        return FQIResult(iterations=0, bellman_residual=0.0)
    device = output.weight.device
    x = th.as_tensor(inputs, dtype=th.float32, device=device)  # (n, d)
    x_next = th.as_tensor(next_inputs, dtype=th.float32, device=device)  # (n, d)
    a = th.as_tensor(actions, device=device).long().reshape(-1, 1)  # (n, 1)
    low, high = return_bounds(rewards, gamma)

    if epochs:
        r = th.as_tensor(rewards, dtype=th.float32, device=device)  # (n,)
        continues = ~th.as_tensor(terminated, device=device).bool().reshape(-1)  # (n,)
        with th.no_grad():
            bootstrap = network(x_next).max(dim=1).values.clamp(low, high)
            y = r + gamma * th.where(continues, bootstrap, 0.0)  # (n,), eq. 1
        squared_bound = max(-low, high, 1e-12) ** 2
        if optimizer is None:
            optimizer = th.optim.Adam(network.parameters(), lr=learning_rate)
        for _ in range(epochs):
            order = th.randperm(len(x), generator=generator).to(device)
            for start in range(0, len(x), batch_size):
                rows = order[start : start + batch_size]
                predicted = network(x[rows]).gather(1, a[rows])[:, 0]  # Q(s, a), (b,)
                loss = th.nn.functional.mse_loss(predicted, y[rows]) / squared_bound
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()

    hidden = network[:-1]
    phi, next_phi = _features(hidden, x), _features(hidden, x_next)
    layer_rows = LinearFQISolver(phi.shape[1], output.out_features, ridge=ridge)
    layer_rows.extend(phi, a[:, 0].cpu().numpy(), next_phi, th.as_tensor(terminated).cpu().numpy())
    with th.no_grad():
        theta0 = th.cat([output.weight, output.bias[:, None]], dim=1).double().cpu().numpy()
    result = layer_rows.fit(
        rewards,
        gamma=gamma,
        theta0=theta0,
        max_iterations=max_iterations,
        tol=tol,
        stop_rule=stop_rule,
        solver=solver,
    )
    assert result.theta is not None
    with th.no_grad():
        output.weight.copy_(th.as_tensor(result.theta[:, :-1]))
        output.bias.copy_(th.as_tensor(result.theta[:, -1]))
    return FQIResult(
        iterations=result.iterations,
        bellman_residual=result.bellman_residual,
        converged=result.converged,
        change=result.change,
        policy_evaluations=result.policy_evaluations,
    )
