"""Policy iteration on the projected Bellman equation (LSTD-Q, Lagoudakis & Parr 2003): the maths of the
``"policy_iteration"`` solver of ``fit_linear_fqi_runs``.

A fitted iteration (eq. 4 in its per-action block form) maps theta to G_a^-1 X_a^T y_a(theta), with
G_a = X_a^T X_a + ridge I and y_i = r_i + gamma * clip(max_b theta_b . Phi(s'_i), low, high) where s'_i is
not absorbing. Fix, at every row, which term the bootstrap takes (its *code*: the greedy action b, the
lower or the upper clip, or none past an absorbing s'): the map is then affine in theta, and its fixed point
is the solution of one linear system of A k unknowns,

    G_a theta_a - gamma sum_b C_ab theta_b = X_a^T r_a + gamma (low L_a + high H_a)   for every action a,

with C_ab = sum over the rows of action a whose code is b of Phi(s_i) Phi(s'_i)^T, and L_a, H_a the sums
of Phi(s_i) over those whose code is the lower or upper clip. Its solution is the fixed point of the fitted
iterations themselves when the codes of that solution are the codes it was solved with: policy iteration
alternates the two (evaluate the greedy policy exactly, take the greedy policy of the result). The cross
moments ``[C | L | H]`` are kept across fits (``PolicyMoments``) and updated on the rows whose code
changed, k x k per row, so that an evaluation costs about the rows whose greedy action changed.
"""

from __future__ import annotations

import weakref
from typing import Protocol

import numpy as np
from scipy.linalg.lapack import dgecon, dgetrf, dgetrs

__all__ = [
    "MAX_POLICY_EVALUATIONS",
    "MAX_UNKNOWNS",
    "MAX_UPDATE_PASSES",
    "MIN_RCOND",
    "PolicyMoments",
    "add_cross_moments",
    "evaluation_system",
    "greedy_codes",
    "solve_policy_evaluation",
]

# Exact evaluations a fit makes before it gives up on policy iteration (from a warm start the greedy policy
# settles in one to three on the maze); past them, as when a policy repeats, the fitted iterations take over.
MAX_POLICY_EVALUATIONS = 8
# Above this many unknowns (n_actions * k) the system's solve ((A k)^3 / 3 flops) and its moments' memory
# outgrow the passes over the rows they save: such fits take the fitted iterations.
MAX_UNKNOWNS = 1024
# An evaluation on moments made for one fit alone whose update (k (A k + 2) products per row whose code
# changed) would cost more than this many passes over the rows (A k products per row) is not made: the fitted
# iterations go on (a first build over every row costs ~k passes).
MAX_UPDATE_PASSES = 2.0
# A system whose reciprocal condition number (LAPACK's estimate, 1-norm) is below this is not solved: its
# solution would carry more rounding than signal (off-policy LSTD can be singular).
MIN_RCOND = 1e-12


def none_code(n_actions: int) -> int:
    """The code of a row that bootstraps nothing (an absorbing s', or padding); ``n_actions`` and
    ``n_actions + 1`` are the lower and the upper clip, 0..n_actions-1 the greedy action."""
    return n_actions + 2


def _lowest_bit_table(n_actions: int) -> np.ndarray:
    """For every set of actions as bits, the lowest one: the first greedy action of a tie, as argmax takes."""
    table = np.zeros(2**n_actions, dtype=np.int8)
    for bits in range(1, len(table)):
        table[bits] = (bits & -bits).bit_length() - 1
    return table


