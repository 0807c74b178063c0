"""Feature maps in normalised coordinates: scale-free, per-dimension widths, sizes that fit, by dimension."""

import math
import pickle

import numpy as np
import pytest

from sb3_trlsd.feature_choice import (
    ADAPTIVE_MAX_FEATURES,
    ADDITIVE_PER_DIM,
    MEMORY_BOUND_BYTES,
    PAPER_OVERLAP,
    check_feature_memory,
    default_kernel_width,
    grid_counts,
    make_feature_map,
    spacing_widths,
)
from sb3_trlsd.feature_maps import AdditiveRBF, RandomFourierFeatures, RBFGrid


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
@pytest.mark.parametrize("kind", ["paper", "rbf", "fourier"])
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
    if kind == "fourier" or (kind == "paper" and dims > 3):
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


# What make_feature_map gave before per-dimension counts and widths existed: the paper's reproduction pins
# these maps, so they may not move (beyond rounding).
TODAY_2D_STATES = np.array([[1.3, -0.4], [7.9, 2.6]])
TODAY_CASES = [
    (
        {"kind": "paper", "low": (0, -1), "high": (10, 4)},
        TODAY_2D_STATES,
        [0, 6, 12, 24],
        [
            [0.6661436107034878, 4.7923257527022e-09, 6.649679292198815e-39, 9.186226576586354e-164],
            [1.6424776768138537e-117, 2.9775484693700807e-57, 1.0411039847077813e-18, 9.132556359306549e-07],
        ],
    ),
    (
        {"kind": "paper", "low": np.zeros(6), "high": np.arange(1.0, 7.0), "seed": 3},
        np.linspace(0, 1, 12).reshape(2, 6),
        [0, 1, 150, 299],
        [
            [-0.03586756934162701, 0.0006581672776268616, -0.06672989657994359, 0.03873501463571625],
            [0.08061245726777648, -0.08162245510003013, 0.012317372559431683, 0.03854671622371699],
        ],
    ),
    (
        {"kind": "fourier", "low": (0, -1), "high": (10, 4), "seed": 5, "rbf_sigma": (0.1, 0.3)},
        TODAY_2D_STATES,
        [0, 57, 99],
        [
            [-0.05604918710731885, 0.14112647997582875, -0.13840427722079077],
            [-0.12444655763670831, 0.14124053126938718, 0.11272845961935594],
        ],
    ),
    (
        {"kind": "rbf", "low": (0, 0, 0), "high": (1, 2, 3), "rbf_per_dim": 4},
        np.array([[0.3, 1.1, 2.9]]),
        [0, 21, 63],
        [[1.3181798505859926e-80, 2.7843216553153665e-34, 2.3875388636581573e-39]],
    ),
]


@pytest.mark.parametrize(
    "case", range(len(TODAY_CASES)), ids=["paper-2d", "paper-6d", "fourier-2d", "rbf-3d"]
)
def test_the_papers_maps_are_unchanged(case):
    """The maps the paper's reproduction pins ("paper": the grid up to 125 centres a fifth of the spacing
    wide, else Fourier features) give the numbers they gave before per-dimension counts and widths."""
    kwargs, states, columns, expected = TODAY_CASES[case]
    kwargs = dict(kwargs)
    kind = kwargs.pop("kind")
    features = make_feature_map(kind, **kwargs)
    np.testing.assert_allclose(features(states)[:, columns], expected, rtol=1e-12, atol=1e-15)


def test_the_papers_2d_map_is_eq_11_with_a_fifth_of_the_spacing():
    """The paper's 2-D map is 5 x 5 RBFs of width 0.2 / 5 of each side, by hand, equal to the grid."""
    low, high = np.array([0.0, -1.0]), np.array([10.0, 4.0])
    features = make_feature_map("paper", low, high)
    assert features == RBFGrid(tuple(low), tuple(high), 5, 0.04)
    axes = [low[i] + (np.arange(5) + 0.5) * (high[i] - low[i]) / 5 for i in range(2)]
    widths = 0.04 * (high - low)
    by_hand = np.exp(
        -((TODAY_2D_STATES[:, 0, None, None] - axes[0][None, :, None]) ** 2) / (2 * widths[0] ** 2)
        - ((TODAY_2D_STATES[:, 1, None, None] - axes[1][None, None, :]) ** 2) / (2 * widths[1] ** 2)
    ).reshape(2, 25)
    np.testing.assert_allclose(features(TODAY_2D_STATES), by_hand, rtol=1e-12, atol=0)


