"""The static checks, run with the tests so that the README's test command runs them too: ``ruff check``
(the lint rules of ``pyproject.toml``) and ``mypy`` (its ``[tool.mypy]``: library, envs and lab)."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def run_tool(module: str, *args: str) -> subprocess.CompletedProcess:
    """
    ``python -m module args`` at the repository's root. A tool that is not installed is a skip on a
    developer's machine, and a failure in CI (``CI`` set), whose set-up installs the dev extra.
    """
    if importlib.util.find_spec(module) is None:
        missing = f"{module} is not installed (it comes with the dev extra: pip install -e '.[dev]')"
        if os.environ.get("CI"):
            pytest.fail(missing)
        pytest.skip(missing)
    return subprocess.run(
        [sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def test_ruff_finds_nothing():
    result = run_tool("ruff", "check", ".")
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_finds_nothing():
    result = run_tool("mypy")
    assert result.returncode == 0, result.stdout + result.stderr
