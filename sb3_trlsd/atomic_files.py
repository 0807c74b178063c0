"""Files written whole or not at all: a temporary file beside the target, then ``os.replace``.

A writer that fails midway (a full disk, an interruption, an exception of its own) leaves the file it was
to replace as it was, and no partial file under the target's name: the model, buffer, transitions and
results a user saved earlier stay readable. The temporary file is in the target's folder, so the
replacement is a rename within one file system (atomic on POSIX and Windows); its contents are flushed to
disk (``fsync``) before it takes the target's name, and the folder's entry after.
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_path", "atomic_write", "save_file", "save_target"]


def save_target(path: str | os.PathLike, suffix: str, what: str = "path") -> Path:
    """
    The file a save to ``path`` writes, as SB3 names it: ``suffix`` (e.g. ``".zip"``) added when the path has
    none, its missing parent folders created.

    :param path: the path given to the save
    :param suffix: the suffix added to a path without one, with its dot
    :param what: the argument's name, for the error
    :return: the file
    :raises ValueError: when the path ends with a separator, or the file it names (its suffix added) is a
        folder (SB3 would save to ``PATH_2`` beside it)
    """
    given = Path(path)
    target = given if given.suffix else given.with_suffix(suffix)
    folder = None
    if os.fspath(path).endswith(("/", os.sep)):  # a folder meant, whatever is there
        folder = given
    elif target.is_dir():  # a folder named "model" beside "model.zip" is no obstacle, as in SB3
        folder = target
    if folder is not None:
        raise ValueError(
            f"{what} {os.fspath(path)!r} is a folder, not a file to save to: give a file's path, e.g. "
            f"{os.fspath(folder / ('model' + suffix))!r}"
        )
    target.parent.mkdir(parents=True, exist_ok=True)
    return target


@contextlib.contextmanager
def save_file(
    path: str | os.PathLike | io.BufferedIOBase, suffix: str, what: str = "path"
) -> Iterator[io.BufferedIOBase]:
    """
    Where a save that takes a path or a file object writes, as SB3's ``save`` does: a file object as it is
    (its owner decides what becomes of it), a path through ``atomic_write`` on ``save_target``.

    :param path: a path, or a binary file object open for writing
    :param suffix: the suffix added to a path without one, with its dot
    :param what: the argument's name, for the error
    :return: the binary file object to write to
    """
    if not isinstance(path, (str, os.PathLike)):
        yield path
        return
    with atomic_write(save_target(path, suffix, what), "wb") as file:
        assert isinstance(file, io.BufferedIOBase)  # os.fdopen's binary writer
        yield file


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """
    A temporary path beside ``path`` for a writer that takes a path (matplotlib's ``savefig``, say): once
    the block ends without an exception, the file written there is flushed to disk and replaces ``path``; if
    the block raises, it is removed and ``path`` is left as it was. The temporary name is hidden and ends
    with ``.tmp``, so that no reader takes a file being written for one of its own (a glob of ``*.npz``): a
    writer that reads the format from the suffix must be given it (``format=``).

    :param path: the file to write
    :return: the temporary path to write to
    """
    target = Path(path)
    temporary = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
    try:
        yield temporary
        _fsync_file(temporary)
        _replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb", **open_kwargs: Any) -> Iterator[IO[Any]]:
    """
    A file object that writes ``path`` whole or not at all: it writes a temporary file beside ``path``
    (with the permissions ``open`` would give), which, once the block ends without an exception, is
    flushed to disk and replaces ``path``; if the block raises, it is removed and ``path`` is left as it
    was.

    :param path: the file to write
    :param mode: ``"wb"`` or ``"w"`` (text)
    :param open_kwargs: further arguments of ``open`` (``newline``, ``encoding``)
    :return: the file object, open for writing
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    with atomic_path(path) as temporary:
        # O_EXCL: a name that exists is never written through; 0o666: the umask applies, as with open().
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
        descriptor = os.open(temporary, flags, 0o666)
        with contextlib.suppress(OSError):
            os.chmod(temporary, os.stat(path).st_mode & 0o7777)  # an existing file keeps its permissions
        with os.fdopen(descriptor, mode, **open_kwargs) as file:
            yield file


def _fsync_file(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _replace(temporary: Path, target: Path) -> None:
    os.replace(temporary, target)
    if os.name == "posix":  # the rename itself reaches the disk with the folder's entry
        descriptor = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        except OSError:  # some file systems cannot sync a folder; the rename has happened all the same
            pass
        finally:
            os.close(descriptor)
