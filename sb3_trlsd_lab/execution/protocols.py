"""
The choices the paper leaves open and a reproduction has to make, as one value each (a ``Protocol``), and
named sets of them (``PRESETS``) that ``sb3-trlsd reproduce --protocol NAME`` runs a figure under.

The choices, with the options a careful reader of the paper could defend (today's first):

1. Restarts in the online phase (``online_termination_prob``). Section 4 gives the 2% chance of a reset
   after each transition for the random source set only; the 1,000 online transitions may have had them
   too (0.02) or been one trajectory (0). Restarts are free exploration for the non-optimistic agent.
2. The discount factor (``gamma``): never given. 0.9 (~10 steps, the longest path round the walls), 0.95
   or 0.99 (the usual defaults of RL libraries).
3. The start state of each multi-task trajectory (``multitask_start``, Figure 8): uniform in the maze as
   the source set's, where that task's previous trajectory ended (``"continue"``: no reset is mentioned
   between turns), or one fixed state.
4. Eq. 9 where W -> 0 (``w_floor``, ``r_max``): W floored at 1e-6, a finite stand-in for UCB's infinite
   optimism, or R~ capped at the reward's upper bound R_max (1 on the maze), which the introduction names as
   expert knowledge.
5. log|Xi_tau| at small counts (``log_count``, a rule of ``LOG_COUNT_RULES``): log(max(n, 2)), log(n + 1)
   or log(max(n, 1)) (``sb3_trlsd.reward_heads.base`` defends each).
6. The first fit of a task (``first_fit``): at its first step, on the optimism of a head with no sample,
   or once its first sample (and reward) is in.
7. Source sets (``source_sets``): one shared by each batch of runs (20 per method of a figure, see
   ``batches.py``), or one per run, as "500 independent runs" can be read.
8. R~ of an unvisited cell in the discrete setting (``tabular_unvisited``): eq. 10 with the count floored
   (an unvisited cell outranks every visited one), or a value, R-MAX's R_max = 1.

Besides those choices, how each refit reaches Fitted-Q's fixed point (``fqi_solver``, a name of
``sb3_trlsd.fqi.SOLVERS``, None for the policy's): exact evaluations of the greedy policy
(``"policy_iteration"``, the linear Q's default) or the fitted iterations alone (``"iterations"``).

Presets: today's choices (``"as-built"``: the library's defaults), one preset per single change from them,
and the study's best-supported combination (``"no-restarts"``: the online phases without restarts), which
``reproduce`` runs unless told otherwise (``DEFAULT_PROTOCOL``). A
``Protocol`` is passed explicitly down to the envs and models a figure builds (``runner.Method.make_model``,
``batches.transfer_batch``, ``runner.multitask_env``); a figure's JSON records it (``protocol_record``). The
run cache keys each run on the choices that reach it (``Protocol.reaching``): a preset's runs of the methods
it does not reach are today's runs, kept once, so a figure under it reruns only what it changes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from sb3_trlsd.fqi import SOLVERS
from sb3_trlsd.reward_heads.base import DEFAULT_LOG_COUNT_RULE, DEFAULT_W_FLOOR, check_log_count_rule
from sb3_trlsd.task_learner import FIRST_FIT_RULES
from sb3_trlsd_envs.maze import check_start

__all__ = [
    "AS_BUILT",
    "AS_BUILT_NAME",
    "DEFAULT_PROTOCOL",
    "PRESETS",
    "SOURCE_SET_RULES",
    "Preset",
    "Protocol",
    "paper_relabelling",
    "protocol_named",
    "protocol_record",
]

SOURCE_SET_RULES = ("per_batch", "per_run")
TABULAR_HEADS = ("tabular", "corners")  # the discrete settings, where ``tabular_unvisited`` applies
# The heads with a floor on W or N, where ``w_floor`` applies (the linear-posterior heads need none).
FLOORED_HEADS = ("ridge", *TABULAR_HEADS, "bernstein")
MAZE_CENTRE = (2.5, 2.5)  # the fixed start: as far from each corner as from the others
MAZE_R_MAX = 1.0  # the largest expected reward of the maze (eq. 12): 1 in the task's cell


def paper_relabelling(reward_head: str) -> dict[str, Any]:
    """
    ``TRLSD`` settings that give a named head the paper's relabelling whatever the library's defaults are:
    R~ on every row of the buffer (``optimism="always"``, Algorithm 1) and, for posterior draws, kappa in the
    env's reward units (``kappa_scale="reward"``).

    :param reward_head: a head name ``TRLSD`` takes
    :return: ``reward_head``, ``optimism`` and ``reward_head_kwargs``
    """
    head_kwargs = {"kappa_scale": "reward"} if reward_head == "thompson" else {}
    return {"reward_head": reward_head, "optimism": "always", "reward_head_kwargs": head_kwargs}


def _finite_or_none(name: str, value: float | None) -> None:
    if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
        raise ValueError(f"{name} must be a finite number or None, got {value!r}")


@dataclass(frozen=True)
class Protocol:
    """
    One value for each choice the paper leaves open (see the module docstring); the defaults are today's.

    :param online_termination_prob: chance of a restart after each online transition of a transfer run
    :param gamma: the discount factor of Fitted-Q Iteration, in (0, 1)
    :param multitask_start: start of each multi-task trajectory: ``"uniform"``, ``"continue"`` or a state
        ``(x, y)`` (``SharedDynamicsMaze``'s ``start``)
    :param w_floor: floor on W (eq. 9) and N (eq. 10), > 0
    :param r_max: cap on R~ of the ridge and tabular heads (None: none)
    :param log_count: how log|Xi_tau| is taken at small counts, one of ``LOG_COUNT_RULES``
    :param first_fit: when a task is first fitted, one of ``FIRST_FIT_RULES``
    :param source_sets: ``"per_batch"`` (a source set shared by the runs of a batch) or ``"per_run"``
    :param tabular_unvisited: R~ of an unvisited cell of the tabular heads (None: eq. 10 with the floor)
    :param fqi_solver: how a refit reaches Fitted-Q's fixed point, one of ``sb3_trlsd.fqi.SOLVERS`` (None:
        the policy's)
    """

    online_termination_prob: float = 0.02
    gamma: float = 0.9
    multitask_start: str | tuple[float, float] = "uniform"
    w_floor: float = DEFAULT_W_FLOOR
    r_max: float | None = None
    log_count: str = DEFAULT_LOG_COUNT_RULE
    first_fit: str = "first_step"
    source_sets: str = "per_batch"
    tabular_unvisited: float | None = None
    fqi_solver: str | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.online_termination_prob <= 1:
            raise ValueError(
                "online_termination_prob must be a probability in [0, 1], "
                f"got {self.online_termination_prob!r}"
            )
        if not 0 < self.gamma < 1:
            raise ValueError(f"gamma must be in (0, 1), got {self.gamma!r}")
        object.__setattr__(self, "multitask_start", check_start(self.multitask_start))
        if not (isinstance(self.w_floor, (int, float)) and self.w_floor > 0 and math.isfinite(self.w_floor)):
            raise ValueError(f"w_floor must be a finite number > 0, got {self.w_floor!r}")
        _finite_or_none("r_max", self.r_max)
        _finite_or_none("tabular_unvisited", self.tabular_unvisited)
        check_log_count_rule(self.log_count)
        if self.first_fit not in FIRST_FIT_RULES:
            raise ValueError(f"first_fit must be one of {list(FIRST_FIT_RULES)}, got {self.first_fit!r}")
        if self.source_sets not in SOURCE_SET_RULES:
            raise ValueError(f"source_sets must be one of {list(SOURCE_SET_RULES)}, got {self.source_sets!r}")
        if self.fqi_solver is not None and self.fqi_solver not in SOLVERS:
            raise ValueError(f"fqi_solver must be one of {list(SOLVERS)}, got {self.fqi_solver!r}")

    def choices(self) -> dict[str, Any]:
        """The choices as a dict (for a figure's JSON)."""
        return asdict(self)

    def target_env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the maze of a transfer run's online phase."""
        return {"termination_prob": self.online_termination_prob}

    def multitask_env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the maze of a multi-task run (Figure 8), besides its tasks and time limit."""
        return {"start": self.multitask_start}

    def head_kwargs(self, reward_head: str) -> dict[str, Any]:
        """
        The ``reward_head_kwargs`` of a TRLSD model with the named head: the choices that differ from the
        heads' own defaults, for the heads they apply to (none for the known reward, no ``w_floor`` for the
        linear-posterior heads, which have no floor).

        :param reward_head: a head name ``TRLSD`` takes
        :return: keyword arguments of ``make_reward_head``
        """
        if reward_head == "known":
            return {}
        kwargs: dict[str, Any] = {}
        if self.w_floor != DEFAULT_W_FLOOR and reward_head in FLOORED_HEADS:
            kwargs["w_floor"] = self.w_floor
        if self.r_max is not None:
            kwargs["r_max"] = self.r_max
        if self.log_count != DEFAULT_LOG_COUNT_RULE:
            kwargs["log_count"] = self.log_count
        if self.tabular_unvisited is not None and reward_head in TABULAR_HEADS:
            kwargs["unvisited_value"] = self.tabular_unvisited
        return kwargs

    def model_kwargs(self, reward_head: str) -> dict[str, Any]:
        """
        Keyword arguments of a ``TRLSD`` model with the named head: ``gamma``, ``first_fit``,
        ``reward_head_kwargs`` (``head_kwargs``) and ``fqi_solver``, with the paper's features (``"paper"``:
        5 x 5 RBFs of width 0.2 on the maze), Fitted-Q's stopping rule on theta, a refit as soon as the
        trigger fires, the first of tied greedy actions and the greedy policy throughout (no epsilon-greedy
        steps), which the library's defaults are not.

        :param reward_head: a head name ``TRLSD`` takes
        """
        return {
            "gamma": self.gamma,
            "first_fit": self.first_fit,
            "reward_head_kwargs": self.head_kwargs(reward_head),
            "feature_map": "paper",
            "fqi_stop": "theta",
            "fqi_solver": self.fqi_solver,
            "refit_growth": 0.0,
            "tie_break": "first",
            "exploration_initial_eps": 0.0,
        }

    def run_inputs(self, reward_head: str, multitask: bool) -> tuple:
        """
        Everything of this protocol that a figure's run is built from: its env's keyword arguments, its
        model's, and for a transfer run its source sets.

        :param reward_head: the run's head name
        :param multitask: a multi-task run (Figure 8) rather than a transfer run
        """
        if multitask:
            return self.multitask_env_kwargs(), self.model_kwargs(reward_head)
        return self.target_env_kwargs(), self.source_sets, self.model_kwargs(reward_head)

    def reaching(self, reward_head: str, multitask: bool = False) -> Protocol:
        """
        This protocol with only the choices that reach a run of ``reward_head``, the others at today's
        values: a run with the same inputs (``run_inputs``) is the same run. A run's kept file is keyed on
        this, so a figure under a preset reuses today's runs of the methods that the preset does not reach
        (e.g. ``multitask-fixed-start`` reaches no transfer run, ``tabular-unvisited-r-max`` only the
        discrete heads).

        :param reward_head: the run's head name
        :param multitask: a multi-task run (Figure 8) rather than a transfer run
        :return: a protocol with the same ``run_inputs``
        """
        today = Protocol()
        inputs = self.run_inputs(reward_head, multitask)
        today_inputs = today.run_inputs(reward_head, multitask)
        reaching = {
            choice.name: getattr(self, choice.name)
            for choice in fields(self)
            if replace(today, **{choice.name: getattr(self, choice.name)}).run_inputs(reward_head, multitask)
            != today_inputs
        }
        projected = replace(today, **reaching)
        if projected.run_inputs(reward_head, multitask) != inputs:  # choices that reach only together
            return self
        return projected


AS_BUILT = Protocol()
AS_BUILT_NAME = "as-built"  # today's choices, the baseline every single change is made from
# What ``reproduce`` runs without ``--protocol``: the study's best-supported reading (see the README).
DEFAULT_PROTOCOL = "no-restarts"


@dataclass(frozen=True)
class Preset:
    """
    A named protocol.

    :param name: what ``--protocol`` takes
    :param protocol: its choices
    :param changes: what it changes from today's protocol
    :param why: why a careful reader of the paper could defend it
    :param combines: for a combination of single changes, the presets whose choices it takes (each choice
        reaching other figures than the others', a combination's runs of a figure are those of the preset
        that reaches it, kept under the same key: ``Protocol.reaching``)
    """

    name: str
    protocol: Protocol
    changes: str
    why: str
    combines: tuple[str, ...] = ()


PRESETS: dict[str, Preset] = {
    preset.name: preset
    for preset in (
        Preset(
            AS_BUILT_NAME,
            AS_BUILT,
            "nothing (today's choices, those of the README's figures)",
            "the reproduction's own reading: 2% online restarts as in the source set, gamma = 0.9, uniform "
            "multi-task starts, W floored at 1e-6, log(max(n, 2)), a task fitted at its first step, a source "
            "set per batch of runs, unvisited cells floored",
        ),
        Preset(
            "no-online-restarts",
            Protocol(online_termination_prob=0.0),
            "no restart in the online phase of a transfer run: its 1,000 transitions are one trajectory",
            "section 4 states the 2% resets for the random source set only, and the online phase as 'the "
            "gathering of 1,000 transitions on the target task'",
        ),
        Preset(
            "gamma-0.95",
            Protocol(gamma=0.95),
            "gamma = 0.95",
            "the paper gives no discount factor; 0.95 is a common choice (a horizon of ~20 steps)",
        ),
        Preset(
            "gamma-0.99",
            Protocol(gamma=0.99),
            "gamma = 0.99",
            "the paper gives no discount factor; 0.99 is the default of most RL libraries (SB3's included)",
        ),
        Preset(
            "multitask-continue",
            Protocol(multitask_start="continue"),
            "each multi-task trajectory starts where that task's previous one ended (uniform the first time)",
            "section 4 runs the tasks 'in turns' and mentions no reset between a task's trajectories",
        ),
        Preset(
            "multitask-fixed-start",
            Protocol(multitask_start=MAZE_CENTRE),
            f"every multi-task trajectory starts at the maze's centre {MAZE_CENTRE}",
            "the episodic convention of navigation tasks, one start for every episode; the paper gives none",
        ),
        Preset(
            "r-max-clip",
            Protocol(r_max=MAZE_R_MAX),
            f"R~ of the ridge and tabular heads capped at R_max = {MAZE_R_MAX:g} (R^ too when kappa = 0)",
            "the introduction names the bounds R_min and R_max as expert knowledge, and UCRL's optimistic "
            "reward stays within the reward's range; the floor then no longer shows in R~",
        ),
        Preset(
            "log-count-plus-one",
            Protocol(log_count="plus_1"),
            "log|Xi_tau| taken as log(n + 1): 0 with no sample, then log 2, log 3, ...",
            "the smoothing UCB-style bounds often use, continuous in n; eq. 9 and 10 leave n <= 1 undefined",
        ),
        Preset(
            "log-count-at-least-one",
            Protocol(log_count="at_least_1"),
            "log|Xi_tau| taken as log(max(n, 1)): no optimism before a task's second sample",
            "eq. 9 and 10 as written, with log 0 read as 0 (no count, no bonus)",
        ),
        Preset(
            "first-fit-after-sample",
            Protocol(first_fit="first_sample"),
            "a task is first fitted once its first sample is in, not before its first action",
            "with no sample R~ is the same everywhere, so a fit then carries no information about the task; "
            "Algorithm 1 learns R~ on Xi_tau, empty before the first sample",
        ),
        Preset(
            "source-set-per-run",
            Protocol(source_sets="per_run"),
            "every transfer run draws a source set of its own (standard errors over runs)",
            "'500 independent runs' (Figure 5), each 'first' generating its 25,000 transitions",
        ),
        Preset(
            "no-restarts",
            Protocol(online_termination_prob=0.0, multitask_start="continue"),
            "no restart in any online phase: a transfer run's 1,000 transitions are one trajectory, and each "
            "multi-task trajectory starts where that task's previous one ended",
            "the study's best-supported reading (README, 'What the paper's claims depend on'): the two "
            "single changes that bring the paper's orderings back in Figures 5-8, read together; neither "
            "restart is stated for an online phase",
            combines=("no-online-restarts", "multitask-continue"),
        ),
        Preset(
            "policy-iteration",
            Protocol(fqi_solver="policy_iteration"),
            "each refit reaches Fitted-Q's fixed point by exact evaluations of the greedy policy (LSTD-Q)",
            "the paper fits by Fitted-Q Iteration without saying how far: policy iteration reaches the same "
            "fixed point exactly, in fewer passes over the buffer",
        ),
        Preset(
            "tabular-unvisited-r-max",
            Protocol(tabular_unvisited=MAZE_R_MAX),
            f"R~ of an unvisited cell of the discrete heads is R_max = {MAZE_R_MAX:g} (kappa > 0)",
            "eq. 10 is undefined with no visit; R-MAX (cited by the paper) values unknown states at R_max",
        ),
    )
}


def protocol_named(name: str) -> Protocol:
    """
    The protocol of a preset.

    :param name: a name of ``PRESETS``
    :return: its choices
    :raises ValueError: naming ``protocol`` and the presets, for another name
    """
    if name not in PRESETS:
        raise ValueError(f"protocol must be one of {', '.join(PRESETS)}, got {name!r}")
    return PRESETS[name].protocol


def protocol_record(protocol: Protocol) -> dict[str, Any]:
    """
    What a figure's JSON says of its protocol: the preset's name (``"custom"`` for choices no preset has),
    what it changes, and every choice.

    :param protocol: the protocol the figure ran under
    :return: ``{"name", "changes", "choices"}``
    """
    preset = next((preset for preset in PRESETS.values() if preset.protocol == protocol), None)
    return {
        "name": "custom" if preset is None else preset.name,
        "changes": "" if preset is None else preset.changes,
        "choices": protocol.choices(),
    }
