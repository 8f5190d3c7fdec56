"""`jiggle simulate`: the muscles' jiggle over a motion (the simple arm, a scene or --clip) with
sim/jiggle/secondary.py's jiggle_rig, rendered static | dynamic, plotted and summarised.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.args import (
    character_options,
    clip_options,
    collision_option,
    count,
    keyed_options,
    keyed_request,
    map_options,
    mesh_options,
    muscle_skin_options,
    non_negative,
    positive,
    template_option,
)
from jiggle.sim.app.loading import generated_character, load_clip, retarget_onto_character

SIMULATE_FPS = 60.0


@dataclass(frozen=True)
class SimulateJob:
    """What `jiggle simulate` runs. rig : rig.muscle.model.MuscleRig. jiggles : one MuscleJiggle per
    muscle (the scene's tables applied). world_at : times (K,) -> (K, J, 4, 4). duration : seconds of
    the motion. fps : the scene's output rate or None. skin : builds the MuscleSkin (only when rendering,
    binding costs a few tenths of a second). source : JSON-ready description. scale : the character's real size
    over its size as simulated (rig.character.real_size), for the materials' rule."""

    name: str
    rig: object
    jiggles: list
    world_at: Callable
    duration: float
    fps: float | None
    scene: object | None
    skin: Callable
    source: dict
    character: object = None
    clip: object = None
    scale: float = 1.0


def simulate_job(args) -> SimulateJob:
    """The built-in simple arm (nothing given), or a scene's / --clip's motion on a generated body or
    on --character, with the template's muscles fitted."""
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    from jiggle.sim.jiggle.materials import default_jiggles
    scene = None
    if args.scene is not None:
        if args.clip is not None:
            raise InputError("give a SCENE or --clip, not both (the scene names its motion)", field="--clip")
        from jiggle.sim.bake.scene import load_scene
        scene = load_scene(args.scene)
    if scene is None and args.clip is None and args.character is not None:
        if not args.character.lower().endswith((".glb", ".gltf")):
            raise InputError("a CHARACTER needs a motion: --clip FILE (retargeted onto it) or a SCENE",
                             field="--character")
        args.clip = args.character  # a glTF character alone plays its own animation (--animation)
    if scene is None and args.clip is None:
        if args.template is not None:
            raise InputError("--template fits muscles to a character; the built-in simple arm has its own biceps",
                             field="--template")
        from jiggle.rig.muscle.simple_arm import FLEX_DURATION, FLEX_PEAK, FLEX_RISE, simple_arm
        arm = simple_arm()
        return SimulateJob(
            name="simple arm", rig=arm.rig, jiggles=default_jiggles(arm.rig), world_at=arm.world_at,
            duration=FLEX_DURATION, fps=None, scene=None,
            skin=lambda: MuscleSkin(arm.character, arm.rig, skinning=args.skinning, method=args.method, mush=args.mush),
            source={"scene": "simple arm (built in)",
                    "motion": f"elbow 0 -> {FLEX_PEAK:g} deg in {FLEX_RISE:g} s, hold, back"}, character=arm.character)
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    clip = scene.clip if scene is not None else load_clip(args)
    if args.character is not None:
        from jiggle.rig.character.load import load_character
        character = load_character(args.character, k=args.influences, unit=args.unit, skin=args.skin)
        clip = retarget_onto_character(clip, args, character)
    else:
        character = generated_character(clip, args)
    mus = fit_musculature(character, args.template or "auto", FitOptions(joint_map=args.character_map))
    from jiggle.rig.character.real_size import real_size
    # the materials' rule at the character's real size: its file's unit (the bake also reads a glTF's own walk)
    scale = real_size(character).scale
    jiggles = default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles], scale=scale)
    if scene is not None:
        jiggles = scene.apply_jiggle(jiggles)
    rig = scene.apply_pose_shapes(mus.rig, character) if scene is not None else mus.rig

    def skin():
        s = MuscleSkin.from_musculature(mus, skinning=args.skinning, method=args.method, mush=args.mush,
                                        character_path=args.character)
        s.rig = rig                         # the scene's pose shapes, when it has any
        return s
    return SimulateJob(
        name=scene.name if scene is not None else clip.name, rig=rig, jiggles=jiggles,
        world_at=lambda t: transforms(*clip.world(*clip.sample(t))), duration=clip.duration,
        fps=scene.fps if scene is not None else None, scene=scene,
        skin=skin, clip=clip,
        source={"scene": scene.path if scene is not None else None, "clip": clip.source or args.clip,
                "character": args.character or "generated body", "template": mus.template.name},
        character=character, scale=scale)


def simulate_times(args, duration: float, fps: float):
    """Output times (T,) seconds: --start..--end (default the whole motion) at fps, the first --frames."""
    from jiggle.sim.bake.setup import output_times
    return output_times(duration, fps, args.start, args.end, args.frames)


