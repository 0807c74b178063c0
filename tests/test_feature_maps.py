"""Feature maps in normalised coordinates: scale-free, per-dimension widths, sizes that fit, by dimension."""

import pickle

import numpy as np
import pytest

from sb3_trlsd.feature_maps import (
    MEMORY_BOUND_BYTES,
    RandomFourierFeatures,
    RBFGrid,
    check_feature_memory,
    default_kernel_width,
    make_feature_map,
)


def unit_states(n, dims, seed=0):
    return np.random.default_rng(seed).uniform(0, 1, size=(n, dims))


@pytest.mark.parametrize("kind", ["rbf", "fourier"])
def test_a_scaled_and_shifted_box_gives_the_same_features(kind):
    """Widths are fractions of the box: states x 10 + 3 in a box x 10 + 3 have the original's features."""
    low, high = np.array([0.0, -1.0]), np.array([1.0, 2.0])
    original = make_feature_map(kind, low, high, seed=3)
    scaled = make_feature_map(kind, 10 * low + 3, 10 * high + 3, seed=3)
    states = low + unit_states(200, 2) * (high - low)
    np.testing.assert_allclose(scaled(10 * states + 3), original(states), rtol=1e-9, atol=1e-12)


def test_rbf_grid_takes_one_width_per_dimension():
    """With widths (0.04, 0.1) of a (5, 10) box, each dimension has its own Gaussian width in state units."""
    grid = RBFGrid((0, 0), (5, 10), n_per_dim=3, sigma=(0.04, 0.1))
    assert grid.widths == (0.2, 1.0)
    states = np.array([[1.0, 7.0], [4.2, 0.3]])
    expected = np.exp(
        -((states[:, None, 0] - grid.centres[None, :, 0]) ** 2) / (2 * 0.2**2)
        - ((states[:, None, 1] - grid.centres[None, :, 1]) ** 2) / (2 * 1.0**2)
    )
    np.testing.assert_allclose(grid(states), expected, rtol=1e-12)


def test_fourier_features_approximate_the_gaussian_kernel():
    """Phi(u) . Phi(u') -> exp(-||u - u'||^2 / 2 sigma^2); with m = 20,000 the error is ~1/sqrt(m) ~ 0.01."""
    features = RandomFourierFeatures((0,) * 3, (1,) * 3, m=20_000, sigma=0.3, seed=0)
    a, b = unit_states(30, 3, seed=1), unit_states(30, 3, seed=2)
    kernel = np.exp(-((a[:, None] - b[None]) ** 2).sum(-1) / (2 * 0.3**2))
    np.testing.assert_allclose(features(a) @ features(b).T, kernel, atol=0.05)
    assert features.n_features == 20_000
    restored = pickle.loads(pickle.dumps(features))
    np.testing.assert_array_equal(restored(a), features(a))


@pytest.mark.parametrize("dims", range(1, 9))
@pytest.mark.parametrize("kind", ["auto", "rbf", "fourier"])
def test_every_map_in_1_to_8_dimensions_fits_the_memory_bound_or_says_which_setting_to_change(kind, dims):
    """Built maps are within the bound; a grid too large to fit is refused before anything is allocated."""
    try:
        features = make_feature_map(kind, np.zeros(dims), np.ones(dims), n_actions=4, n_tasks=25)
    except ValueError as error:
        assert kind == "rbf" and 5**dims > 1_000  # only the grid grows exponentially
        assert "rbf_per_dim" in str(error) and "fourier" in str(error)
        return
    assert (8 + 25) * features.n_features**2 * 8 <= MEMORY_BOUND_BYTES
    phi = features(unit_states(7, dims))
    assert phi.shape == (7, features.n_features) and np.all(np.isfinite(phi))
    if kind == "fourier" or (kind == "auto" and dims > 3):
        assert isinstance(features, RandomFourierFeatures) and features.n_features == 50 * dims  # linear in d


def test_the_memory_check_names_the_setting():
    """The old failure (5^6 RBF centres, 5.46 GiB at construction) is now one clear error naming the fix."""
    with pytest.raises(ValueError, match=r"rbf_per_dim=5 on a 6-D state gives 15,625 features"):
        make_feature_map("rbf", np.zeros(6), np.ones(6), n_actions=3)
    check_feature_memory(100, 4, 25, "anything")  # small enough: no error


def test_the_default_width_covers_the_same_share_of_the_cube_in_every_dimension():
    """0.04 in 2-D (the paper's 0.2 on the maze); (width sqrt(2 pi))^d constant: wider in more dimensions."""
    assert default_kernel_width(2) == 0.04
    shares = [(default_kernel_width(d) * np.sqrt(2 * np.pi)) ** d for d in range(1, 9)]
    np.testing.assert_allclose(shares, shares[1], rtol=1e-12)


@pytest.mark.parametrize(
    ("call", "argument"),
    [
        (lambda: make_feature_map("tiles", (0,), (1,)), "feature_map"),
        (lambda: make_feature_map("rbf", (0,), (1,), rbf_per_dim=0), "rbf_per_dim"),
        (lambda: make_feature_map("fourier", (0,), (1,), fourier_features=0), "fourier_features"),
        (lambda: RBFGrid((0, 0), (1, 1), sigma=(0.1, 0.1, 0.1)), "sigma"),
        (lambda: RBFGrid((0, 0), (1, np.inf)), "finite"),
        (lambda: RandomFourierFeatures((0,), (1,), sigma=-1.0), "sigma"),
    ],
    ids=[
        "unknown-map",
        "no-centres",
        "no-fourier-features",
        "three-widths-in-2d",
        "infinite-box",
        "negative-width",
    ],
)
def test_bad_feature_settings_are_refused_by_name(call, argument):
    with pytest.raises(ValueError, match=argument):
        call()
