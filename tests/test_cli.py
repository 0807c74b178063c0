"""
The ``sb3-trlsd`` command line under faults: unusable paths, interrupts (SIGINT, SIGTERM, a second
signal) of a real ``reproduce`` process, errors while writing.
"""

import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

import pytest
from matplotlib.image import imread

from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.cli_parser import IMAGE_EXTENSIONS
from sb3_trlsd_lab.paper import multitask

TURNS, EPISODE_STEPS = 1, 8  # Figure 8 at these sizes: about 0.2 s per run
RUNS = 4  # per method: 12 runs of Figure 8
# ``sb3-trlsd`` with Figure 8 at the sizes above (set in the main process, where the jobs are made).
TINY_SB3_TRLSD = f"""
import sys
from sb3_trlsd_lab.paper import multitask
multitask.TURNS, multitask.EPISODE_STEPS = {TURNS}, {EPISODE_STEPS}
from sb3_trlsd_lab.cli import main
sys.exit(main(sys.argv[1:]))
"""
# A process holding a child process in ``stopped_by_signals``, whose clean-up after the first signal never
# ends. Neither it nor its child ends on its own (no sleep that a slow machine could outlast): only a kill
# ends them, so a second signal that waited for the clean-up, or left the child, cannot pass unseen.
ENDLESS_CLEAN_UP = """
import multiprocessing, signal
from sb3_trlsd_lab.cli import stopped_by_signals
child = multiprocessing.get_context("fork").Process(target=signal.pause)
child.start()
with stopped_by_signals():
    try:
        print("ready", flush=True)
        while True:
            signal.pause()
    except KeyboardInterrupt:
        print("cleaning up", flush=True)
        while True:
            signal.pause()
"""
# Bound on each wait for a state (a run kept, a line printed, a process or process group ended), for a test
# that would otherwise hang: none is reached unless something is broken, however loaded the machine.
HANG_SECONDS = 300
needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")


def assert_one_line_error(capsys, *fragments: str) -> None:
    """The command wrote one line to stderr, naming each fragment, and no traceback."""
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "Traceback" not in error, error
    for fragment in fragments:
        assert fragment in error, error


@pytest.fixture
def a_file(tmp_path) -> Path:
    """A regular file: no directory can be made under it."""
    path = tmp_path / "file.txt"
    path.write_text("")
    return path


@pytest.mark.parametrize(
    ("arguments", "named", "reason"),
    [
        (["reproduce", "fig5", "--out", "{file}/results"], "{file}/results", "Not a directory"),
        (["reproduce", "fig5", "--out", "{file}"], "{file}", "a file has that name"),
        (
            ["reproduce", "fig5", "--out", "{tmp}/out", "--cache", "{file}/runs"],
            "{file}/runs",
            "Not a directory",
        ),
        (["render", "--out", "{file}/maze.png"], "{file}", "a file has that name"),
        (["render", "--out", "{tmp}/maze.bmq"], "{tmp}/maze.bmq", "must end with one of .png"),
        (["render", "--out", "{tmp}/maze"], "{tmp}/maze", "must end with one of .png"),
    ],
    ids=["out under a file", "out is a file", "cache under a file", "image under a file", "unknown", "none"],
)
def test_an_unusable_path_is_one_line_and_status_2(tmp_path, a_file, capsys, arguments, named, reason):
    """Before, --out under a file was an argparse error but a read-only one or render's were tracebacks."""
    fill = {"file": a_file, "tmp": tmp_path}
    assert main([argument.format(**fill) for argument in arguments]) == 2
    assert_one_line_error(capsys, named.format(**fill), reason)


@needs_proc
@pytest.mark.parametrize(
    "arguments",
    [
        ["reproduce", "fig5", "--out", "/proc/sb3-trlsd-results"],
        ["reproduce", "fig5", "--out", "{tmp}", "--cache", "/proc"],
        ["render", "--out", "/proc/maze.png"],
    ],
    ids=["out", "cache", "render"],
)
def test_a_place_that_cannot_be_written_is_one_line_and_status_2(tmp_path, capsys, arguments):
    """/proc refuses new files even to root (the suite runs as root: chmod would not stop it)."""
    assert main([argument.format(tmp=tmp_path) for argument in arguments]) == 2
    assert_one_line_error(capsys, "cannot make or write to the directory '/proc")


