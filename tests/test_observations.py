"""
What TRLSD reads from observations, and the bad input it refuses or warns about instead of acting on it:
states that are not finite, states outside the box, Discrete spaces not numbered from 0.
"""

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces

import sb3_trlsd_envs  # noqa: F401  (registers the maze)
from sb3_trlsd import TRLSD
from sb3_trlsd.observations import (
    StateBoxMonitor,
    StateOutsideBoxWarning,
    check_action_space,
    outside_box_message,
    read_observation,
    split_observation,
    state_space_of,
    states_outside,
    task_count_of,
)

STATE_BOX = spaces.Box(np.array([-1, 0, 2], dtype=np.float32), np.array([1, 5, 3], dtype=np.float32))
LOW, HIGH = STATE_BOX.low.astype(np.float64), STATE_BOX.high.astype(np.float64)


def multitask_space(task_space: spaces.Space) -> spaces.Dict:
    return spaces.Dict({"state": STATE_BOX, "task": task_space})


@pytest.mark.parametrize(
    ("obs", "states", "tasks"),
    [
        (np.array([0.5, 1.0, 2.5]), [[0.5, 1.0, 2.5]], [0]),
        (th.tensor([[0.5, 1.0, 2.5], [0.0, 0.0, 2.0]]), [[0.5, 1.0, 2.5], [0.0, 0.0, 2.0]], [0, 0]),
        ({"state": np.array([0.5, 1.0, 2.5]), "task": 2}, [[0.5, 1.0, 2.5]], [2]),
        ({"state": np.zeros((2, 3)), "task": np.array([1.0])}, [[0, 0, 0], [0, 0, 0]], [1, 1]),
    ],
    ids=["box", "batched tensor", "dict", "one task for a batch"],
)
def test_split_observation_gives_states_and_tasks(obs, states, tasks):
    got_states, got_tasks = split_observation(obs, 3)
    np.testing.assert_array_equal(got_states, states)
    np.testing.assert_array_equal(got_tasks, tasks)
    assert (got_states.dtype, got_tasks.dtype) == (np.float64, np.int64)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("as_dict", [False, True], ids=["box", "dict"])
def test_a_state_that_is_not_finite_is_refused_naming_its_dimension(bad, as_dict):
    """A NaN state compared to nothing: the greedy action of all-NaN Q-values was action 0, silently."""
    state = np.array([[0.5, 1.0, 2.5], [0.5, bad, 2.5]], dtype=np.float32)
    obs = {"state": state, "task": np.array([0, 1])} if as_dict else state
    with pytest.raises(
        ValueError, match=rf"states must be finite: 1 of 2 state\(s\) have {bad} in dimension\(s\) \[1\]"
    ):
        split_observation(obs, 3, require_finite=True)
    split_observation(obs, 3)  # left to a caller that checks them itself (the replay buffer, naming them)


@pytest.mark.parametrize("task", [1.5, np.nan], ids=["fraction", "nan"])
def test_a_task_that_is_not_an_integer_is_refused(task):
    with pytest.raises(ValueError, match="tasks must be integers"):
        split_observation({"state": np.zeros(3), "task": np.array(task)}, 3)


@pytest.mark.parametrize("task", [-1, 3], ids=["negative", "past the last"])
def test_a_task_out_of_range_is_refused_when_the_count_is_given(task):
    """A task -1 would index the last task's reward head, silently."""
    obs = {"state": np.zeros(3), "task": np.array(task)}
    with pytest.raises(ValueError, match=rf"tasks must be in 0\.\.2, got \[{task}\]"):
        split_observation(obs, 3, task_count=3)
    split_observation(obs, 3)  # without the count: not checked


@pytest.mark.parametrize(
    "obs",
    [np.zeros(2), np.zeros(6), np.zeros((2, 2, 3)), {"state": np.zeros(4), "task": 0}],
    ids=["short", "two states flat", "3-d", "dict"],
)
def test_a_state_of_another_shape_is_refused_not_cut_into_states(obs):
    """(6,) for 3-D states used to be read as two states, silently."""
    with pytest.raises(
        ValueError, match=r"unexpected state shape .*a state is \(3,\) and a batch of them \(n, 3\)"
    ):
        split_observation(obs, 3)


