"""TRLSD's learning state: one owner per task, nothing lost on save/load, validation before storing."""

import base64
import errno
import io
import json
import os
import pickle
import subprocess
import sys
import warnings
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_trlsd import TRLSD, TaskLearner
from sb3_trlsd.fqi import DEFAULT_TOL
from tests.conftest import MAZE_ID


def continued_model(tmp_path, save_and_load: bool, first=120, then=180, reward_timing="auto"):
    """A model learning ``first`` steps, saved and loaded (or not), then learning ``then`` steps more."""
    env = gym.make(MAZE_ID, task=(1, 5))
    model = TRLSD("LinearPolicy", env, source_transitions=2_000, seed=4, reward_timing=reward_timing)
    model.learn(total_timesteps=first)
    if save_and_load:
        env = model.get_env()  # the same env, its RNG and trajectory going on: an uninterrupted run's
        model.save(tmp_path / "model")
        model = TRLSD.load(tmp_path / "model", env=env, force_reset=False)
    model.learn(total_timesteps=then, reset_num_timesteps=False)
    return model


@pytest.mark.parametrize("reward_timing", ["auto", "step"])  # the maze's start state, and (s, a, s')
def test_learning_after_save_and_load_takes_the_actions_of_an_uninterrupted_run(tmp_path, reward_timing):
    """
    Everything a model needs to go on learning is in its zip: the source and online rows of the shared
    buffer, the reward heads with their samples, the trigger state and refit counts. With the env's RNG
    going on (the same env object), the loaded model takes exactly the actions, refits and rewards of a
    run that never stopped; an empty buffer after load would refit on 120 rows and act otherwise.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "empty buffer" warning
        resumed = continued_model(tmp_path, save_and_load=True, reward_timing=reward_timing)
    uninterrupted = continued_model(tmp_path, save_and_load=False, reward_timing=reward_timing)
    assert resumed.reward_timing == reward_timing.replace("auto", "start_state")
    ours, theirs = resumed.replay_buffer.transitions(), uninterrupted.replay_buffer.transitions()
    assert len(ours) == 2_000 + 300
    np.testing.assert_array_equal(ours.actions, theirs.actions)
    np.testing.assert_array_equal(ours.rewards, theirs.rewards)
    assert resumed.policy_updates == uninterrupted.policy_updates
    # The loaded model rebuilds its Gram matrices in one sum, not row batch by row batch: theta differs by
    # rounding in directions the data does not see, which Fitted-Q's default rule ("targets") leaves as they
    # are; on the data, each fit is within gamma / (1 - gamma) * fqi_tol of the return scale of the other's.
    states = uninterrupted.replay_buffer.transitions().states
    q_resumed, q_uninterrupted = (model.policy.q_values(states, 4) for model in (resumed, uninterrupted))
    scale = np.abs(q_uninterrupted).max()
    assert np.abs(q_resumed - q_uninterrupted).max() <= 2 * 0.9 / 0.1 * DEFAULT_TOL * scale


def test_a_loaded_model_has_int_task_keys_and_its_heads_samples(tmp_path):
    """After load, policy_updates[4] works (JSON would have made the keys strings) and R~ is the same."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 5)), source_transitions=500, seed=0)
    model.learn(total_timesteps=80)
    model.save(tmp_path / "model")
    loaded = TRLSD.load(tmp_path / "model")
    assert list(loaded.policy_updates) == [4] and loaded.policy_updates[4] == model.policy_updates[4]
    assert isinstance(loaded.task_learners[4], TaskLearner)
    states = np.random.default_rng(0).uniform(0, 5, size=(300, 2))
    np.testing.assert_array_equal(
        loaded.task_learner(4).head.optimistic(states), model.task_learner(4).head.optimistic(states)
    )
    assert loaded.replay_buffer.size() == 580


def test_the_zip_holds_no_env_and_no_closure(tmp_path):
    """The known head's reward_fn is the env's method: it is not saved, and load binds the new env's."""
    env = gym.make(MAZE_ID, tasks="all")
    model = TRLSD("LinearPolicy", env, reward_head="known", source_transitions=300, seed=0)
    model.learn(total_timesteps=5)
    model.save(tmp_path / "known")
    with zipfile.ZipFile(tmp_path / "known.zip") as archive:
        data = json.loads(archive.read("data"))
    pickled = base64.b64decode(data["task_learners"][":serialized:"])
    assert b"SharedDynamicsMaze" not in pickled and b"functools" not in pickled
    assert "reward_fn" not in data
    loaded = TRLSD.load(tmp_path / "known", env=gym.make(MAZE_ID, tasks="all"))
    states = np.array([[0.5, 0.5], [2.5, 2.5]])
    np.testing.assert_array_equal(loaded.task_learner(0).head.estimate(states), [1.0, 0.0])
    without_env = TRLSD.load(tmp_path / "known")
    with pytest.raises(ValueError, match="reward_fn"):
        without_env.task_learner(0).head.estimate(states)


