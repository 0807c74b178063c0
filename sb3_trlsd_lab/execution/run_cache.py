"""
Finished runs kept on disk, so that a reproduction killed after hours resumes where it stopped.

A run is a pure function of its arguments (its seed included), so a finished one can be reused whenever
the same function is called with the same arguments by the same code. Its key is a sha256 over the
function's qualified name, a canonical form of its arguments and a fingerprint of the code the run
executes: the modules of ``sb3_trlsd``, ``sb3_trlsd_envs`` and ``sb3_trlsd_lab`` that the function's
module imports, directly or not (``code_fingerprint``). An edit of any of them makes the run a miss (it
may change the results); an edit of a module the run does not import (a figure's plotting and tables, the
command line) does not, nor does anything else (installed dependencies are not part of the key).

A kept run is an ``.npz`` file of arrays and JSON, read without unpickling or importing anything: a cache
directory from elsewhere runs no code when read. What the cache trusts is that a file under a run's name
holds that run's result: whoever can write the directory can change the numbers of a figure.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib.util
import inspect
import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trlsd.atomic_files import atomic_write
from sb3_trlsd.data import load_npz_arrays

__all__ = [
    "RunCache",
    "canonical_form",
    "code_fingerprint",
    "decode",
    "encode",
    "fingerprinted_modules",
    "imported_package_modules",
    "run_key",
]

# The code a run's results depend on, besides dependencies (and the only classes a kept run may name).
FINGERPRINTED_PACKAGES = ("sb3_trlsd", "sb3_trlsd_envs", "sb3_trlsd_lab")
RESULT_ENTRY = "result"  # the array of a kept run's .npz that holds its JSON
FORMAT_VERSION = 1


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
    # e.g. __main__ or a test module, which find_spec may not locate
    loaded_file = getattr(sys.modules.get(module), "__file__", None)
    pending = [Path(loaded_file) if loaded_file else module_file(module)]
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


def kept_dataclass(name: str) -> type:
    """
    The dataclass a kept run names as ``module:qualname``: one of ``FINGERPRINTED_PACKAGES``, from a module
    already imported (reading a kept run imports nothing, so it runs no code but the dataclass's own).

    :param name: ``module:qualname``
    :return: the class
    :raises ValueError: if ``name`` is not such a dataclass
    """
    module_name, _, qualname = name.partition(":")
    found: Any = sys.modules.get(module_name)
    if module_name.split(".")[0] not in FINGERPRINTED_PACKAGES or found is None:
        raise ValueError(
            f"{name!r} is not a class of an imported module of {', '.join(FINGERPRINTED_PACKAGES)}"
        )
    for part in qualname.split("."):
        found = getattr(found, part, None)
    if not (isinstance(found, type) and dataclasses.is_dataclass(found)):
        raise ValueError(f"{name!r} is not a dataclass")
    return found


def encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """
    ``value`` as JSON values, its arrays moved to ``arrays`` (named ``array_<n>``) and replaced by their
    names. A result may be made of None, booleans, numbers, strings, numpy arrays that hold no Python
    objects, lists, tuples, dicts with string keys and dataclasses of ``FINGERPRINTED_PACKAGES`` holding
    those; every container but a scalar is tagged (``{"list": [...]}``), so that ``decode`` rebuilds it.

    :param value: a run's result
    :param arrays: where its arrays go (filled in)
    :return: the JSON form
    :raises TypeError: for anything else
    """
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return encode(value.item(), arrays)
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise TypeError("a kept run cannot hold an array of Python objects")
        name = f"array_{len(arrays)}"
        arrays[name] = value
        return {"array": name}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = f"{type(value).__module__}:{type(value).__qualname__}"
        try:
            kept_dataclass(name)
        except ValueError as error:
            raise TypeError(f"a kept run cannot hold this dataclass: {error}") from error
        fields = {
            field.name: encode(getattr(value, field.name), arrays) for field in dataclasses.fields(value)
        }
        return {"dataclass": [name, fields]}
    if isinstance(value, (list, tuple)):
        return {"tuple" if isinstance(value, tuple) else "list": [encode(item, arrays) for item in value]}
    if isinstance(value, dict) and all(isinstance(key, str) for key in value):
        return {"dict": {key: encode(item, arrays) for key, item in value.items()}}
    raise TypeError(f"a kept run cannot hold a {type(value).__name__}: {value!r}")


def decode(value: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    """
    The result ``encode`` turned into ``value``.

    :param value: the JSON form
    :param arrays: the arrays it names
    :return: the result
    :raises ValueError: if ``value`` is not a form ``encode`` writes (other errors may come from a damaged
        form: ``RunCache.load`` reports them all)
    """
    if not isinstance(value, (dict, list)):
        return value
    if not isinstance(value, dict) or len(value) != 1:
        raise ValueError(f"untagged entry {value!r}")
    ((tag, content),) = value.items()
    if tag == "array":
        return arrays[content]
    if tag in ("list", "tuple"):
        items = [decode(item, arrays) for item in content]
        return items if tag == "list" else tuple(items)
    if tag == "dict":
        return {key: decode(item, arrays) for key, item in content.items()}
    if tag == "dataclass":
        name, fields = content
        cls = kept_dataclass(name)
        expected = sorted(field.name for field in dataclasses.fields(cls))
        if sorted(fields) != expected:
            raise ValueError(f"{name} has the fields {expected}, the kept run {sorted(fields)}")
        return cls(**{key: decode(item, arrays) for key, item in fields.items()})
    raise ValueError(f"unknown entry {tag!r}")


class RunCache:
    """
    A directory of finished runs, one ``.npz`` file per run, named after the function and the run's key:
    the run's arrays, and its structure and scalars as JSON (``encode``). Reading one unpickles nothing
    and imports nothing.

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
        return self.directory / f"{function.__name__}-{run_key(function, args, kwargs)}.npz"

    def load(self, path: Path) -> Any:
        """
        :param path: a file of ``path_of`` that exists
        :return: the result stored there
        :raises ValueError: naming the file, if it cannot be read or is not a run ``store`` wrote
        """
        try:
            arrays = load_npz_arrays(path)
        except OSError as error:
            raise ValueError(f"the kept run {str(path)!r} cannot be read: {error.strerror}") from error
        try:
            structure = json.loads(arrays.pop(RESULT_ENTRY).item())
            if structure["format"] != FORMAT_VERSION:
                raise ValueError(f"format {structure['format']!r}, this code reads {FORMAT_VERSION}")
            return decode(structure["result"], arrays)
        except (AttributeError, KeyError, TypeError, ValueError) as error:
            raise ValueError(
                f"{str(path)!r} is not a kept run this code can read ({type(error).__name__}: {error})"
            ) from error

    def store(self, path: Path, result: Any) -> None:
        """
        Write ``result`` to ``path`` atomically.

        :param path: its file, from ``path_of``
        :param result: the run's result (see ``encode`` for what it may hold)
        """
        arrays: dict[str, np.ndarray] = {}
        structure = json.dumps({"format": FORMAT_VERSION, "result": encode(result, arrays)})
        with atomic_write(path, "wb") as file:
            np.savez(file, allow_pickle=False, **{RESULT_ENTRY: np.array(structure)}, **arrays)
