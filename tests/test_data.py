"""collect_transitions and the .npz round trip of Transitions."""

import dataclasses
import errno
import os
import pickle
import re

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD, Transitions, collect_transitions
from tests.conftest import MAZE_ID


def test_collected_transitions_chain_within_trajectories(source_transitions):
    """s'_t is s_{t+1} unless the trajectory was reset; otherwise the set mixes trajectories wrongly."""
    data = source_transitions
    same_trajectory = ~data.truncations[:-1]
    np.testing.assert_array_equal(data.next_states[:-1][same_trajectory], data.states[1:][same_trajectory])
    assert data.truncations.any() and not data.terminations.any()
    assert np.all(data.tasks == 12)  # tau_33 is index 5 * 2 + 2


def test_truncated_transitions_keep_the_real_next_state(source_transitions):
    """The next state of a reset transition is where the move led, not the reset state (moves are short)."""
    data = source_transitions
    moves = np.linalg.norm(data.next_states - data.states, axis=1)
    # Displacement is 1 + N(0, 0.5) along and N(0, 0.25) across: beyond 4 is a > 6 sigma event.
    assert moves[data.truncations].max() < 4.0


def test_collect_is_reproducible():
    """Same seed, same transitions: experiments depend on it."""
    first = collect_transitions(gym.make(MAZE_ID), n_transitions=200, seed=7)
    second = collect_transitions(gym.make(MAZE_ID), n_transitions=200, seed=7)
    for field in dataclasses.fields(Transitions):
        np.testing.assert_array_equal(getattr(first, field.name), getattr(second, field.name))


def test_npz_round_trip(tmp_path, source_transitions):
    """Saving then loading gives back every array unchanged."""
    path = tmp_path / "source.npz"
    source_transitions.save(path)
    assert_same_transitions(Transitions.load(path), source_transitions)


def assert_same_transitions(ours: Transitions, theirs: Transitions) -> None:
    for field in dataclasses.fields(Transitions):
        np.testing.assert_array_equal(getattr(ours, field.name), getattr(theirs, field.name))


