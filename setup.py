"""The package list pyproject.toml cannot say: the repository keeps its pipeline's stage folders at the top (rig/, sim/,
scenes/: ARCHITECTURE.md), and they install under `jiggle` (jiggle.rig, jiggle.sim, jiggle.scenes), so a user's
environment gains the one import name `jiggle`, not generic ones such as `sim`. The links jiggle/rig -> ../rig,
jiggle/sim -> ../sim and jiggle/scenes -> ../scenes put the stage folders where those names say, for Python, for
setuptools (a wheel holds them once, as files) and for every tool that follows imports through the files
(docs/contributing.md). Everything else is in pyproject.toml."""
from setuptools import find_namespace_packages, setup


def packages() -> list[str]:
    """jiggle and every folder under it, the linked stage folders entered (data folders too: their files are package
    data)."""
    return ["jiggle"] + [f"jiggle.{p}" for p in find_namespace_packages("jiggle", exclude=["*__pycache__*"])]


setup(packages=packages())
