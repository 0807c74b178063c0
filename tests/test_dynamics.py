"""The maze's dynamics (envs/sb3_trlsd_envs/dynamics.py): move statistics, rebounds, no move across a wall."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from sb3_trlsd_envs.dynamics import (
    ACTION_DIRECTIONS,
    DEFAULT_WALLS,
    EAST,
    NORTH,
    WEST,
    cell_of,
    make_walls,
    maze_step,
    segment_crosses_walls,
)

OPEN = make_walls(())
MAZE = make_walls(DEFAULT_WALLS)
N = 20_000


@pytest.mark.parametrize("action", range(4), ids=["north", "west", "south", "east"])
def test_open_space_moves_have_the_papers_mean_and_noise(action):
    """
    From the centre of an open grid: 1 along the action's axis with std 0.5, 0 across with std 0.25.
    A move reaches the border only beyond 2.5 / 0.5 = 5 standard deviations, so rebounds are negligible.
    Tolerances: 5 standard errors of the mean (std / sqrt(N)) and of the standard deviation
    (std / sqrt(2 N)).
    """
    rng = np.random.default_rng(action)
    starts = np.full((N, 2), 2.5)
    moves = maze_step(starts, np.full(N, action), rng, OPEN) - starts
    along = np.flatnonzero(ACTION_DIRECTIONS[action])[0]
    across = 1 - along
    assert moves[:, along].mean() == pytest.approx(ACTION_DIRECTIONS[action][along], abs=5 * 0.5 / np.sqrt(N))
    assert moves[:, across].mean() == pytest.approx(0.0, abs=5 * 0.25 / np.sqrt(N))
    assert moves[:, along].std() == pytest.approx(0.5, abs=5 * 0.5 / np.sqrt(2 * N))
    assert moves[:, across].std() == pytest.approx(0.25, abs=5 * 0.25 / np.sqrt(2 * N))


def test_rebound_from_a_wall_lands_between_0_1_and_0_5_from_it():
    """
    Moving EAST by exactly 1 (no noise along) from x = 2.9 always meets the wall x = 3 (the noise across
    keeps y = 1.5 +- 0.25 within the wall's span [0, 3]: 6 standard deviations), stops and rebounds by
    U(0.1, 0.5), so x ends in [2.5, 2.9]. A failure means the rebound is drawn from the wrong law or
    measured from the wrong point.
    """
    rng = np.random.default_rng(0)
    starts = np.tile([2.9, 1.5], (N, 1))
    ends = maze_step(starts, np.full(N, EAST), rng, MAZE, along_noise_std=0.0)
    distances = 3.0 - ends[:, 0]
    assert distances.min() >= 0.1 and distances.max() <= 0.5
    # U(0.1, 0.5): mean 0.3, std 0.4 / sqrt(12); 5 standard errors.
    assert distances.mean() == pytest.approx(0.3, abs=5 * 0.4 / np.sqrt(12 * N))


def test_border_rebounds_stay_inside_the_square():
    """Moving NORTH by exactly 1 from y = 0.2 always hits the border y = 0 and rebounds into [0.1, 0.5]."""
    starts = np.tile([1.5, 0.2], (1000, 1))
    ends = maze_step(starts, np.full(1000, NORTH), np.random.default_rng(1), MAZE, along_noise_std=0.0)
    assert ends[:, 1].min() >= 0.1 and ends[:, 1].max() <= 0.5


@pytest.mark.parametrize(
    ("start", "end", "crosses"),
    [
        ((2.5, 1.5), (3.5, 1.5), True),
        ((2.5, 1.5), (3.0, 1.5), True),
        ((3.0, 1.5), (2.5, 1.5), False),
        ((3.0, 1.5), (3.5, 1.5), False),
        ((3.0, 0.5), (3.0, 2.5), False),
        ((2.5, 3.5), (3.5, 2.5), True),
        ((2.5, 3.5), (3.5, 3.2), False),
        ((2.5, 3.5), (3.0, 3.5), False),
        ((1.0, 1.0), (1.0, 0.0), True),
    ],
    ids=[
        "through",
        "ending-on-it",
        "leaving-its-line-backwards",
        "leaving-its-line-forwards",
        "along-its-line",
        "through-its-end-point",
        "beyond-its-end-point",
        "ending-on-its-line-beyond-it",
        "ending-on-the-border",
    ],
)
def test_touching_a_wall_counts_as_documented(start, end, crosses):
    """
    The touching cases of the dynamics module's docstring, on the wall x = 3 for y in [0, 3] (exact
    floats): a mismatch means the crossing test and its documentation disagree.
    """
    assert segment_crosses_walls(np.array(start), np.array(end), MAZE)[0] == crosses


def test_a_move_ending_exactly_on_a_wall_rebounds():
    """
    A noiseless EAST move from x = 2 ends exactly on the wall x = 3: it must rebound into [2.5, 2.9],
    not stay on the wall.
    """
    starts = np.tile([2.0, 1.5], (1000, 1))
    ends = maze_step(
        starts, np.full(1000, EAST), np.random.default_rng(4), MAZE, along_noise_std=0.0, across_noise_std=0.0
    )
    assert ends[:, 0].min() >= 2.5 and ends[:, 0].max() <= 2.9
    np.testing.assert_array_equal(ends[:, 1], 1.5)


@pytest.mark.parametrize(("action", "x"), [(EAST, 4.0), (WEST, 2.0)], ids=["east", "west"])
def test_a_state_on_a_wall_moves_away_freely(action, x):
    """From (3, 0.5), on the wall x = 3, a noiseless move either way is not stopped by that wall."""
    end = maze_step(
        np.array([[3.0, 0.5]]),
        np.array([action]),
        np.random.default_rng(5),
        MAZE,
        along_noise_std=0.0,
        across_noise_std=0.0,
    )
    np.testing.assert_array_equal(end, [[x, 0.5]])


def grid_walls():
    """Random layouts of unit-or-longer axis-aligned segments on the integer grid."""
    segment = st.tuples(st.booleans(), st.integers(0, 5), st.integers(0, 4), st.integers(1, 5)).map(
        lambda v: (
            ((v[1], v[2]), (v[1], min(5, v[2] + v[3])))
            if v[0]
            else ((v[2], v[1]), (min(5, v[2] + v[3]), v[1]))
        )
    )
    return st.lists(segment, max_size=8)


inside = st.floats(0.0, 5.0, exclude_min=True, exclude_max=True, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(x=inside, y=inside, action=st.integers(0, 3), seed=st.integers(0, 2**32 - 1))
def test_default_maze_moves_stay_inside_and_never_cross_a_wall(x, y, action, seed):
    """For any state and action, the next state is inside (0, 5)^2 and the move crosses no wall."""
    start = np.array([[x, y]])
    end = maze_step(start, np.array([action]), np.random.default_rng(seed), MAZE)
    assert np.all((end > 0) & (end < 5))
    assert not segment_crosses_walls(start, end, MAZE)[0]


@settings(max_examples=300, deadline=None)
@example(walls=[], x=1.0, y=5e-324, action=0, seed=3)  # a denormal from the border: t underflowed to 0
@given(
    walls=grid_walls(),
    x=inside,
    y=inside,
    action=st.integers(0, 3),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_wall_layouts_are_never_crossed(walls, x, y, action, seed):
    """
    The same invariant with any wall layout on the grid, for the drawn state and, in the same batch, 64
    random ones, half of them moved onto a grid line (states lying on a wall), so that rows colliding
    with different walls at once go through the vectorised rebounds together.
    """
    segments = make_walls(walls)
    rng = np.random.default_rng(seed)
    others = rng.uniform(0, 5, size=(64, 2))
    snap = np.arange(32), rng.integers(2, size=32)
    others[snap] = np.clip(np.round(others[snap]), 1, 4)
    starts = np.concatenate([[[x, y]], others])
    actions = np.concatenate([[action], rng.integers(4, size=64)])
    ends = maze_step(starts, actions, rng, segments)
    assert np.all((ends > 0) & (ends < 5))
    assert not segment_crosses_walls(starts, ends, segments).any()


def test_many_states_at_once_match_the_invariant():
    """The vectorised path (many rows colliding at different walls) keeps the invariant for every row."""
    rng = np.random.default_rng(3)
    starts = rng.uniform(0, 5, size=(50_000, 2))
    ends = maze_step(starts, rng.integers(4, size=50_000), rng, MAZE)
    assert np.all((ends > 0) & (ends < 5))
    assert not segment_crosses_walls(starts, ends, MAZE).any()


@pytest.mark.parametrize(
    "walls",
    [
        [((2.5, 0), (2.5, 3))],
        [((1, 1), (2, 2))],
        [((1, 1), (1, 1))],
        [((0, 0), (0, 7))],
        [((0, 0), (0, np.nan))],
        [(1, 2, 3)],
        ((3, 0), (3, 3)),
        [((3, 0), (3,))],
        "x=3",
    ],
    ids=[
        "off-grid",
        "diagonal",
        "zero-length",
        "outside",
        "nan",
        "three-numbers",
        "a-bare-segment",
        "ragged",
        "text",
    ],
)
def test_walls_off_the_grid_are_refused(walls):
    """A wall that is not an axis-aligned segment on the integer grid raises a ValueError naming walls."""
    with pytest.raises(ValueError, match="walls"):
        make_walls(walls)


def test_wall_layouts_are_normalised_and_idempotent():
    """
    Segments in either orientation, as tuples or as an (m, 4) array, give the same layout with the border;
    feeding it back changes nothing (the env passes its layout to the renderer).
    """
    walls = make_walls([((3, 3), (3, 0)), ((4, 2), (4, 4))])
    np.testing.assert_array_equal(walls, MAZE)
    np.testing.assert_array_equal(make_walls(np.array([[3, 0, 3, 3], [4, 4, 4, 2]])), MAZE)
    np.testing.assert_array_equal(make_walls(MAZE), MAZE)
    assert len(OPEN) == 4 and len(MAZE) == 6


def test_cells_are_ceilings_clipped_to_1_5():
    """cell_of is eq. 12's (ceil(x), ceil(y)), so a state on a cell boundary belongs to the lower cell."""
    states = np.array([[0.5, 4.2], [1.0, 2.0], [4.999, 0.001], [0.0, 5.0]])
    np.testing.assert_array_equal(cell_of(states), [[1, 5], [1, 2], [5, 1], [1, 5]])


def test_actions_outside_0_3_are_refused():
    """maze_step names the action when it is not one of the four."""
    with pytest.raises(ValueError, match="action"):
        maze_step(np.ones((1, 2)), np.array([4]), np.random.default_rng(0), MAZE)
