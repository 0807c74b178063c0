"""Reward heads against their closed forms: ridge regression + eq. 8-9, cell means + eq. 10, known reward."""

import pickle

import numpy as np
import pytest
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st

from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.reward_heads import (
    GridCells,
    KernelSumTracker,
    KnownRewardHead,
    RewardTracker,
    RidgeRewardHead,
    TabularRewardHead,
    make_reward_head,
    make_tabular_head,
)
from sb3_trlsd_envs.dynamics import cell_of

GRID = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)  # the paper's width 0.2
MAZE_BOX = spaces.Box(0, 5, (2,))
MAZE_CELLS = GridCells((0, 0), (5, 5), 5)  # the maze's 25 cells, cell id = the task index of its task
# Rounding of sums of up to a few hundred positive terms, computed in different orders or blocks.
SUM_RTOL = 1e-10


def expected_reward(states, task):
    """The maze's E[R_task(s)] (eq. 12): 1 in the task's cell, 0 elsewhere."""
    return (MAZE_CELLS(states) == task).astype(np.float64)


def samples(n, seed=0, task=6):
    """n uniform states of the maze and the paper's noisy rewards of ``task`` there."""
    rng = np.random.default_rng(seed)
    states = rng.uniform(0, 5, size=(n, 2))
    return states, expected_reward(states, task) + rng.normal(size=n)


def eq9_by_hand(head_states, queries, kappa, sigma, points=lambda s: s):
    """kappa sqrt(log|Xi| / W(s)), W(s) = sum_j exp(-||p(s) - p(s_j)||^2 / 2 sigma^2), sample by sample."""
    widths = []
    for query in points(queries):
        weight = sum(
            np.exp(-np.sum((query - sample) ** 2) / (2 * sigma**2)) for sample in points(head_states)
        )
        widths.append(kappa * np.sqrt(np.log(len(head_states)) / weight))
    return np.array(widths)


def all_heads():
    """One head of each kind, with readable ids, for the tests every head must pass."""
    return [
        pytest.param(lambda: RidgeRewardHead(GRID, kappa=0.1, sigma=0.2), id="ridge-state"),
        pytest.param(lambda: RidgeRewardHead(GRID, kappa=0.1, similarity="features"), id="ridge-features"),
        pytest.param(lambda: make_tabular_head(MAZE_BOX, kappa=0.2), id="tabular"),
        pytest.param(lambda: make_tabular_head(MAZE_BOX, kappa=0.2, corners=True), id="corners"),
        pytest.param(lambda: KnownRewardHead(expected_reward, task=6), id="known"),
    ]


@pytest.mark.parametrize("similarity", ["state", "features"])
def test_ridge_head_is_the_closed_form_ridge_and_eq_9(similarity):
    """After incremental updates, R^ is (Phi^T Phi + I)^-1 Phi^T r and CI is eq. 9 computed by hand."""
    states, rewards = samples(300)
    head = RidgeRewardHead(
        GRID, kappa=0.3, sigma=0.5 if similarity == "state" else 0.2, similarity=similarity
    )
    for chunk in np.array_split(np.arange(300), 7):
        head.update(states[chunk], rewards[chunk])
    assert head.n_samples == 300
    phi = GRID(states)
    weights = np.linalg.solve(phi.T @ phi + np.eye(25), phi.T @ rewards)
    queries = np.random.default_rng(1).uniform(0.5, 4.5, size=(20, 2))
    np.testing.assert_allclose(head.estimate(queries), GRID(queries) @ weights, rtol=1e-9, atol=1e-12)
    points = (lambda s: s) if similarity == "state" else GRID
    expected = eq9_by_hand(states, queries, 0.3, head.sigma, points)
    np.testing.assert_allclose(head.bonus(queries), expected, rtol=SUM_RTOL)
    np.testing.assert_allclose(head.uncertainty(queries), expected / 0.3, rtol=SUM_RTOL)
    np.testing.assert_allclose(head.optimistic(queries), head.estimate(queries) + expected, rtol=SUM_RTOL)