@pytest.mark.parametrize("extension", IMAGE_EXTENSIONS)
def test_render_writes_every_format_it_accepts(tmp_path, extension, capsys):
    """The extensions ``render`` checks for are ones matplotlib's imsave really writes."""
    path = tmp_path / "new" / f"maze{extension}"
    assert main(["render", "--out", str(path), "--steps", "3"]) == 0
    assert path.stat().st_size > 0
    if extension in (".png", ".jpg", ".jpeg", ".tiff", ".webp"):
        assert min(imread(path).shape[:2]) > 200


def test_an_error_while_writing_is_one_line_and_status_1(tmp_path, monkeypatch, capsys):
    """A disk that fills up during a reproduction: the OSError's own message, without a traceback."""

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / "fig8.csv"))

    monkeypatch.setattr("sb3_trlsd_lab.registry.reproduce", disk_full)
    assert main(["reproduce", "fig8", "--out", str(tmp_path)]) == 1
    assert_one_line_error(capsys, "No space left on device", "fig8.csv")


@dataclass(frozen=True)
class Process:
    parent: int
    group: int
    command: str  # its command line, arguments separated by spaces


def live_processes() -> dict[int, Process]:
    """The processes of the machine still alive (a zombie is dead, only not yet reaped), by pid."""
    alive = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():  # self, thread-self, and what is not a process
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):  # it ended meanwhile
            continue
        if fields[0] != "Z":
            alive[int(entry.name)] = Process(int(fields[1]), int(fields[2]), command.strip())
    return alive


def live_processes_of_group(group: int) -> list[int]:
    """Processes of the process group ``group`` still alive."""
    return [pid for pid, process in live_processes().items() if process.group == group]


def wait_for(condition: Callable[[], object], seconds: float) -> bool:
    """Whether ``condition`` holds, polled until it does or ``seconds`` have passed."""
    deadline = time.monotonic() + seconds
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.02)
    return bool(condition())


def wait_for_exit(process: subprocess.Popen, since: str) -> int:
    """The exit status of ``process`` once it has ended; a failure if it still runs after ``HANG_SECONDS``."""
    try:
        return process.wait(HANG_SECONDS)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the process still ran {HANG_SECONDS} s after {since}")


def next_line(stream) -> bytes:
    """
    The next line a process writes to ``stream`` (unbuffered: ``bufsize=0``, so nothing beyond the line is
    read ahead); b"" if the process closed it; a failure if nothing comes in ``HANG_SECONDS``.
    """
    if not select.select([stream], [], [], HANG_SECONDS)[0]:
        pytest.fail(f"the process wrote nothing in {HANG_SECONDS} s")
    return stream.readline()


def contents(file) -> str:
    """All that was written to the open file ``file``."""
    file.seek(0)
    return file.read()


def assert_group_ends(group: int) -> None:
    """Every process of ``group`` (the command, its workers, their trackers) ends."""
    ended = wait_for(lambda: not live_processes_of_group(group), HANG_SECONDS)
    assert ended, f"processes of the group still run {HANG_SECONDS} s on: {live_processes_of_group(group)}"


def interrupt_reproduce(
    out: Path,
    signum: int,
    to_group: bool,
    options: Sequence[str] = ("--workers", "2"),
    env: dict[str, str] | None = None,
) -> tuple[int, str]:
    """
    Start a tiny ``reproduce fig8`` in a new process group, send ``signum`` once its first run is kept (to
    the whole group, as Ctrl-C in a terminal does, or to the command alone, as ``kill``).

    Every wait is for a state, bounded only by ``HANG_SECONDS``. No worker of the command may outlive it:
    when it has exited, only its resource trackers (which end once the command's pipe to them closes) may
    still be alive, and then its whole group must end. Waiting alone would not do: loky's idle workers end
    on their own after 300 s.

    :param options: the command's options besides its sizes and ``--out`` (default: 2 loky workers)
    :param env: the command's environment (None: this process's)
    :return: the exit status and stderr of the command, which has ended
    """
    command = [sys.executable, "-c", TINY_SB3_TRLSD, "reproduce", "fig8", "--runs", str(RUNS), "--seed", "0"]
    # stderr in a file, not a pipe: the workers share it, and the end of the command must not wait for them.
    with tempfile.TemporaryFile("w+") as stderr:
        process = subprocess.Popen(
            [*command, "--out", str(out), *options],
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            text=True,
            env=env,
            start_new_session=True,  # its own group: the workers can be found, and Ctrl-C imitated
        )
        try:
            kept = wait_for(lambda: list(out.glob("runs/*.npz")) or process.poll() is not None, HANG_SECONDS)
            assert process.poll() is None, f"it ended before any signal: {contents(stderr)}"
            assert kept, f"no run kept in {HANG_SECONDS} s"
            trackers = {
                pid
                for pid, running in live_processes().items()
                if running.group == process.pid and "resource_tracker" in running.command
            }
            (os.killpg if to_group else os.kill)(process.pid, signum)
            status = wait_for_exit(process, since=f"signal {signum}")
            outlived = set(live_processes_of_group(process.pid)) - trackers
            assert not outlived, f"processes of the command outlived it: {outlived}"
            assert_group_ends(process.pid)
        finally:
            with suppress(ProcessLookupError):  # a failure's leftovers: none outlives the test
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        return status, contents(stderr)


