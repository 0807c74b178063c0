"""Pictures of the maze: target cell in green, walls in black, overlays drawn."""

import numpy as np

from envs import SharedDynamicsMaze
from envs.dynamics import DEFAULT_WALLS
from envs.rendering import render_maze, save_maze_png

SIZE = 400
PIXELS_PER_UNIT = SIZE / 5


def pixel(image, x, y):
    """The pixel of the point (x, y): the picture fills the whole image, y pointing down."""
    return image[int(y * PIXELS_PER_UNIT), int(x * PIXELS_PER_UNIT)].astype(int)


def is_green(rgb):
    return rgb[1] > 150 and rgb[1] > rgb[0] + 30 and rgb[1] > rgb[2] + 30


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


def test_trajectory_is_drawn_in_blue():
    """The trajectory since reset appears as blue pixels."""
    env = SharedDynamicsMaze(task=(5, 5), render_mode="rgb_array", termination_prob=0.0)
    env.reset(seed=3)
    for _ in range(20):
        env.step(env.action_space.sample())
    image = env.render().astype(int)
    blue = (image[..., 2] > 150) & (image[..., 0] < 100) & (image[..., 1] < 100)
    assert blue.sum() > 200


def test_heat_map_and_policy_arrows_overlays():
    """A value per cell is drawn green where high, and policy arrows in red."""
    values = np.zeros((5, 5))
    values[4, 0] = 1.0  # cell (5, 1), top right
    image = render_maze(DEFAULT_WALLS, cell_values=values, policy=np.zeros((5, 5), dtype=int), size_px=SIZE)
    assert is_green(pixel(image, 4.8, 0.2)) and not is_green(pixel(image, 0.2, 0.2))
    red = (image[..., 0] > 180) & (image[..., 1] < 80) & (image[..., 2] < 80)
    assert red.sum() > 100


def test_state_value_heat_map_and_png_file(tmp_path):
    """A value per state on a grid is drawn as a heat map, and save_maze_png writes a PNG."""
    values = np.zeros((50, 50))
    values[:25, :25] = 2.0  # the top left quarter
    image = render_maze((), state_values=values, size_px=SIZE)
    assert is_green(pixel(image, 1.0, 1.0)) and not is_green(pixel(image, 4.0, 4.0))
    path = tmp_path / "maze.png"
    save_maze_png(path, DEFAULT_WALLS, target_cells=[(1, 1)], title="tau_11")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
