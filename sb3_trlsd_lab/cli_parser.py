"""
What the ``sb3-trlsd`` command line accepts: each subcommand's arguments, their types and their help
(``build_parser``). What each subcommand does is ``cli.py``'s.
"""

from __future__ import annotations

import argparse
import os

from sb3_trlsd.zoo import ZOO_SCRIPTS
from sb3_trlsd_lab.benchmarks.benchmark import FAMILIES
from sb3_trlsd_lab.benchmarks.mo_suite.families import FAMILIES as SUITE_FAMILIES
from sb3_trlsd_lab.benchmarks.mo_suite.peers import METHODS as SUITE_METHODS
from sb3_trlsd_lab.benchmarks.mo_suite.sources import SOURCE_POLICIES
from sb3_trlsd_lab.execution.backends import BACKENDS
from sb3_trlsd_lab.execution.protocols import DEFAULT_PROTOCOL, PRESETS
from sb3_trlsd_lab.registry import FIGURES, STUDIES

__all__ = [
    "IMAGE_EXTENSIONS",
    "build_parser",
    "non_negative_int",
    "parse_task",
    "positive_int",
]

# What ``render`` writes, from its file's extension (formats matplotlib's imsave writes, tested).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tiff", ".webp", ".pdf", ".svg", ".eps")


