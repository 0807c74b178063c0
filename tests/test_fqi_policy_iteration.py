"""The policy-iteration solver of linear Fitted-Q: its fixed point, its kept cross moments, its fallbacks."""

import hashlib
import warnings

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD
from sb3_trlsd.config import TRLSDConfig
from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.fqi import LinearFQISolver, PolicyMoments, fit_linear_fqi, fit_linear_fqi_runs, return_bounds
from sb3_trlsd.fqi.policy_iteration import (
    MAX_UNKNOWNS,
    add_cross_moments,
    evaluation_system,
    greedy_codes,
    none_code,
    solve_policy_evaluation,
)
from tests.conftest import MAZE_ID

GAMMA = 0.9
PI = "policy_iteration"


def fit_kept(data, n_actions, ridge=1e-3, **settings):
    """A fit by policy iteration with its ``PolicyMoments`` kept by the caller, as TRLSD keeps them."""
    rows = LinearFQISolver(data[0].shape[1], n_actions, ridge=ridge)
    rows.extend(data[0], data[1], data[3], data[4])
    return rows.fit(data[2], solver=PI, policy_moments=PolicyMoments(), **settings)


def tabular_mdp(n_states=7, n_actions=3, seed=0, terminal=None):
    """Every (s, a) once, one-hot features: the projected fixed point is Q* itself (value iteration's)."""
    rng = np.random.default_rng(seed)
    next_state = rng.integers(n_states, size=(n_states, n_actions))
    reward = rng.normal(size=(n_states, n_actions))
    absorbing = np.zeros(n_states, bool) if terminal is None else np.isin(np.arange(n_states), terminal)
    q = np.zeros((n_states, n_actions))
    for _ in range(3000):
        q = reward + GAMMA * np.where(absorbing[next_state], 0.0, q.max(axis=1)[next_state])
    states, actions = (
        grid.ravel() for grid in np.meshgrid(np.arange(n_states), np.arange(n_actions), indexing="ij")
    )
    one_hot = np.eye(n_states)
    data = (
        one_hot[states],
        actions,
        reward[states, actions],
        one_hot[next_state[states, actions]],
        absorbing[next_state[states, actions]],
    )
    return data, q


@pytest.mark.parametrize("terminal", [None, [2]], ids=["no-absorbing", "absorbing-state"])
def test_policy_iteration_reaches_q_star_in_closed_form_on_a_tabular_mdp(terminal):
    """
    With one-hot features the projected Bellman equation is the Bellman equation: policy iteration's Q is
    Q* to rounding (the ridge 1e-12 aside), after a handful of exact evaluations, where the fitted
    iterations need hundreds at this tolerance. Absorbing next states bootstrap nothing in either.
    """
    data, q_star = tabular_mdp(terminal=terminal)
    result = fit_kept(data, 3, ridge=1e-12, gamma=GAMMA, tol=1e-12, max_iterations=2000)
    np.testing.assert_allclose(result.theta.T, q_star, atol=1e-9)
    assert result.converged and 1 <= result.policy_evaluations <= 6
    iterated = fit_linear_fqi(
        *data, n_actions=3, gamma=GAMMA, ridge=1e-12, tol=1e-12, max_iterations=2000, solver="iterations"
    )
    np.testing.assert_allclose(iterated.theta, result.theta, atol=1e-9)
    assert result.iterations * 10 < iterated.iterations and iterated.policy_evaluations == 0