@pytest.mark.parametrize("similarity", ["state", "features"])
@pytest.mark.parametrize("kappa", [0.0, 0.1])
def test_tracker_follows_the_head_through_updates_and_new_queries(similarity, kappa):
    """The incremental kernel sums equal the head evaluated from scratch at every point of the way."""
    states, rewards = samples(400, seed=2)
    queries = np.random.default_rng(3).uniform(0, 5, size=(500, 2))
    head = RidgeRewardHead(GRID, kappa=kappa, sigma=0.2, similarity=similarity)
    tracker = head.tracker(queries[:150])  # created before any sample
    assert isinstance(tracker, KernelSumTracker)
    np.testing.assert_allclose(tracker.optimistic(), head.optimistic(tracker.states))
    for step, chunk in enumerate(np.array_split(np.arange(400), 5)):
        head.update(states[chunk], rewards[chunk])
        if step % 2:  # asked after some updates only, so that several batches are folded at once
            continue
        tracker.extend(queries[150 + 25 * step : 200 + 25 * step])
        assert tracker.n_states == 200 + 25 * step
        np.testing.assert_allclose(tracker.estimate(), head.estimate(tracker.states), rtol=1e-12)
        np.testing.assert_allclose(tracker.bonus(), head.bonus(tracker.states), rtol=SUM_RTOL)
        np.testing.assert_allclose(tracker.optimistic(), head.optimistic(tracker.states), rtol=SUM_RTOL)


@pytest.mark.parametrize("make_head", all_heads())
def test_every_heads_tracker_equals_the_head(make_head):
    """Whatever the head, tracker.optimistic() is head.optimistic on the tracked states after updates."""
    head = make_head()
    states, rewards = samples(120, seed=8)
    queries = np.random.default_rng(9).uniform(0, 5, size=(60, 2))
    tracker = head.tracker(queries[:30])
    assert isinstance(tracker, RewardTracker)
    head.update(states[:70], rewards[:70])
    tracker.extend(queries[30:])
    head.update(states[70:], rewards[70:])
    np.testing.assert_allclose(tracker.optimistic(), head.optimistic(queries), rtol=SUM_RTOL)


@pytest.mark.parametrize("make_head", all_heads())
def test_an_uncertainty_snapshot_ignores_later_samples(make_head):
    """The refit trigger compares against the head as it was: later updates must not leak into it."""
    head = make_head()
    states, rewards = samples(200, seed=4)
    head.update(states[:100], rewards[:100])
    snapshot = head.snapshot()
    before = head.uncertainty_as_of(snapshot, states[150:])
    np.testing.assert_allclose(before, head.uncertainty(states[150:]), rtol=SUM_RTOL)
    head.update(states[100:], rewards[100:])
    np.testing.assert_array_equal(head.uncertainty_as_of(snapshot, states[150:]), before)
    restored = pickle.loads(pickle.dumps(snapshot))  # plain data, saved with the model
    np.testing.assert_array_equal(head.uncertainty_as_of(restored, states[150:]), before)
    if not isinstance(head, KnownRewardHead):
        # The new samples sit at these states (corners: where the prior allows a reward).
        assert np.all(head.uncertainty(states[150:]) <= before)
        assert np.any(head.uncertainty(states[150:]) < before)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(0, 40),
    sigma=st.floats(0.05, 2.0),
    seed=st.integers(0, 2**31 - 1),
    similarity=st.sampled_from(["state", "features"]),
)
def test_adding_a_sample_never_lowers_w_anywhere(n, sigma, seed, similarity):
    """W (eq. 8) is a sum of positive terms: a new sample at s raises it, by 1 at s, and lowers it nowhere."""
    rng = np.random.default_rng(seed)
    head = RidgeRewardHead(GRID, sigma=sigma, similarity=similarity)
    if n:
        head.update(rng.uniform(0, 5, size=(n, 2)), rng.normal(size=n))
    queries, new = rng.uniform(0, 5, size=(50, 2)), rng.uniform(0, 5, size=(1, 2))
    w_before = head.kernel_sums(head.similarity_points(np.vstack([queries, new])))
    head.update(new, np.zeros(1))
    w_after = head.kernel_sums(head.similarity_points(np.vstack([queries, new])))
    assert np.all(w_after >= w_before * (1 - SUM_RTOL))
    assert w_after[-1] == pytest.approx(w_before[-1] + 1.0, rel=SUM_RTOL)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(0, 40).filter(lambda n: n != 2),
    sigma=st.floats(0.05, 2.0),
    seed=st.integers(0, 2**31 - 1),
    similarity=st.sampled_from(["state", "features"]),
)
def test_uncertainty_shrinks_where_a_sample_is_added(n, sigma, seed, similarity):
    """
    u(s)^2 = log n / W(s) becomes log(n + 1) / (W(s) + 1) when a sample lands at s. Since W(s) <= n, this
    is smaller whenever W(s) log(1 + 1/n) < log n, which holds for every n >= 3 (the left side is < 1 <
    log 3) and for n = 0, 1 (log clamped at log 2), whatever sigma and the similarity. n = 2 is the exception
    (see the next test). Elsewhere u can grow: only the log factor moves far from the new sample.
    """
    rng = np.random.default_rng(seed)
    head = RidgeRewardHead(GRID, sigma=sigma, similarity=similarity)
    if n:
        head.update(rng.uniform(0, 5, size=(n, 2)), rng.normal(size=n))
    new = rng.uniform(0, 5, size=(1, 2))
    before = head.uncertainty(new)[0]
    head.update(new, np.zeros(1))
    assert head.uncertainty(new)[0] < before


