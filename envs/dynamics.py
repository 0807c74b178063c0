"""The maze's shared dynamics P as plain vectorised functions over ``(n, 2)`` states (paper, section 4).

A move is 1 along the action's axis plus N(0, 0.5) noise on it and N(0, 0.25) on the other axis. Walls
are segments on the integer grid; the outer square is one too. A move stops where its straight path
first meets a wall and is pushed back from that wall by U(0.1, 0.5) along the wall's normal, into the
side it came from; this repeats, with the move from the start to the pushed-back point, until the move
crosses no wall.

What "meets a wall" means: the segment from p to q meets the wall when p and q lie strictly on opposite
sides of the wall's line, or q lies on it and p does not, and the crossing point lies on the wall's
(closed) segment. So a move *ending* exactly on a wall hits it, while a state lying exactly on a wall
line does not hit that wall whichever way it moves, and a move along a wall's line never hits it.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = [
    "ACTION_DIRECTIONS",
    "DEFAULT_WALLS",
    "EAST",
    "MAZE_SIZE",
    "NORTH",
    "SOUTH",
    "WEST",
    "cell_of",
    "first_wall_hits",
    "make_walls",
    "maze_step",
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
MAX_REBOUNDS = 64


def make_walls(walls: Iterable = DEFAULT_WALLS) -> np.ndarray:
    """
    Validate a wall layout and add the outer square.

    :param walls: axis-aligned segments ``((x0, y0), (x1, y1))`` with integer ends in [0, 5], or an
        ``(m, 4)`` array of them; ``()`` for an open grid
    :return: ``(m + 4, 4)`` array of ``x0, y0, x1, y1`` with ``x0 <= x1`` and ``y0 <= y1``
    :raises ValueError: naming ``walls`` for a segment off the grid, diagonal, or of zero length
    """
    segments = np.asarray(list(walls) if not isinstance(walls, np.ndarray) else walls, dtype=np.float64)
    segments = segments.reshape(-1, 4) if segments.size else np.zeros((0, 4))
    for x0, y0, x1, y1 in segments:
        text = f"(({x0:g}, {y0:g}), ({x1:g}, {y1:g}))"
        if not np.all(np.isfinite((x0, y0, x1, y1))) or np.any(
            np.round((x0, y0, x1, y1)) != (x0, y0, x1, y1)
        ):
            raise ValueError(f"walls must lie on the integer grid (cell boundaries), got {text}")
        if min(x0, y0, x1, y1) < 0 or max(x0, y0, x1, y1) > MAZE_SIZE:
            raise ValueError(f"walls must lie within [0, {MAZE_SIZE}]^2, got {text}")
        if (x0 == x1) == (y0 == y1):
            raise ValueError(f"walls must be axis-aligned segments of non-zero length, got {text}")
    segments = np.concatenate([np.asarray(BORDER, dtype=np.float64).reshape(-1, 4), segments])
    lows, highs = np.minimum(segments[:, :2], segments[:, 2:]), np.maximum(segments[:, :2], segments[:, 2:])
    return np.concatenate([lows, highs], axis=1)


def first_wall_hits(starts: np.ndarray, ends: np.ndarray, walls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Where each straight move first meets a wall.

    :param starts: p, shape (n, 2)
    :param ends: q, shape (n, 2)
    :param walls: (m, 4) from :func:`make_walls`
    :return: ``t`` (n,), the fraction of the move at the first hit (``inf`` when none), and the index of
        the wall hit (n,) (meaningless where ``t`` is ``inf``)
    """
    moves = ends - starts  # (n, 2)
    hit_t = np.full((len(starts), len(walls)), np.inf)  # (n, m)
    for axis in (0, 1):
        # Walls perpendicular to `axis`: constant coordinate `axis`, spanning the other one.
        other = 1 - axis
        on_axis = np.flatnonzero(walls[:, axis] == walls[:, 2 + axis])
        if not len(on_axis):
            continue
        line = walls[on_axis, axis]  # (k,)
        span_low, span_high = walls[on_axis, other], walls[on_axis, 2 + other]
        before = starts[:, axis : axis + 1] - line[None, :]  # signed distances to the lines, (n, k)
        after = ends[:, axis : axis + 1] - line[None, :]
        # Decided by signs, not by t > 0: t underflows to 0 for a start a denormal away from a wall.
        meets = ((np.sign(before) * np.sign(after) < 0) | ((after == 0) & (before != 0))) & (before != after)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.clip(before / (before - after), 0.0, 1.0)  # (n, k)
        crossing = starts[:, other : other + 1] + t * moves[:, other : other + 1]
        valid = meets & (crossing >= span_low) & (crossing <= span_high)
        hit_t[:, on_axis] = np.where(valid, t, np.inf)
    first = hit_t.argmin(axis=1)
    return hit_t[np.arange(len(starts)), first], first