def test_one_evaluation_solves_the_bellman_equation_of_its_policy():
    """
    ``solve_policy_evaluation`` with the cross moments of one fixed policy gives Q^pi of that policy on a
    tabular MDP: the linear system of eq. 4's fixed point, with the clip of the bootstrap never active.
    """
    data, _ = tabular_mdp()
    phi, actions, rewards, next_phi, _ = data
    n_states, n_actions, k = 7, 3, 7
    policy = np.random.default_rng(1).integers(n_actions, size=n_states)
    codes = policy[next_phi.argmax(axis=1)].astype(np.int8)
    moments = np.zeros((n_actions * k, n_actions * k + 2))
    order = np.argsort(actions, kind="stable")
    add_cross_moments(
        moments,
        phi[order].T,
        next_phi[order].T,
        actions[order],
        np.full(len(order), none_code(n_actions), np.int8),
        codes[order],
    )
    gram = np.stack([phi[actions == a].T @ phi[actions == a] + 1e-12 * np.eye(k) for a in range(n_actions)])
    reward_moments = np.stack([phi[actions == a].T @ rewards[actions == a] for a in range(n_actions)])
    has_rows = np.ones(n_actions, bool)
    system = evaluation_system(gram, has_rows)
    theta = solve_policy_evaluation(
        system, moments, reward_moments, GAMMA, -1e9, 1e9, has_rows, np.zeros((n_actions, k))
    )
    # Q^pi by solving (I - gamma P_pi) q = r over the (s, a) pairs.
    pairs = n_states * n_actions
    transition = np.zeros((pairs, pairs))
    for row in range(len(actions)):
        s, a, s_next = phi[row].argmax(), actions[row], next_phi[row].argmax()
        transition[s * n_actions + a, s_next * n_actions + policy[s_next]] = 1.0
    q_pi = np.linalg.solve(np.eye(pairs) - GAMMA * transition, rewards[np.lexsort((actions, phi.argmax(1)))])
    np.testing.assert_allclose(theta.T, q_pi.reshape(n_states, n_actions), atol=1e-8)


def test_greedy_codes_take_the_first_tied_action_the_clips_and_absorbing_rows():
    """A code says which term a bootstrap takes: argmax's first tie, a clip, or none past an absorbing s'."""
    next_q = np.array([[1.0, 3.0, -5.0, 2.0, 9.0], [1.0, 3.0, -6.0, 0.0, 9.0], [0.5, 3.0, -7.0, 2.0, 9.0]])
    terminated = np.array([False, False, False, False, True])
    codes = greedy_codes(next_q[None], terminated, np.array([[-4.0]]), np.array([[2.5]]))[0]
    np.testing.assert_array_equal(codes, [0, 4, 3, 0, none_code(3)])
    assert codes.dtype == np.int8


@pytest.fixture(scope="module")
def maze_data(source_transitions):
    """The maze's random transitions (3,000) on 5 x 5 RBFs of width 1, a reward bump near one corner."""
    rows = source_transitions
    grid = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=1.0)
    rewards = np.exp(-np.sum((rows.states - 0.5) ** 2, axis=1) / (2 * 0.5**2))
    return grid, (grid(rows.states), rows.actions, rewards, grid(rows.next_states), rows.terminations)


@pytest.mark.parametrize("stop_rule", ["theta", "targets"])
def test_policy_iteration_takes_the_greedy_policy_of_the_fitted_iterations_on_the_maze(maze_data, stop_rule):
    """
    On the maze's transitions, the two solvers reach the same fixed point: the same greedy action at 99% of
    a 30 x 30 grid of states (near-ties aside) and Q within 1e-4 of the return scale of the fitted
    iterations run to a tolerance of 1e-9 (at the default one, they stop up to gamma / (1 - gamma) times it
    short), policy iteration in at most half the passes over the rows that the default tolerance takes.
    """
    grid, data = maze_data
    fits = {
        PI: fit_kept(data, 4, gamma=GAMMA, stop_rule=stop_rule),
        "iterations": fit_linear_fqi(*data, n_actions=4, gamma=GAMMA, stop_rule=stop_rule),
    }
    exact = fit_linear_fqi(
        *data,
        n_actions=4,
        gamma=GAMMA,
        tol=1e-9,
        max_iterations=5000,
        stop_rule=stop_rule,
        solver="iterations",
    )
    axis = np.linspace(0.05, 4.95, 30)
    features = grid(np.stack(np.meshgrid(axis, axis), axis=-1).reshape(-1, 2))
    q, q_exact = features @ fits[PI].theta.T, features @ exact.theta.T
    low, high = return_bounds(data[2], GAMMA)
    assert np.mean(q.argmax(axis=1) == q_exact.argmax(axis=1)) >= 0.99
    assert np.abs(q - q_exact).max() <= 1e-4 * (high - low)
    assert all(fit.converged for fit in fits.values())
    assert 2 * fits[PI].iterations <= fits["iterations"].iterations
    assert fits[PI].policy_evaluations >= 1