def test_a_scalar_is_a_state_when_states_are_1_d():
    states, _ = split_observation(np.float32(0.5), 1)
    np.testing.assert_array_equal(states, [[0.5]])


def test_discrete_and_multidimensional_observations_are_refused_with_the_wrapper_to_use():
    """A tabular env's Discrete(n, start) state index is a 1-D Box of integers; an array Box is flattened."""
    with pytest.raises(
        ValueError,
        match=r"Discrete\(4, start=1\): give the state index as a Box of integers.*"
        r"Box\(1, 4, \(1,\), np.int64\)",
    ):
        state_space_of(spaces.Discrete(4, start=1))
    with pytest.raises(
        ValueError, match=r"got shape \(2, 2\): flatten it \(gymnasium.wrappers.FlattenObservation\)"
    ):
        state_space_of(spaces.Box(0, 1, (2, 2)))


def test_a_tabular_env_given_as_a_box_of_integers_learns():
    """The recipe of the Discrete refusal on deterministic FrozenLake: one feature per state, the goal in
    every evaluation episode."""

    def boxed(env):
        return gym.wrappers.TransformObservation(
            env, lambda s: np.array([s]), spaces.Box(0, env.observation_space.n - 1, (1,), np.int64)
        )

    model = TRLSD(
        "LinearPolicy", boxed(gym.make("FrozenLake-v1", is_slippery=False)), seed=0, source_transitions=2000
    )
    assert model.features.n_features == 16
    model.learn(2000)
    env = boxed(gym.make("FrozenLake-v1", is_slippery=False))
    state, _ = env.reset(seed=0)
    rewards, done = [], False
    while not done:
        state, reward, terminated, truncated, _ = env.step(int(model.predict(state)[0]))
        rewards.append(reward)
        done = terminated or truncated
    assert rewards[-1] == 1.0 and len(rewards) == 6  # the shortest path to the goal


def test_the_state_space_and_task_count_of_box_and_dict_observations():
    assert state_space_of(STATE_BOX) is STATE_BOX and task_count_of(STATE_BOX) == 1
    assert state_space_of(multitask_space(spaces.Discrete(4))) is STATE_BOX
    assert task_count_of(multitask_space(spaces.Discrete(4))) == 4


def test_a_task_space_not_starting_at_0_is_refused_with_the_wrapper_to_use():
    """Tasks 2..4 would be read as indices 2..4 of 3 tasks: the wrong reward heads, or an IndexError later."""
    space = multitask_space(spaces.Discrete(3, start=2))
    for function in (state_space_of, task_count_of):
        with pytest.raises(ValueError, match=r"number its tasks from 0, got Discrete\(3, start=2\).*0\.\.2"):
            function(space)
    with pytest.raises(ValueError, match="TransformObservation subtracting 2 from the task"):
        state_space_of(space)


def test_a_discrete_action_space_from_0_gives_its_number_of_actions():
    assert check_action_space(spaces.Discrete(5)) == 5


@pytest.mark.parametrize(
    ("space", "message"),
    [
        (spaces.Discrete(4, start=1), r"number its actions from 0, got Discrete\(4, start=1\).*action \+ 1"),
        (spaces.Box(-1, 1, (2,)), "action_space must be Discrete"),
    ],
    ids=["start 1", "box"],
)
def test_an_action_space_trlsd_cannot_act_in_is_refused(space, message):
    """With start=1, the greedy index 0 would be sent to the env: an action outside its space."""
    with pytest.raises(ValueError, match=message):
        check_action_space(space)


def test_states_outside_names_each_dimension_with_its_furthest_value():
    states = np.array([[0.0, 6.0, 2.5], [-1.5, 7.0, 2.5], [-1.2, 1.0, 2.5]])
    assert states_outside(states, LOW, HIGH) == {0: -1.5, 1: 7.0}
    assert states_outside(np.array([[0.0, 1.0, 2.5]]), LOW, HIGH) == {}
    assert states_outside(np.zeros((0, 3)), LOW, HIGH) == {}


def test_states_on_the_bounds_or_within_float32_rounding_are_inside():
    """float32 observations of a box given in float64 (state_bounds=(0.1, ...)) must not warn."""
    low, high = np.array([0.1, -0.3]), np.array([0.7, 1e6])
    states = np.array([low, high], dtype=np.float32)
    assert states_outside(states, low, high) == {}
    assert states_outside(np.array([[0.1, 1e6 + 1]]), low, high) == {1: 1e6 + 1}


