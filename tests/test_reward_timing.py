"""What of a transition its reward belongs to (``reward_timing``): the heads learn and relabel at the start
state (the paper's R_tau(s)), at the next state (Gymnasium's convention), at the pair (s, s') or at the step
(s, a, s'), checked against a relabelling by hand."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import TRLSD, RelabellingReplayBuffer
from sb3_trlsd.config import TRLSDConfig
from sb3_trlsd.feature_maps import AdditiveRBF
from sb3_trlsd.reward_timing import (
    ACTION_WIDTH,
    TransitionFeatures,
    input_box,
    rewarded_inputs,
    staying_inputs,
)
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


class CostlyCorridor(Corridor):
    """The corridor whose step right also costs 0.5: a reward of (a, s'), not of the states alone."""

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward - 0.5 * action, terminated, truncated, info


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


def ridge_by_hand(phi: np.ndarray, rewards: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Ridge regression (lambda = 1) of ``rewards`` on the features ``phi``, at the features ``queries``."""
    weights = np.linalg.solve(phi.T @ phi + np.eye(phi.shape[1]), phi.T @ rewards)
    return queries @ weights


def step_features_by_hand(model: TRLSD, states, actions, next_states) -> np.ndarray:
    """[Phi(s), e_a, Phi(s')] of each transition, from the model's state features."""
    one_hot = np.eye(int(model.action_space.n))[np.asarray(actions, dtype=int).reshape(-1)]
    return np.hstack([model.features(states), one_hot, model.features(next_states)])


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
    relabelled = model.engine.relabelled_rewards(0, 0)
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
        relabelled = model.engine.relabelled_rewards(0, 0)
        if timing == "transition":  # a pair of cells: s in the fourth fifth and s' in the last is an entry
            assert np.all(relabelled[stayed] == 0.0) and np.all(relabelled[entered] == 1.0)
        else:  # staying looks paid: the entries share its cell
            assert relabelled[stayed].mean() > 0.1


def test_transition_features_are_each_state_s_side_by_side():
    phi = AdditiveRBF((0.0, -1.0), (1.0, 1.0), n_per_dim=(3, 4), sigma=0.2)
    pair = TransitionFeatures(phi)
    states, next_states = np.array([[0.1, 0.5], [0.9, -0.7]]), np.array([[0.2, 0.4], [0.3, 0.0]])
    inputs = rewarded_inputs(states, np.array([0, 1]), next_states, "transition")
    assert inputs.shape == (2, 4) and pair.low == (0.0, -1.0, 0.0, -1.0) and pair.n_features == 14
    np.testing.assert_array_equal(pair(inputs), np.hstack([phi(states), phi(next_states)]))
    with pytest.raises(ValueError, match="reward_timing must be one of"):
        rewarded_inputs(states, np.array([0, 1]), next_states, "arrival")


def test_the_ridge_head_learns_a_reward_for_entering_with_the_transition_timing():
    env = EntryCorridor()
    model = TRLSD("LinearPolicy", env, kappa=0.0, reward_timing="transition", seed=0)
    fill_online(model, env, steps=600)
    data = model.replay_buffer.transitions()
    entered = (data.states[:, 0] < 0.8) & (data.next_states[:, 0] >= 0.8)
    stayed = (data.states[:, 0] >= 0.8) & (data.next_states[:, 0] >= 0.8)
    relabelled = model.engine.relabelled_rewards(0, 0)
    assert relabelled[entered].mean() > relabelled[stayed].mean() + 0.5


def test_the_known_head_refuses_the_transition_timing():
    with pytest.raises(ValueError, match="not 'transition'"):
        TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), reward_head="known", reward_timing="transition")


def test_auto_reads_the_env_s_declaration_and_defaults_to_gymnasium_s_convention():
    assert TRLSD("LinearPolicy", Corridor()).reward_timing == "step"  # r(s, a, s')
    assert TRLSD("MlpPolicy", Corridor()).reward_timing == "step"
    for head in ("tabular", "corners"):  # a grid over states: the next state's
        assert TRLSD("LinearPolicy", Corridor(), reward_head=head).reward_timing == "next_state"
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
    rewarded = rewarded_inputs(states, np.ones(len(states)), next_states, timing).astype(np.float64)
    queries = rewarded_inputs(sampled_states, np.ones(len(sampled_states)), sampled_next, timing)
    np.testing.assert_allclose(
        sample.rewards.numpy()[:, 0], cell_means_by_hand(rewarded, rewards, queries), rtol=1e-6
    )


def test_step_features_put_the_action_s_one_hot_code_between_the_states():
    phi = AdditiveRBF((0.0, -1.0), (1.0, 1.0), n_per_dim=(3, 4), sigma=0.2)
    step = TransitionFeatures(phi, n_actions=3)
    states, next_states = np.array([[0.1, 0.5], [0.9, -0.7]]), np.array([[0.2, 0.4], [0.3, 0.0]])
    inputs = rewarded_inputs(states, np.array([2, 0]), next_states, "step")
    assert inputs.shape == (2, 5) and np.array_equal(inputs[:, 2], [2.0, 0.0])
    assert step.low == (0.0, -1.0, 0.0, 0.0, -1.0) and step.high == (1.0, 1.0, 2.0, 1.0, 1.0)
    assert step.n_features == 17
    codes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(step(inputs), np.hstack([phi(states), codes, phi(next_states)]))
    low, high = input_box(np.zeros(2), np.ones(2), "step", n_actions=1)  # one action: still low < high
    assert np.all(low < high)


def test_the_step_timing_relabels_the_buffer_as_ridge_regression_by_hand():
    env = CostlyCorridor()
    model = TRLSD("LinearPolicy", env, kappa=0.0, reward_timing="step", seed=0)
    fill_online(model, env, steps=400)
    data = model.replay_buffer.transitions()
    phi = step_features_by_hand(model, data.states, data.actions, data.next_states)
    relabelled = model.engine.relabelled_rewards(0, 0)
    np.testing.assert_allclose(relabelled, ridge_by_hand(phi, data.rewards, phi), atol=1e-8)
    assert model.task_learner(0).head.features.n_features == 2 * model.features.n_features + 2
    widths = TRLSDConfig(reward_timing="step").builder(env.observation_space, 2, linear_q=True)
    state_width = TRLSDConfig().similarity_width(np.zeros(1), np.ones(1))
    np.testing.assert_allclose(
        widths.similarity_width(), np.concatenate([state_width, [ACTION_WIDTH], state_width])
    )


def test_only_the_step_timing_learns_a_cost_per_action():
    """Right costs 0.5 wherever it leads: the step timing learns it, the next state alone cannot."""
    learnt = {}
    for timing in ("next_state", "step"):
        env = CostlyCorridor()
        model = TRLSD("LinearPolicy", env, kappa=0.0, reward_timing=timing, seed=0)
        fill_online(model, env, steps=600)
        data = model.replay_buffer.transitions()
        relabelled = model.engine.relabelled_rewards(0, 0)
        inside = data.next_states[:, 0] < 0.7  # far from the paid fifth: only the cost differs
        right, left = inside & (data.actions == 1), inside & (data.actions == 0)
        learnt[timing] = relabelled[left].mean() - relabelled[right].mean()
    assert abs(learnt["step"] - 0.5) < 0.1
    assert abs(learnt["next_state"]) < 0.1


@pytest.mark.parametrize("head", ["known", "tabular", "corners"])
def test_heads_on_states_alone_refuse_the_step_timing(head):
    with pytest.raises(ValueError, match="step"):
        TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), reward_head=head, reward_timing="step")


def test_the_relabelling_buffer_relabels_a_step_by_its_action():
    env = CostlyCorridor()
    buffer = RelabellingReplayBuffer(
        500,
        env.observation_space,
        env.action_space,
        device="cpu",
        kappa=0.0,
        reward_timing="step",
        relabel_online_rows=True,
    )
    rng = np.random.default_rng(1)
    states = rng.uniform(0, 1, size=(200, 1)).astype(np.float32)
    actions = rng.integers(2, size=200)
    next_states = np.clip(states + np.where(actions, 0.1, -0.1)[:, None], 0, 1).astype(np.float32)
    rewards = (next_states[:, 0] >= 0.8) - 0.5 * actions
    for state, action, next_state, reward in zip(states, actions, next_states, rewards, strict=True):
        buffer.add(
            state[None], next_state[None], np.array([[action]]), np.array([reward]), np.array([False]), [{}]
        )
    sample = buffer.sample(100)
    sampled = [sample.observations.numpy(), sample.actions.numpy()[:, 0], sample.next_observations.numpy()]
    phi = np.hstack([buffer.features(states), np.eye(2)[actions], buffer.features(next_states)])
    queries = np.hstack(
        [buffer.features(sampled[0]), np.eye(2)[sampled[1].astype(int)], buffer.features(sampled[2])]
    )
    np.testing.assert_allclose(sample.rewards.numpy()[:, 0], ridge_by_hand(phi, rewards, queries), rtol=1e-5)


def test_staying_is_one_input_or_one_per_action_of_a_step():
    states = np.array([[0.2], [0.6]])
    assert [rows.shape for rows in staying_inputs(states, "next_state", 3)] == [(2, 1)]
    steps = staying_inputs(states, "step", 3)
    assert [rows[:, 1].tolist() for rows in steps] == [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]
    assert all(np.array_equal(rows[:, [0, 2]], np.hstack([states, states])) for rows in steps)
