"""SharedDynamicsReplayBuffer: storage by task, source loading, relabelling for a target task."""

import pickle
import warnings
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import SharedDynamicsReplayBuffer
from sb3_trlsd.buffers import STORED_FIELDS, BufferCursor, BufferFullWarning
from sb3_trlsd.observations import state_space_of
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


def test_source_rewards_are_discarded_unless_kept(maze_spaces, source_transitions):
    """keep_rewards=False (the paper) stores 0 and marks the rows as having no observed reward."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions, keep_rewards=False)
    assert not buffer.transitions().rewards.any() and not buffer.has_reward[: buffer.pos].any()
    buffer.add_transitions(source_transitions, keep_rewards=True)
    kept = buffer.transitions(start=len(source_transitions))
    np.testing.assert_allclose(kept.rewards, source_transitions.rewards, rtol=1e-6)
    assert buffer.has_reward[len(source_transitions) : buffer.pos].all()
    assert buffer.size() == 2 * len(source_transitions)


def test_online_transitions_are_stored_with_their_task(maze_spaces):
    """Each online transition keeps the task it was collected on, and its reward counts as observed."""
    buffer = make_buffer(maze_spaces)
    rng = np.random.default_rng(0)
    add_online(buffer, rng, task=3, n=5)
    add_online(buffer, rng, task=7, n=4)
    np.testing.assert_array_equal(buffer.transitions().tasks, [3] * 5 + [7] * 4)
    assert buffer.has_reward[:9].all()


def test_transitions_keep_truncations_apart_from_terminations(maze_spaces, source_transitions):
    """Resets must stay truncations (bootstrapped), otherwise FQI would treat them as absorbing."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    stored = buffer.transitions()
    np.testing.assert_array_equal(stored.truncations, source_transitions.truncations)
    assert not stored.terminations.any()
    np.testing.assert_allclose(stored.next_states, source_transitions.next_states, atol=1e-6)


@pytest.mark.parametrize("buffer_size", [20_000, 3_500], ids=["no-wrap", "wrap-around"])
def test_a_cursor_reads_each_new_row_once_and_starts_over_when_rows_are_lost(
    maze_spaces, source_transitions, buffer_size
):
    """read_new hands out exactly the rows added since the reader's last read, or all when any were lost."""
    buffer = make_buffer(maze_spaces, size=buffer_size)
    cursor = BufferCursor()
    buffer.add_transitions(source_transitions)
    rows, restart = buffer.read_new(cursor)
    assert restart and len(rows) == buffer.size()
    rows, restart = buffer.read_new(cursor)
    assert not restart and len(rows) == 0
    wrapped = len(source_transitions) + 600 > buffer_size
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BufferFullWarning)  # wrapping is what this test is about
        add_online(buffer, np.random.default_rng(1), task=0, n=600)
    rows, restart = buffer.read_new(cursor)
    assert restart == wrapped
    expected = buffer.transitions() if wrapped else buffer.transitions(start=len(source_transitions))
    np.testing.assert_array_equal(rows.states, expected.states)
    buffer.reset()
    rows, restart = buffer.read_new(cursor)
    assert restart and len(rows) == 0


def test_a_pickled_buffer_is_a_new_buffer_for_cursors(maze_spaces, source_transitions):
    """save_replay_buffer pickles the buffer: its rows come back, and readers of the old one start over."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    cursor = BufferCursor()
    buffer.read_new(cursor)
    restored = pickle.loads(pickle.dumps(buffer))
    np.testing.assert_array_equal(restored.transitions().states, buffer.transitions().states)
    assert restored.read_new(cursor)[1]


def test_packed_rows_restore_the_buffer_exactly(maze_spaces, source_transitions):
    """What save puts in the zip gives back every stored array, bit for bit (float64 holds them exactly)."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)
    add_online(buffer, np.random.default_rng(2), task=5, n=7)
    copy = make_buffer(maze_spaces)
    copy.restore_packed_rows(buffer.packed_rows())
    assert (copy.pos, copy.full, copy.n_added) == (buffer.pos, buffer.full, buffer.n_added)
    for name in STORED_FIELDS:
        np.testing.assert_array_equal(getattr(copy, name)[: copy.pos], getattr(buffer, name)[: buffer.pos])
    with pytest.raises(ValueError, match="shape"):
        copy.restore_packed_rows(np.zeros((3, 5)))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"reward": np.nan}, "reward"),
        ({"reward": np.inf}, "reward"),
        ({"state": [np.nan, 1.0]}, "state"),
        ({"next_state": [1.0, np.inf]}, "next state"),
        ({"task": 25}, "tasks"),
        ({"task": -1}, "tasks"),
        ({"state": [1.0, 2.0, 3.0]}, "shape"),
        ({"action": 4}, "actions"),
        ({"done": 0.5}, "done must be booleans"),
        ({"done": 2}, "done must be booleans"),
    ],
    ids=[
        "nan-reward",
        "inf-reward",
        "nan-state",
        "inf-next-state",
        "task-25",
        "task-minus-1",
        "3-d",
        "action-4",
        "half-done",
        "done-of-2",
    ],
)
def test_a_bad_online_transition_is_refused_before_anything_is_stored(maze_spaces, change, message):
    """Validation comes first: the buffer is exactly as it was after the ValueError."""
    buffer = make_buffer(maze_spaces)
    add_online(buffer, np.random.default_rng(3), task=1, n=3)
    before = buffer.packed_rows()
    values = {
        "state": [1.0, 1.0],
        "next_state": [1.5, 1.0],
        "reward": 0.0,
        "task": 1,
        "action": 2,
        "done": False,
    }
    values |= change
    obs = {"state": np.array([values["state"]], dtype=np.float32), "task": np.array([values["task"]])}
    next_obs = {
        "state": np.array([values["next_state"]], dtype=np.float32),
        "task": np.array([values["task"]]),
    }
    with pytest.raises(ValueError, match=message):
        buffer.add(
            obs,
            next_obs,
            np.array([[values["action"]]]),
            np.array([values["reward"]]),
            np.array([values["done"]]),
            [{}],
        )
    np.testing.assert_array_equal(buffer.packed_rows(), before)


