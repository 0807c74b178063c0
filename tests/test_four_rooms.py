"""FourRooms: dynamics, rewards, truncations, tasks, seeding, checkers, errors."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sb3_trlsd_envs import (
    EAST,
    FOUR_ROOMS_GOALS,
    FOUR_ROOMS_ID,
    NORTH,
    SOUTH,
    WEST,
    FourRooms,
    four_rooms_step,
    goal_rewards,
    make_room_walls,
    segment_crosses_walls,
)

OPEN = make_room_walls(())


def rooms_of(states: np.ndarray) -> np.ndarray:
    """The room of each state under the default layout: 0 NW, 1 SW, 2 NE, 3 SE."""
    return 2 * (states[:, 0] > 0.5) + (states[:, 1] > 0.5)


@pytest.mark.parametrize("action", [NORTH, WEST, SOUTH, EAST], ids=["north", "west", "south", "east"])
def test_moves_are_an_eighth_plus_noise_of_a_sixteenth_along_and_a_32nd_across(action):
    """
    Away from walls a move is 1/8 along the action's axis with N(0, 1/16) noise on it and N(0, 1/32) on the
    other axis; 5 standard errors on means and standard deviations.
    """
    n = 20_000
    starts = np.full((n, 2), 0.5)
    moves = four_rooms_step(starts, np.full(n, action), np.random.default_rng(0), OPEN) - starts
    along = [1, 0, 1, 0][action]
    sign = [-1, -1, 1, 1][action]
    for axis, mean, std in ((along, sign / 8, 1 / 16), (1 - along, 0.0, 1 / 32)):
        assert moves[:, axis].mean() == pytest.approx(mean, abs=5 * std / np.sqrt(n))
        assert moves[:, axis].std() == pytest.approx(std, abs=5 * std / np.sqrt(2 * n))


def test_walls_stop_moves_and_doorways_let_them_through():
    """Without noise, EAST from just west of x = 1/2 rebounds off the wall, but passes in the doorway row."""
    states = np.array([[0.45, 0.4], [0.45, 3 / 16], [0.45, 13 / 16]])
    ends = four_rooms_step(states, np.full(3, EAST), np.random.default_rng(1), make_room_walls(), 0.0, 0.0)
    assert 0.5 - 1 / 16 <= ends[0, 0] <= 0.5 - 1 / 80
    np.testing.assert_allclose(ends[1:, 0], 0.575)


def test_random_walks_from_one_room_reach_the_other_three():
    """The four doorways connect the rooms: a layout typo that closed one would leave a room unvisited."""
    rng = np.random.default_rng(2)
    walls = make_room_walls()
    states = rng.uniform(0.05, 0.45, size=(500, 2))  # all in the north-west room
    visited = set()
    for _ in range(100):
        states = four_rooms_step(states, rng.integers(4, size=len(states)), rng, walls)
        visited |= set(rooms_of(states).tolist())
    assert visited == {0, 1, 2, 3}


def test_states_stay_inside_and_trajectories_never_cross_walls():
    """Stepping keeps the state in (0, 1)^2 and in the observation space, and every move off every wall."""
    env = FourRooms(termination_prob=0.0)
    obs, _ = env.reset(seed=3)
    for _ in range(2000):
        obs, _, _, _, _ = env.step(env.np_random.integers(4))
        assert env.observation_space.contains(obs)
    path = np.array(env.trajectory)
    assert path.shape == (2001, 2) and np.all((path > 0) & (path < 1))
    assert not segment_crosses_walls(path[:-1], path[1:], env.walls).any()


def test_goal_discs_lie_inside_one_room_each():
    """Task 4 (i - 1) + (j - 1) is the goal ((2i - 1) / 8, (2j - 1) / 8); its disc touches no wall."""
    goals = np.array(FOUR_ROOMS_GOALS)
    assert goals.shape == (16, 2)
    np.testing.assert_array_equal(goals[4 * 2 + 1], [5 / 8, 3 / 8])
    walls = make_room_walls()
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rim = 0.1 * np.column_stack([np.cos(angles), np.sin(angles)])
    for goal in goals:
        assert not segment_crosses_walls(np.tile(goal, (64, 1)), goal + rim, walls).any()
    assert np.bincount(rooms_of(goals)).tolist() == [4, 4, 4, 4]


def test_rewards_are_one_plus_noise_in_the_goal_disc_and_noise_elsewhere():
    """
    Rewards are drawn for the state s_t a step starts from: mean 1 in the task's disc, 0 elsewhere, std
    reward_noise_std in both. Tolerance: 5 standard errors.
    """
    env = FourRooms(task=5, goal_radius=0.2, reward_noise_std=1.0, termination_prob=0.1)
    env.reset(seed=4)
    inside, outside = [], []
    for _ in range(8000):
        start = env.state.copy()
        _, reward, _, truncated, _ = env.step(env.np_random.integers(4))
        (inside if np.linalg.norm(start - FOUR_ROOMS_GOALS[5]) <= 0.2 else outside).append(reward)
        if truncated:
            env.reset()
    for rewards, mean in ((np.array(inside), 1.0), (np.array(outside), 0.0)):
        assert len(rewards) > 300
        assert rewards.mean() == pytest.approx(mean, abs=5 / np.sqrt(len(rewards)))
        assert rewards.std() == pytest.approx(1.0, abs=5 / np.sqrt(2 * len(rewards)))


def test_expected_reward_is_one_in_the_task_disc_only():
    """The function and the env method (current task by default) give 1 within the radius, rim included."""
    goal = np.array(FOUR_ROOMS_GOALS[15])
    states = goal + np.array([[0.0, 0.0], [0.125, 0.0], [0.0, -0.126], [-0.75, -0.75]])
    np.testing.assert_array_equal(goal_rewards(states, goal, 0.125), [1.0, 1.0, 0.0, 0.0])
    states[1, 0] -= 0.03  # within the default radius 0.1
    env = FourRooms(task=15)
    np.testing.assert_array_equal(env.expected_reward(states), [1.0, 1.0, 0.0, 0.0])
    np.testing.assert_array_equal(env.expected_reward(states, task=0), [0.0, 0.0, 0.0, 1.0])


def test_truncation_rate_is_two_percent_and_never_a_termination():
    """Each step resets with probability 0.02, as truncated=True; binomial tolerance of 5 standard errors."""
    env = gym.make(FOUR_ROOMS_ID)
    env.reset(seed=5)
    env.action_space.seed(5)
    n, truncations = 10_000, 0
    for _ in range(n):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated
        truncations += truncated
        if truncated:
            env.reset()
    assert truncations / n == pytest.approx(0.02, abs=5 * np.sqrt(0.02 * 0.98 / n))


def test_vectorised_random_transitions_have_the_same_statistics_as_stepping():
    """
    The all-at-once sampler: 2% resets, trajectories that chain, rewards of the task's disc, and each
    action's mean move as in stepping the env with random actions (5 standard errors of the difference).
    """
    env = FourRooms(task=6, reward_noise_std=0.5)
    data = env.random_transitions(40_000, seed=6)
    n = len(data["actions"])
    assert n == 40_000 and not data["terminations"].any()
    assert data["truncations"].mean() == pytest.approx(0.02, abs=5 * np.sqrt(0.02 * 0.98 / n))
    same = ~data["truncations"][:-1]
    np.testing.assert_array_equal(data["next_states"][:-1][same], data["states"][1:][same])
    in_goal = env.expected_reward(data["states"]) == 1
    assert data["rewards"][in_goal].mean() == pytest.approx(1.0, abs=5 * 0.5 / np.sqrt(in_goal.sum()))
    assert data["rewards"][~in_goal].mean() == pytest.approx(0.0, abs=5 * 0.5 / np.sqrt(n))
    stepped = FourRooms(task=6)
    stepped.reset(seed=7)
    actions, moves = stepped.np_random.integers(4, size=10_000), []
    for action in actions:
        start = stepped.state.copy()
        truncated = stepped.step(action)[3]
        moves.append(stepped.state - start)
        if truncated:
            stepped.reset()
    moves = np.array(moves)
    sampled = data["next_states"] - data["states"]
    for action, axis in ((NORTH, 1), (WEST, 0), (SOUTH, 1), (EAST, 0)):
        mine, theirs = sampled[data["actions"] == action, axis], moves[actions == action, axis]
        error = np.hypot(mine.std() / np.sqrt(len(mine)), theirs.std() / np.sqrt(len(theirs)))
        assert mine.mean() == pytest.approx(theirs.mean(), abs=5 * error)


def test_random_transitions_cap_trajectories_at_max_episode_steps():
    """With a time limit of 10 and no resets, every trajectory is 10 steps long and ends truncated."""
    data = FourRooms(termination_prob=0.0).random_transitions(95, seed=8, max_episode_steps=10)
    assert np.flatnonzero(data["truncations"]).tolist() == list(range(9, 90, 10))


def test_random_transitions_follow_the_task_schedule_trajectory_by_trajectory():
    """A round robin gives the trajectories of the sampler their tasks in turn, as reset does."""
    env = FourRooms(tasks=[3, 8, 12], task_schedule="round_robin", termination_prob=0.0)
    data = env.random_transitions(60, seed=9, max_episode_steps=10)
    assert data["tasks"][::10].tolist() == [3, 8, 12, 3, 8, 12]


def test_same_seed_gives_the_same_trajectory():
    """Seeding reset reproduces states, rewards and truncations exactly."""
    runs = []
    for _ in range(2):
        env = gym.make(FOUR_ROOMS_ID, reward_noise_std=1.0)
        env.reset(seed=42)
        env.action_space.seed(42)
        runs.append([env.step(env.action_space.sample())[:4] for _ in range(100)])
    for first, second in zip(runs[0], runs[1], strict=True):
        np.testing.assert_array_equal(first[0]["state"], second[0]["state"])
        assert first[1:] == second[1:]


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"tasks": [0, 15], "task_schedule": "round_robin"}, {"tasks": "all", "task_schedule": "random"}],
    ids=["single-task", "round-robin", "random-schedule"],
)
def test_env_passes_gymnasium_and_sb3_checkers_without_warnings(kwargs):
    """Both env checkers accept the env and say nothing (a warning points at a space or seeding mismatch)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(FOUR_ROOMS_ID, **kwargs).unwrapped)
        sb3_check_env(FourRooms(**kwargs))
        sb3_check_env(gym.make(FOUR_ROOMS_ID, **kwargs))
    assert [str(w.message) for w in caught] == []


