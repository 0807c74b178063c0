"""The distribution: every package of the checkout is in it, with its type marker, the license and the Zoo
configs; the configs are found by name once installed."""

import shutil
import subprocess
import sys
import zipfile
from importlib import resources
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # the standard library's from Python 3.11

ROOT = Path(__file__).parents[1]
# What the distribution is made of.
DISTRIBUTED = ("pyproject.toml", "README.md", "LICENSE", "MANIFEST.in", "CHANGELOG.md", "constraints.txt")
DISTRIBUTED += ("sb3_trlsd", "sb3_trlsd_lab", "envs", "zoo_configs")
PACKAGE_ROOTS = {"sb3_trlsd": ROOT / "sb3_trlsd", "sb3_trlsd_envs": ROOT / "envs" / "sb3_trlsd_envs"}
PACKAGE_ROOTS["sb3_trlsd_lab"] = ROOT / "sb3_trlsd_lab"


def checkout_packages() -> set[str]:
    """Every folder with an ``__init__.py`` under the three packages, by import name, and the Zoo configs."""
    found = {"sb3_trlsd.zoo_configs"}
    for name, folder in PACKAGE_ROOTS.items():
        for init in folder.rglob("__init__.py"):
            parts = init.parent.relative_to(folder).parts
            found.add(".".join([name, *parts]))
    return found


def test_the_distribution_lists_every_package_of_the_checkout():
    """A package left out of pyproject's list is missing from the wheel: an ImportError once installed."""
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert set(settings["packages"]) == checkout_packages()
    assert settings["package-dir"] == {
        "sb3_trlsd_envs": "envs/sb3_trlsd_envs",
        "sb3_trlsd.zoo_configs": "zoo_configs",
    }


def test_the_wheel_holds_the_type_markers_the_license_and_the_zoo_configs(tmp_path):
    # Built from a copy of what the wheel is made of: a build writes its build/ folder beside the sources.
    source = tmp_path / "source"
    source.mkdir()
    for name in DISTRIBUTED:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(ROOT / name, source / name)
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(source),
        ],
        check=True,
        capture_output=True,
        timeout=200,
    )
    (wheel,) = tmp_path.glob("sb3_trlsd-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"sb3_trlsd/py.typed", "sb3_trlsd_envs/py.typed", "sb3_trlsd_lab/py.typed"} <= names
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)
    configs = {path.name for path in (ROOT / "zoo_configs").glob("*.yml")}
    assert configs and {f"sb3_trlsd/zoo_configs/{name}" for name in configs} <= names
    packaged = {name.rsplit("/", 1)[0].replace("/", ".") for name in names if name.endswith("__init__.py")}
    assert packaged == checkout_packages()


def test_the_installed_package_finds_the_zoo_configs_by_name():
    found = {path.name for path in resources.files("sb3_trlsd.zoo_configs").iterdir()}
    assert {path.name for path in (ROOT / "zoo_configs").glob("*.yml")} <= found
