"""The set-up's lock, ``constraints.txt``: every package the ``dev`` extra needs is pinned, torch at the CPU
build these machines install, and what is installed is what the lock says (the README's commands install
through it)."""

from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name

ROOT = Path(__file__).parents[1]


def pins() -> dict[str, str]:
    """The lock's ``name==version`` lines, by canonical name."""
    found = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            requirement = Requirement(line)
            found[canonicalize_name(requirement.name)] = str(requirement.specifier)
    return found


def needed(name: str, extras: set[str]) -> set[str]:
    """What ``name`` with ``extras`` needs, transitively: canonical names, its own excluded."""
    environment = default_environment()
    visited: set[tuple[str, frozenset[str]]] = set()
    pending = [(canonicalize_name(name), frozenset(extras))]
    while pending:
        current, wanted = pending.pop()
        if (current, wanted) in visited:
            continue
        visited.add((current, wanted))
        for text in metadata.requires(current) or []:
            requirement = Requirement(text)
            if requirement.marker is not None and not any(
                requirement.marker.evaluate({**environment, "extra": extra}) for extra in {*wanted, ""}
            ):
                continue
            pending.append((canonicalize_name(requirement.name), frozenset(requirement.extras)))
    return {found for found, _ in visited} - {canonicalize_name(name)}


def test_every_package_the_dev_extra_needs_is_pinned_at_the_installed_version():
    """A package left out of the lock resolves to whatever a fresh machine finds: not what was tested."""
    lock = pins()
    dependencies = needed("sb3-trlsd", {"dev"})
    assert {"torch", "stable-baselines3", "gymnasium", "ray", "pytest-timeout"} <= dependencies
    missing = sorted(dependencies - set(lock))
    assert not missing, f"constraints.txt pins none of {missing}: refresh it with bash .ci/lock"
    for name in sorted(dependencies):
        installed = metadata.version(name)
        assert SpecifierSet(lock[name]).contains(installed, prereleases=True), (
            f"{name} {installed} is installed, the lock says {lock[name]}: install through constraints.txt"
        )


def test_torch_is_pinned_at_the_cpu_build_and_the_metadata_keeps_a_range():
    assert pins()["torch"] == "==2.13.0"
    torch = [Requirement(text) for text in metadata.requires("sb3-trlsd") or [] if text.startswith("torch")]
    assert [str(requirement.specifier) for requirement in torch] == [">=2.3"]
