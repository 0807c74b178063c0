"""``sb3-trlsd train`` / ``enjoy`` through the RL Zoo, with every config of ``zoo_configs/``, small sizes."""

import sys
from pathlib import Path

import pytest
import yaml
from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

from sb3_trlsd import TRLSD
from sb3_trlsd_envs import MAZE_ID
from sb3_trlsd_lab.console import main
from tests.test_cli import assert_one_line_error

optuna = pytest.importorskip("optuna")
pytest.importorskip("rl_zoo3")

CONFIG_DIR = Path(__file__).parents[1] / "zoo_configs"
CONFIGS = sorted(CONFIG_DIR.glob("*.yml"))
# The configs of one env each (trlsd.yml, the package's config of every env it registers, has its own tests).
ONE_ENV_CONFIGS = [path for path in CONFIGS if path.stem != "trlsd"]
ALGORITHM_SCALARS = {
    "train/policy_updates",
    "train/fqi_iterations",
    "train/bellman_residual",
    "reward/ci_mean",
    "reward/target_samples",
}


def event_tags(directory: Path) -> dict[str, set[str]]:
    """Tags of every TensorBoard event file under ``directory``, by plugin (scalars, images, hparams)."""
    tags: dict[str, set[str]] = {}
    for event_file in directory.rglob("events.out.tfevents.*"):
        for event in EventFileLoader(str(event_file)).Load():
            for value in event.summary.value:
                tags.setdefault(value.metadata.plugin_data.plugin_name, set()).add(value.tag)
    return tags


def test_every_paper_setting_and_task_family_has_a_config():
    assert {path.stem for path in CONFIGS} == {
        "trlsd",
        "known_reward",
        "continuous",
        "discrete",
        "corners",
        "non_optimistic",
        "multitask",
        "four_rooms",
        "goal_cartpole",
    }


@pytest.mark.parametrize("config", ONE_ENV_CONFIGS, ids=lambda path: path.stem)
def test_train_then_enjoy_each_config(config, tmp_path, capsys):
    logs, tensorboard = tmp_path / "logs", tmp_path / "tb"
    (env_id, hyperparameters), *others = yaml.safe_load(config.read_text()).items()
    assert not others, "one env per config"
    arguments = ["train", "--algo", "trlsd", "--env", env_id, "-conf", str(config), "-n", "60"]
    arguments += ["--seed", "0", "-f", str(logs), "--tensorboard-log", str(tensorboard)]
    has_source = "source_transitions" in hyperparameters
    if has_source:
        # The paper's 25,000 source transitions, shrunk through the Zoo's own override of a config value.
        arguments += ["-params", "source_transitions:500"]
    status = main(arguments)
    assert status == 0
    (saved,) = logs.glob("trlsd/*_1/*.zip")
    model = TRLSD.load(saved)
    assert sum(model.policy_updates.values()) >= 1
    assert model.source_transitions == (500 if has_source else None)
    tags = event_tags(tensorboard)
    assert tags["scalars"] >= ALGORITHM_SCALARS
    if env_id == MAZE_ID:  # the env that draws its tasks (``task_picture``)
        assert any(tag.startswith("pictures/task_") for tag in tags["images"])
    assert "_hparams_/experiment" in tags["hparams"]

    status = main(["enjoy", "--algo", "trlsd", "--env", env_id, "-f", str(logs), "-n", "20", "--no-render"])
    assert status == 0
    assert "Loading" in capsys.readouterr().out


@pytest.fixture
def env_kwargs_made(monkeypatch) -> list[tuple[bool, dict]]:
    """``(eval_env, kwargs)`` of every env the Zoo's ``ExperimentManager`` makes, in order."""
    from rl_zoo3.exp_manager import ExperimentManager

    made = []
    create_envs = ExperimentManager.create_envs

    def recording(self, n_envs, eval_env=False, no_log=False):
        made.append((eval_env, dict(self.eval_env_kwargs if eval_env else self.env_kwargs)))
        return create_envs(self, n_envs, eval_env=eval_env, no_log=no_log)

    monkeypatch.setattr(ExperimentManager, "create_envs", recording)
    return made