def greedy_codes(
    next_q: np.ndarray,
    terminated: np.ndarray | None,
    low: float | np.ndarray,
    high: float | np.ndarray,
) -> np.ndarray:
    """
    Which term each row's bootstrap clip(max_b Q(s', b), low, high) takes: the first greedy action, the
    lower clip (``n_actions``), the upper clip (``n_actions + 1``), or none past an absorbing s'
    (``none_code``).

    :param next_q: Q(s', .), (..., n_actions, n)
    :param terminated: s' is absorbing, (n,) or (..., n) bool; None: no s' is
    :param low: lower clip, broadcast against (..., n)
    :param high: upper clip, likewise
    :return: codes, (..., n) int8
    """
    n_actions = next_q.shape[-2]
    best = next_q.max(axis=-2)
    if n_actions <= 8:
        # argmax over a middle axis is slow: the tied-for-best actions as bits, their lowest by a table.
        bits = np.zeros(best.shape, dtype=np.uint8)
        ties = np.empty(best.shape, dtype=bool)
        for action in range(n_actions):
            np.equal(next_q[..., action, :], best, out=ties)
            bits |= ties.view(np.uint8) << action
        codes = _lowest_bit_table(n_actions)[bits]
    else:
        codes = next_q.argmax(axis=-2).astype(np.int8)
    codes[best < low] = n_actions
    codes[best > high] = n_actions + 1
    if terminated is not None:
        codes[np.broadcast_to(terminated, codes.shape)] = none_code(n_actions)
    return codes


def add_cross_moments(
    moments: np.ndarray,
    phi_t: np.ndarray,
    next_phi_t: np.ndarray,
    actions: np.ndarray,
    old: np.ndarray,
    new: np.ndarray,
) -> None:
    """
    Move rows from their old codes to their new ones in the cross moments [C | L | H] (module docstring),
    in place, in float64: each row's Phi(s) Phi(s')^T leaves block (a, old) and joins block (a, new)
    (Phi(s) alone for the clip codes). One product per action: Phi(s)^T of its rows times their signed
    next features laid out by code.

    :param moments: (n_actions * k, n_actions * k + 2), C then L then H as columns
    :param phi_t: Phi(s) of the rows, (k, m)
    :param next_phi_t: Phi(s') of the rows, (k, m)
    :param actions: their actions, (m,), sorted
    :param old: their codes in ``moments``, (m,), different from ``new`` (``none_code``: not in them)
    :param new: their codes now, (m,)
    """
    k, m = phi_t.shape
    n_actions = (moments.shape[1] - 2) // k
    signed = np.zeros((m, moments.shape[1]))  # psi(new) - psi(old) of each row
    by_code = signed[:, : n_actions * k].reshape(m, n_actions, k)
    next_phi = next_phi_t.T
    for codes, sign in ((new, 1.0), (old, -1.0)):
        rows = np.flatnonzero(codes < n_actions)
        by_code[rows, codes[rows]] = next_phi[rows] if sign > 0 else -next_phi[rows]
        clipped = np.flatnonzero((codes >= n_actions) & (codes < none_code(n_actions)))
        # A clip's bootstrap is the constant bound: its column sums Phi(s).
        signed[clipped, n_actions * k - n_actions + codes[clipped].astype(np.int64)] = sign
    phi = phi_t.astype(np.float64)
    bounds = np.searchsorted(actions, np.arange(n_actions + 1))
    for action in range(n_actions):
        start, stop = bounds[action], bounds[action + 1]
        if stop > start:
            moments[action * k : (action + 1) * k] += phi[:, start:stop] @ signed[start:stop]


def evaluation_system(gram: np.ndarray, has_rows: np.ndarray) -> np.ndarray:
    """
    The part of the policy evaluation's system that no policy changes: blockdiag(G_a), with identity blocks
    (and no coupling) for the actions without rows, which keep their parameters.

    :param gram: G_a = X_a^T X_a + ridge I, (n_actions, k, k)
    :param has_rows: which actions have rows, (n_actions,) bool
    :return: (n_actions * k, n_actions * k)
    """
    n_actions, k, _ = gram.shape
    system = np.zeros((n_actions * k, n_actions * k))
    for action in range(n_actions):
        block = slice(action * k, (action + 1) * k)
        system[block, block] = gram[action] if has_rows[action] else np.eye(k)
    return system


