"""TRLSD off the maze: scale-free defaults, unbounded boxes, heads without the maze, source data as given."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd import TRLSD, RelabellingReplayBuffer, Transitions, collect_transitions
from sb3_trlsd.config import TRLSDConfig
from sb3_trlsd.feature_maps import AdditiveRBF, RandomFourierFeatures, RBFGrid
from sb3_trlsd.observations import WideStateBoxWarning
from sb3_trlsd.reward_heads import GridCells, KnownRewardHead, TabularRewardHead
from tests.conftest import MAZE_ID


class ScaledState(gym.ObservationWrapper):
    """The maze with its state Box stretched: states x ``scale`` + ``shift``, the same task family."""

    def __init__(self, env, scale=10.0, shift=0.0):
        super().__init__(env)
        self.scale, self.shift = scale, shift
        box = env.observation_space["state"]
        state_box = spaces.Box(box.low * scale + shift, box.high * scale + shift, dtype=np.float32)
        self.observation_space = spaces.Dict({"state": state_box, "task": env.observation_space["task"]})

    def observation(self, observation):
        state = (observation["state"].astype(np.float64) * self.scale + self.shift).astype(np.float32)
        return {"state": state, "task": observation["task"]}


def scaled(transitions: Transitions, scale: float, shift: float) -> Transitions:
    fields = {name: getattr(transitions, name) for name in Transitions.__dataclass_fields__}
    return Transitions(
        **{
            **fields,
            "states": transitions.states * scale + shift,
            "next_states": transitions.next_states * scale + shift,
        }
    )


@pytest.mark.parametrize("reward_head", ["thompson", "ridge", "tabular"])
def test_a_scaled_copy_of_the_maze_learns_exactly_as_the_original_with_default_arguments(
    source_transitions, reward_head
):
    """
    Widths are fractions of the state box: on the maze x 10 + 3, TRLSD's defaults take the actions they
    take on the maze (with absolute widths, the 0.2 tuned for the maze was 0.02 of the stretched box).
    """
    actions = []
    for scale, shift in ((1.0, 0.0), (10.0, 3.0)):
        env = ScaledState(gym.make(MAZE_ID, task=(1, 5)), scale, shift)
        model = TRLSD("LinearPolicy", env, reward_head=reward_head, seed=1)
        model.load_transitions(scaled(source_transitions, scale, shift))
        model.learn(total_timesteps=150)
        actions.append(model.replay_buffer.transitions().actions[-150:])
        assert model.policy_updates[4] >= 2
    np.testing.assert_array_equal(actions[0], actions[1])


def test_kappa_and_optimism_left_none_take_the_heads_defaults():
    """
    The default head draws from the posterior at 0.01 of the largest reward seen, over a source only; every
    other head is the paper's (kappa 0, R~ on every row); what is given is kept.
    """
    default = TRLSDConfig()
    assert (default.reward_head, default.kappa, default.optimism) == ("thompson", 0.01, "with_source")
    assert default.reward_head_kwargs == {"kappa_scale": "observed"}
    for head in ("ridge", "tabular", "bernstein", "ridge_posterior"):
        config = TRLSDConfig(reward_head=head)
        assert (config.kappa, config.optimism, config.reward_head_kwargs) == (0.0, "always", {})
    given = TRLSDConfig(kappa=0.3, optimism="always", reward_head_kwargs={"kappa_scale": "reward"})
    assert (given.kappa, given.optimism) == (0.3, "always")
    assert given.reward_head_kwargs == {"kappa_scale": "reward"}
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), seed=0)
    head = model.task_learner(0).head
    assert (head.kappa, head.kappa_scale) == (0.01, "observed")
    assert model.task_learner(0).optimism == "with_source"


@pytest.mark.parametrize(
    ("head", "wrong", "taken"),
    [
        ("ridge", "kappa_scale", "w_floor"),  # the draws' setting, on a head without draws
        ("thompson", "w_floor", "kappa_scale"),
        ("tabular", "ridge", "cells_per_dim"),
        ("known", "r_max", None),
        ("bernstein", "cells_per_dim", "reward_range"),
    ],
)
def test_reward_head_kwargs_a_head_does_not_take_are_refused_when_the_model_is_made(head, wrong, taken):
    """An argument of another head fails at once, naming the head's own, not at the first refit."""
    with pytest.raises(ValueError, match=rf"\['{wrong}'\] are not arguments of the '{head}' reward_head"):
        TRLSDConfig(reward_head=head, reward_head_kwargs={wrong: 1.0})
    maze = gym.make(MAZE_ID)
    with pytest.raises(ValueError, match="not arguments of"):
        TRLSD("LinearPolicy", maze, reward_head=head, reward_head_kwargs={wrong: 1.0})
    with pytest.raises(ValueError, match="not arguments of"):
        RelabellingReplayBuffer(
            10, maze.observation_space, maze.action_space, reward_head=head, reward_head_kwargs={wrong: 1.0}
        )
    if taken is not None:
        with pytest.raises(ValueError, match=rf"which takes \[.*'{taken}'"):
            TRLSDConfig(reward_head=head, reward_head_kwargs={wrong: 1.0})
    assert TRLSDConfig(reward_head=head, reward_head_kwargs={"log_count": "plus_1"}).reward_head == head


