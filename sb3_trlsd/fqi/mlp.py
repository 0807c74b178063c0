"""Fitted-Q Iteration with a small network (paper, section 3: "or a small MLP")."""

from __future__ import annotations

import numpy as np
import torch as th

from sb3_trlsd.fqi.targets import DEFAULT_MLP_ITERATIONS, FQIResult, return_bounds

__all__ = ["fit_mlp_fqi", "make_q_network"]


def make_q_network(input_dim: int, n_actions: int, hidden: tuple[int, ...] = (64, 64)) -> th.nn.Sequential:
    """
    A small MLP Q(s, .) with one output per action (ReLU hidden layers).

    :param input_dim: d, the width of the inputs
    :param n_actions: number of actions (outputs)
    :param hidden: hidden layer sizes
    :return: the network, (n, d) -> (n, n_actions)
    """
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
    iterations: int = DEFAULT_MLP_ITERATIONS,
    epochs_per_iteration: int = 2,
    batch_size: int = 512,
    learning_rate: float = 1e-3,
    generator: th.Generator | None = None,
) -> FQIResult:
    """
    Fitted-Q Iteration with a network, trained in place: each iteration computes all the targets
    y = r + gamma max_a' Q_prev(s', a') (eq. 1, bootstrap clipped as in ``bellman_targets``) with the
    previous iterate, frozen under ``torch.no_grad``, then regresses Q(s, a) on y for a few epochs of
    shuffled minibatches (MSE, Adam). Deterministic given the network's initial weights and ``generator``.

    :param inputs: network inputs of s, (n, d)
    :param actions: a, (n,)
    :param rewards: r, (n,)
    :param next_inputs: network inputs of s', (n, d)
    :param terminated: s' is absorbing, (n,) bool; truncations (terminated False) bootstrap
    :param network: Q network, (n, d) -> (n, n_actions), updated in place (e.g. ``make_q_network``)
    :param gamma: discount factor in [0, 1)
    :param iterations: fitted iterations (>= 0)
    :param epochs_per_iteration: regression epochs per iteration (>= 1)
    :param batch_size: minibatch size (>= 1)
    :param learning_rate: Adam learning rate (> 0)
    :param generator: torch generator of the minibatch shuffling (global RNG if None)
    :return: iterations run and the final RMS Bellman residual
    """
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    if not (iterations >= 0 and epochs_per_iteration >= 1 and batch_size >= 1 and learning_rate > 0):
        raise ValueError(
            "iterations must be >= 0, epochs_per_iteration and batch_size >= 1, learning_rate > 0; got "
            f"{iterations}, {epochs_per_iteration}, {batch_size}, {learning_rate}"
        )
    if not len(inputs):
        return FQIResult(iterations=0, bellman_residual=0.0)
    device = next(network.parameters()).device
    x = th.as_tensor(inputs, dtype=th.float32, device=device)
    x_next = th.as_tensor(next_inputs, dtype=th.float32, device=device)
    a = th.as_tensor(np.asarray(actions, dtype=np.int64), device=device)
    r = th.as_tensor(rewards, dtype=th.float32, device=device)
    continues = th.as_tensor(~np.asarray(terminated, dtype=bool), dtype=th.float32, device=device)
    low, high = return_bounds(np.asarray(rewards, dtype=np.float64), gamma)
    optimizer = th.optim.Adam(network.parameters(), lr=learning_rate)

    def targets() -> th.Tensor:
        with th.no_grad():
            # y (n,), eq. 1, bootstrap clipped as in bellman_targets
            return r + gamma * continues * network(x_next).max(dim=1).values.clamp(low, high)

    for _ in range(iterations):
        # All targets are computed before the iteration's regression: they are those of a frozen copy of
        # the previous iterate, without copying the network.
        iteration_targets = targets()
        for _ in range(epochs_per_iteration):
            order = th.randperm(len(x), generator=generator, device=device)
            for start in range(0, len(x), batch_size):
                batch = order[start : start + batch_size]
                predicted = network(x[batch]).gather(1, a[batch, None])[:, 0]  # Q(s, a), (b,)
                loss = th.nn.functional.mse_loss(predicted, iteration_targets[batch])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
    with th.no_grad():
        residual = (targets() - network(x).gather(1, a[:, None])[:, 0]).pow(2).mean().sqrt().item()
    return FQIResult(iterations=iterations, bellman_residual=residual)
