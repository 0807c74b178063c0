"""Goal variants of Gymnasium's CartPole: hold the pole up with the cart near a target position."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from sb3_trlsd_envs.cartpole_dynamics import (
    CARTPOLE_TARGETS,
    STATE_HIGH,
    VELOCITY_BOUNDS,
    X_THRESHOLD,
    cartpole_step,
    cartpole_terminal,
    target_rewards,
)
from sb3_trlsd_envs.family_rendering import render_cartpole
from sb3_trlsd_envs.multitask import TaskFamilyEnv, random_rollouts

__all__ = [
    "CARTPOLE_TARGETS",
    "STATE_HIGH",
    "VELOCITY_BOUNDS",
    "GoalCartPole",
    "cartpole_step",
    "cartpole_terminal",
    "target_rewards",
]

START_NOISE = 0.05  # Gymnasium's reset range of every variable but the cart's position
RENDER_TRAIL = 10  # earlier states a rendered frame shows


def _target_array(targets: Sequence[float]) -> np.ndarray:
    """The targets as a (k,) array of distinct positions on the track, or a ValueError naming ``targets``."""
    try:
        array = np.asarray(targets, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"targets must be a list of cart positions, got {targets!r}") from error
    if array.ndim != 1 or not len(array) or len(np.unique(array)) != len(array):
        raise ValueError(f"targets must be a non-empty list of distinct cart positions, got {targets!r}")
    if not np.all(np.abs(array) < X_THRESHOLD):
        raise ValueError(
            f"targets must lie on the track, in (-{X_THRESHOLD}, {X_THRESHOLD}), got {array.tolist()}"
        )
    return array


class GoalCartPole(TaskFamilyEnv):
    """
    ## Description
    Gymnasium's `CartPole` (Barto, Sutton & Anderson, "Neuronlike adaptive elements that can solve
    difficult learning control problems", IEEE SMC 1983) with its dynamics unchanged and one task per target
    cart position: task k rewards holding the pole up with the cart near `targets[k]`. The pole falling
    and the cart leaving the track are part of the shared dynamics, the same for every task; only the
    reward differs. Each step is `CartPoleEnv.step` (`random_transitions` uses Gymnasium's batched
    `CartPoleVectorEnv`, equal to it to the bit).

    ## Action Space
    `Discrete(2)`: 0 pushes the cart left, 1 right, with 10 N for 0.02 s (Gymnasium's).

    ## Observation Space
    `Dict({"state": Box(-STATE_HIGH, STATE_HIGH, (4,), float32), "task": Discrete(n_targets)})`: the state
    `(x, x_dot, theta, theta_dot)` (m, m/s, rad, rad/s; theta > 0 leans right) clipped to the box, and the
    current task. Gymnasium leaves the velocities unbounded; here they are bounded by `VELOCITY_BOUNDS` =
    4 m/s and 4 rad/s, and x and theta by their termination thresholds plus one step at those velocities:
    `STATE_HIGH` = (2.48, 4, 0.289, 4). Random policies stay below 3.5 m/s and 3.75 rad/s; only the
    observation is clipped, never the dynamics' state (a policy going faster would see 4). `info`
    holds `task` and `target`, the task's target position.

    ## Starting State
    `x` uniform in `[-start_x_bound, start_x_bound]`, the other three uniform in (-0.05, 0.05) as in
    Gymnasium. Gymnasium starts the cart at x = 0; a random policy hardly moves it before the pole falls
    (22 steps on average), so the spread start (1.75 m: past every default target) is what lets random
    source data see every task's reward.

    ## Rewards
    The reward of a transition is drawn for the state s_t it starts from (never terminal):
    `exp(-(x_t - targets[task])^2 / (2 goal_width^2)) + N(0, reward_noise_std)`. A smooth bump rather
    than the maze's indicator: a learner is paid for keeping the pole up wherever the cart is, the more
    the closer to the target (1 m off, exp(-2) = 0.14 a step), so that holding the pole is worth learning
    before the target is found. A terminal state is worth 0.
    `expected_reward(states, task)` gives the noise-free expectation (0 for terminal states).

    ## Episode End
    Termination, as Gymnasium's and the same for all tasks: the pole beyond 12 degrees or the cart beyond
    2.4 m; it is absorbing (`terminated=True`: no bootstrap). Truncation: the registered time limit,
    `max_episode_steps=200` (CartPole-v0's).

    ## Arguments
    - `task`: the task index (default 0, target -1.5); or `tasks`: several, a list or `"all"`, with
      `task_schedule` `"fixed"` (the first), `"round_robin"` (in turn, one trajectory each) or `"random"`
      choosing the task of each trajectory. `reset(options={"task": ...})` forces one for that trajectory
      without taking a turn of the round robin; `reset(seed=...)` restarts the round robin.
    - `targets`: distinct target cart positions on the track, one task each (default -1.5, -0.75, 0,
      0.75, 1.5).
    - `goal_width`: standard deviation of the reward bump, in metres (default 0.5).
    - `start_x_bound`: half-width of the cart's starting range, in [0, 2.4) (default 1.75).
    - `reward_noise_std`: standard deviation of the reward noise (default 0).
    - `render_mode`: `"rgb_array"`: the track and its ends, the task's reward as a green band under it with
      the targets ticked, the cart in black, the pole in brown, its last 9 positions in fading blue.

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50, "reward_timing": "start_state"}
    action_meaning = "0 (push left) or 1 (push right)"

    def __init__(
        self,
        task: int | None = None,
        tasks: str | Sequence[int] | None = None,
        task_schedule: str = "fixed",
        targets: Sequence[float] = CARTPOLE_TARGETS,
        goal_width: float = 0.5,
        start_x_bound: float = 1.75,
        reward_noise_std: float = 0.0,
        render_mode: str | None = None,
    ):
        self.targets = _target_array(targets)
        super().__init__(
            n_tasks=len(self.targets),
            task=task,
            tasks=tasks,
            task_schedule=task_schedule,
            reward_noise_std=reward_noise_std,
            render_mode=render_mode,
        )
        if not goal_width > 0:
            raise ValueError(f"goal_width must be > 0, got {goal_width}")
        if not 0 <= start_x_bound < X_THRESHOLD:
            raise ValueError(f"start_x_bound must be in [0, {X_THRESHOLD}), got {start_x_bound}")
        self.goal_width = goal_width
        self.start_x_bound = start_x_bound
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(-STATE_HIGH, STATE_HIGH, dtype=np.float32),
                "task": spaces.Discrete(len(self.targets)),
            }
        )
        self.action_space = spaces.Discrete(2)
        self.cartpole = CartPoleEnv()  # steps the state; its own reward and observation are not used
        self.cartpole.state = np.zeros(4)
        self.trajectory: deque[np.ndarray] = deque(maxlen=RENDER_TRAIL)  # the latest states, for rendering

    @property
    def state(self) -> np.ndarray:
        """The dynamics' state ``(x, x_dot, theta, theta_dot)``, unclipped."""
        state = self.cartpole.state
        assert state is not None, "set from the constructor on"
        return state

    @state.setter
    def state(self, value: np.ndarray) -> None:
        self.cartpole.state = value

    def expected_reward(self, states: np.ndarray, task: int | None = None) -> np.ndarray:
        """Noise-free E[R_task(s)] for an ``(n, 4)`` array of states (default: the current task)."""
        task = self.task if task is None else self.schedule.check(task)
        return target_rewards(states, self.targets[task], self.goal_width)

    def _start_states(self, rng: np.random.Generator, n: int) -> np.ndarray:
        states = rng.uniform(-START_NOISE, START_NOISE, size=(n, 4))
        states[:, 0] = rng.uniform(-self.start_x_bound, self.start_x_bound, size=n)
        return states

    def random_transitions(
        self, n_transitions: int, seed: int | None = None, max_episode_steps: int | None = None
    ) -> dict[str, np.ndarray]:
        """
        ``n_transitions`` transitions of a uniformly random policy, many trajectories stepped at once.

        The same process as stepping the env with random actions: each trajectory starts from the starting
        distribution with the task its schedule gives and runs until it terminates or reaches
        ``max_episode_steps``; trajectories follow each other and the last one is cut at ``n_transitions``.
        States are observations (clipped to the box). ``sb3_trlsd.collect_transitions`` uses it.

        :param n_transitions: how many transitions
        :param seed: seed of the sampler
        :param max_episode_steps: the time limit, if any
        :return: the fields of ``sb3_trlsd.Transitions`` as arrays, a row per transition
        """
        rng = np.random.default_rng(seed)
        cap = n_transitions if max_episode_steps is None else min(max_episode_steps, n_transitions)
        batches: list[dict[str, np.ndarray]] = []
        n_rows = n_trajectories = 0
        while n_rows < n_transitions:
            # Random trajectories last about 20 steps: a batch of this size is usually the only one.
            size = max(16, (n_transitions - n_rows) // 16)
            batch = random_rollouts(
                rng, self._start_states(rng, size), np.full(size, cap), cartpole_step, n_actions=2
            )
            batch["tasks"] = self.schedule.draw(rng, size, first=n_trajectories)[batch["trajectories"]]
            batch["trajectories"] += n_trajectories
            batches.append(batch)
            n_rows, n_trajectories = n_rows + len(batch["actions"]), n_trajectories + size
        out = {name: np.concatenate([batch[name] for batch in batches]) for name in batches[0]}
        trajectories = out.pop("trajectories")
        # A trajectory's last row that does not terminate reached the cap; rows past n_transitions are cut.
        last = np.append(trajectories[1:] != trajectories[:-1], True)
        out["truncations"] = last & ~out["terminations"]
        out = {name: column[:n_transitions] for name, column in out.items()}
        out["rewards"] = target_rewards(out["states"], self.targets[out["tasks"]], self.goal_width)
        out["rewards"] += self.reward_noise_std * rng.normal(size=n_transitions)
        for name in ("states", "next_states"):
            out[name] = np.clip(out[name], -STATE_HIGH, STATE_HIGH)
        return out

    def _start(self) -> None:
        self.cartpole.state = self._start_states(self.np_random, 1)[0]
        self.cartpole.steps_beyond_terminated = None
        self.trajectory.clear()
        self.trajectory.append(self.state.copy())

    def _move(self, action: int) -> tuple[bool, bool]:
        # Gymnasium's step; the time limit is the TimeLimit wrapper's, as for CartPole-v0.
        _, _, terminated, _, _ = self.cartpole.step(action)
        self.trajectory.append(self.state.copy())
        return terminated, False

    def _observed_state(self) -> np.ndarray:
        return np.clip(self.state, -STATE_HIGH, STATE_HIGH).astype(np.float32)

    def _info(self) -> dict[str, Any]:
        return {"task": self.task, "target": float(self.targets[self.task])}

    def _render(self) -> np.ndarray:
        trail = list(self.trajectory)[:-1]
        return render_cartpole(self.state, self.targets, self.goal_width, target=self.task, trail=trail)