def test_uncertainty_can_grow_at_a_third_sample_on_top_of_two():
    """With 2 samples at s (W = 2), a third there moves u^2 from log 2 / 2 to log 3 / 3, which is larger."""
    head = RidgeRewardHead(GRID, sigma=0.2)
    s = np.array([[2.5, 2.5]])
    head.update(np.vstack([s, s]), np.zeros(2))
    before = head.uncertainty(s)[0]
    head.update(s, np.zeros(1))
    assert before == pytest.approx(np.sqrt(np.log(2) / 2))
    after = head.uncertainty(s)[0]
    assert after == pytest.approx(np.sqrt(np.log(3) / 3))
    assert after > before


def test_far_from_new_samples_only_the_log_factor_moves():
    """Samples added near (1, 1) leave W at (4, 4) almost unchanged, so the CI there grows with log|Xi|."""
    head = RidgeRewardHead(GRID, kappa=0.1, sigma=0.2)
    rng = np.random.default_rng(5)
    head.update(rng.uniform(0, 5, size=(100, 2)), rng.normal(size=100))
    far = np.array([[4.0, 4.0]])
    ci_far = head.bonus(far)[0]
    head.update(1.0 + rng.normal(scale=0.05, size=(20, 2)), rng.normal(size=20))
    assert head.bonus(far)[0] == pytest.approx(ci_far * np.sqrt(np.log(120) / np.log(100)), rel=1e-6)


@pytest.mark.parametrize("similarity", ["state", "features"])
def test_no_nan_or_inf_with_zero_or_one_sample_and_far_queries(similarity):
    """|Xi| <= 1 and W -> 0 are handled: log clamped at log 2, W floored at w_floor (module docstring)."""
    head = RidgeRewardHead(GRID, kappa=0.1, sigma=0.2, similarity=similarity, w_floor=1e-6)
    queries = np.array([[0.01, 0.01], [4.99, 4.99], [1e6, -1e6], [1e200, 1e200]])
    largest = 0.1 * np.sqrt(np.log(2) / 1e-6)
    np.testing.assert_array_equal(head.estimate(queries), 0.0)
    np.testing.assert_allclose(head.bonus(queries), largest)
    head.update(np.array([[0.01, 0.01]]), np.array([1.0]))
    values = head.optimistic(queries)
    assert np.all(np.isfinite(values))
    assert head.bonus(queries[:1])[0] == pytest.approx(0.1 * np.sqrt(np.log(2)))  # W = 1 at the sample
    if similarity == "state":  # S_Phi cannot tell apart states far from every RBF centre
        np.testing.assert_allclose(head.bonus(queries[2:]), largest)


