"""
Where ``run_jobs`` runs its jobs: in this process, over joblib's loky workers on this machine, or as tasks
of a Ray cluster (the optional extra ``sb3-trlsd[cluster]``).

Each backend only submits jobs and hands back ``(index, result)`` as they finish; ``run_jobs`` keeps them
in the run cache (on the driver's disk, whatever the backend), moves the progress bar and reports an
interruption. Closing the iterator early (an interrupt, an error) stops the runs under way: loky's
workers are killed, Ray's tasks cancelled (``ray.cancel(force=True)``), and no job is left queued, since
at most two per worker (per CPU of the cluster) are submitted ahead.
"""

from __future__ import annotations

import importlib
import itertools
import pickle
import signal
import socket
import threading
import warnings
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any, TypeVar

from joblib import Parallel, delayed
from joblib.externals.loky import get_reusable_executor
from threadpoolctl import threadpool_limits

from sb3_trlsd_lab.execution.run_cache import code_fingerprint

__all__ = ["BACKENDS", "LOKY", "Backend", "finished"]

Result = TypeVar("Result")
BACKENDS = ("loky", "ray")
WAIT_SECONDS = 0.2  # longest wait for Ray between two chances for a signal handler to run
TASKS_PER_CPU = 2  # Ray tasks submitted ahead per CPU of the cluster: busy CPUs, a short queue to cancel


@dataclass(frozen=True)
class Backend:
    """
    Where the runs go.

    :param name: ``"loky"``: processes of this machine; ``"ray"``: tasks of a Ray cluster
    :param address: (ray) the cluster to join: ``"auto"`` (one started by ``ray start`` on this machine or
        named by ``RAY_ADDRESS``), ``"host:port"`` or ``"ray://host:port"``; None: start a local one with
        ``workers`` CPUs. A process keeps its first connection for its later calls.
    :raises ValueError: for an unknown name, an address without Ray, or Ray not installed
    """

    name: str = "loky"
    address: str | None = None

    def __post_init__(self) -> None:
        if self.name not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {self.name!r}")
        if self.address is not None and self.name != "ray":
            raise ValueError(f"an address is for the ray backend, not {self.name!r}: got {self.address!r}")
        if self.name == "ray":
            import_ray()


LOKY = Backend()  # the default: processes of this machine


def import_ray() -> ModuleType:
    """:return: the ``ray`` module :raises ValueError: when it is not installed, with how to install it"""
    try:
        return importlib.import_module("ray")
    except ImportError as error:
        raise ValueError(f"the ray backend needs Ray ({error}): pip install 'sb3-trlsd[cluster]'") from None


def call(index: int, function: Callable[..., Result], args: tuple, kwargs: dict) -> tuple[int, Result]:
    """``(index, function(*args, **kwargs))``, with one BLAS thread."""
    # The products of a run are small: BLAS threads only fight the other workers for the cores.
    with threadpool_limits(1):
        return index, function(*args, **kwargs)


