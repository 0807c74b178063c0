"""The ``sb3-trlsd`` command line: one subcommand per job."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

import sb3_trlsd_envs
from sb3_trlsd.experiments import FIGURES

__all__ = ["main"]

ZOO_SCRIPTS = ("train", "enjoy")  # subcommands passed on, unchanged, to the RL Zoo


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


def render_command(args: argparse.Namespace) -> int:
    """Render the maze with one random trajectory of the given task to a PNG."""
    env = gym.make(sb3_trlsd_envs.MAZE_ID, task=args.task, render_mode="rgb_array", termination_prob=0.0)
    env.action_space.seed(args.seed)
    env.reset(seed=args.seed)
    for _ in range(args.steps):
        env.step(env.action_space.sample())
    image = env.render()
    env.close()
    directory = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(directory, exist_ok=True)
    from matplotlib.image import imsave

    imsave(args.out, np.asarray(image))
    print(f"maze with a random trajectory of {args.steps} steps written to {os.path.abspath(args.out)}")
    return 0


def positive_int(text: str) -> int:
    """An integer >= 1, for ``--runs`` and ``--workers``."""
    try:
        value = int(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from error
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def writable_directory(text: str) -> str:
    """A directory that exists or can be created, and can be written to."""
    try:
        os.makedirs(text, exist_ok=True)
    except OSError as error:
        raise argparse.ArgumentTypeError(f"cannot create the output directory {text!r}: {error}") from error
    if not os.access(text, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write to the output directory {text!r}")
    return text


def reproduce_command(args: argparse.Namespace) -> int:
    """Run the experiments of one figure (or all) and write their CSV, PNG and JSON files."""
    from sb3_trlsd.experiments import reproduce
    from sb3_trlsd.experiments.reporting import results_table

    figures = list(FIGURES) if args.figure == "all" else [args.figure]
    cache = None if args.no_cache else Path(args.cache or os.path.join(args.out, "runs"))
    for figure in figures:
        data = reproduce(figure, args.out, runs=args.runs, seed=args.seed, workers=args.workers, cache=cache)
        files = ", ".join(
            os.path.join(os.path.abspath(args.out), f"{figure}.{ext}") for ext in ("png", "csv", "json")
        )
        print(f"{figure} done in {data['wall_time_seconds']:.0f} s: {files}\n\n{results_table(data)}\n")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-trlsd",
        description="Transfer RL with Shared Dynamics (Laroche & Barlier, AAAI 2017) on Stable-Baselines3.",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    render = commands.add_parser("render", help="draw the maze with a random trajectory to a PNG")
    render.add_argument("--out", default="results/maze.png", help="PNG file to write (default: %(default)s)")
    render.add_argument("--task", type=parse_task, default=(1, 5), help="target cell 'i,j' drawn in green")
    render.add_argument("--steps", type=int, default=30, help="random steps of the trajectory drawn in blue")
    render.add_argument("--seed", type=int, default=0, help="seed of the env and of the random policy")
    render.set_defaults(run=render_command)

    reproduce = commands.add_parser(
        "reproduce",
        help="reproduce a figure of the paper's section 4 (CSV, PNG and JSON)",
        description="Reproduce the paper's experiments; without --runs, at the paper's sizes.",
    )
    reproduce.add_argument("figure", choices=[*FIGURES, "all"], help="which figure")
    reproduce.add_argument(
        "--runs", type=positive_int, default=None, help="runs per method (default: the paper's)"
    )
    reproduce.add_argument(
        "--out", type=writable_directory, default="results", help="output directory (default: %(default)s)"
    )
    reproduce.add_argument("--seed", type=int, default=0, help="seed of the first run; run r uses seed + r")
    reproduce.add_argument(
        "--workers", type=positive_int, default=os.cpu_count() or 1, help="processes (default: %(default)s)"
    )
    run_cache = reproduce.add_mutually_exclusive_group()
    run_cache.add_argument(
        "--cache",
        type=writable_directory,
        default=None,
        metavar="DIR",
        help="directory of finished runs (default: OUT/runs; a killed reproduction resumes from there): "
        "finished runs are kept there and reused when the same command is run again with the same code; "
        "--no-cache turns it off",
    )
    run_cache.add_argument("--no-cache", action="store_true", help="keep no finished runs and reuse none")
    reproduce.set_defaults(run=reproduce_command)
    for script in ZOO_SCRIPTS:
        # Listed for --help; main() hands their arguments to the Zoo before this parser sees them.
        commands.add_parser(
            script,
            help=f"the RL Zoo's {script} with --algo trlsd available (arguments as rl_zoo3 {script})",
            add_help=False,
        )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sb3-trlsd`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ZOO_SCRIPTS:
        from sb3_trlsd.zoo import run_zoo

        return run_zoo(argv[0], argv[1:])
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except ValueError as error:
        print(f"sb3-trlsd {args.command}: error: {error}", file=sys.stderr)
        return 2