def test_a_floor_gets_centres_in_proportion_to_its_sides_when_asked():
    """A 20 m x 5 m floor with rbf_per_dim="box": 4x the centres along its length, square cells in metres."""
    grid = make_feature_map("rbf", (0, 0), (20, 5), rbf_per_dim="box", max_features=125, rbf_overlap=0.7)
    assert isinstance(grid, RBFGrid) and grid.counts == (21, 5) and grid.n_features == 105
    spacings = [np.diff(axis)[0] for axis in grid.axes]
    assert 0.8 < spacings[0] / spacings[1] < 1.2
    np.testing.assert_allclose(grid.widths, 0.7 * np.array(spacings), rtol=1e-12)
    cube = make_feature_map("rbf", (0, 0), (20, 5), rbf_per_dim="cube", max_features=125)
    assert cube.counts == (11, 11)  # in normalised coordinates: the same count in both


def test_a_grid_takes_one_count_per_dimension():
    """n_per_dim=(4, 2, 3): 24 centres, the axes of each dimension its own, the first varying slowest."""
    grid = RBFGrid((0, 0, -1), (4, 1, 2), n_per_dim=(4, 2, 3), sigma=(0.1, 0.2, 0.3))
    assert grid.counts == (4, 2, 3) and grid.n_features == 24 and grid.n_per_dim == (4, 2, 3)
    np.testing.assert_allclose(grid.axes[0], [0.5, 1.5, 2.5, 3.5])
    np.testing.assert_allclose(grid.axes[2], [-0.5, 0.5, 1.5])
    np.testing.assert_allclose(
        grid.centres[:4], [[0.5, 0.25, -0.5], [0.5, 0.25, 0.5], [0.5, 0.25, 1.5], [0.5, 0.75, -0.5]]
    )
    states = np.array([[3.1, 0.2, 0.0], [0.4, 0.9, 1.7]])
    widths = np.array(grid.widths)
    direct = np.exp(-(((states[:, None, :] - grid.centres[None]) / widths) ** 2).sum(-1) / 2)
    np.testing.assert_allclose(grid(states), direct, rtol=1e-12)
    assert RBFGrid((0, 0), (1, 1), n_per_dim=(3, 3)) == RBFGrid((0, 0), (1, 1), n_per_dim=3)


def test_widths_tied_to_the_spacing_are_per_dimension():
    """rbf_overlap c: width c / n_i of the box along dimension i, i.e. c spacings in state units."""
    grid = make_feature_map("rbf", (0, 0), (8, 3), rbf_per_dim=(8, 2), rbf_overlap=0.7)
    assert grid.sigma == spacing_widths((8, 2), 0.7) == (0.7 / 8, 0.35)
    np.testing.assert_allclose(grid.widths, (0.7, 1.05), rtol=1e-12)
    assert spacing_widths((5, 5), PAPER_OVERLAP) == (0.04, 0.04)  # the paper's, bit for bit
    additive = make_feature_map("additive", (0, 0), (8, 3), rbf_per_dim=(8, 2), rbf_overlap=1.0)
    np.testing.assert_allclose(additive.widths, (1.0, 1.5), rtol=1e-12)


def test_additive_features_are_each_dimensions_gaussians_side_by_side():
    """AdditiveRBF: the n_1 Gaussians of s_1, then the n_2 of s_2, by hand."""
    features = AdditiveRBF((0, 10), (2, 20), n_per_dim=(2, 3), sigma=(0.25, 0.1))
    states = np.array([[0.3, 12.0], [1.9, 19.0]])
    first = np.exp(-((states[:, :1] - [0.5, 1.5]) ** 2) / (2 * 0.5**2))
    second = np.exp(-((states[:, 1:] - [10 + 5 / 3, 15, 20 - 5 / 3]) ** 2) / (2 * 1.0**2))
    np.testing.assert_allclose(features(states), np.hstack([first, second]), rtol=1e-12)
    assert features.n_features == 5
    restored = pickle.loads(pickle.dumps(features))
    np.testing.assert_array_equal(restored(states), features(states))


