"""The `jiggle` command line.

Every user mistake (a bad file, a bad parameter) ends as one line on stderr naming the file, line or
parameter and what was expected, with exit code 2; tracebacks are for jiggle's own bugs.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass
from typing import Callable

from rig.base.errors import InputError

EXIT_USER_ERROR = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own exit code is 2 too; keep the one-line style
        self.print_usage(sys.stderr)
        self.exit(EXIT_USER_ERROR, f"jiggle: error: {message}\n")


def _clip_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("clip reading")
    g.add_argument("--skeleton", metavar="ASF", help="the ASF skeleton of an AMC clip (default: the one .asf beside it)")
    g.add_argument("--animation", metavar="NAME|INDEX", help="glTF animation to play (default: the first)")
    g.add_argument("--scale", type=float, metavar="M", help="BVH metres per file unit (default: CMU recognised, else guessed from height)")
    g.add_argument("--tpose", choices=["auto", "skip", "keep"], default="auto",
                   help="BVH first frame: auto drops a T-pose added by converters (CMU), skip always drops it, keep never (default: auto)")


def _character_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("character and generated body")
    if p.prog.split()[-1] not in ("body", "fit", "simulate"):
        g.add_argument("--no-character", action="store_true", help="skeleton only: no body, no skinning")
        g.add_argument("--skinning", choices=["lbs", "dqs"], default="lbs",
                       help="linear blend or dual-quaternion skinning (default: lbs)")
    g.add_argument("--influences", type=_count("--influences"), default=4, metavar="K",
                   help="skin weights kept per vertex (default: 4)")
    g.add_argument("--resolution", type=_count("--resolution"), metavar="N",
                   help="generated body: target vertex count, 10000-40000 useful (default: 20000)")
    from rig.character.body import BodyOptions
    for name, what in (("belly", "belly"), ("chest", "chest"), ("glutes", "glutes"), ("upper-arms", "upper arms")):
        default = getattr(BodyOptions(), name.replace("-", "_"))
        g.add_argument(f"--{name}", type=_non_negative(f"--{name}"), metavar="M",
                       help=f"generated body: fat on the {what}, metres it pushes the skin out; 0 for none "
                            f"(default: {default:g})")


def _mesh_options(g) -> None:
    """How to read a character file: --skin, --unit, --up (play and fit)."""
    g.add_argument("--skin", type=int, default=0, metavar="N", help="which skin of a glTF character (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the character file's unit: m, cm, mm, in, ft or metres per unit "
                   "(default: m)")
    g.add_argument("--up", choices=["auto", "y", "z"], default="auto",
                   help="up axis of an OBJ/PLY/STL character (default: auto, the longer of y and z)")


def _map_options(g) -> None:
    """Joint maps for retargeting a clip onto a character: --clip-map, --character-map (play and deform)."""
    g.add_argument("--clip-map", metavar="TOML|PRESET", help="joint map of the clip (default: the built-in preset that fits, e.g. cmu)")
    g.add_argument("--character-map", metavar="TOML|PRESET", help="joint map of the character (default: the built-in preset that fits, e.g. cesiumman)")


def _non_negative(name):
    def conv(v):
        try:
            x = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {v!r}") from None
        if not 0 <= x < float("inf"):
            raise argparse.ArgumentTypeError(f"{name} must be zero or more, got {v!r}")
        return x
    return conv


def _animation(value):
    if value is None:
        return None
    return int(value) if value.lstrip("-").isdigit() else value


def _load_clip(args):
    from rig.motion.mocap import load_clip
    return load_clip(args.clip, skeleton=args.skeleton, animation=_animation(args.animation),
                     scale=args.scale, tpose=args.tpose)


def _positive(name):
    def conv(v):
        try:
            x = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {v!r}") from None
        if not x > 0 or x == float("inf"):
            raise argparse.ArgumentTypeError(f"{name} must be a positive number, got {v!r}")
        return x
    return conv


def _count(name, zero=False):
    least = 0 if zero else 1

    def conv(v):
        try:
            n = int(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a whole number, got {v!r}") from None
        if n < least:
            raise argparse.ArgumentTypeError(f"{name} must be at least {least}, got {v!r}")
        return n
    return conv


def _unit_interval(name):
    def conv(v):
        try:
            x = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {v!r}") from None
        if not 0.0 <= x <= 1.0:
            raise argparse.ArgumentTypeError(f"{name} must be in [0, 1], got {v!r}")
        return x
    return conv


# ---------------------------------------------------------------------------------------- inspect
def cmd_inspect(args) -> int:
    from sim.app.describe import format_report, inspect_file
    report = inspect_file(args.file, skeleton=args.skeleton, animation=_animation(args.animation),
                          scale=args.scale, tpose=args.tpose)
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


# ---------------------------------------------------------------------------------------- play / demo
def _play(clip, out_dir, drive, poses, render, fps=None, mjcf=None, joint_map=None, character=None,
          skinning="lbs"):
    from tqdm import tqdm

    from sim.app.play import write_outputs
    from sim.drive.motion import drive_kinematic, drive_mjcf, drive_physics

    if fps is not None:
        clip = clip.resample(fps)
    times = clip.times
    if mjcf is not None:
        if drive == "physics":
            raise InputError("--mjcf drives the user's model kinematically; --drive physics uses the model "
                             "jiggle builds from the clip", field="--drive")
        body_map = None
        if joint_map is not None:
            from sim.drive.mjcf_drive import read_body_map
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


def _retarget_onto_character(clip, args):
    from rig.motion.retarget import retarget_onto
    return retarget_onto(clip, args.character, args.skin, args.clip_map, args.character_map, print)


def cmd_play(args) -> int:
    clip = _load_clip(args)
    if args.start is not None or args.end is not None:
        clip = clip.between(args.start or 0.0, args.end)
    if args.speed is not None:
        clip = clip.with_speed(args.speed)
    character = None
    if args.character is not None:
        from rig.character.gltf_character import gltf_has_skin
        from rig.character.load import load_character
        if args.character.lower().endswith((".glb", ".gltf")) and gltf_has_skin(args.character):
            clip = _retarget_onto_character(clip, args)
            character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
        else:
            # a mesh standing in the clip's rest pose: the clip's skeleton skins it
            character = load_character(args.character, skeleton=clip, k=args.influences, unit=args.unit,
                                       up=args.up)
    elif not args.no_character and args.mjcf is None:
        character = _generated_character(clip, args)
    if character is not None and args.mjcf is not None:
        raise InputError("--mjcf poses the user's model, whose bodies do not skin a character; add "
                         "--no-character", field="--mjcf")
    _play(clip, args.out, args.drive, args.poses, not args.no_render, fps=args.fps, mjcf=args.mjcf,
          joint_map=args.joint_map, character=character, skinning=args.skinning)
    return 0


def _body_options(args):
    from rig.character.body import BodyOptions
    kw = {k: getattr(args, k) for k in ("resolution", "belly", "chest", "glutes", "upper_arms")
          if getattr(args, k, None) is not None}
    return BodyOptions(**kw)


def _generated_character(clip, args, quiet=False):
    import time

    from rig.character.load import body_character
    t = time.perf_counter()
    character = body_character(clip, _body_options(args), k=args.influences)
    if not quiet:
        print(f"generated a body for {clip.name!r}: {character.num_vertices} vertices, automatic weights "
              f"({time.perf_counter() - t:.1f} s)", file=sys.stderr)
    return character


def default_scene() -> str:
    from sim.bake.scene import default_scene as path
    return path()


def cmd_demo(args) -> int:
    """Bake the built-in scene and compare static with dynamic: the README's first command."""
    import time
    t = time.perf_counter()
    args.scene = args.scene or default_scene()
    summary = run_bake(bake_request(args), args.out, resume=args.resume)
    _print_bake(summary, args.out)
    res = _compare(args.out, render=not args.no_render, video=not args.no_video)
    report = res["files"].get("report", os.path.join(args.out, "report.html"))
    print(f"demo done in {time.perf_counter() - t:.0f} s; open the report: {os.path.abspath(report)}")
    return 0


