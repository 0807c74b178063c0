"""
The protocols of ``reproduce`` (``sb3_trlsd_lab.execution.protocols``): each preset's choices reach the envs,
reward heads, task learners and Fitted-Q fits of the runs a figure makes, batched and alone, on tiny sizes;
the JSON records the protocol, the run cache keeps protocols apart, and today's protocol is the default.
"""

import dataclasses
import inspect
import json

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD, RidgeRewardHead, TabularRewardHead
from sb3_trlsd.reward_heads import DEFAULT_W_FLOOR
from sb3_trlsd_envs import MAZE_ID, SharedDynamicsMaze
from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.execution import batches, runner
from sb3_trlsd_lab.execution.batches import multitask_batch, run_source_seed, source_seed, transfer_batch
from sb3_trlsd_lab.execution.env_batches import env_batch
from sb3_trlsd_lab.execution.lockstep import Lockstep
from sb3_trlsd_lab.execution.protocols import (
    AS_BUILT,
    AS_BUILT_NAME,
    DEFAULT_PROTOCOL,
    PRESETS,
    Protocol,
    protocol_named,
    protocol_record,
)
from sb3_trlsd_lab.execution.run_cache import run_key
from sb3_trlsd_lab.execution.runner import Method, multitask_env, run_online, transfer_run
from sb3_trlsd_lab.paper import multitask
from sb3_trlsd_lab.paper.figures import protocol_title
from sb3_trlsd_lab.registry import reproduce

CONTINUOUS, DISCRETE = Method("continuous"), Method("discrete", reward_head="tabular")
TASKS, SEEDS = (3, 12, 21), (40, 41, 42)
N_SOURCE, N_ONLINE = 300, 60


def preset(name: str) -> Protocol:
    return protocol_named(name)


def changed_fields(protocol: Protocol) -> dict:
    return {key: value for key, value in protocol.choices().items() if value != AS_BUILT.choices()[key]}


@pytest.fixture
def lockstep_batches(monkeypatch) -> list[Lockstep]:
    """Every ``Lockstep`` the figures' batches build, as they build it."""
    built = []

    class Recording(Lockstep):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            built.append(self)

    monkeypatch.setattr(batches, "Lockstep", Recording)
    return built


def spy(monkeypatch, owner, name: str, note) -> list:
    """
    ``owner.name`` still called, and what ``note(original, *args, **kwargs) -> (result, noted)`` notes of
    each call, in a list.
    """
    noted, original = [], getattr(owner, name)

    def called(*args, **kwargs):
        result, note_of_call = note(original, *args, **kwargs)
        noted.append(note_of_call)
        return result

    monkeypatch.setattr(owner, name, called)
    return noted


@pytest.fixture
def maze_resets(monkeypatch) -> list[dict]:
    """Every reset of a maze: its task and where the trajectory before it ended, and its start state."""

    def note(reset, maze, *, seed=None, options=None):
        ended = (maze.task, maze.state.copy()) if maze.trajectory else None
        obs, info = reset(maze, seed=seed, options=options)
        start = {
            "seeded": seed is not None,
            "ended": ended,
            "task": int(obs["task"]),
            "start": maze.state.copy(),
        }
        return (obs, info), start

    return spy(monkeypatch, SharedDynamicsMaze, "reset", note)


@pytest.fixture
def fits(monkeypatch) -> list[dict]:
    """The settings and relabelled rewards of every batched Fitted-Q call of a ``Lockstep``."""
    import sb3_trlsd.q_functions as q_functions_module

    def note(fit, shared, own, rewards, **settings):
        return fit(shared, own, rewards, **settings), {"rewards": [np.array(r) for r in rewards], **settings}

    return spy(monkeypatch, q_functions_module, "fit_linear_fqi_runs", note)


def outcome(records: list) -> list:
    """What a batch's runs did: their refits and rewards (at tiny sizes, rewards alone are often all 0)."""
    return [(record.policy_updates, record.rewards.tolist()) for record in records]


def tiny_transfer_batch(method: Method, protocol: Protocol, **kwargs) -> list:
    return transfer_batch(
        method, TASKS, SEEDS, source_seed(0, 0), N_SOURCE, N_ONLINE, source_set=0, protocol=protocol, **kwargs
    )