def test_a_model_saved_without_its_rows_warns_at_learn_and_names_the_call(tmp_path):
    """If the buffer cannot come back (rows left out of the zip), learn says what restores it."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 5)), source_transitions=300, seed=0)
    model.learn(total_timesteps=10)
    model.save(tmp_path / "model")
    loaded = TRLSD.load(tmp_path / "model", env=gym.make(MAZE_ID, task=(1, 5)))
    loaded.replay_buffer.reset()
    with pytest.warns(UserWarning, match="load_replay_buffer"):
        loaded.learn(total_timesteps=2)


def online_step(
    model, reward=0.0, state=(1.0, 1.0), next_state=(1.5, 1.0), task=0, terminated=False, truncated=False
):
    obs = {"state": np.array(state, dtype=np.float32), "task": task}
    next_obs = {"state": np.array(next_state, dtype=np.float32), "task": task}
    model.add_online_transition(obs, 2, reward, next_obs, terminated, truncated)


@pytest.mark.parametrize(
    ("step", "message"),
    [
        ({"reward": np.nan}, "reward"),
        ({"reward": -np.inf}, "reward"),
        ({"state": (np.nan, 1.0)}, "state"),
        ({"next_state": (1.0, np.inf)}, "next state"),
        ({"task": 25}, "tasks"),
        ({"truncated": 0.5}, "truncated must be booleans"),
        ({"truncated": 2}, "truncated must be booleans"),
        ({"terminated": 2}, "terminated must be booleans"),
    ],
    ids=[
        "nan-reward",
        "inf-reward",
        "nan-state",
        "inf-next-state",
        "task-out-of-range",
        "half-truncation",
        "truncation-of-2",
        "termination-of-2",
    ],
)
def test_a_bad_online_transition_leaves_the_model_as_it_was_and_learning(source_transitions, step, message):
    """Rejected before anything is stored: buffer, head, step count and refits unchanged; then it learns."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks="all"), seed=0)
    model.load_transitions(source_transitions)
    for _ in range(3):
        online_step(model, reward=1.0)
    before = (
        model.replay_buffer.packed_rows(),
        model.num_timesteps,
        model.policy_updates,
        model.task_learner(0).head.n_samples,
    )
    with pytest.raises(ValueError, match=message):
        online_step(model, **step)
    after = (
        model.replay_buffer.packed_rows(),
        model.num_timesteps,
        model.policy_updates,
        model.task_learner(0).head.n_samples,
    )
    np.testing.assert_array_equal(after[0], before[0])
    assert after[1:] == before[1:]
    online_step(model, reward=1.0)
    model.update_policy(0)
    assert model.task_learner(0).head.n_samples == 4 and np.isfinite(model.policy.theta.numpy()).all()


class RewardOnce(gym.Wrapper):
    """Returns ``bad`` as the reward of step ``at``, the env's reward otherwise."""

    def __init__(self, env, at, bad):
        super().__init__(env)
        self.at, self.bad, self.steps = at, bad, 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        return obs, self.bad if self.steps == self.at else reward, terminated, truncated, info


def test_an_env_returning_nan_inside_learn_raises_and_the_model_goes_on(source_transitions):
    """A NaN reward from the env stops learn with a ValueError; nothing was stored; learning goes on."""
    env = RewardOnce(gym.make(MAZE_ID, task=(1, 1)), at=30, bad=np.nan)
    model = TRLSD("LinearPolicy", env, seed=0)
    model.load_transitions(source_transitions)
    with pytest.raises(ValueError, match="reward"):
        model.learn(total_timesteps=100)
    assert model.replay_buffer.size() == len(source_transitions) + 29
    assert model.task_learner(0).head.n_samples == 29
    model.learn(total_timesteps=50, reset_num_timesteps=False)
    assert model.task_learner(0).head.n_samples > 29 and np.isfinite(model.policy.theta.numpy()).all()