def test_r_max_caps_the_optimistic_reward():
    """Expert knowledge of a reward bound caps R~, not R^."""
    capped = RidgeRewardHead(GRID, r_max=2.0)
    far = np.array([[0.01, 0.01], [4.99, 4.99]])
    np.testing.assert_array_equal(capped.optimistic(far), 2.0)
    np.testing.assert_array_equal(capped.tracker(far).optimistic(), 2.0)
    assert capped.bonus(far).min() > 2.0


def test_tabular_head_is_per_cell_means_and_eq_10():
    """R^ is the mean reward of each cell's samples and CI = kappa sqrt(log|Xi| / N(s)); N = 0 is floored."""
    states, rewards = samples(500, seed=6)
    head = TabularRewardHead(MAZE_CELLS, 25, kappa=0.2)
    head.update(states[:250], rewards[:250])
    head.update(states[250:], rewards[250:])
    cells = MAZE_CELLS(states)
    for cell in range(25):
        rows = cells == cell
        query = states[rows][:1]
        assert head.estimate(query)[0] == pytest.approx(rewards[rows].mean(), rel=1e-12)
        assert head.bonus(query)[0] == pytest.approx(0.2 * np.sqrt(np.log(500) / rows.sum()), rel=1e-12)
    empty = TabularRewardHead(MAZE_CELLS, 25, kappa=0.2, w_floor=1e-4)
    assert empty.estimate(states[:1])[0] == 0
    assert empty.bonus(states[:1])[0] == pytest.approx(0.2 * np.sqrt(np.log(2) / 1e-4))


def test_grid_cells_on_the_maze_are_the_task_index_of_the_cell():
    """Cell 5 (ceil(x) - 1) + (ceil(y) - 1), the borders and outside clipped to the nearest cell."""
    states = np.array([[0.3, 0.2], [0.3, 4.2], [4.5, 0.5], [5.0, 5.0], [1.0, 1.0], [1.01, 2.0], [-1, 7]])
    np.testing.assert_array_equal(MAZE_CELLS(states), [0, 4, 20, 24, 0, 6, 4])
    assert MAZE_CELLS.corner_cells() == (0, 4, 20, 24) and MAZE_CELLS.n_cells == 25


def test_grid_cells_agree_with_the_mazes_own_cells():
    """The generic grid over the maze's Box is the maze's cell i = ceil(x), j = ceil(y), everywhere."""
    states = np.random.default_rng(0).uniform(0, 5, size=(2_000, 2))
    states[:20] = np.round(states[:20])  # on the cell boundaries
    i, j = cell_of(states).T
    np.testing.assert_array_equal(MAZE_CELLS(states), 5 * (i - 1) + (j - 1))


def test_grid_cells_in_three_dimensions_count_row_major_with_the_first_slowest():
    """A user discretisation by per-dimension bins: ids, corners and the box edges in 3-D."""
    cells = GridCells((0, -1, 10), (1, 1, 20), 3)
    states = np.array([[0.1, -0.9, 10.5], [0.9, 0.9, 19.9], [0.5, 0.0, 15.0], [0.1, -0.9, 19.0]])
    np.testing.assert_array_equal(cells(states), [0, 26, 13, 2])
    assert cells.n_cells == 27 and cells.corner_cells() == (0, 2, 6, 8, 18, 20, 24, 26)