# ----------------------------------------------------------------------------------------- the registry
def test_every_preset_but_today_s_is_one_change_from_it_or_a_named_combination_of_them():
    """A preset that changed two choices (or none) would confound the study's one-change comparisons."""
    assert PRESETS[AS_BUILT_NAME].protocol == AS_BUILT == Protocol()
    assert PRESETS[DEFAULT_PROTOCOL].combines, "the default is the study's combination, not a single change"
    for name, entry in PRESETS.items():
        assert entry.name == name and entry.changes and entry.why
        if entry.combines:
            assert all(not PRESETS[part].combines for part in entry.combines)
            parts = [changed_fields(PRESETS[part].protocol) for part in entry.combines]
            assert all(len(changes) == 1 for changes in parts)
            assert changed_fields(entry.protocol) == {k: v for changes in parts for k, v in changes.items()}
        elif name != AS_BUILT_NAME:
            assert len(changed_fields(entry.protocol)) == 1, name
    assert len({entry.protocol for entry in PRESETS.values()}) == len(PRESETS)
    # Every choice has at least one alternative preset.
    changed = {field for entry in PRESETS.values() for field in changed_fields(entry.protocol)}
    assert changed == {field.name for field in dataclasses.fields(Protocol)} - {"w_floor"}


def test_a_combination_runs_each_figure_as_the_single_change_that_reaches_it():
    """'no-restarts' transfers as 'no-online-restarts' and multi-tasks as 'multitask-continue' (the README's
    study reads its columns from those runs)."""
    combination = preset("no-restarts")
    assert outcome(tiny_transfer_batch(CONTINUOUS, combination)) == outcome(
        tiny_transfer_batch(CONTINUOUS, preset("no-online-restarts"))
    )
    assert outcome(tiny_transfer_batch(CONTINUOUS, combination)) != outcome(
        tiny_transfer_batch(CONTINUOUS, AS_BUILT)
    )
    tiny = {"n_turns": 2, "episode_steps": 6}
    assert outcome(multitask_batch(CONTINUOUS, (3,), protocol=combination, **tiny)) == outcome(
        multitask_batch(CONTINUOUS, (3,), protocol=preset("multitask-continue"), **tiny)
    )


@pytest.mark.parametrize(
    ("name", "head", "multitask", "reaches"),
    [
        ("multitask-fixed-start", "ridge", False, False),
        ("multitask-fixed-start", "ridge", True, True),
        ("multitask-continue", "tabular", False, False),
        ("no-online-restarts", "ridge", True, False),
        ("no-online-restarts", "known", False, True),
        ("source-set-per-run", "ridge", True, False),
        ("source-set-per-run", "ridge", False, True),
        ("tabular-unvisited-r-max", "ridge", False, False),
        ("tabular-unvisited-r-max", "ridge", True, False),
        ("tabular-unvisited-r-max", "tabular", False, True),
        ("tabular-unvisited-r-max", "corners", False, True),
        ("r-max-clip", "known", False, False),
        ("r-max-clip", "ridge", True, True),
        ("log-count-plus-one", "known", False, False),
        ("gamma-0.95", "known", False, True),
        ("gamma-0.99", "ridge", True, True),
        ("first-fit-after-sample", "tabular", False, True),
    ],
)
def test_a_preset_reaches_a_run_only_through_what_the_run_is_built_from(name, head, multitask, reaches):
    reaching = preset(name).reaching(head, multitask)
    assert reaching == (preset(name) if reaches else AS_BUILT)
    assert reaching.run_inputs(head, multitask) == preset(name).run_inputs(head, multitask)


def test_a_combination_reaches_each_run_as_the_single_change_that_reaches_it():
    for head in ("ridge", "tabular", "known"):
        assert preset("no-restarts").reaching(head) == preset("no-online-restarts")
    assert preset("no-restarts").reaching("ridge", multitask=True) == preset("multitask-continue")