# ---------------------------------------------------------------------------------------- body
def cmd_body(args) -> int:
    from sim.app.body_outputs import write_body_outputs
    if args.skeleton_file is None:
        from sim.bake.scene import load_scene
        clip = load_scene(default_scene()).clip
    else:
        from rig.character.load import load_skeleton
        clip = load_skeleton(args.skeleton_file)
    character = _generated_character(clip, args)
    files = write_body_outputs(character, args.out, render=not args.no_render)
    print(f"body for {clip.name!r}: {character.num_vertices} vertices, {len(character.faces)} faces, "
          f"{character.height:.3f} m tall, {character.num_joints} joints -> {os.path.abspath(args.out)}")
    for k, f in files.items():
        print(f"  {k:13s} {os.path.join(args.out, f)}")
    return 0


# ---------------------------------------------------------------------------------------- fit
SKELETON_SUFFIXES = (".bvh", ".asf", ".amc", ".toml", ".xml")


def fit_character(path: str | None, args):
    """The character `jiggle fit` works on: a skinned glTF, a mesh with --skeleton, or a body generated
    around a skeleton file (clip, ASF, MJCF, keyframed TOML); None: the demo's generated body."""
    from rig.character.load import load_character, load_skeleton
    if path is None:
        from sim.bake.scene import load_scene
        return _generated_character(load_scene(default_scene()).clip, args)
    if os.path.splitext(path)[1].lower() in SKELETON_SUFFIXES:
        return _generated_character(load_skeleton(path), args)
    return load_character(path, skeleton=args.skeleton, k=args.influences, unit=args.unit, up=args.up,
                          skin=args.skin)


def cmd_fit(args) -> int:
    import numpy as np

    from rig.muscle.fit import FitOptions, fit_musculature
    from sim.app.fit_outputs import write_fit_outputs
    character = fit_character(args.character, args)
    options = FitOptions(iterations=args.iterations, lam=args.smoothing, volume=args.volume,
                         joint_map=args.joint_map, exclude=tuple(args.exclude or ()))
    mus = fit_musculature(character, args.template or "human", options)
    png = None if args.no_render else (args.png or os.path.join(os.path.dirname(args.out) or ".", "fit.png"))
    json_path = os.path.splitext(args.out)[0] + ".json"
    files = write_fit_outputs(mus, args.out, png, json_path)
    rig = mus.rig
    print(f"fitted {len(mus.muscles)} muscles ({sum(m.kind == 'fat' for m in mus.muscles)} fat) from template "
          f"{mus.template.name!r} to {character.name or 'the character'} ({character.num_vertices} vertices) in "
          f"{mus.timings['total']:.2f} s; loft fit error rms {1e3 * float(np.sqrt(np.mean(rig.fit_rms ** 2))):.2f} mm, "
          f"worst {1e3 * float(rig.fit_max.max()):.2f} mm")
    for k, f in files.items():
        print(f"  {k:9s} {f}")
    return 0


# ---------------------------------------------------------------------------------------- deform
def _deform_pose(args):
    """(character, rig, world (J, 4, 4), pose description) for `jiggle deform`."""
    import numpy as np
    if args.character is None:
        if args.clip is not None:
            raise InputError("--clip needs a CHARACTER; without one the built-in simple arm bends by --angle",
                             field="--clip")
        from rig.muscle.simple_arm import simple_arm
        arm = simple_arm()
        angle = 90.0 if args.angle is None else args.angle
        return arm.character, arm.rig, arm.world(angle), {"scene": "simple arm", "elbow_deg": angle}
    if args.angle is not None:
        raise InputError("--angle bends the built-in simple arm; pose a CHARACTER with --clip and --time",
                         field="--angle")
    from rig.character.load import load_character
    from rig.motion.clip import transforms
    from rig.muscle.fit import FitOptions, fit_musculature
    character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
    if args.clip is None:
        raise InputError("give the pose: --clip FILE (retargeted onto the character) and --time S",
                         field="--clip")
    clip = _retarget_onto_character(_load_clip(args), args)
    t = 0.0 if args.time is None else args.time
    if not 0.0 <= t <= clip.duration:
        raise InputError(f"expected a time in [0, {clip.duration:.3f}] s of the clip, got {t}", field="--time")
    rot, tra = clip.sample(np.array([t]))
    world = transforms(*clip.world(rot, tra))[0]
    mus = fit_musculature(character, args.template or "human", FitOptions(joint_map=args.joint_map))
    pose = {"character": os.path.basename(args.character), "clip": os.path.basename(args.clip), "time_s": t}
    return character, mus, world, pose