def test_round_robin_cycles_forced_tasks_skip_it_and_seeds_restart_it():
    """
    Each reset takes the next task in turn and info['task'] is obs['task']; reset(options={'task': ...})
    serves any task without taking a turn, and a seeded reset restarts the cycle.
    """
    env = FourRooms(tasks=[0, 5, 10], task_schedule="round_robin")
    seen = []
    for _ in range(4):
        obs, info = env.reset()
        assert obs["task"] == info["task"] and info["goal"] == FOUR_ROOMS_GOALS[info["task"]]
        seen.append(info["task"])
    assert seen == [0, 5, 10, 0]
    assert env.reset(options={"task": 15})[0]["task"] == 15
    assert env.reset()[1]["task"] == 5
    assert env.reset(seed=0)[1]["task"] == 0


def test_random_schedule_draws_from_the_given_tasks():
    """A random schedule only uses its tasks, and uses them all."""
    env = FourRooms(tasks=[2, 13], task_schedule="random")
    assert {env.reset(seed=s)[1]["task"] for s in range(30)} == {2, 13}


def test_custom_goals_make_the_tasks():
    """goals= sets the number of tasks and their discs."""
    env = FourRooms(goals=[(0.2, 0.2), (0.8, 0.8)], goal_radius=0.05, task=1)
    assert env.observation_space["task"].n == 2
    np.testing.assert_array_equal(env.expected_reward(np.array([[0.8, 0.84], [0.2, 0.2]])), [1.0, 0.0])


