"""When linear Fitted-Q Iteration stops: its stopping rules, the fixed point they reach, the cap's warning."""

import warnings

import numpy as np
import pytest

from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.fqi import (
    SOLVERS,
    FQICapWarning,
    LinearFQISolver,
    PolicyMoments,
    fit_linear_fqi_runs,
    return_bounds,
    targets_rule_cap,
)

GAMMA = 0.9
MOVES = np.array([[0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])


def overlapping_rbf_transitions(n=1500, seed=0):
    """
    Uniform states on the unit square, 4 actions moving 0.05 (+ noise sd 0.01), a reward bump at (0.8, 0.8),
    seen through 10 x 10 RBFs of width 0.1: they overlap, the Gram matrices' condition number is ~1e6.
    """
    rng = np.random.default_rng(seed)
    states, actions = rng.uniform(size=(n, 2)), rng.integers(4, size=n)
    next_states = np.clip(states + 0.05 * MOVES[actions] + 0.01 * rng.normal(size=(n, 2)), 0, 1)
    grid = RBFGrid(low=(0, 0), high=(1, 1), n_per_dim=10, sigma=0.1)
    rewards = np.exp(-np.sum((states - 0.8) ** 2, axis=1) / (2 * 0.1**2))
    return grid(states), actions, rewards, grid(next_states), np.zeros(n, bool)


def solver_of(data, dtype=np.float64):
    phi, actions, _, next_phi, terminated = data
    solver = LinearFQISolver(phi.shape[1], 4, dtype=dtype)
    solver.extend(phi, actions, next_phi, terminated)
    return solver


def greedy_values(data, theta):
    """max_a Q(s', a) at every next state, (n,): what the targets read."""
    return (data[3] @ theta.T).max(axis=1)


def cycling_transitions():
    """
    Three transitions, 2 features, 2 actions: off-policy projected FQI has no stable greedy policy here, its
    iterates cycle (period ~8) between policies forever.
    """
    rng = np.random.default_rng(30)
    n = int(rng.integers(3, 8))
    phi, next_phi = rng.uniform(size=(n, 2)), rng.uniform(size=(n, 2))
    actions, rewards = rng.integers(2, size=n), rng.uniform(-1, 1, size=n)
    return phi, actions, rewards, next_phi, np.zeros(n, bool)


@pytest.fixture(scope="module")
def rbf_data():
    return overlapping_rbf_transitions()


@pytest.fixture(scope="module")
def reference(rbf_data):
    """The fixed point's greedy values, from a long float64 run (targets still within 1e-9 of the scale)."""
    result = solver_of(rbf_data).fit(
        rbf_data[2], gamma=GAMMA, stop_rule="targets", tol=1e-9, max_iterations=2000
    )
    assert result.converged
    return greedy_values(rbf_data, result.theta)


def one_iteration(fit, theta0):
    """One projection of eq. 4 from theta0 (the fit warns: one iteration cannot meet tol = 0)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FQICapWarning)
        return fit(theta0=theta0, max_iterations=1, tol=0.0)


def stepped_by_hand(fit, tol):
    """
    Iterate ``fit`` one projection at a time from theta = 0, stopping at the first max |theta_new - theta|
    <= tol * (1 + max |theta_new|), the theta rule applied by hand: (theta, iterations).
    """
    theta, steps = None, 0
    while True:
        step = one_iteration(fit, theta)
        old = 0.0 if theta is None else theta
        theta, steps = step.theta, steps + 1
        if np.abs(theta - old).max() <= tol * (1 + np.abs(theta).max()):
            return theta, steps


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_the_theta_rule_gives_theta_to_the_bit_as_before(rbf_data, dtype):
    """
    The default rule is the one every fit had: the fitted iterations stop at the first max |theta_new - theta|
    <= tol * (1 + max |theta_new|). Stepping one iteration at a time and applying that test by hand gives the
    same theta to the bit, with the default and with stop_rule='theta', alone and in a batch. (A batch is
    stepped as a batch: in float32, BLAS may sum a product of 8 rows in another order than one of 4.)
    """
    solver, rewards, tol = solver_of(rbf_data, dtype), rbf_data[2], 1e-3
    iterations = {"solver": "iterations"}
    theta, steps = stepped_by_hand(lambda **kw: solver.fit(rewards, gamma=GAMMA, **iterations, **kw), tol)
    for result in (
        solver.fit(rewards, gamma=GAMMA, tol=tol, **iterations),
        solver.fit(rewards, gamma=GAMMA, tol=tol, stop_rule="theta", **iterations),
    ):
        np.testing.assert_array_equal(result.theta, theta)
        assert result.iterations == steps and result.converged

    def batch(theta0, **kw):
        theta0 = [None, None] if theta0 is None else [theta0, theta0]
        runs = fit_linear_fqi_runs(
            solver, [None, None], [rewards, rewards], gamma=GAMMA, theta0=theta0, **iterations, **kw
        )
        return runs[1]

    theta, steps = stepped_by_hand(batch, tol)
    result = batch(None, tol=tol)
    np.testing.assert_array_equal(result.theta, theta)
    assert result.iterations == steps and result.converged


def test_float32_rounding_keeps_theta_moving_but_not_the_targets(rbf_data, reference):
    """
    With float32 features and overlapping RBFs, rounding moves theta by more than tol at every fitted
    iteration (along directions the data barely constrains): the theta rule runs to its cap and warns. The
    targets rule stops in a third of that, within the distance to the fixed point its tolerance allows (see
    below; float32's own error, ~2e-5 of the scale here, is well inside it).
    """
    solver, rewards = solver_of(rbf_data, np.float32), rbf_data[2]
    with pytest.warns(FQICapWarning, match="stop_rule='targets'"):
        by_theta = solver.fit(rewards, gamma=GAMMA, tol=1e-4, max_iterations=300, solver="iterations")
    assert not by_theta.converged and by_theta.iterations == 300 and by_theta.change > 1e-4
    with warnings.catch_warnings():
        warnings.simplefilter("error", FQICapWarning)
        by_targets = solver.fit(rewards, gamma=GAMMA, tol=1e-4, max_iterations=300, stop_rule="targets")
    assert by_targets.converged and by_targets.iterations < 100 and by_targets.change <= 1e-4
    low, high = return_bounds(rewards, GAMMA)
    distance = np.abs(greedy_values(rbf_data, by_targets.theta) - reference).max()
    assert distance <= 2 * GAMMA / (1 - GAMMA) * 1e-4 * (high - low)


@pytest.mark.parametrize("tol", [1e-3, 1e-5])
def test_the_targets_rule_reaches_the_fixed_point_within_its_tolerance(rbf_data, reference, tol):
    """
    Stopped when the targets' RMS change is at most tol * (high - low), the iterates of a contraction of
    factor gamma are within gamma / (1 - gamma) * tol * (high - low) of the fixed point in that norm; the
    largest distance over the rows is checked against twice that bound.
    """
    rewards = rbf_data[2]
    low, high = return_bounds(rewards, GAMMA)
    result = solver_of(rbf_data).fit(rewards, gamma=GAMMA, tol=tol, stop_rule="targets")
    assert result.converged
    distance = np.abs(greedy_values(rbf_data, result.theta) - reference).max()
    assert distance <= 2 * GAMMA / (1 - GAMMA) * tol * (high - low)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("stop_rule", ["theta", "targets"])
def test_a_cycling_fit_stops_at_its_cap_and_warns(stop_rule, solver):
    """
    Iterates that cycle between greedy policies never meet either rule: the fit stops at the cap, warns.
    Policy iteration finds no stable policy either: it gives up and runs the fitted iterations from the
    warm start (one pass to restart there), to the same cap.
    """
    phi, actions, rewards, next_phi, terminated = cycling_transitions()
    rows = LinearFQISolver(2, 2)
    rows.extend(phi, actions, next_phi, terminated)
    with pytest.warns(FQICapWarning, match="cycle"):
        result = rows.fit(
            rewards,
            gamma=GAMMA,
            max_iterations=200,
            stop_rule=stop_rule,
            solver=solver,
            policy_moments=PolicyMoments(),
        )
    assert not result.converged and result.change > 1e-2
    evaluations = result.policy_evaluations
    assert result.iterations == 200 + (evaluations + 1 if solver == "policy_iteration" else 0)
    assert (evaluations > 0) == (solver == "policy_iteration")


def test_converged_fits_do_not_warn_and_a_repeated_cap_warns_once(rbf_data):
    """
    The warning's text has no number, so that the default filter shows it once however many refits hit the
    cap; converged fits do not warn at all.
    """
    solver, rewards = solver_of(rbf_data), rbf_data[2]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        for scale in (1.0, 2.0, 3.0):
            solver.fit(scale * rewards, gamma=GAMMA, max_iterations=2, stop_rule="targets")
        solver.fit(rewards, gamma=GAMMA, stop_rule="targets")
    assert [w.category for w in caught] == [FQICapWarning]


def test_each_run_of_a_batch_stops_by_the_targets_rule_as_it_would_alone(rbf_data):
    """
    In a batch, each run stops when its own targets stop moving, relative to its own return scale: rewards
    scaled by 10 stop where the unscaled ones do; a run of zero rewards stops at once; a run capped earlier
    than its rule is the only one flagged. The batch sums the shared and own rows in another order: the
    Gram matrices' condition number (~1e6) makes that ~1e-8 relative in theta (rtol 1e-6).
    """
    rewards = rbf_data[2]
    shared, own = solver_of([x[:1000] for x in rbf_data]), solver_of([x[1000:] for x in rbf_data])
    runs = [rewards, 10 * rewards, np.zeros_like(rewards)]
    batch = fit_linear_fqi_runs(shared, [own] * 3, runs, gamma=GAMMA, theta0=[None] * 3, stop_rule="targets")
    alone = [solver_of(rbf_data).fit(r, gamma=GAMMA, stop_rule="targets") for r in runs]
    for together, single in zip(batch, alone, strict=True):
        np.testing.assert_allclose(together.theta, single.theta, rtol=1e-6, atol=1e-9)
        assert abs(together.iterations - single.iterations) <= 1 and together.converged
    assert batch[0].iterations == batch[1].iterations and batch[2].iterations == 1
    with pytest.warns(FQICapWarning):
        capped = fit_linear_fqi_runs(
            shared, [own] * 3, runs, gamma=GAMMA, theta0=[None] * 3, stop_rule="targets", max_iterations=5
        )
    assert [result.converged for result in capped] == [False, False, True]


def test_an_unknown_stop_rule_is_refused_by_name(rbf_data):
    with pytest.raises(ValueError, match="stop_rule"):
        solver_of(rbf_data).fit(rbf_data[2], gamma=GAMMA, stop_rule="policy")


@pytest.mark.parametrize("tol", [1e-3, 1e-5])
def test_a_contracting_fit_from_zero_meets_the_targets_rule_well_within_its_default_cap(rbf_data, tol):
    """
    The default cap of a "targets" fit is three times the iterations a gamma-contraction needs to shrink a
    change of the whole return scale to tol: 198 at gamma 0.9 and tol 1e-3. A fit that contracts, started
    from theta = 0 (the farthest start), stops within a third of it.
    """
    cap = targets_rule_cap(GAMMA, tol)
    assert cap == 3 * int(np.ceil(np.log(tol) / np.log(GAMMA)))
    result = solver_of(rbf_data).fit(
        rbf_data[2], gamma=GAMMA, tol=tol, stop_rule="targets", max_iterations=cap
    )
    assert result.converged and result.iterations <= cap / 3
