"""
The ``sb3-trlsd`` command line: one subcommand per job. This module runs the lab's (``main``), each run
stopped cleanly by SIGINT or SIGTERM; what each accepts is ``cli_parser.py``'s; ``console.py`` is the entry
point, which hands the Zoo's ``train`` and ``enjoy`` on.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import multiprocessing
import os
import signal
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sb3_trlsd_envs
from sb3_trlsd.atomic_files import atomic_path, atomic_write
from sb3_trlsd_lab.benchmarks.benchmark import FAMILIES
from sb3_trlsd_lab.cli_parser import IMAGE_EXTENSIONS, build_parser
from sb3_trlsd_lab.registry import FIGURES, STUDIES, STUDY_OPTIONS

__all__ = ["main"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


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
        with tempfile.NamedTemporaryFile(dir=os.fspath(path)):
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

    with atomic_path(args.out) as temporary:
        imsave(temporary, np.asarray(image), format=Path(args.out).suffix.lower().lstrip("."))
    print(f"maze with a random trajectory of {args.steps} steps written to {os.path.abspath(args.out)}")
    return 0


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
            if child.pid is not None:  # None: not started
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
    from sb3_trlsd_lab.execution.jobs import RunsInterrupted

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


def study_options(figure: str, args: argparse.Namespace) -> dict[str, Any]:
    """
    The options of a study given on the command line (``--tuning-runs``, ``--mlp-runs`` and ``--mazes`` of
    ``beyond``).

    :raises ValueError: for an option given to a figure or study that does not take it, or a maze that is not
    """
    given = {name: getattr(args, name) for names in STUDY_OPTIONS.values() for name in names}
    given = {name: value for name, value in given.items() if value is not None}
    refused = sorted(set(given) - set(STUDY_OPTIONS.get(figure, ())))
    if refused:
        options = ", ".join("--" + name.replace("_", "-") for name in refused)
        owners = ", ".join(f"'reproduce {study}'" for study in STUDY_OPTIONS)
        raise ValueError(f"{options}: an option of {owners}, not of {figure!r}")
    if "mazes" in given:
        from sb3_trlsd_lab.studies.beyond import mazes_named

        mazes_named(given["mazes"])  # refused here, before anything runs
    return given


def summary_table(figure: str, data: dict) -> str:
    """The Markdown table of a figure's (or a study's, by its own function) JSON summary."""
    if figure in STUDIES:
        module, _, function = STUDIES[figure]
        return getattr(importlib.import_module(module), function)(data)
    from sb3_trlsd_lab.paper.reporting import results_table

    return results_table(data)


def reproduce_figure(figure: str, out: Path, cache: Path | None, args: argparse.Namespace) -> None:
    """Run one figure's experiments, write its files and print its table."""
    from sb3_trlsd_lab.registry import reproduce

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
    from sb3_trlsd_lab.benchmarks.benchmark import benchmark
    from sb3_trlsd_lab.paper.reporting import results_table

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


def suite_command(args: argparse.Namespace) -> int:
    """
    Run the suite on one family (or all that can run here), write their files and print the table.

    :return: 0, or 128 + the signal's number when SIGINT or SIGTERM stopped it
    """
    from sb3_trlsd_lab.benchmarks.mo_suite.families import FAMILIES as SUITE_FAMILIES
    from sb3_trlsd_lab.benchmarks.mo_suite.families import available
    from sb3_trlsd_lab.benchmarks.mo_suite.sources import SOURCE_POLICIES
    from sb3_trlsd_lab.benchmarks.mo_suite.suite import (
        goal_table,
        protocol_table,
        run_suite,
        suite_name,
        suite_table,
    )

    if args.family == "all":
        families = [name for name, family in SUITE_FAMILIES.items() if available(family)]
    else:
        families = [args.family]
    if not all(available(SUITE_FAMILIES[name]) for name in families):
        needs = SUITE_FAMILIES[args.family].requires or "nothing else"
        raise ValueError(
            f"{args.family} needs MO-Gymnasium (and {needs}): pip install 'sb3-trlsd[benchmarks]'"
        )
    out = usable_directory(args.out, "--out")
    cache = None if args.no_cache else usable_directory(args.cache or out / "runs", "--cache")
    done = []

    jobs = {
        suite_name(name, policy): (name, policy)
        for policy in dict.fromkeys(args.source_policy)
        for name in families
    }

    def run_one(stem: str) -> None:
        name, source_policy = jobs[stem]
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
            source_policy=source_policy,
        )
        done.append(data)
        print(f"{stem} done in {data['wall_time_seconds']:.0f} s\n\n{suite_table([data])}\n", flush=True)

    status = run_in_turn("benchmark-suite", list(jobs), run_one, cache)

    # The tables of every family whose JSON is in OUT, this command's and earlier ones' (run one family at a
    # time, or rerun one): the families in the suite's order.
    def stored(source_policy: str) -> list[dict]:
        paths = [out / f"{suite_name(name, source_policy)}.json" for name in SUITE_FAMILIES]
        return [json.loads(path.read_text()) for path in paths if path.exists()]

    datas = stored("random")
    if done and datas:
        table = f"{suite_table(datas)}\n\n{goal_table(datas)}"
        with atomic_write(out / "mo_suite_table.md", "w") as file:
            file.write(table + "\n")
        print(table)
    both = [data for policy in SOURCE_POLICIES for data in stored(policy)]
    if done and any(data["parameters"].get("source_policy") == "trained" for data in both):
        protocols = protocol_table(both)
        (out / "mo_suite_protocols.md").write_text(protocols + "\n")
        print(f"\n{protocols}")
    return status


def claims_command(args: argparse.Namespace) -> int:
    """
    Print (and with ``--out``, write) the table of the paper's claims checked on each directory's figures,
    or with ``--runs`` the table of what ran under each preset and how long it took.

    :return: 0, or 2 when a directory holds no figure
    """
    from sb3_trlsd_lab.studies.claims import claims_table, load_figures, load_wall_times
    from sb3_trlsd_lab.studies.study_runs import runs_table

    columns = []
    for directory in args.directories:
        name, figures = load_figures(Path(directory))
        if not figures:
            print(f"sb3-trlsd claims: error: no figN.json in {directory}", file=sys.stderr)
            return 2
        columns.append((name, figures))
    if args.runs:
        table = runs_table(columns, [load_wall_times(Path(directory)) for directory in args.directories])
    else:
        table = claims_table(columns)
    print(table)
    if args.out:
        with atomic_write(args.out, "w") as file:
            file.write(table + "\n")
    return 0


# Subcommand -> what runs it (the Zoo's scripts are handed on before parsing).
COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "render": render_command,
    "reproduce": reproduce_command,
    "claims": claims_command,
    "benchmark": benchmark_command,
    "benchmark-suite": suite_command,
}


def main(argv: Sequence[str] | None = None) -> int:
    """
    The lab's commands of the ``sb3-trlsd`` console script (``console.main``, which hands the Zoo's
    ``train`` and ``enjoy`` on before it comes here).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except ValueError as error:  # bad input, found before anything ran
        print(f"sb3-trlsd {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # e.g. a disk full while writing
        print(f"sb3-trlsd {args.command}: error: {error}", file=sys.stderr)
        return 1