def test_states_outside_an_unbounded_side_are_inside():
    assert states_outside(np.array([[-1e30, 2.0]]), np.array([-np.inf, 0.0]), np.array([0.0, 1.0])) == {
        1: 2.0
    }


def test_the_warning_names_dimension_value_box_and_what_to_do():
    message = outside_box_message({0: -1.5, 1: 7.0}, LOW, HIGH)
    for fragment in [
        "dimension 0: -1.5 (box [-1, 1])",
        "dimension 1: 7 (box [0, 5])",
        "features and similarities are taken relative to the box",
        "state_bounds=(low, high)",
        "np.clip",
    ]:
        assert fragment in message, message


def test_the_monitor_warns_once_and_only_of_states_outside():
    monitor = StateBoxMonitor(LOW, HIGH)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        monitor.check(np.array([[0.0, 1.0, 2.5]]))  # inside: no warning
    with pytest.warns(StateOutsideBoxWarning, match=r"dimension 2: 3\.5 \(box \[2, 3\]\)") as caught:
        monitor.check(np.array([[0.0, 1.0, 3.5]]))
    assert caught[0].filename == __file__  # at the caller, not in the monitor
    with pytest.warns(StateOutsideBoxWarning) as caught:
        StateBoxMonitor(LOW, HIGH).check(np.array([[0.0, 1.0, 3.5]]), stacklevel=2)
    assert caught[0].filename != __file__  # at the caller's caller (TRLSD's user, called from TRLSD)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        monitor.check(np.array([[9.0, 9.0, 9.0]]))  # warned already
    assert issubclass(StateOutsideBoxWarning, UserWarning)  # filtered as users filter warnings


def test_trlsd_refuses_an_env_whose_tasks_start_at_1_when_it_is_made():
    """Tasks 1..25 read as indices of 25 heads: each task's data taught to the next head, the last's lost."""
    env = gym.make("TRLSD/SharedDynamicsMaze-v0", task=(3, 3))
    space = spaces.Dict({"state": env.observation_space["state"], "task": spaces.Discrete(25, start=1)})
    shifted = gym.wrappers.TransformObservation(env, lambda obs: {**obs, "task": obs["task"] + 1}, space)
    with pytest.raises(ValueError, match=r"tasks from 0, got Discrete\(25, start=1\).*subtracting 1"):
        TRLSD("LinearPolicy", shifted)


def test_a_state_box_of_no_dimension_is_refused_by_name():
    """A Box of shape (0,) failed with numpy's 'argmax of an empty sequence' inside the feature map."""
    with pytest.raises(ValueError, match=r"at least one dimension, got shape \(0,\)"):
        state_space_of(spaces.Box(0, 1, (0,)))
    with pytest.raises(ValueError, match="at least one dimension"):
        state_space_of(spaces.Dict({"state": spaces.Box(0, 1, (0,)), "task": spaces.Discrete(2)}))


def test_read_observation_asks_a_dict_env_for_dicts():
    """A plain array on a Dict env was read as task 0's states, then failed in SB3 with an IndexError."""
    space = multitask_space(spaces.Discrete(3))
    with pytest.raises(ValueError, match=r"must be a \{'state': \.\.\., 'task': \.\.\.\} dict"):
        read_observation(np.array([0.5, 1.0, 2.5]), space)
    states, tasks = read_observation({"state": np.array([0.5, 1.0, 2.5]), "task": 2}, space)
    assert states.shape == (1, 3) and tasks.tolist() == [2]


@pytest.mark.parametrize("task", [3, -1], ids=["past-the-end", "negative"])
def test_read_observation_refuses_a_task_outside_the_task_space(task):
    """An env emitting a task outside its Discrete made TRLSD fail with an IndexError in the policy."""
    with pytest.raises(ValueError, match=r"in 0\.\.2 \(the observation space's 'task' Discrete\(3\)\)"):
        read_observation(
            {"state": np.array([0.5, 1.0, 2.5]), "task": task}, multitask_space(spaces.Discrete(3))
        )
