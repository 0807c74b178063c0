"""TRLSD's settings as one typed object: checked when made, listed for TensorBoard, and what they build.

``TRLSDConfig`` holds the settings of the learning itself (the reward heads, their optimism and similarity,
the refit trigger, Fitted-Q's stopping and the feature map Phi), whoever learns with them: the ``TRLSD``
algorithm, the runs of ``Engine`` stepped together, or the ``RelabellingReplayBuffer`` of another SB3
algorithm. ``TRLSDConfig.builder`` turns them, for one env's spaces, into a ``LearnerBuilder``: the state box,
the shared feature map, and a fresh ``TaskLearner`` (reward head and trigger) for any task.

Features and similarities see states in normalised coordinates, the state box mapped to the unit cube:
``sigma`` and ``rbf_sigma`` are fractions of the box (per dimension if wanted), so the defaults do not
depend on an env's units and a scaled copy of an env learns as the original. On the paper's maze,
(0, 5)^2, the defaults are its sigma = 0.2 and RBF width 0.2, exactly.
"""

from __future__ import annotations

import copy
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd.action_choice import TIE_BREAKS, Exploration
from sb3_trlsd.feature_choice import FEATURE_MAPS, GRID_SHAPES, default_kernel_width, make_feature_map
from sb3_trlsd.feature_maps import FeatureMap
from sb3_trlsd.fqi import DEFAULT_TOL, SOLVERS, STOP_RULES
from sb3_trlsd.observations import (
    MAX_BOX_SIDE,
    WideStateBoxWarning,
    state_space_of,
    task_count_of,
    wide_box_message,
)
from sb3_trlsd.reward_heads import (
    CONFIDENCE_BOUND_HEAD_NAMES,
    REWARD_HEAD_NAMES,
    SIMILARITIES,
    RewardFn,
    RewardHead,
    check_head_kwargs,
    make_reward_head,
)
from sb3_trlsd.reward_timing import REWARD_TIMINGS, TransitionFeatures, input_box, input_widths
from sb3_trlsd.task_learner import FIRST_FIT_RULES, OPTIMISM_RULES, TaskLearner

__all__ = [
    "FEATURE_HEAD_NAMES",
    "HEAD_DEFAULTS",
    "HEAD_NAMES",
    "STEP_HEAD_NAMES",
    "LearnerBuilder",
    "TRLSDConfig",
    "check_algorithm_settings",
    "check_discount",
    "head_seed",
]

# The heads built by name: the paper's, and those with other confidence bounds.
HEAD_NAMES = REWARD_HEAD_NAMES + CONFIDENCE_BOUND_HEAD_NAMES
# The named heads that regress the reward on Phi, and so need the shared feature map (and hold a Gram matrix).
FEATURE_HEAD_NAMES = ("ridge", "ridge_posterior", "thompson")
# The named heads whose similarity is eq. 6 on states or eq. 7 on features, of width ``sigma``.
SIMILARITY_HEAD_NAMES = ("ridge", "bernstein")
# The named heads that can learn the reward of a whole step (s, a, s'): on features, to which the action's
# one-hot code is added, or with a similarity width along the action (``reward_timing``).
STEP_HEAD_NAMES = ("ridge", "ridge_posterior", "thompson", "bernstein")
# The settings a head's name gives when they are left None. Posterior draws (``"thompson"``, the default
# head) of scale 0.01 of the largest absolute reward seen, relabelling the buffer only once it holds rows
# the task did not collect (R^ before, so that a task learnt from scratch walks as the plain estimate
# does): over a source they explore where a reward is rare, whatever the reward units (docs: the
# benchmarks page, the reward head). Every other head: the paper's, no optimism unless kappa is given, R~
# relabelling every row. Exploration follows what is left to learn: a head that learns the reward explores
# at random over a task's first steps; a head with nothing to learn (the known reward: no uncertainty
# anywhere) acts greedily from the first step, as the paper's Figure 1.
HEAD_DEFAULTS: dict[str, dict[str, Any]] = {
    "thompson": {"kappa": 0.01, "optimism": "with_source", "kappa_scale": "observed"},
    "known": {"exploration_initial_eps": 0.0},
}
OTHER_HEAD_DEFAULTS: dict[str, Any] = {"kappa": 0.0, "optimism": "always", "exploration_initial_eps": 1.0}
# The settings of a config (not of the head itself) that a head's defaults give when left None.
HEAD_SETTINGS = ("kappa", "optimism", "exploration_initial_eps")
FEATURES_SIMILARITY_SIGMA = 0.2  # eq. 7 compares feature vectors, whose scale is the features' own
# Fitted-Q's tolerance by stopping rule when none is given. On the targets, an RMS change of 1e-3 of the
# return scale: with gamma = 0.9 the targets are then within ~1% of the scale of their fixed point's, well
# below what the greedy policy can tell apart, while float32 features and near-tied greedy actions keep
# them moving by a few 1e-4.
FQI_TOLS = {"theta": DEFAULT_TOL, "targets": 1e-3}

