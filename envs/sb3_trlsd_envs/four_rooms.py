"""A continuous four-rooms world: 16 goal tasks sharing the maze's dynamics at scale 1/8."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_trlsd_envs.dynamics import as_segments, maze_step
from sb3_trlsd_envs.family_rendering import render_four_rooms
from sb3_trlsd_envs.multitask import TaskFamilyEnv, check_non_negative, random_rollouts, trajectory_lengths

__all__ = [
    "FOUR_ROOMS_GOALS",
    "FOUR_ROOMS_WALLS",
    "FourRooms",
    "four_rooms_step",
    "goal_rewards",
    "make_room_walls",
]

# Walls lie on the 1/8 grid and a move is 1/8 of the side: in units of a move, the square is [0, 8]^2 and
# the dynamics are exactly the maze's (scaling by a power of two is exact in floating point).
GRID = 8
# Sutton, Precup & Singh's hallways moved to the 1/8 grid (their two horizontal walls are one row apart;
# here both are at y = 1/2): doorways at y in [1/8, 2/8] and [6/8, 7/8] through x = 1/2, at x in
# [1/8, 2/8] (west) and [6/8, 7/8] (east) through y = 1/2.
FOUR_ROOMS_WALLS = (
    ((0.5, 0.0), (0.5, 0.125)),
    ((0.5, 0.25), (0.5, 0.75)),
    ((0.5, 0.875), (0.5, 1.0)),
    ((0.0, 0.5), (0.125, 0.5)),
    ((0.25, 0.5), (0.75, 0.5)),
    ((0.875, 0.5), (1.0, 0.5)),
)
# Task 4 (i - 1) + (j - 1) is the goal at ((2i - 1) / 8, (2j - 1) / 8): four per room, 1/8 off its walls.
FOUR_ROOMS_GOALS = tuple(((2 * i - 1) / GRID, (2 * j - 1) / GRID) for i in range(1, 5) for j in range(1, 5))
BORDER = (
    ((0.0, 0.0), (1.0, 0.0)),
    ((1.0, 0.0), (1.0, 1.0)),
    ((0.0, 1.0), (1.0, 1.0)),
    ((0.0, 0.0), (0.0, 1.0)),
)


def make_room_walls(walls: Iterable | np.ndarray = FOUR_ROOMS_WALLS) -> np.ndarray:
    """
    Validate a wall layout of the unit square and add its border.

    :param walls: axis-aligned segments ``((x0, y0), (x1, y1))`` with ends on the 1/8 grid of [0, 1]^2, or
        an ``(m, 4)`` array of them (the output of this function too); ``()`` for one open room
    :return: ``(k, 4)`` distinct segments ``x0, y0, x1, y1`` with ``x0 <= x1``, ``y0 <= y1``, border included
    :raises ValueError: naming ``walls`` for a segment off the grid or the square, diagonal or of zero length
    """
    segments = np.concatenate([np.reshape(BORDER, (-1, 4)), as_segments(walls)])
    ends = segments * GRID
    problems = (
        (~np.isfinite(ends).all(axis=1) | (np.round(ends) != ends).any(axis=1), "lie on the 1/8 grid"),
        ((ends < 0).any(axis=1) | (ends > GRID).any(axis=1), "lie within [0, 1]^2"),
        (
            (segments[:, 0] == segments[:, 2]) == (segments[:, 1] == segments[:, 3]),
            "be axis-aligned, not points",
        ),
    )
    for bad, rule in problems:
        if bad.any():
            x0, y0, x1, y1 = segments[bad][0]
            raise ValueError(f"walls must {rule}, got (({x0:g}, {y0:g}), ({x1:g}, {y1:g}))")
    lows, highs = np.minimum(segments[:, :2], segments[:, 2:]), np.maximum(segments[:, :2], segments[:, 2:])
    return np.unique(np.concatenate([lows, highs], axis=1), axis=0)


def four_rooms_step(
    states: np.ndarray,
    actions: np.ndarray,
    rng: np.random.Generator,
    walls: np.ndarray,
    along_noise_std: float = 1 / 16,
    across_noise_std: float = 1 / 32,
) -> np.ndarray:
    """
    One step of the four-rooms dynamics for a batch of states: the maze's move (``maze_step``) of 1/8.

    :param states: (n, 2) states in (0, 1)^2
    :param actions: (n,) actions in 0..3 (NORTH, WEST, SOUTH, EAST)
    :param rng: random generator of the move noise and the rebounds
    :param walls: (m, 4) from :func:`make_room_walls`
    :param along_noise_std: standard deviation of the noise along the action's axis (half a move)
    :param across_noise_std: standard deviation of the noise on the other axis (a quarter of a move)
    :return: next states (n, 2), strictly inside (0, 1)^2; the move from ``states`` crosses no wall
    """
    scaled = np.asarray(states, dtype=np.float64) * GRID
    return (
        maze_step(scaled, actions, rng, walls * GRID, along_noise_std * GRID, across_noise_std * GRID) / GRID
    )


def goal_rewards(states: np.ndarray, goals: np.ndarray, radius: float) -> np.ndarray:
    """
    Noise-free rewards: 1 within ``radius`` of the goal (the circle included), 0 elsewhere.

    :param states: (n, 2) states
    :param goals: the goal centre of each state's task, (n, 2), or one for all, (2,)
    :param radius: radius of the goal discs
    :return: (n,) rewards
    """
    offsets = np.asarray(states, dtype=np.float64).reshape(-1, 2) - np.asarray(goals, dtype=np.float64)
    return (np.sum(offsets**2, axis=1) <= radius**2).astype(np.float64)


def _goal_array(goals: Sequence | np.ndarray) -> np.ndarray:
    """The goal centres as a (k, 2) array inside the open square, or a ValueError naming ``goals``."""
    try:
        array = np.asarray(goals, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"goals must be a list of points (x, y), got {goals!r}") from error
    if array.ndim != 2 or array.shape[1] != 2 or not len(array):
        raise ValueError(
            f"goals must be a non-empty list of points (x, y), got an array of shape {array.shape}"
        )
    if not np.all((array > 0) & (array < 1)):
        raise ValueError(f"goals must lie inside the open square (0, 1)^2, got {array.tolist()}")
    return array


class FourRooms(TaskFamilyEnv):
    """
    ## Description
    A continuous version of the four-rooms world of Sutton, Precup & Singh, "Between MDPs and semi-MDPs: A
    framework for temporal abstraction in reinforcement learning" (Artificial Intelligence 112, 1999): the
    unit square is split into four rooms by walls with four doorways, and each of 16 tasks rewards being in
    one goal disc, four per room. All tasks share the dynamics; only the reward differs. This is the
    setting of successor-feature transfer (Barreto et al., "Successor Features for Transfer in
    Reinforcement Learning", NeurIPS 2017), whose first benchmark is a four-room navigation problem.

    ## Action Space
    `Discrete(4)`: 0 NORTH (y - 1/8), 1 WEST (x - 1/8), 2 SOUTH (y + 1/8), 3 EAST (x + 1/8). A move is 1/8
    along the action's axis plus N(0, 1/16) noise on it and N(0, 1/32) on the other axis (standard
    deviations); it stops where it first meets a wall and rebounds by U(1/80, 1/16) into the side it came
    from, until it crosses no wall. This is the paper's maze move (`sb3_trlsd_envs.dynamics.maze_step`)
    at scale 1/8, the walls on the 1/8 grid as the maze's are on the unit grid.

    ## Observation Space
    `Dict({"state": Box(0, 1, (2,), float32), "task": Discrete(n_goals)})`: the position `(x, y)` in the
    open square (0, 1)^2 (y grows southwards) and the index of the current task. `info` holds `task` and
    `goal`, the task's goal centre.

    ## Starting State
    Uniform in the square, at every reset.

    ## Rewards
    The reward of a transition is drawn for the state s_t it starts from: `1 + N(0, reward_noise_std)` if
    `|s_t - g_task| <= goal_radius`, `N(0, reward_noise_std)` elsewhere. Task `4 (i - 1) + (j - 1)` (i, j
    in 1..4) has its goal at `((2i - 1) / 8, (2j - 1) / 8)`. Goals do not end trajectories: they are part
    of the reward, which is all that differs between tasks. `expected_reward(states, task)` gives the
    noise-free expectation.

    ## Episode End
    After each step the trajectory ends with probability `termination_prob` (0.02), as in the maze: a reset,
    not an absorbing state, returned as `truncated=True`; `terminated` is always False. A time limit comes
    from `gym.make(..., max_episode_steps=...)`.

    ## Arguments
    - `task`: the task index (default 0); or `tasks`: several, a list or `"all"`, with `task_schedule`
      `"fixed"` (the first), `"round_robin"` (in turn, one trajectory each) or `"random"` choosing the task
      of each trajectory. `reset(options={"task": ...})` forces one for that trajectory without taking a
      turn of the round robin; `reset(seed=...)` restarts the round robin.
    - `walls`: axis-aligned segments `((x0, y0), (x1, y1))` on the 1/8 grid of [0, 1]^2, or an `(m, 4)`
      array of them (default: the four rooms above); `()` for one open room. The border is always a wall.
    - `goals`: the goal centres, one task each, inside (0, 1)^2 (default: the 16 above).
    - `goal_radius`: radius of the goal discs (default 0.1: 3% of the square each).
    - `termination_prob`: probability that a step ends the trajectory (default 0.02).
    - `reward_noise_std`: standard deviation of the reward noise (default 0: the literature's goal rewards
      are exact; 1 is the noise of the paper's maze).
    - `along_noise_std`, `across_noise_std`: the move noise (defaults 1/16 and 1/32).
    - `render_mode`: `"rgb_array"`: walls in black, the goals as circles with the task's filled in green,
      the trajectory since the last reset in blue.

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4, "reward_timing": "start_state"}
    action_meaning = "an integer in 0..3 (NORTH, WEST, SOUTH, EAST)"

    def __init__(
        self,
        task: int | None = None,
        tasks: str | Sequence[int] | None = None,
        task_schedule: str = "fixed",
        walls: Iterable = FOUR_ROOMS_WALLS,
        goals: Sequence = FOUR_ROOMS_GOALS,
        goal_radius: float = 0.1,
        termination_prob: float = 0.02,
        reward_noise_std: float = 0.0,
        along_noise_std: float = 1 / 16,
        across_noise_std: float = 1 / 32,
        render_mode: str | None = None,
    ):
        self.goals = _goal_array(goals)
        super().__init__(
            n_tasks=len(self.goals),
            task=task,
            tasks=tasks,
            task_schedule=task_schedule,
            reward_noise_std=reward_noise_std,
            render_mode=render_mode,
        )
        if not 0.0 <= termination_prob <= 1.0:
            raise ValueError(f"termination_prob must be a probability in [0, 1], got {termination_prob}")
        if not goal_radius > 0:
            raise ValueError(f"goal_radius must be > 0, got {goal_radius}")
        check_non_negative(along_noise_std=along_noise_std, across_noise_std=across_noise_std)
        self.walls = make_room_walls(walls)
        self.goal_radius = goal_radius
        self.termination_prob = termination_prob
        self.along_noise_std = along_noise_std
        self.across_noise_std = across_noise_std
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(0.0, 1.0, shape=(2,), dtype=np.float32),
                "task": spaces.Discrete(len(self.goals)),
            }
        )
        self.action_space = spaces.Discrete(4)
        self.state = np.full(2, 0.5)
        self.trajectory: list[np.ndarray] = []  # the states since the last reset, for rendering

    def expected_reward(self, states: np.ndarray, task: int | None = None) -> np.ndarray:
        """Noise-free E[R_task(s)] for an ``(n, 2)`` array of states (default: the current task)."""
        task = self.task if task is None else self.schedule.check(task)
        return goal_rewards(states, self.goals[task], self.goal_radius)

    def _step_states(self, states: np.ndarray, actions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return four_rooms_step(states, actions, rng, self.walls, self.along_noise_std, self.across_noise_std)

    def random_transitions(
        self, n_transitions: int, seed: int | None = None, max_episode_steps: int | None = None
    ) -> dict[str, np.ndarray]:
        """
        Transitions of a uniformly random policy, all trajectories stepped at once, for
        ``sb3_trlsd.collect_transitions``: the process of the maze's ``random_transitions`` (uniform starts,
        iid lengths with a reset after each step with probability ``termination_prob``, capped at
        ``max_episode_steps``, tasks in the schedule's order, the last trajectory cut).

        :param n_transitions: how many transitions
        :param seed: seed of the sampler
        :param max_episode_steps: the time limit, if any
        :return: the fields of ``sb3_trlsd.Transitions`` as arrays, a row per transition (never terminal)
        """
        rng = np.random.default_rng(seed)
        cap = n_transitions if max_episode_steps is None else min(max_episode_steps, n_transitions)
        full_lengths, cut_lengths = trajectory_lengths(rng, self.termination_prob, n_transitions, cap)
        tasks = self.schedule.draw(rng, len(full_lengths))
        starts = rng.uniform(0.0, 1.0, size=(len(full_lengths), 2))

        def step(states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return self._step_states(states, actions, rng), np.zeros(len(states), dtype=bool)

        out = random_rollouts(rng, starts, cut_lengths, step, n_actions=4)
        out["tasks"] = tasks[out.pop("trajectories")]
        out["rewards"] = goal_rewards(out["states"], self.goals[out["tasks"]], self.goal_radius)
        out["rewards"] += self.reward_noise_std * rng.normal(size=n_transitions)
        # The last row of each trajectory is a reset, unless the trajectory was cut at n_transitions.
        out["truncations"] = np.zeros(n_transitions, dtype=bool)
        out["truncations"][np.cumsum(cut_lengths)[cut_lengths == full_lengths] - 1] = True
        return out

    def _start(self) -> None:
        self.state = self.np_random.uniform(0.0, 1.0, size=2)
        self.trajectory = [self.state.copy()]

    def _move(self, action: int) -> tuple[bool, bool]:
        self.state = self._step_states(self.state[None], np.array([action]), self.np_random)[0]
        self.trajectory.append(self.state.copy())
        # A reset, not an absorbing state: truncated, never terminated.
        return False, bool(self.np_random.random() < self.termination_prob)

    def _observed_state(self) -> np.ndarray:
        return self.state.astype(np.float32)

    def _info(self) -> dict[str, Any]:
        return {"task": self.task, "goal": tuple(self.goals[self.task].tolist())}

    def _render(self) -> np.ndarray:
        return render_four_rooms(
            self.walls, self.goals, self.goal_radius, target=self.task, trajectory=np.array(self.trajectory)
        )