@pytest.mark.parametrize("name", [name for name in PRESETS if name != AS_BUILT_NAME])
def test_a_run_a_preset_does_not_reach_is_today_s_run(name):
    """What ``reaching`` drops must not change a run: the kept runs of today stand for the preset's."""
    multitask_runs = {"n_turns": 1, "episode_steps": 6}
    for method in (CONTINUOUS, DISCRETE, Method("kappa 0", kappa=0.0)):
        if preset(name).reaching(method.reward_head) == AS_BUILT:
            assert outcome(tiny_transfer_batch(method, preset(name))) == outcome(
                tiny_transfer_batch(method, AS_BUILT)
            )
        if preset(name).reaching(method.reward_head, multitask=True) == AS_BUILT:
            assert outcome(
                multitask_batch(method, (3, 4), protocol=preset(name), **multitask_runs)
            ) == outcome(multitask_batch(method, (3, 4), protocol=AS_BUILT, **multitask_runs))


def test_today_s_protocol_is_the_code_s_own_defaults():
    """If a default of TRLSD, the maze or a head moved, 'as-built' would no longer be what runs without it."""

    def default(function, name):
        return inspect.signature(function).parameters[name].default

    assert AS_BUILT.gamma == default(TRLSD.__init__, "gamma")
    assert AS_BUILT.first_fit == default(TRLSD.__init__, "first_fit")
    assert AS_BUILT.online_termination_prob == default(SharedDynamicsMaze.__init__, "termination_prob")
    assert AS_BUILT.multitask_start == default(SharedDynamicsMaze.__init__, "start")
    for head in (RidgeRewardHead, TabularRewardHead):
        assert AS_BUILT.w_floor == default(head.__init__, "w_floor") == DEFAULT_W_FLOOR
        assert AS_BUILT.r_max is default(head.__init__, "r_max") is None
    assert AS_BUILT.tabular_unvisited is default(TabularRewardHead.__init__, "unvisited_value") is None
    assert AS_BUILT.log_count == TabularRewardHead(lambda s: np.zeros(len(s), int), 1).log_count_rule
    for reward_head in ("ridge", "tabular", "corners", "known"):
        assert AS_BUILT.head_kwargs(reward_head) == {}


@pytest.mark.parametrize(
    ("choices", "field"),
    [
        ({"online_termination_prob": 1.5}, "online_termination_prob"),
        ({"gamma": 1.0}, "gamma"),
        ({"multitask_start": "centre"}, "start"),
        ({"multitask_start": (5.0, 2.0)}, "start"),
        ({"w_floor": 0.0}, "w_floor"),
        ({"r_max": float("nan")}, "r_max"),
        ({"log_count": "log2"}, "log_count"),
        ({"first_fit": "never"}, "first_fit"),
        ({"source_sets": "per_task"}, "source_sets"),
        ({"tabular_unvisited": float("inf")}, "tabular_unvisited"),
    ],
    ids=lambda value: value if isinstance(value, str) else next(iter(value)),
)
def test_a_bad_choice_is_refused_by_name(choices, field):
    with pytest.raises(ValueError, match=field):
        Protocol(**choices)


def test_an_unknown_protocol_name_is_refused_with_the_names():
    with pytest.raises(ValueError, match=r"protocol must be one of as-built, no-online-restarts, .*'paper'"):
        protocol_named("paper")
    with pytest.raises(ValueError, match="protocol must be one of"):
        reproduce("fig5", "unused", protocol="paper")


def test_the_command_lists_the_protocols_and_refuses_others(capsys):
    with pytest.raises(SystemExit):
        main(["reproduce", "--help"])
    help_text = " ".join(capsys.readouterr().out.split()).replace("- ", "-")  # names broken at a hyphen
    assert "--protocol NAME" in help_text and f"(default: {DEFAULT_PROTOCOL})" in help_text
    assert all(name in help_text for name in PRESETS)
    with pytest.raises(SystemExit) as error:
        main(["reproduce", "fig5", "--protocol", "paper"])
    assert error.value.code == 2
    assert "invalid choice: 'paper'" in capsys.readouterr().err


