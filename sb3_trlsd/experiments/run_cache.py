"""
Finished runs kept on disk, so that a reproduction killed after hours resumes where it stopped.

A run is a pure function of its arguments (its seed included), so a finished one can be reused whenever
the same function is called with the same arguments by the same code. Its key is a sha256 over the
function's qualified name, a canonical form of its arguments and a fingerprint of the code the run
executes: the modules of ``sb3_trlsd`` and ``sb3_trlsd_envs`` that the function's module imports,
directly or not (``code_fingerprint``). An edit of any of them makes the run a miss (it may change the
results); an edit of a module the run does not import (a figure's plotting and tables, the command line)
does not, nor does anything else (installed dependencies are not part of the key). The runs are pickles:
a cache directory must be as trusted as the code.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib.util
import inspect
import os
import pickle
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "RunCache",
    "canonical_form",
    "code_fingerprint",
    "fingerprinted_modules",
    "imported_package_modules",
    "run_key",
]

# The code a run's results depend on, besides dependencies.
FINGERPRINTED_PACKAGES = ("sb3_trlsd", "sb3_trlsd_envs")


def imported_package_modules(path: Path) -> set[str]:
    """
    The modules of ``FINGERPRINTED_PACKAGES`` that a source file names in its import statements, wherever
    they are (inside functions too), with their parent packages (importing ``a.b.c`` runs ``a`` and ``a.b``).
    ``from a import b`` counts ``a`` and, when ``b`` is a submodule, ``a.b``. Imports by name at run time
    (``importlib.import_module``) are not seen.

    :param path: a Python source file
    :return: module names
    """
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_bytes(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                raise ValueError(f"{path}: relative imports are not followed by the run cache's fingerprint")
            names.add(node.module or "")
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    modules = set()
    for name in names:
        parts = name.split(".")
        if parts[0] not in FINGERPRINTED_PACKAGES:
            continue
        for depth in range(1, len(parts) + 1):
            prefix = ".".join(parts[:depth])
            try:
                spec = importlib.util.find_spec(prefix)
            except ModuleNotFoundError:  # ``from a import b`` with b an attribute, not a module
                spec = None
            if spec is not None and spec.origin is not None:
                modules.add(prefix)
    return modules


def module_file(name: str) -> Path:
    """:return: the source file of the module ``name``"""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"no source file for module {name!r}")
    return Path(spec.origin)


def fingerprinted_modules(module: str) -> set[str]:
    """
    The modules of ``FINGERPRINTED_PACKAGES`` that ``module`` imports, directly or through other modules of
    those packages (``imported_package_modules``), ``module`` itself included if it is one of them.

    :param module: a module name (e.g. the ``__module__`` of a run's function)
    :return: module names
    """
    closure: set[str] = {module} if module.split(".")[0] in FINGERPRINTED_PACKAGES else set()
    loaded = sys.modules.get(module)  # e.g. __main__ or a test module, which find_spec may not locate
    pending = [Path(loaded.__file__) if getattr(loaded, "__file__", None) else module_file(module)]
    while pending:
        for name in imported_package_modules(pending.pop()) - closure:
            closure.add(name)
            pending.append(module_file(name))
    return closure


@functools.cache
def code_fingerprint(module: str) -> str:
    """
    sha256 of the source of ``fingerprinted_modules(module)``, sorted by module name, the names hashed too (a
    moved module counts). Computed once per module and process.

    :param module: the name of the module defining a run's function
    :return: the hex digest
    """
    digest = hashlib.sha256()
    for name in sorted(fingerprinted_modules(module)):
        digest.update(name.encode() + b"\0")
        digest.update(hashlib.sha256(module_file(name).read_bytes()).digest())
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
    name, or leaving a default out, is the same run) in canonical form, and the fingerprint of the code it
    runs (``code_fingerprint`` of the function's module).

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
        code_fingerprint(function.__module__),
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
