"""
The experiments' fast path against ``TRLSD.learn``, the cache of finished runs, and the ``reproduce``
command on tiny sizes.
"""

import csv
import json
import os
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from matplotlib.image import imread

from sb3_trlsd import collect_transitions
from sb3_trlsd.cli import main
from sb3_trlsd.experiments import FIGURES, multitask, run_cache, runner
from sb3_trlsd.experiments.reporting import (
    mean_and_standard_error,
    moving_average,
    results_table,
    window_means,
)
from sb3_trlsd.experiments.run_cache import run_key
from sb3_trlsd.experiments.runner import Method, RunRecord, multitask_run, run_jobs, transfer_run
from sb3_trlsd_envs import MAZE_ID, expected_reward

CALL_LOG_VARIABLE = "SB3_TRLSD_TEST_CALL_LOG"  # file where counted_transfer_run writes the seed of each call


@pytest.mark.parametrize(
    "method",
    [Method("optimistic ridge"), Method("tabular", reward_head="tabular"), Method("kappa 0", kappa=0.0)],
    ids=lambda method: method.label,
)
def test_fast_path_takes_the_actions_of_learn(method):
    """If the fast path drifted from SB3's loop (seeding, resets, storage precision), states would differ."""
    task, seed, n_source, n_online = 7, 3, 1_500, 250
    record = transfer_run(method, task, seed, n_source=n_source, n_online=n_online)

    env = gym.make(MAZE_ID, task=task)
    model = method.make_model(env, seed)
    source_env = gym.make(MAZE_ID, task=(task + 1 + seed) % 25)  # as transfer_run draws its source
    model.load_transitions(collect_transitions(source_env, n_source, seed=seed + 1), keep_rewards=False)
    model.learn(n_online)
    states = model.replay_buffer.transitions().states[-n_online:]

    np.testing.assert_array_equal(record.rewards, expected_reward(states, task))
    assert record.policy_updates == model.policy_updates[task]


def test_multitask_fast_path_takes_the_actions_of_learn():
    """Round-robin tasks with a time limit: each task fitted at its first step, trajectories cut at 50."""
    method, seed = Method("ridge"), 5
    record = multitask_run(method, seed, n_turns=1, episode_steps=20)

    env = gym.make(
        MAZE_ID, tasks="all", task_schedule="round_robin", termination_prob=0.0, max_episode_steps=20
    )
    model = method.make_model(env, seed)
    model.learn(25 * 20)
    data = model.replay_buffer.transitions()

    np.testing.assert_array_equal(record.tasks, data.tasks)
    np.testing.assert_array_equal(record.tasks, np.repeat(np.arange(25), 20))
    for task in range(25):
        rows = data.tasks == task
        np.testing.assert_array_equal(record.rewards[rows], expected_reward(data.states[rows], task))
    assert record.policy_updates == sum(model.policy_updates.values())


def test_reporting_statistics_match_numpy():
    """Wrong standard errors or windows would misstate every figure's uncertainty."""
    values = np.arange(12.0).reshape(3, 4)
    mean, se = mean_and_standard_error(values)
    np.testing.assert_allclose(mean, [4, 5, 6, 7])
    np.testing.assert_allclose(se, np.full(4, 4.0 / np.sqrt(3)))
    windows = window_means(values, [(0, 2), (2, 4)])
    assert windows["[0, 2)"]["mean"] == pytest.approx(4.5)
    assert windows["[2, 4)"]["se"] == pytest.approx(4.0 / np.sqrt(3))
    np.testing.assert_allclose(moving_average(np.array([1.0, 3.0, 5.0, 7.0]), 2), [1, 2, 4, 6])


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
    assert len(list(tmp_path.glob("*.pkl"))) == 3


def test_fingerprint_covers_the_code_a_run_imports_and_not_the_reporting():
    """Editing the algorithm must invalidate the runs; redrawing a figure or the command line must not."""
    modules = run_cache.fingerprinted_modules("sb3_trlsd.experiments.runner")
    for executed in (
        "sb3_trlsd.trlsd",
        "sb3_trlsd.fqi",
        "sb3_trlsd.reward_heads",
        "sb3_trlsd_envs.maze",
        "sb3_trlsd_envs.dynamics",
    ):
        assert executed in modules
    for not_run in ("reporting", "figures", "multitask", "transfer"):
        assert f"sb3_trlsd.experiments.{not_run}" not in modules
    assert "sb3_trlsd.cli" not in modules


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
    files = {path: path.stat() for path in tmp_path.glob("*.pkl")}

    records = run_jobs(counted_transfer_run, small_jobs(tasks_and_seeds), workers=2, cache=tmp_path)
    assert called_seeds()[:2] == [0, 2]
    assert sorted(called_seeds()[2:]) == [1, 3]
    assert [int(record.tasks[0]) for record in records] == [task for task, _ in tasks_and_seeds]
    assert_same_records(records[::2], cached)
    assert all(path.stat().st_mtime_ns == stat.st_mtime_ns for path, stat in files.items())
    assert len(list(tmp_path.glob("*.pkl"))) == 4


