"""The tuning protocol of TRLSD's defaults on the MO-Gymnasium suite: candidates scored on the TUNING weights.

Each candidate is a set of TRLSD settings. It runs on every family of the suite (those that can run here), on
the family's tuning target weights (disjoint from the evaluation weights the suite reports), with the same
source transitions, seeds and budget as the suite, next to the random policy on the same runs. Printed per
candidate and family: the mean gain over random (paired) ± standard error and ms per online step; and per
candidate the number of families where the gain is above 0 by 2 standard errors, and the mean over families
of the gain divided by the family's scale (``family_scale``: the spread of its gains across candidates, at
least twice their median standard error, so that no family's reward scale decides alone and differences
within the noise are not magnified). A timing and a comparison, not a test. Usage::

    python benchmarks/tune_suite.py [--runs 8] [--workers 2] [--families ...] [--out results/tuning]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd.atomic_files import atomic_write
from sb3_trlsd_lab.benchmarks.mo_suite.families import FAMILIES, available
from sb3_trlsd_lab.benchmarks.mo_suite.peers import SETTABLE
from sb3_trlsd_lab.benchmarks.mo_suite.suite import family_scale, suite_run
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.protocols import paper_relabelling

# The ridge head without optimism, which every candidate below but the draws varies one setting of: TRLSD's
# defaults when these candidates were first scored (the stored results call it "defaults" up to the 16-run
# scoring of the draws, after which the draws became the defaults).
RIDGE: dict[str, Any] = {"reward_head": "ridge"}


def draws_in_reward_units(kappa: float) -> dict[str, Any]:
    """Posterior draws of scale ``kappa`` in the env's reward units, relabelling every row (the paper's)."""
    return {**paper_relabelling("thompson"), "kappa": kappa}


# Each candidate: TRLSD's settings other than its defaults ({}: the defaults as they are).
CANDIDATES: dict[str, dict[str, Any]] = {
    "defaults": {},
    "ridge": RIDGE,
    "kappa=1": {**RIDGE, "kappa": 1.0},
    "kappa=0.1": {**RIDGE, "kappa": 0.1},
    "kappa=0.03": {**RIDGE, "kappa": 0.03},
    "kappa=0.01": {**RIDGE, "kappa": 0.01},
    "reward_timing=start_state": {**RIDGE, "reward_timing": "start_state"},
    "reward_timing=next_state": {**RIDGE, "reward_timing": "next_state"},
    "reward_timing=transition": {**RIDGE, "reward_timing": "transition"},
    "reward_timing=step": {**RIDGE, "reward_timing": "step"},
    "tie_break=first": {**RIDGE, "tie_break": "first"},
    "feature_map=paper": {**RIDGE, "feature_map": "paper"},
    # On integer states: "auto" as on real states (a budget under the lattice's points), or the lattice by
    # name (integer-state families only: four-room, resource-gathering, deep-sea treasure).
    "max_features=64": {**RIDGE, "max_features": 64},
    "feature_map=lattice": {**RIDGE, "feature_map": "lattice"},
    "refit_growth=0": {**RIDGE, "refit_growth": 0.0},
    "refit_growth=0.2": {**RIDGE, "refit_growth": 0.2},
    "refit_growth=0.3": {**RIDGE, "refit_growth": 0.3},
    # Posterior sampling of the ridge weights (a random deviation per refit, not a bonus), at four scales.
    "thompson,kappa=0.1": draws_in_reward_units(0.1),
    "thompson,kappa=0.01": draws_in_reward_units(0.01),
    "thompson,kappa=0.003": draws_in_reward_units(0.003),
    "thompson,kappa=0.03": draws_in_reward_units(0.03),
    # The draws in units of the largest reward seen, relabelling only once the buffer holds rows the task
    # did not collect (R^ before): the defaults at 0.01, and at two other scales.
    "thompson,kappa=0.01,observed,with_source": {},
    "thompson,kappa=0.003,observed,with_source": {"kappa": 0.003},
    "thompson,kappa=0.03,observed,with_source": {"kappa": 0.03},
    # The settings tuned under the ridge head, one at a time again under the draws (the defaults).
    "draws,exploration_steps=250": {"exploration_steps": 250},
    "draws,exploration_steps=1000": {"exploration_steps": 1000},
    "draws,exploration_final_eps=0.05": {"exploration_final_eps": 0.05},
    "draws,refit_growth=0": {"refit_growth": 0.0},
    "draws,refit_growth=0.3": {"refit_growth": 0.3},
    "draws,update_ratio=4": {"update_ratio": 4.0},
    "draws,reward_timing=transition": {"reward_timing": "transition"},
    # Epsilon-greedy over each task's first steps: none (the greedy policy), or over other spans.
    "exploration_initial_eps=0": {**RIDGE, "exploration_initial_eps": 0.0},
    "exploration_steps=100": {**RIDGE, "exploration_steps": 100},
    "exploration_steps=250": {**RIDGE, "exploration_steps": 250},
    "exploration_final_eps=0.1": {**RIDGE, "exploration_final_eps": 0.1},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--families", nargs="+", default=[name for name, f in FAMILIES.items() if available(f)]
    )
    parser.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES))
    parser.add_argument("--runs", type=int, default=8, help="runs per candidate and family")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("results/tuning"))
    parser.add_argument("--cache", type=Path, default=None, help="directory of finished runs to reuse")
    parser.add_argument(
        "--method",
        default="trlsd",
        choices=list(SETTABLE),
        help="TRLSD, or TRLSD given the source's true rewards (the reference: which settings let it learn)",
    )
    args = parser.parse_args()
    methods = [("random", None)] + [(args.method, name) for name in args.candidates]
    jobs = [
        (
            (name, method, run, 0, "tuning", FAMILIES[name].n_source, FAMILIES[name].n_online),
            {"settings": CANDIDATES[candidate]} if candidate else {},
        )
        for name in args.families
        for method, candidate in methods
        for run in range(args.runs)
    ]
    rows = run_jobs(suite_run, jobs, args.workers, description="tuning runs", cache=args.cache)
    gains: dict[str, dict[str, tuple[float, float, float]]] = {}
    i = 0
    for name in args.families:
        random_rows = rows[i : i + args.runs]
        i += args.runs
        for candidate in args.candidates:
            runs = rows[i : i + args.runs]
            i += args.runs
            gain = np.array([r["score"] - f["score"] for r, f in zip(runs, random_rows, strict=True)])
            ms = float(np.mean([r["online_ms_per_step"] for r in runs]))
            se = float(gain.std(ddof=1) / np.sqrt(len(gain))) if len(gain) > 1 else 0.0
            gains.setdefault(candidate, {})[name] = (float(gain.mean()), se, ms)
    print(f"{'candidate':<28}" + "".join(f"{name[:18]:>26}" for name in args.families))
    for candidate, by_family in gains.items():
        cells = "".join(f"{f'{m:+.3f} ± {s:.3f} ({ms:.1f} ms)':>26}" for m, s, ms in by_family.values())
        print(f"{candidate:<28}{cells}")
    spreads = {
        name: family_scale(*np.array([gains[c][name][:2] for c in args.candidates]).T)
        for name in args.families
    }
    print("\ncandidate                    above random by 2 SE   mean gain / family scale")
    for candidate, by_family in gains.items():
        above = sum(m - 2 * s > 0 for m, s, _ in by_family.values())
        scaled = np.mean([by_family[name][0] / spreads[name] for name in args.families])
        print(f"{candidate:<28} {above:>10d} of {len(args.families)} {scaled:>26.3f}")
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.out / "tuning.json", "w") as file:
        file.write(json.dumps({"runs": args.runs, "candidates": CANDIDATES, "gains": gains}, indent=1))


if __name__ == "__main__":
    main()
