"""
Finished runs kept on disk, so that a reproduction killed after hours resumes where it stopped.

A run is a pure function of its arguments (its seed included), so a finished one can be reused whenever
the same function is called with the same arguments by the same code. Its key is a sha256 over the
function's qualified name, a canonical form of its arguments and a fingerprint of the source of the
``sb3_trlsd`` and ``envs`` packages: any edit of that code makes every run a miss (it may change the
results), and nothing else invalidates a run (installed dependencies are not part of the key). The runs
are pickles: a cache directory must be as trusted as the code.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import inspect
import os
import pickle
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["RunCache", "canonical_form", "code_fingerprint", "run_key"]

FINGERPRINTED_PACKAGES = ("sb3_trlsd", "envs")  # the code a run's results depend on, besides dependencies


@functools.cache
def code_fingerprint() -> str:
    """
    sha256 of every ``*.py`` file of the installed ``sb3_trlsd`` and ``envs`` packages, sorted by path
    relative to the directory holding the packages (the names are hashed too: a moved file counts).
    Computed once per process.

    :return: the hex digest
    """
    files: dict[str, Path] = {}  # path relative to the directory holding the package -> the file
    for name in FINGERPRINTED_PACKAGES:
        package_directory = Path(importlib.import_module(name).__file__).parent
        for path in package_directory.rglob("*.py"):
            files[path.relative_to(package_directory.parent).as_posix()] = path
    digest = hashlib.sha256()
    for relative_path, path in sorted(files.items()):
        digest.update(relative_path.encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def canonical_form(value: Any) -> Any:
    """
    ``value`` as plain Python values whose ``repr`` is the same for equal arguments: dataclasses as their
    class name and ``dataclasses.asdict``, mappings with their keys sorted, tuples, lists and ranges as
    lists, sets sorted, numpy scalars as Python scalars.

    :param value: an argument of a run
    :return: its canonical form
    :raises TypeError: for a type without a canonical form (its ``repr`` might hold a memory address)
    """
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [type(value).__qualname__, canonical_form(dataclasses.asdict(value))]
    if isinstance(value, Mapping):
        items = {repr(canonical_form(key)): canonical_form(item) for key, item in value.items()}
        return dict(sorted(items.items()))
    if isinstance(value, (tuple, list, range)):
        return [canonical_form(item) for item in value]
    if isinstance(value, (set, frozenset)):
        return sorted((canonical_form(item) for item in value), key=repr)
    raise TypeError(f"no canonical form for a run argument of type {type(value).__name__}: {value!r}")


def run_key(function: Callable[..., Any], args: tuple, kwargs: dict[str, Any]) -> str:
    """
    The key of the run ``function(*args, **kwargs)``: a sha256 over the function's qualified name, its
    arguments bound to its parameters (defaults filled in, so that passing an argument by position or by
    name, or leaving a default out, is the same run) in canonical form, and ``code_fingerprint()``.

    :param function: a module-level function
    :param args: positional arguments of the run
    :param kwargs: keyword arguments of the run
    :return: the hex digest
    """
    arguments = inspect.signature(function).bind(*args, **kwargs)
    arguments.apply_defaults()
    description = [
        f"{function.__module__}.{function.__qualname__}",
        canonical_form(arguments.arguments),
        code_fingerprint(),
    ]
    return hashlib.sha256(repr(description).encode()).hexdigest()


class RunCache:
    """
    A directory of finished runs, one pickle per run, named after the function and the run's key.

    A run is written to a temporary file of the same directory, then renamed over its name: a process
    killed while writing leaves no half file (at worst a hidden ``.tmp`` file, never read).

    :param directory: where the runs are kept (created if needed)
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)

    def path_of(self, function: Callable[..., Any], args: tuple, kwargs: dict[str, Any]) -> Path:
        """
        :param function: the run's function
        :param args: its positional arguments
        :param kwargs: its keyword arguments
        :return: the file that holds (or will hold) the result of ``function(*args, **kwargs)``
        """
        return self.directory / f"{function.__name__}-{run_key(function, args, kwargs)}.pkl"

    def load(self, path: Path) -> Any:
        """
        :param path: a file of ``path_of`` that exists
        :return: the result stored there
        """
        with open(path, "rb") as file:
            return pickle.load(file)

    def store(self, path: Path, result: Any) -> None:
        """
        Write ``result`` to ``path`` atomically.

        :param path: its file, from ``path_of``
        :param result: the run's result (picklable)
        """
        temporary_path = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(temporary_path, "wb") as file:
                pickle.dump(result, file, protocol=pickle.HIGHEST_PROTOCOL)
                file.flush()
                os.fsync(file.fileno())
            os.replace(temporary_path, path)
        except BaseException:
            temporary_path.unlink(missing_ok=True)
            raise
