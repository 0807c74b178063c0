"""Transitions from SB3 replay buffers, their pickles and Minari datasets (``sb3_trlsd.foreign_data``), and
the task their rows belong to when their rewards are kept."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.env_util import make_vec_env

from sb3_trlsd import TRLSD, RelabellingReplayBuffer, Transitions, collect_transitions
from tests.conftest import MAZE_ID

UNLABELLED = "will be learnt as the rewards of this env's task"


class Drone(gym.Env):
    """
    A delivery drone: state (x, y, battery) in [0, 1]^3, 5 actions (hover, north, south, east, west) of 0.1;
    each step costs 0.1 to 0.3 of battery and the episode terminates when it is empty. Pays for being close
    to the pad at ``pad``.
    """

    observation_space = spaces.Box(0.0, 1.0, (3,), np.float32)
    action_space = spaces.Discrete(5)
    MOVES = np.array([[0, 0], [0, 0.1], [0, -0.1], [0.1, 0], [-0.1, 0]])

    def __init__(self, pad: tuple[float, float] = (0.8, 0.8)) -> None:
        self.pad = np.array(pad)
        self.state = np.zeros(3)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.state = np.array([*self.np_random.uniform(0, 1, 2), 1.0])
        return self.state.astype(np.float32), {}

    def step(self, action: int):
        position = np.clip(self.state[:2] + self.MOVES[int(action)], 0, 1)
        battery = max(0.0, self.state[2] - self.np_random.uniform(0.1, 0.3))
        self.state = np.array([*position, battery])
        reward = -float(np.linalg.norm(position - self.pad))
        return self.state.astype(np.float32), reward, battery == 0.0, False, {}


class Recorder(gym.Wrapper):
    """Every step as the env made it: s, a, r, s', terminated, truncated (before any reset)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.steps: list[tuple] = []
        self.obs: Any = None

    def reset(self, **kwargs):
        self.obs, info = self.env.reset(**kwargs)
        return self.obs, info

    def step(self, action):
        next_obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps.append((self.obs, int(action), reward, next_obs, terminated, truncated))
        self.obs = next_obs
        return next_obs, reward, terminated, truncated, info


def drone(max_steps: int = 5) -> Recorder:
    """The drone under a time limit short enough that some episodes end by it and others by the battery."""
    return Recorder(TimeLimit(Drone(), max_steps))


def recorded(recorder: Recorder, reward_dtype: type = np.float32) -> dict[str, np.ndarray]:
    """
    The recorded steps as Transitions' columns; the last is cut (the rows after it are not its). The rewards
    at the precision they were stored at (SB3's buffers: float32).
    """
    states, actions, rewards, next_states, terminated, truncated = zip(*recorder.steps, strict=True)
    states_of = (lambda obs: obs["state"]) if isinstance(states[0], dict) else (lambda obs: obs)
    truncations = np.array(truncated) & ~np.array(terminated)
    truncations[-1] |= not terminated[-1]
    return {
        "states": np.array([states_of(s) for s in states], dtype=np.float64),
        "actions": np.array(actions),
        "next_states": np.array([states_of(s) for s in next_states], dtype=np.float64),
        "rewards": np.array(rewards, dtype=reward_dtype).astype(np.float64),
        "truncations": truncations,
        "terminations": np.array(terminated),
    }


def assert_rows_equal(transitions: Transitions, expected: dict[str, np.ndarray]) -> None:
    for name, column in expected.items():
        np.testing.assert_array_equal(getattr(transitions, name), column, err_msg=name)


def filled_dqn(env: Any, n_steps: int, **kwargs: Any) -> DQN:
    """A DQN whose buffer SB3's own rollouts filled with ``n_steps`` steps (no gradient step: fast)."""
    settings = {
        "buffer_size": 1_000,
        "learning_starts": 10**6,
        "train_freq": 1,
        "seed": 0,
        "device": "cpu",
        **kwargs,
    }
    policy = "MultiInputPolicy" if isinstance(env.observation_space, spaces.Dict) else "MlpPolicy"
    return DQN(policy, env, **settings).learn(n_steps)


def drone_model(**kwargs: Any) -> TRLSD:
    return TRLSD("LinearPolicy", TimeLimit(Drone(pad=(0.2, 0.2)), 5), seed=0, **kwargs)


