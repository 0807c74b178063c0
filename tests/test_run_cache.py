"""
The kept runs of ``reproduce``: keys, code fingerprints, the ``.npz`` + JSON format (nothing unpickled),
damaged files, and ``run_jobs`` loading, running and keeping them.
"""

import errno
import json
import os
import pickle
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from sb3_trlsd_lab.execution import run_cache
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.run_cache import RunCache, run_key
from sb3_trlsd_lab.execution.runner import Method, RunRecord, Snapshot, multitask_run, transfer_run

CALL_LOG_VARIABLE = "SB3_TRLSD_TEST_CALL_LOG"  # file where counted_transfer_run writes the seed of each call


def counted_transfer_run(*args: Any, **kwargs: Any) -> RunRecord:
    """``transfer_run``, writing its seed to the file ``$SB3_TRLSD_TEST_CALL_LOG`` (workers can write it)."""
    with open(os.environ[CALL_LOG_VARIABLE], "a") as log:
        log.write(f"{args[2]}\n")
    return transfer_run(*args, **kwargs)


@pytest.fixture
def called_seeds(tmp_path, monkeypatch):
    """A function returning the seeds ``counted_transfer_run`` has been called with so far, in order."""
    log = tmp_path / "calls.txt"
    log.touch()
    monkeypatch.setenv(CALL_LOG_VARIABLE, str(log))
    return lambda: [int(line) for line in log.read_text().split()]


def small_jobs(tasks_and_seeds, **kwargs) -> list[tuple[tuple, dict]]:
    """Jobs of ``counted_transfer_run``: 300 source and 30 online transitions of the ridge head."""
    return [
        ((Method("ridge"), task, seed), {"n_source": 300, "n_online": 30, **kwargs})
        for task, seed in tasks_and_seeds
    ]


def assert_same_records(records: list[RunRecord], expected: list[RunRecord]) -> None:
    assert len(records) == len(expected)
    for record, other in zip(records, expected, strict=True):
        np.testing.assert_array_equal(record.rewards, other.rewards)
        np.testing.assert_array_equal(record.tasks, other.tasks)
        assert (record.policy_updates, record.seconds) == (other.policy_updates, other.seconds)
        assert len(record.snapshots) == len(other.snapshots)
        for snapshot, other_snapshot in zip(record.snapshots, other.snapshots, strict=True):
            assert snapshot.step == other_snapshot.step
            np.testing.assert_array_equal(snapshot.reward_estimate, other_snapshot.reward_estimate)
            np.testing.assert_array_equal(snapshot.policy, other_snapshot.policy)
            np.testing.assert_array_equal(snapshot.trajectory, other_snapshot.trajectory)


def test_run_jobs_loads_finished_runs_from_the_cache(tmp_path, called_seeds):
    """A second call with the same cache must return the stored records without running anything."""
    jobs = small_jobs([(3, 0), (8, 1)], snapshot_at=[10])
    first = run_jobs(counted_transfer_run, jobs, cache=tmp_path / "runs")
    assert called_seeds() == [0, 1]
    assert len(list((tmp_path / "runs").iterdir())) == 2  # one file per run, no temporary file left

    second = run_jobs(counted_transfer_run, jobs, cache=tmp_path / "runs")
    assert called_seeds() == [0, 1]
    assert_same_records(second, first)
    assert second[0].snapshots  # pictures survive the round trip


def test_run_jobs_misses_the_cache_when_an_argument_or_the_code_changes(tmp_path, called_seeds, monkeypatch):
    """A stale record would be silently plotted: another seed, or edited code, must run again."""
    run_jobs(counted_transfer_run, small_jobs([(3, 0)]), cache=tmp_path)
    (other_seed,) = run_jobs(counted_transfer_run, small_jobs([(3, 1)]), cache=tmp_path)
    assert called_seeds() == [0, 1]
    assert other_seed.tasks[0] == 3

    monkeypatch.setattr(run_cache, "code_fingerprint", lambda module: "the code after an edit")
    run_jobs(counted_transfer_run, small_jobs([(3, 0)]), cache=tmp_path)
    assert called_seeds() == [0, 1, 0]
    assert len(list(tmp_path.glob("*.npz"))) == 3


def test_fingerprint_covers_the_code_a_run_imports_and_not_the_reporting():
    """Editing the algorithm must invalidate the runs; redrawing a figure or the command line must not."""
    modules = run_cache.fingerprinted_modules("sb3_trlsd_lab.execution.runner")
    for executed in (
        "sb3_trlsd.trlsd",
        "sb3_trlsd.fqi",
        "sb3_trlsd.reward_heads",
        "sb3_trlsd_envs.maze",
        "sb3_trlsd_envs.dynamics",
    ):
        assert executed in modules
    for not_run in ("reporting", "figures", "multitask", "transfer"):
        assert f"sb3_trlsd_lab.paper.{not_run}" not in modules
    assert "sb3_trlsd_lab.cli" not in modules