# ------------------------------------------------------------------- choices reach the batched runs
@pytest.mark.parametrize("name", list(PRESETS))
def test_each_preset_reaches_the_envs_models_and_heads_of_a_batch(name, lockstep_batches):
    """What ``transfer_batch`` builds carries the preset's choices (restarts, gamma, head settings)."""
    protocol = preset(name)
    method = DISCRETE if protocol.tabular_unvisited is not None else CONTINUOUS
    tiny_transfer_batch(method, protocol)
    assert lockstep_batches
    for lockstep in lockstep_batches:
        assert all(maze.termination_prob == protocol.online_termination_prob for maze in lockstep.envs.mazes)
        assert (
            lockstep.model.gamma == protocol.gamma and lockstep.model.config.first_fit == protocol.first_fit
        )
        head = lockstep.engine.learner(0, TASKS[0]).head
        assert head.r_max == protocol.r_max and head.w_floor == protocol.w_floor
        assert head.log_count_rule == protocol.log_count
        assert getattr(head, "unvisited_value", None) == protocol.tabular_unvisited
    assert len(lockstep_batches) == (len(TASKS) if protocol.source_sets == "per_run" else 1)


def test_no_restart_happens_online_without_restarts(maze_resets):
    """Under 'no-online-restarts' each run's maze is reset once, at its seeded start; under today's, ~2%."""
    for name, alone in (("as-built", False), ("no-online-restarts", False), ("no-online-restarts", True)):
        maze_resets.clear()
        if alone:
            for task, seed in zip(TASKS, SEEDS, strict=True):
                transfer_run(CONTINUOUS, task, seed, n_source=N_SOURCE, n_online=300, protocol=preset(name))
        else:
            transfer_batch(CONTINUOUS, TASKS, SEEDS, source_seed(0, 0), N_SOURCE, 300, protocol=preset(name))
        restarts = sum(not reset["seeded"] for reset in maze_resets)
        assert sum(reset["seeded"] for reset in maze_resets) == len(TASKS)
        if name == "as-built":
            assert restarts >= 5  # 900 transitions at 2%: 18 on average
        else:
            assert restarts == 0


def test_gamma_reaches_the_fitted_q_iterations(fits):
    """The batched fits run with the preset's discount, and its runs then act differently."""
    records = {}
    for name in ("as-built", "gamma-0.95", "gamma-0.99"):
        fits.clear()
        records[name] = tiny_transfer_batch(CONTINUOUS, preset(name))
        assert fits and {call["gamma"] for call in fits} == {preset(name).gamma}
    assert outcome(records["as-built"]) != outcome(records["gamma-0.99"])
    model = CONTINUOUS.make_model(gym.make(MAZE_ID), 0, preset("gamma-0.99"))
    assert model.gamma == 0.99


@pytest.mark.parametrize("batched", [True, False], ids=["batched", "alone"])
def test_multitask_trajectories_start_where_the_protocol_says(batched, maze_resets):
    """Uniform starts all differ; fixed ones are the centre; 'continue' resumes the task's last trajectory."""
    turns, steps = 2, 4
    for name in ("as-built", "multitask-fixed-start", "multitask-continue"):
        maze_resets.clear()
        if batched:
            multitask_batch(CONTINUOUS, (7,), n_turns=turns, episode_steps=steps, protocol=preset(name))
        else:
            runner.multitask_run(CONTINUOUS, 7, n_turns=turns, episode_steps=steps, protocol=preset(name))
        starts = np.array([reset["start"] for reset in maze_resets])
        assert len(starts) == turns * 25 + 1  # a reset after each trajectory, the last one's included
        ends, resumed = {}, 0
        for reset in maze_resets:
            if reset["ended"] is not None:  # the trajectory this reset ends
                ends[reset["ended"][0]] = reset["ended"][1]
            if not reset["seeded"] and reset["task"] in ends:
                resumed += bool(np.array_equal(reset["start"], ends[reset["task"]]))
        if name == "as-built":
            assert len(np.unique(starts, axis=0)) == len(starts) and resumed == 0
        elif name == "multitask-fixed-start":
            np.testing.assert_array_equal(starts, np.full_like(starts, 2.5))
        else:
            assert resumed == len(starts) - 25  # every trajectory of a task after its first
            assert len(np.unique(starts[:25], axis=0)) == 25


