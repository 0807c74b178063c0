"""SharedDynamicsMaze: rewards, truncations, tasks, seeding, checkers, errors."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sb3_trlsd_envs import (
    CELL_NOISE_STDS,
    CORNER_TASKS,
    MAZE_ID,
    N_TASKS,
    NORTH,
    SharedDynamicsMaze,
    cell_of,
    expected_reward,
    segment_crosses_walls,
    task_cell,
    task_index,
)


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
    env.action_space.seed(1)
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


def rows_by_cell(states):
    """((i, j), the rows of ``states`` in cell (i, j)) for the 25 cells."""
    cells = cell_of(states)
    return [((i, j), (cells[:, 0] == i) & (cells[:, 1] == j)) for i in range(1, 6) for j in range(1, 6)]


def test_expected_reward_agrees_with_sampled_means_per_cell():
    """expected_reward is the mean of the sampled rewards in every cell (5 standard errors)."""
    env = SharedDynamicsMaze(task=(4, 2))
    data = env.random_transitions(60_000, seed=3)
    expected = env.expected_reward(data["states"])
    for _, rows in rows_by_cell(data["states"]):
        assert data["rewards"][rows].mean() == pytest.approx(expected[rows][0], abs=5 / np.sqrt(rows.sum()))


def test_noise_by_cell_has_each_cell_s_standard_deviation_around_eq_12_s_mean():
    """
    With a table of standard deviations, the reward at s_t has its cell's: the checkerboard's 0.1 and 1.44,
    around the same means (1 in the task's cell, 0 elsewhere). Tolerance: 5 standard errors of the mean and
    of the standard deviation, cell by cell, from the vectorised sampler (stepping is compared with it below).
    """
    env = SharedDynamicsMaze(task=(2, 3), reward_noise_std=CELL_NOISE_STDS)
    data = env.random_transitions(100_000, seed=4)
    expected = env.expected_reward(data["states"])
    for (i, j), rows in rows_by_cell(data["states"]):
        std = CELL_NOISE_STDS[i - 1][j - 1]
        assert std == (0.1 if (i + j) % 2 == 0 else 1.44)
        noise = data["rewards"][rows] - expected[rows]
        assert noise.mean() == pytest.approx(0.0, abs=5 * std / np.sqrt(rows.sum()))
        assert noise.std() == pytest.approx(std, abs=5 * std / np.sqrt(2 * rows.sum()))
    assert np.mean(np.square(CELL_NOISE_STDS)) == pytest.approx(1.0, abs=1e-3)  # the paper's on average


@pytest.mark.parametrize("sampler", ["step", "random_transitions"])
def test_noise_by_cell_scales_the_same_draws_and_leaves_the_paper_s_maze_unchanged(sampler):
    """
    A table only scales the noise: the maze makes the same moves and draws the same N(0, 1), seed for seed,
    so that (r - E[r]) / std(cell) is the default maze's r - E[r]; a table of ones is the default, to the bit.
    """

    def rewards_and_states(**kwargs):
        env = SharedDynamicsMaze(task=7, **kwargs)
        if sampler == "random_transitions":
            data = env.random_transitions(3_000, seed=6)
            return data["rewards"], data["states"]
        env.reset(seed=6)
        actions = np.random.default_rng(0).integers(4, size=3_000)
        states, rewards = [], []
        for action in actions:
            states.append(env.state.copy())
            rewards.append(env.step(int(action))[1])
            if len(env.trajectory) > 60:
                env.reset()
        return np.array(rewards), np.array(states)

    paper_rewards, paper_states = rewards_and_states()
    ones_rewards, _ = rewards_and_states(reward_noise_std=np.ones((5, 5)).tolist())
    cell_rewards, cell_states = rewards_and_states(reward_noise_std=CELL_NOISE_STDS)
    np.testing.assert_array_equal(ones_rewards, paper_rewards)
    np.testing.assert_array_equal(cell_states, paper_states)
    expected = expected_reward(paper_states, 7)
    stds = np.array(CELL_NOISE_STDS)[cell_of(paper_states)[:, 0] - 1, cell_of(paper_states)[:, 1] - 1]
    np.testing.assert_allclose((cell_rewards - expected) / stds, paper_rewards - expected, rtol=1e-12)


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


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"tasks": "corners", "task_schedule": "round_robin"},
        {"tasks": "all", "task_schedule": "random"},
        {"reward_noise_std": CELL_NOISE_STDS},
    ],
    ids=["single-task", "round-robin", "random-schedule", "noise-by-cell"],
)
def test_env_passes_gymnasium_and_sb3_checkers_without_warnings(kwargs):
    """
    Both env checkers accept the maze and say nothing; a warning points at a space, seeding or render
    mismatch (the round robin must restart on a seeded reset for the determinism check).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(MAZE_ID, **kwargs).unwrapped)
        sb3_check_env(SharedDynamicsMaze(**kwargs))
        sb3_check_env(gym.make(MAZE_ID, **kwargs))
    assert [str(w.message) for w in caught] == []