def cmd_deform(args) -> int:
    from rig.muscle.fit import Musculature
    from rig.skin.muscle_skin import MuscleSkin
    from sim.app.deform_outputs import write_deform_outputs
    character, rig, world, pose = _deform_pose(args)
    if isinstance(rig, Musculature):
        skin = MuscleSkin.from_musculature(rig, skinning=args.skinning, method=args.method,
                                           weights=args.weights, character_path=args.character)
        views = ("front", "side")
    else:
        weights = None
        if args.weights is not None:
            from rig.skin.shell.weights import load_weights
            weights = load_weights(args.weights, rig.names, character.num_vertices)
        skin = MuscleSkin(character, rig, skinning=args.skinning, method=args.method, weights=weights)
        views = ("side", "back")    # the arm's muscle faces +Y: its profile from the side, its face from +Y
    out = write_deform_outputs(skin, world, args.out, pose=pose, render=not args.no_render, views=views)
    f = out["facts"]
    print(f"{character.name or 'character'}: LBS + {f['muscles']} muscles ({args.skinning}), {f['pairs']} "
          f"(vertex, muscle) pairs kept at bind ({f['pairs_per_vertex']:.2f} per vertex); skin moved from LBS by "
          f"up to {f['max_displacement_mm']:.2f} mm (RMS {f['rms_displacement_mm']:.2f} mm)")
    for k, path in out["files"].items():
        print(f"  {k:8s} {path}")
    return 0


# ---------------------------------------------------------------------------------------- simulate
SIMULATE_FPS = 60.0


@dataclass(frozen=True)
class SimulateJob:
    """What `jiggle simulate` runs. rig : rig.muscle.model.MuscleRig. jiggles : one MuscleJiggle per
    muscle (the scene's tables applied). world_at : times (K,) -> (K, J, 4, 4). duration : seconds of
    the motion. fps : the scene's output rate or None. skin : builds the MuscleSkin (only when rendering,
    binding costs a few tenths of a second). source : JSON-ready description."""

    name: str
    rig: object
    jiggles: list
    world_at: Callable
    duration: float
    fps: float | None
    scene: object | None
    skin: Callable
    source: dict


def _simulate_job(args) -> SimulateJob:
    """The built-in simple arm (nothing given), or a scene's / --clip's motion on a generated body or
    on --character, with the template's muscles fitted."""
    from rig.motion.clip import transforms
    from rig.skin.muscle_skin import MuscleSkin
    from sim.jiggle.params import default_jiggles
    scene = None
    if args.scene is not None:
        if args.clip is not None:
            raise InputError("give a SCENE or --clip, not both (the scene names its motion)", field="--clip")
        from sim.bake.scene import load_scene
        scene = load_scene(args.scene)
    if scene is None and args.clip is None:
        if args.character is not None:
            raise InputError("a CHARACTER needs a motion: --clip FILE (retargeted onto it) or a SCENE",
                             field="--character")
        if args.template is not None:
            raise InputError("--template fits muscles to a character; the built-in simple arm has its own biceps",
                             field="--template")
        from rig.muscle.simple_arm import FLEX_DURATION, FLEX_PEAK, FLEX_RISE, simple_arm
        arm = simple_arm()
        return SimulateJob(
            name="simple arm", rig=arm.rig, jiggles=default_jiggles(arm.rig), world_at=arm.world_at,
            duration=FLEX_DURATION, fps=None, scene=None,
            skin=lambda: MuscleSkin(arm.character, arm.rig, skinning=args.skinning, method=args.method),
            source={"scene": "simple arm (built in)",
                    "motion": f"elbow 0 -> {FLEX_PEAK:g} deg in {FLEX_RISE:g} s, hold, back"})
    from rig.muscle.fit import FitOptions, fit_musculature
    clip = scene.clip if scene is not None else _load_clip(args)
    if args.character is not None:
        from rig.character.load import load_character
        clip = _retarget_onto_character(clip, args)
        character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
    else:
        character = _generated_character(clip, args)
    mus = fit_musculature(character, args.template or "human", FitOptions(joint_map=args.joint_map))
    jiggles = default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles])
    if scene is not None:
        jiggles = scene.apply_jiggle(jiggles)
    return SimulateJob(
        name=scene.name if scene is not None else clip.name, rig=mus.rig, jiggles=jiggles,
        world_at=lambda t: transforms(*clip.world(*clip.sample(t))), duration=clip.duration,
        fps=scene.fps if scene is not None else None, scene=scene,
        skin=lambda: MuscleSkin.from_musculature(mus, skinning=args.skinning, method=args.method,
                                                 character_path=args.character),
        source={"scene": scene.path if scene is not None else None, "clip": clip.source or args.clip,
                "character": args.character or "generated body", "template": args.template or "human"})


def _simulate_times(args, duration: float, fps: float):
    """Output times (T,) seconds: --start..--end (default the whole motion) at fps, the first --frames."""
    from sim.bake.setup import output_times
    return output_times(duration, fps, args.start, args.end, args.frames)