def test_an_unbounded_state_box_is_refused_with_the_way_to_bound_it():
    """CartPole's velocities are unbounded: the error names the dimensions and state_bounds, which fix it."""
    with pytest.raises(ValueError, match=r"unbounded in dimension\(s\) \[1, 3\].*state_bounds"):
        TRLSD("LinearPolicy", "CartPole-v1")
    bounds = (np.array([-2.4, -3.0, -0.21, -3.5]), np.array([2.4, 3.0, 0.21, 3.5]))
    model = TRLSD("LinearPolicy", "CartPole-v1", state_bounds=bounds, seed=0)
    assert isinstance(model.features, AdditiveRBF) and model.features.n_features == 32
    model.learn(total_timesteps=60)
    assert model.policy_updates[0] >= 1 and np.isfinite(model.policy.theta.numpy()).all()
    mlp = TRLSD(
        "MlpPolicy", "CartPole-v1", reward_head="tabular", state_bounds=bounds, fqi_max_iterations=1, seed=0
    )
    mlp.learn(total_timesteps=20)
    assert mlp.policy_updates[0] >= 1


class Stepper(gym.Env):
    """States s_t = t (up to 50) on a Box of ``low``..``high``, two actions that do nothing, reward s / 50."""

    action_space = spaces.Discrete(2)

    def __init__(self, low, high):
        self.observation_space = spaces.Box(low, high, (1,), np.float32)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.full(1, self.t, np.float32), self.t / 50, False, self.t >= 50, {}


def test_a_box_too_wide_to_tell_states_apart_is_warned_of_naming_state_bounds():
    """
    A Box of +-float32 max (a stand-in for an unbounded side) puts every state of ordinary scale at its
    centre: the features, and so Q, are the same at every state. Warned, naming the dimension and
    state_bounds; with state_bounds given, no warning and a Q that differs across states.
    """
    huge = float(np.finfo(np.float32).max)
    with pytest.warns(WideStateBoxWarning, match=r"dimension 0: \[-3.4e\+38, 3.4e\+38\].*state_bounds"):
        wide = TRLSD("LinearPolicy", Stepper(-huge, huge), reward_head="ridge", seed=0)
    wide.learn(total_timesteps=60)
    states = np.arange(0, 50, 7, dtype=np.float64)[:, None]
    assert np.ptp(wide.policy.q_values(states, 0), axis=0).max() == 0  # each action's Q: what is warned of
    with warnings.catch_warnings():
        warnings.simplefilter("error", WideStateBoxWarning)
        bounded = TRLSD(
            "LinearPolicy", Stepper(-huge, huge), reward_head="ridge", state_bounds=([0], [50]), seed=0
        )
        TRLSD("LinearPolicy", Stepper(0, 1e6), seed=0)  # as wide as the rule allows
    bounded.learn(total_timesteps=60)
    assert np.ptp(bounded.policy.q_values(states, 0), axis=0).min() > 0


@pytest.mark.parametrize(
    ("setting", "value"),
    [
        ("sigma", 1e-300),
        ("sigma", 1e300),
        ("sigma", [0.04, 1e9]),
        ("rbf_sigma", 1e300),
        ("rbf_sigma", 1e-12),
        ("rbf_overlap", 1e300),
    ],
    ids=[
        "sigma-tiny",
        "sigma-huge",
        "sigma-huge-in-one-dimension",
        "rbf-sigma-huge",
        "rbf-sigma-tiny",
        "overlap-huge",
    ],
)
def test_a_width_that_makes_every_similarity_or_feature_0_or_1_is_refused(setting, value):
    """
    sigma = 1e-300 made every similarity of eq. 6 0 between two distinct states (NaN at a state with itself:
    2 sigma^2 underflows), rbf_sigma = 1e300 every feature 1 at every state: refused, naming the setting and
    the widths that tell states apart.
    """
    with pytest.raises(ValueError, match=rf"{setting} must be .*a width in \[1e-09, 1e\+08\]"):
        TRLSDConfig(reward_head="ridge", **{setting: value})


