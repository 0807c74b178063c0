"""The library stands apart from its lab: ``import sb3_trlsd`` loads no lab module, none of the lab's
dependencies (Ray, joblib, matplotlib) and not Minari (an optional extra), so a user of the algorithm needs
none of them."""

import json
import subprocess
import sys

# What importing the library must not load: the lab, the dependencies of the ``experiments`` extra, and
# those of the ``minari`` extra (loaded only for a Minari dataset).
NOT_LOADED = ("sb3_trlsd_lab", "ray", "joblib", "matplotlib", "minari", "h5py", "jax")


def loaded_packages(code: str) -> set[str]:
    """The top-level packages in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    listing = "import json, sys\nprint(json.dumps(sorted({name.split('.')[0] for name in sys.modules})))"
    script = f"{code}\n{listing}"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return set(json.loads(result.stdout.splitlines()[-1]))


def test_importing_the_library_loads_no_lab_ray_joblib_matplotlib_or_minari():
    loaded = loaded_packages("import sb3_trlsd, gymnasium as gym\ngym.make('TRLSD/SharedDynamicsMaze-v0')")
    assert "sb3_trlsd" in loaded and "sb3_trlsd_envs" in loaded
    assert not loaded & set(NOT_LOADED), f"import sb3_trlsd loaded {sorted(loaded & set(NOT_LOADED))}"


def test_loading_transitions_that_are_not_minaris_loads_no_minari():
    """Transitions and an SB3 buffer go in without Minari, whose extra a user of them need not install."""
    code = (
        "import gymnasium as gym\n"
        "from stable_baselines3 import DQN\n"
        "from sb3_trlsd import TRLSD, collect_transitions\n"
        "env = gym.make('TRLSD/SharedDynamicsMaze-v0')\n"
        "model = TRLSD('LinearPolicy', env)\n"
        "model.load_transitions(collect_transitions(env, 10, seed=0))\n"
        "model.load_transitions(DQN('MultiInputPolicy', env, learning_starts=100).learn(10).replay_buffer)\n"
    )
    assert not loaded_packages(code) & {"minari", "h5py", "jax"}


def test_the_envs_load_matplotlib_only_to_draw():
    """The maze made with a render mode, reset and stepped, has drawn nothing yet."""
    code = (
        "import sb3_trlsd_envs, gymnasium as gym\n"
        "for name in ('MAZE_ID', 'FOUR_ROOMS_ID', 'GOAL_CARTPOLE_ID'):\n"
        "    env = gym.make(getattr(sb3_trlsd_envs, name), render_mode='rgb_array')\n"
        "    env.reset(seed=0)\n"
        "    env.step(env.action_space.sample())\n"
    )
    assert "matplotlib" not in loaded_packages(code)
