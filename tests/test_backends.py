"""
The backends of ``run_jobs``: the ray backend against a real Ray cluster on this machine (``ray start
--head`` on the loopback, 2 CPUs, a token of its own), through ``sb3-trlsd reproduce`` and ``run_jobs``;
and the options' checks, which need no Ray.
"""

import _thread
import importlib.util
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

import pytest

from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.execution import backends
from sb3_trlsd_lab.execution.backends import Backend
from sb3_trlsd_lab.execution.jobs import RunsInterrupted, run_jobs
from sb3_trlsd_lab.execution.runner import multitask_run
from sb3_trlsd_lab.paper import multitask
from sb3_trlsd_lab.registry import reproduce
from tests.test_cli import (
    EPISODE_STEPS,
    RUNS,
    TINY_SB3_TRLSD,
    TURNS,
    assert_one_line_error,
    assert_says_what_it_kept,
    interrupt_reproduce,
    live_processes,
    needs_proc,
)

# Not pytest.importorskip: importing Ray before the cluster's environment is set would bind this
# process's driver to the machine's network address instead of the loopback.
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed, the ray backend is not tested: pip install -e '.[cluster]'",
)
# Bounds on waits for a state, for a test that would otherwise hang: none is reached unless something is
# broken, however loaded the machine (a fresh clone compiles every module; other jobs share its cores).
CLUSTER_START_SECONDS = 300
HANG_SECONDS = 300


@dataclass(frozen=True)
class Cluster:
    """A Ray cluster of this machine: the address to join, the environment to join it with, its head."""

    address: str
    env: dict[str, str]
    head: int  # pid of ``ray start --block``, whose descendants are the cluster's processes


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def descendants(pid: int) -> dict[int, str]:
    """The live processes descending from ``pid``, with their command lines."""
    alive = live_processes()
    children: dict[int, list[int]] = {}
    for child, process in alive.items():
        children.setdefault(process.parent, []).append(child)
    found: dict[int, str] = {}
    pending = list(children.get(pid, []))
    while pending:
        child = pending.pop()
        found[child] = alive[child].command
        pending.extend(children.get(child, []))
    return found


def running_tasks(cluster: Cluster) -> list[int]:
    """Worker processes of ``cluster`` running a task of ``run_jobs`` (Ray titles them by function)."""
    return [
        pid for pid, command in descendants(cluster.head).items() if command.startswith("ray::cluster_call")
    ]


RAY_INTERNAL_ABORT = "You have likely discovered a bug in Ray"


def release(fifo: Path) -> None:
    """
    Let every reader of the FIFO ``fifo`` go, those waiting and those to come: the readers waiting to open
    it meet a writer, which closes at once (they read nothing), and its path becomes an empty regular file.
    """
    try:
        writer = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
    except OSError:  # ENXIO: no reader waits
        writer = None
    empty = fifo.with_name(fifo.name + ".released")
    empty.write_bytes(b"")
    os.replace(empty, fifo)
    if writer is not None:
        os.close(writer)


def wait_for(condition: Callable[[], bool], seconds: float) -> bool:
    """Whether ``condition`` holds, polled until it does or ``seconds`` have passed."""
    deadline = time.monotonic() + seconds
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.05)
    return condition()


@pytest.fixture(scope="module")
def cluster() -> Iterator[Cluster]:
    """
    ``ray start --head --block`` on 127.0.0.1 with 2 CPUs; stopped at the end by ending that process (and,
    should any survive it, the processes it started, by pid: never ``ray stop``, which would end every Ray
    cluster of the machine). This process's environment is the cluster's while the module runs.
    """
    env = {
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",  # loopback addresses only, as Ray does on macOS
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        "RAY_USAGE_STATS_ENABLED": "0",
    }
    port = free_port()
    temp = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))  # short: Ray's socket paths are limited
    log = temp / "head.log"
    command = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--block", f"--port={port}"]
    options = ["--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"]
    with pytest.MonkeyPatch.context() as patch, open(log, "w") as output:
        for name, value in env.items():
            patch.setenv(name, value)
        head = subprocess.Popen(
            [*command, *options], stdout=output, stderr=subprocess.STDOUT, start_new_session=True
        )
        try:
            started = wait_for(
                lambda: "Ray runtime started" in log.read_text() or head.poll() is not None,
                CLUSTER_START_SECONDS,
            )
            assert started and head.poll() is None, f"ray start failed:\n{log.read_text()}"
            yield Cluster(f"127.0.0.1:{port}", dict(os.environ), head.pid)
        finally:
            left = descendants(head.pid)
            head.terminate()  # --block: ends the processes it started
            try:
                head.wait(timeout=20)
            except subprocess.TimeoutExpired:
                head.kill()
                head.wait()
            alive = live_processes()
            for pid in (
                pid for pid, command in left.items() if pid in alive and alive[pid].command == command
            ):
                # the same pid and command line: one of the cluster's, not a process that took a freed pid
                with suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture
