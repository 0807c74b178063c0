"""
The paper's multi-task continuous maze as a Gymnasium env: 25 tasks sharing one dynamics. Its tasks (and
their names, sets and expected rewards) are ``maze_tasks.py``'s, re-exported here; its moves are
``dynamics.py``'s. ``step_mazes`` steps several mazes at once: one vectorised move for all of them, each
drawing from its own generator what a step of it alone draws, in the same order (its reward noise, its move
noise and rebounds, its end-of-trajectory draw), so that a maze stepped in a batch of runs in lockstep
(``sb3_trlsd_lab.execution.lockstep``) follows the trajectory it follows alone with the same seed;
``SharedDynamicsMaze.step`` is ``step_mazes`` with one maze.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_trlsd_envs.dynamics import (
    DEFAULT_WALLS,
    EAST,
    MAZE_SIZE,
    NORTH,
    SOUTH,
    WEST,
    cell_noise_stds,
    cell_of,
    cell_task,
    make_walls,
    maze_step,
    reward_noise_scales,
)
from sb3_trlsd_envs.maze_tasks import (
    CELL_NOISE_STDS,
    CORNER_TASKS,
    N_TASKS,
    Task,
    expected_reward,
    task_cell,
    task_index,
    task_indices,
)
from sb3_trlsd_envs.multitask import TASK_SCHEDULES, trajectory_lengths, warn_no_render_mode

__all__ = [
    "CELL_NOISE_STDS",
    "CORNER_TASKS",
    "EAST",
    "NORTH",
    "N_TASKS",
    "SOUTH",
    "START_RULES",
    "WEST",
    "MazeSteps",
    "SharedDynamicsMaze",
    "check_start",
    "expected_reward",
    "step_mazes",
    "task_cell",
    "task_index",
    "task_indices",
]

START_RULES = ("uniform", "continue")  # or a fixed start state (x, y)
Start = str | tuple[float, float]


class SharedDynamicsMaze(gym.Env):
    """
    ## Description
    The navigation problem of Laroche & Barlier, "Transfer Reinforcement Learning with Shared Dynamics"
    (AAAI 2017), section 4: an agent moves with noisy steps in a continuous 5x5 maze, and each of 25 tasks
    rewards one cell. All tasks share the dynamics; only the reward differs.

    The paper's walls are only shown in a figure that is not available as text: the default interior
    walls (x = 3 for y in [0, 3], x = 4 for y in [2, 4]) are those of the first author's later 5x5 maze.

    ## Action Space
    `Discrete(4)`: 0 NORTH (y - 1), 1 WEST (x - 1), 2 SOUTH (y + 1), 3 EAST (x + 1). A move is 1 along the
    action's axis plus N(0, 0.5) noise on it, and N(0, 0.25) noise on the other axis (standard
    deviations). A move stops where it first meets a wall and rebounds by U(0.1, 0.5) into the side it
    came from, until it crosses no wall (see `sb3_trlsd_envs.dynamics`).

    ## Observation Space
    `Dict({"state": Box(0, 5, (2,), float32), "task": Discrete(25)})`: the position `(x, y)` in the open
    square (0, 5)^2 (y grows southwards) and the global index `5 (i - 1) + (j - 1)` of the current task.

    ## Starting State
    By default uniform in the square, at every reset. `start="continue"`: where the previous trajectory of
    the same task ended (uniform for a task's first trajectory, and after a seeded reset); `start=(x, y)`: a
    fixed state. The uniform draw is made at every reset whatever the rule, so that the env's random stream
    does not depend on it.

    ## Rewards
    Task tau_ij (eq. 12) draws the reward of a transition for the state s_t it starts from:
    `1 + N(0, reward_noise_std)` if `i = ceil(x_t)` and `j = ceil(y_t)`, `N(0, reward_noise_std)` elsewhere.
    With a table of standard deviations, one per cell (`reward_noise_std=CELL_NOISE_STDS`, a checkerboard
    of 0.1 and 1.44), the noise of s_t's cell is drawn: the same draw N(0, 1) from `np_random`, scaled by
    that cell's standard deviation, so a maze with a table makes the same moves as one without, seed for
    seed. `expected_reward(states, task)` gives the noise-free expectation. `metadata["reward_timing"]` is
    `"start_state"`, which TRLSD's `reward_timing="auto"` reads.

    ## Episode End
    After each step the trajectory ends with probability `termination_prob` (0.02). This is a reset, not an
    absorbing state, so it is returned as `truncated=True` and `terminated` is always False. A time limit
    comes from `gym.make(..., max_episode_steps=50)`.

    ## Arguments
    - `task`: the task, `(i, j)` or index (default `(1, 1)`); or
    - `tasks`: several tasks, a list, `"all"` or `"corners"`, with `task_schedule` `"fixed"` (the first),
      `"round_robin"` (in turn, one trajectory each) or `"random"` choosing the task of each trajectory.
      `reset(options={"task": ...})` forces one (any of the 25) for that trajectory without taking a
      turn of the round robin; `reset(seed=...)` restarts the round robin from the first task.
    - `walls`: axis-aligned segments `((x0, y0), (x1, y1))` on the integer grid, or an `(m, 4)` array of
      them (default: the two walls above); `()` for an open grid. The border is always a wall.
    - `termination_prob`: probability that a step ends the trajectory (default 0.02, as in the paper).
    - `start`: `"uniform"` (default), `"continue"` or a fixed state `(x, y)` in the open square (see
      Starting State); `random_transitions` takes uniform or fixed starts.
    - `reward_noise_std`: standard deviation of the reward noise (default 1.0, eq. 12), or a 5 x 5 table of
      them, one per cell `(i, j)` at `[i - 1][j - 1]` (e.g. `CELL_NOISE_STDS`).
    - `along_noise_std`, `across_noise_std`: standard deviations of the move noise along the action's
      axis and across it (defaults 0.5 and 0.25).
    - `render_mode`: `"rgb_array"`: walls in black, the target cell in green, the trajectory since the
      last reset as a blue broken line.

    ## Version History
    - v0: initial version; `reward_noise_std` may be a table of one standard deviation per cell (the default
      is unchanged).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4, "reward_timing": "start_state"}

    def __init__(
        self,
        task: Task | None = None,
        tasks: str | Sequence[Task] | None = None,
        task_schedule: str = "fixed",
        walls: Iterable = DEFAULT_WALLS,
        termination_prob: float = 0.02,
        reward_noise_std: float | Sequence[Sequence[float]] = 1.0,
        along_noise_std: float = 0.5,
        across_noise_std: float = 0.25,
        start: Start = "uniform",
        render_mode: str | None = None,
    ):
        if task is not None and tasks is not None:
            raise ValueError("pass either task or tasks, not both")
        self.tasks = (
            task_indices(tasks) if tasks is not None else (task_index((1, 1) if task is None else task),)
        )
        if task_schedule not in TASK_SCHEDULES:
            raise ValueError(f"task_schedule must be one of {TASK_SCHEDULES}, got {task_schedule!r}")
        if not 0.0 <= termination_prob <= 1.0:
            raise ValueError(f"termination_prob must be a probability in [0, 1], got {termination_prob}")
        self.reward_noise_stds = cell_noise_stds(reward_noise_std)  # (5, 5), [i - 1, j - 1]
        for name, value in (
            ("along_noise_std", along_noise_std),
            ("across_noise_std", across_noise_std),
        ):
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        self.start = check_start(start)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.task_schedule = task_schedule
        self.walls = make_walls(walls)
        self.termination_prob = termination_prob
        self.reward_noise_std = reward_noise_std
        self.along_noise_std = along_noise_std
        self.across_noise_std = across_noise_std
        self.render_mode = render_mode
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(0.0, float(MAZE_SIZE), shape=(2,), dtype=np.float32),
                "task": spaces.Discrete(N_TASKS),
            }
        )
        self.action_space = spaces.Discrete(4)
        self.task = self.tasks[0]
        self.state = np.full(2, MAZE_SIZE / 2)
        self.trajectory: list[np.ndarray] = []
        self._n_scheduled = 0  # trajectories whose task the round robin chose
        self._ends: dict[int, np.ndarray] = {}  # where each task's last trajectory ended ("continue")

    def expected_reward(self, states: np.ndarray, task: Task | None = None) -> np.ndarray:
        """Noise-free E[R_task(s)] for an ``(n, 2)`` array of states (default: the current task)."""
        return expected_reward(states, self.task if task is None else task)

    def random_transitions(
        self, n_transitions: int, seed: int | None = None, max_episode_steps: int | None = None
    ) -> dict[str, np.ndarray]:
        """
        ``n_transitions`` transitions of a uniformly random policy, all trajectories stepped at once.

        The same process as stepping the env with random actions: trajectory lengths are iid (a reset after
        each step with probability ``termination_prob``, capped at ``max_episode_steps``), each trajectory
        starts uniformly in the square with the task its schedule gives, and the last one is cut at
        ``n_transitions``. ``sb3_trlsd.collect_transitions`` uses it when an env provides it.

        :param n_transitions: how many transitions
        :param seed: seed of the sampler
        :param max_episode_steps: time limit of the trajectories, if any
        :return: arrays ``states``, ``actions``, ``next_states``, ``rewards``, ``tasks``, ``truncations``,
            ``terminations``, one row per transition, trajectory after trajectory
        """
        if self.start == "continue":
            raise ValueError(
                "random_transitions draws independent trajectories; with start='continue' each starts where "
                "its task's previous one ended: step the env instead"
            )
        rng = np.random.default_rng(seed)
        cap = n_transitions if max_episode_steps is None else min(max_episode_steps, n_transitions)
        full_lengths, cut_lengths = trajectory_lengths(rng, self.termination_prob, n_transitions, cap)
        n_trajectories = len(full_lengths)
        offsets = np.concatenate([[0], np.cumsum(cut_lengths)[:-1]])
        tasks = self._scheduled_tasks(rng, n_trajectories)
        out = {
            "states": np.empty((n_transitions, 2)),
            "actions": rng.integers(4, size=n_transitions),
            "next_states": np.empty((n_transitions, 2)),
            "tasks": np.repeat(tasks, cut_lengths),
        }
        states = rng.uniform(0.0, MAZE_SIZE, size=(n_trajectories, 2))
        if not isinstance(self.start, str):
            states[:] = self.start
        active = np.arange(n_trajectories)  # trajectories still running, and their current states
        for step in range(int(cut_lengths.max())):
            running = cut_lengths[active] > step
            active, states = active[running], states[running]
            rows = offsets[active] + step
            out["states"][rows] = states
            states = maze_step(
                states, out["actions"][rows], rng, self.walls, self.along_noise_std, self.across_noise_std
            )
            out["next_states"][rows] = states
        cells = cell_of(out["states"])
        target = cell_task(cells) == out["tasks"]
        noise = reward_noise_scales(out["states"], self.reward_noise_stds) * rng.normal(size=n_transitions)
        out["rewards"] = target + noise
        last = offsets + cut_lengths - 1
        out["truncations"] = np.zeros(n_transitions, dtype=bool)
        # A trajectory cut at n_transitions was not reset.
        out["truncations"][last[cut_lengths == full_lengths]] = True
        out["terminations"] = np.zeros(n_transitions, dtype=bool)
        return out

    def _scheduled_tasks(self, rng: np.random.Generator, n_trajectories: int) -> np.ndarray:
        """The tasks the schedule gives to ``n_trajectories`` trajectories in a row, from the first."""
        tasks = np.asarray(self.tasks)
        if self.task_schedule == "random":
            return tasks[rng.integers(len(tasks), size=n_trajectories)]
        if self.task_schedule == "round_robin":
            return tasks[np.arange(n_trajectories) % len(tasks)]
        return np.full(n_trajectories, tasks[0])

    def _observation(self) -> dict[str, Any]:
        return {"state": self.state.astype(np.float32), "task": self.task}

    def _info(self) -> dict[str, Any]:
        i, j = cell_of(self.state)[0]
        return {"task": self.task, "cell": (int(i), int(j))}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """
        Start a trajectory from the state ``start`` gives (uniform by default), with the task its schedule
        gives.

        :param seed: reseeds ``self.np_random`` and restarts the round robin
        :param options: ``{"task": task}`` forces the task of this trajectory
        :return: the observation and ``info`` (``task``, ``cell``)
        """
        super().reset(seed=seed)
        if self.trajectory:
            self._ends[self.task] = self.state.copy()
        if seed is not None:
            # A seeded reset starts everything afresh, the round robin included: same seed, same trajectory.
            self._n_scheduled = 0
            self._ends.clear()
        if options and options.get("task") is not None:
            self.task = task_index(options["task"])
        elif self.task_schedule == "round_robin":
            self.task = self.tasks[self._n_scheduled % len(self.tasks)]
            self._n_scheduled += 1
        elif self.task_schedule == "random":
            self.task = self.tasks[int(self.np_random.integers(len(self.tasks)))]
        else:
            self.task = self.tasks[0]
        self.state = self.np_random.uniform(0.0, MAZE_SIZE, size=2)
        if not isinstance(self.start, str):
            self.state = np.array(self.start)
        elif self.start == "continue" and self.task in self._ends:
            self.state = self._ends[self.task].copy()
        self.trajectory = [self.state.copy()]
        return self._observation(), self._info()

    def step(self, action):
        """
        Move, rewarding the state the move starts from; the trajectory ends with ``termination_prob``.

        :param action: NORTH, WEST, SOUTH or EAST (0..3)
        :return: observation, reward, ``terminated`` (always False), ``truncated``, ``info``
        """
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in 0..3 (NORTH, WEST, SOUTH, EAST), got {action!r}")
        # The reward is drawn for the state the transition starts from (eq. 12 on s_t).
        step = step_mazes([self], np.array([int(action)]))
        return self._observation(), float(step.rewards[0]), False, bool(step.truncated[0]), self._info()

    def task_picture(self, view: Any) -> np.ndarray:
        """
        A picture of a task's learner on this maze (R^ and greedy policy, its optimism), for TensorBoard.

        :param view: ``task``, ``estimate``, ``bonus``, ``q_values`` and ``trajectory`` of the learner
        :return: an RGB image (H, W, 3), uint8
        """
        from sb3_trlsd_envs.pictures import task_picture

        return task_picture(view, self.walls)

    def render(self):
        if self.render_mode is None:
            warn_no_render_mode()
            return None
        from sb3_trlsd_envs.rendering import render_maze

        return render_maze(
            self.walls, target_cells=[task_cell(self.task)], trajectory=np.array(self.trajectory)
        )


