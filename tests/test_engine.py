"""
One engine, three callers: SB3's ``learn``, ``act``/``add_online_transition`` from a loop of one's own, and a
batch of R runs stepped in lockstep take the same actions and refits on seeded runs.

What is compared, and why it is enough: the actions of every step and the step (and task) of every refit.
The refits of a run follow from its trigger, which reads its reward head, which reads the states its actions
led to; so equal actions and refit steps mean the run went through the same states, samples and refits.
The batched fit adds the shared and own rows' sums in another order than a fit of the run alone, so theta
agrees to rounding (~1e-7 relative, float32 rows), not bit for bit; an action is an argmax, which rounding
changes only where two Q-values tie within it, which these seeded cases do not meet.
"""

import gymnasium as gym
import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from sb3_trlsd import TRLSD, collect_transitions
from sb3_trlsd.engine import REFIT_BLAS_THREADS
from sb3_trlsd_envs import FOUR_ROOMS_ID, GOAL_CARTPOLE_ID, MAZE_ID
from sb3_trlsd_lab.execution.env_batches import env_batch
from sb3_trlsd_lab.execution.lockstep import Lockstep
from sb3_trlsd_lab.execution.runner import Method

Refits = list[tuple[int, int]]


def recording_refits(model: TRLSD) -> Refits:
    """The (step, task) of each refit of ``model`` from now on, as ``LockstepRecord`` counts steps: a first
    fit before the action of step t at t, a refit after the transition of step t at t + 1."""
    refits: Refits = []
    log_refit = model.engine.on_refit

    def record(run, learner, result, rewards):
        refits.append((model.num_timesteps, learner.task))
        if log_refit is not None:
            log_refit(run, learner, result, rewards)

    model.engine.on_refit = record
    return refits


def by_learn(model: TRLSD, n_steps: int) -> tuple[np.ndarray, Refits]:
    """SB3's rollout: the actions stored in the buffer, and the refits."""
    refits = recording_refits(model)
    n_before = model.replay_buffer.size()
    model.learn(n_steps)
    return model.replay_buffer.transitions().actions[n_before:], refits