def driver(cluster: Cluster) -> Iterator[Cluster]:
    """This process as a driver of ``cluster`` (``run_jobs`` joins it), disconnected afterwards."""
    yield cluster
    import ray

    ray.shutdown()


@needs_ray
def test_a_ray_reproduction_writes_the_csv_of_loky(cluster, tmp_path, monkeypatch):
    """
    Runs are pure functions of their seeds: on the cluster's workers they must give the figure of this
    machine's processes (before, a reproduction could not leave this machine).
    """
    command = ["reproduce", "fig8", "--runs", str(RUNS), "--seed", "0", "--out"]
    ray_out, loky_out = tmp_path / "ray", tmp_path / "loky"
    on_ray = [*command, str(ray_out), "--backend", "ray", "--address", cluster.address]
    result = subprocess.run(
        [sys.executable, "-c", TINY_SB3_TRLSD, *on_ray],
        env=cluster.env,
        capture_output=True,
        text=True,
        timeout=HANG_SECONDS,
    )
    assert result.returncode == 0, result.stderr
    assert "fig8 done" in result.stdout
    assert f"Connecting to existing Ray cluster at address: {cluster.address}" in result.stderr
    assert len(list(ray_out.glob("runs/*.npz"))) == 3 * RUNS  # kept by the driver, on its disk

    monkeypatch.setattr(multitask, "TURNS", TURNS)
    monkeypatch.setattr(multitask, "EPISODE_STEPS", EPISODE_STEPS)
    assert main([*command, str(loky_out), "--workers", "1"]) == 0
    assert (ray_out / "fig8.csv").read_text() == (loky_out / "fig8.csv").read_text()


