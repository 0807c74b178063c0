"""
Runs in lockstep against the same runs alone: the batched Fitted-Q fit, the mazes stepped together, and the
multi-task batch (the actions and refits of the engine's callers: ``test_engine.py``).
"""

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD
from sb3_trlsd.fqi import LinearFQISolver, fit_linear_fqi_runs
from sb3_trlsd_envs import CELL_NOISE_STDS, FOUR_ROOMS_ID, MAZE_ID
from sb3_trlsd_envs.maze import step_mazes
from sb3_trlsd_lab.execution.batches import batch_runs, multitask_batch, source_seed
from sb3_trlsd_lab.execution.env_batches import GymEnvBatch, MazeBatch, env_batch
from sb3_trlsd_lab.execution.lockstep import Lockstep
from sb3_trlsd_lab.execution.runner import Method, multitask_run
from sb3_trlsd_lab.paper.reporting import mean_and_standard_error, window_means

K, N_ACTIONS, GAMMA = 6, 3, 0.8


def random_rows(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    phi = rng.uniform(0, 1, (n, K))
    return phi, rng.integers(N_ACTIONS, size=n), rng.uniform(0, 1, (n, K)), rng.random(n) < 0.1


def test_runs_fitted_together_get_their_fits_alone():
    """Shared rows + each run's own rows, fitted in one call = each run's rows fitted by a solver alone."""
    rng = np.random.default_rng(0)
    shared_rows = random_rows(rng, 300)
    shared = LinearFQISolver(K, N_ACTIONS)
    shared.extend(*shared_rows)
    own_rows = [random_rows(rng, n) for n in (0, 40, 25)]
    own = []
    for rows in own_rows:
        solver = LinearFQISolver(K, N_ACTIONS)
        solver.extend(*rows)
        own.append(solver)
    rewards = [rng.normal(size=300 + len(rows[0])) for rows in own_rows]
    theta0 = [None, rng.normal(size=(N_ACTIONS, K)), np.zeros((N_ACTIONS, K))]

    together = fit_linear_fqi_runs(shared, own, rewards, gamma=GAMMA, theta0=theta0, tol=1e-10)

    for rows, run_rewards, start, result in zip(own_rows, rewards, theta0, together, strict=True):
        alone = LinearFQISolver(K, N_ACTIONS)
        alone.extend(*shared_rows)
        if len(rows[0]):
            alone.extend(*rows)
        expected = alone.fit(run_rewards, gamma=GAMMA, theta0=start, tol=1e-10)
        np.testing.assert_allclose(result.theta, expected.theta, rtol=1e-8, atol=1e-10)
        assert abs(result.iterations - expected.iterations) <= 1
        assert result.bellman_residual == pytest.approx(expected.bellman_residual, rel=1e-6)
    # Each run stops by its own rule: the runs did not all take the same number of iterations.
    assert len({result.iterations for result in together}) > 1


def test_a_run_without_rows_keeps_its_start_and_bad_inputs_are_refused():
    own = LinearFQISolver(K, N_ACTIONS)
    start = np.ones((N_ACTIONS, K))
    (result,) = fit_linear_fqi_runs(None, [own], [np.zeros(0)], gamma=GAMMA, theta0=[start])
    np.testing.assert_array_equal(result.theta, start)
    assert result.iterations == 0
    with pytest.raises(ValueError, match="one per row"):
        fit_linear_fqi_runs(None, [own], [np.zeros(3)], gamma=GAMMA, theta0=[None])
    with pytest.raises(ValueError, match="needs rows"):
        fit_linear_fqi_runs(None, [None], [np.zeros(0)], gamma=GAMMA, theta0=[None])
    with pytest.raises(ValueError, match="share sizes"):
        fit_linear_fqi_runs(
            own, [LinearFQISolver(K + 1, N_ACTIONS)], [np.zeros(0)], gamma=GAMMA, theta0=[None]
        )


@pytest.mark.parametrize(
    "maze_kwargs", [{}, {"reward_noise_std": CELL_NOISE_STDS}], ids=["paper-maze", "noise-by-cell"]
)
def test_mazes_stepped_together_follow_their_trajectories_alone(maze_kwargs):
    """Each maze draws from its own generator what it draws alone, rebounds on walls and noise by cell too."""
    seeds, steps = [3, 4, 5, 6], 300
    alone = [gym.make(MAZE_ID, task=task, **maze_kwargs).unwrapped for task in (0, 7, 12, 24)]
    together = [gym.make(MAZE_ID, task=task, **maze_kwargs).unwrapped for task in (0, 7, 12, 24)]
    for maze, twin, seed in zip(alone, together, seeds, strict=True):
        maze.reset(seed=seed)
        twin.reset(seed=seed)
    actions = np.random.default_rng(0).integers(4, size=(steps, len(seeds)))
    for step_actions in actions:
        expected = [maze.step(int(action)) for maze, action in zip(alone, step_actions, strict=True)]
        moved = step_mazes(together, step_actions)
        np.testing.assert_array_equal(moved.states.astype(np.float32), [obs["state"] for obs, *_ in expected])
        np.testing.assert_array_equal(moved.rewards, [reward for _, reward, *_ in expected])
        np.testing.assert_array_equal(moved.truncated, [truncated for *_, truncated, _ in expected])
        for maze, twin, ended in zip(alone, together, moved.truncated, strict=True):
            if ended:
                maze.reset()
                twin.reset()
    with pytest.raises(ValueError, match="one dynamics"):
        step_mazes([alone[0], gym.make(MAZE_ID, walls=()).unwrapped], np.zeros(2, dtype=int))
    other_noise = {"reward_noise_std": 0.5 if maze_kwargs else CELL_NOISE_STDS}
    with pytest.raises(ValueError, match="one dynamics"):
        step_mazes([alone[0], gym.make(MAZE_ID, **other_noise).unwrapped], np.zeros(2, dtype=int))


def test_env_batch_moves_plain_mazes_together_and_any_other_env_one_by_one():
    assert isinstance(env_batch([gym.make(MAZE_ID), gym.make(MAZE_ID, max_episode_steps=5)]), MazeBatch)
    wrapped = gym.wrappers.TransformReward(gym.make(MAZE_ID), lambda reward: 2 * reward)
    assert type(env_batch([gym.make(MAZE_ID), wrapped])) is GymEnvBatch
    assert type(env_batch([gym.make(FOUR_ROOMS_ID)])) is GymEnvBatch


def test_a_multitask_batch_gives_each_run_its_run_alone():
    """Figure 8's setting: round-robin tasks, a time limit counted by the batch, no source."""
    method, seeds = Method("ridge"), (5, 6)
    batch = multitask_batch(method, seeds, n_turns=1, episode_steps=12)
    for seed, record in zip(seeds, batch, strict=True):
        alone = multitask_run(method, seed, n_turns=1, episode_steps=12)
        np.testing.assert_array_equal(record.rewards, alone.rewards)
        np.testing.assert_array_equal(record.tasks, alone.tasks)
        assert record.policy_updates == alone.policy_updates


def test_lockstep_fits_the_linear_q_only():
    env = gym.make(MAZE_ID)
    with pytest.raises(ValueError, match="LinearPolicy"):
        Lockstep(TRLSD("MlpPolicy", env), env_batch([env]), 1, None, 10)


def test_runs_split_into_source_sets_of_consecutive_runs():
    batches = batch_runs(500)
    assert len(batches) == 20 and all(len(batch) == 25 for batch in batches)
    assert [run for batch in batch_runs(107) for run in batch] == list(range(107))
    assert {len(batch) for batch in batch_runs(107)} == {5, 6}
    assert len(batch_runs(3)) == 3
    seeds = {source_seed(0, b) for b in range(20)}
    assert len(seeds) == 20 and seeds.isdisjoint(range(1000))


def test_the_standard_error_counts_each_source_set_once():
    """Runs of one source set share it: the standard error is that of the source sets' means."""
    values = np.array([1.0, 3.0, 2.0, 6.0, 4.0, 8.0])
    clusters = np.array([0, 0, 1, 1, 2, 2])
    mean, se = mean_and_standard_error(values, clusters)
    cluster_means = np.array([2.0, 4.0, 6.0])
    assert mean == pytest.approx(values.mean())
    assert se == pytest.approx(cluster_means.std(ddof=1) / np.sqrt(3))
    windows = window_means(np.tile(values[:, None], (1, 4)), [(0, 4)], clusters)["[0, 4)"]
    assert windows["se"] == pytest.approx(se)
    assert windows["se_runs"] == pytest.approx(values.std(ddof=1) / np.sqrt(6))
