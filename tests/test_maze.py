"""SharedDynamicsMaze: rewards, truncations, tasks, seeding, checkers, errors."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from envs import MAZE_ID, SharedDynamicsMaze, expected_reward, task_cell, task_index
from envs.dynamics import cell_of


def test_rewards_are_one_plus_noise_in_the_target_cell_and_noise_elsewhere():
    """
    Eq. 12: mean 1 in the task's cell and 0 elsewhere, std 1 in both. Rewards are drawn for s_t, so they
    are grouped by the cell of the state each step starts from. Tolerance: 5 standard errors.
    """
    env = SharedDynamicsMaze(task=(2, 2), walls=())
    obs, _ = env.reset(seed=0)
    inside, outside = [], []
    for _ in range(20_000):
        start = obs["state"].astype(np.float64)
        # Stay close to the target cell so that it is visited often.
        action = env.np_random.integers(4) if env.np_random.random() < 0.5 else (3 if start[0] < 1.5 else 1)
        obs, reward, _, truncated, _ = env.step(action)
        (inside if tuple(cell_of(env.trajectory[-2])[0]) == (2, 2) else outside).append(reward)
        if truncated:
            obs, _ = env.reset()
    for rewards, mean in ((np.array(inside), 1.0), (np.array(outside), 0.0)):
        assert len(rewards) > 1000
        assert rewards.mean() == pytest.approx(mean, abs=5 / np.sqrt(len(rewards)))
        assert rewards.std() == pytest.approx(1.0, abs=5 / np.sqrt(2 * len(rewards)))


def test_truncation_rate_is_two_percent_and_never_a_termination():
    """Each step resets with probability 0.02, as truncated=True; binomial tolerance of 5 standard errors."""
    env = gym.make(MAZE_ID)
    env.reset(seed=1)
    n, truncations = 20_000, 0
    for _ in range(n):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated
        if truncated:
            truncations += 1
            env.reset()
    assert truncations / n == pytest.approx(0.02, abs=5 * np.sqrt(0.02 * 0.98 / n))


def test_vectorised_random_transitions_have_the_same_statistics_as_stepping():
    """The maze's all-at-once sampler: 2% resets, trajectories that chain, rewards by eq. 12."""
    env = SharedDynamicsMaze(task=(1, 1))
    data = env.random_transitions(50_000, seed=2)
    n = len(data["actions"])
    assert data["truncations"].mean() == pytest.approx(0.02, abs=5 * np.sqrt(0.02 * 0.98 / n))
    same = ~data["truncations"][:-1]
    np.testing.assert_array_equal(data["next_states"][:-1][same], data["states"][1:][same])
    target = expected_reward(data["states"], 0) == 1
    assert data["rewards"][target].mean() == pytest.approx(1.0, abs=5 / np.sqrt(target.sum()))


def test_expected_reward_agrees_with_sampled_means_per_cell():
    """expected_reward is the mean of the sampled rewards in every cell (5 standard errors)."""
    env = SharedDynamicsMaze(task=(4, 2))
    data = env.random_transitions(60_000, seed=3)
    cells = cell_of(data["states"])
    expected = env.expected_reward(data["states"])
    for i in range(1, 6):
        for j in range(1, 6):
            rows = (cells[:, 0] == i) & (cells[:, 1] == j)
            assert data["rewards"][rows].mean() == pytest.approx(
                expected[rows][0], abs=5 / np.sqrt(rows.sum())
            )


def test_same_seed_gives_the_same_trajectory():
    """Seeding reset reproduces states, rewards and truncations exactly."""
    runs = []
    for _ in range(2):
        env = gym.make(MAZE_ID)
        env.reset(seed=42)
        env.action_space.seed(42)
        runs.append([env.step(env.action_space.sample())[:4] for _ in range(100)])
    for first, second in zip(runs[0], runs[1], strict=True):
        np.testing.assert_array_equal(first[0]["state"], second[0]["state"])
        assert first[1:] == second[1:]


def test_env_passes_gymnasium_and_sb3_checkers_without_warnings():
    """Both env checkers accept the maze and say nothing."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(MAZE_ID).unwrapped)
        sb3_check_env(SharedDynamicsMaze())
        sb3_check_env(gym.make(MAZE_ID))
    assert [str(w.message) for w in caught] == []


def test_tasks_are_named_by_cell_or_index():
    """tau_ij is index 5 (i - 1) + (j - 1), both ways."""
    assert task_index((1, 1)) == 0 and task_index((1, 5)) == 4 and task_index((5, 1)) == 20
    assert task_index(24) == 24 and task_cell(7) == (2, 3)


def test_round_robin_cycles_and_info_matches_the_observation():
    """Multi-task: each reset takes the next task in turn, and info['task'] is obs['task']."""
    env = SharedDynamicsMaze(tasks="corners", task_schedule="round_robin")
    seen = []
    for _ in range(6):
        obs, info = env.reset()
        assert obs["task"] == info["task"]
        seen.append(info["task"])
    assert seen == [0, 4, 20, 24, 0, 4]
    _, _, _, _, info = env.step(0)
    assert info["cell"] == tuple(cell_of(env.state)[0])


def test_random_schedule_draws_from_the_given_tasks_and_options_force_one():
    """A random schedule only uses its tasks; reset(options={'task': ...}) forces one."""
    env = SharedDynamicsMaze(tasks=[(1, 1), (3, 3)], task_schedule="random")
    tasks = {env.reset(seed=s)[1]["task"] for s in range(30)}
    assert tasks == {0, 12}
    assert env.reset(options={"task": (5, 5)})[1]["task"] == 24


def test_time_limit_comes_from_registration_kwargs():
    """max_episode_steps through gym.make truncates trajectories of 50 steps."""
    env = gym.make(MAZE_ID, termination_prob=0.0, max_episode_steps=50)
    env.reset(seed=0)
    truncated = [env.step(0)[3] for _ in range(50)]
    assert truncated == [False] * 49 + [True]


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"task": (0, 3)}, "task"),
        ({"task": (6, 1)}, "task"),
        ({"task": 25}, "task"),
        ({"task": -1}, "task"),
        ({"tasks": "edges"}, "tasks"),
        ({"walls": [((2.5, 0), (2.5, 3))]}, "walls"),
        ({"termination_prob": -0.1}, "termination_prob"),
        ({"task_schedule": "lottery"}, "task_schedule"),
        ({"task": 1, "tasks": "all"}, "task"),
    ],
    ids=[
        "i-zero",
        "i-six",
        "index-25",
        "index-negative",
        "unknown-set",
        "off-grid-wall",
        "negative-p",
        "unknown-schedule",
        "task-and-tasks",
    ],
)
def test_bad_arguments_raise_value_errors_naming_them(kwargs, argument):
    """Bad input gets a clear error naming the argument."""
    with pytest.raises(ValueError, match=argument):
        SharedDynamicsMaze(**kwargs)


@pytest.mark.parametrize("action", [4, -1, 1.5], ids=["four", "negative", "float"])
def test_actions_outside_0_3_are_refused(action):
    """step names the action when it is not one of the four."""
    env = SharedDynamicsMaze()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