def test_the_default_features_follow_the_box_and_the_dimension():
    """A grid of RBFs 1.5 spacings wide, at least 3 centres a dimension within 64 (8 x 8 in 2-D); beyond, a
    row of 8 RBFs per dimension, added; the paper's 5 x 5 grid of width 0.2 by name."""
    maze = TRLSD("LinearPolicy", gym.make(MAZE_ID))
    assert isinstance(maze.features, RBFGrid) and maze.features.counts == (8, 8)
    np.testing.assert_allclose(maze.features.widths, (1.5 * 5 / 8, 1.5 * 5 / 8))
    paper = TRLSD("LinearPolicy", gym.make(MAZE_ID), feature_map="paper")
    assert paper.features.n_features == 25 and paper.features.widths == (0.2, 0.2)
    six_d = gym.make("Acrobot-v1")
    model = TRLSD(
        "LinearPolicy",
        six_d,
        state_bounds=(six_d.observation_space.low * 0 - 1, -six_d.observation_space.low * 0 + 1),
    )
    assert isinstance(model.features, AdditiveRBF) and model.features.n_features == 48
    paper_6d = TRLSD("LinearPolicy", six_d, feature_map="paper", state_bounds=(-np.ones(6), np.ones(6)))
    assert isinstance(paper_6d.features, RandomFourierFeatures) and paper_6d.features.n_features == 300
    with pytest.raises(ValueError, match="rbf_per_dim=5 on a 6-D state"):
        TRLSD("LinearPolicy", six_d, feature_map="rbf", rbf_per_dim=5, state_bounds=(-np.ones(6), np.ones(6)))