def test_a_continued_start_is_the_end_of_that_task_s_previous_trajectory():
    """The maze's own rule, two tasks in turn: each resumes its own trajectory, not the other's."""
    env = gym.make(MAZE_ID, tasks=[0, 1], task_schedule="round_robin", start="continue", termination_prob=0.0)
    env.action_space.seed(0)
    obs, _ = env.reset(seed=3)
    ends = {}
    for _ in range(6):
        task = obs["task"]
        for _ in range(3):
            obs, *_ = env.step(env.action_space.sample())
        ends[task] = env.unwrapped.state.copy()
        obs, _ = env.reset()
        if obs["task"] in ends:
            np.testing.assert_array_equal(env.unwrapped.state, ends[obs["task"]])
    with pytest.raises(ValueError, match="start='continue'"):
        env.unwrapped.random_transitions(10, seed=0)
    fixed = gym.make(MAZE_ID, start=(1.5, 4.5)).unwrapped.random_transitions(40, seed=0)
    trajectory_starts = fixed["states"][np.flatnonzero(np.r_[True, fixed["truncations"][:-1]])]
    np.testing.assert_array_equal(trajectory_starts, np.tile([1.5, 4.5], (len(trajectory_starts), 1)))


def test_r_max_caps_the_relabelled_rewards_where_the_floor_made_them_huge(fits):
    """Without samples nearby, R~ is the floored bonus (~83 at one sample) today, R_max = 1 when clipped."""
    for method in (CONTINUOUS, DISCRETE):
        for name in ("as-built", "r-max-clip"):
            fits.clear()
            tiny_transfer_batch(method, preset(name))
            first_fit_rewards = fits[0]["rewards"][0]
            if name == "r-max-clip":
                assert first_fit_rewards.max() <= 1.0
            else:
                assert first_fit_rewards.max() > 50
        model = method.make_model(gym.make(MAZE_ID, task=0), 0, preset("r-max-clip"))
        head = model.task_learner(0).head
        head.update(np.array([[0.5, 0.5]]), np.array([3.0]))  # a lucky draw: R^ + CI > 1 at it
        far_and_near = np.array([[4.5, 4.5], [0.5, 0.5]])
        np.testing.assert_array_equal(head.optimistic(far_and_near), [1.0, 1.0])
        floored = 0.1 * np.sqrt(np.log(2) / DEFAULT_W_FLOOR)  # kappa sqrt(log 2 / floor): ~83
        assert head.bonus(far_and_near)[0] == pytest.approx(floored)


def bonus_at(method: Method, protocol: Protocol, n_samples: int) -> float:
    """The bonus of a fresh head of ``method`` far from its ``n_samples`` samples."""
    head = method.make_model(gym.make(MAZE_ID, task=0), 0, protocol).task_learner(0).head
    head.update(np.full((n_samples, 2), 0.5), np.zeros(n_samples))
    return float(head.bonus(np.array([[4.5, 4.5]]))[0])


# (preset, samples, its bonus over today's at that count) where the rule differs from today's, and not
LOG_COUNT_CASES = [
    ("log-count-at-least-one", 1, 0.0),
    ("log-count-plus-one", 0, 0.0),
    ("log-count-plus-one", 2, np.sqrt(np.log(3) / np.log(2))),
]
SAME_LOG_COUNT = [("log-count-plus-one", 1, 1.0), ("log-count-at-least-one", 3, 1.0)]


def log_count_cases():
    for method in (DISCRETE, CONTINUOUS):
        for name, n_samples, ratio in LOG_COUNT_CASES + SAME_LOG_COUNT:
            yield pytest.param(method, name, n_samples, ratio, id=f"{method.label}-{name}-{n_samples}")


@pytest.mark.parametrize(("method", "name", "n_samples", "ratio"), log_count_cases())
def test_the_log_count_rule_changes_the_bonus_at_small_counts(method, name, n_samples, ratio):
    """log(max(n, 1)): no bonus at one sample; log(n + 1): none with no sample; elsewhere as today."""
    today = bonus_at(method, AS_BUILT, n_samples)
    assert bonus_at(method, preset(name), n_samples) == pytest.approx(ratio * today, rel=1e-9, abs=1e-12)


