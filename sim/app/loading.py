"""What several subcommands load from their arguments: the clip, the clip retargeted onto a
character, a body generated around a skeleton, and the built-in demo scene's path.
"""
from __future__ import annotations

import sys

from jiggle.sim.app.args import animation


def load_clip(args):
    from jiggle.rig.motion.mocap import load_clip
    return load_clip(args.clip, skeleton=args.skeleton, animation=animation(args.animation),
                     scale=args.scale, tpose=args.tpose)


def retarget_onto_character(clip, args, character):
    """`clip` on the skeleton of the skinned glTF `args.character`, read as `character` (its unit)."""
    from jiggle.rig.motion.retarget_onto import retarget_onto
    return retarget_onto(clip, args.character, args.skin, args.clip_map, args.character_map, print,
                         scale=character.meta.get("unit_scale", 1.0))


def body_overrides(args) -> dict:
    """The generated body's options given on the command line (--resolution and the fat volumes)."""
    return {k: getattr(args, k) for k in ("resolution", "belly", "chest", "glutes", "upper_arms")
            if getattr(args, k, None) is not None}


def body_options(args):
    from jiggle.rig.character.body import BodyOptions
    return BodyOptions(**body_overrides(args))


def generated_character(clip, args, quiet=False):
    import time

    from jiggle.rig.character.load import body_character
    t = time.perf_counter()
    character = body_character(clip, body_options(args), k=args.influences)
    if not quiet:
        print(f"generated a body for {clip.name!r}: {character.num_vertices} vertices, automatic weights "
              f"({time.perf_counter() - t:.1f} s)", file=sys.stderr)
    return character


def default_scene() -> str:
    from jiggle.sim.bake.scene import default_scene as path
    return path()