@pytest.mark.parametrize("shape", ["cube", "box"])
@pytest.mark.parametrize("additive", [False, True], ids=["grid", "additive"])
def test_grid_counts_stay_within_the_budget_and_at_least_two_per_dimension(shape, additive):
    """For d = 1..14 and budgets 30..400 the counts fit the budget, and one more centre would not."""
    rng = np.random.default_rng(0)
    for dims in range(1, 15):
        for budget in (30, 150, 400):
            low = rng.uniform(-5, 5, dims)
            high = low + rng.uniform(0.1, 100, dims)
            size = sum if additive else math.prod
            if size([2] * dims) > budget:
                with pytest.raises(ValueError, match="max_features"):
                    grid_counts(low, high, budget, shape=shape, additive=additive)
                continue
            counts = grid_counts(low, high, budget, shape=shape, additive=additive)
            assert len(counts) == dims and min(counts) >= 2 and size(counts) <= budget
            if shape == "cube":
                assert max(counts) - min(counts) <= 1


@pytest.mark.parametrize("dims", [1, 2, 3, 4, 6, 8, 10, 14])
@pytest.mark.parametrize("kind", ["auto", "additive"])
def test_the_scalable_maps_stay_within_their_budget_as_the_dimension_grows(kind, dims):
    """ "auto" and "additive" have at most ADAPTIVE_MAX_FEATURES features in any dimension up to 14."""
    features = make_feature_map(
        kind, np.zeros(dims), np.arange(1.0, dims + 1), n_actions=2 * dims, n_tasks=25
    )
    assert features.n_features <= ADAPTIVE_MAX_FEATURES
    assert min(features.counts) >= 2
    if isinstance(features, AdditiveRBF) and ADDITIVE_PER_DIM * dims <= ADAPTIVE_MAX_FEATURES:
        assert features.counts == (ADDITIVE_PER_DIM,) * dims  # 8 a dimension while the budget allows
    elif isinstance(features, AdditiveRBF):  # then as many as the budget allows, alike within one
        assert max(features.counts) - min(features.counts) <= 1
        assert features.n_features > ADAPTIVE_MAX_FEATURES - dims
    else:
        assert kind == "auto" and dims <= 4 and min(features.counts) >= 3
    phi = features(unit_states(5, dims))
    assert phi.shape == (5, features.n_features) and np.all(np.isfinite(phi))


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"kind": "rbf", "rbf_per_dim": (3, 3, 3)}, "rbf_per_dim"),
        ({"kind": "additive", "rbf_per_dim": (3,)}, "rbf_per_dim"),
        ({"kind": "rbf", "rbf_per_dim": (3, 0)}, "rbf_per_dim"),
        ({"kind": "rbf", "rbf_per_dim": "square"}, "rbf_per_dim"),
        ({"kind": "rbf", "rbf_overlap": 0.0}, "rbf_overlap"),
        ({"kind": "rbf", "rbf_overlap": 0.5, "rbf_sigma": 0.1}, "rbf_overlap"),
        ({"kind": "fourier", "rbf_overlap": 0.5}, "rbf_overlap"),
        ({"kind": "rbf", "rbf_per_dim": "cube", "max_features": 3}, "max_features"),
        ({"kind": "auto", "max_features": 0}, "max_features"),
    ],
    ids=[
        "three-counts-in-2d",
        "one-count-in-2d",
        "zero-count",
        "unknown-shape",
        "zero-overlap",
        "overlap-and-sigma",
        "overlap-of-fourier",
        "budget-below-two-per-dim",
        "zero-budget",
    ],
)
def test_bad_counts_widths_and_budgets_are_refused_by_name(kwargs, argument):
    kwargs = dict(kwargs)
    with pytest.raises(ValueError, match=argument):
        make_feature_map(kwargs.pop("kind"), (0, 0), (1, 1), **kwargs)
    if kwargs.get("rbf_per_dim") == (3, 3, 3):
        with pytest.raises(ValueError, match="n_per_dim"):
            RBFGrid((0, 0), (1, 1), n_per_dim=(3, 3, 3))