def cmd_simulate(args) -> int:
    import time
    from dataclasses import replace

    from sim.app.jiggle_outputs import top_muscles, write_jiggle_outputs
    from sim.jiggle.params import BlendCurve, JiggleSettings
    from sim.jiggle.secondary import jiggle_rig

    job = _simulate_job(args)
    scene = job.scene
    settings = scene.jiggle if scene is not None and scene.jiggle is not None else JiggleSettings()
    given = {"substeps": args.substeps, "strength": args.jiggle, "preroll": args.preroll,
             "blend": None if args.blend is None else BlendCurve.constant(args.blend),
             "gravity": True if args.gravity else None}
    settings = replace(settings, **{k: v for k, v in given.items() if v is not None})
    jiggles = job.jiggles
    if args.blend is not None:    # --blend is every muscle's, over the scene's own curves
        jiggles = [replace(j, blend=None) for j in jiggles]
    fps = args.fps or job.fps or SIMULATE_FPS
    times = _simulate_times(args, job.duration, fps)
    rig = job.rig
    t0 = time.perf_counter()
    result = jiggle_rig(rig, jiggles, job.world_at, times, settings)
    sim_s = time.perf_counter() - t0
    skin = None
    if not args.no_render:
        t0 = time.perf_counter()
        skin = job.skin()
        bind_s = time.perf_counter() - t0
    focus = args.focus or (scene.focus if scene is not None else None)
    out = write_jiggle_outputs(result, skin, job.world_at(times), args.out, every=args.every,
                               render=not args.no_render, focus=focus, title=job.name,
                               source={**job.source, "simulate_s": round(sim_s, 3)})
    f = out["facts"]
    print(f"{job.name}: {rig.M} muscle{'s' if rig.M != 1 else ''}, {f['particles']} particles, {len(times)} "
          f"frames at {fps:g} fps ({times[0]:.3f}-{times[-1]:.3f} s), simulated in {sim_s:.2f} s "
          f"({settings.substeps} substep{'s' if settings.substeps != 1 else ''} per frame)")
    out_of_blend = [m for m in range(rig.M) if not result.blend[:, m].any()]
    shown = [m for m in top_muscles(result, 5 + len(out_of_blend)) if m not in out_of_blend][:5]
    print("  peak jiggle (largest CV distance dynamic - static; blended: what the skin gets):")
    for m in shown:
        mf = f["muscles"][result.names[m]]
        settle = "keeps moving" if mf["settle_s"] is None else f"settles {mf['settle_s']:.2f} s after"
        blended = "" if mf["blended_peak_mm"] == mf["peak_mm"] else f" (blended {mf['blended_peak_mm']:.1f} mm)"
        print(f"    {result.names[m]:18s} {mf['peak_mm']:8.1f} mm at {mf['peak_time_s']:.3f} s{blended}, "
              f"{mf['end_mm']:.1f} mm at the end, {settle}")
    rest = rig.M - len(shown) - len(out_of_blend)
    more = ([f"{rest} more"] if rest > 0 else []) + ([f"{len(out_of_blend)} blended out (static)"] if out_of_blend else [])
    if more:
        print(f"    ... {', '.join(more)}: see jiggle.json")
    if "skin" in f:
        n = f["frames_written"]["count"]
        print(f"  skin moved up to {f['skin']['peak_move_mm']:.1f} mm from the static skin; {n} frame"
              f"{'s' if n != 1 else ''} rendered (every {args.every}) in {out['timings']['render_s']:.1f} s "
              f"(skin bound in {bind_s:.1f} s)")
    for k, path in out["files"].items():
        print(f"  {k:7s} {path}")
    return 0


# ---------------------------------------------------------------------------------------- bake
def bake_request(args):
    """The BakeRequest of `jiggle bake` (or `jiggle demo`) arguments."""
    from types import MappingProxyType

    from sim.bake.scene import parse_formats
    from sim.bake.setup import BakeRequest
    body = {k: getattr(args, k) for k in ("resolution", "belly", "chest", "glutes", "upper_arms")
            if getattr(args, k, None) is not None}
    formats = None if getattr(args, "formats", None) is None else parse_formats(args.formats)
    return BakeRequest(
        scene=getattr(args, "scene", None), clip=getattr(args, "clip", None), skeleton=getattr(args, "skeleton", None),
        animation=getattr(args, "animation", None), scale=getattr(args, "scale", None),
        tpose=getattr(args, "tpose", "auto"), character=getattr(args, "character", None),
        template=getattr(args, "template", None), fps=args.fps, substeps=args.substeps, blend=args.blend,
        jiggle=args.jiggle, start=args.start, end=args.end, frames=args.frames, drive=args.drive,
        formats=formats, chunk=args.chunk, body=MappingProxyType(body), influences=args.influences,
        skinning=args.skinning, method=args.method, joint_map=getattr(args, "joint_map", None),
        clip_map=getattr(args, "clip_map", None), character_map=getattr(args, "character_map", None),
        skin=getattr(args, "skin", None), unit=getattr(args, "unit", None))


def run_bake(request, out_dir: str, resume: bool = False) -> dict:
    """Prepare and bake with a progress bar; on Ctrl-C say how to resume and re-raise."""
    from tqdm import tqdm

    from sim.bake.baker import bake
    from sim.bake.setup import prepare

    def log(s):
        print(f"  {s}", file=sys.stderr)
    setup = prepare(request, log)
    T = len(setup.times)
    print(f"baking {setup.name!r}: {T} frames at {setup.fps:g} fps ({setup.times[0]:.3f}-{setup.times[-1]:.3f} s), "
          f"{setup.character.num_vertices} vertices, {setup.rig.M} muscles -> {os.path.abspath(out_dir)}",
          file=sys.stderr)
    with tqdm(total=T, unit="frame", desc="bake", disable=None, file=sys.stderr, dynamic_ncols=True) as bar:
        try:
            summary = bake(setup, out_dir, resume=resume, progress=bar.update,
                           log=lambda s: bar.write(f"  {s}", file=sys.stderr))
        except KeyboardInterrupt:
            bar.close()
            print(f"jiggle: interrupted after {bar.n} of {T} frames; the chunks baked so far are kept in "
                  f"{os.path.join(out_dir, '.partial')}: run the same command with --resume to finish", file=sys.stderr)
            raise
    return summary


def _print_bake(summary: dict, out_dir: str) -> None:
    tm = summary["timings"]
    fps = tm.get("frames_per_s")
    print(f"{summary['name']}: {summary['frames']} frames, {summary['vertices']} vertices, {summary['muscles']} "
          f"muscles baked in {tm['frames_s']:.2f} s" + (f" ({fps:.0f} frames/s)" if fps else "") +
          f", caches written in {tm['caches_s']:.2f} s")
    for k, f in summary["files"].items():
        print(f"  {k:5s} {os.path.join(out_dir, f)}")
    print(f"  json  {os.path.join(out_dir, 'bake.json')}")


def cmd_bake(args) -> int:
    summary = run_bake(bake_request(args), args.out, resume=args.resume)
    _print_bake(summary, args.out)
    return 0


# ---------------------------------------------------------------------------------------- compare
def cmd_compare(args) -> int:
    res = _compare(args.out_dir, render=not args.no_render, video=not args.no_video)
    print(f"report: {res['files'].get('report', os.path.join(args.out_dir, 'report.html'))}")
    return 0


def _compare(out_dir: str, render: bool = True, video: bool = True) -> dict:
    from sim.app.compare import compare
    res = compare(out_dir, render=render, video=video)
    m = res["metrics"]
    skin = m.get("skin", {})
    peak = skin.get("max_mm", skin.get("max_displacement_mm"))
    print(f"compared static and dynamic in {out_dir}" + (f": skin moved up to {peak:.1f} mm" if peak is not None else ""))
    for k, f in res["files"].items():
        print(f"  {k:13s} {f}")
    return res


