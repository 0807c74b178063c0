"""
Independent runs spread over processes or a cluster, kept as they finish in a ``RunCache``, stopped cleanly.

The runs go to joblib's loky workers or to a Ray cluster (``sb3_trlsd_lab.execution.backends``), handed a
few at a time: a run is kept as soon as it finishes, and an interruption (``KeyboardInterrupt``, which the
command line also makes of SIGTERM) stops the runs under way (loky's workers killed, Ray's tasks
cancelled) and loses only them.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from contextlib import closing
from pathlib import Path
from typing import Any, TypeVar

from tqdm.auto import tqdm

from sb3_trlsd_lab.execution.backends import LOKY, Backend, finished
from sb3_trlsd_lab.execution.run_cache import RunCache

__all__ = ["RunsInterrupted", "run_jobs"]

Result = TypeVar("Result")


class RunsInterrupted(KeyboardInterrupt):
    """
    ``run_jobs`` was interrupted.

    :param kept: runs of the call found in its cache when it stopped (0 without a cache)
    :param total: runs of the call
    """

    def __init__(self, kept: int, total: int) -> None:
        super().__init__(f"interrupted with {kept} of {total} runs kept")
        self.kept = kept
        self.total = total


def run_jobs(
    function: Callable[..., Result],
    jobs: Sequence[tuple[tuple, dict]],
    workers: int = 1,
    description: str = "runs",
    cache: Path | None = None,
    backend: Backend = LOKY,
) -> list[Result]:
    """
    ``function(*args, **kwargs)`` for each job, in order, over ``workers`` processes or a Ray cluster, with a
    progress bar.

    With a ``cache``, the jobs already found there are loaded instead of run (the progress bar starts at
    their number), and each other job is written there as soon as it finishes: a killed reproduction
    resumes where it stopped. A job is found when ``function`` was called with the same arguments by the
    same code (see ``sb3_trlsd_lab.execution.run_cache``): ``function`` must be a pure function of them. A
    kept run that cannot be read is reported (a warning naming its file) and run again.

    :param function: a module-level function (picklable)
    :param jobs: ``(args, kwargs)`` of each call
    :param workers: loky processes (1, or a single run to do: in this process); with Ray, the CPUs of the
        local cluster it starts (a cluster joined has its own)
    :param description: label of the progress bar
    :param cache: directory of finished runs (created if needed); None: run every job, keep nothing
    :param backend: where the jobs run (default: loky)
    :return: the results in the order of ``jobs``
    :raises RunsInterrupted: on ``KeyboardInterrupt``, once the workers or tasks are stopped, with the count
        of runs kept
    """
    run_cache = None if cache is None else RunCache(cache)
    paths = [] if run_cache is None else [run_cache.path_of(function, *job) for job in jobs]
    results: list[Any] = [None] * len(jobs)
    missing: list[int] = []  # indices of the jobs to run
    for index in range(len(jobs)):
        if run_cache is None or not paths[index].exists():
            missing.append(index)
            continue
        try:
            results[index] = run_cache.load(paths[index])
        except ValueError as error:
            warnings.warn(f"{error}: running it again", stacklevel=2)
            missing.append(index)
    # No bar when the output is not a terminal (a log file would fill with its redraws).
    bar = tqdm(
        total=len(jobs),
        initial=len(jobs) - len(missing),
        desc=description,
        unit="run",
        leave=False,
        disable=None,
    )
    kept = 0 if run_cache is None else len(jobs) - len(missing)
    try:
        with closing(finished(function, jobs, missing, workers, backend)) as results_so_far:
            for index, result in results_so_far:
                results[index] = result
                if run_cache is not None:
                    run_cache.store(paths[index], result)
                    kept += 1
                bar.update()
    except KeyboardInterrupt as interrupt:
        raise RunsInterrupted(kept, len(jobs)) from interrupt
    finally:
        bar.close()
    return results