def test_the_policy_and_the_ridge_heads_share_one_feature_map():
    """One definition of Phi: TRLSD's rbf_per_dim reaches the policy and every ridge head alike."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks="all"), rbf_per_dim=7, seed=0)
    assert model.policy.features is model.features and model.features.n_features == 49
    assert model.task_learner(3).head.features is model.features
    assert model.policy.theta.shape == (25, 4, 49)


def test_predict_on_a_task_never_fitted_warns_once_per_task():
    """Action 0 everywhere is what an unfitted Q gives: say so, once per task, instead of silently."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks="all"), seed=0)
    obs = {"state": np.array([2.5, 2.5], dtype=np.float32), "task": 3}
    with pytest.warns(UserWarning, match="task 3 has never been fitted"):
        model.predict(obs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.predict(obs)
        model.update_policy(5)
        model.predict({**obs, "task": 5})
    with pytest.warns(UserWarning, match="task 4"):
        model.predict({"state": np.ones((2, 2), dtype=np.float32), "task": np.array([4, 5])})


def test_a_user_package_named_envs_does_not_break_the_mazes_registration(tmp_path):
    """The maze installs as sb3_trlsd_envs: a project's own envs package neither shadows nor is shadowed."""
    package = tmp_path / "envs"
    package.mkdir()
    (package / "__init__.py").write_text("USER_ENVS = True\n")
    code = (
        "import envs, sb3_trlsd, gymnasium as gym\n"
        "assert envs.USER_ENVS\n"
        "env = gym.make('TRLSD/SharedDynamicsMaze-v0', task=(2, 3))\n"
        "print(type(env.unwrapped).__module__)\n"
    )
    environment = {**os.environ, "PYTHONPATH": str(tmp_path)}
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env=environment,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "sb3_trlsd_envs.maze"


def fail_midway(monkeypatch, module, name, at_call):
    """
    Make ``module.name``, a writer taking ``(obj, file)``, write a few bytes and then fail as a full disk
    does at its ``at_call``-th call (1: the first), the calls before it going through.
    """
    writer, calls = getattr(module, name), []

    def failing(obj, file, *args, **kwargs):
        calls.append(name)
        if len(calls) < at_call:
            return writer(obj, file, *args, **kwargs)
        file.write(b"\x00" * 64)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(module, name, failing)


def small_learnt_model(steps=60):
    model = TRLSD(
        "LinearPolicy", gym.make(MAZE_ID, task=(1, 5)), source_transitions=300, buffer_size=2_000, seed=0
    )
    return model.learn(total_timesteps=steps)


def what_was_saved(model):
    """Everything a checkpoint must give back: the Q's parameters, the buffer's rows, the greedy actions."""
    states = np.random.default_rng(0).uniform(0, 5, size=(50, 2)).astype(np.float32)
    parameters = {name: value.clone() for name, value in model.policy.state_dict().items()}
    actions = model.predict({"state": states, "task": np.full(50, 4)}, deterministic=True)[0]
    return parameters, model.replay_buffer.packed_rows(), actions


def save_model(model, path):
    model.save(path)


def load_model(path, model):
    return TRLSD.load(path)  # a new model: nothing of ``model`` in it


def save_buffer(model, path):
    model.save_replay_buffer(path)


def load_buffer(path, model):
    model.load_replay_buffer(path)  # its rows replace those learnt since the save
    return model


@pytest.mark.parametrize(
    ("save", "load", "file_name", "writer"),
    [
        (save_model, load_model, "model.zip", (th, "save", 2)),
        (save_buffer, load_buffer, "buffer.pkl", (pickle, "dump", 1)),
    ],
    ids=["model-zip", "replay-buffer-pkl"],
)
def test_a_save_that_fails_midway_leaves_the_earlier_checkpoint_loadable_exactly(
    tmp_path, monkeypatch, save, load, file_name, writer
):
    """
    A save that fails as a full disk does (an OSError midway through the file) must not have destroyed the
    checkpoint it was to replace: written in place, the earlier zip or pickle is cut short and cannot be
    loaded (EOFError, KeyError). The earlier one loads exactly (parameters, buffer rows, greedy actions), and
    no partial file is left beside it.
    """
    model = small_learnt_model()
    path = tmp_path / file_name
    save(model, path)
    saved = what_was_saved(model)
    model.learn(total_timesteps=40, reset_num_timesteps=False)
    with monkeypatch.context() as patch:
        fail_midway(patch, *writer)
        with pytest.raises(OSError, match="No space left"):
            save(model, path)
    assert os.listdir(tmp_path) == [file_name]
    loaded = load(path, model)
    ours = what_was_saved(loaded)
    np.testing.assert_array_equal(ours[1], saved[1])
    if save is save_model:  # a buffer's file holds its rows only
        assert ours[0].keys() == saved[0].keys()
        assert all(th.equal(ours[0][name], saved[0][name]) for name in saved[0])
        np.testing.assert_array_equal(ours[2], saved[2])


def test_a_model_that_never_learnt_saves_and_loads(tmp_path):
    """An empty buffer has rows of no column: packing them must not fail, or no fresh model can be saved."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), seed=0)
    model.save(tmp_path / "fresh")
    assert TRLSD.load(tmp_path / "fresh").replay_buffer.size() == 0


@pytest.mark.parametrize(
    ("folder", "given"),
    [("runs", "runs/"), ("runs.v1", "runs.v1"), ("model.zip", "model")],
    ids=["path-with-a-slash", "folder-with-a-suffix", "folder-named-as-the-zip"],
)
def test_a_save_to_a_folder_is_refused_naming_it(tmp_path, folder, given):
    """SB3 would save beside it, to PATH_2, with a warning a script does not see: refuse it, naming it."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), seed=0)
    (tmp_path / folder).mkdir()
    path = str(tmp_path / given) + ("/" if given.endswith("/") else "")
    with pytest.raises(ValueError, match="is a folder"):
        model.save(path)
    with pytest.raises(ValueError, match="is a folder"):
        model.save_replay_buffer(str(tmp_path / folder) + "/")
    assert os.listdir(tmp_path) == [folder] and not os.listdir(tmp_path / folder)


def test_a_folder_beside_the_zip_is_no_obstacle(tmp_path):
    """As in SB3 (the RL Zoo keeps a folder of the env's name beside its zip): NAME gives NAME.zip."""
    (tmp_path / "model").mkdir()
    TRLSD("LinearPolicy", gym.make(MAZE_ID), seed=0).save(tmp_path / "model")
    assert sorted(os.listdir(tmp_path)) == ["model", "model.zip"]


def test_a_save_to_a_file_object_and_a_path_without_suffix_keep_sb3s_semantics(tmp_path):
    """A path without a suffix gets ``.zip``; a file object is written to as it is, and left open."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), source_transitions=50, seed=0)
    model.learn(total_timesteps=5)
    model.save(tmp_path / "sub" / "model")
    assert (tmp_path / "sub" / "model.zip").is_file()
    stream = io.BytesIO()
    model.save(stream)
    assert not stream.closed
    stream.seek(0)
    np.testing.assert_array_equal(
        TRLSD.load(stream).replay_buffer.packed_rows(), model.replay_buffer.packed_rows()
    )


def zip_without(source, target, entry):
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as out:
        for name in archive.namelist():
            if name != entry:
                out.writestr(name, archive.read(name))


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda path, out: zip_without(path, out, "policy.pth"), r"lacks \['policy.pth'\]"),
        (lambda path, out: zip_without(path, out, "pytorch_variables.pth"), "lacks"),
        (lambda path, out: out.write_bytes(path.read_bytes()[:1000]), "cut short"),
        (lambda path, out: out.write_bytes(b""), "cut short"),
    ],
    ids=["no-policy", "no-buffer-rows", "cut-short", "empty"],
)
def test_a_zip_that_is_not_a_whole_model_is_refused_naming_the_file(tmp_path, damage, message):
    """SB3 fails on these with a KeyError (policy.optimizer) or an AssertionError, or loses the rows."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID), source_transitions=50, seed=0)
    model.save(tmp_path / "model")
    damage(tmp_path / "model.zip", tmp_path / "damaged.zip")
    with pytest.raises(ValueError, match=message) as error:
        TRLSD.load(tmp_path / "damaged")
    assert "damaged.zip" in str(error.value)


class Counter(gym.Env):
    """
    State t, the steps since the reset; every step moves t on by one. ``fail_at``: the step call that raises
    (counted over the env's life) after the state has moved on, as a simulator failing midway does.
    """

    observation_space = gym.spaces.Box(0, 100, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, fail_at=None):
        self.fail_at, self.calls, self.t = fail_at, 0, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.calls += 1
        self.t += 1
        if self.calls == self.fail_at:
            raise RuntimeError("the simulator failed")
        return np.full(1, self.t, np.float32), 0.0, False, self.t >= 90, {}


@pytest.mark.parametrize(
    "envs",
    [[Counter(fail_at=7)], [Counter(), Counter(fail_at=7)]],
    ids=["env-moved-on-then-raised", "second-of-two-envs-raised"],
)
def test_learn_after_an_env_error_stores_no_transition_that_did_not_happen(envs):
    """
    An env raising inside step during learn leaves SB3's last observation behind the env (the failing env
    had moved on, the envs before it in the VecEnv had stepped): going on paired it with the next one, a
    row from t to t + 2. Every stored row is a step of one, or from a reset.
    """
    model = TRLSD(
        "LinearPolicy", DummyVecEnv([lambda env=env: env for env in envs]), learning_starts=0, seed=0
    )
    with pytest.raises(RuntimeError, match="the simulator failed"):
        model.learn(total_timesteps=40)
    model.learn(total_timesteps=10, reset_num_timesteps=False)
    rows = model.replay_buffer.transitions()
    np.testing.assert_array_equal(rows.next_states - rows.states, 1.0)
    assert len(rows) == 6 * len(envs) + 10  # six steps of each env before the error, ten after
