"""The ``sb3-trlsd`` console script on a plain install: the lab's commands name their extra in one line
(status 2) instead of failing on an import; the Zoo's scripts need only the library and the Zoo."""

import subprocess
import sys

import pytest

from sb3_trlsd_lab.console import main

WITHOUT_EXPERIMENTS = "import sys; sys.modules['joblib'] = None; sys.modules['matplotlib'] = None; "


def console(code_before: str, argv: list[str]) -> subprocess.CompletedProcess:
    """``console.main(argv)`` in a new process after ``code_before`` (e.g. hiding the experiments extra)."""
    code = f"{code_before}from sb3_trlsd_lab.console import main; raise SystemExit(main({argv!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("argv", [["--help"], ["reproduce", "fig5"], ["render", "--out", "maze.png"]])
def test_without_the_experiments_extra_a_command_names_it_in_one_line(argv):
    result = console(WITHOUT_EXPERIMENTS, argv)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert "pip install 'sb3-trlsd[experiments]'" in result.stderr
    assert "joblib, matplotlib" in result.stderr


def test_the_zoo_s_train_needs_no_experiments_extra():
    """It reaches the Zoo (here: its one-line refusal of an env no config covers), not the extra's message."""
    pytest.importorskip("rl_zoo3")
    result = console(WITHOUT_EXPERIMENTS, ["train", "--env", "CartPole-v1"])
    assert result.returncode == 2 and "no config for CartPole-v1" in result.stderr, result.stderr


def test_with_the_extra_the_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["--help"])
    assert exited.value.code == 0
    text = capsys.readouterr().out
    assert all(command in text for command in ("render", "reproduce", "benchmark-suite", "train", "enjoy"))