def test_a_task_whose_first_fit_saw_no_optimism_is_refitted_once_it_has_some():
    """Under log(n + 1) the first fit sees a CI of 0: the trigger must fire at the first sample, not never."""
    env = gym.make(MAZE_ID, task=6)
    model = DISCRETE.make_model(env, 1, preset("log-count-plus-one"))
    assert run_online(model, env, 40, seed=1).policy_updates >= 3


def first_refits(model: TRLSD, env: gym.Env) -> tuple[int, int]:
    """The task's refits after its first action, and after its first transition."""
    obs, _ = env.reset(seed=0)
    task = int(obs["task"])
    action = model.act(obs)
    after_act = model.policy_updates[task]
    next_obs, reward, terminated, truncated, _ = env.step(action)
    model.add_online_transition(obs, action, reward, next_obs, terminated, truncated)
    return after_act, model.policy_updates[task]


def test_the_first_fit_comes_after_the_first_sample_under_that_preset(recwarn):
    env = gym.make(MAZE_ID, task=9)
    assert first_refits(CONTINUOUS.make_model(env, 0, AS_BUILT), env)[0] == 1
    assert first_refits(CONTINUOUS.make_model(env, 0, preset("first-fit-after-sample")), env) == (0, 1)
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=9), first_fit="first_sample", seed=0)
    model.learn(5)  # SB3's loop: the first fit at the first training round, after the first step
    assert model.policy_updates[9] >= 1
    assert not [warning for warning in recwarn if "never been fitted" in str(warning.message)]


def test_a_batch_fits_a_task_after_its_first_sample_under_that_preset():
    envs = [gym.make(MAZE_ID, task=task) for task in TASKS]
    model = CONTINUOUS.make_model(envs[0], SEEDS[0], preset("first-fit-after-sample"))
    records = Lockstep(model, env_batch(envs), len(envs), None, 5).run(SEEDS)
    assert [record.refit_steps[0] for record in records] == [(1, task) for task in TASKS]


def test_one_source_set_per_run_gives_each_run_a_distinct_source_set(monkeypatch):
    def note(collect, env, n_transitions, seed=None, **kwargs):
        transitions = collect(env, n_transitions, seed=seed, **kwargs)
        return transitions, (seed, transitions)

    drawn = spy(monkeypatch, batches, "collect_transitions", note)
    shared = tiny_transfer_batch(CONTINUOUS, AS_BUILT)
    assert [seed for seed, _ in drawn] == [source_seed(0, 0)]
    assert {record.source_set for record in shared} == {0}
    drawn.clear()
    own = tiny_transfer_batch(CONTINUOUS, preset("source-set-per-run"))
    assert [seed for seed, _ in drawn] == [run_source_seed(seed) for seed in SEEDS]
    states = [transitions.states for _, transitions in drawn]
    assert all(not np.array_equal(a, b) for i, a in enumerate(states) for b in states[i + 1 :])
    assert all(record.source_set is None for record in own)  # standard errors over runs, not batches
    assert outcome(shared) != outcome(own)


def test_the_discrete_head_values_an_unvisited_cell_at_r_max_under_that_preset():
    visited, unvisited = np.array([[0.5, 0.5]]), np.array([[4.5, 4.5]])
    values = {}
    for name in ("as-built", "tabular-unvisited-r-max"):
        head = DISCRETE.make_model(gym.make(MAZE_ID, task=0), 0, preset(name)).task_learner(0).head
        head.update(np.repeat(visited, 3, axis=0), np.array([0.2, 0.4, 0.6]))
        values[name] = head.optimistic(np.concatenate([visited, unvisited]))
    today, r_max = values["as-built"], values["tabular-unvisited-r-max"]
    assert today[1] == pytest.approx(0.1 * np.sqrt(np.log(3) / DEFAULT_W_FLOOR))
    assert r_max[1] == 1.0
    assert r_max[0] == today[0] == pytest.approx(0.4 + 0.1 * np.sqrt(np.log(3) / 3))
    corners = Method("corners", reward_head="corners")
    head = (
        corners.make_model(gym.make(MAZE_ID, task=0), 0, preset("tabular-unvisited-r-max"))
        .task_learner(0)
        .head
    )
    assert head.optimistic(np.array([[4.5, 4.5], [2.5, 2.5]])).tolist() == [
        1.0,
        0.0,
    ]  # a corner, not a corner


