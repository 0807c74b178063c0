"""Fitted-Q Iteration over arrays (Ernst et al. 2005; paper, eq. 1-4): transitions in, Q-function out.

Both solvers bootstrap through truncations: only ``terminated`` (an absorbing next state) stops the
bootstrap, as a trajectory reset is not the end of the task.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch as th
from scipy.linalg import cho_factor, cho_solve

__all__ = [
    "LinearFQIResult",
    "MLPFQIResult",
    "bellman_targets",
    "fit_linear_fqi",
    "fit_mlp_fqi",
    "linear_q_values",
    "make_q_network",
    "return_bounds",
]


@dataclass(frozen=True)
class LinearFQIResult:
    """theta (n_actions, k) of Q(s, a) = theta[a] . phi(s), the iterations run, the final Bellman residual."""

    theta: np.ndarray
    iterations: int
    bellman_residual: float


@dataclass(frozen=True)
class MLPFQIResult:
    """Fitted iterations run and the final Bellman residual (RMS) of the network trained in place."""

    iterations: int
    bellman_residual: float


def linear_q_values(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Q(s, .) = theta . Phi(s) (eq. 3): phi (n, k), theta (n_actions, k) -> (n, n_actions)."""
    return phi @ theta.T


def return_bounds(rewards: np.ndarray, gamma: float) -> tuple[float, float]:
    """The range of discounted returns the rewards allow: [min(r, 0), max(r, 0)] / (1 - gamma)."""
    if not len(rewards):
        return 0.0, 0.0
    return min(float(rewards.min()), 0.0) / (1 - gamma), max(float(rewards.max()), 0.0) / (1 - gamma)


def bellman_targets(
    rewards: np.ndarray,
    next_q: np.ndarray,
    terminated: np.ndarray,
    gamma: float,
    bounds: tuple[float, float] = (-np.inf, np.inf),
) -> np.ndarray:
    """
    y = r + gamma * max_a' Q(s', a'), without the bootstrap where s' is absorbing (eq. 1, 4): (n,).

    The bootstrap is clipped to ``bounds``: with function approximation and few samples, off-policy
    Fitted-Q Iteration is not a contraction and can diverge; no true Q-value lies outside
    ``return_bounds(rewards, gamma)``, so clipping to them leaves a well-behaved fit unchanged.
    """
    # Reduced along the first axis of next_q.T: fast when next_q is the transpose of an (n_actions, n) array.
    bootstrap = np.clip(np.max(next_q.T, axis=0), *bounds)
    return rewards + gamma * np.where(terminated, 0.0, bootstrap)


def fit_linear_fqi(
    phi: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_phi: np.ndarray,
    terminated: np.ndarray,
    *,
    n_actions: int,
    gamma: float,
    theta0: np.ndarray | None = None,
    max_iterations: int = 500,
    tol: float = 1e-6,
    ridge: float = 1e-3,
) -> LinearFQIResult:
    """
    Linear Fitted-Q Iteration: theta_a <- (X_a^T X_a + ridge I)^-1 X_a^T y_a for each action a (eq. 4 in its
    per-action block form, since Phi(s, a) of eq. 3 is block-diagonal in the actions).

    The per-action Gram matrices are factored once (Cholesky): only the targets y change between
    iterations, so an iteration is a matrix product for the targets and k x k solves. Iterations stop
    when max |theta_new - theta| <= tol * (1 + max |theta|), a tolerance relative to the scale of Q
    (optimistic rewards make it large), or after ``max_iterations``.

    :param phi: Phi(s), (n, k)
    :param actions: a, (n,)
    :param rewards: r, (n,)
    :param next_phi: Phi(s'), (n, k)
    :param terminated: s' is absorbing, (n,) bool
    :param n_actions: number of actions
    :param gamma: discount factor
    :param theta0: warm start, (n_actions, k); zeros if None
    :param max_iterations: cap on the iterations
    :param tol: relative stopping tolerance
    :param ridge: Tikhonov regularisation of each projection, which keeps it well posed where a feature has
        (almost) no sample of an action
    :return: theta, iterations run and the RMS Bellman residual of the last iteration
    """
    n, k = phi.shape
    actions = np.asarray(actions, dtype=np.int64)
    theta = np.zeros((n_actions, k)) if theta0 is None else np.array(theta0, dtype=np.float64, copy=True)
    # Rows sorted by action, so that each action's block is a contiguous slice.
    order = np.argsort(actions, kind="stable")
    starts = np.searchsorted(actions[order], np.arange(n_actions + 1))
    phi_sorted = phi[order]
    next_phi_t = np.ascontiguousarray(next_phi[order].T)  # (k, n)
    rewards_sorted = np.asarray(rewards, dtype=np.float64)[order]
    terminated_sorted = np.asarray(terminated, dtype=bool)[order]
    blocks = [phi_sorted[starts[a] : starts[a + 1]] for a in range(n_actions)]  # X_a, (n_a, k)
    # Cholesky factors of X_a^T X_a + ridge I, or None for an action never taken.
    factors = [cho_factor(block.T @ block + ridge * np.eye(k)) if len(block) else None for block in blocks]
    bounds = return_bounds(rewards_sorted, gamma)

    def targets_of(theta: np.ndarray) -> np.ndarray:
        next_q = (theta @ next_phi_t).T  # (n, n_actions)
        return bellman_targets(rewards_sorted, next_q, terminated_sorted, gamma, bounds)

    targets = targets_of(theta)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (the count is returned)
        new_theta = theta.copy()
        for a, (block, factor) in enumerate(zip(blocks, factors, strict=True)):
            if factor is not None:
                # eq. 4 for the block of action a
                new_theta[a] = cho_solve(factor, block.T @ targets[starts[a] : starts[a + 1]])
        change = np.abs(new_theta - theta).max()
        theta = new_theta
        targets = targets_of(theta)
        if change <= tol * (1.0 + np.abs(theta).max()):
            break
    fitted = np.einsum("nk,nk->n", phi_sorted, theta[actions[order]])  # Q(s, a), (n,)
    residual = float(np.sqrt(np.mean((targets - fitted) ** 2))) if n else 0.0
    return LinearFQIResult(theta=theta, iterations=iterations, bellman_residual=residual)