def test_fingerprint_changes_with_an_imported_module_only(tmp_path, monkeypatch):
    """A package where the run imports ``core`` inside a function, and ``plot`` is never imported by it."""
    package = tmp_path / "fakepkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "run.py").write_text("def run():\n    from fakepkg import core\n    return core.VALUE\n")
    (package / "core.py").write_text("VALUE = 1\n")
    (package / "plot.py").write_text("from fakepkg.run import run\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(run_cache, "FINGERPRINTED_PACKAGES", ("fakepkg",))
    assert run_cache.fingerprinted_modules("fakepkg.run") == {"fakepkg", "fakepkg.run", "fakepkg.core"}

    def fingerprint() -> str:
        run_cache.code_fingerprint.cache_clear()
        return run_cache.code_fingerprint("fakepkg.run")

    before = fingerprint()
    (package / "plot.py").write_text("from fakepkg.run import run\nLABEL = 'redrawn'\n")
    assert fingerprint() == before
    (package / "core.py").write_text("VALUE = 2\n")
    assert fingerprint() != before
    run_cache.code_fingerprint.cache_clear()


def test_run_key_ignores_how_the_same_run_is_spelled():
    """Positional or keyword, defaults left out, ranges or tuples, dict order: one run, one key."""
    method = Method("ridge", kappa=0.3)
    key = run_key(transfer_run, (method, 3, 0), {"snapshot_at": range(2), "env_kwargs": {"a": 1, "b": 2}})
    same_run = {"seed": 0, "n_source": None, "snapshot_at": (0, 1), "env_kwargs": {"b": 2, "a": 1}}
    assert run_key(transfer_run, (Method("ridge", kappa=0.3), 3), same_run) == key
    another_method = run_key(transfer_run, (Method("ridge", kappa=0.1), 3, 0), {})
    assert another_method != run_key(transfer_run, (method, 3, 0), {})
    assert run_key(multitask_run, (method, 0), {}) != run_key(transfer_run, (method, 0, 0), {})
    with pytest.raises(TypeError, match="no canonical form"):
        run_key(transfer_run, (method, 3, 0), {"env_kwargs": {"a": object()}})


def test_run_jobs_runs_only_the_runs_missing_from_the_cache(tmp_path, called_seeds):
    """A killed reproduction resumes: the cached runs are loaded, the others run, all in the jobs' order."""
    tasks_and_seeds = [(2, 0), (5, 1), (11, 2), (17, 3)]
    cached = run_jobs(counted_transfer_run, small_jobs(tasks_and_seeds[::2]), cache=tmp_path)
    files = {path: path.stat() for path in tmp_path.glob("*.npz")}

    records = run_jobs(counted_transfer_run, small_jobs(tasks_and_seeds), workers=2, cache=tmp_path)
    assert called_seeds()[:2] == [0, 2]
    assert sorted(called_seeds()[2:]) == [1, 3]
    assert [int(record.tasks[0]) for record in records] == [task for task, _ in tasks_and_seeds]
    assert_same_records(records[::2], cached)
    assert all(path.stat().st_mtime_ns == stat.st_mtime_ns for path, stat in files.items())
    assert len(list(tmp_path.glob("*.npz"))) == 4


def a_record() -> RunRecord:
    """A record with every kind of value a run's result holds, snapshots included."""
    snapshot = Snapshot(
        step=3,
        reward_estimate=np.linspace(0, 1, 6).reshape(2, 3),
        policy=np.arange(25).reshape(5, 5),
        trajectory=np.array([[0.5, 1.5], [np.nan, np.nan], [2.0, 2.5]]),
    )
    return RunRecord(
        rewards=np.array([0.0, 1.0, 0.25]),
        tasks=np.array([3, 3, 4]),
        policy_updates=2,
        seconds=0.1 + 0.2,
        snapshots=[snapshot],
    )


def test_a_kept_run_comes_back_as_it_was_stored(tmp_path):
    """Arrays keep their values, dtypes and NaN; scalars, tuples, dicts and None their types."""
    cache = RunCache(tmp_path)
    result = {"record": a_record(), "pair": (1, "a"), "nothing": None, "flag": True, "count": np.int64(7)}
    cache.store(tmp_path / "run.npz", result)
    loaded = cache.load(tmp_path / "run.npz")
    assert_same_records([loaded["record"]], [result["record"]])
    assert loaded["record"].tasks.dtype == np.int64
    assert (loaded["pair"], loaded["nothing"], loaded["flag"], loaded["count"]) == ((1, "a"), None, True, 7)
    with np.load(tmp_path / "run.npz", allow_pickle=False) as archive:  # nothing in it needs unpickling
        assert all(archive[name].dtype != object for name in archive.files)


def test_a_store_that_fails_midway_keeps_the_earlier_run(tmp_path, monkeypatch):
    """A full disk midway through the arrays leaves the run kept before whole, and no partial file."""
    cache = RunCache(tmp_path)
    cache.store(tmp_path / "run.npz", {"record": a_record()})

    def failing(file, array, *args, **kwargs):
        file.write(b"\x00" * 64)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np.lib.format, "write_array", failing)
    with pytest.raises(OSError, match="No space left"):
        cache.store(tmp_path / "run.npz", {"record": a_record(), "more": np.zeros(3)})
    monkeypatch.undo()
    assert_same_records([cache.load(tmp_path / "run.npz")["record"]], [a_record()])
    assert os.listdir(tmp_path) == ["run.npz"]