# ------------------------------------------------------------------------------------ SB3 buffers
@pytest.mark.parametrize("n_envs", [1, 2], ids=["one env", "two envs"])
def test_a_dqn_buffer_round_trips_with_time_limits_kept_as_truncations(n_envs):
    """Each env's steps come back as the env made them, oldest first: its float32 states, its (n, 1) actions,
    the time limits as truncations (bootstrapped through), the empty batteries as terminations; a reading
    that took SB3's ``dones`` for terminations would make every time limit an absorbing state."""
    vec_env = make_vec_env(drone, n_envs=n_envs, seed=0)
    dqn = filled_dqn(vec_env, 60)
    transitions = Transitions.from_replay_buffer(dqn.replay_buffer, task=0)
    recorders = [vec_env.envs[i].env for i in range(n_envs)]
    expected = [recorded(recorder) for recorder in recorders]
    assert len(transitions) == sum(len(columns["actions"]) for columns in expected) >= 60
    start = 0
    for columns in expected:
        part = transitions.take(np.arange(start, start + len(columns["actions"])))
        assert_rows_equal(part, columns)
        start += len(part)
    assert transitions.truncations.sum() > n_envs and transitions.terminations.any()
    model = drone_model()
    model.load_transitions(dqn.replay_buffer)
    stored = model.replay_buffer.transitions()
    np.testing.assert_array_equal(stored.truncations, transitions.truncations)
    np.testing.assert_array_equal(stored.terminations, transitions.terminations)


def test_a_wrapped_buffer_gives_its_rows_oldest_first():
    """Once the ring is full, the oldest row is at ``pos``: the last ``buffer_size`` steps, in order."""
    env = drone()
    dqn = filled_dqn(env, 70, buffer_size=50)
    columns = {name: column[-50:] for name, column in recorded(env).items()}
    assert_rows_equal(Transitions.from_replay_buffer(dqn.replay_buffer, task=0), columns)


def test_optimize_memory_usage_reads_the_next_state_from_the_next_row():
    """With ``optimize_memory_usage`` the next state is the next row's observation (the row at ``pos`` of a
    full ring is no transition), and the episode-ending rows, whose next observation SB3 overwrote with the
    next episode's first, are left out with a warning rather than given a wrong next state."""
    env = drone()
    kwargs = {"handle_timeout_termination": False}
    dqn = filled_dqn(env, 70, buffer_size=50, optimize_memory_usage=True, replay_buffer_kwargs=kwargs)
    columns = {name: column[-49:] for name, column in recorded(env).items()}
    ends = np.array([terminated or truncated for *_, terminated, truncated in env.steps])[-49:]
    with pytest.warns(UserWarning, match=f"its {int(ends.sum())} episode-ending rows are left out"):
        transitions = Transitions.from_replay_buffer(dqn.replay_buffer, task=0)
    assert_rows_equal(transitions, {name: column[~ends] for name, column in columns.items()})


def test_a_buffer_without_timeout_handling_reads_its_episode_ends_as_terminations():
    """``handle_timeout_termination=False`` keeps no time limits: said in a warning, not silently."""
    env = drone()
    dqn = filled_dqn(env, 40, replay_buffer_kwargs={"handle_timeout_termination": False})
    with pytest.warns(UserWarning, match="cannot tell time limits from terminations"):
        transitions = Transitions.from_replay_buffer(dqn.replay_buffer, task=0)
    ended = np.array([terminated or truncated for *_, terminated, truncated in env.steps])
    np.testing.assert_array_equal(transitions.terminations, ended)


def test_a_dict_buffer_keeps_each_rows_task_and_teaches_that_tasks_head():
    """A DQN on ``{"state", "task"}`` observations (a ``DictReplayBuffer``): each row's task is its
    observation's, so with ``keep_rewards=True`` they teach that task's head and no other."""
    env = Recorder(TimeLimit(gym.make(MAZE_ID, task=(3, 3)), 30))
    dqn = filled_dqn(env, 80)
    transitions = Transitions.from_replay_buffer(dqn.replay_buffer)
    assert_rows_equal(transitions, recorded(env))
    assert np.all(transitions.tasks == 12)
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 1)), seed=0)
    model.load_transitions(dqn.replay_buffer, keep_rewards=True)
    assert model.task_learner(12).head.n_samples == 80 and model.task_learner(0).head.n_samples == 0


