"""The library stands apart from its lab: ``import sb3_trlsd`` loads no lab module and none of the lab's
dependencies (Ray, joblib, matplotlib), so a user of the algorithm needs none of them."""

import json
import subprocess
import sys

# What importing the library must not load: the lab and the dependencies of the ``experiments`` extra.
NOT_LOADED = ("sb3_trlsd_lab", "ray", "joblib", "matplotlib")


def loaded_packages(code: str) -> set[str]:
    """The top-level packages in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    listing = "import json, sys\nprint(json.dumps(sorted({name.split('.')[0] for name in sys.modules})))"
    script = f"{code}\n{listing}"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return set(json.loads(result.stdout.splitlines()[-1]))


def test_importing_the_library_loads_no_lab_ray_joblib_or_matplotlib():
    loaded = loaded_packages("import sb3_trlsd, gymnasium as gym\ngym.make('TRLSD/SharedDynamicsMaze-v0')")
    assert "sb3_trlsd" in loaded and "sb3_trlsd_envs" in loaded
    assert not loaded & set(NOT_LOADED), f"import sb3_trlsd loaded {sorted(loaded & set(NOT_LOADED))}"


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