def segment_crosses_walls(starts: np.ndarray, ends: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Whether each straight move from ``starts`` to ``ends`` meets a wall, shape (n,)."""
    t, _ = first_wall_hits(np.atleast_2d(starts), np.atleast_2d(ends), walls)
    return np.isfinite(t)


def maze_step(
    states: np.ndarray,
    actions: np.ndarray,
    rng: np.random.Generator,
    walls: np.ndarray,
    along_noise_std: float = 0.5,
    across_noise_std: float = 0.25,
) -> np.ndarray:
    """
    One step of the maze's dynamics for a batch of states.

    :param states: (n, 2) states in (0, 5)^2
    :param actions: (n,) actions in 0..3 (NORTH, WEST, SOUTH, EAST)
    :param rng: random generator of the move noise and the rebounds
    :param walls: (m, 4) from :func:`make_walls`
    :param along_noise_std: standard deviation of the noise along the action's axis
    :param across_noise_std: standard deviation of the noise on the other axis
    :return: next states (n, 2)
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
    actions = np.asarray(actions).reshape(-1)
    if len(actions) != len(states):
        raise ValueError(
            f"actions must have one entry per state, got {len(actions)} for {len(states)} states"
        )
    if actions.size and (
        not np.issubdtype(actions.dtype, np.integer) or actions.min() < 0 or actions.max() > 3
    ):
        raise ValueError(
            f"action must be an integer in 0..3 (NORTH, WEST, SOUTH, EAST), got {np.unique(actions)}"
        )
    directions = ACTION_DIRECTIONS[actions]  # (n, 2)
    along = np.abs(directions)  # 1 on the action's axis, 0 on the other
    noise = rng.normal(size=(len(states), 2)) * (along * along_noise_std + (1 - along) * across_noise_std)
    ends = states + directions + noise
    # Rows whose move may still cross a wall; each rebound shortens the move, so this ends.
    active = np.arange(len(states))
    for _ in range(MAX_REBOUNDS):
        t, wall = first_wall_hits(states[active], ends[active], walls)
        hit = np.isfinite(t)
        if not hit.any():
            return ends
        active, t, wall = active[hit], t[hit], wall[hit]
        contact = states[active] + t[:, None] * (ends[active] - states[active])
        # The wall is perpendicular to `axis`; push back along it, towards the side the move came from.
        axis = (walls[wall, 0] != walls[wall, 2]).astype(np.int64)
        rows = np.arange(len(active))
        direction = np.sign(ends[active, axis] - states[active, axis])
        contact[rows, axis] = walls[wall, axis] - direction * rng.uniform(
            REBOUND_LOW, REBOUND_HIGH, len(active)
        )
        ends[active] = contact
    raise AssertionError("a move was still crossing walls after MAX_REBOUNDS rebounds")


def cell_of(states: np.ndarray) -> np.ndarray:
    """The cell ``(i, j) = (ceil(x), ceil(y))`` of each state, in 1..5, shape (n, 2)."""
    return np.clip(np.ceil(np.asarray(states, dtype=np.float64).reshape(-1, 2)), 1, MAZE_SIZE).astype(
        np.int64
    )
