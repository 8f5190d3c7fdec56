"""`jiggle export BAKE_DIR --glb OUT.glb | --usd OUT.usdc | --pc2 OUT.pc2`: a finished bake as a skinned glTF with
jiggle bones any engine plays (sim/bake/glb.py; its setup rebuilt from bake.json as `jiggle view` rebuilds it), or
its skins as a USD stage or a PC2 point cache, from its npz (whatever formats it was baked with).
"""
from __future__ import annotations

import json
import os

from jiggle.sim.app.args import glb_options


def run(args) -> int:
    from jiggle.rig.base.errors import InputError
    summary_path = os.path.join(args.bake_dir, "bake.json")
    if not os.path.isfile(summary_path):
        raise InputError("not a finished bake (no bake.json): bake it first with `jiggle bake --out BAKE_DIR`",
                         args.bake_dir)
    if not os.path.isfile(os.path.join(args.bake_dir, "bake.npz")):
        raise InputError("the bake has no bake.npz (every export is made from it): bake again with --formats npz",
                         args.bake_dir)
    asked = [(form, getattr(args, form)) for form in ("glb", "usd", "pc2") if getattr(args, form)]
    if not asked:
        raise InputError("nothing to export: give --glb OUT.glb, --usd OUT.usdc or --pc2 OUT.pc2", args.bake_dir)
    ends = {"glb": (".glb",), "usd": (".usd", ".usdc", ".usda"), "pc2": (".pc2",)}
    for form, path in asked:
        if not path.lower().endswith(ends[form]):
            raise InputError(f"expected a path ending in {' or '.join(ends[form])}", path, field=f"--{form}")
    with open(summary_path, encoding="utf-8") as fh:
        summary = json.load(fh)
    for form, path in asked:
        if form == "glb":
            export_glb(args, summary, path)
        else:
            export_cache(args, form, path)
    return 0


def export_cache(args, form: str, path: str) -> None:
    """--usd, --pc2: the bake's skins from its npz (the USD stage holds skin_static and skin_final, as the bake's
    own, without the muscles' meshes; the pc2 skin_final)."""
    from jiggle.sim.bake.caches import read_npz, write_pc2, write_usd
    data = read_npz(os.path.join(args.bake_dir, "bake.npz"))
    if form == "usd":
        write_usd(data, path)
    else:
        write_pc2(data.skin_final, path, data.fps, float(data.times[0]))
    print(f"{path}: {data.num_frames} frames of {data.skin_final.shape[1]} vertices ({os.path.getsize(path) / 1e6:.2f}"
          f" MB)")


def export_glb(args, summary: dict, path: str) -> None:
    from jiggle.rig.base.errors import InputError
    from jiggle.sim.app.view.tuning import NotTunable, request_from_params
    from jiggle.sim.bake.glb import write_for_bake
    from jiggle.sim.bake.setup import prepare
    try:
        setup = prepare(request_from_params(summary.get("params") or {}))
    except NotTunable as e:
        raise InputError(f"the bake's setup does not rebuild: {e}", args.bake_dir) from None
    if setup.key != summary.get("key"):
        raise InputError("the bake's setup rebuilds differently from the bake (a file it read changed?); bake "
                         "again", args.bake_dir)
    rep = write_for_bake(setup, args.bake_dir, bones=args.jiggle_bones, max_influences=args.max_influences,
                         path=path)
    s = rep["summary"]
    print(f"{path}: {rep['bones']} jiggle bones, {rep['bytes'] / 1e6:.2f} MB ({rep['bytes'] / rep['pc2_bytes']:.0%}"
          f" of a pc2 of the same frames); against skin_final per frame: RMS <= {s['rms_mm_max']:.2f} mm, p99 <= "
          f"{s['p99_mm_max']:.2f} mm, max {s['max_mm']:.2f} mm; the bones make {s['share_min']:.0%} or more of "
          f"the muscles' motion; fitted in {rep['fit_s']:.1f} s")


def add_parser(sub) -> None:
    """The `jiggle export` subcommand and its options."""
    p = sub.add_parser("export", help="a bake as a skinned glTF with jiggle bones any engine plays, or as USD or PC2",
                       description="Read BAKE_DIR (bake.json, bake.npz), rebuild its setup, fit jiggle bones to what "
                                   "the muscles add to plain skinning and write one .glb: the character's mesh and "
                                   "material, its skeleton animated as baked, and the jiggle bones (children of the "
                                   "bones the muscles ride, named <muscle>_jiggle_<k>) with their weights.")
    p.add_argument("bake_dir", metavar="BAKE_DIR", help="a folder baked by `jiggle bake --out BAKE_DIR`")
    p.add_argument("--glb", metavar="OUT.glb", help="a skinned glTF with jiggle bones (below) to write")
    p.add_argument("--usd", metavar="OUT.usdc", help="a USD stage of the skins (skin_static, skin_final; .usd, .usdc "
                   "or .usda) to write")
    p.add_argument("--pc2", metavar="OUT.pc2", help="a PC2 point cache of skin_final to write")
    glb_options(p)
    p.set_defaults(func=run)