@dataclass
class NotOurs:
    """A dataclass outside sb3_trlsd: a kept run may not name it (reading one would build any class)."""

    value: int


@pytest.mark.parametrize(
    "result",
    [np.array([{"a": 1}], dtype=object), {1: "int key"}, {1, 2}, NotOurs(1)],
    ids=["object array", "int key", "set", "foreign dataclass"],
)
def test_a_result_that_cannot_be_read_back_safely_is_not_stored(tmp_path, result):
    with pytest.raises(TypeError, match="a kept run cannot hold"):
        RunCache(tmp_path).store(tmp_path / "run.npz", result)
    assert not list(tmp_path.iterdir())  # no temporary file left either


def write_result_entry(path, structure) -> None:
    np.savez(path, **{run_cache.RESULT_ENTRY: np.array(json.dumps(structure))})


class Touch:
    """Unpickling it creates ``path``: proof that a pickle was executed."""

    def __init__(self, path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return open, (self.path, "w")


DAMAGES = {
    "empty": lambda path: path.write_bytes(b""),
    "truncated": lambda path: path.write_bytes(path.read_bytes()[: path.stat().st_size // 2]),
    "not a zip": lambda path: path.write_text("not a run"),
    "a pickle": lambda path: path.write_bytes(pickle.dumps(Touch(path.with_name("executed")))),
    "object array": lambda path: np.savez(path, result=np.array([Touch(path.with_name("executed"))])),
    "another format": lambda path: write_result_entry(path, {"format": 99, "result": None}),
    "a class not ours": lambda path: write_result_entry(
        path, {"format": 1, "result": {"dataclass": ["subprocess:CompletedProcess", {}]}}
    ),
    "fields changed": lambda path: write_result_entry(
        path, {"format": 1, "result": {"dataclass": ["sb3_trlsd_lab.execution.runner:RunRecord", {}]}}
    ),
}


@pytest.mark.parametrize("damage", list(DAMAGES), ids=list(DAMAGES))
def test_a_damaged_kept_run_is_reported_by_path_and_run_again(tmp_path, called_seeds, damage):
    """Before, such a file stopped ``reproduce`` with an UnpicklingError naming no file (or ran a pickle)."""
    cache = tmp_path / "runs"
    (first,) = run_jobs(counted_transfer_run, small_jobs([(3, 0)]), cache=cache)
    (path,) = cache.iterdir()
    DAMAGES[damage](path)
    with pytest.raises(ValueError, match=re.escape(repr(str(path)))):
        RunCache(cache).load(path)

    with pytest.warns(UserWarning, match=re.escape(f"{str(path)!r}") + ".*running it again"):
        (again,) = run_jobs(counted_transfer_run, small_jobs([(3, 0)]), cache=cache)
    assert called_seeds() == [0, 0]
    np.testing.assert_array_equal(again.rewards, first.rewards)
    assert_same_records([RunCache(cache).load(path)], [again])  # the file is whole again
    assert not (tmp_path / "runs" / "executed").exists()


def test_old_pickled_runs_are_never_read(tmp_path, called_seeds):
    """A cache written by the pickling version (or planted) holds ``.pkl`` files: they are ignored."""
    jobs = small_jobs([(3, 0)])
    path = RunCache(tmp_path).path_of(counted_transfer_run, *jobs[0])
    path.with_suffix(".pkl").write_bytes(pickle.dumps(Touch(tmp_path / "executed")))
    run_jobs(counted_transfer_run, jobs, cache=tmp_path)
    assert called_seeds() == [0]
    assert path.exists() and not (tmp_path / "executed").exists()