def test_recent_states_are_a_tasks_online_trajectory_broken_at_resets(maze_spaces, source_transitions):
    """The picture's trail: the task's own observed rows only, a NaN row after each reset."""
    buffer = make_buffer(maze_spaces)
    buffer.add_transitions(source_transitions)  # rewards discarded: not an online trajectory
    rng = np.random.default_rng(4)
    add_online(buffer, rng, task=2, n=3)
    state = np.array([[2.5, 2.5]], dtype=np.float32)
    obs = {"state": state, "task": np.array([2])}
    buffer.add(obs, obs, np.array([[0]]), np.array([0.0]), np.array([True]), [{"TimeLimit.truncated": True}])
    add_online(buffer, rng, task=6, n=2)
    trail = buffer.recent_states(2, 10)
    assert trail.shape == (5, 2) and np.isnan(trail[4]).all() and not np.isnan(trail[:4]).any()
    np.testing.assert_array_equal(trail[3], [2.5, 2.5])


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


@pytest.mark.parametrize(
    "size", [0, -3, np.nan, 2.5, True], ids=["zero", "negative", "nan", "fraction", "bool"]
)
def test_a_buffer_size_that_is_not_a_count_of_rows_is_refused(maze_spaces, size):
    """SB3 makes a buffer of 0 or fewer rows a buffer of one row, silently, and fails on NaN in numpy."""
    with pytest.raises(ValueError, match="buffer_size must be an integer >= 1"):
        make_buffer(maze_spaces, size=size)


def test_more_transitions_than_the_buffer_holds_are_refused_not_cut(maze_spaces, source_transitions):
    """The ring kept the last buffer_size rows of the batch and dropped the first ones, with no word."""
    buffer = make_buffer(maze_spaces, size=len(source_transitions) - 1)
    with pytest.raises(ValueError, match=f"buffer_size >= {len(source_transitions)}"):
        buffer.add_transitions(source_transitions)
    assert buffer.size() == 0


def test_the_ring_warns_once_when_it_starts_replacing_rows(maze_spaces, source_transitions):
    """
    Online rows wrapping the ring replace the oldest, source rows first, as SB3's buffers do: Fitted-Q then
    no longer sees them, which must not happen silently. Warned once, naming buffer_size.
    """
    buffer = make_buffer(maze_spaces, size=len(source_transitions) + 5)
    buffer.add_transitions(source_transitions)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        add_online(buffer, np.random.default_rng(0), task=0, n=5)  # fills the buffer, replaces nothing
    with pytest.warns(BufferFullWarning, match=f"buffer_size={len(source_transitions) + 5}"):
        add_online(buffer, np.random.default_rng(1), task=0, n=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        add_online(buffer, np.random.default_rng(2), task=0, n=20)
    assert buffer.size() == buffer.buffer_size


def test_check_room_refuses_rows_that_would_push_out_stored_ones(maze_spaces, source_transitions):
    """Loaded transitions must fit beside the rows stored: the error names the buffer_size holding both."""
    buffer = make_buffer(maze_spaces, size=len(source_transitions) + 10)
    buffer.add_transitions(source_transitions)
    buffer.check_room(10)
    with pytest.raises(ValueError, match=f"buffer_size >= {len(source_transitions) + 11}"):
        buffer.check_room(11)


@pytest.mark.parametrize("dtype", [np.int64, np.uint8], ids=["int64", "uint8"])
def test_float_states_on_a_box_of_integers_are_refused_not_truncated(source_transitions, dtype):
    """An integer Box stored 1.7 as 1 (numpy's cast), silently: refused, naming the dtype and the fix."""
    buffer = SharedDynamicsReplayBuffer(100, spaces.Box(0, 5, (2,), dtype), spaces.Discrete(4), device="cpu")
    floats = replace(source_transitions.take(np.arange(10)), tasks=np.zeros(10, dtype=np.int64))
    with pytest.raises(
        ValueError, match=f"must be integers on this env's state Box of dtype {np.dtype(dtype)}"
    ):
        buffer.add_transitions(floats)
    assert buffer.size() == 0
    rounded = replace(floats, states=np.rint(floats.states), next_states=np.rint(floats.next_states))
    buffer.add_transitions(rounded)
    np.testing.assert_array_equal(buffer.transitions().states, rounded.states)
    out_of_dtype = replace(rounded, states=np.full_like(rounded.states, 300.0))
    if dtype is np.uint8:  # 300 would wrap round to 44
        with pytest.raises(ValueError, match="must fit the state Box's dtype uint8"):
            buffer.add_transitions(out_of_dtype)
