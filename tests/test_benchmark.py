"""``sb3-trlsd benchmark`` on tiny sizes: its files, its measure, DQN's pre-filled buffer, its seeding."""

import csv
import json

import gymnasium as gym
import numpy as np
import pytest
from matplotlib.image import imread
from stable_baselines3 import DQN

from sb3_trlsd import collect_transitions
from sb3_trlsd_envs import FOUR_ROOMS_ID, GOAL_CARTPOLE_ID, MAZE_ID
from sb3_trlsd_lab.benchmarks import benchmark as bench
from sb3_trlsd_lab.benchmarks.baselines import (
    DQN_SETTINGS,
    ExpectedRewards,
    fill_replay_buffer,
    random_rewards,
)
from sb3_trlsd_lab.cli import main

N_SOURCE, N_ONLINE = 400, 150  # DQN_SETTINGS' learning_starts is 100: 50 gradient steps


@pytest.fixture
def tiny_maze(monkeypatch):
    """The maze benchmark at tiny sizes, through the module's own defaults (what the command reads)."""
    monkeypatch.setattr(bench, "SOURCE_TRANSITIONS", N_SOURCE)
    monkeypatch.setitem(bench.FAMILIES, "maze", (MAZE_ID, N_ONLINE))


def test_the_command_writes_valid_files(tiny_maze, tmp_path, capsys):
    """CSV curves of every method, a PNG, a JSON of aggregates and sizes, a table, and the runs kept."""
    command = ["benchmark", "maze", "--runs", "2", "--workers", "1", "--seed", "3", "--out", str(tmp_path)]
    assert main(command) == 0
    printed = capsys.readouterr().out
    assert "benchmark_maze done" in printed
    labels = [method.label for method in bench.METHODS]
    assert all(f"| {label} | " in printed for label in labels)

    with open(tmp_path / "benchmark_maze.csv") as file:
        rows = list(csv.DictReader(file))
    assert set(rows[0]) == {"transition", "method", "mean", "se", "runs"}
    assert [row["method"] for row in rows] == [label for label in labels for _ in range(N_ONLINE)]
    assert all(
        np.isfinite(float(row["mean"])) and float(row["se"]) >= 0 and row["runs"] == "2" for row in rows
    )

    image = imread(tmp_path / "benchmark_maze.png")
    assert image.ndim == 3 and min(image.shape[:2]) > 200

    data = json.loads((tmp_path / "benchmark_maze.json").read_text())
    assert data["figure"] == "benchmark_maze" and data["seed"] == 3 and data["package_version"]
    parameters = data["parameters"]
    assert (parameters["source_transitions"], parameters["online_transitions"], parameters["runs"]) == (
        N_SOURCE,
        N_ONLINE,
        2,
    )
    assert list(data["results"]) == labels
    for result in data["results"].values():
        assert result["runs"] == 2 and result["seconds_per_run"] > 0
        assert set(result["reward"]) == {f"[0, {N_ONLINE})", f"[{N_ONLINE // 2}, {N_ONLINE})"}
    assert len(list((tmp_path / "runs").iterdir())) == 2 * len(labels)


@pytest.mark.parametrize("env_id", [MAZE_ID, FOUR_ROOMS_ID, GOAL_CARTPOLE_ID], ids=lambda name: name[6:])
def test_the_measure_is_the_noise_free_reward_of_each_step(env_id):
    """Without reward noise, a step's reward is E[R_task(s_t)]: a record off by one step would differ."""
    env = ExpectedRewards(gym.make(env_id, task=1, reward_noise_std=0.0))
    env.reset(seed=0)
    env.action_space.seed(0)
    rewards = []
    for _ in range(1_000):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        rewards.append(reward)
        if terminated or truncated:
            env.reset()
    np.testing.assert_allclose(env.expected, rewards, rtol=1e-12)
    assert np.ptp(rewards) > 0  # the random trajectory met the task's reward: the check says something
    np.testing.assert_array_equal(
        random_rewards(ExpectedRewards(gym.make(env_id, task=1, reward_noise_std=0.0)), 0, 1_000),
        env.expected,
    )


