"""`jiggle morph CANONICAL`: a canonical character morphed to a target from sparse markers
(rig/anatomy/morph.py), or the canonical's markers written out to start from.
"""
from __future__ import annotations

import os

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.args import influences_option, map_options, non_negative, positive


def run(args) -> int:
    """Morph a canonical character to a target from marker positions; or write the canonical's markers."""
    import time

    from jiggle.rig.anatomy.features import FeatureOptions
    from jiggle.rig.anatomy.markers import read_markers, write_markers
    from jiggle.rig.anatomy.morph import MorphOptions, morph, prepare_canonical
    from jiggle.rig.character.load import load_character
    from jiggle.sim.app.outputs.morph import render_morph, side_paths, write_report

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
                           joint_map=args.character_map)
    canon = prepare_canonical(character, options, source=args.canonical)
    if args.write_markers is not None:
        write_markers(args.write_markers, canon.markers.names, canon.markers.positions, source=args.canonical)
        print(f"wrote the {len(canon.markers.names)} markers of {args.canonical} to {args.write_markers} "
              "(metres, Z-up); move them to the target's and run: jiggle morph CANONICAL --markers FILE --out T.glb")
        if args.markers is None:
            return 0
    target = read_markers(args.markers, canon.markers.names)
    res = morph(canon, target, options)
    from jiggle.rig.character.gltf_write import write_character
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


def add_parser(sub) -> None:
    """The `jiggle morph` subcommand and its options."""
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
    map_options(p, clip=False)
    g = p.add_argument_group("skin interpolation")
    g.add_argument("--kernel", choices=["soliton", "gaussian", "multiquadric", "inverse_multiquadric"],
                   default="soliton", help="radial basis function (default: soliton e^(-r/s))")
    g.add_argument("--rbf-scale", type=positive("--rbf-scale"), default=0.1, metavar="S",
                   help="the kernel's scale s as a fraction of the body's height (default: 0.1)")
    g.add_argument("--band", type=non_negative("--band"), default=0.04, metavar="B",
                   help="blend band across zone boundaries, fraction of the height (default: 0.04)")
    g.add_argument("--spacing", type=positive("--spacing"), default=0.02, metavar="D",
                   help="least distance between feature points, fraction of the height (default: 0.02)")
    g.add_argument("--snap-only", action="store_true", help="snap feature points to existing vertices instead "
                   "of inserting new ones (keeps the canonical's topology)")
    g.add_argument("--marker-features", action="store_true", help="also pin the marker vertices to the target's "
                   "markers (exact markers; a misplaced marker dents the skin)")
    g = p.add_argument_group("canonical file")
    g.add_argument("--skin", type=int, default=0, metavar="N", help="which skin of the glTF (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the file's unit: auto, m, cm, mm, in, ft or metres per unit "
                   "(default: auto: metres unless the height says cm or mm)")
    influences_option(g)
    p.set_defaults(func=run)
