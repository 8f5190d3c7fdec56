"""`jiggle bake`: a clip baked into caches (USD, npz, pc2), chunk by chunk, with a progress bar and
--resume after Ctrl-C (sim/bake).
"""
from __future__ import annotations

import os
import sys

from jiggle.sim.app.args import (bake_options, chain_request, clip_options, keyed_request, map_options, positive,
                                 template_option)
from jiggle.sim.app.loading import body_overrides


def bake_request(args):
    """The BakeRequest of `jiggle bake` (or `jiggle demo`) arguments."""
    from types import MappingProxyType

    from jiggle.sim.bake.scene import parse_formats
    from jiggle.sim.bake.setup import BakeRequest
    body = body_overrides(args)
    formats = None if getattr(args, "formats", None) is None else parse_formats(args.formats)
    return BakeRequest(
        scene=getattr(args, "scene", None), clip=getattr(args, "clip", None), skeleton=getattr(args, "skeleton", None),
        animation=getattr(args, "animation", None), scale=getattr(args, "scale", None),
        tpose=getattr(args, "tpose", "auto"), character=getattr(args, "character", None),
        template=getattr(args, "template", None), fps=args.fps, substeps=args.substeps, **keyed_request(args),
        gravity=getattr(args, "gravity", None), preroll=getattr(args, "preroll", None),
        collisions=getattr(args, "collisions", None), colliders=getattr(args, "colliders", None),
        muscle_collisions=getattr(args, "muscle_collisions", None), device=getattr(args, "device", None),
        start=args.start, end=args.end, frames=args.frames, drive=args.drive,
        formats=formats, chunk=args.chunk, body=MappingProxyType(body), influences=args.influences,
        jiggle_bones=getattr(args, "jiggle_bones", None), max_influences=getattr(args, "max_influences", 4),
        skinning=args.skinning, method=args.method, clip_map=getattr(args, "clip_map", None),
        character_map=getattr(args, "character_map", None),
        skin=getattr(args, "skin", None), unit=getattr(args, "unit", None), mush=getattr(args, "mush", None),
        loop=getattr(args, "loop", None), rigid=getattr(args, "rigid", None), height=getattr(args, "height", None),
        tissue=getattr(args, "tissue", None), activation=getattr(args, "activation", None), **chain_request(args))


def emit(event: str, **fields) -> None:
    """One line of the machine-readable progress stream (`--progress json`) on stdout: {"event": ..., ...}."""
    import json
    print(json.dumps({"event": event, **fields}), flush=True)


class JsonProgress:
    """tqdm's update(n) and write(s), as `--progress json` lines: frames done, frames per second, time left."""

    def __init__(self, total: int):
        import time
        self.total, self.done, self.t0, self.clock = total, 0, time.perf_counter(), time.perf_counter

    def update(self, n: int) -> None:
        self.done += int(n)
        dt = max(self.clock() - self.t0, 1e-9)
        fps = self.done / dt
        emit("progress", frames=self.done, total=self.total, fps=round(fps, 2),
             eta_s=round((self.total - self.done) / fps, 2) if fps > 0 else None)

    def write(self, s: str, file=None) -> None:
        emit("note", text=s.strip())


def run_bake(request, out_dir: str, resume: bool = False, progress: str = "bar") -> dict:
    """Prepare and bake with a progress bar (or, progress="json", a line of JSON per chunk on stdout: see
    `emit`; "none": nothing printed); on Ctrl-C re-raise KeyboardInterrupt with a message saying what was kept and how to resume (main
    prints it after "jiggle: interrupted")."""
    from tqdm import tqdm

    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import prepare

    def log(s):
        print(f"  {s}", file=sys.stderr)
    if progress == "none":                                            # the public API's progress=False
        setup = prepare(request)
        try:
            return bake(setup, out_dir, resume=resume)
        except KeyboardInterrupt:
            raise KeyboardInterrupt(interrupted_message(setup, out_dir)) from None
    if progress == "json":
        emit("preparing")
    setup = prepare(request, log)
    T = len(setup.times)
    if progress == "json":
        emit("start", frames=T, fps=setup.fps, vertices=setup.character.num_vertices, muscles=setup.rig.M,
             out=os.path.abspath(out_dir))
        bar = JsonProgress(T)
        try:
            summary = bake(setup, out_dir, resume=resume, progress=bar.update, log=bar.write)
        except KeyboardInterrupt:
            raise KeyboardInterrupt(interrupted_message(setup, out_dir)) from None
        emit("done", out=os.path.abspath(out_dir), files=summary["files"])
        return summary
    print(f"baking {setup.name!r}: {T} frames at {setup.fps:g} fps ({setup.times[0]:.3f}-{setup.times[-1]:.3f} s), "
          f"{setup.character.num_vertices} vertices, {setup.rig.M} muscles -> {os.path.abspath(out_dir)}",
          file=sys.stderr)
    with tqdm(total=T, unit="frame", desc="bake", disable=None, file=sys.stderr, dynamic_ncols=True) as bar:
        try:
            summary = bake(setup, out_dir, resume=resume, progress=bar.update,
                           log=lambda s: bar.write(f"  {s}", file=sys.stderr))
        except KeyboardInterrupt:
            bar.close()
            raise KeyboardInterrupt(interrupted_message(setup, out_dir)) from None
    return summary


