"""TRLSD as an SB3 algorithm: transfer on the maze, refit trigger, SB3 conventions, errors."""

import csv
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

from sb3_trlsd import TRLSD, Transitions
from sb3_trlsd.observations import StateOutsideBoxWarning
from sb3_trlsd_envs.evaluation import greedy_expected_rewards
from sb3_trlsd_envs.maze_tasks import N_TASKS
from tests.conftest import MAZE_ID


def make_model(source, task=(1, 1), n_steps_seed=0, **kwargs):
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=task), seed=n_steps_seed, **kwargs)
    model.load_transitions(source, keep_rewards=False)
    return model


def test_known_reward_gives_a_rational_policy_at_once(paper_source_transitions):
    """
    Figure 1's setting: with the reward known, the greedy policy fitted on the paper's 25,000 random
    transitions heads for the reward cell. Averaged over the 25 tasks and 1,000 steps, the expected reward
    must reach 0.6 (a random policy gets 1/25 = 0.04; a reference implementation 0.66).
    """
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks="all"), reward_head="known", seed=0)
    model.load_transitions(paper_source_transitions)
    for task in range(N_TASKS):
        model.update_policy(task)
    rewards = greedy_expected_rewards(
        model.policy.q_values, np.arange(N_TASKS), n_steps=1_000, rng=np.random.default_rng(0)
    )
    assert rewards.mean() >= 0.6


def test_learn_relabels_fits_and_logs_to_tensorboard(source_transitions, tmp_path):
    """learn() with the optimistic ridge head refits the policy and writes the documented TensorBoard tags."""
    model = make_model(source_transitions, tensorboard_log=str(tmp_path), kappa=0.1, sigma=0.04)
    model.learn(total_timesteps=300, log_interval=1)
    assert model.policy_updates[0] >= 2
    assert model.task_learner(0).head.n_samples == 300
    (event_file,) = tmp_path.glob("TRLSD_1/events.out.tfevents.*")
    tags = set(EventAccumulator(str(event_file)).Reload().Tags()["scalars"])
    expected = {
        "train/policy_updates",
        "train/fqi_iterations",
        "train/bellman_residual",
        "reward/ci_mean",
        "reward/target_samples",
        "rollout/ep_rew_mean",
        "rollout/exploration_rate",
    }
    assert expected <= tags