def test_a_save_replay_buffer_pickle_loads_by_its_path(tmp_path):
    """``save_replay_buffer``'s file, named with or without its ``.pkl``, gives the buffer's rows."""
    env = drone()
    dqn = filled_dqn(env, 30)
    dqn.save_replay_buffer(tmp_path / "buffer")
    model = drone_model()
    model.load_transitions(tmp_path / "buffer.pkl")
    model.load_transitions(str(tmp_path / "buffer"))
    stored = model.replay_buffer.transitions()
    expected = recorded(env)
    for half in (stored.take(np.arange(30)), stored.take(np.arange(30, 60))):
        assert_rows_equal(half, {name: expected[name] for name in ("states", "actions", "terminations")})


def test_trlsds_own_buffers_load_and_only_observed_rewards_are_learnt(source_transitions):
    """A TRLSD model's buffer holds source rows whose rewards were discarded (stored as 0) and online rows:
    loaded with ``keep_rewards=True``, only the online rows teach the head, never the zeros. A DQN's
    ``RelabellingReplayBuffer`` loads too."""
    trained = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(3, 3)), seed=0)
    trained.load_transitions(source_transitions.take(np.arange(200)))
    trained.learn(40)
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 1)), seed=0)
    model.load_transitions(trained.replay_buffer, keep_rewards=True)
    assert model.replay_buffer.size() == 240
    assert model.task_learner(12).head.n_samples == 40
    relabelling = DQN(
        "MultiInputPolicy",
        gym.make(MAZE_ID, task=(3, 3)),
        buffer_size=500,
        learning_starts=10**6,
        replay_buffer_class=RelabellingReplayBuffer,
        device="cpu",
    ).learn(20)
    model.load_transitions(relabelling.replay_buffer)
    assert model.replay_buffer.size() == 260


# --------------------------------------------------------------------------------------- Minari
@pytest.fixture
def minari_home(tmp_path, monkeypatch):
    """A Minari datasets directory of the test's own: nothing is written to ~/.minari."""
    pytest.importorskip("minari", reason="the minari extra (in dev) installs it")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return tmp_path / "minari"


def make_dataset(env: gym.Env, dataset_id: str, n_steps: int):
    """A Minari dataset of ``n_steps`` random steps, collected with ``minari.DataCollector``."""
    import minari

    collector = minari.DataCollector(env)
    collector.reset(seed=0)
    collector.action_space.seed(0)
    for _ in range(n_steps):
        _, _, terminated, truncated, _ = collector.step(collector.action_space.sample())
        if terminated or truncated:
            collector.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Minari's advice on authors and permalinks
        return collector.create_dataset(dataset_id, algorithm_name="random", ref_min_score=0.0)


def test_a_minari_dataset_loads_with_its_episode_ends(minari_home):
    """A dataset made with ``minari.DataCollector``: n + 1 observations per n actions become n rows, its
    truncations stay truncations and its terminations terminations; by the dataset or by its local id."""
    import minari

    env = drone()
    dataset = make_dataset(env, "drone/random-v0", 60)
    transitions = Transitions.from_minari(dataset, task=0)
    assert_rows_equal(transitions, recorded(env, np.float64))
    assert transitions.truncations.any() and transitions.terminations.any()
    model = drone_model()
    model.load_transitions("drone/random-v0")
    model.load_transitions(minari.load_dataset("drone/random-v0"))
    assert model.replay_buffer.size() == 120
    assert list((minari_home / "drone").iterdir())


def test_a_minari_dataset_of_a_multi_task_env_keeps_the_observed_tasks(minari_home):
    """Dict observations with a state and a task: each row's task is its observation's."""
    env = Recorder(TimeLimit(gym.make(MAZE_ID, task=(2, 4)), 25))
    dataset = make_dataset(env, "maze/random-v0", 50)
    transitions = Transitions.from_minari(dataset)
    assert_rows_equal(transitions, recorded(env, np.float64))
    assert np.all(transitions.tasks == 8)


# ------------------------------------------------------------------------------------- task labels
@pytest.fixture(scope="module")
def box_buffer() -> ReplayBuffer:
    """A DQN's buffer of task A of the drone (its pad elsewhere than the target's)."""
    return filled_dqn(TimeLimit(Drone(pad=(0.8, 0.8)), 5), 40).replay_buffer


