"""The maze's shared dynamics P as plain vectorised functions over ``(n, 2)`` states (paper, section 4).

A move is 1 along the action's axis plus N(0, 0.5) noise on it and N(0, 0.25) on the other axis. Walls
are segments on the integer grid; the outer square is one too. A move stops where its straight path
first meets a wall and is pushed back from that wall by U(0.1, 0.5) along the wall's normal, into the
side it came from; this repeats, with the move from the start to the pushed-back point, until the move
crosses no wall.

What "meets a wall" (or "crosses" it) means: the segment from p to q meets the wall when p and q lie
strictly on opposite sides of the wall's line, or q lies on the line and p does not, and the point where
the segment reaches the line lies on the wall's closed segment (its end points included). So:

- a move *ending* exactly on a wall hits it;
- a state lying exactly on a wall's line does not hit that wall, whichever way it moves away;
- a move along a wall's line never hits that wall;
- a move through a wall's end point hits it, a move passing beyond the end point does not.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

__all__ = [
    "ACTION_DIRECTIONS",
    "DEFAULT_WALLS",
    "EAST",
    "MAZE_SIZE",
    "NORTH",
    "SOUTH",
    "WEST",
    "cell_noise_stds",
    "cell_of",
    "cell_task",
    "first_wall_hits",
    "make_walls",
    "maze_step",
    "reward_noise_scales",
    "segment_crosses_walls",
]

NORTH, WEST, SOUTH, EAST = 0, 1, 2, 3
# Unit displacement (dx, dy) of each action; y grows southwards (downwards on pictures).
ACTION_DIRECTIONS = np.array([[0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
MAZE_SIZE = 5
# The first author's later 5x5 maze: x = 3 for y in [0, 3] and x = 4 for y in [2, 4].
DEFAULT_WALLS = (((3, 0), (3, 3)), ((4, 2), (4, 4)))
BORDER = (((0, 0), (5, 0)), ((5, 0), (5, 5)), ((0, 5), (5, 5)), ((0, 0), (0, 5)))
REBOUND_LOW, REBOUND_HIGH = 0.1, 0.5
# A few rebounds always suffice (each one shortens the move, or turns it back inside the band of width
# 0.5 along the wall, where no other wall is met); the cap turns a bug into an error, not a hang.
MAX_REBOUNDS = 64


def as_segments(walls: Iterable | np.ndarray) -> np.ndarray:
    """The walls as an ``(m, 4)`` float array, or a ValueError naming ``walls`` for any other shape."""
    try:
        segments = np.asarray(walls if isinstance(walls, np.ndarray) else list(walls), dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"walls must be a list of segments ((x0, y0), (x1, y1)), got {walls!r}") from error
    if segments.size == 0:
        return np.zeros((0, 4))
    if segments.shape[1:] not in ((2, 2), (4,)):
        raise ValueError(
            "walls must be a list of segments ((x0, y0), (x1, y1)) or an (m, 4) array, "
            f"got an array of shape {segments.shape}"
        )
    return segments.reshape(-1, 4)


def make_walls(walls: Iterable | np.ndarray = DEFAULT_WALLS) -> np.ndarray:
    """
    Validate a wall layout and add the outer square.

    :param walls: axis-aligned segments ``((x0, y0), (x1, y1))`` with integer ends in [0, 5], or an
        ``(m, 4)`` array of them (the output of this function is accepted too); ``()`` for an open grid
    :return: ``(k, 4)`` array of distinct segments ``x0, y0, x1, y1`` with ``x0 <= x1`` and ``y0 <= y1``,
        the four sides of the square included
    :raises ValueError: naming ``walls`` for a segment off the grid, diagonal, or of zero length
    """
    segments = as_segments(walls)
    for x0, y0, x1, y1 in segments:
        text = f"(({x0:g}, {y0:g}), ({x1:g}, {y1:g}))"
        ends = np.array([x0, y0, x1, y1])
        if not np.all(np.isfinite(ends)) or np.any(np.round(ends) != ends):
            raise ValueError(f"walls must lie on the integer grid (cell boundaries), got {text}")
        if ends.min() < 0 or ends.max() > MAZE_SIZE:
            raise ValueError(f"walls must lie within [0, {MAZE_SIZE}]^2, got {text}")
        if (x0 == x1) == (y0 == y1):
            raise ValueError(f"walls must be axis-aligned segments of non-zero length, got {text}")
    segments = np.concatenate([np.asarray(BORDER, dtype=np.float64).reshape(-1, 4), segments])
    lows, highs = np.minimum(segments[:, :2], segments[:, 2:]), np.maximum(segments[:, :2], segments[:, 2:])
    # Distinct rows, so that passing a layout through twice (env -> renderer) changes nothing.
    return np.unique(np.concatenate([lows, highs], axis=1), axis=0)


def _wall_normal_axes(walls: np.ndarray) -> np.ndarray:
    """The axis each wall is perpendicular to: 0 for a wall ``x = c``, 1 for a wall ``y = c``, shape (m,)."""
    return (walls[:, 0] != walls[:, 2]).astype(np.intp)


def first_wall_hits(starts: np.ndarray, ends: np.ndarray, walls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Where each straight move first meets a wall, in the sense of the module's docstring.

    :param starts: p, shape (n, 2)
    :param ends: q, shape (n, 2)
    :param walls: (m, 4) from :func:`make_walls`
    :return: ``t`` (n,), the fraction of the move at the first hit (``inf`` when none), and the index of
        the wall hit (n,) (meaningless where ``t`` is ``inf``)
    """
    axis = _wall_normal_axes(walls)  # (m,)
    other = 1 - axis
    columns = np.arange(len(walls))
    line, span_low, span_high = walls[columns, axis], walls[columns, other], walls[columns, 2 + other]
    before = starts[:, axis] - line  # signed distances of p to each wall's line, (n, m)
    after = ends[:, axis] - line
    # Decided by signs, not by t > 0: t underflows to 0 for a start a denormal away from a wall.
    meets = (np.sign(before) * np.sign(after) < 0) | ((after == 0) & (before != 0))
    # Where the line is met, |before| <= |before - after| holds after rounding too, so t is in [0, 1].
    t = np.divide(before, before - after, out=np.zeros_like(before), where=meets)
    crossing = starts[:, other] + t * (ends[:, other] - starts[:, other])  # (n, m)
    hit_t = np.where(meets & (crossing >= span_low) & (crossing <= span_high), t, np.inf)
    first = hit_t.argmin(axis=1)
    return hit_t[np.arange(len(starts)), first], first


