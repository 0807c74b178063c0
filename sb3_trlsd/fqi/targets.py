"""What every Fitted-Q solver shares: its defaults, its result, and the targets of eq. 1 and 4.

The solvers bootstrap through truncations: only ``terminated`` (an absorbing next state) stops the
bootstrap, as a trajectory reset is not the end of the task.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEFAULT_LINEAR_ITERATIONS",
    "DEFAULT_MLP_ITERATIONS",
    "DEFAULT_RIDGE",
    "DEFAULT_TOL",
    "FQIResult",
    "bellman_targets",
    "bellman_targets_by_action",
    "linear_q_values",
    "return_bounds",
]

# The Fitted-Q settings, in one place (TRLSD's arguments and the policies default to these).
# A cold linear fit with gamma = 0.9 takes ~130 iterations to reach DEFAULT_TOL, warm ones far fewer.
DEFAULT_LINEAR_ITERATIONS = 500
# The MLP's iterations are linear FQI of its output layer on its hidden features: on the maze, ~70 for a
# first fit and ~30 for a warm refit reach DEFAULT_TOL.
DEFAULT_MLP_ITERATIONS = 200
# Relative change of theta at which the linear iterations stop: from a warm start, half the iterations of
# 1e-6 and the same greedy actions in practice.
DEFAULT_TOL = 1e-4
# Tikhonov regularisation of each per-action projection of eq. 4 (see ``LinearFQISolver``).
DEFAULT_RIDGE = 1e-3


@dataclass(frozen=True)
class FQIResult:
    """
    What one Fitted-Q Iteration fit did.

    :param iterations: fitted iterations run
    :param bellman_residual: RMS of y - Q(s, a) over the transitions with the final Q
    :param theta: the linear solvers' parameters (n_actions, k) of Q(s, a) = theta[a] . Phi(s); None for a
        network, trained in place
    """

    iterations: int
    bellman_residual: float
    theta: np.ndarray | None = None


def linear_q_values(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """
    Q(s, a) = theta_a . Phi(s) (eq. 3) for every action.

    :param phi: Phi(s), (n, k)
    :param theta: (n_actions, k)
    :return: (n, n_actions)
    """
    return phi @ theta.T  # eq. 3


def return_bounds(rewards: np.ndarray, gamma: float) -> tuple[float, float]:
    """
    The discounted returns the rewards allow, terminated or not: [min(r, 0), max(r, 0)] / (1 - gamma).

    :param rewards: r, (n,)
    :param gamma: discount factor in [0, 1)
    :return: (low, high)
    """
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
    y = r + gamma * max_a' Q(s', a'), without the bootstrap where s' is absorbing (eq. 1, 4).

    The bootstrap is clipped to ``bounds``: with function approximation and few samples, off-policy
    Fitted-Q Iteration is not a contraction and can diverge; no true Q-value lies outside
    ``return_bounds(rewards, gamma)``, so clipping to them leaves a well-behaved fit unchanged.

    :param rewards: r, (n,)
    :param next_q: Q(s', .), (n, n_actions); fastest as the transpose of a C-contiguous (n_actions, n) array
    :param terminated: s' is absorbing, (n,) bool
    :param gamma: discount factor
    :param bounds: (low, high) clip of the bootstrap
    :return: y, (n,)
    """
    return bellman_targets_by_action(rewards, next_q.T, terminated, gamma, *bounds)


def bellman_targets_by_action(
    rewards: np.ndarray,
    next_q: np.ndarray,
    terminated: np.ndarray | None,
    gamma: float,
    low: float | np.ndarray,
    high: float | np.ndarray,
) -> np.ndarray:
    """
    ``bellman_targets`` for Q(s', .) laid out action by action, with leading axes (several runs at once).

    :param rewards: r, (..., n)
    :param next_q: Q(s', .), (..., n_actions, n)
    :param terminated: s' is absorbing, (n,) or (..., n) bool; None: no s' is
    :param gamma: discount factor
    :param low: lower clip of the bootstrap, broadcast against (..., n) (e.g. one per run, (runs, 1))
    :param high: upper clip of the bootstrap, likewise
    :return: y, (..., n)
    """
    # max over the actions (one reduction), clipped, and without the bootstrap past an absorbing s': in
    # place, as the iterations are bound by these passes over the rows.
    bootstrap = next_q.max(axis=-2).astype(np.result_type(next_q, rewards), copy=False)
    np.clip(bootstrap, low, high, out=bootstrap)
    if terminated is not None and terminated.any():
        bootstrap[..., terminated] = 0.0
    bootstrap *= gamma
    bootstrap += rewards
    return bootstrap  # eq. 1