def test_new_model_settings_are_saved_loaded_and_checked(tmp_path):
    env = gym.make(MAZE_ID, task=2)
    kwargs = {"log_count": "plus_1", "unvisited_value": 1.0}
    model = TRLSD(
        "LinearPolicy", env, reward_head="tabular", first_fit="first_sample", reward_head_kwargs=kwargs
    )
    model.learn(30)
    assert model.task_learner(2).first_fit == "first_sample"
    model.save(tmp_path / "model")
    loaded = TRLSD.load(tmp_path / "model", env=env)
    assert (
        loaded.config.first_fit == "first_sample" and loaded.hyperparameters()["first_fit"] == "first_sample"
    )
    assert loaded.task_learner(2).head.log_count_rule == "plus_1"
    assert loaded.task_learner(2).head.unvisited_value == 1.0
    assert loaded.task_learner(2).first_fit == "first_sample"
    with pytest.raises(ValueError, match="first_fit must be one of"):
        TRLSD("LinearPolicy", env, first_fit="first_reward")
    with pytest.raises(ValueError, match="log_count must be one of"):
        TRLSD("LinearPolicy", env, reward_head_kwargs={"log_count": "log2"}).task_learner(0)


@pytest.mark.parametrize(
    ("head", "floored"), [("ridge_posterior", False), ("thompson", False), ("bernstein", True)]
)
def test_a_method_s_head_kwargs_go_over_the_protocol_s_and_each_head_gets_what_applies(head, floored):
    """
    A ``Method``'s ``reward_head_kwargs`` reach its head over the protocol's choices; the protocol's
    ``w_floor`` reaches the heads with a floor and not the linear-posterior ones (which would refuse it).
    """
    protocol = Protocol(w_floor=1e-3, r_max=1.0)
    method = Method("beyond", reward_head=head, reward_head_kwargs={"r_max": 2.0})
    built = method.make_model(gym.make(MAZE_ID, task=1), seed=0, protocol=protocol).task_learner(1).head
    assert built.r_max == 2.0
    assert (getattr(built, "w_floor", None) == 1e-3) is floored
    assert method.parameters()["reward_head_kwargs"] == {"r_max": 2.0}


# ---------------------------------------------------------------------------- figures, JSON, cache
@pytest.fixture
def tiny_figures(monkeypatch):
    monkeypatch.setattr(runner, "SOURCE_TRANSITIONS", 300)
    monkeypatch.setattr(batches, "SOURCE_TRANSITIONS", 300)
    monkeypatch.setattr(multitask, "TURNS", 1)
    monkeypatch.setattr(multitask, "EPISODE_STEPS", 6)


def reproduce_figure(figure: str, out, *options: str, runs: int = 2) -> dict:
    command = ["reproduce", figure, "--runs", str(runs), "--workers", "1", "--seed", "1", "--out", str(out)]
    assert main([*command, *options]) == 0
    return json.loads((out / f"{figure}.json").read_text())


def without_timings(data: dict) -> dict:
    results = json.loads(json.dumps(data["results"]))
    for entry in results.values():
        entry.pop("seconds_per_run", None)
    return results


@pytest.mark.parametrize("figure", ["fig1", "fig8"])
def test_the_json_records_the_protocol_and_the_study_s_is_the_default(figure, tiny_figures, tmp_path, capsys):
    default = reproduce_figure(figure, tmp_path / "default", "--no-cache", runs=1)
    named = reproduce_figure(figure, tmp_path / "named", "--no-cache", "--protocol", "no-restarts", runs=1)
    assert DEFAULT_PROTOCOL == "no-restarts"
    assert default["parameters"]["protocol"] == named["parameters"]["protocol"]
    assert default["parameters"]["protocol"] == protocol_record(preset("no-restarts"))
    assert without_timings(default) == without_timings(named)
    today = reproduce_figure(figure, tmp_path / "today", "--no-cache", "--protocol", AS_BUILT_NAME, runs=1)
    assert today["parameters"]["protocol"] == protocol_record(AS_BUILT)
    other = "no-online-restarts" if figure == "fig1" else "multitask-fixed-start"
    changed = reproduce_figure(figure, tmp_path / "other", "--no-cache", "--protocol", other, runs=1)
    assert changed["parameters"]["protocol"]["name"] == other
    assert changed["parameters"]["protocol"]["choices"] == json.loads(json.dumps(preset(other).choices()))
    assert without_timings(changed) != without_timings(today)