# ---------------------------------------------------------------------------------------- morph
def cmd_morph(args) -> int:
    """Morph a canonical character to a target from marker positions; or write the canonical's markers."""
    import time

    from rig.anatomy.features import FeatureOptions
    from rig.anatomy.markers import read_markers, write_markers
    from rig.anatomy.morph import MorphOptions, morph, prepare_canonical
    from rig.character.load import load_character
    from sim.app.morph_outputs import render_morph, side_paths, write_report

    if args.markers is None and args.write_markers is None:
        raise InputError("give --markers FILE (the target's marker positions) or --write-markers FILE (the "
                         "canonical's, to edit)", field="--markers")
    ext = os.path.splitext(args.out)[1].lower()
    if args.markers is not None and ext not in (".glb", ".gltf"):
        raise InputError(f"expected a .glb or .gltf output, got {args.out!r}", field="--out")
    t = time.perf_counter()
    character = load_character(args.canonical, k=args.influences, unit=args.unit, skin=args.skin)
    features = FeatureOptions(spacing=args.spacing, insert=not args.snap_only)
    options = MorphOptions(template=args.template or "human", kernel=args.kernel, scale=args.rbf_scale,
                           band=args.band, marker_features=args.marker_features, features=features,
                           joint_map=args.joint_map)
    canon = prepare_canonical(character, options, source=args.canonical)
    if args.write_markers is not None:
        write_markers(args.write_markers, canon.markers.names, canon.markers.positions, source=args.canonical)
        print(f"wrote the {len(canon.markers.names)} markers of {args.canonical} to {args.write_markers} "
              "(metres, Z-up); move them to the target's and run: jiggle morph CANONICAL --markers FILE --out T.glb")
        if args.markers is None:
            return 0
    target = read_markers(args.markers, canon.markers.names)
    res = morph(canon, target, options)
    from rig.character.gltf_write import write_character
    folder = os.path.dirname(os.path.abspath(args.out))
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise InputError(f"{folder} is a file, not a folder", field="--out")
    os.makedirs(folder, exist_ok=True)
    write_character(res.character, args.out, source=args.canonical,
                    extras={"jiggle": {"morphed_from": os.path.basename(args.canonical),
                                       "markers": os.path.basename(args.markers)}})
    json_path, png_path = side_paths(args.out)
    rep = res.report
    rep["seconds"]["total"] = round(time.perf_counter() - t, 3)
    write_report(json_path, rep)
    files = {"character": args.out, "report": json_path}
    if not args.no_render:
        files["picture"] = render_morph(png_path, canon.character.vertices, res.character.vertices,
                                        canon.character.faces, [target[n] for n in canon.markers.names])
    H = rep["height_m"]
    conds = [c for c in rep["rbf"].get("condition", []) if c is not None]
    print(f"morphed {os.path.basename(args.canonical)} ({rep['vertices']} vertices, {rep['features']['count']} "
          f"feature points: {rep['features']['snapped']} snapped, {rep['features']['inserted']} inserted) to "
          f"{len(canon.markers.names)} markers in {rep['seconds']['total']:.1f} s")
    print(f"  markers: rms {1e3 * rep['marker_rms_m']:.1f} mm ({100 * rep['marker_rms_m'] / H:.2f}% of the "
          f"{H:.2f} m height), worst {1e3 * rep['marker_max_m']:.1f} mm; flipped triangles {rep['flipped']}"
          + (f"; RBF condition up to {max(conds):.2g}" if conds else ""))
    for k, f in files.items():
        print(f"  {k:10s} {f}")
    return 0


# ---------------------------------------------------------------------------------------- parser
def _bake_options(p: argparse.ArgumentParser, out: str) -> None:
    """Options shared by `jiggle bake` and `jiggle demo`."""
    from sim.bake.scene import FORMATS
    p.add_argument("--out", default=out, help=f"output folder (default: {out})")
    p.add_argument("--resume", action="store_true", help="finish the interrupted bake in --out (same parameters)")
    g = p.add_argument_group("time")
    g.add_argument("--fps", type=_positive("--fps"), metavar="N", help="output frames per second (default: the "
                   "scene's, else 30)")
    g.add_argument("--start", type=_non_negative("--start"), metavar="S", help="first frame, seconds of the clip "
                   "(default: 0)")
    g.add_argument("--end", type=_non_negative("--end"), metavar="E", help="last frame, seconds of the clip "
                   "(default: its end)")
    g.add_argument("--frames", type=_count("--frames"), metavar="N", help="only the first N output frames")
    g.add_argument("--drive", choices=["kinematic", "physics"], help="kinematic: MuJoCo poses the skeleton from the "
                   "clip; physics: MuJoCo simulates the body on a floor following it (default: the scene's, else "
                   "kinematic)")
    g = p.add_argument_group("jiggle (over the scene's [jiggle] section)")
    g.add_argument("--substeps", type=_count("--substeps"), metavar="N", help="integration steps per output frame "
                   "(default: 4)")
    g.add_argument("--blend", type=_unit_interval("--blend"), metavar="B", help="static_dyn_blend of every muscle: "
                   "0 static, 1 dynamic (default: the scene's curves, else 1)")
    g.add_argument("--jiggle", type=_unit_interval("--jiggle"), metavar="J", help="jiggle strength of every muscle "
                   "in [0, 1] (default: each muscle's, 1)")
    g = p.add_argument_group("caches")
    g.add_argument("--formats", metavar="LIST", help=f"comma-separated cache formats: {', '.join(FORMATS)} "
                   "(default: the scene's, else npz,usdc)")
    g.add_argument("--chunk", type=_count("--chunk"), metavar="N", help="frames per chunk written and resumed "
                   "(default: 64)")
    g = p.add_argument_group("skin")
    g.add_argument("--skinning", choices=["shell", "influence", "rbf"], help="how the muscles move the skin: shell, influence or rbf "
                   "(default: shell)")
    g.add_argument("--method", choices=["lbs", "dqs"], help="smooth skinning underneath (default: lbs)")
    g.add_argument("--influences", type=_count("--influences"), metavar="K", help="skin weights kept per vertex "
                   "(default: 4)")
    g.add_argument("--resolution", type=_count("--resolution"), metavar="N",
                   help="generated body: target vertex count (default: the scene's, else 20000)")
    for name in ("belly", "chest", "glutes", "upper-arms"):
        g.add_argument(f"--{name}", type=_non_negative(f"--{name}"), metavar="M",
                       help=f"generated body: metres of fat on the {name.replace('-', ' ')}")