def test_box_rows_without_a_task_warn_before_their_rewards_are_learnt_as_this_tasks(box_buffer):
    """On a single-task env, rows of Box observations say nothing of their task: their rewards kept are
    learnt as this env's, which the user is told once; without rewards, or with task=0, nothing to say."""
    with pytest.warns(UserWarning, match=UNLABELLED) as caught:
        drone_model().load_transitions(box_buffer, keep_rewards=True)
    assert len(caught) == 1 and caught[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        drone_model().load_transitions(box_buffer)
        model = drone_model()
        model.load_transitions(box_buffer, keep_rewards=True, task=0)
    assert model.task_learner(0).head.n_samples == 40


def test_rows_of_another_task_keep_no_rewards_on_a_single_task_env(box_buffer, source_transitions):
    """``task=k`` other than the single-task env's 0 (or Transitions of other tasks) says that their rewards
    are another task's: kept, they would be learnt as this one's, so that is refused; their dynamics load."""
    with pytest.raises(ValueError, match=r"rewards of task\(s\) \[1\] as this env's"):
        drone_model().load_transitions(box_buffer, keep_rewards=True, task=1)
    model = drone_model()
    model.load_transitions(box_buffer, task=1)
    assert model.replay_buffer.size() == 40 and np.all(model.replay_buffer.transitions().tasks == 0)
    maze_rows = TRLSD("LinearPolicy", TimeLimit(Drone(), 5), seed=0)
    with pytest.raises(ValueError, match="state"):
        maze_rows.load_transitions(source_transitions)  # the maze's 2-D states, not the drone's 3


def test_a_multi_task_env_needs_the_task_of_rows_whose_rewards_it_learns(box_buffer):
    """Box rows on a multi-task env: without rewards they load; with them, task=k says whose head learns,
    and without task= they are refused (no head is theirs)."""
    maze_box = make_vec_env(
        lambda: gym.wrappers.TransformObservation(
            TimeLimit(gym.make(MAZE_ID, task=(1, 1)), 10),
            lambda obs: obs["state"],
            spaces.Box(0, 5, (2,), np.float32),
        ),
        n_envs=1,
    )
    buffer = filled_dqn(maze_box, 30).replay_buffer
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 1)), seed=0)
    with pytest.raises(ValueError, match="give task=k"):
        model.load_transitions(buffer, keep_rewards=True)
    model.load_transitions(buffer, keep_rewards=True, task=7)
    model.load_transitions(buffer)
    assert model.task_learner(7).head.n_samples == 30 and model.replay_buffer.size() == 60
    with pytest.raises(ValueError, match="task=k"):
        Transitions.from_replay_buffer(box_buffer)


def test_a_list_of_sources_loads_them_all_in_order(box_buffer, tmp_path):
    """Transitions, a buffer and an .npz, in one call."""
    env = TimeLimit(Drone(), 5)
    collected = collect_transitions(env, 25, seed=0)
    collected.save(tmp_path / "more.npz")
    model = drone_model()
    model.load_transitions([collected, box_buffer, tmp_path / "more.npz"])
    stored = model.replay_buffer.transitions()
    assert len(stored) == 90
    np.testing.assert_allclose(stored.states[:25], collected.states, rtol=1e-6)
    np.testing.assert_allclose(stored.states[65:], collected.states, rtol=1e-6)


def test_other_objects_are_refused_with_the_accepted_kinds(box_buffer):
    """A model, a number, a missing file, an empty list, a buffer of another env: each says what is wrong."""
    model = drone_model()
    dqn = DQN("MlpPolicy", TimeLimit(Drone(), 5), device="cpu")
    with pytest.raises(TypeError, match=r"an SB3 model: give its buffer, model.replay_buffer"):
        model.load_transitions(dqn)
    with pytest.raises(TypeError, match="SB3 ReplayBuffer or DictReplayBuffer"):
        model.load_transitions(3)
    with pytest.raises(ValueError, match="neither a file nor the id of a local Minari dataset"):
        model.load_transitions("no/such-dataset-v0")
    with pytest.raises(ValueError, match="empty list"):
        model.load_transitions([])
    with pytest.raises(ValueError, match="task must be None"):
        model.load_transitions(box_buffer, task=-1)
    cartpole = filled_dqn(gym.make("CartPole-v1"), 20).replay_buffer
    with pytest.raises(ValueError, match="collected with 2 actions, this model's env has 5"):
        model.load_transitions(cartpole)
    assert model.replay_buffer.size() == 0


def test_source_transitions_takes_a_buffer_pickle(tmp_path):
    """``TRLSD(source_transitions=<.pkl>)`` loads a DQN's saved buffer at the first learn."""
    dqn = filled_dqn(TimeLimit(Drone(), 5), 30)
    dqn.save_replay_buffer(tmp_path / "buffer.pkl")
    model = drone_model(source_transitions=str(tmp_path / "buffer.pkl"))
    model.learn(5)
    assert model.replay_buffer.size() == 35
