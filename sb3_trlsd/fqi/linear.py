"""Linear Fitted-Q Iteration (Ernst et al. 2005; paper, eq. 3-4) on a set of transitions that only grows."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.linalg import cho_factor, cho_solve

from sb3_trlsd.arrays import GrowableColumns
from sb3_trlsd.fqi.targets import (
    DEFAULT_LINEAR_ITERATIONS,
    DEFAULT_RIDGE,
    DEFAULT_TOL,
    FQIResult,
    bellman_targets,
    return_bounds,
)

__all__ = ["LinearFQISolver", "fit_linear_fqi"]


class _ActionBlock(NamedTuple):
    """The transitions of one action as the iterations use them, and the inverse of its Gram matrix."""

    action: int
    phi_t: np.ndarray  # X_a^T, (k, n_a)
    next_phi_t: np.ndarray  # Phi(s')^T, (k, n_a)
    terminated: np.ndarray  # (n_a,) bool
    rows: np.ndarray  # row of each column in the order of extend calls, (n_a,) int
    inverse: np.ndarray  # (X_a^T X_a + ridge I)^-1, (k, k), float64


class LinearFQISolver:
    """
    Linear Fitted-Q Iteration on a set of transitions that only grows, for rewards that change between fits
    (the algorithm refits every task on the same shared transitions with its own relabelled rewards, and
    appends transitions between refits).

    Q(s, a) = theta_a . Phi(s) (eq. 3). Since Phi(s, a) is block-diagonal in the actions, the projection of
    eq. 4 splits into one ridge regression per action, theta_a = (X_a^T X_a + ridge I)^-1 X_a^T y_a. The
    transitions of each action are stored as columns that grow in place (an ``extend`` copies only the new
    ones), and X_a^T X_a + ridge I is kept as a running sum, its inverse (k x k, from a Cholesky
    factorisation) cached until the action gets new rows: a fit only recomputes the targets y and
    multiplies.

    :param n_features: k, the width of Phi(s)
    :param n_actions: number of actions
    :param ridge: Tikhonov regularisation of each per-action projection (> 0), which keeps it well posed
        where a feature has (almost) no sample of an action. The default 1e-3 is negligible next to the
        Gram diagonal of the maze's RBFs (~30 with 6,500 samples per action), so it barely biases theta
    :param dtype: precision of the stored features and of the targets: ``np.float64`` (default), or
        ``np.float32``, which halves the memory the iterations read (they are bound by it) at the cost of
        ~1e-6 relative rounding in theta; the Gram matrices, their inverses and theta stay float64
    """

    def __init__(
        self,
        n_features: int,
        n_actions: int,
        ridge: float = DEFAULT_RIDGE,
        dtype: npt.DTypeLike = np.float64,
    ):
        if not n_features >= 1 or not n_actions >= 1:
            raise ValueError(f"n_features and n_actions must be >= 1, got {n_features} and {n_actions}")
        if not ridge > 0:
            raise ValueError(f"ridge must be > 0 (it keeps each projection well posed), got {ridge}")
        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.float32, np.float64):
            raise ValueError(f"dtype must be float32 or float64, got {self.dtype}")
        self.n_features, self.n_actions, self.ridge = int(n_features), int(n_actions), float(ridge)
        k = self.n_features
        self._phi_t = [GrowableColumns(k, self.dtype) for _ in range(n_actions)]
        self._next_phi_t = [GrowableColumns(k, self.dtype) for _ in range(n_actions)]
        self._terminated = [GrowableColumns(1, bool) for _ in range(n_actions)]
        self._rows = [GrowableColumns(1, np.int64) for _ in range(n_actions)]
        self._gram = np.tile(self.ridge * np.eye(k), (n_actions, 1, 1))  # X_a^T X_a + ridge I, (A, k, k)
        self._inverse: list[np.ndarray | None] = [None] * n_actions  # cached until the action grows
        self.n_transitions = 0

    def __repr__(self) -> str:
        return (
            f"LinearFQISolver(n_features={self.n_features}, n_actions={self.n_actions}, "
            f"ridge={self.ridge:g}, dtype={self.dtype.name}, n_transitions={self.n_transitions})"
        )

    def extend(
        self, phi: np.ndarray, actions: np.ndarray, next_phi: np.ndarray, terminated: np.ndarray
    ) -> None:
        """
        Append transitions; their rewards are given to ``fit``, after those of the earlier transitions.

        :param phi: Phi(s), (n, k)
        :param actions: a, (n,) integers in 0..n_actions-1
        :param next_phi: Phi(s'), (n, k)
        :param terminated: s' is absorbing (no bootstrap), (n,) bool; truncated transitions are not
        """
        phi, next_phi = np.asarray(phi, dtype=np.float64), np.asarray(next_phi, dtype=np.float64)
        actions, terminated = np.asarray(actions), np.asarray(terminated, dtype=bool)
        n = len(phi)
        if phi.shape != (n, self.n_features) or next_phi.shape != phi.shape:
            raise ValueError(
                f"phi and next_phi must have shape (n, {self.n_features}), "
                f"got {phi.shape} and {next_phi.shape}"
            )
        if actions.shape != (n,) or terminated.shape != (n,):
            raise ValueError(
                f"actions and terminated must have shape ({n},), got {actions.shape} and {terminated.shape}"
            )
        if n and (actions.min() < 0 or actions.max() >= self.n_actions or np.any(actions % 1)):
            raise ValueError(f"actions must be integers in 0..{self.n_actions - 1}")
        actions = actions.astype(np.int64)
        stored_phi, stored_next_phi = self._storable(phi), self._storable(next_phi)
        for a in range(self.n_actions):
            rows = np.flatnonzero(actions == a)
            if not len(rows):
                continue
            block = phi[rows]  # (n_a, k)
            self._gram[a] += block.T @ block
            self._inverse[a] = None
            self._phi_t[a].append(stored_phi[rows].T)
            self._next_phi_t[a].append(stored_next_phi[rows].T)
            self._terminated[a].append(terminated[rows])
            self._rows[a].append(self.n_transitions + rows)
        self.n_transitions += n

    def _storable(self, features: np.ndarray) -> np.ndarray:
        """
        Features in the storage precision. In float32, values below its smallest normal number (RBFs far
        from their centre reach 1e-40) are flushed to zero: subnormal operands make every product an order
        of magnitude slower.
        """
        if self.dtype == np.float64:
            return features
        return np.where(np.abs(features) < np.finfo(self.dtype).tiny, 0.0, features).astype(self.dtype)

    def _blocks(self) -> list[_ActionBlock]:
        """The actions with samples, their columns and inverted Gram matrices."""
        blocks = []
        for a in range(self.n_actions):
            if not len(self._rows[a]):
                continue
            if self._inverse[a] is None:
                self._inverse[a] = cho_solve(cho_factor(self._gram[a]), np.eye(self.n_features))
            blocks.append(
                _ActionBlock(
                    action=a,
                    phi_t=self._phi_t[a].view(),
                    next_phi_t=self._next_phi_t[a].view(),
                    terminated=self._terminated[a].view()[0],
                    rows=self._rows[a].view()[0],
                    inverse=self._inverse[a],
                )
            )
        return blocks

    def fit(
        self,
        rewards: np.ndarray,
        *,
        gamma: float,
        theta0: np.ndarray | None = None,
        max_iterations: int = DEFAULT_LINEAR_ITERATIONS,
        tol: float = DEFAULT_TOL,
    ) -> FQIResult:
        """
        Fitted-Q Iteration on the stored transitions with the given rewards (see ``fit_linear_fqi``).

        :param rewards: r of every stored transition in the order they were added, (n_transitions,)
        :param gamma: discount factor in [0, 1)
        :param theta0: warm start, (n_actions, k); zeros if None. Actions without samples keep it
        :param max_iterations: cap on the iterations (>= 1)
        :param tol: stop when max |theta_new - theta| <= tol * (1 + max |theta_new|); with float32 storage,
            a tol below 64 float32 epsilons (7.6e-6), which rounding would never let the iterations meet, is
            raised to it
        :return: theta, iterations run and the RMS Bellman residual
        """
        rewards = np.asarray(rewards, dtype=np.float64)
        if rewards.shape != (self.n_transitions,) or not np.all(np.isfinite(rewards)):
            raise ValueError(
                f"rewards must be finite, one per stored transition: shape ({self.n_transitions},), "
                f"got {rewards.shape}"
            )
        if not 0 <= gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {gamma}")
        if not max_iterations >= 1 or not tol >= 0:
            raise ValueError(f"max_iterations must be >= 1 and tol >= 0, got {max_iterations} and {tol}")
        shape = (self.n_actions, self.n_features)
        theta = np.zeros(shape) if theta0 is None else np.array(theta0, dtype=np.float64, copy=True)
        if theta.shape != shape:
            raise ValueError(f"theta0 must have shape {shape}, got {theta.shape}")
        if not self.n_transitions:
            return FQIResult(theta=theta, iterations=0, bellman_residual=0.0)
        tol = max(tol, 64 * float(np.finfo(self.dtype).eps))

        blocks = self._blocks()
        block_rewards = [rewards[block.rows].astype(self.dtype) for block in blocks]
        bounds = return_bounds(rewards, gamma)

        def targets_of(theta: np.ndarray) -> list[np.ndarray]:
            # y = r + gamma max_a' theta_a' . Phi(s') (eq. 4), per action block, Q(s', .) as (A, n_a)^T
            theta = theta.astype(self.dtype, copy=False)
            return [
                bellman_targets(r, (theta @ block.next_phi_t).T, block.terminated, gamma, bounds)
                for block, r in zip(blocks, block_rewards, strict=True)
            ]

        targets = targets_of(theta)
        iterations = 0
        for iterations in range(1, max_iterations + 1):  # noqa: B007 (the count is returned)
            new_theta = theta.copy()
            for block, y in zip(blocks, targets, strict=True):
                new_theta[block.action] = block.inverse @ (block.phi_t @ y)  # eq. 4, block a
            change = np.abs(new_theta - theta).max()
            theta = new_theta
            targets = targets_of(theta)
            if change <= tol * (1.0 + np.abs(theta).max()):
                break
        squared_error = sum(
            float(np.sum((y - theta[block.action].astype(self.dtype) @ block.phi_t) ** 2, dtype=np.float64))
            for block, y in zip(blocks, targets, strict=True)
        )
        residual = float(np.sqrt(squared_error / self.n_transitions))
        return FQIResult(theta=theta, iterations=iterations, bellman_residual=residual)


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
    max_iterations: int = DEFAULT_LINEAR_ITERATIONS,
    tol: float = DEFAULT_TOL,
    ridge: float = DEFAULT_RIDGE,
) -> FQIResult:
    """
    Linear Fitted-Q Iteration in one call: theta_a <- (X_a^T X_a + ridge I)^-1 X_a^T y_a for each action a
    (eq. 4 in its per-action block form, since Phi(s, a) of eq. 3 is block-diagonal in the actions), with
    y = r + gamma * (1 - terminated) * max_a' theta_a' . Phi(s').

    The per-action Gram matrices are factored once: only the targets y change between iterations. The
    iterations stop when max |theta_new - theta| <= tol * (1 + max |theta_new|), a tolerance relative to
    the scale of theta (optimistic rewards make it large) and absolute below 1, or after
    ``max_iterations``. To refit the same, growing transitions with other rewards, keep a
    ``LinearFQISolver`` instead: it keeps the factorisation between fits.

    :param phi: Phi(s), (n, k)
    :param actions: a, (n,)
    :param rewards: r, (n,)
    :param next_phi: Phi(s'), (n, k)
    :param terminated: s' is absorbing, (n,) bool; truncations (terminated False) bootstrap
    :param n_actions: number of actions
    :param gamma: discount factor in [0, 1)
    :param theta0: warm start, (n_actions, k); zeros if None. Actions without samples keep it
    :param max_iterations: cap on the iterations (default 500: a cold fit with gamma = 0.9 needs ~130 for
        a contraction of factor gamma, far fewer in practice and when warm-started)
    :param tol: relative stopping tolerance (default ``DEFAULT_TOL``)
    :param ridge: Tikhonov regularisation of each projection (default 1e-3, see ``LinearFQISolver``)
    :return: theta (n_actions, k), iterations run and the RMS Bellman residual sqrt(mean (y - X theta)^2) of
        the final theta
    """
    solver = LinearFQISolver(np.shape(phi)[-1], n_actions, ridge=ridge)
    solver.extend(phi, actions, next_phi, terminated)
    return solver.fit(rewards, gamma=gamma, theta0=theta0, max_iterations=max_iterations, tol=tol)