def check_start(start: Start) -> Start:
    """
    ``start`` as the maze keeps it: a rule of ``START_RULES``, or a fixed state as a tuple of two floats.

    :raises ValueError: naming ``start`` for anything else
    """
    if isinstance(start, str):
        if start not in START_RULES:
            raise ValueError(f"start must be one of {START_RULES} or a state (x, y), got {start!r}")
        return start
    point = np.asarray(start, dtype=np.float64)
    if point.shape != (2,) or not np.all((point > 0) & (point < MAZE_SIZE)):
        raise ValueError(
            f"start must be one of {START_RULES} or a state (x, y) in the open square (0, {MAZE_SIZE})^2, "
            f"got {start!r}"
        )
    return float(point[0]), float(point[1])


class MazeSteps:
    """
    What ``step_mazes`` returns, one row per maze.

    :param states: the states reached, (n, 2) float64 (observations are their float32 rounding)
    :param rewards: the rewards, drawn for the states the steps start from, (n,)
    :param truncated: the trajectory ended (``termination_prob``), (n,) bool
    """

    def __init__(self, states: np.ndarray, rewards: np.ndarray, truncated: np.ndarray):
        self.states, self.rewards, self.truncated = states, rewards, truncated


def _dynamics_settings(maze: SharedDynamicsMaze) -> tuple:
    return (
        maze.walls.tobytes(),
        maze.along_noise_std,
        maze.across_noise_std,
        maze.reward_noise_stds.tobytes(),
        maze.termination_prob,
    )


