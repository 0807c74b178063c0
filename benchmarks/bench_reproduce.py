"""Seconds per run of every Figure 5 method, and of Figure 8's, batched in lockstep and one run at a time.

The one-run-at-a-time path is ``TRLSD`` itself driven alone (``transfer_run``, ``multitask_run``: the
reference the equivalence tests compare the batches with); the batched path is what ``reproduce`` runs
(``transfer_batch``: one source set shared by a batch of consecutive runs stepped in lockstep,
``multitask_batch``). Both run here, in one process with one BLAS thread as the experiments' workers do, on
tasks 0, 1, ... and seeds 0, 1, ...; their mean rewards are printed for reference only (the runs alone are
the first tasks with a source set each, the batch all its tasks on one source set: the equivalence of the
two paths is tested on equal inputs in ``tests/test_lockstep.py``, not here). From the
seconds per run, the full Figure 5 (500 runs of each of its 6 methods) and Figure 8 (200 runs of each of
its 3 methods) are extrapolated for ``--workers`` processes. Nothing about time is asserted. Usage::

    python benchmarks/bench_reproduce.py [--alone-runs 5] [--batch-runs 25] [--fig8-runs 2] [--workers 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from sb3_trlsd_lab.execution.batches import multitask_batch, transfer_batch
from sb3_trlsd_lab.execution.runner import Method, RunRecord, multitask_run, transfer_run
from sb3_trlsd_lab.paper import multitask, transfer


def timed(function, *args, **kwargs) -> tuple[float, list[RunRecord]]:
    """Wall seconds of one call, and its records as a list."""
    start = time.perf_counter()
    result = function(*args, **kwargs)
    return time.perf_counter() - start, result if isinstance(result, list) else [result]


def transfer_seconds(method: Method, alone_runs: int, batch_runs: int) -> tuple[float, float, float, float]:
    """Seconds per run alone and batched, and the mean rewards of each (tasks 0, 1, ..., seeds 0, 1, ...)."""
    alone_seconds, alone = 0.0, []
    for run in range(alone_runs):
        seconds, records = timed(transfer_run, method, run % 25, run)
        alone_seconds, alone = alone_seconds + seconds, alone + records
    tasks, seeds = tuple(run % 25 for run in range(batch_runs)), tuple(range(batch_runs))
    batch_seconds, batch = timed(transfer_batch, method, tasks, seeds, 0, 25_000, 1_000)
    return (
        alone_seconds / alone_runs,
        batch_seconds / batch_runs,
        float(np.mean([record.rewards.mean() for record in alone])),
        float(np.mean([record.rewards.mean() for record in batch])),
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--alone-runs", type=int, default=5, help="runs of each method one at a time")
    parser.add_argument("--batch-runs", type=int, default=25, help="runs of the batch of each method")
    parser.add_argument("--fig8-runs", type=int, default=2, help="Figure 8 runs alone, and in its batch")
    parser.add_argument(
        "--workers", type=int, default=2, help="processes the full figures are extrapolated to"
    )
    args = parser.parse_args()

    print(
        f"Figure 5 methods: {args.alone_runs} runs alone, a batch of {args.batch_runs} runs (one source "
        "set), 25,000 source + 1,000 online transitions, one BLAS thread\n"
    )
    print("| method | s / run alone | s / run batched | ratio | mean reward alone | batched |")
    print("|---|---|---|---|---|---|")
    totals = np.zeros(2)
    with threadpool_limits(1):
        for method in transfer.METHODS:
            alone_s, batch_s, alone_reward, batch_reward = transfer_seconds(
                method, args.alone_runs, args.batch_runs
            )
            totals += alone_s, batch_s
            print(
                f"| {method.label} | {alone_s:.3f} | {batch_s:.3f} | {alone_s / batch_s:.1f}x "
                f"| {alone_reward:.3f} | {batch_reward:.3f} |"
            )
        fig8 = Method("similarity on states (eq. 6)")
        fig8_alone, _ = timed(lambda: [multitask_run(fig8, seed) for seed in range(args.fig8_runs)])
        fig8_batch, _ = timed(multitask_batch, fig8, tuple(range(args.fig8_runs)))
    fig8_alone, fig8_batch = fig8_alone / args.fig8_runs, fig8_batch / args.fig8_runs
    print(
        f"| Figure 8, {fig8.label} ({args.fig8_runs} runs) | {fig8_alone:.2f} | {fig8_batch:.2f} "
        f"| {fig8_alone / fig8_batch:.1f}x | | |"
    )
    fig5_runs = transfer.DEFAULT_RUNS
    fig8_runs = multitask.DEFAULT_RUNS * len(multitask.METHODS)
    workers = args.workers
    for name, seconds in (("one at a time", totals[0]), ("batched", totals[1])):
        print(f"\nfull Figure 5 {name}: {seconds * fig5_runs / workers / 60:.1f} min with {workers} workers")
    for name, seconds in (("one at a time", fig8_alone), ("batched", fig8_batch)):
        print(
            f"full Figure 8 {name}: {seconds * fig8_runs / workers / 60:.1f} min with {workers} workers "
            f"(every method costed as {fig8.label})"
        )


if __name__ == "__main__":
    main()
