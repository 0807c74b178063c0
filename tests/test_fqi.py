"""Fitted-Q Iteration against value iteration on a small deterministic MDP, and its solver's bookkeeping."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_trlsd import TRLSD
from sb3_trlsd.arrays import GrowableColumns
from sb3_trlsd.fqi import (
    FQICapWarning,
    LinearFQISolver,
    fit_linear_fqi,
    fit_linear_fqi_runs,
    fit_mlp_fqi,
    linear_q_values,
    make_q_network,
)
from tests.conftest import MAZE_ID

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
    for _ in range(2000):  # value iteration: the error after 2000 sweeps is ~0.9^2000, i.e. none
        q = reward + GAMMA * q.max(axis=1)[next_state]
    one_hot = np.eye(N_STATES)
    return {
        "phi": one_hot[states],
        "actions": actions,
        "rewards": reward[states, actions],
        "next_phi": one_hot[next_state[states, actions]],
        "terminated": np.zeros(len(actions), bool),
        "q_star": q,
    }


def data_of(mdp):
    return mdp["phi"], mdp["actions"], mdp["rewards"], mdp["next_phi"], mdp["terminated"]


def test_linear_fqi_reaches_value_iterations_q_star(mdp):
    """
    With one-hot features linear FQI is value iteration: its Q is Q* within 1e-3. The relative tolerance
    1e-10 bounds the distance to the fixed point by ~1e-10 * max|Q| / (1 - gamma) ~ 1e-8; the ridge 1e-9
    shrinks each entry by a factor 2 / (2 + 1e-9).
    """
    result = fit_linear_fqi(
        *data_of(mdp), n_actions=N_ACTIONS, gamma=GAMMA, ridge=1e-9, tol=1e-10, max_iterations=1000
    )
    np.testing.assert_allclose(result.theta.T, mdp["q_star"], atol=1e-3)
    np.testing.assert_allclose(linear_q_values(np.eye(N_STATES), result.theta), mdp["q_star"], atol=1e-3)
    assert result.bellman_residual < 1e-6
    assert result.iterations < 1000


def test_bellman_residual_is_the_rms_of_y_minus_x_theta():
    """The reported residual is sqrt(mean (r + gamma max Q(s') - Q(s, a))^2) at the returned theta."""
    rng = np.random.default_rng(4)
    phi, next_phi = rng.uniform(size=(40, 3)), rng.uniform(size=(40, 3))
    actions, rewards = rng.integers(2, size=40), rng.uniform(size=40)
    terminated = rng.random(40) < 0.3
    result = fit_linear_fqi(phi, actions, rewards, next_phi, terminated, n_actions=2, gamma=0.5)
    targets = rewards + 0.5 * ~terminated * linear_q_values(next_phi, result.theta).max(axis=1)
    fitted = linear_q_values(phi, result.theta)[np.arange(40), actions]
    assert result.bellman_residual == pytest.approx(np.sqrt(np.mean((targets - fitted) ** 2)), rel=1e-9)


def test_warm_start_needs_fewer_iterations(mdp):
    """Starting from the previous solution (the algorithm refits often) converges faster."""
    cold = fit_linear_fqi(*data_of(mdp), n_actions=N_ACTIONS, gamma=GAMMA, ridge=1e-9)
    warm = fit_linear_fqi(
        *data_of(mdp), n_actions=N_ACTIONS, gamma=GAMMA, ridge=1e-9, theta0=cold.theta * 0.99
    )
    assert warm.iterations < cold.iterations
    np.testing.assert_allclose(warm.theta, cold.theta, atol=1e-3)


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


def test_actions_without_samples_keep_their_warm_start(mdp):
    """No data on an action says nothing about its Q: its parameters stay those given in theta0."""
    taken = mdp["actions"] != 2
    theta0 = np.full((N_ACTIONS, N_STATES), 7.0)
    data = [array[taken] for array in data_of(mdp)]
    result = fit_linear_fqi(*data, n_actions=N_ACTIONS, gamma=GAMMA, theta0=theta0)
    np.testing.assert_array_equal(result.theta[2], 7.0)
    assert not np.allclose(result.theta[:2], 7.0)
    assert np.all(fit_linear_fqi(*data, n_actions=N_ACTIONS, gamma=GAMMA).theta[2] == 0)


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


def test_solver_grown_in_chunks_refits_other_rewards_like_a_fresh_fit():
    """
    The solver's running Gram sums over appended chunks, and its cached factorisation reused for new
    rewards, give the one-shot fit's theta (same arithmetic up to summation order: rtol 1e-9).
    """
    rng = np.random.default_rng(2)
    n, k = 600, 5
    phi, next_phi = rng.uniform(size=(n, k)), rng.uniform(size=(n, k))
    actions, terminated = rng.integers(3, size=n), rng.random(n) < 0.1
    solver = LinearFQISolver(k, 3, ridge=1e-3)
    for chunk in np.array_split(np.arange(n), 4):
        solver.extend(phi[chunk], actions[chunk], next_phi[chunk], terminated[chunk])
    assert solver.n_transitions == n
    for seed in (3, 4):  # two tasks' rewards on the same transitions
        rewards = np.random.default_rng(seed).uniform(-1, 1, size=n)
        fresh = fit_linear_fqi(phi, actions, rewards, next_phi, terminated, n_actions=3, gamma=GAMMA)
        refit = solver.fit(rewards, gamma=GAMMA)
        np.testing.assert_allclose(refit.theta, fresh.theta, rtol=1e-9, atol=1e-12)
        assert refit.iterations == fresh.iterations


def test_rows_in_any_order_fit_as_rows_sorted_by_action():
    """
    The iterations read each action's rows as one range: a solver whose rows came sorted by action (a
    batch's source) is read as it is, one whose rows came in any order (a run's own rows) is laid out action
    by action for the fit. Either way, the same transitions with their rewards and terminations give the
    same fit, alone and for several runs sharing the rows (same per-action sums: rtol 1e-9).
    """
    rng = np.random.default_rng(5)
    n, k, n_actions = 900, 6, 4
    phi, next_phi = rng.uniform(size=(n, k)), rng.uniform(size=(n, k))
    actions, terminated = rng.integers(n_actions, size=n), rng.random(n) < 0.1
    order = np.argsort(actions, kind="stable")
    arrival, by_action = LinearFQISolver(k, n_actions), LinearFQISolver(k, n_actions)
    arrival.extend(phi, actions, next_phi, terminated)
    by_action.extend(phi[order], actions[order], next_phi[order], terminated[order])
    assert all(isinstance(block.rows, slice) for block in by_action.action_blocks())
    assert not all(isinstance(block.rows, slice) for block in arrival.action_blocks())
    rewards = [np.random.default_rng(seed).uniform(-1, 1, size=n) for seed in (6, 7, 8)]
    alone = [arrival.fit(r, gamma=GAMMA) for r in rewards]
    together = fit_linear_fqi_runs(arrival, [None] * 3, rewards, gamma=GAMMA, theta0=[None] * 3)
    sorted_together = fit_linear_fqi_runs(
        by_action, [None] * 3, [r[order] for r in rewards], gamma=GAMMA, theta0=[None] * 3
    )
    for one, batched, sorted_fit in zip(alone, together, sorted_together, strict=True):
        np.testing.assert_allclose(batched.theta, one.theta, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(sorted_fit.theta, one.theta, rtol=1e-9, atol=1e-12)
        assert abs(sorted_fit.iterations - one.iterations) <= 1
        assert sorted_fit.bellman_residual == pytest.approx(one.bellman_residual, rel=1e-9)


def test_float32_storage_fits_the_float64_theta_within_its_rounding():
    """
    Storing the features in float32 changes theta by float32 rounding only (~1e-7 relative, amplified by the
    condition number of the Gram matrices: here checked at 1e-3 of theta's scale), subnormal features are
    flushed to zero, and a tol float32 cannot meet is raised.
    """
    rng = np.random.default_rng(5)
    n, k = 3000, 6
    phi, next_phi = rng.uniform(size=(n, k)), rng.uniform(size=(n, k))
    phi[:, 0] = 1e-40  # an RBF far from its centre: subnormal in float32
    actions, terminated = rng.integers(3, size=n), rng.random(n) < 0.1
    rewards = rng.uniform(-1, 1, size=n)
    fits = {}
    for dtype in (np.float64, np.float32):
        solver = LinearFQISolver(k, 3, ridge=1e-3, dtype=dtype)
        solver.extend(phi, actions, next_phi, terminated)
        fits[dtype] = solver.fit(rewards, gamma=GAMMA, tol=1e-12, max_iterations=300, solver="iterations")
        assert solver._phi_t[0].view().dtype == dtype
    assert np.all(solver._phi_t[0].view()[0] == 0)  # flushed, not subnormal
    scale = np.abs(fits[np.float64].theta).max()
    np.testing.assert_allclose(fits[np.float32].theta, fits[np.float64].theta, atol=1e-3 * scale)
    assert fits[np.float64].iterations > fits[np.float32].iterations  # tol 1e-12 raised to 64 eps in float32
    with pytest.raises(ValueError, match="dtype"):
        LinearFQISolver(k, 3, dtype=np.int32)


def test_growable_columns_keep_appended_columns_in_order():
    """Columns appended past the capacity (16, then doubled) come back in order, rows contiguous."""
    columns = GrowableColumns(3, np.float32)
    chunks = [np.arange(3 * m, dtype=float).reshape(3, m) + 100 * i for i, m in enumerate((5, 20, 1, 40))]
    for chunk in chunks:
        columns.append(chunk)
    np.testing.assert_array_equal(columns.view(), np.concatenate(chunks, axis=1).astype(np.float32))
    assert len(columns) == 66 and columns.view().strides[1] == 4
    flags = GrowableColumns(1, bool)
    flags.append(np.array([True, False, True]))
    np.testing.assert_array_equal(flags.view()[0], [True, False, True])


def test_an_empty_solver_returns_its_warm_start():
    """No transition yet: nothing to fit, theta0 comes back unchanged."""
    theta0 = np.ones((2, 3))
    result = LinearFQISolver(3, 2).fit(np.zeros(0), gamma=GAMMA, theta0=theta0)
    assert result.iterations == 0 and result.bellman_residual == 0
    np.testing.assert_array_equal(result.theta, theta0)


@pytest.mark.parametrize(
    ("call", "argument"),
    [
        (lambda s: s.extend(np.ones((2, 3)), np.array([0, 2]), np.ones((2, 3)), np.zeros(2)), "actions"),
        (lambda s: s.extend(np.ones((2, 4)), np.array([0, 1]), np.ones((2, 4)), np.zeros(2)), "phi"),
        (lambda s: s.fit(np.ones(3), gamma=GAMMA), "rewards"),
        (lambda s: s.fit(np.array([np.nan]), gamma=GAMMA), "rewards"),
        (lambda s: s.fit(np.ones(1), gamma=1.0), "gamma"),
        (lambda s: s.fit(np.ones(1), gamma=GAMMA, theta0=np.zeros((3, 3))), "theta0"),
    ],
    ids=[
        "action-out-of-range",
        "wrong-feature-width",
        "one-reward-too-many",
        "nan-reward",
        "gamma-1",
        "theta0",
    ],
)
def test_bad_fqi_inputs_are_refused_by_name(call, argument):
    """Mis-shaped or invalid inputs raise a ValueError naming the argument."""
    solver = LinearFQISolver(3, 2)
    solver.extend(np.ones((1, 3)), np.array([1]), np.ones((1, 3)), np.zeros(1, bool))
    with pytest.raises(ValueError, match=argument):
        call(solver)


def fit_small_network(mdp, seed, network=None, rewards=None, **settings):
    """``fit_mlp_fqi`` on the small MDP (one-hot inputs), from a network seeded by ``seed`` unless given."""
    if network is None:
        th.manual_seed(seed)
        network = make_q_network(N_STATES, N_ACTIONS, hidden=(32,))
    phi, actions, mdp_rewards, next_phi, terminated = data_of(mdp)
    settings = {
        "batch_size": 12,
        "learning_rate": 1e-2,
        "tol": 1e-8,
        "max_iterations": 2000,
        "ridge": 1e-5,
        **settings,
    }
    result = fit_mlp_fqi(
        phi,
        actions,
        mdp_rewards if rewards is None else rewards,
        next_phi,
        terminated,
        network=network,
        gamma=GAMMA,
        generator=th.Generator().manual_seed(seed),
        **settings,
    )
    return network, result


def q_of_states(network):
    with th.no_grad():
        return network(th.eye(N_STATES)).numpy().astype(np.float64)


@pytest.mark.parametrize("epochs", [0, 3], ids=["random-features", "trained-features"])
def test_mlp_fqi_finds_the_greedy_actions_of_q_star(mdp, epochs):
    """
    The network version gets argmax Q* right on the small MDP, features trained or not. Its output layer is
    linear FQI on 32 hidden features of 6 one-hot states, which span every Q over them: at the fixed point
    (tol 1e-8) Q is Q* up to the ridge's shrinkage, far within half the smallest gap between the best and
    second-best action (0.19 here), which is what makes the argmax exact.
    """
    sorted_q = np.sort(mdp["q_star"], axis=1)
    margin = np.min(sorted_q[:, -1] - sorted_q[:, -2])
    network, result = fit_small_network(mdp, seed=0, epochs=epochs)
    q = q_of_states(network)
    assert np.abs(q - mdp["q_star"]).max() < margin / 10
    np.testing.assert_array_equal(q.argmax(axis=1), mdp["q_star"].argmax(axis=1))
    assert result.iterations < 2000 and result.bellman_residual < 0.01


def test_mlp_warm_start_needs_fewer_iterations(mdp):
    """
    A refit after the rewards moved a little (the algorithm's steady state) starts from the previous fit's
    output layer and converges in fewer iterations than a fit of the same rewards and features from
    scratch, to the same Q (with the features kept, a warm start ignored would take as many).
    """
    network, _ = fit_small_network(mdp, seed=2, epochs=0, tol=1e-6)
    moved = mdp["rewards"] + 0.01 * np.random.default_rng(3).normal(size=len(mdp["rewards"]))
    _, warm = fit_small_network(mdp, seed=2, network=network, rewards=moved, epochs=0, tol=1e-6)
    cold_network, cold = fit_small_network(mdp, seed=2, rewards=moved, epochs=0, tol=1e-6)
    assert warm.iterations < 0.8 * cold.iterations
    np.testing.assert_allclose(q_of_states(network), q_of_states(cold_network), atol=1e-3)


def test_mlp_stopping_rule_stops_on_converged_targets_and_runs_to_the_cap_otherwise(mdp):
    """
    Refitting a converged network on the same rewards moves theta by less than tol at once: one iteration.
    With tol = 0, or from scratch with a cap, the fitted iterations run to ``max_iterations``.
    """
    network, converged = fit_small_network(mdp, seed=4, epochs=0, solver="iterations", tol=1e-6)
    assert 1 < converged.iterations < 2000
    _, again = fit_small_network(mdp, seed=4, network=network, epochs=0, solver="iterations", tol=1e-6)
    assert again.iterations == 1
    with pytest.warns(FQICapWarning):
        _, exact = fit_small_network(
            mdp, seed=4, network=network, epochs=0, solver="iterations", tol=0.0, max_iterations=7
        )
    assert exact.iterations == 7 and not exact.converged
    with pytest.warns(FQICapWarning):
        _, capped = fit_small_network(mdp, seed=4, epochs=0, solver="iterations", tol=1e-6, max_iterations=5)
    assert capped.iterations == 5 and capped.bellman_residual > converged.bellman_residual
    assert converged.converged and not capped.converged


@pytest.mark.filterwarnings("ignore::sb3_trlsd.fqi.FQICapWarning")
def test_mlp_fqi_is_deterministic_given_its_seeds(mdp):
    """Same initial weights, optimizer state and shuffling generator: the same network, weight for weight."""
    first, _ = fit_small_network(mdp, seed=1, epochs=2, max_iterations=3)
    second, _ = fit_small_network(mdp, seed=1, epochs=2, max_iterations=3)
    for a, b in zip(first.parameters(), second.parameters(), strict=True):
        assert th.equal(a, b)
    third, _ = fit_small_network(mdp, seed=5, epochs=2, max_iterations=3)
    assert not th.equal(first[0].weight, third[0].weight)


def test_an_unfitted_q_network_is_zero():
    """Before its first fit a task's Q is 0, as the linear policy's (TRLSD's warning says so)."""
    network = make_q_network(3, 2)
    assert th.equal(network(th.randn(5, 3)), th.zeros(5, 2))


@pytest.mark.filterwarnings("ignore::sb3_trlsd.fqi.FQICapWarning")
def test_mlp_policy_refits_after_save_and_load_as_it_would_have(tmp_path, source_transitions):
    """
    The MLP's warm start lives in the policy's state: its networks, Adam's moments and the minibatch
    generator. A loaded model's next refit gives the Q-values of the model that was never saved; Adam made
    anew or another shuffle would not.
    """
    model = TRLSD("MlpPolicy", gym.make(MAZE_ID, task=(1, 1)), fqi_max_iterations=5, seed=0)
    model.load_transitions(source_transitions)
    model.learn(total_timesteps=20)
    model.save(tmp_path / "mlp")
    loaded = TRLSD.load(tmp_path / "mlp", env=model.get_env())
    assert loaded.policy.optimizer.state_dict()["state"]
    for each in (model, loaded):
        each.update_policy(0)
    states = np.random.default_rng(0).uniform(0, 5, size=(50, 2))
    # float32 Q-values; the relabelling rebuilt after load sums in another order (rewards within ~1e-12)
    np.testing.assert_allclose(loaded.policy.q_values(states, 0), model.policy.q_values(states, 0), rtol=1e-5)
