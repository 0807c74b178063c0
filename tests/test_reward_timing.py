"""What of a transition its reward belongs to (``reward_timing``): the heads learn and relabel at the start
state (the paper's R_tau(s)), at the next state (Gymnasium's convention) or at the pair (s, s'), checked
against a relabelling by hand."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import TRLSD, RelabellingReplayBuffer
from sb3_trlsd.feature_maps import AdditiveRBF
from sb3_trlsd.reward_timing import TransitionFeatures, rewarded_inputs
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


class EntryCorridor(Corridor):
    """The corridor paid 1 only on entering its last fifth from outside: a reward of (s, s'), not of one."""

    def step(self, action):
        before = self.x
        obs, _, terminated, truncated, info = super().step(action)
        return obs, float(before < 0.8 <= self.x), terminated, truncated, info


def cells_of(points: np.ndarray) -> np.ndarray:
    """The cell of each point of [0, 1]^k on a grid of CELLS per dimension, as one index, (n,)."""
    per_dim = np.minimum((points * CELLS).astype(int), CELLS - 1)
    return np.ravel_multi_index(per_dim.T, (CELLS,) * points.shape[1])


def cell_means_by_hand(rewarded: np.ndarray, rewards: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Per-cell means of the observed rewards at the rewarded states (0 in a cell without any), at queries."""
    cells, query_cells = cells_of(rewarded), cells_of(queries)
    means = np.array(
        [rewards[cells == c].mean() if np.any(cells == c) else 0.0 for c in range(CELLS ** rewarded.shape[1])]
    )
    return means[query_cells]


def fill_online(model: TRLSD, env: Corridor, steps: int = 300) -> None:
    """``steps`` online transitions of random actions, added to ``model``."""
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        action = int(rng.integers(2))
        next_obs, reward, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, reward, next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs


def tabular_model(env: Corridor, timing: str) -> TRLSD:
    """TRLSD whose head is the per-cell mean of the rewards (kappa = 0) at the timing's inputs."""
    return TRLSD(
        "LinearPolicy",
        env,
        reward_head="tabular",
        kappa=0.0,
        reward_head_kwargs={"cells_per_dim": CELLS},
        reward_timing=timing,
        seed=0,
    )


@pytest.mark.parametrize("timing", ["start_state", "next_state", "transition"])
def test_each_timing_relabels_the_buffer_as_by_hand(timing):
    env = Corridor()
    model = tabular_model(env, timing)
    fill_online(model, env)
    data = model.replay_buffer.transitions()
    by_hand = {"start_state": data.states, "next_state": data.next_states}
    rewarded = by_hand.get(timing, np.concatenate([data.states, data.next_states], axis=1))
    expected = cell_means_by_hand(rewarded, data.rewards, rewarded)
    relabelled = model.task_learner(0).relabelled_rewards(model.replay_buffer)
    np.testing.assert_allclose(relabelled, expected, atol=1e-12)
    # On arrival the reward is all in the last cell; read at the start state it leaks into its neighbour.
    arrived = data.next_states[:, 0] >= 0.8
    assert (np.all(expected[arrived] == 1.0)) == (timing != "start_state")


def test_a_reward_for_entering_is_learnt_only_by_the_transition_timing():
    """Paid on entering the last fifth, not for staying in it: the next state alone cannot tell the two."""
    for timing in ("next_state", "transition"):
        env = EntryCorridor()
        model = tabular_model(env, timing)
        fill_online(model, env, steps=600)
        data = model.replay_buffer.transitions()
        entered = (data.states[:, 0] < 0.8) & (data.next_states[:, 0] >= 0.8)
        stayed = (data.states[:, 0] >= 0.8) & (data.next_states[:, 0] >= 0.8)
        assert entered.any() and stayed.any()
        assert np.array_equal(data.rewards, entered.astype(float))
        relabelled = model.task_learner(0).relabelled_rewards(model.replay_buffer)
        if timing == "transition":  # a pair of cells: s in the fourth fifth and s' in the last is an entry
            assert np.all(relabelled[stayed] == 0.0) and np.all(relabelled[entered] == 1.0)
        else:  # staying looks paid: the entries share its cell
            assert relabelled[stayed].mean() > 0.1


def test_transition_features_are_each_state_s_side_by_side():
    phi = AdditiveRBF((0.0, -1.0), (1.0, 1.0), n_per_dim=(3, 4), sigma=0.2)
    pair = TransitionFeatures(phi)
    states, next_states = np.array([[0.1, 0.5], [0.9, -0.7]]), np.array([[0.2, 0.4], [0.3, 0.0]])
    inputs = rewarded_inputs(states, next_states, "transition")
    assert inputs.shape == (2, 4) and pair.low == (0.0, -1.0, 0.0, -1.0) and pair.n_features == 14
    np.testing.assert_array_equal(pair(inputs), np.hstack([phi(states), phi(next_states)]))
    with pytest.raises(ValueError, match="reward_timing must be one of"):
        rewarded_inputs(states, next_states, "arrival")


def test_the_ridge_head_learns_a_reward_for_entering_with_the_transition_timing():
    env = EntryCorridor()
    model = TRLSD("LinearPolicy", env, kappa=0.0, reward_timing="transition", seed=0)
    fill_online(model, env, steps=600)
    data = model.replay_buffer.transitions()
    entered = (data.states[:, 0] < 0.8) & (data.next_states[:, 0] >= 0.8)
    stayed = (data.states[:, 0] >= 0.8) & (data.next_states[:, 0] >= 0.8)
    relabelled = model.task_learner(0).relabelled_rewards(model.replay_buffer)
    assert relabelled[entered].mean() > relabelled[stayed].mean() + 0.5


def test_the_known_head_refuses_the_transition_timing():
    with pytest.raises(ValueError, match="not 'transition'"):
        TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), reward_head="known", reward_timing="transition")


def test_auto_reads_the_env_s_declaration_and_defaults_to_gymnasium_s_convention():
    assert TRLSD("LinearPolicy", Corridor()).reward_timing == "next_state"
    maze = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3))
    assert maze.reward_timing == "start_state" and maze.task_learner(3).reward_timing == "start_state"
    with pytest.raises(ValueError, match="reward_timing must be one of"):
        TRLSD("LinearPolicy", Corridor(), reward_timing="arrival")


@pytest.mark.parametrize("timing", ["start_state", "next_state", "transition"])
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
    rewarded = rewarded_inputs(states, next_states, timing).astype(np.float64)
    queries = rewarded_inputs(sampled_states, sampled_next, timing)
    np.testing.assert_allclose(
        sample.rewards.numpy()[:, 0], cell_means_by_hand(rewarded, rewards, queries), rtol=1e-6
    )
