"""Epsilon-greedy while learning, per task: the schedule, the actions it gives, and where it is off."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd.action_choice import Exploration
from sb3_trlsd.config import head_defaults
from sb3_trlsd_lab.execution.protocols import AS_BUILT
from tests.conftest import MAZE_ID

ZOO_CONFIGS = Path(__file__).parents[1] / "zoo_configs"


def test_the_rate_falls_linearly_over_a_task_s_first_steps_then_stays():
    schedule = Exploration(initial_eps=1.0, final_eps=0.1, steps=10)
    np.testing.assert_allclose([schedule.rate(n) for n in (0, 5, 9, 10, 1_000)], [1.0, 0.55, 0.19, 0.1, 0.1])
    assert Exploration(0.5, 0.2, steps=0).rate(0) == 0.2
    assert not Exploration().explores and Exploration(0.0, 0.01, 5).explores


def act_online(model: TRLSD, env: gym.Env, n_steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n_steps`` of ``act`` and ``add_online_transition``: the actions taken, and the greedy ones."""
    taken, greedy = [], []
    obs, _ = env.reset(seed=seed)
    for _ in range(n_steps):
        action = model.act(obs)
        states, tasks = obs["state"][None].astype(np.float64), np.array([obs["task"]])
        greedy.append(int(model.engine.greedy(np.zeros(1, dtype=np.int64), states, tasks)[0]))
        taken.append(action)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, float(reward), next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    return np.array(taken), np.array(greedy)


def test_always_exploring_takes_uniform_actions_and_never_exploring_the_greedy_ones():
    env = gym.make(MAZE_ID, task=(1, 5))
    model = TRLSD("LinearPolicy", env, exploration_initial_eps=1.0, exploration_final_eps=1.0, seed=0)
    taken, greedy = act_online(model, env, 400)
    counts = np.bincount(taken, minlength=4) / len(taken)
    assert np.all((counts > 0.17) & (counts < 0.33)), counts
    assert np.mean(taken == greedy) < 0.5  # a quarter, up to the greedy action's own randomness

    env = gym.make(MAZE_ID, task=(1, 5))
    model = TRLSD("LinearPolicy", env, exploration_initial_eps=0.0, tie_break="first", seed=0)
    taken, greedy = act_online(model, env, 100)
    np.testing.assert_array_equal(taken, greedy)


def test_each_new_task_explores_anew():
    """The schedule counts each task's own samples: a task met late starts at the initial rate."""
    env = gym.make(MAZE_ID, tasks="all")
    model = TRLSD("LinearPolicy", env, exploration_steps=50, seed=0)
    model.learn(120)
    met = {task: learner.samples for task, learner in model.task_learners.items()}
    assert met and all(samples > 0 for samples in met.values())
    rates = {task: model.engine.exploration.rate(samples) for task, samples in met.items()}
    assert rates == {task: max(0.0, 1.0 - samples / 50) for task, samples in met.items()}
    unseen = next(task for task in range(25) if task not in met)
    assert model.engine.exploration.rate(model.task_learner(unseen).samples) == 1.0


def test_the_paper_s_protocol_and_its_zoo_configs_never_explore():
    settings = AS_BUILT.model_kwargs("ridge")
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), **settings)
    assert not model.config.exploration.explores
    configs = ZOO_CONFIGS.glob("*.yml")
    paper_configs = [path for path in configs if "as the paper's figures" in path.read_text()]
    assert len(paper_configs) == 6
    for path in paper_configs:
        (hyperparameters,) = yaml.safe_load(path.read_text()).values()
        default = head_defaults(hyperparameters["reward_head"])["exploration_initial_eps"]
        rate = hyperparameters.get("exploration_initial_eps", default)
        assert rate == 0.0, path.name


def greedy_sets_of_online_steps(model: TRLSD, env: gym.Env, n_steps: int) -> list[tuple[int, np.ndarray]]:
    """``n_steps`` of ``act`` and ``add_online_transition``: each action, and its state's greedy actions."""
    steps = []
    obs, _ = env.reset(seed=0)
    for _ in range(n_steps):
        action = model.act(obs)  # fits the task first at its first step
        q_values = model.policy.q_values(obs["state"][None].astype(np.float64), int(obs["task"]))[0]
        steps.append((action, np.flatnonzero(q_values == q_values.max())))
        next_obs, reward, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, float(reward), next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    return steps


def test_with_the_reward_known_the_defaults_act_greedily_from_the_first_step():
    """
    With the reward known there is nothing left to explore: an epsilon-greedy start would spend the first
    steps of the agent that knows the reward on random actions (Figure 1: it heads for the reward at once).
    A head that learns the reward keeps its exploration, and a rate given explicitly wins.
    """
    source = collect_transitions(gym.make(MAZE_ID, task=(3, 3)), 3_000, seed=0)
    env = gym.make(MAZE_ID, task=(1, 5))
    known = TRLSD("LinearPolicy", env, reward_head="known", seed=0)
    known.load_transitions(source)
    assert known.config.exploration_initial_eps == 0.0
    steps = greedy_sets_of_online_steps(known, env, 100)
    assert all(action in greedy for action, greedy in steps)

    learnt = TRLSD("LinearPolicy", env, seed=0)
    learnt.load_transitions(source)
    assert learnt.config.exploration_initial_eps == 1.0
    assert sum(action not in greedy for action, greedy in greedy_sets_of_online_steps(learnt, env, 100)) > 20
    explicit = TRLSD("LinearPolicy", env, reward_head="known", exploration_initial_eps=0.5, seed=0)
    assert explicit.config.exploration_initial_eps == 0.5


@pytest.mark.parametrize(
    ("setting", "value", "message"),
    [
        ("exploration_initial_eps", 1.5, "exploration_initial_eps must be in \\[0, 1\\]"),
        ("exploration_final_eps", -0.1, "exploration_final_eps must be in \\[0, 1\\]"),
        ("exploration_final_eps", float("nan"), "exploration_final_eps must be a finite number"),
        ("exploration_steps", -1, "exploration_steps must be an integer >= 0"),
        ("exploration_steps", 2.5, "exploration_steps must be an integer >= 0"),
    ],
)
def test_bad_exploration_settings_are_named(setting, value, message):
    with pytest.raises(ValueError, match=message):
        TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), **{setting: value})