def test_kept_moments_give_the_fit_of_fresh_ones(maze_data):
    """
    Refits with ``PolicyMoments`` kept from the previous fit (rows appended in between, rewards moved)
    update only the rows whose code changed: they give the theta of moments built afresh, to rounding.
    """
    _, (phi, actions, rewards, next_phi, terminated) = maze_data
    solver = LinearFQISolver(phi.shape[1], 4)
    kept, theta = PolicyMoments(), None
    rng = np.random.default_rng(2)
    for chunk in np.array_split(np.arange(len(actions)), 3):
        solver.extend(phi[chunk], actions[chunk], next_phi[chunk], terminated[chunk])
        moved = rewards[: solver.n_transitions] + 0.05 * rng.normal(size=solver.n_transitions)
        warm = solver.fit(moved, gamma=GAMMA, theta0=theta, policy_moments=kept, solver=PI)
        fresh = solver.fit(moved, gamma=GAMMA, theta0=theta, policy_moments=PolicyMoments(), solver=PI)
        np.testing.assert_allclose(warm.theta, fresh.theta, rtol=1e-7, atol=1e-9)
        assert warm.iterations == fresh.iterations and warm.converged
        theta = warm.theta
    # Other rows (a buffer started over) start the moments afresh.
    other = LinearFQISolver(phi.shape[1], 4)
    other.extend(phi[:100], actions[:100], next_phi[:100], terminated[:100])
    again = other.fit(rewards[:100], gamma=GAMMA, policy_moments=kept, solver=PI)
    alone = other.fit(rewards[:100], gamma=GAMMA, policy_moments=PolicyMoments(), solver=PI)
    np.testing.assert_allclose(again.theta, alone.theta, rtol=1e-7, atol=1e-9)


def test_each_run_of_a_batch_gets_its_fit_alone(maze_data):
    """Shared rows and own rows, several runs at once: each run's theta is the one it gets fitted alone."""
    _, (phi, actions, rewards, next_phi, terminated) = maze_data

    def rows_of(index):
        solver = LinearFQISolver(phi.shape[1], 4)
        solver.extend(phi[index], actions[index], next_phi[index], terminated[index])
        return solver

    shared, own = rows_of(slice(0, 2000)), [rows_of(slice(2000, 2500)), rows_of(slice(2000, 3000))]
    runs = [rewards[:2500], 3 * rewards[:3000]]
    moments = [PolicyMoments(), PolicyMoments()]
    together = fit_linear_fqi_runs(
        shared, own, runs, gamma=GAMMA, theta0=[None, None], solver=PI, policy_moments=moments
    )
    for n_rows, run_rewards, result in zip((2500, 3000), runs, together, strict=True):
        alone = rows_of(slice(0, n_rows)).fit(
            run_rewards, gamma=GAMMA, solver=PI, policy_moments=PolicyMoments()
        )
        scale = np.abs(alone.theta).max()
        np.testing.assert_allclose(result.theta, alone.theta, atol=1e-6 * scale)
        assert result.policy_evaluations >= 1 and result.converged


