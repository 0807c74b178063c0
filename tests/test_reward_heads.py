"""Reward heads against their closed forms: ridge regression + eq. 9, per-cell means + eq. 10, known."""

import numpy as np
import pytest

from envs.maze import expected_reward
from sb3_trlsd.features import RBFGrid
from sb3_trlsd.reward_heads import (
    KnownRewardHead,
    RidgeRewardHead,
    TabularRewardHead,
    make_reward_head,
    maze_cell_index,
)

GRID = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.2)


def samples(n, seed=0):
    rng = np.random.default_rng(seed)
    states = rng.uniform(0, 5, size=(n, 2))
    return states, expected_reward(states, 6) + rng.normal(size=n)


def eq9_by_hand(head_states, queries, kappa, sigma, points=lambda s: s):
    """kappa sqrt(log|Xi| / W(s)), W(s) = sum_j exp(-||p(s) - p(s_j)||^2 / 2 sigma^2), sample by sample."""
    widths = []
    for query in points(queries):
        weight = sum(
            np.exp(-np.sum((query - sample) ** 2) / (2 * sigma**2)) for sample in points(head_states)
        )
        widths.append(kappa * np.sqrt(np.log(len(head_states)) / weight))
    return np.array(widths)


@pytest.mark.parametrize("similarity", ["state", "features"])
def test_ridge_head_is_the_closed_form_ridge_and_eq_9(similarity):
    """After incremental updates, R^ is (Phi^T Phi + I)^-1 Phi^T r and CI is eq. 9 computed by hand."""
    states, rewards = samples(300)
    head = RidgeRewardHead(
        GRID, kappa=0.3, sigma=0.5 if similarity == "state" else 0.2, similarity=similarity
    )
    for chunk in np.array_split(np.arange(300), 7):
        head.update(states[chunk], rewards[chunk])
    phi = GRID(states)
    weights = np.linalg.solve(phi.T @ phi + np.eye(25), phi.T @ rewards)
    queries = np.random.default_rng(1).uniform(0.5, 4.5, size=(20, 2))
    np.testing.assert_allclose(head.estimate(queries), GRID(queries) @ weights, rtol=1e-9, atol=1e-12)
    points = (lambda s: s) if similarity == "state" else GRID
    expected = eq9_by_hand(states, queries, 0.3, head.sigma, points)
    np.testing.assert_allclose(head.bonus(queries), expected, rtol=1e-9)
    np.testing.assert_allclose(head.optimistic(queries), head.estimate(queries) + expected, rtol=1e-9)


def test_tracker_follows_the_head_through_updates_and_new_queries():
    """The incremental kernel sums equal the head evaluated from scratch at every point of the way."""
    states, rewards = samples(400, seed=2)
    queries = np.random.default_rng(3).uniform(0, 5, size=(500, 2))
    head = RidgeRewardHead(GRID, kappa=0.1, sigma=0.2)
    tracker = head.tracker(queries[:200])
    for step, chunk in enumerate(np.array_split(np.arange(400), 4)):
        head.update(states[chunk], rewards[chunk])
        tracker.extend(queries[200 + 75 * step : 275 + 75 * step])
        np.testing.assert_allclose(tracker.optimistic(), head.optimistic(tracker.states), rtol=1e-10)


def test_frozen_uncertainty_ignores_later_samples():
    """The refit trigger compares against the head as it was: later updates must not leak into it."""
    states, rewards = samples(200, seed=4)
    head = RidgeRewardHead(GRID)
    head.update(states[:100], rewards[:100])
    frozen = head.frozen_uncertainty()
    before = frozen(states[150:])
    head.update(states[100:], rewards[100:])
    np.testing.assert_array_equal(frozen(states[150:]), before)
    assert np.all(head.uncertainty(states[150:]) < before)  # the new samples sit at these states


