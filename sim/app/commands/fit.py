"""`jiggle fit [CHARACTER]`: fit a template's muscles and fat to a character from the outside in and
write the musculature, its facts and a picture, and print how well each muscle fits (rig.muscle.fit_quality:
a summary line, then one line per muscle kept with a warning or refused).

It also writes the painted maps' starting point (rig.character.painted_maps): ``<stem>.painted.glb``, a
copy of the character with a ``_JIGGLE`` and a ``_SHELL_<MUSCLE>`` vertex attribute per muscle to paint
in Blender (import, paint the attributes, export with "Attributes" on) and read back as the character,
and ``<stem>.jiggle_map.npz``, the same maps as a sidecar to put beside the original character file.
"""
from __future__ import annotations

import os

from jiggle.sim.app.args import character_options, count, map_options, mesh_options, template_option, unit_interval
from jiggle.sim.app.loading import default_scene, generated_character

SKELETON_SUFFIXES = (".bvh", ".asf", ".amc", ".toml", ".xml")


def fit_character(path: str | None, args):
    """The character `jiggle fit` works on: a skinned glTF, a mesh with --skeleton, or a body generated
    around a skeleton file (clip, ASF, MJCF, keyframed TOML); None: the demo's generated body."""
    from jiggle.rig.character.load import load_character, load_skeleton
    if path is None:
        from jiggle.sim.bake.scene import load_scene
        return generated_character(load_scene(default_scene()).clip, args)
    if os.path.splitext(path)[1].lower() in SKELETON_SUFFIXES:
        return generated_character(load_skeleton(path), args)
    return load_character(path, skeleton=args.skeleton, k=args.influences, unit=args.unit, up=args.up,
                          skin=args.skin, jiggle_attribute=getattr(args, "jiggle_attribute", None))


def starting_maps(mus):
    """The painted maps a user starts from (rig.character.painted_maps.PaintedMaps, complete): the
    character's own where it has them, else the jiggle map 1 everywhere (today's skin: a map of ones
    changes nothing, stays right when the template later reaches further, and the painter only lowers
    it where jiggle should not show) and each muscle's computed shell region (rig.skin.painted_maps.
    shell_regions, smooth: 1 within the drop-off shell, fading to 0 at the culling line), so that read
    back unpainted they give the skin jiggle gives without them."""
    import numpy as np

    from jiggle.rig.character.painted_maps import PaintedMaps
    from jiggle.rig.skin.painted_maps import shell_regions
    ch, rig = mus.character, mus.rig
    own = ch.maps
    computed = shell_regions(ch, rig, [m.spec.shell for m in mus.muscles])
    if own is not None:
        painted = own.influence_table(rig.names)
        if painted is not None:
            computed = np.where(np.isnan(painted), computed, painted)
    jiggle = own.jiggle if own is not None and own.jiggle is not None else np.ones(ch.num_vertices, np.float32)
    return PaintedMaps(jiggle=jiggle, influence={n: computed[:, m] for m, n in enumerate(rig.names)},
                       source="jiggle fit")


def write_maps(mus, maps, out_dir: str) -> dict:
    """The starting point to paint: ``<stem>.painted.glb`` (the character's glTF with _JIGGLE and
    _SHELL_<MUSCLE> attributes, rig.character.gltf_maps) and ``<stem>.jiggle_map.npz`` (the same maps;
    beside the original character file it is read as its sidecar), in `out_dir`. Returns {kind: path}."""
    from jiggle.rig.character.gltf_maps import write_maps_copy
    from jiggle.rig.character.painted_maps import SIDECAR, save_maps
    ch = mus.character
    stem = os.path.splitext(os.path.basename(ch.source))[0] if ch.source else (ch.name or "body").replace(" ", "_")
    glb = write_maps_copy(ch, os.path.join(out_dir, f"{stem}.painted.glb"), maps)
    npz = save_maps(os.path.join(out_dir, f"{stem}{SIDECAR}.npz"), maps, ch.num_vertices)
    return {"painted": glb, "maps": str(npz)}


def fit_capsules(mus, colliders: str = "bone"):
    """The capsules a bake of this musculature collides with (sim.jiggle.colliders.collider_model: the
    character's bone capsules, or with colliders "model" the capsule geoms of the MuJoCo model of its own
    skeleton kept inside its skin, each shrunk inside the muscles over its bone), or None when it has none."""
    from jiggle.sim.jiggle.colliders import collider_model
    given = None
    if colliders == "model" and mus.character.skeleton is not None:
        from jiggle.sim.drive.skeleton import model_capsules
        given, _, _ = model_capsules(mus.character.skeleton, mus.character)
    caps = collider_model(mus.rig, mus.character, capsules=given).capsules
    return caps if caps.count else None