def test_the_exploration_rate_logged_is_the_stepping_task_s_epsilon(tmp_path):
    """As SB3's DQN logs its epsilon: the rate the task of the last step explores with at its next step."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), exploration_steps=100, seed=0)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(total_timesteps=40, log_interval=1)
    rows = list(csv.DictReader((tmp_path / "progress.csv").open()))
    assert float(rows[-1]["rollout/exploration_rate"]) == pytest.approx(1.0 - 40 / 100)


@pytest.mark.parametrize("reward_timing", ["auto", "step"])  # a head of states, and of (s, a, s')
def test_learn_logs_pictures_and_hyperparameters_to_tensorboard(tmp_path, reward_timing):
    """
    The maze's picture of a task at its first refit and every log_picture_every refits, and the HParams.
    With the default log_interval (4 episodes, ~4 dumps in 300 steps) a picture recorded into the logger
    would be overwritten before the dump; written when made, every due picture is in the file. A head of
    steps is drawn as its mean over the actions of staying.
    """
    model = TRLSD(
        "LinearPolicy",
        gym.make(MAZE_ID, task=(1, 5)),
        source_transitions=500,
        log_picture_every=3,
        tensorboard_log=str(tmp_path),
        kappa=0.1,
        reward_timing=reward_timing,
        seed=0,
    )
    model.learn(total_timesteps=300)
    pictures, steps, hparams = [], [], set()
    for event_file in tmp_path.rglob("events.out.tfevents.*"):
        for event in EventFileLoader(str(event_file)).Load():
            for value in event.summary.value:
                if value.tag == "pictures/task_4":
                    pictures.append(value.tensor.string_val)  # width, height, PNG bytes
                    steps.append(event.step)
                if value.metadata.plugin_data.plugin_name == "hparams":
                    hparams.add(value.tag)
    refits = model.policy_updates[4]
    assert refits >= 6
    assert len(pictures) == 1 + refits // 3
    assert steps[0] == 0  # the first refit, before the first step
    width, height, png = pictures[0]
    assert (int(height), int(width)) == (360, 720)
    assert png.startswith(b"\x89PNG")
    assert "_hparams_/experiment" in hparams
    assert model.hyperparameters()["kappa"] == 0.1


def test_source_transitions_are_collected_from_a_copy_of_the_env_or_loaded_from_a_file(tmp_path):
    """The config-file way of giving the source set: seeded, loaded once, rewards discarded."""
    env = gym.make(MAZE_ID, task=(2, 2))
    first = TRLSD("LinearPolicy", env, source_transitions=400, seed=3)
    first.learn(total_timesteps=10)
    second = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(2, 2)), source_transitions=400, seed=3)
    second.learn(total_timesteps=10)
    rows = first.replay_buffer.transitions()
    np.testing.assert_array_equal(rows.states, second.replay_buffer.transitions().states)
    assert len(rows) == 410
    assert first.task_learner(6).head.n_samples == 10  # tau_22's own online samples: source rewards discarded
    first.learn(total_timesteps=10, reset_num_timesteps=False)
    assert first.replay_buffer.size() == 420  # not collected again

    path = tmp_path / "source.npz"
    Transitions(
        states=rows.states[:400],
        actions=rows.actions[:400],
        next_states=rows.next_states[:400],
        rewards=rows.rewards[:400],
        tasks=rows.tasks[:400],
        truncations=rows.truncations[:400],
        terminations=rows.terminations[:400],
    ).save(path)
    from_file = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(2, 2)), source_transitions=str(path), seed=3)
    from_file.learn(total_timesteps=10)
    np.testing.assert_array_equal(from_file.replay_buffer.transitions().states, rows.states)


def test_smaller_update_ratio_triggers_more_policy_updates(source_transitions):
    """update_ratio is the refit trigger of section 3: a threshold closer to 1 must fire more often."""
    counts = {}
    for ratio in (2.0, 1.2):
        model = make_model(source_transitions, update_ratio=ratio)
        model.learn(total_timesteps=300)
        counts[ratio] = model.policy_updates[0]
    assert counts[1.2] > counts[2.0]


def test_non_optimistic_head_still_triggers_refits(source_transitions):
    """kappa=0 has a zero CI, yet its refits follow the same kappa-free trigger as the optimistic head."""
    model = make_model(source_transitions, kappa=0.0)
    model.learn(total_timesteps=300)
    assert model.policy_updates[0] >= 2


def test_seeded_runs_are_reproducible(source_transitions):
    """Same seed, same online trajectory and same Q parameters."""
    runs = []
    for _ in range(2):
        model = make_model(source_transitions, n_steps_seed=3)
        model.learn(total_timesteps=150)
        runs.append((model.replay_buffer.transitions(), model.policy.theta.clone()))
    np.testing.assert_array_equal(runs[0][0].actions, runs[1][0].actions)
    np.testing.assert_array_equal(runs[0][1].numpy(), runs[1][1].numpy())


def test_callbacks_and_progress_bar_work(source_transitions):
    """Callbacks are called once per step and the progress bar does not break learn()."""

    class CountSteps(BaseCallback):
        def __init__(self):
            super().__init__()
            self.calls = 0

        def _on_step(self) -> bool:
            self.calls += 1
            return True

    callback = CountSteps()
    make_model(source_transitions).learn(total_timesteps=50, callback=callback, progress_bar=True)
    assert callback.calls == 50


def test_predict_on_single_and_batched_observations(source_transitions):
    """predict follows SB3: a single observation gives a scalar action, a batch one action per row."""
    model = make_model(source_transitions)
    model.learn(total_timesteps=20)
    single, _ = model.predict(
        {"state": np.array([0.5, 0.5], dtype=np.float32), "task": 0}, deterministic=True
    )
    batch, _ = model.predict(
        {
            "state": np.array([[0.5, 0.5], [4.5, 4.5], [2.5, 0.5]], dtype=np.float32),
            "task": np.array([0, 0, 0]),
        }
    )
    assert np.ndim(single) == 0 and batch.shape == (3,)
    assert batch[0] == single


def test_save_load_round_trip_predicts_the_same_and_keeps_learning(source_transitions, tmp_path):
    """A loaded model has the same Q and reward heads, the same actions, and can go on learning."""
    model = make_model(source_transitions)
    model.learn(total_timesteps=200)
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    env = gym.make(MAZE_ID, task=(1, 1))
    loaded = TRLSD.load(tmp_path / "model", env=env)
    loaded.load_replay_buffer(tmp_path / "buffer")
    states = np.random.default_rng(0).uniform(0, 5, size=(500, 2))
    np.testing.assert_array_equal(loaded.policy.q_values(states, 0), model.policy.q_values(states, 0))
    np.testing.assert_allclose(
        loaded.task_learner(0).head.optimistic(states), model.task_learner(0).head.optimistic(states)
    )
    assert loaded.replay_buffer.size() == model.replay_buffer.size()
    loaded.learn(total_timesteps=100, reset_num_timesteps=False)
    assert loaded.task_learner(0).head.n_samples == 300


def test_mlp_policy_learns(source_transitions):
    """The MLP policy goes through the same loop: fitted at the first step, refitted on triggers."""
    mlp = TRLSD("MlpPolicy", gym.make(MAZE_ID, task=(1, 1)), fqi_max_iterations=3, seed=0)
    mlp.load_transitions(source_transitions)
    mlp.learn(total_timesteps=60)
    assert mlp.policy_updates[0] >= 1 and mlp.task_learner(0).fitted
    assert np.isfinite(mlp.policy.q_values(np.ones((4, 2)), 0)).all()


def test_multi_task_env_triggers_each_task_on_its_own():
    """With tasks in turns and no source data, every task seen gets its own head and its own refits."""
    env = gym.make(
        MAZE_ID, tasks="corners", task_schedule="round_robin", termination_prob=0.0, max_episode_steps=50
    )
    model = TRLSD("LinearPolicy", env, seed=0)
    model.learn(total_timesteps=400)
    assert sorted(model.task_learners) == [0, 4, 20, 24]
    assert all(model.policy_updates[task] >= 1 for task in (0, 4, 20, 24))
    assert all(learner.head.n_samples == 100 for learner in model.task_learners.values())


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"kappa": -0.1}, "kappa"),
        ({"sigma": 0.0}, "sigma"),
        ({"update_ratio": 1.0}, "update_ratio"),
        ({"reward_head": "gaussian-process"}, "reward_head"),
        ({"similarity": "cosine"}, "similarity"),
        ({"source_transitions": 0}, "source_transitions"),
        ({"source_transitions": 2.5}, "source_transitions"),
        ({"log_picture_every": -1}, "log_picture_every"),
        ({"kappa": np.nan}, "kappa"),
        ({"kappa": np.inf}, "kappa"),
        ({"sigma": np.nan}, "sigma"),
        ({"update_ratio": np.nan}, "update_ratio"),
        ({"gamma": np.nan}, "gamma"),
        ({"fqi_tol": -1e-4}, "fqi_tol"),
        ({"fqi_tol": np.nan}, "fqi_tol"),
        ({"fqi_max_iterations": 0}, "fqi_max_iterations"),
        ({"rbf_per_dim": 0}, "rbf_per_dim"),
        ({"rbf_sigma": -0.2}, "rbf_sigma"),
        ({"policy_kwargs": {"rbf_per_dim": 7}}, "rbf_per_dim"),
        ({"first_fit": "first_reward"}, "first_fit"),
        ({"buffer_size": 0}, "buffer_size"),
        ({"buffer_size": -10}, "buffer_size"),
        ({"buffer_size": np.nan}, "buffer_size"),
        ({"buffer_size": 100, "source_transitions": 500}, "buffer_size >= 500"),
        ({"learning_starts": np.inf}, "learning_starts"),
        ({"seed": np.nan}, "seed"),
        ({"train_freq": (4, "epoch")}, "train_freq"),
    ],
    ids=[
        "negative-kappa",
        "zero-sigma",
        "update-ratio-1",
        "unknown-head",
        "unknown-similarity",
        "no-source",
        "fractional-source",
        "negative-picture-period",
        "nan-kappa",
        "inf-kappa",
        "nan-sigma",
        "nan-update-ratio",
        "nan-gamma",
        "negative-tol",
        "nan-tol",
        "no-iterations",
        "no-rbf",
        "negative-rbf-sigma",
        "rbf-in-policy-kwargs",
        "unknown-first-fit",
        "zero-buffer",
        "negative-buffer",
        "nan-buffer",
        "source-larger-than-buffer",
        "inf-learning-starts",
        "nan-seed",
        "unknown-train-freq-unit",
    ],
)
def test_bad_hyperparameters_are_refused_by_name(kwargs, argument):
    """Each bad setting raises a ValueError naming the argument at construction (NaN passes a `< 0` check)."""
    with pytest.raises(ValueError, match=argument):
        TRLSD("LinearPolicy", gym.make(MAZE_ID), **kwargs)


def test_one_policy_kwargs_dict_builds_several_models():
    """TRLSD keeps a copy of ``policy_kwargs`` (it adds the features to it): the caller's dict is left as it
    was and builds a second model."""
    layers = {"net_arch": [8]}
    models = [TRLSD("MlpPolicy", gym.make(MAZE_ID), policy_kwargs=layers, seed=seed) for seed in (0, 1)]
    assert layers == {"net_arch": [8]}
    assert all(model.policy_kwargs["net_arch"] == [8] for model in models)


def test_bad_policy_and_spaces_are_refused():
    """An unknown policy, a continuous action space or an observation without a state Box is refused."""
    for policy in ("CnnPolicy", 3, dict):
        with pytest.raises(ValueError, match="policy must be one of"):
            TRLSD(policy, gym.make(MAZE_ID))
    with pytest.raises(ValueError, match="action_space must be Discrete"):
        TRLSD("LinearPolicy", "Pendulum-v1")
    with pytest.raises(ValueError, match="observation_space"):
        TRLSD("LinearPolicy", "FrozenLake-v1")


def test_transitions_that_do_not_match_the_env_are_refused(source_transitions):
    """Wrong state dimension, task index, or NaN rewards are refused with a clear error."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), seed=0)
    fields = {name: getattr(source_transitions, name) for name in Transitions.__dataclass_fields__}
    with pytest.raises(ValueError, match="dimension"):
        model.load_transitions(
            Transitions(
                **{
                    **fields,
                    "states": np.ones((len(source_transitions), 3)),
                    "next_states": np.ones((len(source_transitions), 3)),
                }
            )
        )
    with pytest.raises(ValueError, match="tasks"):
        model.load_transitions(Transitions(**{**fields, "tasks": np.full(len(source_transitions), 30)}))
    with pytest.raises(ValueError, match="rewards"):
        Transitions(**{**fields, "rewards": np.full(len(source_transitions), np.nan)})