def segment_crosses_walls(starts: np.ndarray, ends: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """
    Whether each straight move meets a wall, in the sense of the module's docstring.

    :param starts: p, shape (n, 2) or (2,)
    :param ends: q, same shape
    :param walls: (m, 4) from :func:`make_walls`
    :return: (n,) booleans
    """
    t, _ = first_wall_hits(np.atleast_2d(starts), np.atleast_2d(ends), walls)
    return np.isfinite(t)


def _check_actions(actions: np.ndarray, n_states: int) -> None:
    """Raise a ValueError naming ``action`` unless there is one action in 0..3 per state."""
    if len(actions) != n_states:
        raise ValueError(f"actions must have one entry per state, got {len(actions)} for {n_states} states")
    if actions.size and (
        not np.issubdtype(actions.dtype, np.integer) or actions.min() < 0 or actions.max() > 3
    ):
        raise ValueError(
            f"action must be an integer in 0..3 (NORTH, WEST, SOUTH, EAST), got {np.unique(actions)}"
        )


Generators = np.random.Generator | Sequence[np.random.Generator]


def _normal_rows(rng: Generators, n: int) -> np.ndarray:
    """(n, 2) standard normal draws: from one generator, or the row's own generator for each row."""
    if isinstance(rng, np.random.Generator):
        return rng.normal(size=(n, 2))
    return np.array([generator.normal(size=2) for generator in rng]).reshape(n, 2)


def _uniform_rows(rng: Generators, low: float, high: float, rows: np.ndarray) -> np.ndarray:
    """U(low, high) draws for the given rows: from one generator, or each row's own."""
    if isinstance(rng, np.random.Generator):
        return rng.uniform(low, high, len(rows))
    return np.array([rng[row].uniform(low, high) for row in rows])


def maze_step(
    states: np.ndarray,
    actions: np.ndarray,
    rng: Generators,
    walls: np.ndarray,
    along_noise_std: float = 0.5,
    across_noise_std: float = 0.25,
) -> np.ndarray:
    """
    One step of the maze's dynamics for a batch of states.

    :param states: (n, 2) states in (0, 5)^2
    :param actions: (n,) actions in 0..3 (NORTH, WEST, SOUTH, EAST)
    :param rng: random generator of the move noise and the rebounds, or one per state (the states of
        several mazes stepped at once, each drawing from its own generator what a step of it alone draws)
    :param walls: (m, 4) from :func:`make_walls`
    :param along_noise_std: standard deviation of the noise along the action's axis
    :param across_noise_std: standard deviation of the noise on the other axis
    :return: next states (n, 2): strictly inside (0, 5)^2, and the move from ``states`` crosses no wall
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
    actions = np.asarray(actions).reshape(-1)
    _check_actions(actions, len(states))
    directions = ACTION_DIRECTIONS[actions]  # (n, 2)
    along = np.abs(directions)  # 1 on the action's axis, 0 on the other
    if not isinstance(rng, np.random.Generator) and len(rng) != len(states):
        raise ValueError(f"rng must be one generator or one per state, got {len(rng)} for {len(states)}")
    noise = _normal_rows(rng, len(states)) * (along * along_noise_std + (1 - along) * across_noise_std)
    ends = states + directions + noise
    # Rows whose move may still cross a wall: all of them at first, then those that rebounded.
    active = np.arange(len(states))
    for _ in range(MAX_REBOUNDS):
        t, wall = first_wall_hits(states[active], ends[active], walls)
        hit = np.isfinite(t)
        active, t, wall = active[hit], t[hit], wall[hit]
        if not len(active):
            break
        contact = states[active] + t[:, None] * (ends[active] - states[active])
        # Push back along the wall's normal, towards the side the move came from (the sign of the move
        # along the normal is never 0: the move changed sides of the wall's line).
        axis = _wall_normal_axes(walls[wall])
        rows = np.arange(len(active))
        direction = np.sign(ends[active, axis] - states[active, axis])
        rebound = _uniform_rows(rng, REBOUND_LOW, REBOUND_HIGH, active)
        contact[rows, axis] = walls[wall, axis] - direction * rebound
        ends[active] = contact
    assert not len(active), f"{len(active)} moves still crossed walls after {MAX_REBOUNDS} rebounds"
    return ends


def cell_of(states: np.ndarray) -> np.ndarray:
    """
    The cell of each state, as the paper's eq. 12 reads it.

    :param states: (n, 2) or (2,) states ``(x, y)``
    :return: (n, 2) integers ``(i, j) = (ceil(x), ceil(y))``, clipped to 1..5
    """
    cells = np.ceil(np.asarray(states, dtype=np.float64).reshape(-1, 2))
    return np.clip(cells, 1, MAZE_SIZE).astype(np.int64)


def cell_task(cells: np.ndarray) -> np.ndarray:
    """
    The task rewarding each cell: tau_ij (eq. 12) has index ``5 (i - 1) + (j - 1)``.

    :param cells: (n, 2) cells ``(i, j)`` from ``cell_of``
    :return: (n,) task indices
    """
    return MAZE_SIZE * (cells[:, 0] - 1) + (cells[:, 1] - 1)


def cell_noise_stds(reward_noise_std: float | Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    """
    The standard deviation of the reward noise in each cell: one number for all of them (eq. 12), or a table
    with one per cell.

    :param reward_noise_std: a number >= 0, or a 5 x 5 table of them indexed ``[i - 1][j - 1]`` (cell
        ``(i, j)``, ``i = ceil(x)``, ``j = ceil(y)``: a row per column x of the maze)
    :return: (5, 5) float64, indexed ``[i - 1, j - 1]``
    :raises ValueError: naming ``reward_noise_std`` for anything else (negative, NaN or another shape)
    """
    try:
        stds = np.asarray(reward_noise_std, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"reward_noise_std must be a number >= 0 or a {MAZE_SIZE} x {MAZE_SIZE} table of them, "
            f"got {reward_noise_std!r}"
        ) from error
    valid = np.all(stds >= 0) and np.all(np.isfinite(stds))
    if stds.shape not in ((), (MAZE_SIZE, MAZE_SIZE)) or not valid:
        raise ValueError(
            f"reward_noise_std must be a finite number >= 0 or a {MAZE_SIZE} x {MAZE_SIZE} table of them "
            f"(one per cell, [i - 1][j - 1]), got {reward_noise_std!r}"
        )
    return np.broadcast_to(stds, (MAZE_SIZE, MAZE_SIZE)).copy()


def reward_noise_scales(states: np.ndarray, stds: np.ndarray) -> np.ndarray:
    """
    The standard deviation of the reward noise at each state: that of its cell (eq. 12 reads cells as
    ``cell_of``).

    :param states: (n, 2) states
    :param stds: (5, 5) from ``cell_noise_stds``
    :return: (n,)
    """
    cells = cell_of(states)
    return stds[cells[:, 0] - 1, cells[:, 1] - 1]
