"""Seconds per run of every Figure 5 method, and of Figure 8's, batched in lockstep and one run at a time,
under a protocol of ``sb3-trlsd reproduce`` (default: its own) and each Fitted-Q solver.

The one-run-at-a-time path is ``TRLSD`` itself driven alone (``transfer_run``, ``multitask_run``: the
reference the equivalence tests compare the batches with); the batched path is what ``reproduce`` runs
(``transfer_batch``: one source set shared by a batch of consecutive runs stepped in lockstep,
``multitask_batch``). Both run here, in one process with one BLAS thread as the experiments' workers do, on
tasks 0, 1, ... and seeds 0, 1, ...; their mean rewards are printed for reference only (the runs alone are
the first tasks with a source set each, the batch all its tasks on one source set: the equivalence of the
two paths is tested on equal inputs in ``tests/test_lockstep.py``, not here). From the
seconds per run, the full Figure 5 (500 runs of each of its 6 methods) and Figure 8 (200 runs of each of
its 3 methods) are extrapolated for ``--workers`` processes, for each ``fqi_solver`` of ``--solvers``,
with their ratio against the fitted iterations and the mean passes over the rows per refit. Nothing about
time is asserted. Usage::

    python benchmarks/bench_reproduce.py [--alone-runs 5] [--batch-runs 25] [--fig8-runs 2] [--workers 2]
        [--protocol no-restarts] [--solvers iterations,policy_iteration]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
from threadpoolctl import threadpool_limits

import sb3_trlsd.q_functions
from sb3_trlsd.fqi import SOLVERS
from sb3_trlsd_lab.execution.batches import multitask_batch, transfer_batch
from sb3_trlsd_lab.execution.protocols import DEFAULT_PROTOCOL, PRESETS, Protocol, protocol_named
from sb3_trlsd_lab.execution.runner import Method, RunRecord, multitask_run, transfer_run
from sb3_trlsd_lab.paper import multitask, transfer

PASSES: list[int] = []  # the iterations of every batched refit, as fit_linear_fqi_runs reports them


def counting_fits():
    """Record the iterations of the batches' fits (``LinearRunsQFunctions`` calls ``fit_linear_fqi_runs``)."""
    fit = sb3_trlsd.q_functions.fit_linear_fqi_runs

    def counted(*args, **kwargs):
        results = fit(*args, **kwargs)
        PASSES.extend(result.iterations for result in results)
        return results

    sb3_trlsd.q_functions.fit_linear_fqi_runs = counted


def timed(function, *args, **kwargs) -> tuple[float, list[RunRecord]]:
    """Wall seconds of one call, and its records as a list."""
    start = time.perf_counter()
    result = function(*args, **kwargs)
    return time.perf_counter() - start, result if isinstance(result, list) else [result]


def transfer_seconds(
    method: Method, alone_runs: int, batch_runs: int, protocol: Protocol
) -> tuple[float, float, float, float]:
    """Seconds per run alone and batched, and the mean rewards of each (tasks 0, 1, ..., seeds 0, 1, ...)."""
    alone_seconds, alone = 0.0, []
    for run in range(alone_runs):
        seconds, records = timed(transfer_run, method, run % 25, run, protocol=protocol)
        alone_seconds, alone = alone_seconds + seconds, alone + records
    tasks, seeds = tuple(run % 25 for run in range(batch_runs)), tuple(range(batch_runs))
    reaching = protocol.reaching(method.reward_head)
    batch_seconds, batch = timed(transfer_batch, method, tasks, seeds, 0, 25_000, 1_000, protocol=reaching)
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
    parser.add_argument("--protocol", default=DEFAULT_PROTOCOL, choices=list(PRESETS), help="the protocol")
    parser.add_argument(
        "--solvers",
        default=",".join(reversed(SOLVERS)),
        help="the fqi_solver values to time, comma-separated",
    )
    args = parser.parse_args()
    counting_fits()
    minutes: dict[str, tuple[float, float]] = {}
    for solver in args.solvers.split(","):
        protocol = dataclasses.replace(protocol_named(args.protocol), fqi_solver=solver)
        print(f"\n## protocol {args.protocol}, fqi_solver={solver}\n")
        minutes[solver] = time_figures(args, protocol)
    if "iterations" in minutes:
        for solver, (fig5, fig8) in minutes.items():
            base5, base8 = minutes["iterations"]
            print(
                f"\n{solver}: Figure 5 {base5 / fig5:.2f}x, Figure 8 {base8 / fig8:.2f}x "
                "the fitted iterations' speed"
            )


def time_figures(args: argparse.Namespace, protocol: Protocol) -> tuple[float, float]:
    """Print the table and the extrapolated figures under one protocol; return their batched minutes."""
    PASSES.clear()
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
                method, args.alone_runs, args.batch_runs, protocol
            )
            totals += alone_s, batch_s
            print(
                f"| {method.label} | {alone_s:.3f} | {batch_s:.3f} | {alone_s / batch_s:.1f}x "
                f"| {alone_reward:.3f} | {batch_reward:.3f} |"
            )
        fig5_passes = float(np.mean(PASSES)) if PASSES else 0.0
        PASSES.clear()
        fig8 = Method("similarity on states (eq. 6)")
        fig8_alone, _ = timed(
            lambda: [multitask_run(fig8, seed, protocol=protocol) for seed in range(args.fig8_runs)]
        )
        fig8_batch, _ = timed(multitask_batch, fig8, tuple(range(args.fig8_runs)), protocol=protocol)
    fig8_passes = float(np.mean(PASSES)) if PASSES else 0.0
    fig8_alone, fig8_batch = fig8_alone / args.fig8_runs, fig8_batch / args.fig8_runs
    print(
        f"| Figure 8, {fig8.label} ({args.fig8_runs} runs) | {fig8_alone:.2f} | {fig8_batch:.2f} "
        f"| {fig8_alone / fig8_batch:.1f}x | | |"
    )
    print(f"\nmean iterations per batched refit: Figure 5 {fig5_passes:.1f}, Figure 8 {fig8_passes:.1f}")
    fig5_runs = transfer.DEFAULT_RUNS
    fig8_runs = multitask.DEFAULT_RUNS * len(multitask.METHODS)
    workers = args.workers
    for name, seconds in (("one at a time", totals[0]), ("batched", totals[1])):
        print(f"full Figure 5 {name}: {seconds * fig5_runs / workers / 60:.1f} min with {workers} workers")
    for name, seconds in (("one at a time", fig8_alone), ("batched", fig8_batch)):
        print(
            f"full Figure 8 {name}: {seconds * fig8_runs / workers / 60:.1f} min with {workers} workers "
            f"(every method costed as {fig8.label})"
        )
    return totals[1] * fig5_runs / workers / 60, fig8_batch * fig8_runs / workers / 60


if __name__ == "__main__":
    main()