def solve_policy_evaluation(
    system: np.ndarray,
    moments: np.ndarray,
    reward_moments: np.ndarray,
    gamma: float,
    low: float,
    high: float,
    has_rows: np.ndarray,
    theta0: np.ndarray,
) -> np.ndarray | None:
    """
    The fixed point of the fitted iterations under fixed codes (module docstring): one LU solve of the
    A k unknowns; actions without rows keep ``theta0``.

    :param system: ``evaluation_system`` of the rows, (n_actions * k, n_actions * k)
    :param moments: [C | L | H] of the codes, (n_actions * k, n_actions * k + 2)
    :param reward_moments: X_a^T r_a, (n_actions, k)
    :param gamma: discount factor
    :param low: the lower clip of the bootstrap
    :param high: its upper clip
    :param has_rows: which actions have rows, (n_actions,) bool
    :param theta0: the parameters of the actions without rows, (n_actions, k)
    :return: theta (n_actions, k), or None where the system is too ill-conditioned to be solved
    """
    n_actions, k = theta0.shape
    size = n_actions * k
    coupled = np.repeat(has_rows, k)  # the rows of the equations of actions with rows
    matrix = system - gamma * (moments[:, :size] * coupled[:, None])
    rhs = reward_moments.reshape(size) + gamma * (low * moments[:, size] + high * moments[:, size + 1])
    rhs = np.where(coupled, rhs, theta0.reshape(size))
    norm = float(np.abs(matrix).sum(axis=0).max())
    lu, pivots, info = dgetrf(matrix, overwrite_a=True)
    if info != 0:
        return None
    rcond, info = dgecon(lu, norm, norm="1")
    if info != 0 or not rcond >= MIN_RCOND:  # NaN included
        return None
    theta, info = dgetrs(lu, pivots, rhs)
    if info != 0 or not np.all(np.isfinite(theta)):
        return None
    return theta.reshape(n_actions, k)


class _Rows(Protocol):
    """What ``PolicyMoments`` needs of a set of rows: how many, and its identity."""

    n_transitions: int


class PolicyMoments:
    """
    The cross moments [C | L | H] of one Q-function's rows (shared, then its own) under the codes they were
    last evaluated with, kept from one fit to the next: the warm start of policy iteration, as theta0 is
    the fitted iterations'. Rows only grow between fits; new rows enter with no code, and other rows (a
    buffer started over) start the moments afresh.
    """

    def __init__(self) -> None:
        self._forget()

    def _forget(self) -> None:
        self._rows: tuple[weakref.ref | None, weakref.ref | None] = (None, None)
        self._sizes = (0, 0)
        self.shared_codes = np.zeros(0, dtype=np.int8)  # codes of the shared rows, in their stored order
        self.own_codes = np.zeros(0, dtype=np.int8)  # codes of the own rows, in order
        self.moments: np.ndarray | None = None  # (n_actions * k, n_actions * k + 2)

    def __repr__(self) -> str:
        return f"PolicyMoments(rows={self._sizes})"

    def __getstate__(self) -> dict:
        # Derived from the rows and the last policy: rebuilt at the next fit, never saved.
        return {}

    def __setstate__(self, state: dict) -> None:
        self._forget()

    def prepare(self, shared: _Rows | None, own: _Rows | None, n_actions: int, n_features: int) -> None:
        """
        Fit the moments to the rows about to be fitted: new rows with no code, or everything afresh if the
        rows are not those of the last fit (or fewer).

        :param shared: the shared rows of the fit (None: none)
        :param own: the run's own rows (None: none)
        :param n_actions: number of actions
        :param n_features: k
        """
        sizes = tuple(0 if rows is None else rows.n_transitions for rows in (shared, own))
        same = all(
            (ref is None and rows is None) or (ref is not None and ref() is rows)
            for ref, rows in zip(self._rows, (shared, own), strict=True)
        )
        size = n_actions * n_features
        fresh = (
            self.moments is None
            or self.moments.shape != (size, size + 2)
            or not same
            or any(now < then for now, then in zip(sizes, self._sizes, strict=True))
        )
        empty = none_code(n_actions)
        if fresh:
            self.moments = np.zeros((size, size + 2))
            self.shared_codes = np.full(sizes[0], empty, dtype=np.int8)
            self.own_codes = np.full(sizes[1], empty, dtype=np.int8)
            self._rows = (
                None if shared is None else weakref.ref(shared),
                None if own is None else weakref.ref(own),
            )
        else:
            pairs = zip(sizes, self._sizes, strict=True)
            grown = [np.full(now - then, empty, np.int8) for now, then in pairs]
            self.shared_codes = np.concatenate([self.shared_codes, grown[0]])
            self.own_codes = np.concatenate([self.own_codes, grown[1]])
        self._sizes = (sizes[0], sizes[1])
