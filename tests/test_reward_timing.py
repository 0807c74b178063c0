"""The state a reward belongs to (``reward_timing``): the heads learn and relabel at the start state (the
paper's R_tau(s)) or at the next state (Gymnasium's convention), checked against a relabelling by hand."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import TRLSD, RelabellingReplayBuffer
from tests.conftest import MAZE_ID

CELLS = 5


class Corridor(gym.Env):
    """A corridor [0, 1]: left or right by 0.1, paid 1 on arriving in its last fifth (the next state's)."""

    def __init__(self):
        self.observation_space = spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.x = 0.5

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(0, 1))
        return np.array([self.x], dtype=np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + (0.1 if action else -0.1) + self.np_random.normal(0, 0.02), 0, 1))
        reward = float(self.x >= 0.8)
        return np.array([self.x], dtype=np.float32), reward, False, self.np_random.random() < 0.05, {}


def cell_means_by_hand(rewarded: np.ndarray, rewards: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Per-cell means of the observed rewards at the rewarded states (0 in a cell without any), at queries."""
    cells = np.minimum((rewarded[:, 0] * CELLS).astype(int), CELLS - 1)
    query_cells = np.minimum((queries[:, 0] * CELLS).astype(int), CELLS - 1)
    means = np.array([rewards[cells == c].mean() if np.any(cells == c) else 0.0 for c in range(CELLS)])
    return means[query_cells]


@pytest.mark.parametrize("timing", ["start_state", "next_state"])
def test_each_timing_relabels_the_buffer_as_by_hand(timing):
    env = Corridor()
    model = TRLSD(
        "LinearPolicy",
        env,
        reward_head="tabular",
        kappa=0.0,
        reward_head_kwargs={"cells_per_dim": CELLS},
        reward_timing=timing,
        seed=0,
    )
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(300):
        action = int(rng.integers(2))
        next_obs, reward, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, reward, next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    data = model.replay_buffer.transitions()
    rewarded = data.next_states if timing == "next_state" else data.states
    expected = cell_means_by_hand(rewarded, data.rewards, rewarded)
    relabelled = model.task_learner(0).relabelled_rewards(model.replay_buffer)
    np.testing.assert_allclose(relabelled, expected, atol=1e-12)
    # On arrival the reward is all in the last cell; read at the start state it leaks into its neighbour.
    last_cell = expected[rewarded[:, 0] >= 0.8]
    assert (np.all(last_cell == 1.0)) == (timing == "next_state")


def test_auto_reads_the_env_s_declaration_and_defaults_to_gymnasium_s_convention():
    assert TRLSD("LinearPolicy", Corridor()).reward_timing == "next_state"
    maze = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3))
    assert maze.reward_timing == "start_state" and maze.task_learner(3).reward_timing == "start_state"
    with pytest.raises(ValueError, match="reward_timing must be one of"):
        TRLSD("LinearPolicy", Corridor(), reward_timing="arrival")


@pytest.mark.parametrize("timing", ["start_state", "next_state"])
def test_the_relabelling_buffer_learns_and_relabels_at_the_timing_s_state(timing):
    env = Corridor()
    buffer = RelabellingReplayBuffer(
        500,
        env.observation_space,
        env.action_space,
        device="cpu",
        reward_head="tabular",
        kappa=0.0,
        reward_head_kwargs={"cells_per_dim": CELLS},
        reward_timing=timing,
        relabel_online_rows=True,
    )
    rng = np.random.default_rng(1)
    states = rng.uniform(0, 1, size=(200, 1)).astype(np.float32)
    next_states = np.clip(states + rng.choice([-0.1, 0.1], size=(200, 1)), 0, 1).astype(np.float32)
    rewards = (next_states[:, 0] >= 0.8).astype(float)
    for state, next_state, reward in zip(states, next_states, rewards, strict=True):
        buffer.add(
            state[None], next_state[None], np.array([[1]]), np.array([reward]), np.array([False]), [{}]
        )
    sample = buffer.sample(100)
    sampled_states = sample.observations.numpy().astype(np.float64)
    sampled_next = sample.next_observations.numpy().astype(np.float64)
    rewarded = (next_states if timing == "next_state" else states).astype(np.float64)
    queries = sampled_next if timing == "next_state" else sampled_states
    np.testing.assert_allclose(
        sample.rewards.numpy()[:, 0], cell_means_by_hand(rewarded, rewards, queries), rtol=1e-6
    )