@pytest.mark.parametrize("figure", ["fig2", "fig5", "fig7", "fig8"])
def test_a_figure_s_title_names_its_protocol(figure, tiny_figures, figure_titles, tmp_path, capsys):
    """
    A figure under one protocol must not pass for another's: its PNG's title names the protocol it ran, here
    one that is not the default (one run per method: the title, not the runs, is under test; the default's
    title is ``protocol_title``'s test).
    """
    reproduce_figure(figure, tmp_path, "--no-cache", "--protocol", "gamma-0.95", runs=1)
    assert figure_titles and all(
        " ".join(title.split()).endswith("(protocol: gamma-0.95)") for title in figure_titles
    ), figure_titles


def test_a_title_names_choices_no_preset_has_custom():
    assert protocol_title("Figure 5", AS_BUILT) == f"Figure 5 (protocol: {AS_BUILT_NAME})"
    custom = dataclasses.replace(AS_BUILT, gamma=0.5)
    assert protocol_title("Figure 5", custom) == "Figure 5 (protocol: custom)"


def test_runs_of_different_protocols_are_kept_apart(tiny_figures, tmp_path, capsys):
    """The same command under another protocol must run its own runs, not reuse today's."""
    cache = tmp_path / "runs"
    reproduce_figure("fig8", tmp_path, "--cache", str(cache))
    kept = set(cache.iterdir())
    fixed = reproduce_figure("fig8", tmp_path, "--cache", str(cache), "--protocol", "multitask-fixed-start")
    assert kept < set(cache.iterdir()) and len(set(cache.iterdir())) == 2 * len(kept)
    again = reproduce_figure("fig8", tmp_path, "--cache", str(cache), "--protocol", "multitask-fixed-start")
    assert len(set(cache.iterdir())) == 2 * len(kept) and without_timings(again) == without_timings(fixed)
    arguments = (CONTINUOUS, TASKS, SEEDS, 0, N_SOURCE, N_ONLINE)
    keys = {run_key(transfer_batch, arguments, {"protocol": entry.protocol}) for entry in PRESETS.values()}
    assert len(keys) == len(PRESETS)
    assert run_key(transfer_batch, arguments, {}) == run_key(
        transfer_batch, arguments, {"protocol": AS_BUILT}
    )


def test_a_figure_under_a_preset_reuses_today_s_runs_of_what_the_preset_does_not_reach(
    tiny_figures, tmp_path, capsys
):
    cache = tmp_path / "runs"
    today = {
        figure: reproduce_figure(figure, tmp_path, "--cache", str(cache), "--protocol", AS_BUILT_NAME, runs=1)
        for figure in ("fig5", "fig8")
    }
    kept = set(cache.iterdir())
    for figure, name in (
        ("fig8", "no-online-restarts"),
        ("fig8", "source-set-per-run"),
        ("fig5", "multitask-fixed-start"),
    ):
        under_preset = reproduce_figure(figure, tmp_path, "--cache", str(cache), "--protocol", name, runs=1)
        assert set(cache.iterdir()) == kept, (figure, name)
        assert under_preset["parameters"]["protocol"]["name"] == name
        assert without_timings(under_preset) == without_timings(today[figure])
    # Figure 5 under R_max for unvisited cells: only its two discrete methods' batches run again.
    reproduce_figure("fig5", tmp_path, "--cache", str(cache), "--protocol", "tabular-unvisited-r-max", runs=1)
    discrete = sum(method["reward_head"] == "tabular" for method in today["fig5"]["parameters"]["methods"])
    assert discrete == 2
    assert len(set(cache.iterdir()) - kept) == discrete  # 1 run: a batch of 1 run each


def test_the_multitask_env_of_a_protocol_is_today_s_maze_under_as_built():
    env = multitask_env(50).unwrapped
    assert env.start == "uniform" and env.termination_prob == 0.0
    assert multitask_env(50, preset("multitask-fixed-start")).unwrapped.start == (2.5, 2.5)