def by_act(model: TRLSD, env: gym.Env, n_steps: int, seed: int) -> tuple[np.ndarray, Refits]:
    """A loop of one's own through ``act`` and ``add_online_transition``."""
    refits = recording_refits(model)
    actions = []
    obs, _ = env.reset(seed=seed)
    for _ in range(n_steps):
        action = model.act(obs)
        actions.append(action)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        model.add_online_transition(obs, action, float(reward), next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    return np.array(actions), refits


@pytest.mark.parametrize(
    "method",
    [
        Method("optimistic ridge"),
        Method("tabular", reward_head="tabular", update_ratio=1.2),
        Method("kappa 0", kappa=0.0),
        Method("features similarity", similarity="features"),
        Method("known", reward_head="known"),
        Method("no transfer", transfer=False),
        Method("ridge posterior", reward_head="ridge_posterior", kappa=0.3),
        Method("thompson", reward_head="thompson", kappa=0.3),  # each run draws from its own seed
        Method("bernstein", reward_head="bernstein", kappa=0.03, reward_head_kwargs={"reward_range": 0.5}),
    ],
    ids=lambda method: method.label,
)
def test_learn_act_and_a_batch_take_the_same_actions_and_refits(method):
    tasks, seeds, n_source, n_steps = (4, 20), (30, 32), 1_500, 200
    source = collect_transitions(gym.make(MAZE_ID, task=0), n_source, seed=99) if method.transfer else None
    envs = [gym.make(MAZE_ID, task=task) for task in tasks]
    lockstep = Lockstep(method.make_model(envs[0], seeds[0]), env_batch(envs), len(envs), source, n_steps)
    records = lockstep.run(seeds)

    for task, seed, record in zip(tasks, seeds, records, strict=True):
        followed = []
        for caller in ("learn", "act"):
            env = gym.make(MAZE_ID, task=task)
            model = method.make_model(env, seed)
            if source is not None:
                model.load_transitions(source, keep_rewards=False)
            followed.append(
                by_learn(model, n_steps) if caller == "learn" else by_act(model, env, n_steps, seed)
            )
        for actions, refits in followed:
            np.testing.assert_array_equal(record.actions, actions)
            assert record.refit_steps == refits and refits[0] == (0, task)
    if method.reward_head != "known":  # the known head refits when the buffer doubles: not within 200 steps
        assert all(len(record.refit_steps) > 5 for record in records)  # the triggers fired, and were compared


def test_a_batch_on_another_family_steps_its_envs_one_by_one_with_the_same_result():
    """
    The four rooms through a generic env batch, with the library's defaults (epsilon-greedy over each task's
    first steps, ties at random): the actions and refits of each run driven alone, by ``act`` and by
    ``learn``, exploratory steps included.
    """
    seeds, n_steps = (1, 2), 120
    envs = [gym.make(FOUR_ROOMS_ID, task=task) for task in (0, 3)]
    lockstep = Lockstep(TRLSD("LinearPolicy", envs[0], seed=seeds[0]), env_batch(envs), 2, None, n_steps)
    for env, seed, record in zip(envs, seeds, lockstep.run(seeds), strict=True):
        for caller in ("learn", "act"):
            alone_env = gym.make(FOUR_ROOMS_ID, task=env.unwrapped.task)
            model = TRLSD("LinearPolicy", alone_env, seed=seed)
            assert model.config.exploration.explores
            actions, refits = (
                by_learn(model, n_steps) if caller == "learn" else by_act(model, alone_env, n_steps, seed)
            )
            np.testing.assert_array_equal(record.actions, actions)
            assert record.refit_steps == refits


def test_refits_run_blas_on_one_thread_and_give_the_threads_back():
    """A refit's products are thin and its solves small: BLAS runs them on ``REFIT_BLAS_THREADS`` threads."""
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=3), source_transitions=500, seed=0)
    seen = []
    model.engine.on_refit = lambda *_: seen.append(
        [library["num_threads"] for library in threadpool_info() if library["user_api"] == "blas"]
    )
    with threadpool_limits(2, user_api="blas"):
        model.learn(total_timesteps=20)
        after = [library["num_threads"] for library in threadpool_info() if library["user_api"] == "blas"]
    assert seen and all(threads == [REFIT_BLAS_THREADS] * len(threads) for threads in seen)
    assert REFIT_BLAS_THREADS == 1 and all(threads == 2 for threads in after)


def box_cartpole(task: int) -> gym.Env:
    """The goal cart-pole as an env of one task with a state Box, its trajectories cut at 25 steps."""
    env = gym.make(GOAL_CARTPOLE_ID, task=task, max_episode_steps=25)
    state_space = env.observation_space["state"]
    return gym.wrappers.TransformObservation(env, lambda obs: obs["state"], state_space)


def test_sb3_s_rollout_and_add_online_transition_store_and_refit_the_same():
    """
    One step entry point: SB3's rollout (terminal observations, time limits as SB3 flags them) and a loop of
    one's own through ``add_online_transition`` hand the engine the same transitions, so they store the same
    rows, terminations apart from truncations, and take the same actions and refits, on an env of one task
    with a state Box whose trajectories end both ways.
    """
    seed, n_steps = 3, 150
    followed = []
    for caller in ("learn", "act"):
        env = box_cartpole(task=2)
        model = TRLSD("LinearPolicy", env, seed=seed, kappa=0.1, reward_head="ridge")
        actions, refits = by_learn(model, n_steps) if caller == "learn" else by_act(model, env, n_steps, seed)
        followed.append((actions, refits, model.replay_buffer.transitions()))
    (learn_actions, learn_refits, learnt), (act_actions, act_refits, acted) = followed
    np.testing.assert_array_equal(learn_actions, act_actions)
    assert learn_refits == act_refits and len(learn_refits) > 3
    for name in ("states", "actions", "next_states", "rewards", "truncations", "terminations"):
        np.testing.assert_array_equal(getattr(learnt, name), getattr(acted, name), err_msg=name)
    assert learnt.truncations.any() and learnt.terminations.any()
    assert not (learnt.truncations & learnt.terminations).any()
