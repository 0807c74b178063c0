"""
The ``sb3-trlsd`` console script, which a plain install of the package has too: the RL Zoo's ``train`` and
``enjoy`` need only the library and the Zoo (the ``zoo`` extra); every other command is the lab's
(``cli.py``), which needs the ``experiments`` extra. Without it, the command says so in one line and exits
with status 2, instead of failing on an import.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from sb3_trlsd.zoo import ZOO_SCRIPTS, run_zoo

__all__ = ["LAB_REQUIREMENTS", "main", "missing_lab_requirements"]

LAB_REQUIREMENTS = ("joblib", "matplotlib")  # what the experiments extra adds to the library's requirements
EXPERIMENTS_MISSING = (
    "sb3-trlsd: render, reproduce, benchmark, benchmark-suite and claims need the experiments extra, which "
    "is not installed (no {missing}): pip install 'sb3-trlsd[experiments]' (train and enjoy: "
    "'sb3-trlsd[zoo]')"
)


def missing_lab_requirements() -> list[str]:
    """The modules of the ``experiments`` extra that cannot be imported here."""
    missing = []
    for name in LAB_REQUIREMENTS:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    return missing


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sb3-trlsd`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ZOO_SCRIPTS:
        return run_zoo(argv[0], argv[1:])
    missing = missing_lab_requirements()
    if missing:
        print(EXPERIMENTS_MISSING.format(missing=", ".join(missing)), file=sys.stderr)
        return 2
    from sb3_trlsd_lab.cli import main as lab_main

    return lab_main(argv)
