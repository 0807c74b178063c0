"""Fitted-Q Iteration against value iteration on a small deterministic MDP."""

import numpy as np
import pytest
import torch as th

from sb3_trlsd.fqi import fit_linear_fqi, fit_mlp_fqi, make_q_network

N_STATES, N_ACTIONS, GAMMA = 6, 3, 0.9


@pytest.fixture(scope="module")
def mdp():
    """Deterministic transitions and rewards; every (s, a) present twice in the data, one-hot features."""
    rng = np.random.default_rng(0)
    next_state = rng.integers(N_STATES, size=(N_STATES, N_ACTIONS))
    reward = rng.normal(size=(N_STATES, N_ACTIONS))
    states, actions = np.meshgrid(np.arange(N_STATES), np.arange(N_ACTIONS), indexing="ij")
    states, actions = np.tile(states.ravel(), 2), np.tile(actions.ravel(), 2)
    q = np.zeros((N_STATES, N_ACTIONS))
    for _ in range(2000):  # value iteration to convergence
        q = reward + GAMMA * q.max(axis=1)[next_state]
    one_hot = np.eye(N_STATES)
    return {
        "phi": one_hot[states],
        "actions": actions,
        "rewards": reward[states, actions],
        "next_phi": one_hot[next_state[states, actions]],
        "q_star": q,
    }


def test_linear_fqi_reaches_value_iterations_q_star(mdp):
    """With one-hot features linear FQI is exact: its Q is value iteration's Q* within 1e-3."""
    result = fit_linear_fqi(
        mdp["phi"],
        mdp["actions"],
        mdp["rewards"],
        mdp["next_phi"],
        np.zeros(len(mdp["actions"]), bool),
        n_actions=N_ACTIONS,
        gamma=GAMMA,
        ridge=1e-9,
        tol=1e-10,
        max_iterations=1000,
    )
    np.testing.assert_allclose(result.theta.T, mdp["q_star"], atol=1e-3)
    assert result.bellman_residual < 1e-6


def test_warm_start_needs_fewer_iterations(mdp):
    """Starting from the previous solution (the algorithm refits often) converges faster."""
    args = (mdp["phi"], mdp["actions"], mdp["rewards"], mdp["next_phi"], np.zeros(len(mdp["actions"]), bool))
    cold = fit_linear_fqi(*args, n_actions=N_ACTIONS, gamma=GAMMA, ridge=1e-9)
    warm = fit_linear_fqi(*args, n_actions=N_ACTIONS, gamma=GAMMA, ridge=1e-9, theta0=cold.theta * 0.99)
    assert warm.iterations < cold.iterations


def test_terminations_stop_the_bootstrap_and_truncations_do_not():
    """A terminated transition is worth its reward only; a truncated one (terminated=False) bootstraps."""
    phi = np.eye(2)
    next_phi = np.eye(2)[[0, 0]]  # both transitions lead to state 0, which loops on itself with reward 1
    rewards = np.array([1.0, 0.0])
    for terminated, value in (
        (np.array([False, True]), 0.0),
        (np.array([False, False]), GAMMA / (1 - GAMMA)),
    ):
        result = fit_linear_fqi(
            phi,
            np.zeros(2, int),
            rewards,
            next_phi,
            terminated,
            n_actions=1,
            gamma=GAMMA,
            ridge=1e-9,
            tol=1e-12,
            max_iterations=2000,
        )
        assert result.theta[0, 1] == pytest.approx(value, abs=1e-4)


def test_scarce_data_cannot_make_linear_fqi_diverge():
    """Overlapping features and few samples: the clipped bootstrap keeps Q within the achievable returns."""
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 0.05, size=(5, 4))
    next_phi = rng.uniform(0, 1, size=(5, 4))
    rewards = rng.uniform(0, 1, size=5)
    result = fit_linear_fqi(
        phi, rng.integers(2, size=5), rewards, next_phi, np.zeros(5, bool), n_actions=2, gamma=GAMMA
    )
    assert np.isfinite(result.theta).all()
    assert np.abs(next_phi @ result.theta.T).max() < 1e6


def test_mlp_fqi_finds_the_greedy_actions_of_q_star(mdp):
    """The network version gets argmax Q* right on the small MDP."""
    th.manual_seed(0)
    network = make_q_network(N_STATES, N_ACTIONS, hidden=(32,))
    fit_mlp_fqi(
        mdp["phi"],
        mdp["actions"],
        mdp["rewards"],
        mdp["next_phi"],
        np.zeros(len(mdp["actions"]), bool),
        network=network,
        gamma=GAMMA,
        iterations=60,
        epochs_per_iteration=30,
        batch_size=36,
        learning_rate=1e-2,
        generator=th.Generator().manual_seed(0),
    )
    with th.no_grad():
        q = network(th.eye(N_STATES)).numpy()
    np.testing.assert_array_equal(q.argmax(axis=1), mdp["q_star"].argmax(axis=1))