class GridWalk(gym.Env):
    """A W x H grid world (6 x 4 by default) whose states are a Box of integers, paid on the far corner."""

    action_space = spaces.Discrete(4)

    def __init__(self, width=6, height=4):
        self.corner = np.array([width - 1, height - 1])
        self.observation_space = spaces.Box(0, self.corner, dtype=np.int64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.cell = np.zeros(2, dtype=np.int64)
        return self.cell.copy(), {}

    def step(self, action):
        move = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[action]
        self.cell = np.clip(self.cell + move, 0, self.corner)
        return self.cell.copy(), float(np.all(self.cell == self.corner)), False, False, {}


def greedy_paid_steps(model, env, steps=30):
    """The steps paid to the model's greedy policy in one episode of ``steps``."""
    state, _ = env.reset()
    paid = 0
    for _ in range(steps):
        action, _ = model.predict(state, deterministic=True)
        state, reward, *_ = env.step(int(action))
        paid += int(reward)
    return paid


def test_integer_states_get_one_rbf_per_cell_and_learn():
    """On a Box of integers the default features are the lattice's (one RBF per cell, half a cell wide), for
    the greedy policy after 600 steps reaches the rewarded cell (8 steps away) and keeps coming back to it."""
    model = TRLSD("LinearPolicy", gym.wrappers.TimeLimit(GridWalk(), 30), seed=0)
    assert isinstance(model.features, RBFGrid) and model.features.n_features == 24
    np.testing.assert_allclose(model.features.widths, (0.5, 0.5))
    phi = model.features(np.array([[2.0, 1.0]]))
    assert phi.argmax() == 2 * 4 + 1 and phi.max() == pytest.approx(1.0)
    model.learn(600)
    assert greedy_paid_steps(model, GridWalk()) >= 10  # a random walk earns ~1 in 30 steps


@pytest.mark.parametrize("seed", [0, 1])
def test_the_default_posterior_draws_explore_over_a_source_and_walk_from_scratch(seed):
    """
    The default head's Thompson draws relabel the buffer only once it holds rows the task did not collect:
    over random source transitions of a 10 x 6 grid they lead the greedy policy to the corner 14 steps away
    (paid on 17 of 30 steps); from scratch on the 6 x 4 grid R^ relabels it, the tie-break walks, and the
    corner is found on the seeds where draws over the task's own rows alone stay among them.
    """
    kwargs = {"seed": seed}
    large = GridWalk(10, 6)
    model = TRLSD("LinearPolicy", gym.wrappers.TimeLimit(large, 30), **kwargs)
    rng = np.random.default_rng(seed)
    states = rng.integers(0, large.corner + 1, size=(2000, 2))
    actions = rng.integers(0, 4, size=2000)
    next_states = np.clip(states + np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[actions], 0, large.corner)
    no = np.zeros(2000, dtype=bool)
    model.load_transitions(
        Transitions(states, actions, next_states, np.zeros(2000), np.zeros(2000, int), no, no)
    )
    model.learn(1000)
    assert greedy_paid_steps(model, GridWalk(10, 6)) == 17
    scratch = TRLSD("LinearPolicy", gym.wrappers.TimeLimit(GridWalk(), 30), **kwargs)
    scratch.learn(600)
    assert greedy_paid_steps(scratch, GridWalk()) == 23
    always = TRLSD("LinearPolicy", gym.wrappers.TimeLimit(GridWalk(), 30), **{**kwargs, "optimism": "always"})
    always.learn(600)
    assert greedy_paid_steps(always, GridWalk()) == 0


def test_the_tabular_head_takes_a_user_discretisation_and_the_grid_by_default():
    """reward_head='tabular' on a 3-D Box: GridCells of cells_per_dim; or the user's cell_fn and n_cells."""
    env = gym.make(MAZE_ID)
    grid = TRLSD("LinearPolicy", env, reward_head="tabular", reward_head_kwargs={"cells_per_dim": 2})
    head = grid.task_learner(0).head
    assert isinstance(head, TabularRewardHead) and head.n_cells == 4 and isinstance(head.cell_fn, GridCells)
    corners = TRLSD("LinearPolicy", env, reward_head="corners").task_learner(0).head
    assert np.flatnonzero(corners.allowed).tolist() == [0, 4, 20, 24]

    def halves(states):
        return (states[:, 0] > 2.5).astype(np.int64)

    user = TRLSD(
        "LinearPolicy", env, reward_head="tabular", reward_head_kwargs={"cell_fn": halves, "n_cells": 2}
    )
    user.task_learner(0).head.update(
        np.array([[1.0, 1.0], [4.0, 1.0], [4.5, 3.0]]), np.array([0.0, 1.0, 3.0])
    )
    np.testing.assert_allclose(
        user.task_learner(0).head.estimate(np.array([[0.5, 0.5], [3.0, 4.0]])), [0.0, 2.0]
    )


def test_the_known_head_checks_its_reward_fn_and_refits_as_the_buffer_grows():
    """
    reward_fn(states, task) must return one finite reward per state. Without source data, the known head
    (CI = 0, nothing to divide) refits whenever the shared buffer has doubled since its last refit.
    """
    env = gym.make(
        MAZE_ID, tasks="corners", task_schedule="round_robin", termination_prob=0.0, max_episode_steps=50
    )
    model = TRLSD("LinearPolicy", env, reward_head="known", seed=0)
    model.learn(total_timesteps=400)
    assert all(isinstance(learner.head, KnownRewardHead) for learner in model.task_learners.values())
    # Task 0 first fits on no row, then at 2, 4, 8, ... 256 rows; task 24 first fits on 150, then at 300.
    assert model.policy_updates[0] >= 7 and all(model.policy_updates[task] >= 2 for task in (4, 20, 24))

    def wrong(states, task):
        return np.zeros((len(states), 2))

    bad = TRLSD("LinearPolicy", gym.make(MAZE_ID), reward_head="known", reward_fn=wrong)
    with pytest.raises(ValueError, match=r"reward_fn\(states, task=0\) must return"):
        bad.update_policy(0)


def test_source_collection_goes_through_the_users_wrappers():
    """source_transitions=<number> collects from the env as given: every source state is stretched x 10."""
    env = ScaledState(gym.make(MAZE_ID, task=(2, 2)), 10.0)
    model = TRLSD("LinearPolicy", env, source_transitions=300, seed=0)
    model.learn(total_timesteps=5)
    states = model.replay_buffer.transitions().states
    assert len(states) == 305 and states.max() > 10 and states.min() >= 0 and states.max() <= 50


def test_source_env_is_used_when_given():
    """source_env= (an env, or a function making one) replaces the copy of the model's env."""
    made = []

    def make_source():
        made.append(True)
        return gym.make(MAZE_ID, task=(4, 4))

    model = TRLSD(
        "LinearPolicy", gym.make(MAZE_ID, task=(2, 2)), source_transitions=200, source_env=make_source, seed=0
    )
    model.learn(total_timesteps=3)
    reference = collect_transitions(gym.make(MAZE_ID, task=(4, 4)), 200, seed=0)
    assert made and np.array_equal(model.replay_buffer.transitions().tasks[:200], reference.tasks)