def make_q_network(input_dim: int, n_actions: int, hidden: tuple[int, ...] = (64, 64)) -> th.nn.Sequential:
    """A small MLP Q(s, .) with one output per action."""
    layers: list[th.nn.Module] = []
    width = input_dim
    for size in hidden:
        layers += [th.nn.Linear(width, size), th.nn.ReLU()]
        width = size
    layers.append(th.nn.Linear(width, n_actions))
    return th.nn.Sequential(*layers)


def fit_mlp_fqi(
    inputs: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_inputs: np.ndarray,
    terminated: np.ndarray,
    *,
    network: th.nn.Module,
    gamma: float,
    iterations: int = 20,
    epochs_per_iteration: int = 2,
    batch_size: int = 512,
    learning_rate: float = 1e-3,
    generator: th.Generator | None = None,
) -> MLPFQIResult:
    """
    Fitted-Q Iteration with a network, trained in place: each iteration computes the targets
    y = r + gamma max_a' Q_prev(s', a') with a frozen copy of the previous iterate, then regresses
    Q(s, a) on y for a few epochs (MSE, Adam).

    :param inputs: network inputs of s, (n, d)
    :param actions: a, (n,)
    :param rewards: r, (n,)
    :param next_inputs: network inputs of s', (n, d)
    :param terminated: s' is absorbing, (n,)
    :param network: Q network, (d) -> (n_actions), updated in place
    :param gamma: discount factor
    :param iterations: fitted iterations
    :param epochs_per_iteration: regression epochs per iteration
    :param batch_size: minibatch size
    :param learning_rate: Adam learning rate
    :param generator: torch generator of the minibatch shuffling (global RNG if None)
    :return: iterations run and the final RMS Bellman residual
    """
    device = next(network.parameters()).device
    x = th.as_tensor(inputs, dtype=th.float32, device=device)
    x_next = th.as_tensor(next_inputs, dtype=th.float32, device=device)
    a = th.as_tensor(np.asarray(actions, dtype=np.int64), device=device)
    r = th.as_tensor(rewards, dtype=th.float32, device=device)
    continues = th.as_tensor(~np.asarray(terminated, dtype=bool), dtype=th.float32, device=device)
    low, high = return_bounds(np.asarray(rewards, dtype=np.float64), gamma)
    optimizer = th.optim.Adam(network.parameters(), lr=learning_rate)

    def targets_of(q_network: th.nn.Module) -> th.Tensor:
        with th.no_grad():
            # (n,), eq. 1, bootstrap clipped as in bellman_targets
            return r + gamma * continues * q_network(x_next).max(dim=1).values.clamp(low, high)

    for _ in range(iterations):
        targets = targets_of(copy.deepcopy(network))
        for _ in range(epochs_per_iteration):
            order = th.randperm(len(x), generator=generator, device=device)
            for start in range(0, len(x), batch_size):
                batch = order[start : start + batch_size]
                predicted = network(x[batch]).gather(1, a[batch, None])[:, 0]  # Q(s, a), (b,)
                loss = th.nn.functional.mse_loss(predicted, targets[batch])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
    with th.no_grad():
        residual = (targets_of(network) - network(x).gather(1, a[:, None])[:, 0]).pow(2).mean().sqrt().item()
    return MLPFQIResult(iterations=iterations, bellman_residual=residual)
