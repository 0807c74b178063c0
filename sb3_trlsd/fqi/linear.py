"""Linear Fitted-Q Iteration (Ernst et al. 2005; paper, eq. 3-4) on a set of transitions that only grows."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.linalg import cho_factor, cho_solve

from sb3_trlsd.arrays import GrowableColumns
from sb3_trlsd.fqi.linear_runs import ActionBlock, fit_linear_fqi_runs
from sb3_trlsd.fqi.policy_iteration import PolicyMoments
from sb3_trlsd.fqi.targets import (
    DEFAULT_LINEAR_ITERATIONS,
    DEFAULT_RIDGE,
    DEFAULT_SOLVER,
    DEFAULT_STOP_RULE,
    DEFAULT_TOL,
    FQIResult,
)

__all__ = ["ActionBlock", "LinearFQISolver", "fit_linear_fqi"]


class LinearFQISolver:
    """
    Linear Fitted-Q Iteration on a set of transitions that only grows, for rewards that change between fits
    (the algorithm refits every task on the same shared transitions with its own relabelled rewards, and
    appends transitions between refits).

    Q(s, a) = theta_a . Phi(s) (eq. 3). Since Phi(s, a) is block-diagonal in the actions, the projection of
    eq. 4 splits into one ridge regression per action, theta_a = (X_a^T X_a + ridge I)^-1 X_a^T y_a. The
    transitions' Phi(s) are stored action by action as columns that grow in place (an ``extend`` copies
    only the new ones), their Phi(s') in the order they came (one product gives Q(s', .) of all of them),
    and X_a^T X_a + ridge I is kept as a running sum, its inverse (k x k, from a Cholesky factorisation)
    cached until the action gets new rows: a fit only recomputes the targets y and multiplies.

    :param n_features: k, the width of Phi(s)
    :param n_actions: number of actions
    :param ridge: Tikhonov regularisation of each per-action projection (> 0), which keeps it well posed
        where a feature has (almost) no sample of an action. The default 1e-3 is negligible next to the
        Gram diagonal of the maze's RBFs (~30 with 6,500 samples per action), so it barely biases theta
    :param dtype: precision of the stored features and of the targets: ``np.float64`` (default), or
        ``np.float32``, which halves the memory the iterations read (they are bound by it) at the cost of
        ~1e-6 relative rounding in the targets, which an ill-conditioned Gram matrix magnifies in theta (and
        which may differ between a run fitted alone and in a batch, as BLAS sums products of different
        shapes in different orders); the Gram matrices, their inverses and theta stay float64
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
        self._phi_t = [GrowableColumns(k, self.dtype) for _ in range(n_actions)]  # X_a^T, action by action
        self._rows = [GrowableColumns(1, np.int64) for _ in range(n_actions)]  # the row of each column
        self._next_phi_t = GrowableColumns(k, self.dtype)  # Phi(s')^T of every row, in order
        self._terminated = GrowableColumns(1, bool)
        self._any_terminated = False
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
            self._rows[a].append(self.n_transitions + rows)
        self._next_phi_t.append(stored_next_phi.T)
        self._terminated.append(terminated)
        self._any_terminated = self._any_terminated or bool(terminated.any())
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

    def n_rows_of(self, action: int) -> int:
        """The rows of one action."""
        return len(self._rows[action])

    def gram(self, action: int) -> np.ndarray:
        """X_a^T X_a + ridge I of one action, (k, k) float64 (the solver's own array: do not modify)."""
        return self._gram[action]

    def inverse(self, action: int) -> np.ndarray:
        """(X_a^T X_a + ridge I)^-1 for an action, (k, k) float64, factored once until the action grows."""
        inverse = self._inverse[action]
        if inverse is None:
            inverse = cho_solve(cho_factor(self._gram[action]), np.eye(self.n_features))
            self._inverse[action] = inverse
        return inverse

    def action_blocks(self) -> list[ActionBlock]:
        """
        The actions with samples, their columns and inverted Gram matrices. An action whose rows are one
        range (rows stored sorted by action, as a batch's shared source is) gives them as a slice: the
        iterations then read its targets as a view instead of gathering them.
        """
        return [
            ActionBlock(
                action=a, phi_t=self._phi_t[a].view(), rows=self._row_range(a), inverse=self.inverse(a)
            )
            for a in range(self.n_actions)
            if len(self._rows[a])
        ]

    def _row_range(self, action: int) -> np.ndarray | slice:
        """The rows of ``action``: a slice when they are consecutive, else their indices (n_a,)."""
        rows = self._rows[action].view()[0]
        # Rows are appended in increasing order, so first and last say whether they are consecutive.
        first, last = int(rows[0]), int(rows[-1])
        return slice(first, last + 1) if last - first + 1 == len(rows) else rows

    @property
    def next_phi_t(self) -> np.ndarray:
        """Phi(s')^T of every row in the order they came, (k, n), a view."""
        return self._next_phi_t.view()

    @property
    def terminated(self) -> np.ndarray | None:
        """Whether each row's s' is absorbing, (n,); None when none is."""
        return self._terminated.view()[0] if self._any_terminated else None

    def fit(
        self,
        rewards: np.ndarray,
        *,
        gamma: float,
        theta0: np.ndarray | None = None,
        max_iterations: int = DEFAULT_LINEAR_ITERATIONS,
        tol: float = DEFAULT_TOL,
        stop_rule: str = DEFAULT_STOP_RULE,
        solver: str = DEFAULT_SOLVER,
        policy_moments: PolicyMoments | None = None,
    ) -> FQIResult:
        """
        Fitted-Q Iteration on the stored transitions with the given rewards (see ``fit_linear_fqi``): one run
        of ``fit_linear_fqi_runs``.

        :param rewards: r of every stored transition in the order they were added, (n_transitions,)
        :param gamma: discount factor in [0, 1)
        :param theta0: warm start, (n_actions, k); zeros if None. Actions without samples keep it
        :param max_iterations: cap on the iterations (>= 1)
        :param tol: tolerance of the stopping rule; with float32 storage, a tol below 64 float32 epsilons
            (7.6e-6), which rounding would never let the iterations meet, is raised to it
        :param stop_rule: ``"theta"`` (default): stop when max |theta_new - theta| <= tol * (1 +
            max |theta_new|); ``"targets"``: when the Bellman targets move by sqrt(mean (y_new - y)^2) <= tol
            times the return scale (see ``fit_linear_fqi_runs``)
        :param solver: how the fixed point is reached, one of ``SOLVERS``: ``"policy_iteration"`` (default)
            or ``"iterations"`` (see ``fit_linear_fqi_runs``)
        :param policy_moments: policy iteration's cross moments of the Q-function being refitted, kept by the
            caller between its fits (None: made afresh)
        :return: theta, iterations run, the RMS Bellman residual and whether the rule was met (a fit that
            stops at ``max_iterations`` without meeting it warns, ``FQICapWarning``)
        """
        return fit_linear_fqi_runs(
            self,
            [None],
            [rewards],
            gamma=gamma,
            theta0=[theta0],
            max_iterations=max_iterations,
            tol=tol,
            stop_rule=stop_rule,
            solver=solver,
            policy_moments=None if policy_moments is None else [policy_moments],
        )[0]


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
    stop_rule: str = DEFAULT_STOP_RULE,
    solver: str = DEFAULT_SOLVER,
) -> FQIResult:
    """
    Linear Fitted-Q Iteration in one call: theta_a <- (X_a^T X_a + ridge I)^-1 X_a^T y_a for each action a
    (eq. 4 in its per-action block form, since Phi(s, a) of eq. 3 is block-diagonal in the actions), with
    y = r + gamma * (1 - terminated) * max_a' theta_a' . Phi(s').

    The per-action Gram matrices are factored once: only the targets y change between iterations. The
    iterations stop when ``stop_rule`` is met, or after ``max_iterations`` (with an ``FQICapWarning``). To
    refit the same, growing transitions with other rewards, keep a
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
    :param stop_rule: ``"theta"`` (default): stop when max |theta_new - theta| <= tol * (1 + max |theta_new|),
        a tolerance relative to the scale of theta (optimistic rewards make it large) and absolute below 1;
        ``"targets"``: when sqrt(mean (y_new - y)^2) <= tol * (high - low) of ``return_bounds``, the RMS
        change of the Bellman targets relative to the return scale, blind to the directions of theta the data
        does not see (see ``fit_linear_fqi_runs``)
    :param solver: how the fixed point is reached, one of ``SOLVERS``: ``"policy_iteration"`` (default: exact
        evaluations of the greedy policy) or ``"iterations"`` (the fitted iterations alone)
    :return: theta (n_actions, k), iterations run, the RMS Bellman residual sqrt(mean (y - X theta)^2) of
        the final theta, whether the stopping rule was met and the last change it measured
    """
    rows = LinearFQISolver(np.shape(phi)[-1], n_actions, ridge=ridge)
    rows.extend(phi, actions, next_phi, terminated)
    return rows.fit(
        rewards,
        gamma=gamma,
        theta0=theta0,
        max_iterations=max_iterations,
        tol=tol,
        stop_rule=stop_rule,
        solver=solver,
    )