def test_a_lattice_puts_one_rbf_on_each_integer_point():
    """On (row, col) in 0..10 x 0..3: 44 RBFs, one per point, 1 there and e^-2 at the next point (half a
    spacing wide), in the grid's order (the first coordinate slowest)."""
    lattice = make_feature_map("lattice", (0, 0), (10, 3))
    assert isinstance(lattice, RBFGrid) and lattice.n_features == 44
    points = np.array([[0.0, 0.0], [4.0, 2.0], [10.0, 3.0]])
    phi = lattice(points)
    np.testing.assert_array_equal(phi.argmax(axis=1), [0, 4 * 4 + 2, 43])
    np.testing.assert_allclose(phi.max(axis=1), 1.0)
    np.testing.assert_allclose(phi[1, 4 * 4 + 3], math.exp(-2), rtol=1e-12)  # (4, 3), one point away
    wider = make_feature_map("lattice", (0, 0), (10, 3), rbf_overlap=1.0)
    np.testing.assert_allclose(wider(points)[1, 4 * 4 + 3], math.exp(-0.5), rtol=1e-12)


def test_a_lattice_beyond_the_budget_is_added_and_bad_lattices_are_refused():
    """13 x 13 positions and 12 flags in {0, 1} (four-room's states): 13 + 13 + 12 x 2 Gaussians side by side.
    Bounds that are not integers, or counts and widths given, are refused naming what to give."""
    lattice = make_feature_map("lattice", (0,) * 14, (12, 12) + (1,) * 12)
    assert isinstance(lattice, AdditiveRBF) and lattice.n_features == 50
    assert isinstance(make_feature_map("lattice", (0, 0, 0), (4, 4, 4)), RBFGrid)  # 125 points
    assert isinstance(make_feature_map("lattice", (0, 0, 0), (5, 4, 4)), AdditiveRBF)  # 150
    assert isinstance(make_feature_map("lattice", (0, 0, 0), (5, 4, 4), max_features=150), RBFGrid)
    with pytest.raises(ValueError, match=r"integer state bounds .* state_bounds"):
        make_feature_map("lattice", (0, 0), (1.5, 2))
    with pytest.raises(ValueError, match="leave rbf_per_dim and rbf_sigma unset"):
        make_feature_map("lattice", (0, 0), (3, 3), rbf_per_dim=4)
    for kind, integers in [("lattice", False), ("auto", True)]:
        with pytest.raises(ValueError, match="max_features must be an integer"):
            make_feature_map(kind, (0, 0), (3, 3), max_features=0.5, integer_states=integers)


def test_auto_takes_the_lattice_on_integer_states_it_can_cover():
    """Integer states (a Box of an integer dtype) within MAX_GRID_FEATURES lattice points get one RBF per
    point; beyond it, or with counts or widths given, or real states, "auto" is what it is on any states."""
    on_integers = make_feature_map("auto", (0, 0), (10, 10), integer_states=True)
    assert isinstance(on_integers, RBFGrid) and on_integers.n_features == 121
    np.testing.assert_array_equal(on_integers.centres, make_feature_map("lattice", (0, 0), (10, 10)).centres)
    for kwargs in [
        {"low": (0, 0), "high": (100, 100), "integer_states": True},  # 10,201 points
        {"low": (0, 0), "high": (10, 10), "integer_states": True, "rbf_per_dim": 8},
        {"low": (0, 0), "high": (10, 10), "integer_states": True, "max_features": 64},
        {"low": (0, 0), "high": (10.5, 10), "integer_states": True},
    ]:
        low, high = kwargs.pop("low"), kwargs.pop("high")
        real = {key: value for key, value in kwargs.items() if key != "integer_states"}
        expected = make_feature_map("auto", low, high, **real)
        got = make_feature_map("auto", low, high, **kwargs)
        assert type(got) is type(expected) and got.n_features == expected.n_features
