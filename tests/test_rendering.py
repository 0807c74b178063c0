"""Pictures of the maze: target cell in green, walls in black, overlays drawn."""

import subprocess
import sys

import numpy as np
import pytest

from sb3_trlsd_envs import EAST, NORTH, SOUTH, WEST, SharedDynamicsMaze
from sb3_trlsd_envs.dynamics import DEFAULT_WALLS
from sb3_trlsd_envs.rendering import render_maze, save_maze_png

SIZE = 400
PIXELS_PER_UNIT = SIZE / 5


def pixel(image, x, y):
    """The pixel of the point (x, y): the picture fills the whole image, y pointing down."""
    return image[int(y * PIXELS_PER_UNIT), int(x * PIXELS_PER_UNIT)].astype(int)


def is_green(rgb):
    return rgb[1] > 150 and rgb[1] > rgb[0] + 30 and rgb[1] > rgb[2] + 30


def red_mask(image):
    return (image[..., 0] > 180) & (image[..., 1] < 80) & (image[..., 2] < 80)


def test_rendered_env_shows_the_target_green_and_the_walls_black():
    """render() fills the target cell in green and draws the walls (and border) in black."""
    env = SharedDynamicsMaze(task=(1, 5), render_mode="rgb_array")
    env.reset(seed=0)
    image = env.render()
    assert image.shape == (SIZE, SIZE, 3) and image.dtype == np.uint8
    assert is_green(pixel(image, 0.5, 4.3))  # inside cell (1, 5), the bottom left one
    assert not is_green(pixel(image, 4.5, 0.5))
    for x, y in ((3.0, 1.5), (4.0, 3.0), (0.01, 2.5), (2.5, 4.99)):
        assert pixel(image, x, y).max() < 60, (x, y)  # interior walls and the border
    assert pixel(image, 2.0, 2.5).min() > 200  # open space stays white


def test_trajectory_is_drawn_in_blue_where_the_agent_went():
    """
    The trajectory since reset appears as blue pixels around each visited state (y pointing down), except
    under a wall: walls are drawn on top, so that a path running along a wall never seems to cross it.
    """
    env = SharedDynamicsMaze(task=(5, 5), render_mode="rgb_array", termination_prob=0.0)
    env.reset(seed=3)
    for _ in range(20):
        env.step(env.np_random.integers(4))
    image = env.render().astype(int)
    blue = (image[..., 2] > 150) & (image[..., 0] < 100) & (image[..., 1] < 100)
    assert blue.sum() > 200
    for x, y in env.trajectory:
        row, col = int(y * PIXELS_PER_UNIT), int(x * PIXELS_PER_UNIT)
        drawn = blue[max(row - 4, 0) : row + 5, max(col - 4, 0) : col + 5].any()
        assert drawn or image[row, col].max() < 60, (x, y)


def test_heat_map_and_policy_arrows_overlays():
    """A value per cell is drawn green where high, and policy arrows in red."""
    values = np.zeros((5, 5))
    values[4, 0] = 1.0  # cell (5, 1), top right
    image = render_maze(DEFAULT_WALLS, cell_values=values, policy=np.zeros((5, 5), dtype=int), size_px=SIZE)
    assert is_green(pixel(image, 4.8, 0.2)) and not is_green(pixel(image, 0.2, 0.2))
    assert red_mask(image).sum() > 100


@pytest.mark.parametrize(
    ("action", "towards"),
    [(NORTH, (0, -1)), (WEST, (-1, 0)), (SOUTH, (0, 1)), (EAST, (1, 0))],
    ids=["north-up", "west-left", "south-down", "east-right"],
)
def test_policy_arrows_point_the_way_the_action_moves(action, towards):
    """
    An arrow starts at the cell centre and points the way its action moves on the picture (NORTH up,
    since y points down): red beyond the centre on that side, none on the opposite side.
    """
    image = render_maze((), policy=np.full((5, 5), action), size_px=SIZE)
    red = red_mask(image)
    centre = np.array([2.5, 2.5]) * PIXELS_PER_UNIT  # cell (3, 3), as (col, row)
    ahead = (centre + 0.25 * PIXELS_PER_UNIT * np.array(towards)).astype(int)
    behind = (centre - 0.25 * PIXELS_PER_UNIT * np.array(towards)).astype(int)
    assert red[ahead[1] - 2 : ahead[1] + 3, ahead[0] - 2 : ahead[0] + 3].any()
    assert not red[behind[1] - 2 : behind[1] + 3, behind[0] - 2 : behind[0] + 3].any()


def test_heat_map_is_white_at_or_below_zero_and_greenest_at_the_maximum():
    """The documented normalisation: values clipped to [0, max], so negative estimates do not show."""
    values = np.zeros((5, 5))
    values[0, 0], values[1, 0], values[2, 0] = -3.0, 0.5, 1.0  # cells (1, 1), (2, 1), (3, 1)
    image = render_maze((), cell_values=values, size_px=SIZE)
    assert pixel(image, 0.5, 0.5).min() == 255 and pixel(image, 4.5, 4.5).min() == 255
    half, full = pixel(image, 1.5, 0.5), pixel(image, 2.5, 0.5)
    assert is_green(full) and np.all(full <= half) and np.any(full < half)


@pytest.mark.parametrize(
    ("overlay", "value"),
    [("cell_values", np.zeros((4, 5))), ("policy", np.zeros((5, 4))), ("policy", np.full((5, 5), 4))],
    ids=["cell-values-shape", "policy-shape", "policy-action"],
)
def test_malformed_overlays_raise_value_errors_naming_them(overlay, value):
    """An overlay of the wrong shape or with an action outside 0..3 is refused, not drawn wrongly."""
    with pytest.raises(ValueError, match=overlay):
        render_maze(DEFAULT_WALLS, **{overlay: value})


def test_importing_envs_does_not_import_matplotlib():
    """matplotlib is loaded only when drawing, so creating and stepping envs stays light."""
    code = "import sys, sb3_trlsd_envs; assert 'matplotlib' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_state_value_heat_map_and_png_file(tmp_path):
    """A value per state on a grid is drawn as a heat map, and save_maze_png writes a PNG."""
    values = np.zeros((50, 50))
    values[:25, :25] = 2.0  # the top left quarter
    image = render_maze((), state_values=values, size_px=SIZE)
    assert is_green(pixel(image, 1.0, 1.0)) and not is_green(pixel(image, 4.0, 4.0))
    path = tmp_path / "maze.png"
    save_maze_png(path, DEFAULT_WALLS, target_cells=[(1, 1)], title="tau_11")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