# The widths of the Gaussians (sigma, rbf_sigma: fractions of the state box; rbf_overlap: spacings) that
# tell states apart. Below MIN_WIDTH, two float32 states that differ at all, by one rounding step (~6e-8 of
# the box), are over 38 widths apart, where exp(-x^2 / 2) underflows float64: every similarity between two
# states and every feature away from its centre is 0. Above MAX_WIDTH, exp(-1 / (2 w^2)) rounds to 1 in
# float64 across the whole box: every similarity and every feature is 1.
MIN_WIDTH, MAX_WIDTH = 1e-9, 1e8
DEGENERATE = (
    "a narrower one makes every similarity or feature 0 between distinct states, a wider one 1 across the box"
)

Widths = float | Sequence[float] | None
Counts = int | Sequence[int] | str | None
Bounds = tuple[Sequence[float], Sequence[float]]


def _require(condition: bool, name: str, meaning: str, value: object) -> None:
    if not condition:
        raise ValueError(f"{name} must be {meaning}, got {value!r}")


def _finite(name: str, value: object) -> float:
    if not (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    _require(math.isfinite(value), name, "a finite number", value)
    return float(value)


def _probability(name: str, value: object) -> None:
    _require(0 <= _finite(name, value) <= 1, name, "in [0, 1] (a probability)", value)


def _integer(name: str, value: object, minimum: int, none_allowed: bool = False) -> None:
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool) and bool(value >= minimum)
    meaning = f"an integer >= {minimum}" + (" or None" if none_allowed else "")
    _require(ok or (none_allowed and value is None), name, meaning, value)


def _widths(name: str, value: Widths, meaning: str) -> None:
    array = np.asarray(value if value is not None else 1.0)
    ok = array.dtype.kind in "fiu" and array.ndim <= 1 and array.size and np.all(np.isfinite(array))
    _require(
        bool(ok) and bool(np.all(array >= MIN_WIDTH)) and bool(np.all(array <= MAX_WIDTH)),
        name,
        f"None or a width in [{MIN_WIDTH:g}, {MAX_WIDTH:g}] (or one per dimension), {meaning}: {DEGENERATE}",
        value,
    )


