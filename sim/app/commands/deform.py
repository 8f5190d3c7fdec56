"""`jiggle deform`: one pose skinned with LBS and then the muscles' deformers, compared (the simple
arm bent by --angle, or a character posed by a clip at --time).
"""
from __future__ import annotations

import os

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.args import (
    clip_options,
    influences_option,
    map_options,
    mesh_options,
    muscle_skin_options,
    non_negative,
    template_option,
)
from jiggle.sim.app.loading import load_clip, retarget_onto_character


def deform_pose(args):
    """(character, rig, world (J, 4, 4), pose description) for `jiggle deform`."""
    import numpy as np
    if args.character is None:
        if args.clip is not None:
            raise InputError("--clip needs a CHARACTER; without one the built-in simple arm bends by --angle",
                             field="--clip")
        from jiggle.rig.muscle.simple_arm import simple_arm
        arm = simple_arm()
        angle = 90.0 if args.angle is None else args.angle
        return arm.character, arm.rig, arm.world(angle), {"scene": "simple arm", "elbow_deg": angle}
    if args.angle is not None:
        raise InputError("--angle bends the built-in simple arm; pose a CHARACTER with --clip and --time",
                         field="--angle")
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
    if args.clip is None:
        raise InputError("give the pose: --clip FILE (retargeted onto the character) and --time S",
                         field="--clip")
    clip = retarget_onto_character(load_clip(args), args, character)
    t = 0.0 if args.time is None else args.time
    if not 0.0 <= t <= clip.duration:
        raise InputError(f"expected a time in [0, {clip.duration:.3f}] s of the clip, got {t}", field="--time")
    rot, tra = clip.sample(np.array([t]))
    world = transforms(*clip.world(rot, tra))[0]
    mus = fit_musculature(character, args.template or "auto", FitOptions(joint_map=args.character_map))
    pose = {"character": os.path.basename(args.character), "clip": os.path.basename(args.clip), "time_s": t}
    return character, mus, world, pose


def run(args) -> int:
    from jiggle.rig.muscle.fit import Musculature
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    from jiggle.sim.app.outputs.deform import write_deform_outputs
    character, rig, world, pose = deform_pose(args)
    if isinstance(rig, Musculature):
        skin = MuscleSkin.from_musculature(rig, skinning=args.skinning, method=args.method, mush=args.mush,
                                           weights=args.weights, character_path=args.character)
        views = ("front", "side")
    else:
        weights = None
        if args.weights is not None:
            from jiggle.rig.skin.shell.weights import load_weights
            weights = load_weights(args.weights, rig.names, character.num_vertices)
        skin = MuscleSkin(character, rig, skinning=args.skinning, method=args.method, mush=args.mush, weights=weights)
        views = ("side", "back")    # the arm's muscle faces +Y: its profile from the side, its face from +Y
    out = write_deform_outputs(skin, world, args.out, pose=pose, render=not args.no_render, views=views)
    f = out["facts"]
    print(f"{character.name or 'character'}: LBS + {f['muscles']} muscles ({args.skinning}), {f['pairs']} "
          f"(vertex, muscle) pairs kept at bind ({f['pairs_per_vertex']:.2f} per vertex); skin moved from LBS by "
          f"up to {f['max_displacement_mm']:.2f} mm (RMS {f['rms_displacement_mm']:.2f} mm)")
    for k, path in out["files"].items():
        print(f"  {k:8s} {path}")
    return 0


def add_parser(sub) -> None:
    """The `jiggle deform` subcommand and its options."""
    p = sub.add_parser("deform", help="skin one pose with the muscles' deformers and compare with LBS",
                       description="Pose a character (or the built-in simple arm: a cylinder on two bones with "
                                   "one muscle, the thesis's example), skin it with LBS and then the muscles' "
                                   "shell deformers (or influence objects), and write deform.png (LBS | muscles, "
                                   "coloured by the move from LBS), deform.json and deform.ply to --out.")
    p.add_argument("character", nargs="?", metavar="CHARACTER",
                   help="a skinned glTF/GLB (muscles fitted from --template); default: the simple arm")
    p.add_argument("--clip", metavar="FILE", help="the pose's clip (BVH, AMC, glTF), retargeted onto CHARACTER")
    p.add_argument("--time", type=non_negative("--time"), metavar="S", help="seconds into --clip (default: 0)")
    p.add_argument("--angle", type=float, metavar="DEG", help="simple arm: elbow flexion in degrees (default: 90)")
    muscle_skin_options(p)
    p.add_argument("--weights", metavar="NPZ", help="painted per-vertex muscle weights (default: "
                   "<character>.shell_weights.npz beside the character when present, else 1)")
    template_option(p)
    map_options(p)
    influences_option(p)
    p.add_argument("--out", default="out/deform", help="output folder (default: out/deform)")
    p.add_argument("--no-render", action="store_true", help="skip the picture")
    mesh_options(p)
    clip_options(p)
    p.set_defaults(func=run)