def test_known_head_needs_no_env_method_when_given_a_reward_function(source_transitions):
    """reward_fn replaces the env's expected_reward for the 'known' head."""
    calls = []

    def reward_fn(states, task):
        calls.append(task)
        return np.zeros(len(states))

    model = make_model(source_transitions, reward_head="known", reward_fn=reward_fn)
    model.update_policy(0)
    assert calls and set(calls) == {0}


def test_several_envs_feed_one_buffer_and_one_learner_per_task(source_transitions, tmp_path):
    """n_envs=2: each env's step is a row of the one shared buffer and a sample of its task's head; the model
    saves, loads and goes on learning from where it was."""
    envs = make_vec_env(MAZE_ID, n_envs=2, env_kwargs={"task": 6}, seed=0)
    model = TRLSD("LinearPolicy", envs, seed=0)
    model.load_transitions(source_transitions, keep_rewards=False)
    model.learn(total_timesteps=200)
    n_source = len(source_transitions)
    assert model.num_timesteps == 200 and model.replay_buffer.size() == n_source + 200
    assert model.task_learner(6).head.n_samples == 200 and model.policy_updates[6] >= 2
    model.save(tmp_path / "two_envs")
    loaded = TRLSD.load(tmp_path / "two_envs", env=envs)
    assert loaded.replay_buffer.size() == n_source + 200
    loaded.learn(total_timesteps=100, reset_num_timesteps=False)
    assert loaded.num_timesteps == 300 and loaded.task_learner(6).head.n_samples == 300
    assert loaded.replay_buffer.size() == n_source + 300


