"""
Independent runs spread over processes, kept as they finish in a ``RunCache``, stopped cleanly.

The processes are joblib's loky workers, handed one run at a time: a run is kept as soon as it finishes,
and an interruption (``KeyboardInterrupt``, which the command line also makes of SIGTERM) kills the
workers (joblib aborts its pool on any exception) and loses only the runs under way.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import closing
from pathlib import Path
from typing import Any, TypeVar

from joblib import Parallel, delayed
from joblib.externals.loky import get_reusable_executor
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from sb3_trlsd.experiments.run_cache import RunCache

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


def _call(index: int, function: Callable[..., Result], args: tuple, kwargs: dict) -> tuple[int, Result]:
    # The products of a run are small: BLAS threads only fight the other workers for the cores.
    with threadpool_limits(1):
        return index, function(*args, **kwargs)


def _finished(
    function: Callable[..., Result], jobs: Sequence[tuple[tuple, dict]], indices: list[int], workers: int
) -> Iterator[tuple[int, Result]]:
    """``(index, result)`` of the jobs ``indices`` as they finish, over ``workers`` processes."""
    if workers <= 1 or len(indices) <= 1:  # no process to start for one run
        for index in indices:
            yield _call(index, function, *jobs[index])
        return
    # One run per dispatch (batch_size=1) and 2 per worker queued at most: a finished run is kept at once.
    parallel = Parallel(n_jobs=workers, backend="loky", return_as="generator_unordered", batch_size=1)
    results = parallel(delayed(_call)(index, function, *jobs[index]) for index in indices)
    try:
        yield from results
    finally:
        with warnings.catch_warnings():  # joblib counts the runs lost: RunsInterrupted says what is kept
            warnings.simplefilter("ignore", UserWarning)
            results.close()  # aborts the pool (kills its workers) unless every run was consumed
        # loky keeps its workers for the next call: end them, none outlives the runs.
        get_reusable_executor().shutdown(wait=True, kill_workers=True)


def run_jobs(
    function: Callable[..., Result],
    jobs: Sequence[tuple[tuple, dict]],
    workers: int = 1,
    description: str = "runs",
    cache: Path | None = None,
) -> list[Result]:
    """
    ``function(*args, **kwargs)`` for each job, in order, over ``workers`` processes, with a progress bar.

    With a ``cache``, the jobs already found there are loaded instead of run (the progress bar starts at
    their number), and each other job is written there as soon as it finishes: a killed reproduction
    resumes where it stopped. A job is found when ``function`` was called with the same arguments by the
    same code (see ``sb3_trlsd.experiments.run_cache``): ``function`` must be a pure function of them. A
    kept run that cannot be read is reported (a warning naming its file) and run again.

    :param function: a module-level function (picklable)
    :param jobs: ``(args, kwargs)`` of each call
    :param workers: processes (1, or a single run to do: in this process)
    :param description: label of the progress bar
    :param cache: directory of finished runs (created if needed); None: run every job, keep nothing
    :return: the results in the order of ``jobs``
    :raises RunsInterrupted: on ``KeyboardInterrupt``, once the workers are stopped, with the count of
        runs kept
    """
    run_cache = None if cache is None else RunCache(cache)
    paths = [None if run_cache is None else run_cache.path_of(function, *job) for job in jobs]
    results: list[Any] = [None] * len(jobs)
    missing: list[int] = []  # indices of the jobs to run
    for index, path in enumerate(paths):
        if path is None or not path.exists():
            missing.append(index)
            continue
        try:
            results[index] = run_cache.load(path)
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
        with closing(_finished(function, jobs, missing, workers)) as finished:
            for index, result in finished:
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
