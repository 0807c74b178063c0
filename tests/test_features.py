"""RBF features and similarities (eq. 3, 6, 7, 11)."""

import numpy as np
import pytest

from sb3_trlsd.features import (
    RBFGrid,
    feature_similarity,
    gaussian_similarity,
    grid_centres,
    rbf_features,
    state_action_features,
)


def test_maze_grid_centres_are_the_papers_in_task_order():
    """5x5 centres at (i - 0.5, j - 0.5), index 5 (i - 1) + (j - 1) as the maze's task index."""
    centres = grid_centres(np.zeros(2), np.full(2, 5.0), 5)
    assert centres.shape == (25, 2)
    np.testing.assert_allclose(centres[0], [0.5, 0.5])
    np.testing.assert_allclose(centres[5 * (2 - 1) + (4 - 1)], [1.5, 3.5])


def test_rbf_grid_equals_eq_11_and_is_one_at_its_centres():
    """The separable grid evaluation equals exp(-||s - s_ij||^2 / 2 sigma^2) for every centre."""
    grid = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.2)
    states = np.random.default_rng(0).uniform(0, 5, size=(200, 2))
    direct = np.exp(-((states[:, None, :] - grid.centres[None]) ** 2).sum(-1) / (2 * 0.2**2))
    np.testing.assert_allclose(grid(states), direct, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(rbf_features(states, grid.centres, 0.2), direct, rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(np.diag(grid(grid.centres)), 1.0)


def test_state_action_features_are_eq_3_blocks():
    """Phi(s, a) holds Phi(s) in block a and zeros elsewhere."""
    phi = np.arange(6.0).reshape(2, 3) + 1
    blocks = state_action_features(phi, np.array([2, 0]), n_actions=4)
    np.testing.assert_array_equal(blocks[0], [0, 0, 0, 0, 0, 0, 1, 2, 3, 0, 0, 0])
    np.testing.assert_array_equal(blocks[1], [4, 5, 6] + [0] * 9)


def test_similarities_equal_eq_6_and_eq_7_by_hand():
    """S_S on states and S_Phi on features, against a hand computation."""
    a, b = np.array([[0.0, 0.0]]), np.array([[0.3, 0.4]])
    assert gaussian_similarity(a, b, 0.5)[0, 0] == pytest.approx(np.exp(-0.25 / (2 * 0.25)))
    grid = RBFGrid(low=(0, 0), high=(5, 5))
    distance = np.sum((grid(a) - grid(b)) ** 2)
    assert feature_similarity(grid(a), grid(b), 0.2)[0, 0] == pytest.approx(np.exp(-distance / 0.08))


def test_rbf_grid_refuses_a_non_positive_sigma():
    """sigma <= 0 is named in the error."""
    with pytest.raises(ValueError, match="sigma"):
        RBFGrid(low=(0, 0), high=(5, 5), sigma=0.0)
