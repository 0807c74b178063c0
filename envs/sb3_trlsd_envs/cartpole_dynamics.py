"""The goal cart-pole's moves and rewards over batches of states: Gymnasium's CartPole, a bump per target."""

from __future__ import annotations

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv, CartPoleVectorEnv

__all__ = [
    "CARTPOLE_TARGETS",
    "STATE_HIGH",
    "THETA_THRESHOLD",
    "VELOCITY_BOUNDS",
    "X_THRESHOLD",
    "cartpole_step",
    "cartpole_terminal",
    "target_rewards",
]

_CARTPOLE = CartPoleEnv()  # Gymnasium's constants: thresholds, time step, pole length
X_THRESHOLD, THETA_THRESHOLD = _CARTPOLE.x_threshold, _CARTPOLE.theta_threshold_radians
# Bounds of the cart's and the pole's velocities in the observation (m/s, rad/s): 200,000 random episodes
# stayed within 3.45 m/s and 3.72 rad/s, and between +-12 degrees a 10 N push cannot swing the pole much
# faster than 4 rad/s.
VELOCITY_BOUNDS = (4.0, 4.0)
# One step beyond the thresholds at those velocities is the farthest a terminal state can lie.
STATE_HIGH = np.array(
    [
        X_THRESHOLD + _CARTPOLE.tau * VELOCITY_BOUNDS[0],
        VELOCITY_BOUNDS[0],
        THETA_THRESHOLD + _CARTPOLE.tau * VELOCITY_BOUNDS[1],
        VELOCITY_BOUNDS[1],
    ],
    dtype=np.float32,
)
CARTPOLE_TARGETS = (-1.5, -0.75, 0.0, 0.75, 1.5)


def cartpole_step(states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Gymnasium's CartPole step for a batch of states, by Gymnasium's own batched code (``CartPoleVectorEnv``).

    :param states: (n, 4) states ``(x, x_dot, theta, theta_dot)``
    :param actions: (n,) 0 (push left) or 1 (push right)
    :return: next states (n, 4), equal to ``CartPoleEnv.step``'s to the bit, and whether each is terminal
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, 4)
    actions = np.asarray(actions).reshape(-1)
    if len(actions) != len(states):
        raise ValueError(
            f"actions must have one entry per state, got {len(actions)} for {len(states)} states"
        )
    if actions.size and (not np.issubdtype(actions.dtype, np.integer) or not np.isin(actions, (0, 1)).all()):
        raise ValueError(f"action must be 0 (push left) or 1 (push right), got {np.unique(actions)}")
    vector = CartPoleVectorEnv(num_envs=len(states))
    # Its batch is (4, n); none is done, so none is reset. (Gymnasium declares the attribute as None.)
    vector.state = states.T.copy()  # type: ignore[assignment]
    _, _, terminated, _, _ = vector.step(actions.astype(np.int64))
    return np.asarray(vector.state).T.copy(), terminated


def cartpole_terminal(states: np.ndarray) -> np.ndarray:
    """Gymnasium's termination: the cart beyond the track's ends or the pole beyond 12 degrees, (n,)."""
    states = np.asarray(states, dtype=np.float64).reshape(-1, 4)
    return (np.abs(states[:, 0]) > X_THRESHOLD) | (np.abs(states[:, 2]) > THETA_THRESHOLD)


def target_rewards(states: np.ndarray, targets: np.ndarray | float, goal_width: float) -> np.ndarray:
    """
    Noise-free rewards: ``exp(-(x - target)^2 / (2 goal_width^2))`` in a non-terminal state, 0 in a terminal.

    :param states: (n, 4) states
    :param targets: the target position of each state's task, (n,), or one for all
    :param goal_width: standard deviation of the bump, in metres
    :return: (n,) rewards in [0, 1]
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, 4)
    bump = np.exp(-0.5 * ((states[:, 0] - targets) / goal_width) ** 2)
    return np.where(cartpole_terminal(states), 0.0, bump)
