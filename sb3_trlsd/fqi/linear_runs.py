"""Linear Fitted-Q Iteration of several runs at once (eq. 3-4): the iterations of ``LinearFQISolver.fit``.

Runs of one ``Engine`` (``sb3_trlsd.engine``) that share their source transitions share their rows:
the products of eq. 4 over them are one matrix-matrix product for every run still iterating. A fit of one
run (``LinearFQISolver.fit``, and so ``TRLSD``) is this with a batch of one.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from sb3_trlsd.fqi.policy_iteration import (
    MAX_POLICY_EVALUATIONS,
    MAX_UNKNOWNS,
    MAX_UPDATE_PASSES,
    PolicyMoments,
    add_cross_moments,
    evaluation_system,
    greedy_codes,
    none_code,
    solve_policy_evaluation,
)
from sb3_trlsd.fqi.targets import (
    DEFAULT_LINEAR_ITERATIONS,
    DEFAULT_SOLVER,
    DEFAULT_STOP_RULE,
    DEFAULT_TOL,
    SOLVERS,
    STOP_RULES,
    FQIResult,
    bellman_targets_by_action,
    return_bounds,
    warn_at_cap,
)

__all__ = ["ActionBlock", "FQIRows", "fit_linear_fqi_runs"]

# Up to this many runs, X_a^T y_a over the shared rows is one matrix-vector product per run: a (runs, n_a) x
# (n_a, k) product with few runs and long rows runs at a fraction of BLAS's speed on either form (measured on
# 25,000 rows, float32, one thread: 3 runs 123 us as one product against 3 x 14 us; 8 runs 99 against 112).
GEMV_RUNS = 6


class ActionBlock(NamedTuple):
    """The transitions of one action as the projection uses them, and the inverse of its Gram matrix."""

    action: int
    phi_t: np.ndarray  # X_a^T, (k, n_a)
    rows: np.ndarray | slice  # row of each column in the order they came, (n_a,) int, or their range
    inverse: np.ndarray  # (X_a^T X_a + ridge I)^-1, (k, k), float64


class FQIRows(Protocol):
    """
    The transitions a linear fit reads (``LinearFQISolver`` stores them): Phi(s) action by action with each
    action's Gram matrix, and Phi(s') of every row in the order the rows came.
    """

    n_features: int
    n_actions: int
    ridge: float
    dtype: np.dtype
    n_transitions: int

    def n_rows_of(self, action: int) -> int:
        """The rows of one action."""
        ...

    def gram(self, action: int) -> np.ndarray:
        """X_a^T X_a + ridge I of one action, (k, k) float64."""
        ...

    def inverse(self, action: int) -> np.ndarray:
        """(X_a^T X_a + ridge I)^-1 of one action, (k, k) float64."""
        ...

    def action_blocks(self) -> list[ActionBlock]:
        """The actions with rows, each with its columns X_a^T and inverse Gram matrix."""
        ...

    @property
    def next_phi_t(self) -> np.ndarray:
        """Phi(s')^T of every row, (k, n)."""
        ...

    @property
    def terminated(self) -> np.ndarray | None:
        """Whether each row's s' is absorbing, (n,); None when none is."""
        ...


class _Run(NamedTuple):
    """What one run of ``fit_linear_fqi_runs`` fits: its own rows, projections and bounds."""

    theta0: np.ndarray  # (n_actions, k) float64
    own: FQIRows | None  # its own rows
    own_rewards: np.ndarray  # its rewards of them, (n_own,) in the storage precision
    inverse: np.ndarray  # (n_actions, k, k): (G_a + G_a,r - ridge I)^-1, identity where a has no row
    gram: np.ndarray  # (n_actions, k, k): G_a + G_a,r - ridge I
    has_rows: np.ndarray  # (n_actions,) bool
    bounds: tuple[float, float]  # ``return_bounds`` of its rewards
    n_rows: int


def _check_solvers(solvers: list[FQIRows]) -> FQIRows:
    """The first solver, once every solver is known to have its sizes, ridge and precision."""
    first = solvers[0]
    for solver in solvers[1:]:
        settings = (solver.n_features, solver.n_actions, solver.ridge, solver.dtype)
        if settings != (first.n_features, first.n_actions, first.ridge, first.dtype):
            raise ValueError(f"the runs' solvers must share sizes, ridge and dtype: {first!r} and {solver!r}")
    return first


def _gram_of(shared: FQIRows | None, own: FQIRows | None, action: int) -> np.ndarray:
    """The Gram matrix of one action over the shared rows and a run's own ones, ridge I once."""
    solvers = [rows for rows in (shared, own) if rows is not None]
    # Each Gram matrix holds ridge I: the sum keeps it once.
    extra_ridge = (len(solvers) - 1) * solvers[0].ridge * np.eye(solvers[0].n_features)
    return np.sum([rows.gram(action) for rows in solvers], axis=0) - extra_ridge


def _projection_of(shared: FQIRows | None, own: FQIRows | None, action: int) -> np.ndarray | None:
    """The inverse Gram matrix of one action over the shared rows and a run's own ones (None: no row)."""
    in_shared = shared is not None and shared.n_rows_of(action) > 0
    in_own = own is not None and own.n_rows_of(action) > 0
    if in_shared and in_own:
        assert shared is not None and own is not None
        identity = np.eye(shared.n_features)
        # Both Gram matrices hold ridge I: the sum holds it twice.
        return cho_solve(
            cho_factor(shared.gram(action) + own.gram(action) - shared.ridge * identity), identity
        )
    if in_shared or in_own:
        solver = shared if in_shared else own
        assert solver is not None
        return solver.inverse(action)
    return None


class _OwnRows(NamedTuple):
    """The own rows of the active runs side by side, padded to the longest (a padded row weighs 0)."""

    phi_t: np.ndarray  # (runs, k, n) X^T of every own row, in order
    next_phi_t: np.ndarray  # (runs, k, n)
    action_mask: np.ndarray  # (runs, n_actions, n): 1 where the row is of that action, 0 elsewhere
    rewards: np.ndarray  # (runs, n)
    terminated: np.ndarray  # (runs, n) bool
    actions: np.ndarray  # (runs, n) int64, -1 on padding

    @classmethod
    def of(cls, runs: list[_Run], n_actions: int, k: int, dtype: np.dtype) -> _OwnRows:
        n = max((len(run.own_rewards) for run in runs), default=0)
        rows = cls(
            np.zeros((len(runs), k, n), dtype),
            np.zeros((len(runs), k, n), dtype),
            np.zeros((len(runs), n_actions, n), dtype),
            np.zeros((len(runs), n), dtype),
            np.zeros((len(runs), n), dtype=bool),
            np.full((len(runs), n), -1, dtype=np.int64),
        )
        for i, run in enumerate(runs):
            if run.own is None or not run.own.n_transitions:
                continue
            n_own = run.own.n_transitions
            rows.next_phi_t[i, :, :n_own] = run.own.next_phi_t
            rows.rewards[i, :n_own] = run.own_rewards
            if run.own.terminated is not None:
                rows.terminated[i, :n_own] = run.own.terminated
            for block in run.own.action_blocks():
                rows.phi_t[i][:, block.rows] = block.phi_t
                rows.action_mask[i, block.action, block.rows] = 1.0
                rows.actions[i, block.rows] = block.action
        return rows

    def kept(self, keep: np.ndarray) -> _OwnRows:
        return _OwnRows(*(array[keep] for array in self))


class _SharedRows(NamedTuple):
    """The shared rows laid out action by action for one fit: each action's rows are a slice."""

    next_phi_t: np.ndarray  # (k, n) Phi(s')^T
    terminated: np.ndarray | None  # (n,) bool, None when no s' is absorbing
    blocks: list[ActionBlock]  # rows: slices of the layout
    order: np.ndarray | None  # the stored row of each column (None: the stored order is this layout)

    @classmethod
    def of(cls, solver: FQIRows) -> _SharedRows:
        """
        The solver's rows as they are when each action's are a range (a batch's source, stored sorted by
        action); otherwise a copy of Phi(s')^T in action order, made once per fit: reading the targets of
        an action as a slice at every iteration saves more than the copy costs (rows in the order they came:
        1.15-1.9 x faster iterations on 2,000-25,000 rows).
        """
        blocks = solver.action_blocks()
        if all(isinstance(block.rows, slice) for block in blocks):
            return cls(solver.next_phi_t, solver.terminated, blocks, None)
        rows = np.arange(solver.n_transitions)
        order = np.concatenate([rows[block.rows] for block in blocks])
        starts = np.cumsum([0] + [block.phi_t.shape[1] for block in blocks])
        terminated = solver.terminated
        return cls(
            solver.next_phi_t[:, order],
            None if terminated is None else terminated[order],
            [
                block._replace(rows=slice(start, stop))
                for block, start, stop in zip(blocks, starts[:-1], starts[1:], strict=True)
            ],
            order,
        )


class _BatchedFit:
    """The iterations of ``fit_linear_fqi_runs`` over the runs still iterating (``active``: their indices)."""

    def __init__(self, shared: FQIRows | None, runs: list[_Run], shared_rewards: np.ndarray, gamma: float):
        self.shared = None if shared is None else _SharedRows.of(shared)
        self.shared_blocks = [] if self.shared is None else self.shared.blocks
        self.n_shared = 0 if shared is None else shared.n_transitions
        self.runs, self.gamma = runs, gamma
        self.dtype = shared_rewards.dtype
        self.n_actions, self.k = runs[0].theta0.shape
        self.active = np.array([r for r, run in enumerate(runs) if run.n_rows], dtype=np.int64)
        # Per active run, kept as the set shrinks: shared rows' rewards (in the shared rows' layout), bounds,
        # projections, own rows.
        self.shared_rewards = shared_rewards[self.active]
        if self.shared is not None and self.shared.order is not None:
            self.shared_rewards = self.shared_rewards[:, self.shared.order]
        bounds = np.array([runs[r].bounds for r in self.active], dtype=self.dtype).reshape(-1, 2)
        self.low, self.high = bounds[:, :1], bounds[:, 1:]
        self.scale = (bounds[:, 1] - bounds[:, 0]).astype(np.float64)  # the return scale of each run
        self.inverses = np.stack([runs[r].inverse for r in self.active]) if len(self.active) else None
        self.has_rows = np.array([runs[r].has_rows for r in self.active]).reshape(-1, self.n_actions, 1)
        self.own = _OwnRows.of([runs[r] for r in self.active], self.n_actions, self.k, self.dtype)
        # Q(s', .) of the last targets, (active, n_actions, n_shared) and (active, n_actions, n_own)
        self.next_q: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def drop(self, done: np.ndarray) -> None:
        """Stop iterating the active runs where ``done``."""
        keep = ~done
        self.active, self.shared_rewards = self.active[keep], self.shared_rewards[keep]
        self.low, self.high, self.has_rows = self.low[keep], self.high[keep], self.has_rows[keep]
        self.scale = self.scale[keep]
        self.inverses = None if self.inverses is None else self.inverses[keep]
        self.own = self.own.kept(keep)
        self.next_q = tuple(None if q is None else q[keep] for q in self.next_q)  # type: ignore[assignment]

    def targets(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        y = r + gamma max_a' theta_a' . Phi(s') (eq. 4) of every active run: (active, n_shared) from one
        product over the shared rows, and (active, n_own) from one batched product over the own rows.
        """
        stored = theta.astype(self.dtype, copy=False)
        m = len(self.active)
        shared_q = own_q = None
        if self.shared is None:
            shared_y = self.shared_rewards
        else:
            shared_q = (stored.reshape(m * self.n_actions, self.k) @ self.shared.next_phi_t).reshape(
                m, self.n_actions, -1
            )
            shared_y = bellman_targets_by_action(
                self.shared_rewards, shared_q, self.shared.terminated, self.gamma, self.low, self.high
            )
        own = self.own
        if not own.rewards.shape[1]:
            self.next_q = (shared_q, None)
            return shared_y, own.rewards
        own_q = np.matmul(stored, own.next_phi_t)
        own_y = bellman_targets_by_action(own.rewards, own_q, own.terminated, self.gamma, self.low, self.high)
        self.next_q = (shared_q, own_q)
        return shared_y, own_y

    def codes(self, active: np.ndarray) -> np.ndarray:
        """
        The codes of the given active runs' rows at their last targets (``greedy_codes``): their shared rows
        in their layout, then their own rows (padding: none), (len(active), n_shared + n_own_padded) int8.
        """
        parts = []
        shared_q, own_q = self.next_q
        low, high = self.low[active], self.high[active]
        if shared_q is not None and self.shared is not None:
            parts.append(greedy_codes(shared_q[active], self.shared.terminated, low, high))
        if own_q is not None:
            own_codes = greedy_codes(own_q[active], self.own.terminated[active], low, high)
            own_codes[self.own.actions[active] < 0] = none_code(self.n_actions)
            parts.append(own_codes)
        return np.concatenate(parts, axis=1) if parts else np.zeros((len(active), 0), dtype=np.int8)

    def moments(self, shared_y: np.ndarray, own_y: np.ndarray) -> np.ndarray:
        """X_a^T y_a of every active run, (active, n_actions, k) float64."""
        moments = np.zeros((len(self.active), self.n_actions, self.k))
        for block in self.shared_blocks:
            block_y = shared_y[:, block.rows]
            if len(block_y) <= GEMV_RUNS:
                # X_a^T y_a run by run: a few matrix-vector products beat one matrix product this thin.
                for i, run_y in enumerate(block_y):
                    moments[i, block.action] += block.phi_t @ run_y
            else:
                moments[:, block.action] += block_y @ block.phi_t.T
        if own_y.shape[1]:
            # X_a^T y_a over the own rows of action a, every action and run in one batched product.
            moments += np.matmul(self.own.action_mask * own_y[:, None, :], self.own.phi_t.transpose(0, 2, 1))
        return moments

    def projected(self, theta: np.ndarray, shared_y: np.ndarray, own_y: np.ndarray) -> np.ndarray:
        """theta_a <- (X_a^T X_a + ridge I)^-1 X_a^T y_a (eq. 4, block a) for every active run."""
        moments = self.moments(shared_y, own_y)
        assert self.inverses is not None, "a fit with active runs holds their inverses"
        new = np.einsum("rakj,raj->rak", self.inverses, moments)
        return np.where(self.has_rows, new, theta)

    def move_codes(self, i: int, moments: np.ndarray, old: np.ndarray, new: np.ndarray) -> None:
        """Move active run ``i``'s rows whose code changed from ``old`` to ``new`` in its cross moments."""
        changed = np.flatnonzero(old != new)
        if not len(changed):
            return
        split = np.searchsorted(changed, self.n_shared)
        shared_rows, own_rows = changed[:split], changed[split:] - self.n_shared
        shared_actions = self.shared_actions[shared_rows]
        # Own rows after the shared ones, each part sorted by action.
        own_rows = own_rows[np.argsort(self.own.actions[i, own_rows], kind="stable")]
        columns = [
            (self.shared_phi_t[:, shared_rows], self.shared_next_phi_t[:, shared_rows]),
            (self.own.phi_t[i][:, own_rows], self.own.next_phi_t[i][:, own_rows]),
        ]
        rows = np.concatenate([shared_rows, own_rows + self.n_shared])
        actions = np.concatenate([shared_actions, self.own.actions[i, own_rows]])
        order = np.argsort(actions, kind="stable")
        phi_t = np.concatenate([phi for phi, _ in columns], axis=1)[:, order]
        next_phi_t = np.concatenate([next_phi for _, next_phi in columns], axis=1)[:, order]
        rows = rows[order]
        add_cross_moments(moments, phi_t, next_phi_t, actions[order], old[rows], new[rows])

    @functools.cached_property
    def shared_phi_t(self) -> np.ndarray:
        """Phi(s)^T of the shared rows in their layout, (k, n_shared), made once a fit needs it."""
        if self.shared is None:
            return np.zeros((self.k, 0), dtype=self.dtype)
        return np.concatenate([block.phi_t for block in self.shared_blocks], axis=1)

    @functools.cached_property
    def shared_actions(self) -> np.ndarray:
        """The action of each shared row in their layout, (n_shared,)."""
        return np.concatenate(
            [np.zeros(0, np.int64)]
            + [np.full(block.phi_t.shape[1], block.action) for block in self.shared_blocks]
        )

    @property
    def shared_next_phi_t(self) -> np.ndarray:
        """Phi(s')^T of the shared rows in their layout, (k, n_shared)."""
        if self.shared is None:
            return np.zeros((self.k, 0), dtype=self.dtype)
        return self.shared.next_phi_t

    def residual(self, i: int, theta: np.ndarray, shared_y: np.ndarray, own_y: np.ndarray) -> float:
        """The RMS Bellman residual sqrt(mean (y - X theta)^2) of active run ``i``."""
        stored = theta.astype(self.dtype, copy=False)
        squared_error = sum(
            float(
                np.sum((shared_y[i, block.rows] - stored[block.action] @ block.phi_t) ** 2, dtype=np.float64)
            )
            for block in self.shared_blocks
        )
        if own_y.shape[1]:
            own_error = self.own.action_mask[i] * (own_y[i] - stored @ self.own.phi_t[i])  # (n_actions, n)
            squared_error += float(np.sum(own_error**2, dtype=np.float64))
        return float(np.sqrt(squared_error / self.runs[self.active[i]].n_rows))

    def stopped(
        self,
        stop_rule: str,
        tol: float,
        thetas: tuple[np.ndarray, np.ndarray],
        targets: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Whether each active run meets ``stop_rule`` after an iteration, and the change it measured, both
        (active,).

        :param stop_rule: one of ``STOP_RULES`` (see ``fit_linear_fqi_runs``)
        :param tol: its tolerance
        :param thetas: theta before and after the iteration, (active, n_actions, k) each
        :param targets: (shared y, own y) before and after the iteration
        """
        if stop_rule == "theta":
            return _theta_change(*thetas, tol)
        # RMS of y_new - y over each run's rows; padded own rows have y = 0 before and after.
        squares = np.zeros(len(self.active))
        for old_y, new_y in zip(*targets, strict=True):
            if old_y.shape[1]:
                squares += np.sum(np.square(new_y - old_y, dtype=np.float64), axis=1)
        n_rows = np.array([self.runs[r].n_rows for r in self.active], dtype=np.float64)
        change = np.sqrt(squares / n_rows)
        # Relative to the return scale; a run whose rewards are all 0 has targets 0: no change.
        change = np.divide(change, self.scale, out=np.zeros_like(change), where=self.scale > 0)
        return change <= tol, change


def _theta_change(old: np.ndarray, new: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``"theta"`` rule over runs (..., n_actions, k): met, and max |new - old| / (1 + max |new|)."""
    step, scale = np.abs(new - old).max(axis=(-2, -1)), 1.0 + np.abs(new).max(axis=(-2, -1))
    return step <= tol * scale, step / scale


class _Progress:
    """
    Where one run of a ``"policy_iteration"`` fit is: evaluating greedy policies, or fitting by the fitted
    iterations (from the start, or after giving policy iteration up).

    :param run: the run
    :param moments: its cross moments, kept across fits (``PolicyMoments``), prepared for this fit's rows
    :param codes: the codes those moments hold, in the fit's layout (shared rows, then own rows padded)
    :param reward_moments: X_a^T r_a of its rewards, (n_actions, k)
    """

    def __init__(
        self, run: _Run, moments: PolicyMoments | None, codes: np.ndarray, reward_moments: np.ndarray
    ):
        self.run = run
        self.policy_moments = moments
        self.codes = codes
        self.reward_moments = reward_moments
        self.system = None if moments is None else evaluation_system(run.gram, run.has_rows)
        self.iterating = moments is None  # the fitted iterations alone from now on
        self.steps = self.fitted = self.evaluations = 0
        self.last = "start"  # what made the current theta: "start", "fitted", "evaluated"
        self.close = False  # under the "targets" rule: the next step is a fitted iteration that may stop
        self.kept = False  # the moments were kept by the caller, from earlier fits and for later ones
        self.evaluated: set[int] = set()  # hashes of the codes evaluated so far (a repeat is a cycle)


def _policy_step(
    fit: _BatchedFit, i: int, progress: _Progress, theta: np.ndarray, codes: np.ndarray, gamma: float
) -> np.ndarray | None:
    """
    Policy iteration's step for active run ``i``: the exact evaluation of ``codes``, those of its current
    theta, or None where the evaluations are used up, the policy repeats or its system is not solvable.
    """
    key = hash(codes.tobytes())
    if progress.evaluations >= MAX_POLICY_EVALUATIONS or key in progress.evaluated:
        return None
    progress.evaluated.add(key)
    assert progress.policy_moments is not None and progress.policy_moments.moments is not None
    assert progress.system is not None
    moments = progress.policy_moments.moments
    fit.move_codes(i, moments, progress.codes, codes)
    progress.codes = codes
    run = progress.run
    return solve_policy_evaluation(
        progress.system, moments, progress.reward_moments, gamma, *run.bounds, run.has_rows, theta
    )


def fit_linear_fqi_runs(
    shared: FQIRows | None,
    own: Sequence[FQIRows | None],
    rewards: Sequence[np.ndarray],
    *,
    gamma: float,
    theta0: Sequence[np.ndarray | None],
    max_iterations: int = DEFAULT_LINEAR_ITERATIONS,
    tol: float = DEFAULT_TOL,
    stop_rule: str = DEFAULT_STOP_RULE,
    solver: str = DEFAULT_SOLVER,
    policy_moments: Sequence[PolicyMoments | None] | None = None,
) -> list[FQIResult]:
    """
    Linear Fitted-Q Iteration of several runs at once (eq. 3-4): run r fits on the ``shared`` rows followed by
    its ``own[r]`` rows, with its rewards ``rewards[r]`` of those rows in that order, from ``theta0[r]``.

    Runs of a batch that share their source transitions share their rows: the products of eq. 4 over the
    shared rows are then one matrix-matrix product for every run still iterating (Phi(s')^T of the rows
    times the parameters of all of them), read from memory once. Run r's projection of action a is
    (G_a + G_a,r - ridge I)^-1 (X_a^T y_a + X_a,r^T y_a,r), the Gram matrices of the shared and own rows
    (each holding ridge I) added. Each run stops by its own rule, so it gets what a fit of it alone gives,
    up to the order of floating-point sums. ``LinearFQISolver.fit`` is this function with one run.

    Two solvers reach the fixed point (``SOLVERS``):

    - ``"policy_iteration"`` (default): each step evaluates the greedy policy of the current theta exactly,
      the fixed point of the fitted iterations under that policy (LSTD-Q, ``sb3_trlsd.fqi.policy_iteration``),
      until a fitted iteration from the result meets ``stop_rule`` (under ``"theta"``, taken when it will;
      under ``"targets"``, once the policy or the targets stop moving). Its steps are one pass over the rows
      each, as a fitted iteration's, plus the k x k updates of the rows whose greedy action changed. Where
      n_actions * k exceeds ``MAX_UNKNOWNS``, a system is too ill-conditioned, the policies cycle or
      ``MAX_POLICY_EVALUATIONS`` are used up, the run takes the fitted iterations from ``theta0`` instead;
      where an update would cost more than ``MAX_UPDATE_PASSES`` passes, it goes on by fitted iterations;
    - ``"iterations"``: the fitted iterations alone, theta <- (X^T X + ridge I)^-1 X^T y(theta).

    A run that stops at ``max_iterations`` without meeting its rule has ``converged=False`` in its result,
    and the call warns once (``FQICapWarning``) for all such runs.

    :param shared: the rows every run has (None: none)
    :param own: each run's own rows (None: none); the solvers' sizes, ridge and precision must agree
    :param rewards: each run's r, (n_shared + n_own_r,)
    :param gamma: discount factor in [0, 1)
    :param theta0: each run's warm start, (n_actions, k) or None for zeros. Actions without rows keep it
    :param max_iterations: cap on the fitted iterations of each run (>= 1; the policy evaluations are
        bounded by ``MAX_POLICY_EVALUATIONS``)
    :param tol: tolerance of the stopping rule (>= 0); with float32 storage, a tol below 64 float32 epsilons
        (7.6e-6), which rounding would never let the iterations meet, is raised to it
    :param stop_rule: when each run stops (``STOP_RULES``):

        - ``"theta"`` (default, the rule every fit had so far): max |theta_new - theta| <= tol * (1 +
          max |theta_new|). It can run to the cap while Q has converged: with float32 features and an
          ill-conditioned Gram matrix, rounding keeps moving theta where the data barely constrains it;
        - ``"targets"``: sqrt(mean (y_new - y)^2) <= tol * (high - low) over the run's rows, the Bellman
          targets' RMS change relative to the run's return scale (``return_bounds``). Where the iterations
          contract with factor rho in that norm, the targets are then within rho / (1 - rho) * tol *
          (high - low) of their fixed point's. The RMS, not the largest change: where the greedy action
          flips back and forth on a few rows (approximate value iteration need not converge), their
          targets keep moving by a few thousandths of the scale and the largest change never settles
    :param solver: how the fixed point is reached, one of ``SOLVERS``
    :param policy_moments: each run's ``PolicyMoments``, kept by the caller from one fit of its Q to the next
        so that policy iteration updates only the rows whose greedy action changed (None, or a None entry:
        made afresh for this fit)
    :return: one result per run
    """
    first = _check_arguments(
        shared, own, rewards, theta0, policy_moments, gamma, max_iterations, tol, stop_rule, solver
    )
    n_actions, k, dtype = first.n_actions, first.n_features, first.dtype
    tol = max(tol, 64 * float(np.finfo(dtype).eps))
    n_shared = 0 if shared is None else shared.n_transitions
    runs, shared_rewards = [], np.zeros((len(own), n_shared), dtype=dtype)
    for r, (own_rows, run_rewards, start) in enumerate(zip(own, rewards, theta0, strict=True)):
        n_rows = n_shared + (0 if own_rows is None else own_rows.n_transitions)
        run_rewards = np.asarray(run_rewards, dtype=np.float64)
        if run_rewards.shape != (n_rows,) or not np.all(np.isfinite(run_rewards)):
            raise ValueError(
                f"rewards must be finite, one per row of the run: shape ({n_rows},), got {run_rewards.shape}"
            )
        theta = np.zeros((n_actions, k)) if start is None else np.array(start, dtype=np.float64, copy=True)
        if theta.shape != (n_actions, k):
            raise ValueError(f"theta0 must have shape {(n_actions, k)}, got {theta.shape}")
        shared_rewards[r] = run_rewards[:n_shared]
        projections = [_projection_of(shared, own_rows, a) for a in range(n_actions)]
        runs.append(
            _Run(
                theta0=theta,
                own=own_rows,
                own_rewards=run_rewards[n_shared:].astype(dtype),
                inverse=np.stack([np.eye(k) if p is None else p for p in projections]),
                gram=np.stack([_gram_of(shared, own_rows, a) for a in range(n_actions)]),
                has_rows=np.array([p is not None for p in projections]),
                bounds=return_bounds(run_rewards, gamma),
                n_rows=n_rows,
            )
        )

    fit = _BatchedFit(shared, runs, shared_rewards, gamma)
    results = [
        FQIResult(theta=run.theta0, iterations=0, bellman_residual=0.0) if not run.n_rows else None
        for run in runs
    ]
    capped = False
    if len(fit.active):
        theta = np.stack([runs[r].theta0 for r in fit.active])
        shared_y, own_y = fit.targets(theta)
        evaluating = solver == "policy_iteration" and n_actions * k <= MAX_UNKNOWNS
        progress = _start_progress(fit, runs, shared, own, policy_moments, shared_y, own_y, evaluating)
        while True:
            step_theta, fitted = _next_thetas(fit, progress, theta, shared_y, own_y, stop_rule, tol)
            old_theta, old_y = theta, (shared_y, own_y)
            theta = step_theta
            shared_y, own_y = fit.targets(theta)
            converged, change = fit.stopped(stop_rule, tol, (old_theta, theta), (old_y, (shared_y, own_y)))
            done = _count_step(fit, progress, fitted, converged, max_iterations, stop_rule)
            capped = capped or not converged[done].all()
            for i in np.flatnonzero(done):
                state = progress[fit.active[i]]
                results[fit.active[i]] = FQIResult(
                    theta=theta[i],
                    iterations=state.steps,
                    bellman_residual=fit.residual(int(i), theta[i], shared_y, own_y),
                    converged=bool(converged[i]),
                    change=float(change[i]),
                    policy_evaluations=state.evaluations,
                )
            if done.all():
                break
            if done.any():
                theta = theta[~done]
                shared_y, own_y = shared_y[~done], own_y[~done]
                fit.drop(done)
        _keep_policy_moments(fit, progress, shared, runs)
    if capped:
        warn_at_cap(stop_rule)
    fitted_results = [result for result in results if result is not None]
    assert len(fitted_results) == len(results), "every run has its result"
    return fitted_results


def _check_arguments(
    shared: FQIRows | None,
    own: Sequence[FQIRows | None],
    rewards: Sequence[np.ndarray],
    theta0: Sequence[np.ndarray | None],
    policy_moments: Sequence[PolicyMoments | None] | None,
    gamma: float,
    max_iterations: int,
    tol: float,
    stop_rule: str,
    solver: str,
) -> FQIRows:
    """Refuse the arguments of ``fit_linear_fqi_runs`` it cannot take; return the first solver."""
    solvers = [solver for solver in (shared, *own) if solver is not None]
    if not solvers:
        raise ValueError("fit_linear_fqi_runs needs rows: a shared solver or an own solver per run")
    if not len(own) == len(rewards) == len(theta0):
        raise ValueError(
            f"own, rewards and theta0 need one entry per run, got {len(own)}, {len(rewards)}, {len(theta0)}"
        )
    if policy_moments is not None and len(policy_moments) != len(own):
        raise ValueError(f"policy_moments needs one entry per run, got {len(policy_moments)} for {len(own)}")
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    if not max_iterations >= 1 or not tol >= 0:
        raise ValueError(f"max_iterations must be >= 1 and tol >= 0, got {max_iterations} and {tol}")
    if stop_rule not in STOP_RULES:
        raise ValueError(f"stop_rule must be one of {list(STOP_RULES)}, got {stop_rule!r}")
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {list(SOLVERS)}, got {solver!r}")
    return _check_solvers(solvers)


def _count_step(
    fit: _BatchedFit,
    progress: dict[int, _Progress],
    fitted: np.ndarray,
    converged: np.ndarray,
    max_iterations: int,
    stop_rule: str,
) -> np.ndarray:
    """Count the step each active run made; return which runs are done (a fitted iteration that met the
    rule, or the cap of fitted iterations)."""
    done = np.zeros(len(fit.active), dtype=bool)
    settling = []
    for i, r in enumerate(fit.active):
        state = progress[r]
        state.steps += 1
        if fitted[i]:
            state.fitted += 1
            done[i] = converged[i] or state.fitted == max_iterations
            state.close = False
        elif state.last == "evaluated" and stop_rule == "targets":
            settling.append(i)
    if settling:
        # Under the "targets" rule, try a fitted iteration once the policy or its targets settle.
        for i, codes in zip(settling, fit.codes(np.array(settling)), strict=True):
            state = progress[fit.active[i]]
            state.close = bool(converged[i]) or bool(np.array_equal(codes, state.codes))
    return done


def _start_progress(
    fit: _BatchedFit,
    runs: list[_Run],
    shared: FQIRows | None,
    own: Sequence[FQIRows | None],
    policy_moments: Sequence[PolicyMoments | None] | None,
    shared_y: np.ndarray,
    own_y: np.ndarray,
    evaluating: bool,
) -> dict[int, _Progress]:
    """Each active run's ``_Progress``; under policy iteration, with its moments prepared for these rows."""
    progress = {}
    reward_moments = fit.moments(fit.shared_rewards, fit.own.rewards) if evaluating else None
    n_own = fit.own.rewards.shape[1]
    for i, r in enumerate(fit.active):
        if not evaluating:
            progress[r] = _Progress(runs[r], None, np.zeros(0, np.int8), np.zeros(0))
            continue
        assert reward_moments is not None
        kept = None if policy_moments is None else policy_moments[r]
        moments = PolicyMoments() if kept is None else kept
        moments.prepare(shared, own[r], fit.n_actions, fit.k)
        shared_codes = moments.shared_codes
        if fit.shared is not None and fit.shared.order is not None:
            shared_codes = shared_codes[fit.shared.order]
        own_codes = np.full(n_own, none_code(fit.n_actions), dtype=np.int8)
        own_codes[: len(moments.own_codes)] = moments.own_codes
        codes = np.concatenate([shared_codes, own_codes])
        progress[r] = _Progress(runs[r], moments, codes, reward_moments[i])
        progress[r].kept = kept is not None
    return progress


def _next_thetas(
    fit: _BatchedFit,
    progress: dict[int, _Progress],
    theta: np.ndarray,
    shared_y: np.ndarray,
    own_y: np.ndarray,
    stop_rule: str,
    tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Each active run's next theta, and whether it is a fitted iteration (else a policy evaluation, or a
    restart from theta0 when policy iteration is given up).
    """
    step_theta = fit.projected(theta, shared_y, own_y)
    fitted = np.ones(len(fit.active), dtype=bool)
    will_stop = _theta_change(theta, step_theta, tol)[0] if stop_rule == "theta" else None
    evaluating = []
    for i, r in enumerate(fit.active):
        state = progress[r]
        if state.iterating:
            continue
        if will_stop is not None:
            evaluate = not will_stop[i]  # the fitted iteration would meet the rule: take it
        else:
            evaluate = state.last == "fitted" or (state.last == "evaluated" and not state.close)
        if evaluate:
            evaluating.append(i)
        else:
            state.last = "fitted"
    if not evaluating:
        return step_theta, fitted
    for i, codes in zip(evaluating, fit.codes(np.array(evaluating)), strict=True):
        state = progress[fit.active[i]]
        # Moments kept across fits are updated for all the fits to come; fresh ones only for this one.
        cost = np.count_nonzero(codes != state.codes) * (fit.n_actions * fit.k + 2)
        if not state.kept and cost > MAX_UPDATE_PASSES * state.run.n_rows * fit.n_actions:
            # The update would cost more than the passes it saves: the fitted iterations, from here on.
            state.iterating, state.last = True, "fitted"
            continue
        solution = _policy_step(fit, i, state, theta[i], codes, fit.gamma)
        fitted[i] = False
        if solution is None:
            # Policy iteration given up: the fitted iterations from the warm start, as if from the beginning.
            state.iterating, state.last = True, "restart"
            step_theta[i] = state.run.theta0
        else:
            state.evaluations += 1
            state.last = "evaluated"
            step_theta[i] = solution
    return step_theta, fitted


def _keep_policy_moments(
    fit: _BatchedFit, progress: dict[int, _Progress], shared: FQIRows | None, runs: list[_Run]
) -> None:
    """Write each run's codes back to its ``PolicyMoments`` in the rows' stored order, for the next fit."""
    for state in progress.values():
        moments = state.policy_moments
        if moments is None:
            continue
        shared_codes = state.codes[: fit.n_shared]
        if fit.shared is not None and fit.shared.order is not None:
            stored = np.empty_like(shared_codes)
            stored[fit.shared.order] = shared_codes
            shared_codes = stored
        n_own = 0 if state.run.own is None else state.run.own.n_transitions
        moments.shared_codes = shared_codes.copy()
        moments.own_codes = state.codes[fit.n_shared : fit.n_shared + n_own].copy()
