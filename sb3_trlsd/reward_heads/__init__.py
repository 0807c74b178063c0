"""
Reward heads: the optimistic reward proxy R~_tau = R^_tau + CI_tau of one task (paper, section 3, eq. 5).

- ``RidgeRewardHead`` (``ridge.py``): the continuous setting. R^ is a ridge regression on the features
  Phi(s) with Tikhonov regularisation lambda = 1, kept as running sufficient statistics; CI by eq. 9 with
  the neighbouring weight W_tau(s) of eq. 8 under the similarity of eq. 6 (states) or eq. 7 (features).
- ``TabularRewardHead`` (``tabular.py``): the discrete setting. R^ is a per-cell mean, CI by eq. 10, on
  any cell function or a ``GridCells`` grid over the state Box; an optional set of allowed cells encodes
  the prior that rewards are zero elsewhere (``"corners"``: the grid's corner cells).
- ``KnownRewardHead`` (``known.py``): the reward is known, CI = 0.
- Other confidence bounds (``posterior.py``, ``thompson.py``, ``bernstein.py``): ``RidgePosteriorRewardHead``
  (OFUL / LinUCB's sqrt(phi^T A^-1 phi), with the determinant-doubling refit rule),
  ``ThompsonRidgeRewardHead`` (posterior sampling of the ridge weights, one draw per refit) and
  ``BernsteinRewardHead`` (UCB-V's empirical-Bernstein bound, kernel-weighted). ``make_reward_head`` builds
  them by name (``CONFIDENCE_BOUND_HEAD_NAMES``); a TRLSD model takes them by name or as instances.

The edge cases (W -> 0, |Xi| <= 1, with the choices a head offers there) are decided in ``base.py``'s
docstring.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd.reward_heads.base import (
    DEFAULT_W_FLOOR,
    LOG_COUNT_RULES,
    RewardHead,
    RewardTracker,
    check_log_count_rule,
)
from sb3_trlsd.reward_heads.bernstein import BernsteinRewardHead, BernsteinTracker
from sb3_trlsd.reward_heads.known import KnownRewardHead, RewardFn, env_reward_fn
from sb3_trlsd.reward_heads.posterior import PosteriorSnapshot, PosteriorTracker, RidgePosteriorRewardHead
from sb3_trlsd.reward_heads.ridge import SIMILARITIES, KernelSumTracker, RidgeRewardHead
from sb3_trlsd.reward_heads.tabular import CellFn, GridCells, TabularRewardHead
from sb3_trlsd.reward_heads.thompson import ThompsonRidgeRewardHead

__all__ = [
    "CONFIDENCE_BOUND_HEAD_NAMES",
    "DEFAULT_W_FLOOR",
    "LOG_COUNT_RULES",
    "REWARD_HEAD_NAMES",
    "SIMILARITIES",
    "BernsteinRewardHead",
    "BernsteinTracker",
    "CellFn",
    "GridCells",
    "KernelSumTracker",
    "KnownRewardHead",
    "PosteriorSnapshot",
    "PosteriorTracker",
    "RewardFn",
    "RewardHead",
    "RewardTracker",
    "RidgePosteriorRewardHead",
    "RidgeRewardHead",
    "TabularRewardHead",
    "ThompsonRidgeRewardHead",
    "check_head_kwargs",
    "env_reward_fn",
    "head_arguments",
    "make_reward_head",
    "make_tabular_head",
]

REWARD_HEAD_NAMES = ("ridge", "tabular", "corners", "known")
# Heads with other confidence bounds than the paper's; TRLSD builds them by name too (``builders.py``), on its
# features ("ridge_posterior", "thompson") or with its similarity's width ("bernstein").
CONFIDENCE_BOUND_HEAD_NAMES = ("ridge_posterior", "thompson", "bernstein")
DEFAULT_CELLS_PER_DIM = 5  # the paper's 5 x 5 cells of the maze


def head_arguments(name: str) -> frozenset[str]:
    """
    The keyword arguments the reward head called ``name`` takes from ``reward_head_kwargs``: its
    constructor's (and for the tabular heads ``make_tabular_head``'s) but those ``make_reward_head`` sets
    itself, and ``log_count``, which every head takes.

    :param name: a name of ``REWARD_HEAD_NAMES`` or ``CONFIDENCE_BOUND_HEAD_NAMES``
    :raises ValueError: for any other name
    """
    if name not in _HEAD_BUILDERS:
        known = list(REWARD_HEAD_NAMES + CONFIDENCE_BOUND_HEAD_NAMES)
        raise ValueError(f"reward_head must be one of {known}, got {name!r}")
    names = {"log_count"}
    for builder, set_here in _HEAD_BUILDERS[name]:
        parameters = inspect.signature(builder).parameters.values()
        names.update(p.name for p in parameters if p.kind in _NAMED and p.name not in set_here)
    return frozenset(names)


def check_head_kwargs(name: str, kwargs: Mapping[str, Any]) -> None:
    """
    Refuse ``reward_head_kwargs`` that the head called ``name`` does not take, naming those it does.

    :param name: the head's name
    :param kwargs: its ``reward_head_kwargs``
    :raises ValueError: for an argument that is not the head's, or an unknown head
    """
    allowed = head_arguments(name)
    unknown = sorted(set(kwargs) - allowed)
    if unknown:
        raise ValueError(
            f"reward_head_kwargs {unknown} are not arguments of the {name!r} reward_head, which takes "
            f"{sorted(allowed)}"
        )


def make_tabular_head(
    state_space: spaces.Box | None = None,
    *,
    kappa: float = 0.1,
    corners: bool = False,
    cell_fn: CellFn | None = None,
    n_cells: int | None = None,
    cells_per_dim: int = DEFAULT_CELLS_PER_DIM,
    **kwargs: Any,
) -> TabularRewardHead:
    """
    A tabular head on a user discretisation (``cell_fn`` and ``n_cells``) or on ``GridCells`` over the state
    Box (``cells_per_dim`` cells per dimension: the maze's 25 cells by default).

    :param state_space: the state Box (finite bounds), needed without ``cell_fn``
    :param kappa: optimism (eq. 10)
    :param corners: rewards only possible in the grid's 2^d corner cells (the corners experiment's prior)
    :param cell_fn: states (n, d) -> cell ids (n,) in 0..n_cells-1
    :param n_cells: the number of cells of ``cell_fn``
    :param cells_per_dim: cells per dimension of the grid, without ``cell_fn``
    :param kwargs: further arguments of ``TabularRewardHead`` (``allowed_cells``, ``w_floor``, ``r_max``)
    :return: the head
    """
    if cell_fn is None:
        if n_cells is not None:
            raise ValueError(
                "n_cells goes with cell_fn; without cell_fn the grid has cells_per_dim ** d cells"
            )
        if not isinstance(state_space, spaces.Box):
            raise ValueError(
                "the tabular head needs cell_fn and n_cells, or a state Box to lay a grid of cells on"
            )
        cell_fn = GridCells(
            tuple(state_space.low.astype(float)), tuple(state_space.high.astype(float)), cells_per_dim
        )
        n_cells = cell_fn.n_cells
    elif n_cells is None:
        raise ValueError("cell_fn needs n_cells, the number of cells it maps states to")
    if corners:
        if not isinstance(cell_fn, GridCells):
            raise ValueError(
                "the 'corners' prior is the corner cells of a GridCells grid: give allowed_cells instead"
            )
        if "allowed_cells" in kwargs:
            raise ValueError("'corners' sets allowed_cells to the grid's corners: give one or the other")
        kwargs["allowed_cells"] = cell_fn.corner_cells()
    return TabularRewardHead(cell_fn, n_cells, kappa=kappa, **kwargs)


def make_reward_head(
    name: str,
    *,
    task: int = 0,
    features: Callable[[np.ndarray], np.ndarray] | None = None,
    state_space: spaces.Box | None = None,
    kappa: float = 0.1,
    sigma: float = 0.2,
    similarity: str = "state",
    reward_fn: RewardFn | None = None,
    log_count: str | None = None,
    **kwargs: Any,
) -> RewardHead:
    """
    A reward head by name: ``"ridge"`` (continuous setting), ``"tabular"`` (per-cell means, see
    ``make_tabular_head``), ``"corners"`` (tabular, rewards only possible in the corner cells) or
    ``"known"`` (``reward_fn``); or one of ``CONFIDENCE_BOUND_HEAD_NAMES``: ``"ridge_posterior"`` and
    ``"thompson"`` (on ``features``), ``"bernstein"`` (of width ``sigma``, on states). Arguments a head does
    not use (``sigma`` and ``similarity`` of the tabular and linear-posterior heads, ``kappa`` of the known
    one) are ignored.

    :param name: the head's name
    :param task: the task the head is for (the known head passes it to ``reward_fn``)
    :param features: Phi for the ridge head
    :param state_space: the state Box, for the tabular heads' grid
    :param kappa: optimism
    :param sigma: similarity width of the ridge head
    :param similarity: similarity of the ridge head, ``"state"`` or ``"features"``
    :param reward_fn: the known expected reward, ``reward_fn(states, task) -> (n,)``
    :param log_count: how log|Xi_tau| is taken at small counts, one of ``LOG_COUNT_RULES`` (None: the
        default, log(max(|Xi_tau|, 2))); the heads without a log|Xi_tau| factor (known, posterior) ignore it
    :param kwargs: further arguments of the head (``ridge``, ``w_floor``, ``r_max``; ``cell_fn``,
        ``n_cells``, ``cells_per_dim``, ``allowed_cells``, ``unvisited_value`` for the tabular heads; ``seed``
        and ``kappa_scale`` for ``"thompson"``, ``reward_range`` for ``"bernstein"``)
    :return: the head
    """
    check_head_kwargs(name, kwargs)
    rule = None if log_count is None else check_log_count_rule(log_count)
    head = _named_head(
        name,
        task=task,
        features=features,
        state_space=state_space,
        kappa=kappa,
        sigma=sigma,
        similarity=similarity,
        reward_fn=reward_fn,
        **kwargs,
    )
    if rule is not None:
        head.log_count_rule = rule
    return head


def _named_head(
    name: str,
    *,
    task: int,
    features: Callable[[np.ndarray], np.ndarray] | None,
    state_space: spaces.Box | None,
    kappa: float,
    sigma: float,
    similarity: str,
    reward_fn: RewardFn | None,
    **kwargs: Any,
) -> RewardHead:
    """The head ``make_reward_head`` names, before its log-count rule is set."""
    if name == "ridge":
        if features is None:
            raise ValueError("the 'ridge' reward_head needs features (Phi, e.g. an RBFGrid)")
        return RidgeRewardHead(features, kappa=kappa, sigma=sigma, similarity=similarity, **kwargs)
    if name in ("tabular", "corners"):
        return make_tabular_head(state_space, kappa=kappa, corners=name == "corners", **kwargs)
    if name == "known":
        return KnownRewardHead(reward_fn, task)
    if name in ("ridge_posterior", "thompson"):
        if features is None:
            raise ValueError(f"the {name!r} reward_head needs features (Phi, e.g. an RBFGrid)")
        head_class = RidgePosteriorRewardHead if name == "ridge_posterior" else ThompsonRidgeRewardHead
        return head_class(features, kappa=kappa, **kwargs)
    if name == "bernstein":
        if similarity != "state":
            raise ValueError(
                f"the 'bernstein' reward_head weighs samples by eq. 6 (similarity='state'), "
                f"got {similarity!r}"
            )
        return BernsteinRewardHead(kappa=kappa, sigma=sigma, **kwargs)
    raise ValueError(
        f"reward_head must be one of {list(REWARD_HEAD_NAMES + CONFIDENCE_BOUND_HEAD_NAMES)}, got {name!r}"
    )


# What builds each named head, and the arguments ``make_reward_head`` gives it itself: the builders' other
# named arguments are the head's ``reward_head_kwargs``.
_NAMED = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
_SET_ON_FEATURES = frozenset({"self", "features", "kappa"})
_TABULAR = (
    (make_tabular_head, frozenset({"state_space", "kappa", "corners"})),
    (TabularRewardHead, frozenset({"self", "kappa"})),
)
_HEAD_BUILDERS: dict[str, tuple[tuple[Callable[..., Any], frozenset[str]], ...]] = {
    "ridge": ((RidgeRewardHead, _SET_ON_FEATURES | {"sigma", "similarity"}),),
    "tabular": _TABULAR,
    "corners": _TABULAR,
    "known": (),
    "ridge_posterior": ((RidgePosteriorRewardHead, _SET_ON_FEATURES),),
    "thompson": ((ThompsonRidgeRewardHead, _SET_ON_FEATURES),),
    "bernstein": ((BernsteinRewardHead, frozenset({"self", "kappa", "sigma"})),),
}
