"""RBF features and similarities (eq. 3, 6, 7, 11) against hand computations."""

import pickle

import numpy as np
import pytest

from sb3_trlsd.feature_choice import make_feature_map
from sb3_trlsd.feature_maps import RBFGrid, grid_centres
from sb3_trlsd.similarity import gaussian_similarity, squared_distances

MAZE_GRID = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)  # the paper's width 0.2


def test_maze_grid_centres_are_the_papers_in_task_order():
    """Centre s_ij = (i - 0.5, j - 0.5) sits at row 5 (i - 1) + (j - 1), the maze's task index (x-major)."""
    centres = grid_centres(np.zeros(2), np.full(2, 5.0), 5)
    assert centres.shape == (25, 2)
    for i in range(1, 6):
        for j in range(1, 6):
            np.testing.assert_allclose(centres[5 * (i - 1) + (j - 1)], [i - 0.5, j - 0.5])
    np.testing.assert_array_equal(MAZE_GRID.centres, centres)


def test_grid_centres_in_three_dimensions_vary_the_first_coordinate_slowest():
    """On a 2 x 2 x 2 grid over [0, 2]^3 the rows are (0.5|1.5)^3 in lexicographic order."""
    centres = grid_centres(np.zeros(3), np.full(3, 2.0), 2)
    expected = [[x, y, z] for x in (0.5, 1.5) for y in (0.5, 1.5) for z in (0.5, 1.5)]
    np.testing.assert_allclose(centres, expected)


def test_grid_centres_take_one_count_per_dimension():
    """3 x 2 cells over [0, 3] x [0, 1]: x-major rows (0.5|1.5|2.5) x (0.25|0.75); a count per dimension."""
    centres = grid_centres(np.zeros(2), np.array([3.0, 1.0]), (3, 2))
    np.testing.assert_allclose(centres, [[x, y] for x in (0.5, 1.5, 2.5) for y in (0.25, 0.75)])
    np.testing.assert_array_equal(
        grid_centres(np.zeros(2), np.ones(2), (4, 4)), grid_centres(np.zeros(2), np.ones(2), 4)
    )


def test_rbf_grid_equals_eq_11_and_is_one_at_its_centres():
    """The separable grid evaluation equals exp(-||s - s_ij||^2 / 2 sigma^2) for every centre."""
    states = np.random.default_rng(0).uniform(0, 5, size=(200, 2))
    direct = np.exp(-((states[:, None, :] - MAZE_GRID.centres[None]) ** 2).sum(-1) / (2 * 0.2**2))
    assert MAZE_GRID(states).shape == (200, MAZE_GRID.n_features) == (200, 25)
    np.testing.assert_allclose(MAZE_GRID(states), direct, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(
        gaussian_similarity(states, MAZE_GRID.centres, 0.2), direct, rtol=1e-10, atol=1e-300
    )
    np.testing.assert_allclose(np.diag(MAZE_GRID(MAZE_GRID.centres)), 1.0)


def test_similarities_equal_eq_6_and_eq_7_by_hand():
    """S_S on states and S_Phi on features, pair by pair against a hand computation."""
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 5, size=(4, 2)), rng.uniform(0, 5, size=(3, 2))
    s_s, s_phi = gaussian_similarity(a, b, 0.7), gaussian_similarity(MAZE_GRID(a), MAZE_GRID(b), 0.2)
    assert s_s.shape == s_phi.shape == (4, 3)
    for i in range(4):
        for j in range(3):
            assert s_s[i, j] == pytest.approx(np.exp(-np.sum((a[i] - b[j]) ** 2) / (2 * 0.7**2)), rel=1e-12)
            distance = np.sum((MAZE_GRID(a[i : i + 1]) - MAZE_GRID(b[j : j + 1])) ** 2)
            assert s_phi[i, j] == pytest.approx(np.exp(-distance / 0.08), rel=1e-10)


def test_squared_distances_stay_accurate_far_from_the_origin():
    """
    Points near (1e8, 1e8), 0.1 apart: the raw expansion |a|^2 + |b|^2 - 2 a.b would lose every digit (its
    terms are ~1e16, rounded to ~2); centring keeps the error at the inputs' own rounding (~1e-8 * 0.1).
    """
    rng = np.random.default_rng(2)
    a = 1e8 + rng.uniform(0, 0.1, size=(5, 2))
    b = 1e8 + rng.uniform(0, 0.1, size=(6, 2))
    direct = ((a[:, None, :] - b[None]) ** 2).sum(-1)
    np.testing.assert_allclose(squared_distances(a, b), direct, atol=1e-8)
    assert np.all(squared_distances(a, a).diagonal() >= 0)


def test_overflowing_distances_give_zero_similarity_not_nan():
    """States beyond ~1e154 overflow the squares: they are infinitely far, similarity 0 (and no warning)."""
    huge = np.array([[1e200, -1e200], [3e300, 1.0]])
    box = np.array([[1.0, 1.0], [4.0, 2.0]])
    for a, b in ((huge, box), (box, huge), (huge, huge[::-1])):
        similarity = gaussian_similarity(a, b, 0.2)
        assert np.all(np.isfinite(similarity)) and np.all(similarity == 0)
    assert np.all(MAZE_GRID(huge) == 0)


def test_the_papers_map_of_the_maze_is_its_grid_and_pickles():
    """The "paper" map on the maze's box is the paper's grid (width 0.2); it survives pickling."""
    grid = make_feature_map("paper", (0.0, 0.0), (5.0, 5.0))
    assert grid == MAZE_GRID and grid.widths == (0.2, 0.2)
    restored = pickle.loads(pickle.dumps(grid))
    np.testing.assert_array_equal(restored.centres, grid.centres)
    states = np.array([[0.3, 4.1]])
    np.testing.assert_array_equal(restored(states), grid(states))


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"sigma": 0.0}, "sigma"),
        ({"sigma": -1.0}, "sigma"),
        ({"n_per_dim": 0}, "n_per_dim"),
        ({"low": (5, 5), "high": (0, 0)}, "low"),
    ],
    ids=["zero-sigma", "negative-sigma", "no-centres", "inverted-box"],
)
def test_rbf_grid_refuses_bad_settings_by_name(kwargs, argument):
    """Bad grid settings raise a ValueError naming the argument."""
    with pytest.raises(ValueError, match=argument):
        RBFGrid(**{"low": (0, 0), "high": (5, 5), **kwargs})
