"""
The experiments' fast path against ``TRLSD.learn``, and the ``reproduce`` command on tiny sizes (the kept
runs: ``test_run_cache.py``; interrupts and paths: ``test_cli.py``).
"""

import csv
import errno
import json
import os

import gymnasium as gym
import numpy as np
import pytest
from matplotlib.image import imread

from sb3_trlsd import collect_transitions
from sb3_trlsd_envs import MAZE_ID, expected_reward
from sb3_trlsd_lab.benchmarks.mo_suite.suite import write_rows
from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.execution import batches, runner
from sb3_trlsd_lab.execution.runner import Method, multitask_run, transfer_run
from sb3_trlsd_lab.paper import multitask
from sb3_trlsd_lab.paper.figures import new_figure, save_figure
from sb3_trlsd_lab.paper.reporting import (
    mean_and_standard_error,
    moving_average,
    results_table,
    window_means,
    write_curves_csv,
    write_json,
)
from sb3_trlsd_lab.registry import FIGURES


def test_a_transfer_run_records_the_rewards_of_the_states_learn_visits():
    """If ``transfer_run`` drew its source or seeded its env otherwise than a model learning alone, or
    scored other states, its rewards would differ (the engine's callers: ``test_engine.py``)."""
    method, task, seed, n_source, n_online = Method("optimistic ridge"), 7, 3, 1_500, 250
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


@pytest.mark.parametrize("reward_head", ["ridge", "tabular", "thompson", "bernstein"])
def test_a_method_is_the_papers_relabelling_whatever_the_librarys_defaults(reward_head):
    """A figure's method relabels every row with R~ (the paper's Algorithm 1) at the kappa it names, in
    reward units for the draws too, which the library's defaults would take from the largest reward seen."""
    model = Method("m", reward_head=reward_head, kappa=0.3).make_model(gym.make(MAZE_ID, task=0), 0)
    learner = model.task_learner(0)
    assert (learner.optimism, learner.head.kappa) == ("always", 0.3)
    assert getattr(learner.head, "kappa_scale", "reward") == "reward"


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


@pytest.fixture
def tiny_sizes(monkeypatch):
    """Few source transitions and one short multi-task turn: the figures' code paths in seconds."""
    monkeypatch.setattr(runner, "SOURCE_TRANSITIONS", 400)  # runs alone (the pictures of Figures 1-4)
    monkeypatch.setattr(batches, "SOURCE_TRANSITIONS", 400)  # the figures' batches
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
    """``<out>/runs`` keeps one file per batch of runs; the same command again runs nothing, ``--no-cache``
    does."""
    command = ["reproduce", "fig8", "--runs", "1", "--workers", "1", "--seed", "2", "--out"]
    assert main([*command, str(tmp_path)]) == 0
    files = {path.name: path.stat().st_mtime_ns for path in (tmp_path / "runs").iterdir()}
    assert len(files) == len(multitask.METHODS)
    first = json.loads((tmp_path / "fig8.json").read_text())

    def no_run(*args, **kwargs):
        raise AssertionError("a finished run ran again")

    monkeypatch.setattr(batches.Lockstep, "run", no_run)
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


class Unwritable(dict):
    """A value the writers fail on once they have written part of the file (as a full disk fails them)."""

    def __array__(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getitem__(self, key):
        raise OSError(errno.ENOSPC, "No space left on device")

    def items(self):
        raise OSError(errno.ENOSPC, "No space left on device")


def failing_figure(path):
    """A figure whose drawing writes part of the PNG and then fails as a full disk does."""
    figure, _ = new_figure(1)

    def savefig(target, *args, **kwargs):
        with open(target, "wb") as file:
            file.write(b"\x89PNG partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    figure.savefig = savefig
    save_figure(figure, path, "a figure")


def good_figure(path):
    figure, _ = new_figure(1)
    save_figure(figure, path, "a figure")


ROWS = {
    "trlsd": [dict.fromkeys(["run", "task", "seed", "score", "seconds", "online_ms_per_step", "updates"], 1)]
}
WRITERS = {
    "json": (
        "fig5.json",
        lambda path: write_json(path, {"runs": 3}),
        lambda path: write_json(path, {"runs": 4, "rewards": Unwritable(mean=1.0)}),
    ),
    "curves-csv": (
        "fig5.csv",
        lambda path: write_curves_csv(path, "transition", {"a": np.ones((2, 3))}),
        lambda path: write_curves_csv(path, "transition", {"a": np.zeros((2, 3)), "b": Unwritable()}),
    ),
    "figure-png": ("fig5.png", good_figure, failing_figure),
    "suite-rows-csv": (
        "mo_suite.csv",
        lambda path: write_rows(path, ROWS),
        lambda path: write_rows(path, {"random": ROWS["trlsd"], "dqn": [Unwritable()]}),
    ),
}


@pytest.mark.parametrize("writer", list(WRITERS), ids=list(WRITERS))
def test_a_result_file_that_fails_midway_leaves_the_earlier_one_whole(tmp_path, writer):
    """
    The lab's JSON, CSV and PNG writers write whole files or none: a write that fails partway (a full disk)
    leaves the results of the earlier run as they were, where writing in place had cut them short.
    """
    name, write, fail = WRITERS[writer]
    path = tmp_path / name
    write(path)
    earlier = path.read_bytes()
    with pytest.raises(OSError, match="No space left"):
        fail(path)
    assert path.read_bytes() == earlier
    assert os.listdir(tmp_path) == [name]