@pytest.fixture
def tiny_sizes(monkeypatch):
    """Few source transitions and one short multi-task turn: the figures' code paths in seconds."""
    monkeypatch.setattr(runner, "SOURCE_TRANSITIONS", 400)
    monkeypatch.setattr(multitask, "TURNS", 1)
    monkeypatch.setattr(multitask, "EPISODE_STEPS", 8)


@pytest.mark.parametrize("figure", list(FIGURES))
def test_reproduce_writes_valid_files(figure, tiny_sizes, tmp_path, capsys):
    """Each figure's command must leave a readable CSV of curves, a PNG and a JSON summary."""
    assert (
        main(["reproduce", figure, "--runs", "1", "--out", str(tmp_path), "--workers", "1", "--seed", "2"])
        == 0
    )
    assert f"{figure} done" in capsys.readouterr().out

    with open(tmp_path / f"{figure}.csv") as file:
        rows = list(csv.DictReader(file))
    x_name = "episode" if figure == "fig8" else "transition"
    assert rows and set(rows[0]) == {x_name, "method", "mean", "se", "runs"}
    assert all(np.isfinite(float(row["mean"])) and float(row["se"]) >= 0 for row in rows)

    image = imread(tmp_path / f"{figure}.png")
    assert image.ndim == 3 and min(image.shape[:2]) > 200

    data = json.loads((tmp_path / f"{figure}.json").read_text())
    assert data["figure"] == figure and data["seed"] == 2 and data["wall_time_seconds"] > 0
    assert data["package_version"] and data["parameters"] and data["results"]


def test_reproduce_resumes_from_the_runs_of_a_previous_command(tiny_sizes, tmp_path, monkeypatch):
    """``<out>/runs`` keeps one file per run; the same command again runs nothing, ``--no-cache`` does."""
    command = ["reproduce", "fig8", "--runs", "1", "--workers", "1", "--seed", "2", "--out"]
    assert main([*command, str(tmp_path)]) == 0
    files = {path.name: path.stat().st_mtime_ns for path in (tmp_path / "runs").iterdir()}
    assert len(files) == len(multitask.METHODS)
    first = json.loads((tmp_path / "fig8.json").read_text())

    def no_run(*args, **kwargs):
        raise AssertionError("a finished run ran again")

    monkeypatch.setattr(runner, "run_online", no_run)
    assert main([*command, str(tmp_path)]) == 0
    assert {path.name: path.stat().st_mtime_ns for path in (tmp_path / "runs").iterdir()} == files
    assert json.loads((tmp_path / "fig8.json").read_text())["results"] == first["results"]

    with pytest.raises(AssertionError, match="ran again"):
        main([*command, str(tmp_path / "uncached"), "--no-cache"])
    assert not (tmp_path / "uncached" / "runs").exists()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["reproduce", "fig9"], "invalid choice: 'fig9'"),
        (["reproduce", "fig5", "--runs", "0"], "expected an integer >= 1, got 0"),
        (["reproduce", "fig5", "--workers", "two"], "expected an integer >= 1, got 'two'"),
    ],
    ids=["unknown figure", "zero runs", "workers not a number"],
)
def test_reproduce_rejects_bad_arguments(arguments, message, capsys):
    with pytest.raises(SystemExit) as error:
        main(arguments)
    assert error.value.code == 2
    assert message in capsys.readouterr().err


def test_reproduce_rejects_an_unwritable_output_directory(tmp_path, capsys):
    """A file where the directory should be: the error names the directory before any run starts."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(SystemExit) as error:
        main(["reproduce", "fig5", "--out", str(blocker / "results")])
    assert error.value.code == 2
    assert "cannot create the output directory" in capsys.readouterr().err


def test_results_table_has_a_row_per_method_with_standard_errors():
    """The table the command prints (and the README quotes) must carry every method's mean ± se."""
    data = {
        "figure": "figX",
        "results": {
            "a": {"reward": {"[0, 10)": {"mean": 0.5, "se": 0.01}}, "runs": 3},
            "b": {"reward": {"[0, 10)": {"mean": 0.25, "se": 0.02}}, "runs": 3},
        },
    }
    lines = results_table(data).splitlines()
    assert lines[0] == "| method | reward [0, 10) | runs |"
    assert lines[2:] == ["| a | 0.500 ± 0.010 | 3 |", "| b | 0.250 ± 0.020 | 3 |"]