def parse_task(text: str) -> int | tuple[int, int]:
    """``"1,5"`` -> (1, 5) (the paper's tau_15); ``"4"`` -> task index 4."""
    try:
        parts = tuple(int(part) for part in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(
            f"a task is 'i,j' with i, j in 1..5 or an index 0..24, got {text!r}"
        ) from error
    if len(parts) == 1:
        return parts[0]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise argparse.ArgumentTypeError(f"a task is 'i,j' or an index, got {text!r}")


def positive_int(text: str, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (1), for ``--runs`` and ``--workers``."""
    try:
        value = int(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from error
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0, for ``--mlp-runs``."""
    return positive_int(text, minimum=0)


def add_cache_options(command: argparse.ArgumentParser) -> None:
    """``--cache DIR`` and ``--no-cache``, for the subcommands whose runs go through ``run_jobs``."""
    run_cache = command.add_mutually_exclusive_group()
    run_cache.add_argument(
        "--cache",
        default=None,
        metavar="DIR",
        help="directory of finished runs (default: OUT/runs; a killed command resumes from there): "
        "finished runs are kept there and reused when the same command is run again with the same code; "
        "--no-cache turns it off",
    )
    run_cache.add_argument("--no-cache", action="store_true", help="keep no finished runs and reuse none")


def build_parser() -> argparse.ArgumentParser:
    """
    The parser of ``sb3-trlsd``: a subcommand per job, its name in ``command`` (``main`` runs it).

    :return: the parser
    """
    parser = argparse.ArgumentParser(
        prog="sb3-trlsd",
        description="Transfer RL with Shared Dynamics (Laroche & Barlier, AAAI 2017) on Stable-Baselines3.",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    render = commands.add_parser("render", help="draw the maze with a random trajectory to an image file")
    render.add_argument(
        "--out",
        default="results/maze.png",
        help=f"image to write, {', '.join(IMAGE_EXTENSIONS)} (default: %(default)s)",
    )
    render.add_argument("--task", type=parse_task, default=(1, 5), help="target cell 'i,j' drawn in green")
    render.add_argument("--steps", type=int, default=30, help="random steps of the trajectory drawn in blue")
    render.add_argument("--seed", type=int, default=0, help="seed of the env and of the random policy")

    reproduce = commands.add_parser(
        "reproduce",
        help="reproduce a figure of the paper's section 4, or a study beyond it (CSV, PNG and JSON)",
        description="Reproduce the paper's experiments; without --runs, at the paper's sizes. 'beyond' "
        "tunes eq. 9, OFUL, Thompson sampling and the Bernstein bound on the same budget (8 "
        "configurations each, on --tuning-runs runs whose seeds are disjoint from the evaluation's, selected "
        "on the reward over the last 500 online transitions), then evaluates each selection on --runs runs "
        "in Figure 5's setting (linear Q; MLP Q on --mlp-runs runs), on the paper's maze and on its variant "
        "with reward noise by cell, next to the known reward: beyond.csv, beyond.png, "
        "beyond_improvement.png and beyond.json, with IQM and mean under 95% stratified bootstrap "
        "intervals and P(method > eq. 9).",
    )
    reproduce.add_argument(
        "figure",
        choices=[*FIGURES, *STUDIES, "all"],
        help="which figure (all: fig1 to fig8), or beyond: the comparison of confidence bounds",
    )
    reproduce.add_argument(
        "--runs",
        type=positive_int,
        default=None,
        help="runs per method (default: the paper's; beyond: 500 evaluation runs)",
    )
    reproduce.add_argument(
        "--tuning-runs",
        type=positive_int,
        default=None,
        metavar="N",
        help="beyond only: tuning runs per configuration (default: 100)",
    )
    reproduce.add_argument(
        "--mlp-runs",
        type=non_negative_int,
        default=None,
        metavar="N",
        help="beyond only: evaluation runs per method with the MLP Q too, one run at a time (~10 s each; "
        "at most --runs; default: 0, none)",
    )
    reproduce.add_argument(
        "--mazes",
        nargs="+",
        default=None,
        metavar="MAZE",
        help="beyond only: the mazes to study, paper-maze and/or noise-by-cell (default: both; one per "
        "sitting gives a JSON each)",
    )
    reproduce.add_argument("--out", default="results", help="output directory (default: %(default)s)")
    reproduce.add_argument("--seed", type=int, default=0, help="seed of the first run; run r uses seed + r")
    reproduce.add_argument(
        "--workers",
        type=positive_int,
        default=os.cpu_count() or 1,
        help="processes, or CPUs of the local Ray cluster started without --address (default: %(default)s)",
    )
    reproduce.add_argument(
        "--backend",
        choices=BACKENDS,
        default="loky",
        help="where the runs go: loky, processes of this machine; ray, tasks of a Ray cluster (needs "
        "sb3-trlsd[cluster]); the kept runs stay on this machine (default: %(default)s)",
    )
    reproduce.add_argument(
        "--address",
        default=None,
        help="with --backend ray, the cluster to join: auto (started by 'ray start' here, or RAY_ADDRESS), "
        "HOST:PORT or ray://HOST:PORT (default: start a local one)",
    )
    reproduce.add_argument(
        "--protocol",
        choices=list(PRESETS),
        default=DEFAULT_PROTOCOL,
        metavar="NAME",
        help="the choices the paper leaves open, a named set (recorded in the JSON; runs of different "
        "protocols are kept apart): "
        + "; ".join(f"{name}: {preset.changes}" for name, preset in PRESETS.items())
        + " (default: %(default)s)",
    )
    add_cache_options(reproduce)

    claims = commands.add_parser(
        "claims",
        help="the paper's claims checked on reproduced figures, one column per directory (protocol)",
        description="Each directory holds figN.json files written by 'sb3-trlsd reproduce' under one "
        "protocol; a claim comparing two methods holds when their difference is more than 2 standard "
        "errors of the difference (a claim of likeness: less).",
    )
    claims.add_argument("directories", nargs="+", help="directories of figN.json (one column each)")
    claims.add_argument("--out", default=None, help="also write the Markdown table to this file")
    claims.add_argument(
        "--runs",
        action="store_true",
        help="print instead what ran under each preset: each figure's wall time, or the earlier "
        "directory whose runs it reads again, or 'not run'",
    )

    benchmark = commands.add_parser(
        "benchmark",
        help="TRLSD against DQN and a random policy on a task family (CSV, PNG and JSON)",
        description="Each method learns the same target tasks with the same seeds, after the same 25,000 "
        "random source transitions of another task (rewards discarded), for the family's online budget.",
    )
    benchmark.add_argument("family", choices=[*FAMILIES, "all"], help="which task family")
    benchmark.add_argument(
        "--runs", type=positive_int, default=20, help="runs per method (default: %(default)s)"
    )
    benchmark.add_argument("--out", default="results", help="output directory (default: %(default)s)")
    benchmark.add_argument("--seed", type=int, default=0, help="seed of the first run; run r uses seed + r")
    benchmark.add_argument(
        "--workers", type=positive_int, default=os.cpu_count() or 1, help="processes (default: %(default)s)"
    )
    add_cache_options(benchmark)
    suite = commands.add_parser(
        "benchmark-suite",
        help="TRLSD and its peers on MO-Gymnasium task families, one task per weight vector (CSV, PNG, JSON)",
        description="Each MO-Gymnasium env is a family of tasks sharing its dynamics, one per weight "
        "vector w of its reward vector (reward w . r_vec). Every method learns the same held-out target "
        "weights with the same seeds, after the same random source transitions collected under other "
        "weights (or a DQN's trained on them: --source-policy), for the family's online budget; the score "
        "is the mean scalar reward per online step. "
        "Writes mo_suite_<family>.csv, .png and .json, and mo_suite_table.md: the tables of every family "
        "whose JSON is in --out, this command's and earlier ones'. Needs sb3-trlsd[benchmarks].",
    )
    suite.add_argument(
        "family", choices=[*SUITE_FAMILIES, "all"], help="which family (all: those that can run here)"
    )
    suite.add_argument("--runs", type=positive_int, default=20, help="runs per method (default: %(default)s)")
    suite.add_argument("--out", default="results", help="output directory (default: %(default)s)")
    suite.add_argument("--seed", type=int, default=0, help="seed of the first run; run r uses seed + r")
    suite.add_argument(
        "--workers", type=positive_int, default=os.cpu_count() or 1, help="processes (default: %(default)s)"
    )
    suite.add_argument(
        "--methods",
        nargs="+",
        choices=list(SUITE_METHODS),
        default=list(SUITE_METHODS),
        help="methods (default: all)",
    )
    suite.add_argument(
        "--source", type=positive_int, default=None, help="source transitions (default: 20,000)"
    )
    suite.add_argument(
        "--source-policy",
        nargs="+",
        choices=list(SOURCE_POLICIES),
        default=["random"],
        help="what collects the source: random, a random policy (mo_suite_<family>.*); trained, SB3's DQN "
        "trained on the source weights for --source steps, its replay buffer the source "
        "(mo_suite_trained_<family>.*); both, one after the other (default: random). mo_suite_protocols.md "
        "sets them side by side",
    )
    suite.add_argument("--online", type=positive_int, default=None, help="online steps (default: 1,000)")
    add_cache_options(suite)
    for script in ZOO_SCRIPTS:
        # Listed for --help; main() hands their arguments to the Zoo before this parser sees them.
        commands.add_parser(
            script,
            help=f"the RL Zoo's {script} with --algo trlsd available (arguments as rl_zoo3 {script})",
            add_help=False,
        )
    return parser