def assert_says_what_it_kept(error: str, out: Path) -> int:
    """The one-line message names the runs kept (those in ``out/runs``) and how to resume; returns them."""
    kept = len(list(out.glob("runs/*.npz")))
    assert 1 <= kept < 3 * RUNS
    message = (
        f"interrupted: {kept} of {3 * RUNS} runs of fig8 kept in {out / 'runs'}; run the same command again"
    )
    assert message in error and "Traceback" not in error, error
    return kept


@needs_proc
def test_ctrl_c_stops_reproduce_and_the_same_command_resumes(tmp_path, monkeypatch, capsys):
    """
    Before, one Ctrl-C left every queued run running (none kept) and printed a traceback; a second hung.
    Now: status 130 before the runs are done, the finished runs kept, no worker left, and the rerun runs
    only the rest and writes the CSV an uninterrupted run writes.
    """
    out = tmp_path / "interrupted"
    status, error = interrupt_reproduce(out, signal.SIGINT, to_group=True)
    assert status == 128 + signal.SIGINT
    assert_says_what_it_kept(error, out)
    kept = {path: path.stat().st_mtime_ns for path in out.glob("runs/*.npz")}

    monkeypatch.setattr(multitask, "TURNS", TURNS)
    monkeypatch.setattr(multitask, "EPISODE_STEPS", EPISODE_STEPS)
    command = ["reproduce", "fig8", "--runs", str(RUNS), "--seed", "0", "--workers", "1", "--out"]
    assert main([*command, str(out)]) == 0
    assert {path: path.stat().st_mtime_ns for path in kept} == kept
    assert len(list(out.glob("runs/*.npz"))) == 3 * RUNS
    assert main([*command, str(tmp_path / "uninterrupted"), "--no-cache"]) == 0
    assert (out / "fig8.csv").read_text() == (tmp_path / "uninterrupted" / "fig8.csv").read_text()


@needs_proc
def test_sigterm_stops_reproduce_without_leaving_workers(tmp_path):
    """Before, SIGTERM ended the command at once and left its workers running, orphaned."""
    out = tmp_path / "terminated"
    status, error = interrupt_reproduce(out, signal.SIGTERM, to_group=False)
    assert status == 128 + signal.SIGTERM
    assert_says_what_it_kept(error, out)


@needs_proc
def test_a_second_signal_exits_at_once_and_kills_the_children():
    """
    The first signal's clean-up may be slow: a second one must not wait for it, nor orphan a child. Here the
    clean-up and the child never end on their own: the process ends only if the second signal ends it, and
    its group only if the child is killed.
    """
    process = subprocess.Popen(
        [sys.executable, "-c", ENDLESS_CLEAN_UP],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        bufsize=0,  # lines read as they come, with select
        start_new_session=True,
    )
    try:
        assert next_line(process.stdout) == b"ready\n"
        process.send_signal(signal.SIGINT)
        assert next_line(process.stdout) == b"cleaning up\n"
        process.send_signal(signal.SIGTERM)
        assert wait_for_exit(process, since="the second signal") == 128 + signal.SIGTERM
        assert_group_ends(process.pid)
    finally:
        with suppress(ProcessLookupError):  # a failure's leftovers: none outlives the test
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    assert b"interrupted again, stopped at once" in process.stderr.read()
