"""
The RL Zoo's ``train`` and ``enjoy`` with ``--algo trlsd``.

The Zoo has no plugin mechanism for algorithms: its ``--algo`` choices are the keys of
``rl_zoo3.utils.ALGOS``, read before ``--gym-packages`` is imported. ``register_with_zoo`` adds ``trlsd``
to that table (and to the hyperparameter samplers of ``-optimize``), the maze is registered by importing
this package, and ``run_zoo`` then hands the user's arguments to the Zoo's own script (the pattern the Zoo
documents for SBX), with three additions: ``--algo`` defaults to ``trlsd``; without ``-conf``, ``train`` takes
the package's ``trlsd.yml`` (``sb3_trlsd.zoo_configs``, the Zoo's ``hyperparams/<algo>.yml`` layout), and a
``-conf`` naming one of the package's configs (``-conf continuous``) takes it; and ``train`` evaluates on the
tasks it trains on.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any
from unittest import mock

from sb3_trlsd.trlsd import TRLSD

if TYPE_CHECKING:
    from rl_zoo3.exp_manager import ExperimentManager

__all__ = [
    "DEFAULT_CONFIG",
    "ZOO_MISSING",
    "ZOO_SCRIPTS",
    "config_arguments",
    "convert_trlsd_params",
    "evaluating_on_the_training_tasks",
    "packaged_config",
    "register_with_zoo",
    "run_zoo",
    "sample_trlsd_params",
]

ZOO_MISSING = "the RL Zoo is not installed: pip install 'sb3-trlsd[zoo]' (or pip install rl_zoo3)"
ZOO_SCRIPTS = ("train", "enjoy")  # the Zoo's scripts ``sb3-trlsd`` hands on
DEFAULT_CONFIG = "trlsd.yml"  # the package's config of every env it registers, the Zoo's hyperparams layout
CONFIG_OPTIONS = ("-conf", "--conf-file")
ENV_OPTIONS = ("--env",)


def packaged_config(name: str) -> Path | None:
    """
    The path of one of the package's Zoo configs (``sb3_trlsd.zoo_configs``), by its file name with or without
    ``.yml``.

    :param name: e.g. ``"continuous"`` or ``"trlsd.yml"``
    :return: its path, or None when the package has no such config
    """
    file_name = name if name.endswith(".yml") else f"{name}.yml"
    if os.sep in file_name or (os.altsep and os.altsep in file_name):
        return None
    path = Path(str(resources.files("sb3_trlsd.zoo_configs") / file_name))
    return path if path.is_file() else None


def _option_value(argv: Sequence[str], names: Sequence[str]) -> tuple[int, str] | None:
    """The index and value of the first of ``names`` in ``argv`` (``--name value`` or ``--name=value``)."""
    for index, argument in enumerate(argv):
        for name in names:
            if argument == name and index + 1 < len(argv):
                return index, argv[index + 1]
            if argument.startswith(f"{name}="):
                return index, argument.split("=", 1)[1]
    return None


def config_arguments(script: str, argv: Sequence[str]) -> list[str]:
    """
    The Zoo's command line for the user's ``argv``: ``--algo trlsd`` unless an algorithm is named; for
    ``train``, a ``-conf`` naming one of the package's configs (and not a file) replaced by its path, and
    without ``-conf`` the package's ``trlsd.yml``.

    :param script: ``"train"`` or ``"enjoy"``
    :param argv: the user's arguments
    :return: the arguments to hand to the Zoo
    :raises ValueError: for ``train`` without ``-conf`` on an env the package's ``trlsd.yml`` has no config
        for, saying where configs are looked for
    """
    arguments = list(argv)
    if _option_value(arguments, ("--algo",)) is None:
        arguments = ["--algo", "trlsd", *arguments]
    algorithm = _option_value(arguments, ("--algo",))
    if script != "train" or algorithm is None or algorithm[1] != "trlsd":
        return arguments
    given = _option_value(arguments, CONFIG_OPTIONS)
    if given is not None:
        index, name = given
        packaged = packaged_config(name)
        if packaged is not None and not os.path.exists(name):
            if arguments[index] in CONFIG_OPTIONS:
                arguments[index + 1] = str(packaged)
            else:
                arguments[index] = f"{arguments[index].split('=', 1)[0]}={packaged}"
        return arguments
    default = packaged_config(DEFAULT_CONFIG)
    assert default is not None, "the package ships its trlsd.yml"
    env = _option_value(arguments, ENV_OPTIONS)
    if env is not None:
        import yaml

        covered = yaml.safe_load(default.read_text()) or {}
        if env[1] not in covered:
            raise ValueError(
                f"no config for {env[1]}: give one with -conf FILE (a Zoo-style YAML of TRLSD's arguments "
                f"per env id, or the name of one of the package's: {', '.join(sorted(configs_named()))}); "
                f"without -conf, configs are looked for in {default}, which covers {', '.join(covered)}"
            )
    return [*arguments, "-conf", str(default)]


def configs_named() -> list[str]:
    """The names of the package's Zoo configs (file names without ``.yml``)."""
    folder = resources.files("sb3_trlsd.zoo_configs")
    return [entry.name[:-4] for entry in folder.iterdir() if entry.name.endswith(".yml")]


