"""The ``sb3-trlsd`` command line: one subcommand per job."""

from __future__ import annotations

import argparse
import functools
import importlib
import multiprocessing
import os
import signal
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path

import gymnasium as gym
import numpy as np

import sb3_trlsd_envs
from sb3_trlsd.experiments import FIGURES, STUDIES, STUDY_OPTIONS
from sb3_trlsd.experiments.backends import BACKENDS
from sb3_trlsd.experiments.benchmark import FAMILIES
from sb3_trlsd.experiments.protocols import DEFAULT_PROTOCOL, PRESETS

__all__ = ["main"]

ZOO_SCRIPTS = ("train", "enjoy")  # subcommands passed on, unchanged, to the RL Zoo
# What ``render`` writes, from its file's extension (formats matplotlib's imsave writes, tested).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tiff", ".webp", ".pdf", ".svg", ".eps")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


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


def usable_directory(path: str | os.PathLike, option: str) -> Path:
    """
    ``path``, made if needed, once a file could be created in it.

    :param path: a directory
    :param option: what it comes from, for the message (e.g. ``"--out"``)
    :return: the directory
    :raises ValueError: if it cannot be made or written to
    """
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            pass
    except OSError as error:
        reason = "a file has that name" if os.path.isfile(path) else error.strerror
        raise ValueError(
            f"{option}: cannot make or write to the directory {os.fspath(path)!r} ({reason})"
        ) from None
    return Path(path)


def render_command(args: argparse.Namespace) -> int:
    """Render the maze with one random trajectory of the given task to an image file."""
    if Path(args.out).suffix.lower() not in IMAGE_EXTENSIONS:
        raise ValueError(f"--out {args.out!r}: the file must end with one of {', '.join(IMAGE_EXTENSIONS)}")
    usable_directory(os.path.dirname(os.path.abspath(args.out)), f"--out {args.out!r}")
    env = gym.make(sb3_trlsd_envs.MAZE_ID, task=args.task, render_mode="rgb_array", termination_prob=0.0)
    env.action_space.seed(args.seed)
    env.reset(seed=args.seed)
    for _ in range(args.steps):
        env.step(env.action_space.sample())
    image = env.render()
    env.close()
    from matplotlib.image import imsave

    imsave(args.out, np.asarray(image))
    print(f"maze with a random trajectory of {args.steps} steps written to {os.path.abspath(args.out)}")
    return 0


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


@contextmanager
def stopped_by_signals() -> Iterator[list[int]]:
    """
    Within the block, the first SIGINT or SIGTERM raises ``KeyboardInterrupt`` (on which joblib stops its
    workers and the command says what it kept); a second one kills the worker processes and exits at once.

    :return: (as the ``with`` target) the signals received, filled in by the handler
    """
    received: list[int] = []

    def interrupt(signum: int, frame: object) -> None:
        received.append(signum)
        if len(received) == 1:
            raise KeyboardInterrupt
        for child in multiprocessing.active_children():  # loky's workers are multiprocessing processes
            with suppress(ProcessLookupError):
                os.kill(child.pid, signal.SIGKILL)
        os.write(sys.stderr.fileno(), b"sb3-trlsd: interrupted again, stopped at once\n")
        os._exit(128 + signum)

    previous = {number: signal.signal(number, interrupt) for number in STOP_SIGNALS}
    try:
        yield received
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def interruption_message(interrupt: KeyboardInterrupt, figure: str, cache: Path | None) -> str:
    """What an interrupted ``reproduce`` (or ``benchmark``) kept, and how to resume it."""
    from sb3_trlsd.experiments.jobs import RunsInterrupted

    if cache is None:
        return "interrupted: no runs kept (--no-cache), a rerun starts again from the first one"
    if isinstance(interrupt, RunsInterrupted):
        kept = f"{interrupt.kept} of {interrupt.total} runs of {figure}"
    else:
        kept = "the finished runs"
    return f"interrupted: {kept} kept in {cache}; run the same command again to resume"


def print_warning(
    message: Warning | str, *args: object, command: str = "reproduce", **kwargs: object
) -> None:
    """A warning on one line of stderr (``warnings.showwarning`` adds its file and source line)."""
    print(f"sb3-trlsd {command}: warning: {message}", file=sys.stderr)


def run_in_turn(
    command: str, names: Sequence[str], run_one: Callable[[str], None], cache: Path | None
) -> int:
    """
    ``run_one(name)`` for each name in turn, each warning on one line; the first SIGINT or SIGTERM stops it
    and says what the run cache kept.

    :param command: the subcommand, for the messages
    :param names: the figures or families
    :param run_one: runs one of them, writes its files and prints its table
    :param cache: the run cache (None: none)
    :return: 0, or 128 + the signal's number when SIGINT or SIGTERM stopped it
    """
    name = names[0]
    with stopped_by_signals() as received, warnings.catch_warnings():
        warnings.showwarning = functools.partial(print_warning, command=command)
        try:
            for name in names:
                run_one(name)
        except KeyboardInterrupt as interrupt:
            print(f"sb3-trlsd {command}: {interruption_message(interrupt, name, cache)}", file=sys.stderr)
            status = 128 + (received[0] if received else signal.SIGINT)
            leave_ray_at_once(status)
            return status
    return 0


def leave_ray_at_once(status: int) -> None:
    """
    After an interruption with the ray backend, exit now with ``status``: Ray's core worker can abort the
    process at its normal exit on the late replies of the tasks just cancelled ("Tried to complete task that
    was not pending", seen with ray 2.60), which would turn 130 or 143 into 1. The cluster drops the tasks of
    a driver that has gone. Without Ray connected, nothing happens.
    """
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)