def test_a_save_that_fails_midway_leaves_the_earlier_file_loadable(tmp_path, monkeypatch, source_transitions):
    """
    A save that fails as a full disk does, midway through the arrays, leaves the earlier file whole (written
    in place, it is cut short and unreadable), and no partial file beside it.
    """
    path = tmp_path / "source.npz"
    source_transitions.save(path)
    write_array, calls = np.lib.format.write_array, []

    def failing(file, array, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            file.write(b"\x00" * 64)
            raise OSError(errno.ENOSPC, "No space left on device")
        write_array(file, array, *args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", failing)
    with pytest.raises(OSError, match="No space left"):
        source_transitions.take(np.arange(10)).save(path)
    monkeypatch.undo()
    assert_same_transitions(Transitions.load(path), source_transitions)
    assert os.listdir(tmp_path) == ["source.npz"]


def test_a_save_names_the_file_as_numpy_does_and_refuses_a_folder(tmp_path, source_transitions):
    """``.npz`` is added when missing; a folder's name is refused instead of failing inside numpy."""
    source_transitions.save(tmp_path / "source")
    assert os.listdir(tmp_path) == ["source.npz"]
    (tmp_path / "folder.npz").mkdir()
    with pytest.raises(ValueError, match="is a folder"):
        source_transitions.save(tmp_path / "folder")


def test_loading_a_file_that_is_not_transitions_fails_clearly(tmp_path, source_transitions):
    """A .npz lacking arrays, or with arrays of inconsistent shapes or NaN rewards, is refused by name."""
    path = tmp_path / "other.npz"
    np.savez(path, states=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="lacks the arrays"):
        Transitions.load(path)
    arrays = {f.name: getattr(source_transitions, f.name) for f in dataclasses.fields(Transitions)}
    np.savez(path, **{**arrays, "actions": arrays["actions"][:-1]})
    with pytest.raises(ValueError, match="rows"):
        Transitions.load(path)
    np.savez(path, **{**arrays, "rewards": np.full(len(source_transitions), np.nan)})
    with pytest.raises(ValueError, match="rewards"):
        Transitions.load(path)
    np.savez(path, **{**arrays, "states": arrays["states"][:, :1]})
    with pytest.raises(ValueError, match="states"):
        Transitions.load(path)


def save_with(path, transitions, **replaced) -> None:
    """``transitions`` saved to ``path`` with some arrays replaced."""
    np.savez(
        path,
        **{**{f.name: getattr(transitions, f.name) for f in dataclasses.fields(Transitions)}, **replaced},
    )


def truncate(path, transitions) -> None:
    transitions.save(path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def save_one_array(path, transitions) -> None:
    """An ``.npy`` file under an ``.npz`` name."""
    with open(path, "wb") as file:
        np.save(file, transitions.states)


def flip_a_byte(path, transitions) -> None:
    """Damage inside an array's data: the zip's directory is whole, the CRC of one member is not."""
    transitions.save(path)
    data = bytearray(path.read_bytes())
    data[200] ^= 0xFF
    path.write_bytes(bytes(data))


DAMAGED_FILES = {
    "empty": (lambda path, data: path.write_bytes(b""), "empty, truncated or damaged"),
    "truncated": (truncate, "empty, truncated or damaged"),
    "a byte flipped": (flip_a_byte, "damaged"),
    "text": (lambda path, data: path.write_text("states,actions\n"), "not an .npz file"),
    "a pickle": (lambda path, data: path.write_bytes(pickle.dumps(data)), "pickles are not loaded"),
    "one array": (save_one_array, "holds one array"),
    "objects": (lambda path, data: save_with(path, data, tasks=data.tasks.astype(object)), "Python objects"),
    "float flags": (
        lambda path, data: save_with(path, data, truncations=data.truncations.astype(float)),
        "'truncations' has dtype float64, expected booleans",
    ),
    "text states": (
        lambda path, data: save_with(path, data, states=data.states.astype(str)),
        "'states' has dtype <U32, expected real numbers",
    ),
}


@pytest.mark.parametrize("damage", list(DAMAGED_FILES), ids=list(DAMAGED_FILES))
def test_a_damaged_or_foreign_file_is_refused_by_name(tmp_path, source_transitions, damage):
    """Before, these raised BadZipFile, EOFError or TypeError without the path, or loaded wrong flags."""
    write, what = DAMAGED_FILES[damage]
    path = tmp_path / "source.npz"
    write(path, source_transitions)
    with pytest.raises(ValueError, match=re.escape(repr(str(path)))) as error:
        Transitions.load(path)
    assert what in str(error.value)
    assert "\n" not in str(error.value)


def test_a_damaged_source_file_of_trlsd_is_named_by_learn(tmp_path, source_transitions):
    """``TRLSD(source_transitions=<path>)`` loads the file at the first ``learn``: the error names it."""
    path = tmp_path / "source.npz"
    truncate(path, source_transitions)
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=(1, 1)), source_transitions=str(path), seed=0)
    with pytest.raises(ValueError, match=re.escape(repr(str(path))) + " is not a readable .npz file"):
        model.learn(1)


def test_collect_rejects_bad_arguments():
    """A non-positive size or a continuous action space is refused before anything runs."""
    with pytest.raises(ValueError, match="n_transitions"):
        collect_transitions(gym.make(MAZE_ID), n_transitions=0)
    with pytest.raises(ValueError, match="Discrete"):
        collect_transitions(gym.make("Pendulum-v1"), n_transitions=10)


def test_envs_without_a_sampler_are_stepped_one_transition_at_a_time():
    """Any Discrete-action env works: CartPole's transitions chain and its terminations are kept."""
    data = collect_transitions(gym.make("CartPole-v1"), n_transitions=300, seed=0)
    assert len(data) == 300 and data.state_dim == 4
    assert data.terminations.any() and np.all(data.tasks == 0)
    ended = data.terminations[:-1] | data.truncations[:-1]
    np.testing.assert_array_equal(data.next_states[:-1][~ended], data.states[1:][~ended])


@pytest.mark.parametrize(
    ("name", "flags", "message"),
    [
        ("truncations", np.full(3, 0.5), r"truncations must be booleans .* got \[0.5\]"),
        ("truncations", np.full(3, 2), r"truncations must be booleans .* got \[2\]"),
        ("terminations", np.array([0, 1, 3]), r"terminations must be booleans .* got \[3\]"),
    ],
    ids=["half-truncation", "truncation-of-2", "termination-of-3"],
)
def test_flags_that_are_not_booleans_are_refused_by_name(name, flags, message):
    """0.5 failed inside numpy's bitwise_or when stored; 2 was stored as a done of 2, silently."""
    arrays = {"states": np.zeros((3, 2)), "actions": np.zeros(3, int), "next_states": np.zeros((3, 2))}
    arrays |= {"rewards": np.zeros(3), "tasks": np.zeros(3, int)}
    arrays |= {"truncations": np.zeros(3, bool), "terminations": np.zeros(3, bool), name: flags}
    with pytest.raises(ValueError, match=message):
        Transitions(**arrays)


def test_flags_of_0_and_1_are_taken_as_booleans():
    """Integer flags of 0 and 1 (a CSV's, say) are what they mean: stored as booleans."""
    transitions = Transitions(
        np.zeros((2, 2)), np.zeros(2, int), np.zeros((2, 2)), np.zeros(2), np.zeros(2, int), [0, 1], [1, 0]
    )
    assert transitions.truncations.dtype == bool and transitions.truncations.tolist() == [False, True]