def run(args) -> int:
    import numpy as np

    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    from jiggle.sim.app.outputs.fit import quality_line, write_fit_outputs
    character = fit_character(args.character, args)
    options = FitOptions(iterations=args.iterations, lam=args.smoothing, volume=args.volume,
                         joint_map=args.character_map, exclude=tuple(args.exclude or ()), strict=args.strict)
    mus = fit_musculature(character, args.template or "auto", options)
    png = None if args.no_render else (args.png or os.path.join(os.path.dirname(args.out) or ".", "fit.png"))
    json_path = os.path.splitext(args.out)[0] + ".json"
    maps = None if args.no_maps else starting_maps(mus)
    shown = None
    if maps is not None:
        import numpy as np
        reach = np.max(np.stack(list(maps.influence.values())), axis=0) if maps.influence else \
            np.zeros(character.num_vertices)
        shown = {"jiggle map (0 dark: none, 1 bright)": maps.jiggle, "shell regions (max over muscles)": reach}
    files = write_fit_outputs(mus, args.out, png, json_path, maps=shown, capsules=fit_capsules(mus, args.colliders),
                              capsules_title=f"{'MuJoCo model' if args.colliders == 'model' else 'bone'} capsules "
                              "(collisions)")
    if maps is not None:
        files.update(write_maps(mus, maps, os.path.dirname(args.out) or "."))
    rig = mus.rig
    print(f"body plan: {mus.plan.kind} ({mus.plan.reason})")
    print(f"fitted {len(mus.muscles)} muscles ({sum(m.kind == 'fat' for m in mus.muscles)} fat) from template "
          f"{mus.template.name!r} to {character.name or 'the character'} ({character.num_vertices} vertices) in "
          f"{mus.timings['total']:.2f} s; loft fit error rms {1e3 * float(np.sqrt(np.mean(rig.fit_rms ** 2))):.2f} mm, "
          f"worst {1e3 * float(rig.fit_max.max()):.2f} mm")
    print(quality_line(mus))
    for k, f in files.items():
        print(f"  {k:9s} {f}")
    return 0


def add_parser(sub) -> None:
    """The `jiggle fit` subcommand and its options."""
    p = sub.add_parser("fit", help="fit muscles and fat to a character from a template (outside in)",
                       description="Segment the character's skin by bone, fit the template's ellipsoidal muscles "
                                   "and muscle pairs to the regions, attach tendons, conform them to the skin and "
                                   "build the lofted muscle model; write the musculature (TOML), its facts (JSON) "
                                   "and a picture of the skin over the muscles.")
    p.add_argument("character", nargs="?", metavar="CHARACTER",
                   help="a skinned glTF/GLB, a mesh (OBJ/PLY/STL/glTF, with --skeleton), or a skeleton "
                        "(BVH, ASF, AMC, MJCF, keyframed TOML) to generate a body around (default: the demo's body)")
    template_option(p)
    p.add_argument("--out", default="out/fit/muscles.toml", help="musculature TOML (default: out/fit/muscles.toml)")
    p.add_argument("--png", metavar="FILE", help="picture (default: fit.png beside --out)")
    p.add_argument("--no-render", action="store_true", help="skip the picture")
    map_options(p, clip=False)
    p.add_argument("--iterations", type=count("--iterations", zero=True), default=25,
                   help="normal smoothing iterations for the segmentation (default: 25)")
    p.add_argument("--smoothing", type=unit_interval("--smoothing"), default=1.0, metavar="LAMBDA",
                   help="normal smoothing lambda in [0, 1] (default: 1)")
    p.add_argument("--exclude", action="append", metavar="JOINT", help="leave a joint's bones out of the "
                   "segmentation (repeatable)")
    p.add_argument("--strict", action="store_true", help="fail when a muscle is refused by the fit quality "
                   "check (mostly outside the skin, or a loft error over 50%% of the local radius) instead of "
                   "leaving it out with a warning")
    p.add_argument("--volume", choices=["exact", "sqrt", "thesis", "none"], default="exact",
                   help="how muscles keep their volume when they stretch (default: exact)")
    p.add_argument("--skeleton", metavar="FILE", help="the skeleton of a mesh character (clip, ASF, MJCF)")
    mesh_options(p)
    p.add_argument("--no-maps", action="store_true", help="do not write the painted maps' starting point "
                   "(<stem>.painted.glb with _JIGGLE and _SHELL_<MUSCLE> vertex attributes, <stem>.jiggle_map.npz)")
    p.add_argument("--jiggle-attribute", metavar="ATTR", help="the glTF vertex attribute the jiggle map is read "
                   "from: _JIGGLE (default), another '_NAME', or a vertex colour's channel such as COLOR_0.r")
    p.add_argument("--colliders", choices=["bone", "model"], default="bone",
                   help="the capsules drawn in fit.png and listed in the JSON: bone (fitted inside the skin) or model "
                   "(the MuJoCo model's own capsule geoms, kept inside the skin) (default: bone)")
    character_options(p)
    p.set_defaults(func=run)