def study_options(figure: str, args: argparse.Namespace) -> dict[str, int]:
    """
    The options of a study given on the command line (``--tuning-runs`` and ``--mlp-runs`` of ``beyond``).

    :raises ValueError: for an option given to a figure or study that does not take it
    """
    given = {name: getattr(args, name) for names in STUDY_OPTIONS.values() for name in names}
    given = {name: value for name, value in given.items() if value is not None}
    refused = sorted(set(given) - set(STUDY_OPTIONS.get(figure, ())))
    if refused:
        options = ", ".join("--" + name.replace("_", "-") for name in refused)
        owners = ", ".join(f"'reproduce {study}'" for study in STUDY_OPTIONS)
        raise ValueError(f"{options}: an option of {owners}, not of {figure!r}")
    return given


def summary_table(figure: str, data: dict) -> str:
    """The Markdown table of a figure's (or a study's, by its own function) JSON summary."""
    if figure in STUDIES:
        module, _, function = STUDIES[figure]
        return getattr(importlib.import_module(f"sb3_trlsd.experiments.{module}"), function)(data)
    from sb3_trlsd.experiments.reporting import results_table

    return results_table(data)


def reproduce_figure(figure: str, out: Path, cache: Path | None, args: argparse.Namespace) -> None:
    """Run one figure's experiments, write its files and print its table."""
    from sb3_trlsd.experiments import reproduce

    data = reproduce(
        figure,
        out,
        runs=args.runs,
        seed=args.seed,
        workers=args.workers,
        cache=cache,
        backend=args.backend,
        address=args.address,
        protocol=args.protocol,
        options=study_options(figure, args),
    )
    paths = data.get("files") or [out / f"{figure}.{ext}" for ext in ("png", "csv", "json")]
    files = ", ".join(str(Path(path).absolute()) for path in paths)
    print(f"{figure} done in {data['wall_time_seconds']:.0f} s: {files}\n\n{summary_table(figure, data)}\n")


def reproduce_command(args: argparse.Namespace) -> int:
    """
    Run the experiments of one figure (or all) and write their CSV, PNG and JSON files.

    :return: 0, or 128 + the signal's number when SIGINT or SIGTERM stopped it
    """
    figures = list(FIGURES) if args.figure == "all" else [args.figure]
    for figure in figures:
        study_options(figure, args)  # refused before anything is made
    out = usable_directory(args.out, "--out")
    cache = None if args.no_cache else usable_directory(args.cache or out / "runs", "--cache")
    return run_in_turn("reproduce", figures, lambda figure: reproduce_figure(figure, out, cache, args), cache)


def benchmark_family(family: str, out: Path, cache: Path | None, args: argparse.Namespace) -> None:
    """Run one family's benchmark, write its files and print its table."""
    from sb3_trlsd.experiments.benchmark import benchmark
    from sb3_trlsd.experiments.reporting import results_table

    data = benchmark(family, out, runs=args.runs, seed=args.seed, workers=args.workers, cache=cache)
    name = f"benchmark_{family}"
    files = ", ".join(str(out.absolute() / f"{name}.{ext}") for ext in ("png", "csv", "json"))
    print(f"{name} done in {data['wall_time_seconds']:.0f} s: {files}\n\n{results_table(data)}\n")


def benchmark_command(args: argparse.Namespace) -> int:
    """
    Benchmark TRLSD against DQN on one task family (or all) and write their CSV, PNG and JSON files.

    :return: 0, or 128 + the signal's number when SIGINT or SIGTERM stopped it
    """
    out = usable_directory(args.out, "--out")
    cache = None if args.no_cache else usable_directory(args.cache or out / "runs", "--cache")
    families = list(FAMILIES) if args.family == "all" else [args.family]
    return run_in_turn(
        "benchmark", families, lambda family: benchmark_family(family, out, cache, args), cache
    )


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


def claims_command(args: argparse.Namespace) -> int:
    """
    Print (and with ``--out``, write) the table of the paper's claims checked on each directory's figures.

    :return: 0, or 2 when a directory holds no figure
    """
    from sb3_trlsd.experiments.claims import claims_table, load_figures

    columns = []
    for directory in args.directories:
        name, figures = load_figures(Path(directory))
        if not figures:
            print(f"sb3-trlsd claims: error: no figN.json in {directory}", file=sys.stderr)
            return 2
        columns.append((name, figures))
    table = claims_table(columns)
    print(table)
    if args.out:
        Path(args.out).write_text(table + "\n")
    return 0


def build_parser() -> argparse.ArgumentParser:
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
    render.set_defaults(run=render_command)

    reproduce = commands.add_parser(
        "reproduce",
        help="reproduce a figure of the paper's section 4, or a study beyond it (CSV, PNG and JSON)",
        description="Reproduce the paper's experiments; without --runs, at the paper's sizes. 'beyond' "
        "(issue 18) tunes eq. 9, OFUL, Thompson sampling and the Bernstein bound on the same budget (8 "
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
    reproduce.set_defaults(run=reproduce_command)

    claims = commands.add_parser(
        "claims",
        help="the paper's claims checked on reproduced figures, one column per directory (protocol)",
        description="Each directory holds figN.json files written by 'sb3-trlsd reproduce' under one "
        "protocol; a claim comparing two methods holds when their difference is more than 2 standard "
        "errors of the difference (a claim of likeness: less).",
    )
    claims.add_argument("directories", nargs="+", help="directories of figN.json (one column each)")
    claims.add_argument("--out", default=None, help="also write the Markdown table to this file")
    claims.set_defaults(run=claims_command)

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
    benchmark.set_defaults(run=benchmark_command)
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
    except ValueError as error:  # bad input, found before anything ran
        print(f"sb3-trlsd {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # e.g. a disk full while writing
        print(f"sb3-trlsd {args.command}: error: {error}", file=sys.stderr)
        return 1
