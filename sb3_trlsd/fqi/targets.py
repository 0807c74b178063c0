"""What every Fitted-Q solver shares: its defaults, its result, and the targets of eq. 1 and 4.

The solvers bootstrap through truncations: only ``terminated`` (an absorbing next state) stops the
bootstrap, as a trajectory reset is not the end of the task.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEFAULT_LINEAR_ITERATIONS",
    "DEFAULT_MLP_ITERATIONS",
    "DEFAULT_RIDGE",
    "DEFAULT_SOLVER",
    "DEFAULT_STOP_RULE",
    "DEFAULT_TOL",
    "SOLVERS",
    "STOP_RULES",
    "FQICapWarning",
    "FQIResult",
    "bellman_targets",
    "bellman_targets_by_action",
    "check_finite_fit",
    "linear_q_values",
    "return_bounds",
    "targets_rule_cap",
    "warn_at_cap",
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
# When the linear iterations stop (``fit_linear_fqi_runs``):
# - "theta": max |theta_new - theta| <= tol * (1 + max |theta_new|). With float32 features and an
#   ill-conditioned Gram matrix (overlapping RBFs: condition number 1e6 for 10 x 10 RBFs of width 0.1),
#   rounding moves theta by ~1e-3 of its scale along the directions the data barely sees, at every
#   iteration: this rule then runs to the cap while the Q-values on the data have long stopped moving;
# - "targets": sqrt(mean (y_new - y)^2) <= tol * (high - low) of ``return_bounds``, the Bellman targets' RMS
#   change relative to the scale of the returns. The next theta is a function of the targets alone, so this
#   is the change the iterations can still make to Q on the data, blind to theta's unseen directions (and to
#   a greedy action that flips back and forth on a few rows).
STOP_RULES = ("theta", "targets")
# "theta" keeps every existing fit as it was, to the bit; "targets" is the rule to choose off the maze.
DEFAULT_STOP_RULE = "theta"
# How the linear fits reach their fixed point (``fit_linear_fqi_runs``):
# - "policy_iteration": exact evaluations of the greedy policy (LSTD-Q on the rows, eq. 4's projection of the
#   Bellman equation of that policy, solved as one (A k) x (A k) linear system), each followed by the greedy
#   policy of its Q, until a fitted iteration from the Q meets the stopping rule; where the system is too
#   large, ill-conditioned, or the policies cycle, the fitted iterations from theta0 instead;
# - "iterations": the fitted iterations alone, theta <- (X^T X + ridge I)^-1 X^T y(theta).
SOLVERS = ("policy_iteration", "iterations")
# Fewer passes are not less time where many rows change their greedy action at every refit (each costs k
# (A k + 2) products in the moments against A k in a pass): on the maze policy iteration takes a quarter of
# the passes in about the same time, on larger feature maps more time. The fitted iterations stay the default.
DEFAULT_SOLVER = "iterations"
# The cap of a "targets" fit, in units of the iterations a gamma-contraction needs to bring a change of the
# whole return scale below tol: a fit still moving after three times that is not contracting, and more
# iterations of it cost time without reaching the rule (the cap's warning says so instead).
CONTRACTION_MARGIN = 3


def targets_rule_cap(gamma: float, tol: float) -> int:
    """
    The iterations after which a fit under the ``"targets"`` rule stops: ``CONTRACTION_MARGIN`` times
    ceil(ln(tol) / ln(gamma)), the iterations a contraction of factor gamma needs to shrink a change of the
    whole return scale (the targets lie within it) to ``tol`` of it.

    :param gamma: discount factor in [0, 1)
    :param tol: the rule's tolerance, in (0, 1)
    :return: a cap >= 1
    """
    if gamma <= 0 or not 0 < tol < 1:
        return CONTRACTION_MARGIN
    return CONTRACTION_MARGIN * max(1, math.ceil(math.log(tol) / math.log(gamma)))


class FQICapWarning(UserWarning):
    """A Fitted-Q fit stopped at its cap of iterations before its stopping rule was met."""


def warn_at_cap(stop_rule: str, stacklevel: int = 2) -> None:
    """
    Warn (``FQICapWarning``) that a fit ran to its cap without meeting its stopping rule. The text holds no
    number, so Python's default filter shows it once per calling line however many refits hit the cap.

    :param stop_rule: the fit's stopping rule, one of ``STOP_RULES``
    :param stacklevel: as in ``warnings.warn``
    """
    other_rule = "stop_rule='targets', which ignores the directions of theta the data does not see, "
    advice = other_rule if stop_rule == "theta" else ""
    warnings.warn(
        f"Fitted-Q Iteration stopped at max_iterations (TRLSD: fqi_max_iterations) before its stopping rule "
        f"{stop_rule!r} was met (tol, TRLSD: fqi_tol): its Q may be short of the fixed point, or the greedy "
        f"policy may cycle between iterations (FQIResult.converged, .change). Try {advice}a larger tol, "
        "a larger max_iterations, or float64 features",
        FQICapWarning,
        stacklevel=stacklevel + 1,
    )


@dataclass(frozen=True)
class FQIResult:
    """
    What one Fitted-Q Iteration fit did.

    :param iterations: steps run, each ending with the Bellman targets of its Q over every row (one pass over
        them): fitted iterations, and the policy evaluations of ``policy_evaluations``
    :param bellman_residual: RMS of y - Q(s, a) over the transitions with the final Q
    :param theta: the linear solvers' parameters (n_actions, k) of Q(s, a) = theta[a] . Phi(s); None for a
        network, trained in place
    :param converged: the stopping rule was met (False: the iterations stopped at their cap)
    :param change: the last change the stopping rule measured, in its relative units (stopped when
        <= tol); 0 when there was nothing to fit
    :param policy_evaluations: of the ``iterations``, the exact policy evaluations of the
        ``"policy_iteration"`` solver (0 for the fitted iterations alone)
    """

    iterations: int
    bellman_residual: float
    theta: np.ndarray | None = None
    converged: bool = True
    change: float = 0.0
    policy_evaluations: int = 0


def check_finite_fit(task: int, rewards: np.ndarray, gamma: float, result: FQIResult | None = None) -> None:
    """
    Refuse a refit whose relabelled rewards are not finite or give returns, up to ``max |r| / (1 - gamma)``,
    beyond float32's range (in which the features and networks compute), or whose fitted Q (``result``: its
    Bellman residual and linear parameters) is not finite: a NaN Q makes every action tie, and the greedy
    policy take action 0 at every state, silently. Optimism far beyond the reward scale (a huge ``kappa``) is
    the usual cause.

    :param task: the task refitted, named in the error
    :param rewards: the rewards it is fitted on, (n,)
    :param gamma: the discount factor
    :param result: the fit's result (None: the rewards only, before the fit)
    :raises ValueError: naming the task, the largest reward and the settings to change
    """
    largest = float(np.max(np.abs(rewards), initial=0.0))
    if not math.isfinite(largest):
        what = f"the relabelled rewards of task {task} are not finite (NaN or inf)"
    elif largest / (1.0 - gamma) > np.finfo(np.float32).max:
        what = (
            f"the relabelled rewards of task {task}, up to {largest:.3g}, give returns beyond float32's "
            "range in which Q is computed"
        )
    elif result is not None and not (
        math.isfinite(result.bellman_residual) and (result.theta is None or np.all(np.isfinite(result.theta)))
    ):
        what = f"the Q-function Fitted-Q gave task {task} on rewards up to {largest:.3g} is not finite"
    else:
        return
    raise ValueError(
        f"{what}, on which predict would take action 0 everywhere: lower kappa (the optimism of "
        "R~ = R^ + kappa * CI, in reward units) or rescale the env's rewards"
    )


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