def build_parser() -> argparse.ArgumentParser:
    top = _Parser(prog="jiggle", description=(
        "Physics-backed muscle jiggle and secondary motion for animated characters. "
        "Start with 'jiggle demo'; bake your own clip with 'jiggle bake --clip FILE' and compare static "
        "with dynamic deformation with 'jiggle compare OUT_DIR'."),
        epilog="Run 'jiggle COMMAND --help' for a command's options. Exit codes: 0 done, 2 bad input, "
               "130 interrupted.")
    sub = top.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("inspect", help="describe a clip, character or MuJoCo model file",
                       description="Describe a file: for a clip (BVH, AMC, ASF, glTF/GLB animation) its joints, "
                                   "frames, fps, duration, units and detected T-pose; for a character (glTF/GLB, OBJ, "
                                   "PLY, STL) its vertices, faces, joints, skins and animations; for an MJCF its "
                                   "bodies and joints.")
    p.add_argument("file", help="the file to describe")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    _clip_options(p)
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("play", help="play a clip on its skeleton through MuJoCo and write pictures",
                       description="Play a mocap clip on its own skeleton through MuJoCo and write to --out: "
                                   "skeleton.png (the skeleton over time), trajectories.png (joint positions over "
                                   "time), motion.npz (bone world transforms per frame) and summary.json.")
    p.add_argument("clip", help="BVH, AMC (with its ASF), or glTF/GLB with animations")
    p.add_argument("--out", default="out/play", help="output folder (default: out/play)")
    p.add_argument("--start", type=float, metavar="S", help="start, seconds of the clip (default: 0)")
    p.add_argument("--end", type=float, metavar="E", help="end, seconds of the clip (default: its end)")
    p.add_argument("--fps", type=_positive("--fps"), help="output frame rate (default: the clip's)")
    p.add_argument("--speed", type=_positive("--speed"), help="play this many times faster (default: 1)")
    p.add_argument("--drive", choices=["kinematic", "physics"], default="kinematic",
                   help="kinematic: MuJoCo poses the bones from the clip; physics: MuJoCo simulates the body "
                        "on a floor following the clip (default: kinematic)")
    p.add_argument("--poses", type=_count("--poses"), default=8, help="poses in the skeleton picture (default: 8)")
    p.add_argument("--no-render", action="store_true", help="skip the 3D picture (plots and data only)")
    g = p.add_argument_group("retargeting onto a character's skeleton")
    g.add_argument("--character", metavar="FILE", help="the character to skin: a skinned glTF/GLB (the clip is "
                   "retargeted onto its skeleton), or an OBJ/PLY/STL/unskinned glTF mesh standing in the clip's "
                   "rest pose (automatic weights). Default: a body generated around the clip's skeleton")
    _map_options(g)
    _mesh_options(g)
    _character_options(p)
    g = p.add_argument_group("your own MuJoCo model")
    g.add_argument("--mjcf", metavar="XML", help="drive this MJCF instead of the model built from the clip "
                   "(e.g. dm_control's humanoid_CMU.xml with a CMU AMC clip)")
    g.add_argument("--joint-map", metavar="TOML", help="clip joint -> MJCF body names, a [joints] table "
                   "(default: clip joints drive the bodies of the same name)")
    _clip_options(p)
    p.set_defaults(func=cmd_play)

    p = sub.add_parser("demo", help="bake and compare the built-in demo (no files needed)",
                       description="The built-in scene (scenes/default.toml): a body generated by jiggle, with "
                                   "belly fat, doing jumping jacks keyframed by the project; its muscles and fat "
                                   "are fitted, jiggled, baked into caches and compared, static against dynamic, "
                                   "in --out (default out/demo). Ends by printing where report.html is.")
    p.add_argument("--scene", help="scene TOML (default: the built-in scenes/default.toml)")
    _bake_options(p, "out/demo")
    p.add_argument("--no-render", action="store_true", help="compare without renders (plots and numbers only)")
    p.add_argument("--no-video", action="store_true", help="compare without the video")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("bake", help="bake jiggle for a clip into caches (USD, npz, pc2)",
                       description="Clip -> MuJoCo skeleton -> static muscles -> particles -> blend -> skinning -> "
                                   "caches. Writes bake.npz, bake.usdc (or .usda) and optionally bake.pc2, with "
                                   "bake.json (parameters, timings), into --out. Long bakes are written in chunks: "
                                   "Ctrl-C keeps the chunks done and --resume finishes the bake, equal to an "
                                   "unbroken one. Without a scene or --clip: the built-in demo scene. "
                                   "Command-line settings override the scene's.")
    p.add_argument("scene", nargs="?", metavar="SCENE", help="a scene TOML (scenes/*.toml); its [motion] may be left "
                   "out and given with --clip")
    p.add_argument("--clip", metavar="FILE", help="the motion: BVH, AMC (its ASF beside it or --skeleton) or "
                   "glTF/GLB with animations (--animation)")
    p.add_argument("--character", metavar="FILE", help="a skinned glTF/GLB: the clip is retargeted onto it "
                   "(default: the scene's, else a body generated around the clip's skeleton)")
    p.add_argument("--template", metavar="T", help="muscle template: built-in name or .toml/.xml (default: human)")
    _bake_options(p, "out/bake")
    g = p.add_argument_group("character")
    g.add_argument("--joint-map", metavar="TOML|PRESET", help="joint map naming the template's roles")
    _map_options(g)
    g.add_argument("--skin", type=int, metavar="N", help="which skin of a glTF character (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the character file's unit: m, cm, mm, in, ft or metres per "
                   "unit (default: m)")
    _clip_options(p)
    p.set_defaults(func=cmd_bake)

    p = sub.add_parser("compare", help="compare static and dynamic deformation of a bake",
                       description="Read OUT_DIR/bake.npz and write, into OUT_DIR: metrics.json (per-vertex "
                                   "maximum and RMS displacement of the final skin from the static one, per-muscle "
                                   "jiggle amplitude, energy and dominant frequency), plots (amplitude, energy, "
                                   "spectrum, displacement), renders (static | dynamic at the frame of peak jiggle "
                                   "with a displacement heat map, a video of the clip) and report.html, one "
                                   "self-contained page showing them all.")
    p.add_argument("out_dir", metavar="OUT_DIR", help="a folder baked by `jiggle bake --out OUT_DIR`")
    p.add_argument("--no-render", action="store_true", help="skip the renders and the video")
    p.add_argument("--no-video", action="store_true", help="skip the video only")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("morph", help="morph a canonical character to a target from sparse marker positions",
                       description="Morph a canonical skinned character into a target, inside out (Simmons et al. "
                                   "2002): joints from the target's markers, chains without markers keeping their "
                                   "shape, bones and muscles scaled by the measured body dimensions, then the skin "
                                   "by zoned RBF interpolation of feature points anchored to bones and muscles. "
                                   "Writes a skinned, animatable glTF, a report (.morph.json) and a picture "
                                   "(.morph.png). --write-markers writes the canonical's markers to start from.")
    p.add_argument("canonical", metavar="CANONICAL", help="the canonical character: a skinned glTF/GLB")
    p.add_argument("--markers", metavar="FILE", help="the target's marker positions (TOML or JSON, metres, Z-up)")
    p.add_argument("--write-markers", metavar="FILE", help="write the canonical's markers (TOML) to FILE")
    p.add_argument("--out", default="out/morph/target.glb", help="the target character, .glb or .gltf "
                   "(default: out/morph/target.glb)")
    p.add_argument("--no-render", action="store_true", help="skip the picture")
    p.add_argument("--template", metavar="T", help="muscle template of the canonical (default: human)")
    p.add_argument("--joint-map", metavar="TOML|PRESET", help="joint map naming the canonical's roles "
                   "(default: a built-in preset that fits, else found from the skeleton)")
    g = p.add_argument_group("skin interpolation")
    g.add_argument("--kernel", choices=["soliton", "gaussian", "multiquadric", "inverse_multiquadric"],
                   default="soliton", help="radial basis function (default: soliton e^(-r/s))")
    g.add_argument("--rbf-scale", type=_positive("--rbf-scale"), default=0.1, metavar="S",
                   help="the kernel's scale s as a fraction of the body's height (default: 0.1)")
    g.add_argument("--band", type=_non_negative("--band"), default=0.04, metavar="B",
                   help="blend band across zone boundaries, fraction of the height (default: 0.04)")
    g.add_argument("--spacing", type=_positive("--spacing"), default=0.02, metavar="D",
                   help="least distance between feature points, fraction of the height (default: 0.02)")
    g.add_argument("--snap-only", action="store_true", help="snap feature points to existing vertices instead "
                   "of inserting new ones (keeps the canonical's topology)")
    g.add_argument("--marker-features", action="store_true", help="also pin the marker vertices to the target's "
                   "markers (exact markers; a misplaced marker dents the skin)")
    g = p.add_argument_group("canonical file")
    g.add_argument("--skin", type=int, default=0, metavar="N", help="which skin of the glTF (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the file's unit: m, cm, mm, in, ft or metres per unit (default: m)")
    g.add_argument("--influences", type=_count("--influences"), default=4, metavar="K",
                   help="skin weights kept per vertex (default: 4)")
    p.set_defaults(func=cmd_morph)

    p = sub.add_parser("body", help="generate a body mesh around a skeleton, with automatic weights",
                       description="Generate a smooth, closed body around a skeleton (proportions from its bone "
                                   "lengths, optional fat volumes) with automatic weights, and write body.png "
                                   "(front and side), weights.png (coloured by dominant joint), body.ply and "
                                   "body.json to --out.")
    p.add_argument("skeleton_file", nargs="?", metavar="SKELETON",
                   help="a clip (BVH, AMC, ASF, glTF), an MJCF model or a skinned glTF (default: the demo's skeleton)")
    p.add_argument("--out", default="out/body", help="output folder (default: out/body)")
    p.add_argument("--no-render", action="store_true", help="skip the pictures")
    _character_options(p)
    p.set_defaults(func=cmd_body)

    p = sub.add_parser("fit", help="fit muscles and fat to a character from a template (outside in)",
                       description="Segment the character's skin by bone, fit the template's ellipsoidal muscles "
                                   "and muscle pairs to the regions, attach tendons, conform them to the skin and "
                                   "build the lofted muscle model; write the musculature (TOML), its facts (JSON) "
                                   "and a picture of the skin over the muscles.")
    p.add_argument("character", nargs="?", metavar="CHARACTER",
                   help="a skinned glTF/GLB, a mesh (OBJ/PLY/STL/glTF, with --skeleton), or a skeleton "
                        "(BVH, ASF, AMC, MJCF, keyframed TOML) to generate a body around (default: the demo's body)")
    p.add_argument("--template", metavar="T", help="template: built-in name or .toml/.xml file (default: human)")
    p.add_argument("--out", default="out/fit/muscles.toml", help="musculature TOML (default: out/fit/muscles.toml)")
    p.add_argument("--png", metavar="FILE", help="picture (default: fit.png beside --out)")
    p.add_argument("--no-render", action="store_true", help="skip the picture")
    p.add_argument("--joint-map", metavar="TOML|PRESET", help="joint map naming the template's roles (default: "
                   "a built-in preset that fits, else found from the skeleton)")
    p.add_argument("--iterations", type=_count("--iterations", zero=True), default=25,
                   help="normal smoothing iterations for the segmentation (default: 25)")
    p.add_argument("--smoothing", type=_unit_interval("--smoothing"), default=1.0, metavar="LAMBDA",
                   help="normal smoothing lambda in [0, 1] (default: 1)")
    p.add_argument("--exclude", action="append", metavar="JOINT", help="leave a joint's bones out of the "
                   "segmentation (repeatable)")
    p.add_argument("--volume", choices=["exact", "sqrt", "thesis", "none"], default="exact",
                   help="how muscles keep their volume when they stretch (default: exact)")
    p.add_argument("--skeleton", metavar="FILE", help="the skeleton of a mesh character (clip, ASF, MJCF)")
    _mesh_options(p)
    _character_options(p)
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("deform", help="skin one pose with the muscles' deformers and compare with LBS",
                       description="Pose a character (or the built-in simple arm: a cylinder on two bones with "
                                   "one muscle, the thesis's example), skin it with LBS and then the muscles' "
                                   "shell deformers (or influence objects), and write deform.png (LBS | muscles, "
                                   "coloured by the move from LBS), deform.json and deform.ply to --out.")
    p.add_argument("character", nargs="?", metavar="CHARACTER",
                   help="a skinned glTF/GLB (muscles fitted from --template); default: the simple arm")
    p.add_argument("--clip", metavar="FILE", help="the pose's clip (BVH, AMC, glTF), retargeted onto CHARACTER")
    p.add_argument("--time", type=_non_negative("--time"), metavar="S", help="seconds into --clip (default: 0)")
    p.add_argument("--angle", type=float, metavar="DEG", help="simple arm: elbow flexion in degrees (default: 90)")
    p.add_argument("--skinning", choices=["shell", "influence", "rbf"], default="shell",
                   help="how the muscles move the skin: shell deformers, influence objects or anatomy-driven RBF "
                   "(default: shell)")
    p.add_argument("--method", choices=["lbs", "dqs"], default="lbs", help="smooth skinning underneath (default: lbs)")
    p.add_argument("--weights", metavar="NPZ", help="painted per-vertex muscle weights (default: "
                   "<character>.shell_weights.npz beside the character when present, else 1)")
    p.add_argument("--template", metavar="T", help="muscle template: built-in name or .toml/.xml (default: human)")
    p.add_argument("--joint-map", metavar="TOML|PRESET", help="joint map naming the template's roles")
    _map_options(p)
    p.add_argument("--influences", type=_count("--influences"), default=4, metavar="K",
                   help="skin weights kept per vertex (default: 4)")
    p.add_argument("--out", default="out/deform", help="output folder (default: out/deform)")
    p.add_argument("--no-render", action="store_true", help="skip the picture")
    _mesh_options(p)
    _clip_options(p)
    p.set_defaults(func=cmd_deform)

    p = sub.add_parser("simulate", help="simulate the muscles' jiggle and render static | dynamic",
                       description="Simulate the secondary motion of the muscles (particles on every muscle CV "
                                   "pulled toward the static shape) over a motion and write to --out: "
                                   "frames/frame_NNNN.png (static skin and muscles | skin from the jiggled, "
                                   "blended muscles coloured by its move, the static muscles as a wireframe), "
                                   "amplitude.png (jiggle per muscle over time) and jiggle.json (peaks, settle "
                                   "times, settings). With nothing given: the built-in simple arm (a cylinder on "
                                   "two bones with one muscle) flexing fast. Command-line settings override the "
                                   "scene's [jiggle] section.")
    p.add_argument("scene", nargs="?", metavar="SCENE", help="a scene TOML with a motion and an optional [jiggle] "
                   "section (e.g. scenes/belly_run.toml); default: the simple arm, or --clip")
    p.add_argument("--clip", metavar="FILE", help="the motion (BVH, AMC, glTF) instead of a scene: a generated body "
                   "runs it, or CHARACTER with --character")
    p.add_argument("--character", metavar="FILE", help="a skinned glTF/GLB: the clip is retargeted onto it and "
                   "the template's muscles fitted (default: a body generated around the clip's skeleton)")
    p.add_argument("--template", metavar="T", help="muscle template: built-in name or .toml/.xml (default: human)")
    p.add_argument("--fps", type=_positive("--fps"), metavar="N", help="output frames per second (default: the "
                   f"scene's, else {SIMULATE_FPS:g})")
    p.add_argument("--start", type=_non_negative("--start"), metavar="S", help="first output time, seconds (default: 0)")
    p.add_argument("--end", type=_non_negative("--end"), metavar="E", help="last output time, seconds (default: the "
                   "motion's end)")
    p.add_argument("--frames", type=_count("--frames"), metavar="N", help="only the first N output frames")
    g = p.add_argument_group("jiggle (over the scene's [jiggle] section)")
    g.add_argument("--substeps", type=_count("--substeps"), metavar="N", help="integration steps per output frame "
                   "(default: 4; the solver splits further where it must)")
    g.add_argument("--jiggle", type=_unit_interval("--jiggle"), metavar="J", help="jiggle strength in [0, 1] of "
                   "every muscle: 0 glues the muscles to their static shape, the jiggle's size grows with J "
                   "(default: each muscle's, 1)")
    g.add_argument("--blend", type=_unit_interval("--blend"), metavar="B", help="static_dyn_blend in [0, 1] of every "
                   "muscle: 0 static, 1 dynamic (default: the scene's curves, else 1)")
    g.add_argument("--gravity", action="store_true", help="let the muscles sag under gravity below their static shape")
    g.add_argument("--preroll", type=_non_negative("--preroll"), metavar="S", help="start at rest at the bind pose S "
                   "seconds early (default: 0, start settled on the first frame)")
    g = p.add_argument_group("output")
    g.add_argument("--out", default="out/simulate", help="output folder (default: out/simulate)")
    g.add_argument("--every", type=_count("--every"), default=1, metavar="K", help="render every K-th frame "
                   "(default: 1)")
    g.add_argument("--no-render", action="store_true", help="skip the frame pictures (plot and facts only)")
    g.add_argument("--focus", action="append", metavar="MUSCLE", help="muscle the pictures frame and draw "
                   "(repeatable; default: the scene's [output] focus, else those jiggling at least half as much as "
                   "the most)")
    g.add_argument("--skinning", choices=["shell", "influence", "rbf"], default="shell",
                   help="how the muscles move the skin: shell deformers, influence objects or anatomy-driven RBF "
                   "(default: shell)")
    g.add_argument("--method", choices=["lbs", "dqs"], default="lbs", help="smooth skinning underneath (default: lbs)")
    g = p.add_argument_group("character")
    g.add_argument("--joint-map", metavar="TOML|PRESET", help="joint map naming the template's roles")
    _map_options(g)
    _mesh_options(g)
    _character_options(p)
    _clip_options(p)
    p.set_defaults(func=cmd_simulate)
    return top


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USER_ERROR
    import warnings

    from rig.base.errors import JiggleWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, JiggleWarning):
            print(f"jiggle: warning: {message}", file=sys.stderr)
        else:
            sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))
    try:
        with warnings.catch_warnings():  # restored afterwards, for callers that run main() in-process
            warnings.simplefilter("always", JiggleWarning)
            warnings.showwarning = show
            return int(args.func(args) or 0)
    except InputError as e:
        print(f"jiggle: error: {e}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("jiggle: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
