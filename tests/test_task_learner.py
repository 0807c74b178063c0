"""
When a task is due for a refit (the trigger of section 3, the lazy refits of ``refit_growth``), and where
its relabelling is optimistic (``optimism``).
"""

import numpy as np
import pytest
from gymnasium import spaces

from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.config import TRLSDConfig
from sb3_trlsd.data import Transitions
from sb3_trlsd.engine import RunRows
from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.reward_heads import make_reward_head
from sb3_trlsd.task_learner import TaskLearner

N_SAMPLES = 400


def refit_steps(refit_growth: float, seed: int = 0) -> list[int]:
    """The samples after which a ridge-head learner refits, fed uniform states of the unit square."""
    grid = RBFGrid(low=(0.0, 0.0), high=(1.0, 1.0), n_per_dim=5, sigma=0.2)
    head = make_reward_head("ridge", features=grid, kappa=0.1, sigma=0.1)
    learner = TaskLearner(0, head, update_ratio=2.0, refit_growth=refit_growth)
    learner.refitted(n_rows=0)  # its first fit, before its first sample
    rng = np.random.default_rng(seed)
    steps = []
    for n in range(1, N_SAMPLES + 1):
        state = rng.uniform(size=2)
        learner.observe(state, 0, state, float(state.sum()), n_rows=n)
        if learner.due:
            steps.append(n)
            learner.refitted(n_rows=n)
    return steps


def test_without_growth_a_task_refits_as_soon_as_its_trigger_fires():
    """refit_growth=0 is Algorithm 1: the refit follows the sample that fired the trigger, every time."""
    grid = RBFGrid(low=(0.0, 0.0), high=(1.0, 1.0), n_per_dim=5, sigma=0.2)
    head = make_reward_head("ridge", features=grid, kappa=0.1, sigma=0.1)
    learner = TaskLearner(0, head, update_ratio=2.0, refit_growth=0.0)
    learner.refitted(n_rows=0)
    rng = np.random.default_rng(1)
    fired = 0
    for n in range(1, N_SAMPLES + 1):
        state = rng.uniform(size=2)
        snapshot = learner.uncertainty_at_refit
        learner.observe(state, 0, state, 1.0, n_rows=n)
        expected = head.refit_due(snapshot, state.reshape(1, -1), 2.0)
        assert learner.due == expected
        if learner.due:
            fired += 1
            learner.refitted(n_rows=n)
    assert fired > 10


@pytest.mark.parametrize("growth", [0.1, 0.5])
def test_with_growth_refits_wait_for_the_samples_to_grow_and_stay_few(growth):
    """
    Each refit comes once the samples have grown by refit_growth since the last one (and the trigger has
    fired), so that over n samples there are at most 1 / growth + ln(n) / ln(1 + growth) + 1 of them, and
    no more than Algorithm 1's refits on the same samples (fewer once the wait binds).
    """
    steps = refit_steps(growth)
    previous = 0
    for step in steps:
        assert step - previous >= max(1.0, growth * previous)
        previous = step
    assert len(steps) <= 1 / growth + np.log(N_SAMPLES) / np.log(1 + growth) + 1
    eager = refit_steps(0.0)
    assert 0 < len(steps) <= len(eager)
    if growth >= 0.5:
        assert len(steps) < len(eager)


def test_a_fired_trigger_is_kept_until_the_wait_is_over():
    """
    A trigger that fires within the wait is not forgotten: with refit_growth=1 and a refit after 10 samples,
    a sample in an unvisited corner fires it at the 11th, and the task is due at the 20th sample, not before.
    """
    grid = RBFGrid(low=(0.0, 0.0), high=(1.0, 1.0), n_per_dim=5, sigma=0.2)
    head = make_reward_head("ridge", features=grid, kappa=0.1, sigma=0.1)
    learner = TaskLearner(0, head, update_ratio=2.0, refit_growth=1.0)
    learner.refitted(n_rows=0)
    visited, corner = np.array([0.1, 0.1]), np.array([0.9, 0.9])
    for n in range(1, 11):
        learner.observe(visited, 0, visited, 0.0, n_rows=n)
    learner.refitted(n_rows=10)
    learner.observe(corner, 0, corner, 1.0, n_rows=11)
    assert learner.triggered and not learner.due
    for n in range(12, 21):
        learner.observe(visited, 0, visited, 0.0, n_rows=n)
        assert learner.due == (n == 20)


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf")])
def test_a_bad_refit_growth_is_refused_by_name(value):
    with pytest.raises(ValueError, match="refit_growth"):
        TRLSDConfig(refit_growth=value)


def rows(states: np.ndarray) -> Transitions:
    n = len(states)
    no = np.zeros(n, dtype=bool)
    return Transitions(states, np.zeros(n, np.int64), states, np.zeros(n), np.zeros(n, np.int64), no, no)


@pytest.mark.parametrize("head_name", ["thompson", "ridge"])
def test_with_source_the_relabelling_is_optimistic_once_the_buffer_holds_rows_the_task_did_not_collect(
    head_name,
):
    """
    optimism="with_source": R^ while every row of the buffer is one of the task's own samples, R~ once a row
    it did not collect (a source's) is in; optimism="always" (the paper) relabels with R~ throughout.
    """
    grid = RBFGrid(low=(0.0, 0.0), high=(1.0, 1.0), n_per_dim=3, sigma=0.3)
    rng = np.random.default_rng(0)
    own, source = rng.uniform(size=(6, 2)), rng.uniform(size=(1, 2))
    learners = {}
    for optimism in ("with_source", "always"):
        seed = {"seed": 0} if head_name == "thompson" else {}
        head = make_reward_head(head_name, features=grid, kappa=0.5, sigma=0.2, **seed)
        learners[optimism] = TaskLearner(0, head, update_ratio=2.0, optimism=optimism)
    buffer = SharedDynamicsReplayBuffer(100, spaces.Box(0, 1, (2,)), spaces.Discrete(1), device="cpu")
    buffer.add_transitions(rows(own))
    for learner in learners.values():
        for state in own:
            learner.observe(state, 0, state, float(state[0]), n_rows=buffer.size())
    scratch, stored = learners["with_source"], buffer.transitions().states  # as the buffer keeps them
    read = RunRows("start_state")  # the run's rows, as the engine reads them at a refit

    def relabelled(learner: TaskLearner) -> np.ndarray:
        read.read(buffer)
        assert read.inputs is not None
        return learner.relabelled_rewards(read.inputs.view(), read.generation)

    np.testing.assert_allclose(relabelled(scratch), scratch.head.estimate(stored))
    always = relabelled(learners["always"])
    np.testing.assert_allclose(always, learners["always"].head.optimistic(stored))
    assert not np.allclose(always, scratch.head.estimate(stored))
    buffer.add_transitions(rows(source))
    stored = buffer.transitions().states
    np.testing.assert_allclose(relabelled(scratch), scratch.head.optimistic(stored))


def test_a_bad_optimism_is_refused_by_name():
    with pytest.raises(ValueError, match=r"optimism must be one of \['always', 'with_source'\]"):
        TRLSDConfig(optimism="source")