def test_optimize_scores_each_trial_on_the_task_it_learns(tmp_path, env_kwargs_made):
    """
    Before, the Zoo evaluated on the env's default task 0 while the config trains on tau_15: the models,
    never fitted there, took action 0 everywhere and every trial got the same score.
    """
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    arguments = ["train", "--algo", "trlsd", "--env", MAZE_ID, "-conf", str(CONFIG_DIR / "continuous.yml")]
    arguments += ["-n", "100", "-f", str(tmp_path / "logs"), "-optimize", "--n-trials", "3", "--n-jobs", "1"]
    arguments += ["--sampler", "random", "--pruner", "none", "--storage", storage, "--study-name", "maze"]
    arguments += ["--n-evaluations", "1", "--eval-episodes", "2", "--no-optim-plots"]
    arguments += ["-params", "source_transitions:1000", "--seed", "0"]
    assert main(arguments) == 0
    study = optuna.load_study(study_name="maze", storage=storage)
    trials = [trial for trial in study.trials if trial.state == optuna.trial.TrialState.COMPLETE]
    assert len(trials) == 3
    assert set(trials[0].params) == {"kappa", "sigma", "update_ratio", "gamma"}
    assert len({trial.value for trial in trials}) == 3
    assert {str(kwargs) for _, kwargs in env_kwargs_made} == {"{'task': [1, 5]}"}
    assert sum(eval_env for eval_env, _ in env_kwargs_made) == 3  # one evaluation env per trial


@pytest.mark.parametrize(
    ("extra", "evaluated_on"),
    [([], {"task": [1, 5]}), (["--eval-env-kwargs", "task:(2,3)"], {"task": (2, 3)})],
    ids=["the config's task", "--eval-env-kwargs"],
)
def test_train_evaluates_on_the_config_task_unless_told_otherwise(
    tmp_path, env_kwargs_made, extra, evaluated_on
):
    """Plain ``train`` evaluates (``--eval-freq``) on the task it trains on, or where the user says."""
    arguments = ["train", "--algo", "trlsd", "--env", MAZE_ID, "-conf", str(CONFIG_DIR / "continuous.yml")]
    arguments += ["-n", "40", "-f", str(tmp_path / "logs"), "--eval-freq", "20", "--eval-episodes", "1"]
    assert main([*arguments, "-params", "source_transitions:300", "--seed", "0", *extra]) == 0
    assert [kwargs for eval_env, kwargs in env_kwargs_made if not eval_env] == [{"task": [1, 5]}]
    assert [kwargs for eval_env, kwargs in env_kwargs_made if eval_env] == [evaluated_on]


def test_an_env_the_config_lacks_is_one_line(capsys):
    """Before, the Zoo's ValueError came out as a traceback."""
    config = str(CONFIG_DIR / "continuous.yml")
    assert main(["train", "--algo", "trlsd", "--env", "CartPole-v1", "-conf", config]) == 2
    assert_one_line_error(capsys, f"Hyperparameters not found for trlsd-CartPole-v1 in {config}")


def test_without_the_zoo_train_says_how_to_install_it(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rl_zoo3", None)  # import rl_zoo3 now raises ImportError
    assert main(["train", "--algo", "trlsd", "--env", MAZE_ID]) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error
    assert "pip install 'sb3-trlsd[zoo]'" in error


def test_the_package_config_of_every_env_it_registers_covers_them():
    import gymnasium as gym

    covered = set(yaml.safe_load((CONFIG_DIR / "trlsd.yml").read_text()))
    assert covered == {env_id for env_id in gym.registry if env_id.startswith("TRLSD/")}


def test_train_without_algo_or_config_takes_trlsd_and_the_package_config(tmp_path, monkeypatch):
    """A user with no checkout: ``sb3-trlsd train --env ID`` finds TRLSD's config of the env by its id."""
    monkeypatch.chdir(tmp_path)  # no zoo_configs/ folder around
    arguments = ["train", "--env", MAZE_ID, "-n", "40", "-f", str(tmp_path / "logs"), "--seed", "0"]
    assert main([*arguments, "-params", "source_transitions:300"]) == 0
    (saved,) = (tmp_path / "logs").glob("trlsd/*_1/*.zip")
    model = TRLSD.load(saved)
    assert model.num_timesteps == 40 and model.replay_buffer.size() == 340


def test_a_config_named_as_the_package_s_is_found_without_a_checkout(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    arguments = ["train", "--algo", "trlsd", "--env", MAZE_ID, "-conf", "known_reward", "-n", "20"]
    assert main([*arguments, "-f", str(tmp_path / "logs"), "-params", "source_transitions:300"]) == 0
    (saved,) = (tmp_path / "logs").glob("trlsd/*_1/*.zip")
    assert TRLSD.load(saved).config.reward_head == "known"


def test_an_env_no_config_covers_says_where_configs_are_looked_for(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--env", "CartPole-v1"]) == 2
    assert_one_line_error(capsys, "no config for CartPole-v1", "give one with -conf FILE", "trlsd.yml")
