"""GoalCartPole: Gymnasium's dynamics exactly, rewards, episode ends, tasks, seeding, checkers, errors."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sb3_trlsd_envs import (
    CARTPOLE_TARGETS,
    GOAL_CARTPOLE_ID,
    STATE_HIGH,
    VELOCITY_BOUNDS,
    GoalCartPole,
    cartpole_step,
    cartpole_terminal,
    target_rewards,
)


def balancing_action(state: np.ndarray, target: float) -> int:
    """A hand-tuned bang-bang controller that holds the pole up and walks the cart to ``target``."""
    x, x_dot, theta, theta_dot = state
    return int(10 * theta + 2 * theta_dot + 0.8 * (x - target) + 1.2 * x_dot > 0)


def some_states(n: int, seed: int) -> np.ndarray:
    """States all over the non-terminal region and a little beyond, velocities within the bounds."""
    high = np.array([2.5, VELOCITY_BOUNDS[0], 0.25, VELOCITY_BOUNDS[1]])
    return np.random.default_rng(seed).uniform(-high, high, size=(n, 4))


def test_batched_step_is_gymnasiums_cartpole_step_to_the_bit():
    """cartpole_step (random_transitions' dynamics) gives CartPoleEnv.step's next state and termination."""
    states = some_states(2000, seed=0)
    actions = np.random.default_rng(1).integers(2, size=2000)
    next_states, terminated = cartpole_step(states, actions)
    gymnasium_env = CartPoleEnv()
    gymnasium_env.reset(seed=0)
    for state, action, next_state, done in zip(states, actions, next_states, terminated, strict=True):
        gymnasium_env.state, gymnasium_env.steps_beyond_terminated = state.copy(), None
        _, _, gymnasium_done, _, _ = gymnasium_env.step(int(action))
        np.testing.assert_array_equal(gymnasium_env.state, next_state)
        assert gymnasium_done == done
    np.testing.assert_array_equal(cartpole_terminal(next_states), terminated)


def test_env_steps_are_gymnasiums_from_the_same_start():
    """The env's state follows CartPoleEnv exactly, and its terminated flag is Gymnasium's."""
    env = GoalCartPole()
    env.reset(seed=2)
    gymnasium_env = CartPoleEnv()
    gymnasium_env.reset(seed=0)
    gymnasium_env.state = env.state.copy()
    for action in np.random.default_rng(3).integers(2, size=100):
        _, _, terminated, truncated, _ = env.step(int(action))
        _, _, gymnasium_terminated, _, _ = gymnasium_env.step(int(action))
        np.testing.assert_array_equal(env.state, gymnasium_env.state)
        assert terminated == gymnasium_terminated and not truncated
        if terminated:
            break
    assert terminated, "a random policy drops the pole within 100 steps"


def test_starting_states_spread_the_cart_and_keep_gymnasiums_small_rest():
    """x is uniform in [-1.75, 1.75] (mean, variance within 5 standard errors), the rest in (-0.05, 0.05)."""
    env = GoalCartPole()
    starts = np.array([env.reset(seed=seed)[0]["state"] for seed in range(2000)])
    assert starts[:, 0].mean() == pytest.approx(0.0, abs=5 * 1.75 / np.sqrt(3 * 2000))
    assert starts[:, 0].var() == pytest.approx(1.75**2 / 3, rel=5 * np.sqrt(0.8 / 2000))
    assert np.abs(starts[:, 1:]).max() < 0.05


def test_rewards_are_the_bump_of_the_start_state_plus_noise():
    """
    Rewards are drawn for s_t: their residuals around target_rewards(s_t) have mean 0 and standard deviation
    reward_noise_std (5 standard errors); the bump is 1 at the target, exp(-1/2) one width away.
    """
    env = GoalCartPole(task=3, reward_noise_std=0.5)
    env.reset(seed=4)
    residuals = []
    for _ in range(5000):
        expected = target_rewards(env.state, CARTPOLE_TARGETS[3], 0.5)[0]
        _, reward, terminated, _, _ = env.step(int(env.np_random.integers(2)))
        residuals.append(reward - expected)
        if terminated:
            env.reset()
    assert np.mean(residuals) == pytest.approx(0.0, abs=5 * 0.5 / np.sqrt(5000))
    assert np.std(residuals) == pytest.approx(0.5, abs=5 * 0.5 / np.sqrt(2 * 5000))
    states = np.zeros((3, 4))
    states[:, 0] = [0.75, 1.25, 0.25]
    np.testing.assert_allclose(env.expected_reward(states), [1.0, np.exp(-0.5), np.exp(-0.5)])


def test_expected_reward_is_zero_in_terminal_states_and_per_task():
    """A fallen pole or a cart off the track is worth 0 for every task; task= picks the bump."""
    env = GoalCartPole(task=0)
    states = np.zeros((4, 4))
    states[:, 0] = [-1.5, -1.5, 2.41, 0.0]
    states[1, 2] = 0.21  # beyond 12 degrees
    np.testing.assert_allclose(env.expected_reward(states), [1.0, 0.0, 0.0, np.exp(-4.5)])
    np.testing.assert_allclose(env.expected_reward(states, task=2), [np.exp(-4.5), 0.0, 0.0, 1.0])


def test_observations_are_the_state_clipped_to_a_finite_box():
    """The Box is finite; x and theta one step beyond their thresholds fit it; faster velocities clip."""
    env = GoalCartPole()
    box = env.observation_space["state"]
    assert np.all(np.isfinite(box.low)) and np.all(np.isfinite(box.high))
    np.testing.assert_allclose(STATE_HIGH, [2.48, 4.0, 0.2094395 + 0.08, 4.0], atol=1e-6)
    env.reset(seed=5)
    env.cartpole.state = np.array([0.5, 9.0, 0.0, -7.0])
    obs, _, _, _, _ = env.step(1)
    assert box.contains(obs["state"]) and obs["state"][1] == 4.0 and obs["state"][3] == -4.0
    assert env.state[1] > 9.0  # the dynamics' state itself is never clipped


def test_random_policies_stay_within_the_velocity_bounds():
    """The documented bounds are not reached by random data (what TRLSD's source sets are)."""
    data = GoalCartPole().random_transitions(50_000, seed=6, max_episode_steps=200)
    for name in ("states", "next_states"):
        assert np.all(np.abs(data[name][:, [1, 3]]) < np.array(VELOCITY_BOUNDS) * 0.95)


def test_a_balancing_controller_is_truncated_at_200_steps_and_earns_far_more_than_random():
    """
    The registered time limit is CartPole-v0's 200 steps (truncated, not terminated); a controller that
    holds the cart at the target earns twice what a random policy does (0.72 and 0.35 a step, seed 7).
    """
    env = gym.make(GOAL_CARTPOLE_ID, task=2)
    earned = {}
    for name in ("controller", "random"):
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        rewards, ends = [], []
        while len(rewards) < 1000:
            action = (
                balancing_action(obs["state"], 0.0) if name == "controller" else env.action_space.sample()
            )
            obs, reward, terminated, truncated, _ = env.step(action)
            rewards.append(reward)
            if terminated or truncated:
                ends.append((len(rewards), terminated))
                obs, _ = env.reset()
        earned[name] = np.mean(rewards)
        if name == "controller":
            assert ends == [(200, False), (400, False), (600, False), (800, False), (1000, False)]
        else:
            assert all(terminated for _, terminated in ends)
    assert earned["controller"] > 0.6 and earned["controller"] > 1.8 * earned["random"]


def test_vectorised_random_transitions_have_the_same_statistics_as_stepping():
    """
    The all-at-once sampler: termination rate and mean reward as in stepping the env with random actions
    (5 standard errors of the difference), trajectories that chain, rewards of target_rewards on s.
    """
    env = GoalCartPole(task=1)
    data = env.random_transitions(20_000, seed=8, max_episode_steps=200)
    assert len(data["actions"]) == 20_000 and not data["truncations"].any()
    ongoing = ~data["terminations"][:-1]
    np.testing.assert_array_equal(data["next_states"][:-1][ongoing], data["states"][1:][ongoing])
    np.testing.assert_array_equal(data["rewards"], env.expected_reward(data["states"]))
    env.reset(seed=9)
    rewards, terminations = [], []
    for action in env.np_random.integers(2, size=10_000):
        _, reward, terminated, _, _ = env.step(int(action))
        rewards.append(reward)
        terminations.append(terminated)
        if terminated:
            env.reset()
    for mine, theirs in ((data["terminations"], terminations), (data["rewards"], rewards)):
        error = np.hypot(np.std(mine) / np.sqrt(len(mine)), np.std(theirs) / np.sqrt(len(theirs)))
        assert np.mean(mine) == pytest.approx(np.mean(theirs), abs=5 * error)


def test_random_transitions_truncate_at_max_episode_steps_and_follow_the_schedule():
    """With a cap of 5 steps most trajectories are truncated; a round robin gives them their tasks in turn."""
    env = GoalCartPole(tasks=[4, 0], task_schedule="round_robin")
    data = env.random_transitions(100, seed=10, max_episode_steps=5)
    ends = np.flatnonzero(data["truncations"] | data["terminations"])
    assert not (data["truncations"] & data["terminations"]).any()
    assert np.diff(np.concatenate([[-1], ends])).max() == 5 and data["truncations"].sum() >= 15
    starts = np.concatenate([[0], ends[:-1] + 1])
    assert data["tasks"][starts].tolist() == [4, 0] * (len(starts) // 2) + [4] * (len(starts) % 2)


def test_same_seed_gives_the_same_trajectory():
    """Seeding reset reproduces states, rewards and episode ends exactly."""
    runs = []
    for _ in range(2):
        env = gym.make(GOAL_CARTPOLE_ID, reward_noise_std=1.0)
        env.reset(seed=42)
        env.action_space.seed(42)
        runs.append([env.step(env.action_space.sample())[:4] for _ in range(8)])
    for first, second in zip(runs[0], runs[1], strict=True):
        np.testing.assert_array_equal(first[0]["state"], second[0]["state"])
        assert first[1:] == second[1:]


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"tasks": [1, 3], "task_schedule": "round_robin"}, {"tasks": "all", "task_schedule": "random"}],
    ids=["single-task", "round-robin", "random-schedule"],
)
def test_env_passes_gymnasium_and_sb3_checkers_without_warnings(kwargs):
    """Both env checkers accept the env and say nothing (a warning points at a space or seeding mismatch)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(GOAL_CARTPOLE_ID, **kwargs).unwrapped)
        sb3_check_env(GoalCartPole(**kwargs))
        sb3_check_env(gym.make(GOAL_CARTPOLE_ID, **kwargs))
    assert [str(w.message) for w in caught] == []


def test_round_robin_cycles_forced_tasks_skip_it_and_seeds_restart_it():
    """
    Each reset takes the next task in turn, info['task'] is obs['task'] and info['target'] its position;
    reset(options={'task': ...}) serves any task without taking a turn; a seeded reset restarts the cycle.
    """
    env = GoalCartPole(tasks="all", task_schedule="round_robin")
    seen = []
    for _ in range(6):
        obs, info = env.reset()
        assert obs["task"] == info["task"] and info["target"] == CARTPOLE_TARGETS[info["task"]]
        seen.append(info["task"])
    assert seen == [0, 1, 2, 3, 4, 0]
    assert env.reset(options={"task": 3})[0]["task"] == 3
    assert env.reset()[1]["task"] == 1
    assert env.reset(seed=0)[1]["task"] == 0


def test_random_schedule_and_custom_targets():
    """A random schedule only uses its tasks; targets= sets the tasks and their bumps."""
    env = GoalCartPole(targets=[-1.0, 1.0], tasks="all", task_schedule="random", goal_width=0.25)
    assert {env.reset(seed=s)[1]["task"] for s in range(30)} == {0, 1}
    assert env.observation_space["task"].n == 2
    state = np.array([[1.25, 0.0, 0.0, 0.0]])
    assert env.expected_reward(state, task=1)[0] == pytest.approx(np.exp(-0.5))


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"task": 5}, "task"),
        ({"task": -1}, "task"),
        ({"task": 1.0}, "task"),
        ({"tasks": [0, 5]}, "task"),
        ({"tasks": []}, "tasks"),
        ({"tasks": "corners"}, "tasks"),
        ({"task": 1, "tasks": "all"}, "task"),
        ({"task_schedule": "lottery"}, "task_schedule"),
        ({"targets": [0.0, 2.5]}, "targets"),
        ({"targets": [0.5, 0.5]}, "targets"),
        ({"targets": []}, "targets"),
        ({"targets": [[0.0, 1.0]]}, "targets"),
        ({"targets": ["left"]}, "targets"),
        ({"goal_width": 0.0}, "goal_width"),
        ({"start_x_bound": 2.4}, "start_x_bound"),
        ({"start_x_bound": -0.1}, "start_x_bound"),
        ({"reward_noise_std": -1.0}, "reward_noise_std"),
        ({"render_mode": "human"}, "render_mode"),
    ],
    ids=[
        "index-5",
        "index-negative",
        "float",
        "bad-member",
        "no-tasks",
        "unknown-set",
        "task-and-tasks",
        "unknown-schedule",
        "target-off-track",
        "repeated-target",
        "no-targets",
        "targets-2d",
        "target-text",
        "zero-width",
        "start-at-the-edge",
        "negative-start",
        "negative-reward-noise",
        "unknown-render-mode",
    ],
)
def test_bad_arguments_raise_value_errors_naming_them(kwargs, argument):
    """Bad input gets a clear error naming the argument, at construction."""
    with pytest.raises(ValueError, match=argument):
        GoalCartPole(**kwargs)


@pytest.mark.parametrize("action", [2, -1, 0.5], ids=["two", "negative", "float"])
def test_actions_other_than_0_1_are_refused(action):
    """step and cartpole_step name the action when it is not a push left or right."""
    env = GoalCartPole()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    with pytest.raises(ValueError, match="action"):
        cartpole_step(np.zeros((1, 4)), np.array([action]))


def test_render_draws_the_cart_and_warns_without_a_render_mode():
    """rgb_array: a (160, 540, 3) picture with the black cart at x; no render mode warns and returns None."""
    env = GoalCartPole(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(0)
    image = env.render()
    assert image.shape == (160, 540, 3) and image.dtype == np.uint8
    column = int((env.state[0] + 2.7) / 5.4 * 540)
    assert image[:, column].min() < 30 and image[:, 5].min() > 200
    with pytest.warns(UserWarning, match="render mode"):
        assert GoalCartPole().render() is None