def test_ci_only_shrinks_where_samples_are_added():
    """
    Adding samples never lowers W anywhere (eq. 8 is a sum of positive terms). Where they land W grows
    faster than log|Xi|, so the CI there shrinks; far from them only the log factor moves, and it grows.
    """
    head = RidgeRewardHead(GRID, kappa=0.1, sigma=0.2)
    rng = np.random.default_rng(5)
    head.update(rng.uniform(0, 5, size=(100, 2)), rng.normal(size=100))
    near, far = np.array([[1.0, 1.0]]), np.array([[4.0, 4.0]])
    w_before = head.kernel_sums(np.vstack([near, far]))
    ci_near, ci_far = head.bonus(near)[0], head.bonus(far)[0]
    head.update(near + rng.normal(scale=0.05, size=(20, 2)), rng.normal(size=20))
    assert np.all(head.kernel_sums(np.vstack([near, far])) >= w_before)
    assert head.bonus(near)[0] < ci_near
    assert head.bonus(far)[0] >= ci_far * 0.999


def test_no_nan_or_inf_with_zero_or_one_sample_and_far_queries():
    """|Xi| <= 1 and W -> 0 are handled: log clamped at log 2, W floored at w_floor."""
    head = RidgeRewardHead(GRID, kappa=0.1, sigma=0.2, w_floor=1e-6)
    far = np.array([[0.01, 0.01], [4.99, 4.99]])
    assert np.all(head.estimate(far) == 0)
    np.testing.assert_allclose(head.bonus(far), 0.1 * np.sqrt(np.log(2) / 1e-6))
    head.update(np.array([[0.01, 0.01]]), np.array([1.0]))
    values = head.optimistic(far)
    assert np.all(np.isfinite(values)) and values[1] > values[0] > 0
    capped = RidgeRewardHead(GRID, r_max=2.0)
    assert capped.optimistic(far).max() == 2.0


def test_tabular_head_is_per_cell_means_and_eq_10():
    """R^ is the mean reward of each cell's samples and CI = kappa sqrt(log|Xi| / N(s))."""
    states, rewards = samples(500, seed=6)
    head = TabularRewardHead(maze_cell_index, 25, kappa=0.2)
    head.update(states[:250], rewards[:250])
    head.update(states[250:], rewards[250:])
    cells = maze_cell_index(states)
    for cell in (0, 6, 24):
        rows = cells == cell
        query = states[rows][:1]
        assert head.estimate(query)[0] == pytest.approx(rewards[rows].mean())
        assert head.bonus(query)[0] == pytest.approx(0.2 * np.sqrt(np.log(500) / rows.sum()))


def test_corners_preset_has_no_estimate_nor_bonus_outside_the_corners():
    """With the corner prior, R^ = 0 and CI = 0 outside the 4 corner cells, whatever the samples."""
    head = make_reward_head("corners", kappa=0.5)
    states, rewards = samples(300, seed=7)
    head.update(states, rewards + 5.0)
    middle, corner = np.array([[2.5, 2.5]]), np.array([[0.5, 4.5]])
    assert head.estimate(middle)[0] == 0 and head.bonus(middle)[0] == 0
    assert head.estimate(corner)[0] > 4 and head.bonus(corner)[0] > 0


def test_known_head_has_no_uncertainty():
    """The known head returns the true expected reward and a zero CI."""
    head = KnownRewardHead(lambda s: expected_reward(s, 0))
    states, _ = samples(50)
    np.testing.assert_array_equal(head.optimistic(states), expected_reward(states, 0))
    assert not head.bonus(states).any()


@pytest.mark.parametrize(
    ("make", "argument"),
    [
        (lambda: RidgeRewardHead(GRID, kappa=-1), "kappa"),
        (lambda: RidgeRewardHead(GRID, sigma=0), "sigma"),
        (lambda: RidgeRewardHead(GRID, similarity="cosine"), "similarity"),
        (lambda: RidgeRewardHead(GRID, w_floor=0), "w_floor"),
        (lambda: make_reward_head("gp"), "reward_head"),
        (lambda: make_reward_head("known"), "reward_fn"),
    ],
    ids=[
        "negative-kappa",
        "zero-sigma",
        "unknown-similarity",
        "zero-floor",
        "unknown-name",
        "known-without-fn",
    ],
)
def test_bad_head_settings_are_refused_by_name(make, argument):
    """Each bad setting raises a ValueError naming the argument."""
    with pytest.raises(ValueError, match=argument):
        make()


def test_nan_rewards_are_refused():
    """A NaN reward would poison every relabelled sample: refused at update."""
    with pytest.raises(ValueError, match="rewards"):
        RidgeRewardHead(GRID).update(np.ones((2, 2)), np.array([1.0, np.nan]))