def test_a_system_too_large_takes_the_fitted_iterations():
    """Above ``MAX_UNKNOWNS`` unknowns no system is built: the fit is the fitted iterations', to the bit."""
    rng = np.random.default_rng(3)
    k, n_actions, n = MAX_UNKNOWNS // 2 + 1, 2, 300
    phi, next_phi = rng.normal(size=(n, k)) * 0.1, rng.normal(size=(n, k)) * 0.1
    data = (phi, rng.integers(n_actions, size=n), rng.normal(size=n), next_phi, np.zeros(n, bool))
    big = fit_kept(data, n_actions, gamma=0.5, max_iterations=20)
    iterated = fit_linear_fqi(*data, n_actions=n_actions, gamma=0.5, max_iterations=20, solver="iterations")
    np.testing.assert_array_equal(big.theta, iterated.theta)
    assert big.policy_evaluations == 0


@pytest.mark.filterwarnings("ignore::sb3_trlsd.fqi.FQICapWarning")
def test_an_unsolvable_system_falls_back_to_the_fitted_iterations():
    """
    Next features Phi(s') = Phi(s) / gamma along one feature make the evaluation's system singular there
    (G - gamma C has a null column, the ridge aside): the solver refuses it and runs the fitted iterations
    from the warm start instead, one pass to restart there, to the theta they give alone.
    """
    rng = np.random.default_rng(4)
    phi = np.stack([np.ones(30), rng.uniform(0.5, 1.0, size=30)], axis=1)
    data = (phi, np.zeros(30, int), np.ones(30), phi * [1 / GAMMA, 0.5], np.zeros(30, bool))
    settings = {"n_actions": 1, "gamma": GAMMA, "ridge": 1e-14, "max_iterations": 300}
    result = fit_kept(data, 1, ridge=1e-14, gamma=GAMMA, max_iterations=300)
    iterated = fit_linear_fqi(*data, **settings, solver="iterations")
    np.testing.assert_array_equal(result.theta, iterated.theta)
    assert result.policy_evaluations == 0 and result.iterations == iterated.iterations + 1


def test_the_iterations_option_gives_the_fits_it_gave_before_to_the_bit(source_transitions):
    """
    ``fqi_solver="iterations"`` is the solver TRLSD had: a short run on the maze gives the parameters it gave
    before the policy-iteration solver existed, to the bit (their digest), under both stopping rules.
    """
    digests = {}
    for stop in ("targets", "theta"):
        model = TRLSD(
            "LinearPolicy", gym.make(MAZE_ID, task=(1, 1)), seed=0, fqi_stop=stop, fqi_solver="iterations"
        )
        model.load_transitions(source_transitions, keep_rewards=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.learn(300)
        theta = model.policy.theta.cpu().numpy()
        digests[stop] = hashlib.sha256(theta.tobytes()).hexdigest()[:16]
    assert digests == {"targets": "9d6ee53cb932a0b0", "theta": "995eb3bf0db10ee6"}


def test_a_bad_solver_is_refused_by_name():
    with pytest.raises(ValueError, match="fqi_solver"):
        TRLSDConfig(fqi_solver="lstd")
    with pytest.raises(ValueError, match="solver"):
        fit_linear_fqi(*tabular_mdp()[0], n_actions=3, gamma=GAMMA, solver="lstd")


def test_fresh_moments_too_costly_to_build_leave_the_fit_to_the_fitted_iterations(maze_data):
    """
    Moments made for one fit alone (no ``PolicyMoments`` kept by the caller) would cost a build over every
    row, ~k passes: policy iteration leaves such a fit to the fitted iterations, which give their theta.
    """
    _, data = maze_data
    alone = fit_linear_fqi(*data, n_actions=4, gamma=GAMMA, solver=PI)
    iterated = fit_linear_fqi(*data, n_actions=4, gamma=GAMMA, solver="iterations")
    np.testing.assert_array_equal(alone.theta, iterated.theta)
    assert alone.policy_evaluations == 0 and alone.iterations == iterated.iterations
