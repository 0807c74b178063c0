"""The greedy action among equal Q-values: random while learning (``tie_break``), else the first."""

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd.action_choice import greedy_actions, tie_rng
from sb3_trlsd_envs import MAZE_ID


def test_ties_are_drawn_among_the_tied_actions_only_and_alike_in_any_batch():
    q = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 2.0], [3.0, 1.0, 0.0], [5.0, 5.0, 1.0]])
    assert greedy_actions(q).tolist() == [0, 1, 0, 0]
    draws = np.array([greedy_actions(q, [tie_rng(seed)] * len(q)) for seed in range(200)])
    assert set(draws[:, 0]) == {0, 1, 2} and set(draws[:, 1]) == {1, 2} and set(draws[:, 3]) == {0, 1}
    assert np.all(draws[:, 2] == 0)  # no tie: the argmax, and no draw
    # One state at a time draws what the batch draws: a draw for each tied state, in order.
    rng = tie_rng(3)
    one_by_one = [int(greedy_actions(q[i : i + 1], [rng])[0]) for i in range(len(q))]
    assert one_by_one == greedy_actions(q, [tie_rng(3)] * len(q)).tolist()


def maze_model(tie_break: str) -> TRLSD:
    """
    TRLSD with kappa = 0 and a source of one task whose rewards it discards: its Q is 0 everywhere. The
    greedy policy throughout, so that every action is the tie-break's (no epsilon-greedy step).
    """
    source = collect_transitions(gym.make(MAZE_ID, task=12), 300, seed=1)
    model = TRLSD(
        "LinearPolicy",
        gym.make(MAZE_ID, task=0),
        seed=0,
        kappa=0.0,
        tie_break=tie_break,
        exploration_initial_eps=0.0,
    )
    model.load_transitions(source, keep_rewards=False)
    return model


@pytest.mark.parametrize("tie_break", ["random", "first"])
def test_a_q_of_zero_explores_at_random_unless_ties_take_the_first(tie_break):
    model = maze_model(tie_break)
    env = gym.make(MAZE_ID, task=0)
    obs, _ = env.reset(seed=0)
    actions = []
    for _ in range(40):
        action = model.act(obs)
        actions.append(action)
        next_obs, _, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, 0.0, next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    assert np.all(model.policy.q_values(obs["state"][None], obs["task"]) == 0)
    if tie_break == "random":
        assert len(set(actions)) == model.action_space.n
    else:
        assert set(actions) == {0}
    assert int(model.predict(obs, deterministic=True)[0]) == 0


def test_predict_draws_ties_as_learn_does_and_a_loaded_model_draws_on(tmp_path):
    """predict(deterministic=False) breaks ties with the model's generator, which save and load keep."""
    model = maze_model("random")
    env = gym.make(MAZE_ID, task=0)
    obs, _ = env.reset(seed=0)
    model.act(obs)  # the task's first fit
    model.save(tmp_path / "model")
    loaded = TRLSD.load(tmp_path / "model", env=env)
    ahead = [int(model.predict(obs)[0]) for _ in range(20)]
    assert len(set(ahead)) > 1
    assert [int(loaded.predict(obs)[0]) for _ in range(20)] == ahead
    assert np.shape(model.predict(obs)[0]) == np.shape(model.predict(obs, deterministic=True)[0])


def test_an_unknown_tie_break_is_refused_by_name():
    with pytest.raises(ValueError, match="tie_break"):
        TRLSD("LinearPolicy", gym.make(MAZE_ID, task=0), tie_break="last")
