"""SharedDynamicsReplayBuffer: storage by task, source loading, relabelling for a target task."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import KnownRewardHead, RBFGrid, RidgeRewardHead, SharedDynamicsReplayBuffer
from sb3_trlsd.buffers import state_space_of
from sb3_trlsd_envs.maze import expected_reward
from tests.conftest import MAZE_ID


@pytest.fixture
def maze_spaces():
    env = gym.make(MAZE_ID)
    return env.observation_space, env.action_space


def make_buffer(maze_spaces, size=10_000):
    observation_space, action_space = maze_spaces
    return SharedDynamicsReplayBuffer(size, observation_space, action_space, device="cpu")


def add_online(buffer, rng, task, n):
    """n online steps of `task` the way SB3's collect_rollouts stores them."""
    for _ in range(n):
        state = rng.uniform(0, 5, size=(1, 2)).astype(np.float32)
        obs = {"state": state, "task": np.array([task])}
        next_obs = {"state": np.clip(state + 0.5, 0.01, 4.99), "task": np.array([task])}
        buffer.add(obs, next_obs, np.array([[1]]), np.array([rng.normal()]), np.array([False]), [{}])


def ridge_head(kappa=0.1):
    return RidgeRewardHead(RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.2), kappa=kappa, sigma=0.2)


def test_source_rewards_are_discarded_unless_kept(maze_spaces, source_transitions):
    """keep_rewards=False (the paper) must not leak the source task's rewards into its sample set Xi_tau."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions, keep_rewards=False)
    states, rewards = buffer.task_samples(12)
    assert len(states) == 0 and len(rewards) == 0
    buffer.add_transitions(source_transitions, keep_rewards=True)
    states, rewards = buffer.task_samples(12)
    np.testing.assert_allclose(rewards, source_transitions.rewards, rtol=1e-6)
    assert buffer.size() == 2 * len(source_transitions)


def test_online_transitions_are_stored_with_their_task(maze_spaces):
    """Each task's samples are exactly the transitions collected on it."""
    buffer = make_buffer(maze_spaces)
    rng = np.random.default_rng(0)
    add_online(buffer, rng, task=3, n=5)
    add_online(buffer, rng, task=7, n=4)
    assert len(buffer.task_samples(3)[0]) == 5 and len(buffer.task_samples(7)[0]) == 4
    np.testing.assert_array_equal(buffer.transitions().tasks, [3] * 5 + [7] * 4)


def test_transitions_keep_truncations_apart_from_terminations(maze_spaces, source_transitions):
    """Resets must stay truncations (bootstrapped), otherwise FQI would treat them as absorbing."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    stored = buffer.transitions()
    np.testing.assert_array_equal(stored.truncations, source_transitions.truncations)
    assert not stored.terminations.any()
    np.testing.assert_allclose(stored.next_states, source_transitions.next_states, atol=1e-6)


@pytest.mark.parametrize("buffer_size", [20_000, 3_500], ids=["no-wrap", "wrap-around"])
def test_relabelled_rewards_follow_the_head_incrementally(maze_spaces, source_transitions, buffer_size):
    """Cached relabelling equals R~ evaluated from scratch after interleaved head updates and new rows."""
    buffer = make_buffer(maze_spaces, size=buffer_size)
    buffer.add_transitions(source_transitions)
    head = ridge_head()
    rng = np.random.default_rng(1)
    for _ in range(3):
        add_online(buffer, rng, task=0, n=300)
        states, rewards = buffer.task_samples(0)
        head.update(states[-300:], rewards[-300:])
        relabelled = buffer.relabelled_rewards(0, head)
        expected = head.optimistic(buffer.transitions().states)
        np.testing.assert_allclose(relabelled, expected, rtol=1e-9, atol=1e-9)


def test_relabelled_set_is_the_whole_buffer_cast_on_the_target_task(maze_spaces, source_transitions):
    """psi keeps s, a, s' and replaces the reward by R~_tau(s) and the task by tau."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    head = KnownRewardHead(lambda states: expected_reward(states, 0))
    relabelled = buffer.relabelled(0, head)
    np.testing.assert_array_equal(relabelled.tasks, 0)
    np.testing.assert_array_equal(relabelled.actions, source_transitions.actions)
    np.testing.assert_allclose(relabelled.rewards, expected_reward(relabelled.states, 0))


def test_sampled_batches_are_relabelled(maze_spaces, source_transitions):
    """A sampled batch carries R~ of its own observations (HER-style relabelling at sample time)."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    head = KnownRewardHead(lambda states: expected_reward(states, 24))
    batch = buffer.sample_relabelled(256, task=24, head=head)
    states = batch.observations.numpy().astype(np.float64)
    np.testing.assert_allclose(batch.rewards.numpy()[:, 0], expected_reward(states, 24))


def test_pickling_drops_the_relabelling_cache(maze_spaces, source_transitions):
    """save_replay_buffer pickles the buffer: the caches (with their heads) must not go along."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    buffer.relabelled_rewards(0, ridge_head())
    restored = pickle.loads(pickle.dumps(buffer))
    assert restored._trackers == {}
    np.testing.assert_array_equal(restored.transitions().states, buffer.transitions().states)


def test_buffer_rejects_transitions_that_do_not_fit(maze_spaces, source_transitions):
    """Transitions of another state dimension or action space are refused by name."""
    buffer = make_buffer(maze_spaces)
    narrow = SharedDynamicsReplayBuffer(100, spaces.Box(0, 5, (3,)), spaces.Discrete(4), device="cpu")
    with pytest.raises(ValueError, match="dimension"):
        narrow.add_transitions(source_transitions)
    two_actions = SharedDynamicsReplayBuffer(100, spaces.Box(0, 5, (2,)), spaces.Discrete(2), device="cpu")
    with pytest.raises(ValueError, match="actions"):
        two_actions.add_transitions(source_transitions)
    assert buffer.size() == 0


def test_state_space_must_be_a_box_or_a_state_task_dict():
    """Observation spaces the algorithm cannot read a state from are refused at construction."""
    assert state_space_of(spaces.Box(0, 1, (3,))).shape == (3,)
    with pytest.raises(ValueError, match="observation_space"):
        state_space_of(spaces.Discrete(3))
    with pytest.raises(ValueError, match="observation_space"):
        state_space_of(spaces.Dict({"position": spaces.Box(0, 1, (2,))}))
