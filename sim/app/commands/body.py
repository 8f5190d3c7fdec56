"""`jiggle body [SKELETON]`: a body generated around a skeleton with automatic weights, written as
pictures, a PLY and its facts.
"""
from __future__ import annotations

import os

from jiggle.sim.app.args import character_options
from jiggle.sim.app.loading import default_scene, generated_character


def run(args) -> int:
    from jiggle.sim.app.outputs.body import write_body_outputs
    if args.skeleton_file is None:
        from jiggle.sim.bake.scene import load_scene
        clip = load_scene(default_scene()).clip
    else:
        from jiggle.rig.character.load import load_skeleton
        clip = load_skeleton(args.skeleton_file)
    character = generated_character(clip, args)
    files = write_body_outputs(character, args.out, render=not args.no_render)
    print(f"body for {clip.name!r}: {character.num_vertices} vertices, {len(character.faces)} faces, "
          f"{character.height:.3f} m tall, {character.num_joints} joints -> {os.path.abspath(args.out)}")
    for k, f in files.items():
        print(f"  {k:13s} {os.path.join(args.out, f)}")
    return 0


def add_parser(sub) -> None:
    """The `jiggle body` subcommand and its options."""
    p = sub.add_parser("body", help="generate a body mesh around a skeleton, with automatic weights",
                       description="Generate a smooth, closed body around a skeleton (proportions from its bone "
                                   "lengths, optional fat volumes) with automatic weights, and write body.png "
                                   "(front and side), weights.png (coloured by dominant joint), body.ply and "
                                   "body.json to --out.")
    p.add_argument("skeleton_file", nargs="?", metavar="SKELETON",
                   help="a clip (BVH, AMC, ASF, glTF), an MJCF model or a skinned glTF (default: the demo's skeleton)")
    p.add_argument("--out", default="out/body", help="output folder (default: out/body)")
    p.add_argument("--no-render", action="store_true", help="skip the pictures")
    character_options(p)
    p.set_defaults(func=run)
