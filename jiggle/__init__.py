"""jiggle: physics-backed muscle jiggle and secondary motion for animated characters.

The public Python API (documented in the site's API reference; everything else is internal):

    import jiggle
    bake = jiggle.bake("walk.bvh", "hero.glb", muscles={"belly_fat": {"strength": 0.5}})
    bake.skin_final            # (T, V, 3) float32 metres, read-only

`bake`, `Bake`, `Metrics`, `InputError`, and the stages for a pipeline of one's own: `load_character`,
`load_clip`, `fit`, `simulate`. They load on first use, so `import jiggle` stays light.

The pipeline's stage packages are installed under this one (jiggle.rig, jiggle.sim, jiggle.scenes); in a source
checkout they are the folders rig/, sim/ and scenes/ beside this one.
"""
from __future__ import annotations

import os as _os

from jiggle._version import __version__

_here = _os.path.dirname(_os.path.abspath(__file__))
if not _os.path.isdir(_os.path.join(_here, "rig")):       # a source checkout: the stage folders sit beside jiggle/
    __path__.append(_os.path.dirname(_here))               # noqa: F821 (a package's own __path__)

__all__ = ["__version__", "bake", "Bake", "Metrics", "InputError", "load_character", "load_clip", "fit", "simulate",
           "Muscles", "Simulation", "Character", "Clip"]


def __getattr__(name: str):
    if name in __all__:
        from jiggle import api
        return getattr(api, name)
    raise AttributeError(f"module 'jiggle' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
