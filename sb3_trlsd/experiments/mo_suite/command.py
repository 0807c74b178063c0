"""
``sb3-trlsd benchmark-suite``: the MO-Gymnasium suite from the command line (``add_parser`` declares it,
``suite_command`` runs it), next to ``benchmark``, which runs the package's own task families.
"""

from __future__ import annotations

import argparse
import os

from sb3_trlsd.experiments.mo_suite.families import FAMILIES, available
from sb3_trlsd.experiments.mo_suite.peers import METHODS

__all__ = ["add_parser", "suite_command"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare ``benchmark-suite`` among the subcommands ``commands``."""
    from sb3_trlsd.cli_parser import add_cache_options, positive_int

    suite = commands.add_parser(
        "benchmark-suite",
        help="TRLSD and its peers on MO-Gymnasium task families, one task per weight vector (CSV, PNG, JSON)",
        description="Each MO-Gymnasium env is a family of tasks sharing its dynamics, one per weight "
        "vector w of its reward vector (reward w . r_vec). Every method learns the same held-out target "
        "weights with the same seeds, after the same random source transitions collected under other "
        "weights, for the family's online budget; the score is the mean scalar reward per online step. Needs "
        "sb3-trlsd[benchmarks].",
    )
    suite.add_argument(
        "family", choices=[*FAMILIES, "all"], help="which family (all: those that can run here)"
    )
    suite.add_argument("--runs", type=positive_int, default=20, help="runs per method (default: %(default)s)")
    suite.add_argument("--out", default="results", help="output directory (default: %(default)s)")
    suite.add_argument("--seed", type=int, default=0, help="seed of the first run; run r uses seed + r")
    suite.add_argument(
        "--workers", type=positive_int, default=os.cpu_count() or 1, help="processes (default: %(default)s)"
    )
    suite.add_argument(
        "--methods", nargs="+", choices=list(METHODS), default=list(METHODS), help="methods (default: all)"
    )
    suite.add_argument(
        "--source", type=positive_int, default=None, help="source transitions (default: 20,000)"
    )
    suite.add_argument("--online", type=positive_int, default=None, help="online steps (default: 1,000)")
    add_cache_options(suite)


def suite_command(args: argparse.Namespace) -> int:
    """
    Run the suite on one family (or all that can run here), write their files and print the table.

    :return: 0, or 128 + the signal's number when SIGINT or SIGTERM stopped it
    """
    from sb3_trlsd.cli import run_in_turn, usable_directory
    from sb3_trlsd.experiments.mo_suite.suite import run_suite, suite_table

    if args.family == "all":
        families = [name for name, family in FAMILIES.items() if available(family)]
    else:
        families = [args.family]
    if not all(available(FAMILIES[name]) for name in families):
        raise ValueError(
            f"{args.family} needs MO-Gymnasium (and {FAMILIES[args.family].requires or 'nothing else'}):"
            " pip install 'sb3-trlsd[benchmarks]'"
        )
    out = usable_directory(args.out, "--out")
    cache = None if args.no_cache else usable_directory(args.cache or out / "runs", "--cache")
    done = []

    def run_one(name: str) -> None:
        data = run_suite(
            name,
            out,
            runs=args.runs,
            seed=args.seed,
            workers=args.workers,
            methods=args.methods,
            cache=cache,
            n_source=args.source,
            n_online=args.online,
        )
        done.append(data)
        print(
            f"mo_suite_{name} done in {data['wall_time_seconds']:.0f} s\n\n{suite_table([data])}\n",
            flush=True,
        )

    status = run_in_turn("benchmark-suite", families, run_one, cache)
    if len(done) > 1:
        table = suite_table(done)
        (out / "mo_suite_table.md").write_text(table + "\n")
        print(table)
    return status