def test_states_stay_inside_and_trajectories_never_cross_walls():
    """
    Stepping the env keeps the state strictly inside (0, 5)^2, in the observation space, and each step's
    move off every wall; the trajectory kept for rendering is the states since the last reset.
    """
    env = SharedDynamicsMaze(termination_prob=0.0)
    obs, _ = env.reset(seed=7)
    for _ in range(2000):
        obs, _, _, _, _ = env.step(env.np_random.integers(4))
        assert env.observation_space.contains(obs)
    path = np.array(env.trajectory)
    assert path.shape == (2001, 2) and np.all((path > 0) & (path < 5))
    assert not segment_crosses_walls(path[:-1], path[1:], env.walls).any()
    env.reset()
    assert len(env.trajectory) == 1


def test_tasks_are_named_by_cell_or_index():
    """tau_ij is index 5 (i - 1) + (j - 1) both ways, for all 25 tasks; the corners are tau_11, 15, 51, 55."""
    assert task_index((1, 1)) == 0 and task_index((1, 5)) == 4 and task_index((5, 1)) == 20
    assert task_index(24) == 24 and task_index(np.int64(3)) == 3 and task_cell(7) == (2, 3)
    assert [task_index(task_cell(index)) for index in range(N_TASKS)] == list(range(N_TASKS))
    assert CORNER_TASKS == (0, 4, 20, 24)


@pytest.mark.parametrize("task", [(0, 3), (6, 1), 25, -1, "foo", (1.0, 2), (1, 2, 3), True], ids=repr)
def test_task_index_refuses_anything_but_a_cell_or_an_index(task):
    """task_index names the task for cells outside 1..5, indices outside 0..24 and other types."""
    with pytest.raises(ValueError, match="task"):
        task_index(task)


def test_expected_reward_is_one_in_the_task_cell_only():
    """The module function and the env method (current task by default) give eq. 12's noise-free mean."""
    states = np.array([[0.5, 4.5], [0.5, 0.5], [1.0, 5.0], [1.01, 4.5]])
    np.testing.assert_array_equal(expected_reward(states, (1, 5)), [1.0, 0.0, 1.0, 0.0])
    env = SharedDynamicsMaze(task=(1, 5))
    np.testing.assert_array_equal(env.expected_reward(states), [1.0, 0.0, 1.0, 0.0])
    np.testing.assert_array_equal(env.expected_reward(states, task=0), [0.0, 1.0, 0.0, 0.0])


def test_round_robin_cycles_and_info_matches_the_observation():
    """Multi-task: each reset takes the next task in turn, and info['task'] is obs['task']."""
    env = SharedDynamicsMaze(tasks="corners", task_schedule="round_robin")
    seen = []
    for _ in range(6):
        obs, info = env.reset()
        assert obs["task"] == info["task"]
        seen.append(info["task"])
    assert seen == [0, 4, 20, 24, 0, 4]
    obs, _, _, _, info = env.step(NORTH)
    assert info["cell"] == tuple(cell_of(env.state)[0]) and info["task"] == obs["task"] == 4


def test_forced_tasks_skip_the_round_robin_and_seeds_restart_it():
    """
    reset(options={'task': ...}) serves any task without taking a turn (else the cycle would skip a task),
    and a seeded reset starts the cycle again from the first task (else the same seed differs).
    """
    env = SharedDynamicsMaze(tasks="all", task_schedule="round_robin")
    assert [env.reset()[1]["task"] for _ in range(N_TASKS)] == list(range(N_TASKS))
    assert env.reset()[1]["task"] == 0
    assert env.reset(options={"task": (3, 3)})[0]["task"] == 12
    assert env.reset()[1]["task"] == 1
    assert env.reset(seed=0)[1]["task"] == 0


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
        ({"task": "foo"}, "task"),
        ({"tasks": [(1, 1), (0, 3)]}, "task"),
        ({"tasks": []}, "tasks"),
        ({"tasks": "edges"}, "tasks"),
        ({"walls": [((2.5, 0), (2.5, 3))]}, "walls"),
        ({"termination_prob": -0.1}, "termination_prob"),
        ({"termination_prob": 1.5}, "termination_prob"),
        ({"reward_noise_std": -1.0}, "reward_noise_std"),
        ({"reward_noise_std": np.ones((4, 5))}, "reward_noise_std"),
        ({"reward_noise_std": [[1.0] * 5] * 4 + [[1.0, 1.0, -0.1, 1.0, 1.0]]}, "reward_noise_std"),
        ({"reward_noise_std": [[np.nan] * 5] * 5}, "reward_noise_std"),
        ({"reward_noise_std": "loud"}, "reward_noise_std"),
        ({"render_mode": "human"}, "render_mode"),
        ({"task_schedule": "lottery"}, "task_schedule"),
        ({"task": 1, "tasks": "all"}, "task"),
    ],
    ids=[
        "i-zero",
        "i-six",
        "index-25",
        "index-negative",
        "text",
        "bad-member",
        "no-tasks",
        "unknown-set",
        "off-grid-wall",
        "negative-p",
        "p-above-one",
        "negative-reward-noise",
        "noise-table-4x5",
        "noise-table-negative-cell",
        "noise-table-nan",
        "noise-text",
        "unknown-render-mode",
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


def test_render_without_a_render_mode_warns_and_returns_nothing():
    """As in Gymnasium's own envs: rendering an env made without render_mode is a user error worth a word."""
    env = SharedDynamicsMaze()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render mode"):
        assert env.render() is None
