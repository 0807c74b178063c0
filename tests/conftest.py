"""Shared fixtures: small seeded transition sets of the maze, and the titles of the figures drawn."""

import gymnasium as gym
import pytest
from matplotlib.figure import Figure

import sb3_trlsd_envs  # noqa: F401  (registers the maze)
from sb3_trlsd import Transitions, collect_transitions

MAZE_ID = "TRLSD/SharedDynamicsMaze-v0"


@pytest.fixture(scope="session")
def source_transitions() -> Transitions:
    """3,000 random transitions of task tau_33, the size the fast tests use instead of the paper's 25,000."""
    return collect_transitions(gym.make(MAZE_ID, task=(3, 3)), n_transitions=3_000, seed=0)


@pytest.fixture(scope="session")
def paper_source_transitions() -> Transitions:
    """The paper's source set: 25,000 random transitions, 2% trajectory termination, uniform reset."""
    return collect_transitions(gym.make(MAZE_ID, task=(3, 3)), n_transitions=25_000, seed=1)


def record_figure_titles(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """
    The titles of the figures drawn from now on, in a list that grows as they are drawn (every figure is
    titled through ``Figure.suptitle``).
    """
    titles = []
    suptitle = Figure.suptitle

    def recording(self, title, *args, **kwargs):
        titles.append(title)
        return suptitle(self, title, *args, **kwargs)

    monkeypatch.setattr(Figure, "suptitle", recording)
    return titles


@pytest.fixture
def figure_titles(monkeypatch) -> list[str]:
    """The titles of the figures a test draws."""
    return record_figure_titles(monkeypatch)