def interrupted_message(setup, out_dir: str) -> str:
    """What a Ctrl-C kept: the frames of the chunks finished on disk (not the progress bar's count, which
    stays 0 when stderr is not a terminal), and how to resume."""
    import shlex

    from jiggle.sim.bake.baker import PARTIAL, chunk_frames, chunk_path, num_chunks
    n, T = num_chunks(setup), len(setup.times)
    kept = 0
    while kept < n and os.path.isfile(chunk_path(out_dir, kept)):    # chunks are written atomically, in order
        kept += 1
    frames = chunk_frames(setup, kept - 1)[1] if kept else 0
    partial = os.path.join(os.path.abspath(out_dir), PARTIAL)
    if not os.path.isdir(partial):
        return f"after 0 of {T} frames, before the bake began; nothing was kept"
    return (f"after {frames} of {T} frames: the {kept} finished chunks (of {n}) are kept in {partial}; to "
            f"finish, run the same command with --resume --out {shlex.quote(out_dir)}")


def print_bake(summary: dict, out_dir: str) -> None:
    tm = summary["timings"]
    fps = tm.get("frames_per_s")
    print(f"{summary['name']}: {summary['frames']} frames, {summary['vertices']} vertices, {summary['muscles']} "
          f"muscles baked in {tm['frames_s']:.2f} s" + (f" ({fps:.0f} frames/s)" if fps else "") +
          f", caches written in {tm['caches_s']:.2f} s")
    for k, f in summary["files"].items():
        print(f"  {k:5s} {os.path.join(out_dir, f)}")
    print(f"  json  {os.path.join(out_dir, 'bake.json')}")


def run(args) -> int:
    mode = getattr(args, "progress", None) or "bar"
    summary = run_bake(bake_request(args), args.out, resume=args.resume, progress=mode)
    if mode != "json":
        print_bake(summary, args.out)
    return 0


def add_parser(sub) -> None:
    """The `jiggle bake` subcommand and its options."""
    p = sub.add_parser("bake", help="bake jiggle for a clip into caches (USD, npz, pc2)",
                       description="Clip -> MuJoCo skeleton -> static muscles -> particles -> blend -> skinning -> "
                                   "caches. Writes bake.npz, bake.usdc (or .usda) and optionally bake.pc2, with "
                                   "bake.json (parameters, timings), into --out. Long bakes are written in chunks: "
                                   "Ctrl-C keeps the chunks done and --resume finishes the bake, equal to an "
                                   "unbroken one. Without a scene or --clip: the built-in demo scene. "
                                   "Command-line settings override the scene's.")
    p.add_argument("scene", nargs="?", metavar="SCENE", help="a scene TOML (scenes/*.toml); its [motion] may be left "
                   "out and given with --clip")
    p.add_argument("--clip", metavar="FILE", help="the motion: BVH, AMC (its ASF beside it or --skeleton), "
                   "glTF/GLB with animations or FBX (6.1/7.x, binary or ASCII) with takes (--animation; FBX is read "
                   "through Blender's importer)")
    p.add_argument("--character", metavar="FILE", help="a skinned glTF/GLB or FBX: the clip is retargeted onto it "
                   "(default: the scene's, else a body generated around the clip's skeleton)")
    template_option(p)
    bake_options(p, "out/bake")
    p.add_argument("--progress", choices=["bar", "json"], default="bar", help="bar: a progress bar on stderr; json: "
                   "one JSON object a line on stdout for another program (a DCC's add-on) to read: "
                   '{"event": "preparing" | "start" (frames, fps, vertices, muscles, out) | "progress" (frames, '
                   'total, fps, eta_s) | "note" (text) | "done" (out, files)}; errors stay one line on stderr '
                   "(default: bar)")
    g = p.add_argument_group("character")
    map_options(g)
    g.add_argument("--skin", type=int, metavar="N", help="which skin of a glTF character (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the character file's unit: auto, m, cm, mm, in, ft or metres per "
                   "unit (default: auto: metres unless the height says cm or mm)")
    g.add_argument("--height", type=positive("--height"), metavar="METRES", help="the character's real height, for "
                   "its tissue materials (--material): default inferred from its own walk cycle, else the file's unit")
    g.add_argument("--tissue", choices=("particles", "fem"), help="the tissue solver: particles (goal springs on "
                   "each muscle's control points, the default) or fem (the hero mode: every simulated muscle a "
                   "Neo-Hookean solid of its material, its control points embedded in its tets; minutes, not seconds)")
    g.add_argument("--activation", choices=("on", "off"), help="on: each muscle's activation (0 to 1) from the "
                   "clip's own joint torques (inverse dynamics with the ground, shared among the muscles by least "
                   "effort): a working muscle's springs stiffen with its fibres' tension and its belly bulges (fat never); "
                   "written to bake.npz "
                   "(activation, frames x muscles) and bake.json (each muscle's peak and mean) (default: on wherever the "
                   "character has muscles (fat alone has none to work), off with --tissue fem)")
    clip_options(p)
    p.set_defaults(func=run)