def test_tabular_head_on_a_user_cell_function():
    """Any cell function works, and one returning ids out of range is refused with the head unchanged."""
    head = TabularRewardHead(lambda states: (states[:, 0] > 0).astype(np.int64), 2, kappa=0.1)
    head.update(np.array([[-1.0, 0.0], [1.0, 0.0], [2.0, 5.0]]), np.array([0.0, 1.0, 3.0]))
    np.testing.assert_allclose(head.estimate(np.array([[5.0, 1.0], [-3.0, 1.0]])), [2.0, 0.0])
    bad = TabularRewardHead(lambda states: np.full(len(states), 2), 2)
    with pytest.raises(ValueError, match="cell_fn"):
        bad.update(np.ones((1, 2)), np.ones(1))
    assert bad.n_samples == 0 and not bad.counts.any()


def test_corners_preset_has_no_estimate_nor_bonus_outside_the_corners():
    """With the corner prior, R^ = 0 and CI = 0 outside the 4 corner cells, whatever the samples."""
    head = make_reward_head("corners", state_space=MAZE_BOX, kappa=0.5)
    states, rewards = samples(300, seed=7)
    head.update(states, rewards + 5.0)
    grid_of_cells = GRID.centres
    inside = np.isin(MAZE_CELLS(grid_of_cells), [0, 4, 20, 24])
    assert np.all(head.estimate(grid_of_cells)[~inside] == 0)
    assert np.all(head.bonus(grid_of_cells)[~inside] == 0)
    assert np.all(head.estimate(grid_of_cells)[inside] > 4) and np.all(head.bonus(grid_of_cells)[inside] > 0)


def test_known_head_has_no_uncertainty():
    """The known head returns the true expected reward and a zero CI; updates only count samples."""
    head = make_reward_head("known", task=0, reward_fn=expected_reward)
    states, rewards = samples(50)
    head.update(states, rewards)
    assert head.n_samples == 50
    np.testing.assert_array_equal(head.optimistic(states), expected_reward(states, 0))
    assert not head.bonus(states).any() and not head.uncertainty(states).any()
    assert not head.uncertainty_as_of(head.snapshot(), states).any()


def test_known_head_checks_its_reward_fn_and_is_saved_without_it():
    """The reward_fn(states, task) contract: one finite reward per state; the function is not pickled."""
    head = KnownRewardHead(expected_reward, task=3)
    restored = pickle.loads(pickle.dumps(head))
    assert restored.reward_fn is None and restored.task == 3
    with pytest.raises(ValueError, match="reward_fn"):
        restored.estimate(np.ones((2, 2)))
    restored.bind(expected_reward)
    np.testing.assert_array_equal(restored.estimate(np.ones((2, 2))), expected_reward(np.ones((2, 2)), 3))
    for bad in (
        lambda states, task: np.zeros(len(states) + 1),
        lambda states, task: np.full(len(states), np.nan),
    ):
        with pytest.raises(ValueError, match="reward_fn"):
            KnownRewardHead(bad, task=0).estimate(np.ones((2, 2)))


@pytest.mark.parametrize(
    ("name", "kind"),
    [("ridge", RidgeRewardHead), ("tabular", TabularRewardHead), ("corners", TabularRewardHead)],
)
def test_make_reward_head_builds_each_named_head(name, kind):
    """The factory's names map to the heads of the paper's settings."""
    head = make_reward_head(
        name, features=GRID, state_space=MAZE_BOX, kappa=0.3, sigma=0.4, similarity="features"
    )
    assert isinstance(head, kind) and head.kappa == 0.3
    if name == "corners":
        assert head.allowed.sum() == 4


@pytest.mark.parametrize("make_head", all_heads())
def test_heads_and_trackers_pickle_and_have_short_reprs(make_head):
    """Models are saved with their heads: a pickled head answers as the original; repr fits on one line."""
    head = make_head()
    states, rewards = samples(80, seed=10)
    head.update(states, rewards)
    tracker = head.tracker(states[:20])
    restored_head, restored_tracker = pickle.loads(pickle.dumps((head, tracker)))
    if isinstance(head, KnownRewardHead):  # saved without its function (often an env's method): bound again
        restored_head.bind(head.reward_fn)
    np.testing.assert_array_equal(restored_head.optimistic(states), head.optimistic(states))
    np.testing.assert_array_equal(restored_tracker.optimistic(), tracker.optimistic())
    assert restored_head.n_samples == 80
    assert len(repr(head)) < 100 and type(head).__name__ in repr(head) and "\n" not in repr(tracker)