def _one_of(name: str, value: Any, choices: Sequence[str]) -> None:
    """Reject a setting that is not one of its names, naming it and them."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")


def head_defaults(reward_head: str | RewardHead) -> dict[str, Any]:
    """
    The settings a reward head takes when they are left None: ``HEAD_DEFAULTS`` of its name over
    ``OTHER_HEAD_DEFAULTS``. A ``RewardHead`` instance takes ``OTHER_HEAD_DEFAULTS``, and acts greedily from
    the first step (``exploration_initial_eps`` 0) when it has no uncertainty (``has_uncertainty``): there is
    nothing about the reward left for it to explore.

    :param reward_head: a head name or a ``RewardHead``
    :return: ``kappa``, ``optimism`` and ``exploration_initial_eps`` (and ``kappa_scale`` of the
        ``"thompson"`` head)
    """
    defaults = dict(OTHER_HEAD_DEFAULTS)
    if isinstance(reward_head, str):
        defaults.update(HEAD_DEFAULTS.get(reward_head, {}))
    elif not reward_head.has_uncertainty:
        defaults["exploration_initial_eps"] = 0.0
    return defaults


def check_discount(gamma: float) -> None:
    """
    Reject a discount factor outside (0, 1), naming it.

    :raises ValueError: for NaN, infinite or out-of-range values
    """
    _require(0 < _finite("gamma", gamma) < 1, "gamma", "in (0, 1)", gamma)


# Settings of the features Phi that belong to TRLSD (which shares Phi between the policy and the heads).
FEATURE_SETTINGS = ("features", "rbf_per_dim", "rbf_sigma", "rbf_overlap", "max_features", "state_bounds")


def check_algorithm_settings(
    gamma: float,
    buffer_size: int,
    learning_starts: int,
    train_freq: int | tuple[int, str],
    seed: int | None,
    source_transitions: int | str | os.PathLike | None,
    log_picture_every: int,
    policy_kwargs: Mapping[str, object] | None,
) -> None:
    """
    Reject the settings of a ``TRLSD`` model beside its ``TRLSDConfig``, naming each: the discount factor, the
    settings it passes to SB3 that SB3 would take silently or fail on far from them (a ``buffer_size`` of 0
    or less, which SB3 makes one row, or NaN; a ``learning_starts`` that is not a count, inf never refitting;
    a ``train_freq`` that is not a count of steps or episodes; a ``seed`` numpy cannot take), a number of
    ``source_transitions`` the buffer cannot hold, ``log_picture_every``, and ``policy_kwargs`` that would
    set the features TRLSD shares between the policy and the heads.

    :raises ValueError: naming the setting, its value and what it accepts
    """
    check_discount(gamma)
    _integer("log_picture_every", log_picture_every, 0)
    shadowed = sorted(set(policy_kwargs or {}) & set(FEATURE_SETTINGS))
    if shadowed:
        raise ValueError(
            f"policy_kwargs may not set {shadowed}: the features are TRLSD's, shared by the policy and "
            "the reward heads; give feature_map, rbf_per_dim, rbf_sigma or state_bounds to TRLSD(...)"
        )
    _integer("buffer_size", buffer_size, 1)
    _integer("learning_starts", learning_starts, 0)
    frequency, unit = (
        train_freq if isinstance(train_freq, tuple) and len(train_freq) == 2 else (train_freq, "step")
    )
    ok = not isinstance(frequency, bool) and isinstance(frequency, (int, np.integer)) and frequency >= 1
    if not (ok and unit in ("step", "episode")):
        raise ValueError(
            f"train_freq must be an integer >= 1 (steps) or (n, 'step') / (n, 'episode'), got {train_freq!r}"
        )
    seed_ok = isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and 0 <= seed < 2**32
    _require(seed is None or seed_ok, "seed", "None or an integer in 0..2**32 - 1 (numpy's seeds)", seed)
    if isinstance(source_transitions, (int, np.integer)) and source_transitions > buffer_size:
        raise ValueError(
            f"source_transitions={source_transitions} do not fit the shared buffer of "
            f"buffer_size={buffer_size}: make the model with buffer_size >= {source_transitions} plus the "
            "online steps to come"
        )


def head_seed(seed: int | None, task: int) -> int | None:
    """
    The seed of a named ``"thompson"`` head's draws: one per run and task, derived from the run's seed so that
    every task of every run draws its own normals, reproducibly (None, fresh entropy, without a seed).

    :param seed: the run's seed (a model's ``seed``)
    :param task: the task
    :return: an integer >= 0, or None
    """
    if seed is None:
        return None
    return int(np.random.SeedSequence([int(seed) % 2**64, int(task), 3]).generate_state(1)[0])


@dataclass(frozen=True)
class TRLSDConfig:
    """
    The settings of TRLSD's learning, whoever learns with them (a ``TRLSD`` model, the runs of an ``Engine``
    stepped together, a ``RelabellingReplayBuffer``): each one's meaning is here, and ``TRLSD`` takes them as
    its keyword arguments. Bad values raise a ``ValueError`` naming the setting when the config is made.

    :param reward_head: ``"ridge"`` (eq. 9), ``"tabular"`` (per-cell means, eq. 10, on a grid over the state
        box or a ``cell_fn``), ``"corners"`` (only the grid's corner cells pay), ``"known"`` (CI = 0); other
        confidence bounds (``sb3_trlsd.reward_heads``): ``"ridge_posterior"`` (OFUL / LinUCB's kappa
        sqrt(phi^T A^-1 phi) on the shared features, refitted when det A has grown by ``update_ratio``),
        ``"thompson"`` (the default: posterior draws of the ridge weights of scale kappa, one per refit,
        seeded by ``seed`` and the task) or ``"bernstein"`` (UCB-V's kernel-weighted empirical-Bernstein
        bound, eq. 6 of width ``sigma``); or a ``RewardHead`` copied for each task
    :param kappa: optimism (eq. 9, 10), in the env's reward units, and for ``"thompson"`` the posterior
        scale, by default in units of the largest absolute reward seen (its ``kappa_scale="observed"``). 0 is
        the non-optimistic method of Atkeson & Santamaria; the paper's continuous setting uses 0.1 on rewards
        in [0, 1]. None: the head's (``sb3_trlsd.config.head_defaults``), 0.01 for ``"thompson"`` and 0 for
        the others
    :param sigma: width of the similarity in W (eq. 8): for eq. 6 a fraction of the state box, one or one per
        dimension (None: ``default_kernel_width(d)``, 0.04 in 2-D: the paper's 0.2 on the maze); for eq. 7
        a distance between feature vectors (None: 0.2)
    :param similarity: ``"state"`` (eq. 6, on states) or ``"features"`` (eq. 7, on RBF features)
    :param update_ratio: refit a task when the CI at an encountered state has been divided by this (> 1)
    :param first_fit: when a task's Q is first fitted (the paper does not say): ``"first_step"``, before its
        first action, on the optimism of a head with no sample; ``"first_sample"``, once its first sample is
        in (its first action is the unfitted Q's argmax)
    :param refit_growth: once the trigger has fired, a task's refit waits until its samples have grown by this
        fraction since its last refit: refits are then at most ~1 / refit_growth + ln(n) / ln(1 +
        refit_growth) over n samples (rarely-switching optimism's lazy updates), so their cost per step
        falls as a run goes on; 0 refits as soon as the trigger fires (the paper's Algorithm 1)
    :param optimism: where the shared buffer is relabelled with the optimistic R~ rather than the estimate
        R^: ``"always"`` (the paper), or ``"with_source"``, once the buffer holds rows the task did not
        collect itself (a source, other tasks' rows); None: the head's, ``"with_source"`` for
        ``"thompson"`` and ``"always"`` for the others. Fitted-Q sees the buffer's rows only, so optimism
        reaches the Q-function through the rows it relabels: learning from scratch, a bonus or a posterior
        draw values the rows visited against unvisited ones left at 0 and keeps the greedy policy among the
        visited, where R^ (0 everywhere before a reward) leaves it to the tie-break and exploration
    :param tie_break: the action taken among equal Q-values while learning (``learn``, ``act``, ``predict``
        with ``deterministic=False``): ``"random"``, one of them drawn with a generator seeded by ``seed``
        (a Q that is 0 everywhere, as before any reward is seen with kappa = 0, then explores at random
        instead of repeating action 0), or ``"first"`` (the paper's reproduction). ``predict`` with
        ``deterministic=True`` takes the first
    :param exploration_initial_eps: epsilon-greedy while learning (``learn``, ``act``; ``predict`` stays
        greedy), per task: the probability of a uniformly random action at a task's first online step. A
        greedy policy on a Q that no reward supports yet is deterministic all the same and can walk into a
        wall and stay there; random steps spread a new task's first samples instead. None: 1 for the heads
        that learn the reward, 0 for a head with nothing to learn (``"known"``, or a ``RewardHead`` without
        uncertainty), which acts greedily from its first step (``sb3_trlsd.config.head_defaults``); a value
        given wins. 0 with ``exploration_final_eps=0`` is the paper's greedy policy (its reproduction)
    :param exploration_final_eps: the probability once the task has ``exploration_steps`` online samples
    :param exploration_steps: a task's online samples over which the probability falls linearly from
        ``exploration_initial_eps`` to ``exploration_final_eps``. The schedule counts each task's own samples,
        not the ``total_timesteps`` of ``learn`` (SB3's DQN's ``exploration_fraction``): TRLSD meets new
        tasks as it goes, and ``act`` knows no budget
    :param fqi_max_iterations: cap on Fitted-Q iterations per refit (None: the policy's own default, 500
        linear and 200 MLP, and under ``fqi_stop="targets"`` at most ``sb3_trlsd.fqi.targets_rule_cap(gamma,
        fqi_tol)``, three times what a gamma-contraction needs: 198 at gamma 0.9)
    :param fqi_tol: Fitted-Q's relative stopping tolerance (see ``fqi_stop``; None: 1e-3 on the targets,
        1e-4 on theta)
    :param fqi_stop: Fitted-Q's stopping rule: ``"targets"``, once the Bellman targets move by less than
        ``fqi_tol`` of the return scale (what the next fit can still change on the data); ``"theta"``, once
        the parameters move by less than ``fqi_tol`` of their scale (the paper's reproduction: with float32
        features, directions of theta the data does not see may never settle). A refit that reaches
        ``fqi_max_iterations`` first warns (``sb3_trlsd.fqi.FQICapWarning``)
    :param fqi_solver: how a refit reaches Fitted-Q's fixed point, one of ``SOLVERS``: ``"iterations"``
        (the fitted iterations, the default) or ``"policy_iteration"`` (exact evaluations of the greedy
        policy, LSTD-Q, between fitted iterations; fewer passes over the rows) (None: the policy's)
    :param feature_map: Phi, shared by the linear policy and the feature heads: ``"auto"`` (on a Box of
        integers with at most 125 points, ``"lattice"``; else a grid of RBFs 1.5 spacings wide, counts from
        the box under ``max_features``, while every dimension gets at least 3 centres; else a row of RBFs per
        dimension, added), ``"lattice"`` (one RBF per integer point of the box, half a spacing wide: a
        grid-world's cells), ``"paper"`` (eq. 11: the grid up to 125 centres, a fifth of the spacing wide,
        else Fourier features), ``"rbf"``, ``"additive"``, ``"fourier"``, or a ``FeatureMap`` (see
        ``sb3_trlsd.feature_choice.make_feature_map``)
    :param rbf_per_dim: RBF centres per state dimension: one integer, one per dimension, or ``"cube"`` (the
        same count in every dimension) / ``"box"`` (counts proportional to the box's sides, in its units)
        under ``max_features``; None: the feature map's default (``"cube"``; 5 for ``"paper"``)
    :param rbf_sigma: width of the features, a fraction of the state box (one, or one per dimension); None:
        ``rbf_overlap`` spacings of the centres, ``default_kernel_width(d)`` for Fourier features
    :param rbf_overlap: width of the RBFs in spacings of their centres (None: 1.5, the paper's 0.2 for
        ``"paper"``); not with ``rbf_sigma``
    :param max_features: the feature map's budget (None: 64, 125 for ``"paper"``)
    :param fourier_features: the number of Fourier features (None: 50 per state dimension)
    :param state_bounds: ``(low, high)`` of the states for an unbounded Box (None: the Box's, finite)
    :param reward_head_kwargs: extra arguments of the named reward heads (e.g. ``w_floor``, ``r_max``;
        ``ridge`` of the linear-posterior heads, ``seed`` and ``kappa_scale`` of ``"thompson"``
        (``"observed"``, its default here: kappa in units of the largest absolute reward seen; ``"reward"``:
        in the env's reward units), ``reward_range`` of
        ``"bernstein"``); one the head does not take is refused (``reward_heads.head_arguments``)
    :param reward_timing: what of a transition its reward belongs to, which the reward heads learn and
        relabel at: ``"start_state"`` (the paper's R_tau(s)), ``"next_state"`` (the state it arrives at:
        e.g. a goal paid on arrival), ``"transition"`` (the pair (s, s'), whose features are Phi(s) and
        Phi(s') side by side: a reward paid the first time a place is reached, say), ``"step"`` ((s, a, s'),
        the action's one-hot code between them: a cost per action too) or ``"auto"`` (the env's
        ``metadata["reward_timing"]`` where it declares one, as this package's envs do, else ``"step"``,
        Gymnasium's r(s, a, s'), for the heads that can learn it and ``"next_state"`` for the ``"known"``
        and tabular heads)
    """

    reward_head: str | RewardHead = "thompson"
    kappa: float | None = None
    sigma: Widths = None
    similarity: str = "state"
    update_ratio: float = 2.0
    first_fit: str = "first_step"
    refit_growth: float = 0.1
    optimism: str | None = None
    tie_break: str = "random"
    exploration_initial_eps: float | None = None
    exploration_final_eps: float = 0.0
    exploration_steps: int = 500
    fqi_max_iterations: int | None = None
    fqi_tol: float | None = None
    fqi_stop: str = "targets"
    fqi_solver: str | None = None
    feature_map: str | FeatureMap = "auto"
    rbf_per_dim: Counts = None
    rbf_sigma: Widths = None
    rbf_overlap: float | None = None
    max_features: int | None = None
    fourier_features: int | None = None
    state_bounds: Bounds | None = None
    reward_head_kwargs: Mapping[str, Any] | None = field(default_factory=dict)
    reward_timing: str = "auto"

    @classmethod
    def of(cls, arguments: Mapping[str, object]) -> TRLSDConfig:
        """
        The settings among ``arguments``, a constructor's keyword arguments (its ``locals()``): each field of
        the config found there, the others at their defaults. ``TRLSD`` and ``RelabellingReplayBuffer`` take
        the settings as keyword arguments of their own and make their config this way.

        :param arguments: names to values, any others among them ignored
        :return: the config, checked
        """
        names = {setting.name for setting in fields(cls)}
        given = {name: value for name, value in arguments.items() if name in names}
        return cls(**given)  # type: ignore[arg-type]  # each value is checked by __post_init__

    def __post_init__(self) -> None:
        self._resolve_head()
        _require(
            _finite("kappa", self.kappa) >= 0, "kappa", ">= 0 (0 is the non-optimistic method)", self.kappa
        )
        _widths("sigma", self.sigma, "the similarity's, a fraction of the state box")
        _widths("rbf_sigma", self.rbf_sigma, "the features', a fraction of the state box")
        if not isinstance(self.feature_map, FeatureMap) and self.feature_map not in FEATURE_MAPS:
            raise ValueError(
                f"feature_map must be one of {list(FEATURE_MAPS)} or a FeatureMap, got {self.feature_map!r}"
            )
        _integer("fourier_features", self.fourier_features, 1, none_allowed=True)
        _require(
            _finite("update_ratio", self.update_ratio) > 1,
            "update_ratio",
            "> 1 (the CI must shrink to trigger a refit)",
            self.update_ratio,
        )
        _require(
            _finite("refit_growth", self.refit_growth) >= 0,
            "refit_growth",
            ">= 0 (a fraction of the task's samples; 0 refits as soon as the trigger fires)",
            self.refit_growth,
        )
        _one_of("optimism", self.optimism, OPTIMISM_RULES)
        _one_of("tie_break", self.tie_break, TIE_BREAKS)
        _probability("exploration_initial_eps", self.exploration_initial_eps)
        _probability("exploration_final_eps", self.exploration_final_eps)
        _integer("exploration_steps", self.exploration_steps, 0)
        _one_of("fqi_stop", self.fqi_stop, STOP_RULES)
        if self.fqi_solver is not None:
            _one_of("fqi_solver", self.fqi_solver, SOLVERS)
        if self.fqi_tol is None:
            object.__setattr__(self, "fqi_tol", FQI_TOLS[self.fqi_stop])
        _require(
            _finite("fqi_tol", self.fqi_tol) >= 0, "fqi_tol", ">= 0 (a relative tolerance)", self.fqi_tol
        )
        counts = self.rbf_per_dim
        if isinstance(counts, str):
            _require(
                counts in GRID_SHAPES,
                "rbf_per_dim",
                f"an integer >= 1, one per dimension or one of {list(GRID_SHAPES)}",
                counts,
            )
        elif counts is not None:
            for count in np.atleast_1d(np.asarray(counts, dtype=object)):
                _integer("rbf_per_dim", count, 1)
        _integer("max_features", self.max_features, 1, none_allowed=True)
        if self.rbf_overlap is not None:
            _require(
                MIN_WIDTH <= _finite("rbf_overlap", self.rbf_overlap) <= MAX_WIDTH,
                "rbf_overlap",
                f"a width in [{MIN_WIDTH:g}, {MAX_WIDTH:g}] spacings of the centres: {DEGENERATE}",
                self.rbf_overlap,
            )
            if self.rbf_sigma is not None:
                raise ValueError(
                    "give rbf_sigma (a fraction of the box) or rbf_overlap (of the spacing), not both"
                )
        _integer("fqi_max_iterations", self.fqi_max_iterations, 1, none_allowed=True)
        _one_of("similarity", self.similarity, SIMILARITIES)
        if self.reward_head == "bernstein" and self.similarity != "state":
            raise ValueError(
                f"similarity must be 'state' with reward_head='bernstein' (its weights are eq. 6's), "
                f"got {self.similarity!r}"
            )
        if self.reward_timing not in (*REWARD_TIMINGS, "auto"):
            raise ValueError(
                f"reward_timing must be one of {[*REWARD_TIMINGS, 'auto']} (what of a transition a reward "
                f"belongs to), got {self.reward_timing!r}"
            )
        if self.first_fit not in FIRST_FIT_RULES:
            raise ValueError(
                f"first_fit must be one of {list(FIRST_FIT_RULES)} (when a task's Q is first fitted), "
                f"got {self.first_fit!r}"
            )

    @property
    def head_name(self) -> str:
        """The reward head's name, or its class name for a ``RewardHead`` instance."""
        return self.reward_head if isinstance(self.reward_head, str) else type(self.reward_head).__name__

    def _resolve_head(self) -> None:
        """
        Check the reward head and its arguments, and give the settings left None the head's
        (``head_defaults``); the kwargs are copied: the caller's dict is theirs (and a frozen config is not
        changed through it).
        """
        if not isinstance(self.reward_head, RewardHead) and self.reward_head not in HEAD_NAMES:
            raise ValueError(
                f"reward_head must be one of {list(HEAD_NAMES)} or a RewardHead instance, "
                f"got {self.reward_head!r}"
            )
        head_kwargs = dict(self.reward_head_kwargs or {})
        for name, value in head_defaults(self.reward_head).items():
            if name not in HEAD_SETTINGS:
                head_kwargs.setdefault(name, value)  # an argument of the head itself
            elif getattr(self, name) is None:
                object.__setattr__(self, name, value)
        object.__setattr__(self, "reward_head_kwargs", head_kwargs)
        if isinstance(self.reward_head, str):
            check_head_kwargs(self.reward_head, head_kwargs)

    @property
    def exploration(self) -> Exploration:
        """The epsilon-greedy behaviour of these settings."""
        assert self.exploration_initial_eps is not None, "resolved when the settings are made"
        initial, final = float(self.exploration_initial_eps), float(self.exploration_final_eps)
        return Exploration(initial, final, int(self.exploration_steps))

    @property
    def fqi_tolerance(self) -> float:
        """``fqi_tol`` as the fits take it: the rule's ``FQI_TOLS`` entry when it was given as None."""
        assert self.fqi_tol is not None, "resolved when the settings are made"
        return self.fqi_tol

    def hyperparameters(self) -> dict[str, int | float | str | bool]:
        """The settings as TensorBoard's HParams tab shows them (numbers, or their text)."""
        settings = {
            "reward_head": self.head_name,
            "kappa": self.kappa,
            "sigma": self.sigma,
            "similarity": self.similarity,
            "update_ratio": self.update_ratio,
            "first_fit": self.first_fit,
            "refit_growth": self.refit_growth,
            "optimism": self.optimism,
            "tie_break": self.tie_break,
            "exploration_initial_eps": self.exploration_initial_eps,
            "exploration_final_eps": self.exploration_final_eps,
            "exploration_steps": self.exploration_steps,
            "fqi_max_iterations": self.fqi_max_iterations,
            "fqi_tol": self.fqi_tol,
            "fqi_stop": self.fqi_stop,
            "fqi_solver": self.fqi_solver,
            "feature_map": self.feature_map
            if isinstance(self.feature_map, str)
            else type(self.feature_map).__name__,
            "rbf_per_dim": self.rbf_per_dim,
            "rbf_sigma": self.rbf_sigma,
            "rbf_overlap": self.rbf_overlap,
            "max_features": self.max_features,
            "reward_timing": self.reward_timing,
        }
        return {
            key: value if isinstance(value, (int, float, bool)) else str(value)
            for key, value in settings.items()
        }

    def state_box(self, observation_space: spaces.Space) -> tuple[np.ndarray, np.ndarray]:
        """
        The box [low, high] normalised coordinates are taken in: ``state_bounds`` if given, else the state
        Box's bounds, which must then be finite; a side of the Box wider than ``MAX_BOX_SIDE`` is warned of
        (``WideStateBoxWarning``).

        :param observation_space: the env's observation space (a state Box, or a ``{"state", "task"}`` Dict)
        :return: low and high, (d,) float64
        :raises ValueError: naming the unbounded dimensions and how to bound them
        """
        space = state_space_of(observation_space)
        if self.state_bounds is not None:
            try:
                low, high = (np.asarray(bound, dtype=np.float64) for bound in self.state_bounds)
            except (TypeError, ValueError) as error:
                raise ValueError(f"state_bounds must be (low, high), got {self.state_bounds!r}") from error
            if (
                low.shape != space.shape
                or high.shape != space.shape
                or not np.all(np.isfinite(low) & np.isfinite(high))
            ):
                raise ValueError(
                    f"state_bounds must be (low, high), finite, of shape {space.shape} each, "
                    f"got {self.state_bounds!r}"
                )
            if not np.all(low < high):
                raise ValueError(
                    f"state_bounds must have low < high in every dimension, got {self.state_bounds!r}"
                )
            return low, high
        low, high = space.low.astype(np.float64), space.high.astype(np.float64)
        unbounded = np.flatnonzero(~(np.isfinite(low) & np.isfinite(high)))
        if len(unbounded):
            raise ValueError(
                f"the state Box is unbounded in dimension(s) {unbounded.tolist()} (low {low[unbounded]}, "
                f"high {high[unbounded]}), and TRLSD's features and similarities are taken relative to the "
                "box: give state_bounds=(low, high) with the range the states really take, or wrap the env "
                "so that its observation space is finite (gymnasium.wrappers.TransformObservation with "
                "np.clip and a bounded Box, then RescaleObservation if wanted)"
            )
        wide = np.flatnonzero(high - low > MAX_BOX_SIDE)
        if len(wide):
            warnings.warn(wide_box_message(wide.tolist(), low, high), WideStateBoxWarning, stacklevel=2)
        return low, high

    def similarity_width(self, low: np.ndarray, high: np.ndarray) -> float | np.ndarray:
        """
        The width of the similarity of the ridge (and Bernstein) heads in the units it compares: for eq. 6
        (``"state"``) ``sigma`` (default ``default_kernel_width(d)``) times the box's size per dimension; for
        eq. 7 (``"features"``) ``sigma`` as given (default 0.2).
        """
        if self.similarity == "features":
            return FEATURES_SIMILARITY_SIGMA if self.sigma is None else float(self.sigma)  # type: ignore[arg-type]
        sigma = (
            default_kernel_width(len(low)) if self.sigma is None else np.asarray(self.sigma, dtype=np.float64)
        )
        return sigma * (high - low)

    def heads_use_features(self) -> bool:
        """Whether the named reward head regresses on the shared feature map Phi."""
        return isinstance(self.reward_head, str) and self.reward_head in FEATURE_HEAD_NAMES

    def builder(
        self,
        observation_space: spaces.Space,
        n_actions: int,
        linear_q: bool,
        seed: int | None = None,
        env_reward_timing: str | None = None,
    ) -> LearnerBuilder:
        """
        What these settings build for an env of these spaces: its state box, the feature map Phi shared by
        the linear Q and the feature heads (None when neither uses one), and its task learners.

        :param observation_space: the env's observation space
        :param n_actions: the env's actions
        :param linear_q: whether a linear Q-function is fitted on Phi
        :param seed: the run's seed: of the Fourier features and of the Thompson heads' draws
        :param env_reward_timing: the reward timing the env declares (its ``metadata["reward_timing"]``),
            which ``reward_timing="auto"`` takes (None: see ``timing_for``)
        :return: the builder
        """
        low, high = self.state_box(observation_space)
        features: FeatureMap | None = None
        if linear_q or self.heads_use_features():
            features = (
                self.feature_map
                if isinstance(self.feature_map, FeatureMap)
                else make_feature_map(
                    self.feature_map,
                    low,
                    high,
                    rbf_per_dim=self.rbf_per_dim,
                    rbf_sigma=self.rbf_sigma,
                    rbf_overlap=self.rbf_overlap,
                    max_features=self.max_features,
                    fourier_features=self.fourier_features,
                    seed=0 if seed is None else seed,
                    n_actions=n_actions if linear_q else 0,
                    n_tasks=task_count_of(observation_space) if self.heads_use_features() else 0,
                    integer_states=np.issubdtype(state_space_of(observation_space).dtype, np.integer),
                )
            )
        return LearnerBuilder(self, low, high, n_actions, features, self.timing_for(env_reward_timing), seed)

    def timing_for(self, env_reward_timing: str | None) -> str:
        """
        The reward timing these settings give on an env that declares ``env_reward_timing`` (None: nothing):
        ``reward_timing`` unless it is ``"auto"``; else the declaration, or without one ``"step"`` for the
        heads that can learn it (``STEP_HEAD_NAMES``) and ``"next_state"`` for the others (a head instance
        included: it was built on states).

        :raises ValueError: when ``"auto"`` meets a declaration that is not one of ``REWARD_TIMINGS``
        """
        if self.reward_timing != "auto":
            return self.reward_timing
        if env_reward_timing is None:
            return "step" if self.reward_head in STEP_HEAD_NAMES else "next_state"
        if env_reward_timing not in REWARD_TIMINGS:
            raise ValueError(
                f"the env's metadata['reward_timing'] must be one of {list(REWARD_TIMINGS)}, "
                f"got {env_reward_timing!r}"
            )
        return env_reward_timing


@dataclass(frozen=True)
class LearnerBuilder:
    """
    What a ``TRLSDConfig`` builds for one env: its state box, the shared feature map, and task learners.

    :param config: the settings
    :param low: the state box's lower corner, (d,)
    :param high: its upper corner, (d,)
    :param n_actions: the env's actions
    :param features: Phi, shared by the linear Q and the feature heads (None when neither uses one)
    :param reward_timing: what of a transition its reward belongs to, one of ``REWARD_TIMINGS``
    :param seed: the run's seed (of the Thompson heads' draws, unless ``reward_head_kwargs`` gives theirs)
    """

    config: TRLSDConfig
    low: np.ndarray
    high: np.ndarray
    n_actions: int
    features: FeatureMap | None
    reward_timing: str
    seed: int | None = None

    def __post_init__(self) -> None:
        head, timing = self.config.reward_head, self.reward_timing
        if head == "known" and timing in ("transition", "step"):
            raise ValueError(
                "the 'known' reward_head takes the expected reward of one state, reward_fn(states, task): "
                f"use reward_timing='start_state' or 'next_state' with it, not {timing!r}"
            )
        if isinstance(head, str) and head not in STEP_HEAD_NAMES and timing == "step":
            raise ValueError(
                f"the {head!r} reward_head lays a grid of cells over states, not over actions: with "
                "reward_timing='step' use a head on features or similarities ('ridge', 'ridge_posterior', "
                "'thompson', 'bernstein')"
            )

    def new_reward_head(
        self, task: int, reward_fn: RewardFn | None = None, seed: int | None = None
    ) -> RewardHead:
        """
        A reward head for ``task`` with no samples: a copy of the config's ``RewardHead`` instance, or the
        named head with kappa, the shared features, the similarity's width and the head kwargs.

        :param task: the task
        :param reward_fn: the expected reward ``reward_fn(states, task)`` of the ``"known"`` head
        :param seed: the run's seed (None: the builder's), of a ``"thompson"`` head's draws
        :return: the head
        :raises ValueError: for the ``"known"`` head without a ``reward_fn``
        """
        config = self.config
        if isinstance(config.reward_head, RewardHead):
            return copy.deepcopy(config.reward_head)
        assert config.kappa is not None, "resolved when the settings are made"
        kwargs = dict(config.reward_head_kwargs or {})
        if config.reward_head == "known":
            if reward_fn is None:
                raise ValueError(
                    "the 'known' reward_head needs reward_fn=reward_fn(states, task) -> expected rewards "
                    "(n,), or an env whose unwrapped object has expected_reward(states, task)"
                )
            return make_reward_head("known", task=task, reward_fn=reward_fn, **kwargs)
        if config.reward_head == "thompson":
            kwargs.setdefault("seed", head_seed(self.seed if seed is None else seed, task))
        features = self.features
        if self.reward_timing in ("transition", "step") and features is not None:
            features = TransitionFeatures(features, self.n_actions if self.reward_timing == "step" else 0)
        low, high = input_box(self.low, self.high, self.reward_timing, self.n_actions)
        return make_reward_head(
            config.reward_head,
            task=task,
            features=features,
            state_space=spaces.Box(low, high, dtype=np.float64),
            kappa=config.kappa,
            sigma=self.similarity_width()  # type: ignore[arg-type]
            if config.reward_head in SIMILARITY_HEAD_NAMES
            else 0.2,
            similarity=config.similarity,
            **kwargs,
        )

    def similarity_width(self) -> float | np.ndarray:
        """
        The similarity width of the heads (``TRLSDConfig.similarity_width``) on their inputs: a state's
        widths, or those of a pair or a step (``input_widths``).
        """
        width = self.config.similarity_width(self.low, self.high)
        if isinstance(width, np.ndarray):
            return input_widths(width, self.reward_timing)
        return width  # eq. 7's, one width over feature vectors

    def new_task_learner(
        self, task: int, reward_fn: RewardFn | None = None, seed: int | None = None
    ) -> TaskLearner:
        """
        The learning state of ``task`` with no samples: its reward head (``new_reward_head``), the config's
        ``update_ratio``, ``first_fit``, ``refit_growth`` and ``optimism``, and the reward timing.

        :param task: the task
        :param reward_fn: see ``new_reward_head``
        :param seed: see ``new_reward_head``
        :return: the learner
        """
        config = self.config
        assert config.optimism is not None, "resolved when the settings are made"
        return TaskLearner(
            task,
            self.new_reward_head(task, reward_fn, seed),
            config.update_ratio,
            first_fit=config.first_fit,
            reward_timing=self.reward_timing,
            refit_growth=config.refit_growth,
            optimism=config.optimism,
        )
