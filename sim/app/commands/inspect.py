"""`jiggle inspect FILE`: describe a clip, a character or a MuJoCo model (text or --json).
"""
from __future__ import annotations

import json

from jiggle.sim.app.args import animation, clip_options


def run(args) -> int:
    from jiggle.sim.app.outputs.inspect import format_report, inspect_file
    report = inspect_file(args.file, skeleton=args.skeleton, animation=animation(args.animation),
                          scale=args.scale, tpose=args.tpose)
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


def add_parser(sub) -> None:
    """The `jiggle inspect` subcommand and its options."""
    p = sub.add_parser("inspect", help="describe a clip, character or MuJoCo model file",
                       description="Describe a file: for a clip (BVH, AMC, ASF, glTF/GLB animation) its joints, "
                                   "frames, fps, duration, units and detected T-pose; for a character (glTF/GLB, OBJ, "
                                   "PLY, STL) its vertices, faces, joints, skins and animations; for an MJCF its "
                                   "bodies and joints.")
    p.add_argument("file", help="the file to describe")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    clip_options(p)
    p.set_defaults(func=run)
