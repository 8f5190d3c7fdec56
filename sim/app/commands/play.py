"""`jiggle play CLIP`: a clip on its skeleton through MuJoCo (kinematic, physics or your own MJCF),
with a character skinned over it, written as pictures, plots and the motion (sim/app/outputs/play.py).
"""
from __future__ import annotations

import os
import sys

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.args import character_options, clip_options, count, map_options, mesh_options, positive
from jiggle.sim.app.loading import generated_character, load_clip, retarget_onto_character


def play_clip(clip, out_dir, drive, poses, render, fps=None, mjcf=None, joint_map=None, character=None,
          skinning="lbs"):
    from tqdm import tqdm

    from jiggle.sim.app.outputs.play import write_outputs
    from jiggle.sim.drive.motion import drive_kinematic, drive_mjcf, drive_physics

    if fps is not None:
        clip = clip.resample(fps)
    times = clip.times
    if mjcf is not None:
        if drive == "physics":
            raise InputError("--mjcf drives the user's model kinematically; --drive physics uses the model "
                             "jiggle builds from the clip", field="--drive")
        body_map = None
        if joint_map is not None:
            from jiggle.sim.drive.mjcf_drive import read_body_map
            body_map = read_body_map(joint_map)
        runner = lambda c, t, progress: drive_mjcf(c, t, mjcf, body_map, progress=progress)  # noqa: E731
    else:
        runner = drive_physics if drive == "physics" else drive_kinematic
    with tqdm(total=len(times), unit="frame", desc=f"{clip.name} ({drive})", disable=None,
              file=sys.stderr) as bar:
        motion = runner(clip, times, progress=bar.update)
    summary = write_outputs(motion, clip.name, out_dir, poses=poses, render=render, source=clip.source,
                            character=character, skin_method=skinning)
    print(f"{summary['frames']} frames of {clip.name!r} ({summary['duration_s']:.2f} s, "
          f"{summary['joints']} joints, {summary['drive']} drive) -> {os.path.abspath(out_dir)}")
    for k, f in summary["files"].items():
        print(f"  {k:13s} {os.path.join(out_dir, f)}")
    if "character" in summary:
        c = summary["character"]
        print(f"  character: {c['name'] or 'generated body'}, {c['vertices']} vertices, {c['joints']} joints, "
              f"weights from {c['weights']}, {c['skinning'].upper()} skinning")
    if "rms_joint_error_m" in summary:
        print(f"  tracking error: RMS {summary['rms_joint_error_m'] * 100:.2f} cm, max "
              f"{summary['max_joint_error_m'] * 100:.2f} cm; deepest foot below the floor "
              f"{summary['max_foot_penetration_m'] * 1000:.1f} mm; feet carry "
              f"{summary['mean_foot_force_over_weight']:.2f} x body weight on average")
    return summary


def run(args) -> int:
    clip = load_clip(args)
    if args.start is not None or args.end is not None:
        clip = clip.between(args.start or 0.0, args.end)
    if args.speed is not None:
        clip = clip.with_speed(args.speed)
    character = None
    if args.character is not None:
        from jiggle.rig.character.gltf_character import gltf_has_skin
        from jiggle.rig.character.load import load_character
        if args.character.lower().endswith((".glb", ".gltf")) and gltf_has_skin(args.character):
            character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
            clip = retarget_onto_character(clip, args, character)
        else:
            # a mesh standing in the clip's rest pose: the clip's skeleton skins it
            character = load_character(args.character, skeleton=clip, k=args.influences, unit=args.unit,
                                       up=args.up)
    elif not args.no_character and args.mjcf is None:
        character = generated_character(clip, args)
    if character is not None and args.mjcf is not None:
        raise InputError("--mjcf poses the user's model, whose bodies do not skin a character; add "
                         "--no-character", field="--mjcf")
    play_clip(clip, args.out, args.drive, args.poses, not args.no_render, fps=args.fps, mjcf=args.mjcf,
          joint_map=args.mjcf_map, character=character, skinning=args.skinning)
    return 0


def add_parser(sub) -> None:
    """The `jiggle play` subcommand and its options."""
    p = sub.add_parser("play", help="play a clip on its skeleton through MuJoCo and write pictures",
                       description="Play a mocap clip on its own skeleton through MuJoCo and write to --out: "
                                   "skeleton.png (the skeleton over time), trajectories.png (joint positions over "
                                   "time), motion.npz (bone world transforms per frame) and summary.json.")
    p.add_argument("clip", help="BVH, AMC (with its ASF), or glTF/GLB with animations")
    p.add_argument("--out", default="out/play", help="output folder (default: out/play)")
    p.add_argument("--start", type=float, metavar="S", help="start, seconds of the clip (default: 0)")
    p.add_argument("--end", type=float, metavar="E", help="end, seconds of the clip (default: its end)")
    p.add_argument("--fps", type=positive("--fps"), help="output frame rate (default: the clip's)")
    p.add_argument("--speed", type=positive("--speed"), help="play this many times faster (default: 1)")
    p.add_argument("--drive", choices=["kinematic", "physics"], default="kinematic",
                   help="kinematic: MuJoCo poses the bones from the clip; physics: MuJoCo simulates the body "
                        "on a floor following the clip (default: kinematic)")
    p.add_argument("--poses", type=count("--poses"), default=8, help="poses in the skeleton picture (default: 8)")
    p.add_argument("--no-render", action="store_true", help="skip the 3D picture (plots and data only)")
    g = p.add_argument_group("retargeting onto a character's skeleton")
    g.add_argument("--character", metavar="FILE", help="the character to skin: a skinned glTF/GLB or FBX (the clip is "
                   "retargeted onto its skeleton), or an OBJ/PLY/STL/unskinned glTF mesh standing in the clip's "
                   "rest pose (automatic weights). Default: a body generated around the clip's skeleton")
    map_options(g, alias=False)
    mesh_options(g)
    character_options(p)
    g = p.add_argument_group("your own MuJoCo model")
    g.add_argument("--mjcf", metavar="XML", help="drive this MJCF instead of the model built from the clip "
                   "(e.g. dm_control's humanoid_CMU.xml with a CMU AMC clip)")
    g.add_argument("--mjcf-map", "--joint-map", dest="mjcf_map", metavar="TOML", help="clip joint -> MJCF body "
                   "names, a [joints] table (default: clip joints drive the bodies of the same name; --joint-map is "
                   "the old name)")
    clip_options(p)
    p.set_defaults(func=run)
