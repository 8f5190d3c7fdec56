"""The package layout pyproject.toml cannot say: the repository keeps its pipeline's stage folders at the top
(rig/, sim/, scenes/: ARCHITECTURE.md), and they install under `jiggle` (jiggle.rig, jiggle.sim, jiggle.scenes),
so a user's environment gains the one import name `jiggle`, not generic ones such as `sim`. Everything else is in
pyproject.toml."""
from setuptools import find_namespace_packages, setup

STAGES = ("rig", "sim", "scenes")


def packages() -> list[str]:
    """jiggle, and every folder of the stages under it (data folders too: their files are package data)."""
    out = ["jiggle"]
    for top in STAGES:
        out += [f"jiggle.{top}"] + [f"jiggle.{top}.{p}" for p in find_namespace_packages(top, exclude=["*__pycache__*"])]
    return out


setup(packages=packages(), package_dir={"jiggle": "jiggle", **{f"jiggle.{top}": top for top in STAGES}})
