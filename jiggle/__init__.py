"""jiggle: physics-backed muscle jiggle and secondary motion for animated characters.

The public Python API (documented in the site's API reference; everything else is internal):

    import jiggle
    bake = jiggle.bake("walk.bvh", "hero.glb", muscles={"belly_fat": {"strength": 0.5}})
    bake.skin_final            # (T, V, 3) float32 metres, read-only

`bake`, `Bake`, `Metrics`, `InputError`, `Material` (with `FAT` and `MUSCLE`: tissue in physical units), and the stages for a pipeline of one's own: `load_character`,
`load_clip`, `fit`, `simulate`. They load on first use, so `import jiggle` stays light.

The pipeline's stage packages are installed under this one (jiggle.rig, jiggle.sim, jiggle.scenes); in a source
checkout they are the folders rig/, sim/ and scenes/ beside this one, reached through the links jiggle/rig, jiggle/sim
and jiggle/scenes (docs/contributing.md).
"""
from __future__ import annotations

from jiggle._version import __version__

__all__ = ["__version__", "bake", "Bake", "Metrics", "InputError", "load_character", "load_clip", "fit", "simulate",
           "Muscles", "Simulation", "Character", "Clip", "Material", "FAT", "MUSCLE"]


def __getattr__(name: str):
    if name in __all__:
        from jiggle import api
        return getattr(api, name)
    raise AttributeError(f"module 'jiggle' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
