"""
The docs site builds with warnings as errors, and every code block a user would paste runs.

Convention, for the pages (``docs/*.rst``) and the README: a code block whose first line is the comment
``# full size: not run by the tests`` is parsed but not run (reproductions at the paper's size); it shows
in the rendered page. Every other Python block is executed in a fresh directory. In shell blocks, every
``sb3-trlsd`` command is parsed by the command line's own parser, and the cheap ones (``render``,
``claims``) are run; ``pip``, ``python`` scripts and other tools are not run (a ``python`` script named
must exist).
"""

from __future__ import annotations

import importlib
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
NOT_RUN = "# full size: not run by the tests"
PAGES = sorted(DOCS.glob("*.rst"))


def rst_blocks(path: Path) -> list[tuple[str, str, int]]:
    """(language, code, line) of each ``.. code-block::`` of a reST page."""
    lines = path.read_text().splitlines()
    blocks = []
    for index, line in enumerate(lines):
        match = re.match(r"^(\s*)\.\. code-block:: (\w+)", line)
        if not match:
            continue
        indent = len(match.group(1))
        body, cursor = [], index + 1
        while cursor < len(lines) and (
            not lines[cursor].strip() or lines[cursor].startswith(" " * (indent + 1))
        ):
            body.append(lines[cursor])
            cursor += 1
        body = [line for line in body if not line.strip().startswith(":")] if body else body
        code = "\n".join(body)
        width = min((len(line) - len(line.lstrip()) for line in body if line.strip()), default=0)
        blocks.append(
            (match.group(2), "\n".join(line[width:] for line in code.splitlines()).strip(), index + 1)
        )
    return blocks


def markdown_blocks(path: Path) -> list[tuple[str, str, int]]:
    """(language, code, line) of each fenced block of a Markdown file."""
    blocks = []
    for match in re.finditer(r"^```(\w*)\n(.*?)^```", path.read_text(), flags=re.M | re.S):
        line = path.read_text()[: match.start()].count("\n") + 1
        blocks.append((match.group(1) or "text", match.group(2).strip(), line))
    return blocks


def all_blocks(language: str) -> list:
    found = []
    for path in [*PAGES, ROOT / "README.md"]:
        reader = markdown_blocks if path.suffix == ".md" else rst_blocks
        for block_language, code, line in reader(path):
            if block_language == language:
                found.append(pytest.param(code, id=f"{path.name}:{line}"))
    return found


def cli_parser():
    """The command line's parser, wherever the lab keeps it."""
    for module in ("sb3_trlsd.cli_parser", "sb3_trlsd_lab.cli_parser"):
        try:
            return importlib.import_module(module).build_parser()
        except ModuleNotFoundError:
            continue
    pytest.fail("no cli_parser module with build_parser found")


def commands(code: str) -> list[tuple[str, list[str]]]:
    """(directory, argv) of each command of a shell block, following ``cd`` and ``&&``."""
    joined = code.replace("\\\n", " ")
    found, directory = [], "."
    for line in joined.splitlines():
        line = line.split(" #")[0].strip()
        if not line or line.startswith("#"):
            continue
        for part in re.split(r"&&|;|\|\|", line):
            words = shlex.split(part.replace("&", " "), comments=True)
            if words[:1] in (["for"], ["do"], ["done"]):
                words = words[1:] if words[:1] == ["do"] else []
            if words[:1] == ["cd"]:
                directory = words[1]
            elif words:
                found.append((directory, words))
    return found


@pytest.mark.parametrize("code", all_blocks("python"))
def test_python_block_runs(code: str, tmp_path: Path) -> None:
    if code.startswith(NOT_RUN):
        # A full-size block is not run, but it must still be Python a reader can paste.
        compile(code, "<docs block>", "exec")
        return
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env
    )
    assert result.returncode == 0, f"{code}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"


@pytest.mark.parametrize("code", all_blocks("bash"))
def test_shell_block_commands_parse(code: str, tmp_path: Path) -> None:
    parser = cli_parser()
    for directory, argv in commands(code):
        if argv[0] == "sb3-trlsd":
            if argv[1] in ("train", "enjoy"):  # handed to the RL Zoo unparsed: the subcommand must exist
                continue
            try:
                parser.parse_args([word for word in argv[1:] if "$" not in word])
            except SystemExit as error:
                pytest.fail(f"sb3-trlsd rejects {' '.join(argv)!r} (status {error.code})")
            if argv[1] in ("render", "claims"):
                cwd = DOCS / directory.removeprefix("docs/") if directory.startswith("docs") else tmp_path
                run_cheap(argv, cwd, tmp_path)
        elif argv[0] == "python" and argv[1:] and argv[1].endswith(".py"):
            assert (ROOT / argv[1]).is_file(), f"{argv[1]} named in a shell block does not exist"


def run_cheap(argv: list[str], cwd: Path, tmp_path: Path) -> None:
    """Run a cheap command, its outputs sent to ``tmp_path``."""
    argv = list(argv)
    if "--out" in argv:
        argv[argv.index("--out") + 1] = str(tmp_path / Path(argv[argv.index("--out") + 1]).name)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run(
        [sys.executable, "-m", "sb3_trlsd_lab", *argv[1:]],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert result.returncode == 0, (
        f"{' '.join(argv)}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    )


def test_the_docs_build_without_warnings(tmp_path: Path) -> None:
    pytest.importorskip("sphinx", reason="the docs extra (in dev) installs Sphinx")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "html",
            str(DOCS),
            str(tmp_path / "html"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, (
        f"sphinx-build failed\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    )


def test_every_page_is_checked() -> None:
    """The block extraction sees the pages' code blocks (a renamed directive would empty it silently)."""
    assert len(all_blocks("python")) >= 2 and len(all_blocks("bash")) >= 10