def test_predict_and_act_refuse_a_state_that_is_not_finite():
    """A NaN state has no greedy action: predict used to return action 0 for it."""
    env = gym.make(MAZE_ID, task=(3, 3))
    model = TRLSD("LinearPolicy", env)
    obs, _ = env.reset(seed=0)
    bad = {"state": np.array([np.nan, 1.0], dtype=np.float32), "task": obs["task"]}
    for call in (model.predict, model.act):
        with pytest.raises(ValueError, match=r"states must be finite: 1 of 1 state\(s\) have nan"):
            call(bad)


def test_states_outside_the_box_are_warned_of_once():
    """Features and similarities are taken relative to the box: a state far outside it is warned of, once,
    whether it reaches the model through predict or through learn."""
    env = gym.make(MAZE_ID, task=(3, 3))
    model = TRLSD("LinearPolicy", env)
    obs, _ = env.reset(seed=0)
    outside = {"state": np.array([7.0, 1.0], dtype=np.float32), "task": obs["task"]}
    with pytest.warns(StateOutsideBoxWarning, match=r"dimension 0: 7 \(box \[0, 5\]\)"):
        model.predict(outside)
    with warnings.catch_warnings():
        warnings.simplefilter("error", StateOutsideBoxWarning)
        model.predict(outside)
    shifted = gym.wrappers.TransformObservation(
        gym.make(MAZE_ID, task=(3, 3)), lambda o: {**o, "state": o["state"] + 10}, env.observation_space
    )
    with pytest.warns(StateOutsideBoxWarning) as caught:
        TRLSD("LinearPolicy", shifted).learn(20)
    assert sum(issubclass(w.category, StateOutsideBoxWarning) for w in caught) == 1


