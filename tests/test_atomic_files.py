"""Files written whole or not at all: a failed write leaves the earlier file, and nothing beside it."""

import os
import stat

import pytest

from sb3_trlsd.atomic_files import atomic_path, atomic_write, save_file, save_target


@pytest.mark.parametrize("mode", ["w", "wb"], ids=["text", "binary"])
def test_a_write_that_raises_midway_leaves_the_earlier_file_as_it_was(tmp_path, mode):
    """Written in place, the file would be cut to what was written before the error."""
    path = tmp_path / "result.json"
    path.write_text("earlier")
    with pytest.raises(OSError, match="disk full"), atomic_write(path, mode) as file:
        file.write("partial" if mode == "w" else b"partial")
        raise OSError("disk full")
    assert path.read_text() == "earlier"
    assert os.listdir(tmp_path) == ["result.json"]


def test_a_write_that_ends_replaces_the_file_with_the_permissions_open_gives(tmp_path):
    """A temporary file made private (0600, as mkstemp makes it) would leave results unreadable to others."""
    new, existing = tmp_path / "new.csv", tmp_path / "existing.csv"
    existing.write_text("earlier")
    existing.chmod(0o640)
    for path in (new, existing):
        with atomic_write(path, "w", newline="") as file:
            file.write("a,b\r\n")
    assert new.read_bytes() == existing.read_bytes() == b"a,b\r\n"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(new.stat().st_mode) == 0o666 & ~umask
    assert stat.S_IMODE(existing.stat().st_mode) == 0o640
    assert sorted(os.listdir(tmp_path)) == ["existing.csv", "new.csv"]


def test_a_path_writer_gets_a_hidden_temporary_path_beside_the_target(tmp_path):
    """Beside it (a rename within one file system), and named so that no glob of results takes it for one."""
    path = tmp_path / "figure.png"
    with atomic_path(path) as temporary:
        temporary.write_bytes(b"png")
        assert temporary.parent == tmp_path and temporary.name.startswith(".") and temporary.suffix == ".tmp"
        assert not list(tmp_path.glob("*.png"))
    assert path.read_bytes() == b"png" and os.listdir(tmp_path) == ["figure.png"]
    with pytest.raises(RuntimeError), atomic_path(path) as temporary:
        temporary.write_bytes(b"half")
        raise RuntimeError
    assert path.read_bytes() == b"png" and os.listdir(tmp_path) == ["figure.png"]


@pytest.mark.parametrize(
    ("given", "written"),
    [
        ("model", "model.zip"),
        ("model.zip", "model.zip"),
        ("model.v2", "model.v2"),
        ("sub/model", "sub/model.zip"),
    ],
    ids=["no-suffix", "zip", "other-suffix", "missing-folder"],
)
def test_save_target_names_the_file_as_sb3_does(tmp_path, given, written):
    """SB3 adds the suffix only to a path without one, and makes the folders missing."""
    assert save_target(tmp_path / given, ".zip") == tmp_path / written
    assert (tmp_path / written).parent.is_dir()


def test_save_file_passes_a_file_object_through(tmp_path):
    """A file object is the caller's: written to as it is, neither replaced nor closed."""
    with open(tmp_path / "stream", "wb") as stream:
        with save_file(stream, ".zip") as file:
            assert file is stream
        assert not stream.closed
