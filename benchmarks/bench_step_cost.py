"""Milliseconds per online step of TRLSD, on every family of the MO-Gymnasium suite and on the paper's maze.

Each family: ``--source`` random source transitions (rewards discarded, the suite's source weights), then
``--steps`` online steps on the first evaluation task, driven through ``act`` / ``add_online_transition``
(the loop ``learn`` runs, without SB3's rollout machinery), with TRLSD's defaults and the family's state
bounds. Printed per family: ms per online step (the whole online phase over its steps: refits, relabelling,
features, the env), refits, the refits' mean Fitted-Q iterations and how many stopped at their cap, and the
feature count, and whether the step cost is within ``TARGET_MS``. ``--refit-threads`` sets the BLAS
threads of the refits (``sb3_trlsd.engine.REFIT_BLAS_THREADS``, 1) to compare them with the process's
(``--threads``). A timing, not a test: nothing is asserted. Usage::

    python benchmarks/bench_step_cost.py [--families four-room-v0 ...] [--source 25000] [--steps 1000]
        [--policy LinearPolicy] [--threads 2] [--refit-threads 1]
"""

from __future__ import annotations

import argparse
import warnings

import gymnasium as gym
import numpy as np
from threadpoolctl import threadpool_limits

import sb3_trlsd.engine
from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd.fqi import FQIResult
from sb3_trlsd_envs import MAZE_ID
from sb3_trlsd_lab.benchmarks.mo_suite.families import FAMILIES, available, collect_source, make_env
from sb3_trlsd_lab.execution.runner import run_online

TARGET_MS = 5.0  # per online step, averaged over 1,000 steps after 25,000 source rows, on 2 cores


def timed_online(model: TRLSD, env: gym.Env, n_steps: int, seed: int) -> dict[str, float]:
    """``n_steps`` online steps of ``model`` on ``env`` (the lab's loop): ms per step, what the refits did."""
    results: list[FQIResult] = []
    log_refit = model.engine.on_refit

    def record(run, learner, result, rewards):
        results.append(result)
        if log_refit is not None:
            log_refit(run, learner, result, rewards)

    model.engine.on_refit = record
    max_iterations = model.engine.max_iterations
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the cap's warning: counted below instead
        seconds = run_online(model, env, n_steps, seed, expected_rewards=False).seconds
    iterations = [result.iterations for result in results]
    return {
        "ms_per_step": 1000 * seconds / n_steps,
        "refits": len(results),
        "mean_iterations": float(np.mean(iterations)) if iterations else 0.0,
        "at_cap": sum(iteration >= max_iterations for iteration in iterations),
        "n_features": getattr(model.features, "n_features", 0),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--families", nargs="+", default=[*FAMILIES, "maze"])
    parser.add_argument("--source", type=int, default=25_000, help="source transitions")
    parser.add_argument("--steps", type=int, default=1_000, help="online steps")
    parser.add_argument("--threads", type=int, default=2, help="BLAS threads")
    parser.add_argument("--refit-threads", type=int, default=None, help="BLAS threads of the refits")
    parser.add_argument("--policy", default="LinearPolicy", choices=["LinearPolicy", "MlpPolicy"])
    args = parser.parse_args()
    if args.refit_threads is not None:
        sb3_trlsd.engine.REFIT_BLAS_THREADS = args.refit_threads
    print(
        f"{'family':<24} {'ms/step':>8} {'refits':>7} {'FQI its':>8} {'at cap':>7} {'features':>9} "
        f"{f'<= {TARGET_MS:g} ms':>10}"
    )
    with threadpool_limits(args.threads):
        for name in args.families:
            if name == "maze":
                env = gym.make(MAZE_ID, task=0)
                source = collect_transitions(gym.make(MAZE_ID, task=12), args.source, seed=1)
                model = TRLSD(args.policy, env, seed=0)
            else:
                family = FAMILIES[name]
                if not available(family):
                    print(f"{name:<24} (not installed here)")
                    continue
                task = int(family.tasks_of("evaluation")[0])
                env = make_env(family, task)
                source = collect_source(family, args.source, seed=1).transitions
                model = TRLSD(args.policy, env, seed=0, state_bounds=family.state_bounds)
            model.load_transitions(source, keep_rewards=False)
            row = timed_online(model, env, args.steps, seed=0)
            print(
                f"{name:<24} {row['ms_per_step']:>8.1f} {row['refits']:>7d} {row['mean_iterations']:>8.1f} "
                f"{row['at_cap']:>7d} {row['n_features']:>9d} "
                f"{'yes' if row['ms_per_step'] <= TARGET_MS else 'NO':>10}",
                flush=True,
            )


if __name__ == "__main__":
    main()