def test_time_limit_comes_from_gym_make():
    """max_episode_steps through gym.make truncates trajectories of that length."""
    env = gym.make(FOUR_ROOMS_ID, termination_prob=0.0, max_episode_steps=20)
    env.reset(seed=0)
    assert [env.step(0)[3] for _ in range(20)] == [False] * 19 + [True]


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"task": 16}, "task"),
        ({"task": -1}, "task"),
        ({"task": (1, 1)}, "task"),
        ({"tasks": [0, 16]}, "task"),
        ({"tasks": []}, "tasks"),
        ({"tasks": "corners"}, "tasks"),
        ({"task": 1, "tasks": "all"}, "task"),
        ({"task_schedule": "lottery"}, "task_schedule"),
        ({"walls": [((0.3, 0.0), (0.3, 0.5))]}, "walls"),
        ({"walls": [((0.5, 0.0), (0.5, 1.5))]}, "walls"),
        ({"walls": [((0.0, 0.0), (0.5, 0.5))]}, "walls"),
        ({"walls": [(0.5, 0.0, 0.5)]}, "walls"),
        ({"goals": [(0.5, 1.0)]}, "goals"),
        ({"goals": []}, "goals"),
        ({"goal_radius": 0.0}, "goal_radius"),
        ({"termination_prob": 1.5}, "termination_prob"),
        ({"reward_noise_std": -1.0}, "reward_noise_std"),
        ({"along_noise_std": float("nan")}, "along_noise_std"),
        ({"render_mode": "human"}, "render_mode"),
    ],
    ids=[
        "index-16",
        "index-negative",
        "cell",
        "bad-member",
        "no-tasks",
        "unknown-set",
        "task-and-tasks",
        "unknown-schedule",
        "off-grid-wall",
        "wall-outside",
        "diagonal-wall",
        "malformed-wall",
        "goal-on-border",
        "no-goals",
        "zero-radius",
        "p-above-one",
        "negative-reward-noise",
        "nan-move-noise",
        "unknown-render-mode",
    ],
)
def test_bad_arguments_raise_value_errors_naming_them(kwargs, argument):
    """Bad input gets a clear error naming the argument, at construction."""
    with pytest.raises(ValueError, match=argument):
        FourRooms(**kwargs)


@pytest.mark.parametrize("action", [4, -1, 1.5], ids=["four", "negative", "float"])
def test_actions_outside_0_3_are_refused_by_step_and_the_batched_dynamics(action):
    """step and four_rooms_step name the action when it is not one of the four moves."""
    env = FourRooms()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    with pytest.raises(ValueError, match="action"):
        four_rooms_step(np.full((1, 2), 0.5), np.array([action]), np.random.default_rng(0), OPEN)


def test_render_draws_the_target_goal_green_and_warns_without_a_render_mode():
    """rgb_array: a (400, 400, 3) picture, green at the task's goal centre, black on a wall; no mode warns."""
    env = FourRooms(task=15, render_mode="rgb_array")
    env.reset(seed=0)
    image = env.render()
    assert image.shape == (400, 400, 3) and image.dtype == np.uint8
    x, y = (np.array(FOUR_ROOMS_GOALS[15]) * 400).astype(int)
    red, green, blue = image[y, x].astype(int)
    assert green > red + 40 and green > blue + 40
    assert image[200, 150].max() < 60  # on the wall y = 1/2, west of x = 1/2
    with pytest.warns(UserWarning, match="render mode"):
        assert FourRooms().render() is None