@pytest.mark.parametrize(
    ("make", "argument"),
    [
        (lambda: RidgeRewardHead(GRID, kappa=-1), "kappa"),
        (lambda: RidgeRewardHead(GRID, sigma=0), "sigma"),
        (lambda: RidgeRewardHead(GRID, similarity="cosine"), "similarity"),
        (lambda: RidgeRewardHead(GRID, ridge=0), "ridge"),
        (lambda: RidgeRewardHead(GRID, w_floor=0), "w_floor"),
        (lambda: RidgeRewardHead(GRID, r_max=np.nan), "r_max"),
        (lambda: TabularRewardHead(MAZE_CELLS, 0), "n_cells"),
        (lambda: TabularRewardHead(MAZE_CELLS, 25, allowed_cells=[25]), "allowed_cells"),
        (lambda: TabularRewardHead(MAZE_CELLS, 25, w_floor=-1), "w_floor"),
        (lambda: make_tabular_head(MAZE_BOX, cells_per_dim=0), "cells_per_dim"),
        (lambda: make_tabular_head(spaces.Box(0, np.inf, (2,))), "bound the state Box"),
        (lambda: make_tabular_head(MAZE_BOX, cell_fn=MAZE_CELLS), "n_cells"),
        (lambda: make_tabular_head(None), "cell_fn"),
        (lambda: make_tabular_head(MAZE_BOX, corners=True, cell_fn=np.sign, n_cells=3), "corners"),
        (lambda: make_reward_head("gp"), "reward_head"),
        (lambda: make_reward_head("ridge"), "features"),
        (lambda: RidgeRewardHead(GRID, kappa=np.nan), "kappa"),
        (lambda: RidgeRewardHead(GRID, sigma=np.nan), "sigma"),
    ],
    ids=[
        "negative-kappa",
        "zero-sigma",
        "unknown-similarity",
        "zero-ridge",
        "zero-floor",
        "nan-r-max",
        "no-cells",
        "allowed-cell-out-of-range",
        "negative-tabular-floor",
        "zero-cells-per-dim",
        "unbounded-box",
        "cell-fn-without-count",
        "no-cells-at-all",
        "corners-of-a-user-function",
        "unknown-name",
        "ridge-without-features",
        "nan-kappa",
        "nan-sigma",
    ],
)
def test_bad_head_settings_are_refused_by_name(make, argument):
    """Each bad setting raises a ValueError naming the argument."""
    with pytest.raises(ValueError, match=argument):
        make()


@pytest.mark.parametrize(
    ("states", "rewards", "argument"),
    [
        (np.ones((2, 2)), np.array([1.0, np.nan]), "rewards"),
        (np.ones((2, 2)), np.array([1.0, np.inf]), "rewards"),
        (np.ones((2, 2)), np.ones(3), "rewards"),
        (np.ones(2), np.ones(2), "states"),
        (np.ones((2, 3)), np.ones(2), "states"),
        (np.array([[1.0, np.nan]]), np.ones(1), "states"),
    ],
    ids=["nan-reward", "inf-reward", "one-reward-too-many", "flat-states", "wrong-state-width", "nan-state"],
)
def test_bad_samples_are_refused_and_leave_the_head_unchanged(states, rewards, argument):
    """A NaN reward or a mis-shaped batch would poison every relabelled sample: refused at update."""
    head = RidgeRewardHead(GRID)
    head.update(np.full((1, 2), 2.5), np.ones(1))
    with pytest.raises(ValueError, match=argument):
        head.update(states, rewards)
    assert head.n_samples == 1


def test_an_empty_update_is_a_no_op():
    """An empty batch (no transition of the task this round) changes nothing."""
    head = RidgeRewardHead(GRID)
    head.update(np.zeros((0, 2)), np.zeros(0))
    assert head.n_samples == 0 and head.weights is None