def run(args) -> int:
    import time
    from dataclasses import replace

    import numpy as np

    from jiggle.sim.app.outputs.simulate import top_muscles, write_jiggle_outputs
    from jiggle.sim.jiggle.params import BlendCurve, JiggleSettings
    from jiggle.sim.jiggle.secondary import jiggle_rig

    job = simulate_job(args)
    scene = job.scene
    settings = scene.jiggle if scene is not None and scene.jiggle is not None else JiggleSettings()
    keyed = keyed_request(args)
    given = {"substeps": args.substeps, "strength": keyed["jiggle"], "preroll": args.preroll,
             "blend": None if keyed["blend"] is None else BlendCurve.parse(keyed["blend"], "--blend"),
             "gravity": True if args.gravity else None, "collisions": getattr(args, "collisions", None),
             "colliders": getattr(args, "colliders", None), "muscle_collisions": getattr(args, "muscle_collisions", None)}
    settings = replace(settings, **{k: v for k, v in given.items() if v is not None})
    jiggles = job.jiggles         # the scene's [jiggle] strength and tables applied (Scene.apply_jiggle)
    if keyed["blend"] is not None:    # --blend is every muscle's, over the scene's own curves
        jiggles = [replace(j, blend=None) for j in jiggles]
    if keyed["jiggle"] is not None:   # --strength: every muscle's, over the scene's
        jiggles = [replace(j, strength=settings.strength) for j in jiggles]
    if keyed["materials"]:            # then --material (goal springs from the tissue's material and size)
        from jiggle.sim.bake.setup import apply_materials
        jiggles, _ = apply_materials(jiggles, job.rig, keyed["materials"], scale=job.scale)
    if keyed["muscles"]:              # then NAME=VALUE entries, names and globs
        from jiggle.sim.bake.scene import apply_entries
        jiggles = apply_entries(jiggles, keyed["muscles"])
    # every muscle's strength is resolved above: jiggle_rig must not put the global one over the entries
    settings = replace(settings, strength=None)
    fps = args.fps or job.fps or SIMULATE_FPS
    times = simulate_times(args, job.duration, fps)
    rig = job.rig
    colliders = None
    if settings.collisions:
        from jiggle.sim.jiggle.colliders import collider_model, rest_floor
        from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE
        ts = np.linspace(times[0], times[-1], max(2, int((times[-1] - times[0]) * DEFAULT_GOAL_RATE) + 1))
        floor = rest_floor(job.character, float(np.min(np.asarray(job.world_at(ts))[..., 2, 3])))
        given = None
        if settings.colliders == "model":
            if job.clip is None:
                raise InputError("the built-in simple arm has no MuJoCo model, so no geoms to collide with; use "
                                 "--colliders bone", field="--colliders")
            from jiggle.sim.drive.skeleton import model_capsules
            given, _, _ = model_capsules(job.clip, job.character)
        colliders = collider_model(rig, job.character, capsules=given, floor=floor, device=settings.device)
    t0 = time.perf_counter()
    result = jiggle_rig(rig, jiggles, job.world_at, times, settings, colliders=colliders,
                        tissue=bool(settings.collisions and settings.muscle_collisions) or None)
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


def add_parser(sub) -> None:
    """The `jiggle simulate` subcommand and its options."""
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
    template_option(p)
    p.add_argument("--fps", type=positive("--fps"), metavar="N", help="output frames per second (default: the "
                   f"scene's, else {SIMULATE_FPS:g})")
    p.add_argument("--start", type=non_negative("--start"), metavar="S", help="first output time, seconds (default: 0)")
    p.add_argument("--end", type=non_negative("--end"), metavar="E", help="last output time, seconds (default: the "
                   "motion's end)")
    p.add_argument("--frames", type=count("--frames"), metavar="N", help="only the first N output frames")
    keyed_options(p)
    g = p.add_argument_group("jiggle solver (over the scene's [jiggle] section)")
    g.add_argument("--substeps", type=count("--substeps"), metavar="N", help="integration steps per output frame "
                   "(default: 4; the solver splits further where it must)")
    g.add_argument("--gravity", action="store_true", help="let the muscles sag under gravity below their static shape")
    collision_option(g)
    g.add_argument("--preroll", type=non_negative("--preroll"), metavar="S", help="start at rest at the bind pose S "
                   "seconds early (default: 0, start settled on the first frame)")
    g = p.add_argument_group("output")
    g.add_argument("--out", default="out/simulate", help="output folder (default: out/simulate)")
    g.add_argument("--every", type=count("--every"), default=1, metavar="K", help="render every K-th frame "
                   "(default: 1)")
    g.add_argument("--no-render", action="store_true", help="skip the frame pictures (plot and facts only)")
    g.add_argument("--focus", action="append", metavar="MUSCLE", help="muscle the pictures frame and draw "
                   "(repeatable; default: the scene's [output] focus, else those jiggling at least half as much as "
                   "the most)")
    muscle_skin_options(g)
    g = p.add_argument_group("character")
    map_options(g)
    mesh_options(g)
    character_options(p)
    clip_options(p)
    p.set_defaults(func=run)