def sample_trlsd_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler of TRLSD's hyperparameters for the Zoo's ``-optimize``: the optimism ``kappa`` and the width
    ``sigma`` of eq. 8-9 on log scales around the paper's values (Figure 7; ``sigma`` reaches the ridge and
    Bernstein heads only, the config's ``reward_head``), the refit ``update_ratio`` (the paper tries 1.05 to
    2) and the discount factor.

    :param trial: an Optuna trial
    :param n_actions: unused (the Zoo's sampler signature)
    :param n_envs: unused
    :param additional_args: unused
    :return: constructor arguments of ``TRLSD``
    """
    return convert_trlsd_params(
        {
            "kappa": trial.suggest_float("kappa", 0.003, 1.0, log=True),
            # A fraction of the state box (0.01-0.2: the paper's 0.05-1 on the 5 x 5 maze).
            "sigma": trial.suggest_float("sigma", 0.01, 0.2, log=True),
            "update_ratio": trial.suggest_float("update_ratio", 1.05, 4.0, log=True),
            "gamma": trial.suggest_float("gamma", 0.8, 0.99),
        }
    )


def convert_trlsd_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """A trial's parameters as ``TRLSD`` arguments (the Zoo's ``--trial-id`` reload): they already are."""
    return dict(sampled_params)


def register_with_zoo() -> None:
    """
    Make ``trlsd`` an algorithm of the installed RL Zoo, with its ``-optimize`` sampler.

    :raises ImportError: when ``rl_zoo3`` is not installed
    """
    from rl_zoo3 import hyperparams_opt, utils

    utils.ALGOS["trlsd"] = TRLSD  # the one table the Zoo's scripts import by name
    hyperparams_opt.HYPERPARAMS_SAMPLER["trlsd"] = sample_trlsd_params
    hyperparams_opt.HYPERPARAMS_CONVERTER["trlsd"] = convert_trlsd_params


def evaluating_on_the_training_tasks() -> type[ExperimentManager]:
    """
    A subclass of the Zoo's ``ExperimentManager`` whose evaluation env, without ``--eval-env-kwargs``, is
    made with the env kwargs of training, the config's included.

    The Zoo means to do so (without ``--eval-env-kwargs``, ``eval_env_kwargs`` is the same dict as
    ``env_kwargs``) but replaces ``env_kwargs`` by the config's after that: its evaluation then ran on the
    env's default task (task 0 on the maze) while the model learnt the config's, and every ``-optimize``
    trial got the same score.

    :return: the subclass
    """
    from rl_zoo3.exp_manager import ExperimentManager

    class TrainingTasksManager(ExperimentManager):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.evaluate_on_training_kwargs = self.eval_env_kwargs is self.env_kwargs

        def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> Any:
            if eval_env and self.evaluate_on_training_kwargs:
                self.eval_env_kwargs = self.env_kwargs
            return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)

    return TrainingTasksManager


def run_zoo(script: str, argv: Sequence[str]) -> int:
    """
    Run the Zoo's ``train`` or ``enjoy`` with ``argv`` as its command line, ``trlsd`` registered (and
    ``train``'s evaluation on the tasks of training, see ``evaluating_on_the_training_tasks``).

    :param script: ``"train"`` or ``"enjoy"``
    :param argv: the user's arguments, passed on unchanged
    :return: exit status: 2 with a one-line message naming the extra when the Zoo is not installed, or when
        the Zoo or TRLSD rejects an argument (a ``ValueError``: e.g. an env no config covers)
    """
    try:
        register_with_zoo()
    except ImportError:
        print(f"sb3-trlsd {script}: {ZOO_MISSING}", file=sys.stderr)
        return 2
    if script not in ZOO_SCRIPTS:
        raise ValueError(f"script must be 'train' or 'enjoy', got {script!r}")
    saved_argv = sys.argv
    try:
        sys.argv = [f"sb3-trlsd {script}", *config_arguments(script, argv)]
        if script == "train":
            zoo_train()
        else:
            from rl_zoo3.enjoy import enjoy

            enjoy()
    except ValueError as error:
        print(f"sb3-trlsd {script}: error: {' '.join(str(error).split())}", file=sys.stderr)
        return 2
    finally:
        sys.argv = saved_argv
    return 0


def zoo_train() -> None:
    """The Zoo's ``train`` on ``sys.argv``, its ``ExperimentManager`` evaluating on the training tasks."""
    import rl_zoo3.train

    with mock.patch.object(rl_zoo3.train, "ExperimentManager", evaluating_on_the_training_tasks()):
        rl_zoo3.train.train()
