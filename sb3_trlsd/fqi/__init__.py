"""Fitted-Q Iteration over arrays (Ernst et al. 2005; paper, eq. 1-4): transitions in, Q-function out.

- ``targets.py``: the defaults, the stopping rules, ``FQIResult``, ``FQICapWarning`` and the Bellman targets
  every solver uses;
- ``linear.py``: ``LinearFQISolver``, linear FQI that keeps its per-action factorisations across refits;
- ``linear_runs.py``: ``fit_linear_fqi_runs``, its iterations for several runs at once (one is a fit);
- ``policy_iteration.py``: the exact evaluations of a greedy policy (LSTD-Q) that the ``"policy_iteration"``
  solver steps by, and their cross moments kept between fits (``PolicyMoments``);
- ``mlp.py``: FQI with a small network: its output layer by linear FQI on its hidden features.
"""

from sb3_trlsd.fqi.linear import LinearFQISolver, fit_linear_fqi
from sb3_trlsd.fqi.linear_runs import fit_linear_fqi_runs
from sb3_trlsd.fqi.mlp import fit_mlp_fqi, make_q_network
from sb3_trlsd.fqi.policy_iteration import PolicyMoments
from sb3_trlsd.fqi.targets import (
    DEFAULT_LINEAR_ITERATIONS,
    DEFAULT_MLP_ITERATIONS,
    DEFAULT_RIDGE,
    DEFAULT_SOLVER,
    DEFAULT_STOP_RULE,
    DEFAULT_TOL,
    SOLVERS,
    STOP_RULES,
    FQICapWarning,
    FQIResult,
    bellman_targets,
    bellman_targets_by_action,
    check_finite_fit,
    linear_q_values,
    return_bounds,
    targets_rule_cap,
)

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
    "LinearFQISolver",
    "PolicyMoments",
    "bellman_targets",
    "bellman_targets_by_action",
    "check_finite_fit",
    "fit_linear_fqi",
    "fit_linear_fqi_runs",
    "fit_mlp_fqi",
    "linear_q_values",
    "make_q_network",
    "return_bounds",
    "targets_rule_cap",
]