def test_actions_and_tasks_not_numbered_from_0_are_refused_when_the_model_is_made():
    env = gym.make(MAZE_ID, task=(3, 3))
    shifted = gym.wrappers.TransformAction(env, lambda a: a - 1, spaces.Discrete(4, start=1))
    with pytest.raises(ValueError, match=r"number its actions from 0, got Discrete\(4, start=1\)"):
        TRLSD("LinearPolicy", shifted)


def test_a_model_without_an_env_is_refused_unless_load_makes_it(tmp_path):
    """env=None failed with an AttributeError deep in SB3; load's own env=None, unbuilt, must still work."""
    with pytest.raises(ValueError, match="env must be an env"):
        TRLSD("LinearPolicy", None)
    assert TRLSD("LinearPolicy", None, _init_setup_model=False).config.reward_head == "thompson"


def test_loading_more_transitions_than_the_buffer_holds_is_refused_naming_the_sizes(source_transitions):
    """The ring kept the last rows of the source set and dropped the others, silently."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), buffer_size=4_000, seed=0)
    model.load_transitions(source_transitions)
    with pytest.raises(ValueError, match=r"next to its 3000 rows: buffer_size=4000 .* buffer_size >= 6000"):
        model.load_transitions(source_transitions)
    assert model.replay_buffer.size() == len(source_transitions)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("train_freq", [10**12, (10**12, "episode")], ids=["steps", "episodes"])
def test_a_train_freq_beyond_total_timesteps_is_refused_before_learn_runs_past_it(train_freq):
    """SB3 collects a whole train_freq before it looks at total_timesteps: learn(10) ran 10**12 steps."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), train_freq=train_freq, seed=0)
    with pytest.raises(ValueError, match=r"train_freq=1000000000000 (step|episode)s .* train_freq <= 10"):
        model.learn(total_timesteps=10)
    assert model.num_timesteps == 0


class TaskOutside(gym.Wrapper):
    """The maze (its 'task' Discrete(25)) whose observations, from step ``at`` on, name task 30."""

    def __init__(self, at):
        super().__init__(gym.make(MAZE_ID, tasks=[(1, 1), (5, 5)]))
        self.at, self.steps = at, 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        return ({**obs, "task": 30} if self.steps >= self.at else obs), reward, terminated, truncated, info


def test_an_env_emitting_a_task_outside_its_discrete_is_named_by_learn():
    """Acting on it failed with an IndexError inside the policy's parameters (its Q of task 30)."""
    model = TRLSD("LinearPolicy", TaskOutside(at=3), seed=0)
    with pytest.raises(ValueError, match=r"tasks must be in 0\.\.24 .* got \[30\]"):
        model.learn(total_timesteps=20)
    assert max(model.task_learners, default=0) < 25


def test_predict_of_an_array_on_a_dict_env_asks_for_the_dict():
    """A plain state on a {"state", "task"} env failed in SB3 with an IndexError about indices."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks=[(1, 1), (5, 5)]), seed=0)
    with pytest.raises(ValueError, match=r"pass \{'state': states, 'task': tasks\}"):
        model.predict(np.array([1.0, 1.0], dtype=np.float32))
    with pytest.raises(ValueError, match="dict"):
        model.act(np.array([1.0, 1.0], dtype=np.float32))


@pytest.mark.parametrize(
    ("policy", "kappa", "message"),
    [
        ("LinearPolicy", 1e30, "the Q-function Fitted-Q gave task 0 .* is not finite"),
        ("LinearPolicy", 1e40, "beyond float32's range"),
        ("MlpPolicy", 1e40, "beyond float32's range"),
        ("LinearPolicy", 1e308, "the relabelled rewards of task 0 are not finite"),
    ],
    ids=[
        "linear-q-overflows",
        "linear-returns-beyond-float32",
        "mlp-returns-beyond-float32",
        "rewards-overflow",
    ],
)
def test_optimism_that_overflows_q_is_refused_naming_kappa(source_transitions, policy, kappa, message):
    """
    kappa = 1e40 gave a NaN Q, on which predict took action 0 at every state, silently (the MLP failed in
    torch's clamp): the refit raises, naming kappa.
    """
    model = TRLSD(policy, gym.make(MAZE_ID), reward_head="ridge", kappa=kappa, seed=0)
    model.load_transitions(source_transitions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the overflows' own on the way
        with pytest.raises(ValueError, match=f"{message}.*lower kappa"):
            model.learn(total_timesteps=5)
