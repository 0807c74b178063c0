"""
The RL Zoo's ``train`` and ``enjoy`` with ``--algo trlsd``.

The Zoo has no plugin mechanism for algorithms: its ``--algo`` choices are the keys of
``rl_zoo3.utils.ALGOS``, read before ``--gym-packages`` is imported. ``register_with_zoo`` adds ``trlsd``
to that table (and to the hyperparameter samplers of ``-optimize``), the maze is registered by importing
this package, and ``run_zoo`` then hands the user's arguments, unchanged, to the Zoo's own script (the
pattern the Zoo documents for SBX).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from sb3_trlsd.trlsd import TRLSD

__all__ = ["ZOO_MISSING", "convert_trlsd_params", "register_with_zoo", "run_zoo", "sample_trlsd_params"]

ZOO_MISSING = "the RL Zoo is not installed: pip install 'sb3-trlsd[zoo]' (or pip install rl_zoo3)"


def sample_trlsd_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler of TRLSD's hyperparameters for the Zoo's ``-optimize``: the optimism ``kappa`` and the width
    ``sigma`` of eq. 8-9 on log scales around the paper's values (Figure 7), the refit ``update_ratio``
    (the paper tries 1.05 to 2) and the discount factor.

    :param trial: an Optuna trial
    :param n_actions: unused (the Zoo's sampler signature)
    :param n_envs: unused
    :param additional_args: unused
    :return: constructor arguments of ``TRLSD``
    """
    return convert_trlsd_params(
        {
            "kappa": trial.suggest_float("kappa", 0.003, 1.0, log=True),
            "sigma": trial.suggest_float("sigma", 0.05, 1.0, log=True),
            "update_ratio": trial.suggest_float("update_ratio", 1.05, 4.0, log=True),
            "gamma": trial.suggest_float("gamma", 0.8, 0.99),
        }
    )


def convert_trlsd_params(params: dict[str, Any]) -> dict[str, Any]:
    """A trial's parameters as ``TRLSD`` arguments (the Zoo's ``--trial-id`` reload): they already are."""
    return dict(params)


def register_with_zoo() -> None:
    """
    Make ``trlsd`` an algorithm of the installed RL Zoo, with its ``-optimize`` sampler.

    :raises ImportError: when ``rl_zoo3`` is not installed
    """
    from rl_zoo3 import hyperparams_opt, utils

    utils.ALGOS["trlsd"] = TRLSD  # the one table the Zoo's scripts import by name
    hyperparams_opt.HYPERPARAMS_SAMPLER["trlsd"] = sample_trlsd_params
    hyperparams_opt.HYPERPARAMS_CONVERTER["trlsd"] = convert_trlsd_params


def run_zoo(script: str, argv: Sequence[str]) -> int:
    """
    Run the Zoo's ``train`` or ``enjoy`` with ``argv`` as its command line, ``trlsd`` registered.

    :param script: ``"train"`` or ``"enjoy"``
    :param argv: the user's arguments, passed on unchanged
    :return: exit status (1 with a one-line instruction when the Zoo is not installed)
    """
    try:
        register_with_zoo()
    except ImportError:
        print(f"sb3-trlsd {script}: {ZOO_MISSING}", file=sys.stderr)
        return 1
    if script == "train":
        from rl_zoo3.train import train as zoo_script
    elif script == "enjoy":
        from rl_zoo3.enjoy import enjoy as zoo_script
    else:
        raise ValueError(f"script must be 'train' or 'enjoy', got {script!r}")
    saved_argv = sys.argv
    sys.argv = [f"sb3-trlsd {script}", *argv]
    try:
        zoo_script()
    finally:
        sys.argv = saved_argv
    return 0