def step_mazes(mazes: Sequence[SharedDynamicsMaze], actions: np.ndarray) -> MazeSteps:
    """
    Step every maze with its action: move, reward the state the move starts from (eq. 12 on s_t), end the
    trajectory with ``termination_prob``. Each maze's ``state`` and ``trajectory`` are updated.

    :param mazes: the (unwrapped) mazes, with the same walls, noises and termination probability
    :param actions: one action in 0..3 per maze, (n,)
    :return: the states reached, rewards and ends of trajectory
    """
    first = mazes[0]
    if any(_dynamics_settings(maze) != _dynamics_settings(first) for maze in mazes[1:]):
        raise ValueError("step_mazes steps mazes of one dynamics: the same walls, noises and termination")
    generators = [maze.np_random for maze in mazes]
    states = np.array([maze.state for maze in mazes], dtype=np.float64).reshape(len(mazes), 2)
    # E[R_tau(s_t)] (eq. 12) of each maze's task, and its noise (of s_t's cell): the first draw of a step.
    expected = (cell_task(cell_of(states)) == np.array([maze.task for maze in mazes])).astype(np.float64)
    noise = np.array([g.normal() for g in generators])
    rewards = expected + reward_noise_scales(states, first.reward_noise_stds) * noise
    next_states = maze_step(
        states, np.asarray(actions), generators, first.walls, first.along_noise_std, first.across_noise_std
    )
    truncated = np.array([g.random() < first.termination_prob for g in generators], dtype=bool)
    for maze, state in zip(mazes, next_states, strict=True):
        maze.state = state
        maze.trajectory.append(state.copy())
    return MazeSteps(next_states, rewards, truncated)