def test_the_prefilled_dqn_holds_the_source_with_zero_rewards_before_learning(monkeypatch):
    """What DQN learns from must be the source's states, actions and ends, as the target task, rewards 0."""
    buffers = []
    learn = DQN.learn

    def recording_learn(model, *args, **kwargs):
        buffer, n = model.replay_buffer, model.replay_buffer.pos
        buffers.append(
            {
                "state": buffer.observations["state"][:n, 0].copy(),
                "task": buffer.observations["task"][:n, 0, 0].copy(),
                "actions": buffer.actions[:n, 0, 0].copy(),
                "rewards": buffer.rewards[:n, 0].copy(),
                "dones": buffer.dones[:n, 0].copy(),
                "timeouts": buffer.timeouts[:n, 0].copy(),
            }
        )
        return learn(model, *args, **kwargs)

    monkeypatch.setattr(DQN, "learn", recording_learn)
    run, seed = 4, 1  # target task 4, source drawn on task 5
    with_source = bench.Contender("DQN, source in buffer", "dqn")
    from_scratch = bench.Contender("DQN", "dqn", source=False)
    bench.benchmark_run("four-rooms", with_source, run, seed, N_SOURCE, N_ONLINE)
    bench.benchmark_run("four-rooms", from_scratch, run, seed, N_SOURCE, N_ONLINE)
    filled, empty = buffers

    source = collect_transitions(
        gym.make(FOUR_ROOMS_ID, task=run + 1), N_SOURCE, seed=bench.SOURCE_SEED + seed + run
    )
    assert source.truncations.any()
    np.testing.assert_array_equal(filled["state"], source.states.astype(np.float32))
    np.testing.assert_array_equal(filled["task"], np.full(N_SOURCE, run))
    np.testing.assert_array_equal(filled["actions"], source.actions)
    np.testing.assert_array_equal(filled["rewards"], np.zeros(N_SOURCE))
    np.testing.assert_array_equal(filled["dones"], source.truncations | source.terminations)
    np.testing.assert_array_equal(filled["timeouts"], source.truncations & ~source.terminations)
    assert len(empty["rewards"]) == 0


def test_fill_replay_buffer_keeps_terminations_absorbing():
    """A cart-pole fall must stay absorbing for DQN (done, no time limit), unlike a truncation."""
    source = collect_transitions(gym.make(GOAL_CARTPOLE_ID, task=0), 300, seed=0)
    assert source.terminations.any()
    model = DQN("MultiInputPolicy", gym.make(GOAL_CARTPOLE_ID, task=2), **DQN_SETTINGS)
    fill_replay_buffer(model, source, 2)
    buffer = model.replay_buffer
    assert buffer.pos == 300
    absorbing = buffer.dones[:300, 0] * (1 - buffer.timeouts[:300, 0])
    np.testing.assert_array_equal(absorbing, source.terminations)
    np.testing.assert_array_equal(
        buffer.next_observations["state"][:300, 0], source.next_states.astype(np.float32)
    )


def test_the_same_seed_gives_the_same_numbers(tmp_path):
    """Every method, TRLSD on a family other than the maze included, is a function of its seed alone."""
    curves = []
    for seed, out in [(5, "a"), (5, "b"), (6, "c")]:
        bench.benchmark("four-rooms", tmp_path / out, runs=2, seed=seed, n_source=N_SOURCE, n_online=N_ONLINE)
        with open(tmp_path / out / "benchmark_four-rooms.csv") as file:
            rows = list(csv.DictReader(file))
        curves.append(
            {
                method.label: [row["mean"] for row in rows if row["method"] == method.label]
                for method in bench.METHODS
            }
        )
    assert curves[0] == curves[1]
    assert all(curves[0][label] != curves[2][label] for label in curves[0])


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["benchmark", "pong"], "invalid choice: 'pong'"),
        (["benchmark", "maze", "--runs", "0"], "expected an integer >= 1, got 0"),
    ],
    ids=["unknown family", "zero runs"],
)
def test_the_command_rejects_bad_arguments(arguments, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(arguments)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