@needs_ray
@needs_proc
@pytest.mark.parametrize(
    ("signum", "to_group"), [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["ctrl-c", "sigterm"]
)
def test_an_interrupted_ray_reproduction_says_what_it_kept(cluster, tmp_path, signum, to_group):
    """Ray must not take over the command's signals: the same status and message as with loky."""
    options = ["--backend", "ray", "--address", cluster.address]
    for attempt in range(2):
        out = tmp_path / f"interrupted-{attempt}"
        status, error = interrupt_reproduce(out, signum, to_group, options=options, env=cluster.env)
        # Ray's core worker sometimes aborts on a task cancelled as its reply arrives ("Check failed: ...
        # Tried to complete task that was not pending", its own words below): an upstream bug, not ours,
        # about 1 run in 6 here. Only that abort earns a second attempt.
        if RAY_INTERNAL_ABORT not in error:
            break
    assert status == 128 + signum, error
    assert_says_what_it_kept(error, out)
    none_left = wait_for(lambda: not running_tasks(cluster), HANG_SECONDS)
    assert none_left, "tasks of the command still run on the cluster"


def writer_of(fifo: Path) -> int | None:
    """A write end of the FIFO ``fifo`` if some process has it open to read (or waits to), else None."""
    try:
        return os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
    except OSError:  # ENXIO: no reader
        return None


def readers_of(fifo: Path) -> list[int]:
    """The processes other than this one that hold ``fifo`` open."""
    found = []
    for fd_dir in Path("/proc").glob("[0-9]*/fd"):
        pid = int(fd_dir.parent.name)
        if pid == os.getpid():
            continue
        with suppress(OSError):  # the process ended, or is not ours to read
            if any(os.readlink(fd) == str(fifo) for fd in fd_dir.iterdir()):
                found.append(pid)
    return found


@needs_ray
@needs_proc
def test_an_interrupt_cancels_the_tasks_on_the_cluster(driver, tmp_path):
    """
    A driver that lives on (a notebook's Ctrl-C) must not leave its tasks running on the cluster, nor wait
    for them: RunsInterrupted, and no task of it left. Its tasks read a FIFO whose write end the test holds
    and never writes to: they end only when cancelled, so neither claim depends on how fast runs are or how
    loaded the machine is. That a task runs, and that none is left, is read from the FIFO itself (a reader
    opened it; no process holds it), not from the names Ray gives its worker processes.
    """
    fifo = tmp_path / "never-written"
    os.mkfifo(fifo)
    jobs = [((fifo,), {}) for _ in range(6)]
    returned = threading.Event()  # run_jobs has returned or raised
    released: list[str] = []  # why the tasks were let go by the test, which only a failing run_jobs needs
    writers: list[int] = []  # the write end, held open so that the tasks' reads block instead of ending

    def interrupt_once_a_task_runs() -> None:
        deadline = time.monotonic() + HANG_SECONDS
        while (writer := writer_of(fifo)) is None:
            if returned.wait(0.05):
                return
            if time.monotonic() > deadline:
                released.append(f"no task of run_jobs ran within {HANG_SECONDS} s")
                release(fifo)
                return
        writers.append(writer)
        _thread.interrupt_main()
        if not returned.wait(HANG_SECONDS):  # run_jobs waits for its tasks, which would never end
            released.append("run_jobs waited for its tasks instead of cancelling them")
            release(fifo)

    threading.Thread(target=interrupt_once_a_task_runs, daemon=True).start()
    try:
        with pytest.raises(RunsInterrupted) as interrupted:
            run_jobs(Path.read_bytes, jobs, backend=Backend("ray", driver.address))
        returned.set()
        assert not released, released[0]
        assert (interrupted.value.kept, interrupted.value.total) == (0, len(jobs))
        assert wait_for(lambda: not readers_of(fifo), HANG_SECONDS), "the cancelled tasks still run"
    finally:
        returned.set()
        for writer in writers:
            os.close(writer)
        release(fifo)  # whatever happened, no task of this test holds the cluster's CPUs after it


@needs_ray
def test_a_node_running_other_code_than_the_driver_is_refused(driver, tmp_path, monkeypatch):
    """Its runs would be kept under the key of the driver's code: a stale figure, and nothing to say so."""
    monkeypatch.setattr(backends, "code_fingerprint", lambda module: "0" * 64)  # the driver's code, edited
    jobs = [((multitask.METHODS[0], seed, TURNS, EPISODE_STEPS), {}) for seed in range(2)]
    with pytest.raises(ValueError, match=r"runs other code than the driver .* same sb3-trlsd on every node"):
        run_jobs(multitask_run, jobs, cache=tmp_path, backend=Backend("ray", driver.address))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("arguments", "fragments"),
    [
        (["--backend", "ray"], ["the ray backend needs Ray", "pip install 'sb3-trlsd[cluster]'"]),
        (["--address", "auto"], ["an address is for the ray backend, not 'loky'", "'auto'"]),
    ],
    ids=["ray not installed", "address without ray"],
)
def test_a_backend_that_cannot_be_used_is_one_line_and_status_2(
    tmp_path, monkeypatch, capsys, arguments, fragments
):
    """Found before any run, as other bad options are, not as a traceback once the first runs are done."""
    monkeypatch.setitem(sys.modules, "ray", None)  # what ``import ray`` meets where Ray is not installed
    assert main(["reproduce", "fig8", "--out", str(tmp_path), *arguments]) == 2
    assert_one_line_error(capsys, *fragments)
    assert not list((tmp_path / "runs").iterdir())


def test_reproduce_names_the_backends_it_accepts(tmp_path):
    with pytest.raises(ValueError, match="backend must be one of loky, ray, got 'dask'"):
        reproduce("fig8", tmp_path, backend="dask")