def _loky_worker_call(
    index: int, function: Callable[..., Result], args: tuple, kwargs: dict
) -> tuple[int, Result]:
    """
    ``call`` in a loky worker, which leaves SIGINT to the command: Ctrl-C in a terminal reaches the whole
    process group, and a worker raising ``KeyboardInterrupt`` between two runs (outside any job: loky's
    idle loop) would print multiprocessing's traceback. The command stops the pool itself, workers included.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return call(index, function, args, kwargs)


def cluster_call(fingerprint: str, index: int, function: Callable, args: tuple, kwargs: dict) -> bytes:
    """
    ``call`` on a node of a Ray cluster, once the node is found to run the driver's code.

    :param fingerprint: ``code_fingerprint`` of ``function``'s module on the driver
    :return: the pickled ``(index, result)``: unpickled, its arrays are the driver's own and writable, as
        from loky (Ray would give read-only views of its object store)
    :raises ValueError: if the node's code differs: the run cache would keep its results under the key of
        the driver's code
    """
    found = code_fingerprint(function.__module__)
    if found != fingerprint:
        raise ValueError(
            f"the node {socket.gethostname()} runs other code than the driver ({function.__module__}: "
            f"fingerprint {found[:12]}, driver {fingerprint[:12]}): install the same sb3-trlsd on every node"
        )
    return pickle.dumps(call(index, function, args, kwargs))


def finished(
    function: Callable[..., Result],
    jobs: Sequence[tuple[tuple, dict]],
    indices: list[int],
    workers: int,
    backend: Backend,
) -> Generator[tuple[int, Result], None, None]:
    """
    ``(index, result)`` of the jobs ``indices`` as they finish.

    :param workers: loky processes (1, or a single job: in this process); CPUs of a local Ray cluster
    :param backend: where they run
    """
    if not indices:  # everything was kept: no pool to start, no cluster to join
        return
    if backend.name == "ray":
        yield from _ray_finished(function, jobs, indices, workers, backend.address)
    elif workers <= 1 or len(indices) == 1:  # no process to start for one run
        for index in indices:
            yield call(index, function, *jobs[index])
    else:
        yield from _loky_finished(function, jobs, indices, workers)


def _loky_finished(
    function: Callable[..., Result], jobs: Sequence[tuple[tuple, dict]], indices: list[int], workers: int
) -> Generator[tuple[int, Result], None, None]:
    # One run per dispatch (batch_size=1) and 2 per worker queued at most: a finished run is kept at once.
    parallel = Parallel(n_jobs=workers, backend="loky", return_as="generator_unordered", batch_size=1)
    results = parallel(delayed(_loky_worker_call)(index, function, *jobs[index]) for index in indices)
    try:
        yield from results
    finally:
        with warnings.catch_warnings():  # joblib counts the runs lost: RunsInterrupted says what is kept
            warnings.simplefilter("ignore", UserWarning)
            results.close()  # aborts the pool (kills its workers) unless every run was consumed
        # loky keeps its workers for the next call: end them, none outlives the runs.
        get_reusable_executor().shutdown(wait=True, kill_workers=True)


def _connect(ray: ModuleType, address: str | None, workers: int) -> None:
    """
    ``ray.init``, this process's SIGTERM handler kept: Ray's exits at once, where the command line's stops
    the runs and says what was kept.
    """
    handler = signal.getsignal(signal.SIGTERM)
    try:
        if address is None:  # "local": a new cluster even if this machine runs one; ends with this process
            ray.init(address="local", num_cpus=workers)
        else:
            ray.init(address=address)
    finally:
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)


def _ray_finished(
    function: Callable[..., Result],
    jobs: Sequence[tuple[tuple, dict]],
    indices: list[int],
    workers: int,
    address: str | None,
) -> Generator[tuple[int, Result], None, None]:
    ray = import_ray()
    if not ray.is_initialized():
        _connect(ray, address, workers)
    remote = ray.remote(num_cpus=1)(cluster_call)
    fingerprint = code_fingerprint(function.__module__)
    limit = TASKS_PER_CPU * max(1, int(ray.cluster_resources().get("CPU", 1)))
    queued = iter(indices)
    pending: list[Any] = []
    try:
        while True:
            for index in itertools.islice(queued, limit - len(pending)):
                pending.append(remote.remote(fingerprint, index, function, *jobs[index]))
            if not pending:
                return
            # A timeout, so that SIGINT's handler (run between bytecodes) raises within WAIT_SECONDS.
            ready, pending = ray.wait(pending, num_returns=1, timeout=WAIT_SECONDS)
            for reference in ready:
                try:
                    yield pickle.loads(ray.get(reference))
                except ray.exceptions.RayTaskError as error:
                    if error.cause is None:  # an exception Ray could not bring back
                        raise
                    # The task's own exception, as loky re-raises it (Ray's has the remote traceback).
                    raise error.cause from error
    finally:
        for reference in pending:
            ray.cancel(reference, force=True)
