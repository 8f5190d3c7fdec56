"""`jiggle export BAKE_DIR --glb OUT.glb`: a finished bake as a skinned glTF with jiggle bones any engine plays
(sim/bake/glb.py), its setup rebuilt from bake.json as `jiggle view` rebuilds it.
"""
from __future__ import annotations

import json
import os

from sim.app.args import glb_options


def run(args) -> int:
    from rig.base.errors import InputError
    from sim.app.view.tuning import NotTunable, request_from_params
    from sim.bake.glb import write_for_bake
    from sim.bake.setup import prepare
    summary_path = os.path.join(args.bake_dir, "bake.json")
    if not os.path.isfile(summary_path):
        raise InputError("not a finished bake (no bake.json): bake it first with `jiggle bake --out BAKE_DIR`",
                         args.bake_dir)
    if not os.path.isfile(os.path.join(args.bake_dir, "bake.npz")):
        raise InputError("the bake has no bake.npz (the glb is fitted from it): bake again with --formats npz "
                         "(or glb)", args.bake_dir)
    if not args.glb.lower().endswith(".glb"):
        raise InputError("expected a path ending in .glb", args.glb, field="--glb")
    with open(summary_path, encoding="utf-8") as fh:
        summary = json.load(fh)
    try:
        setup = prepare(request_from_params(summary.get("params") or {}))
    except NotTunable as e:
        raise InputError(f"the bake's setup does not rebuild: {e}", args.bake_dir) from None
    if setup.key != summary.get("key"):
        raise InputError("the bake's setup rebuilds differently from the bake (a file it read changed?); bake "
                         "again", args.bake_dir)
    rep = write_for_bake(setup, args.bake_dir, bones=args.jiggle_bones, max_influences=args.max_influences,
                         path=args.glb)
    s = rep["summary"]
    print(f"{args.glb}: {rep['bones']} jiggle bones, {rep['bytes'] / 1e6:.2f} MB ({rep['bytes'] / rep['pc2_bytes']:.0%}"
          f" of a pc2 of the same frames); against skin_final per frame: RMS <= {s['rms_mm_max']:.2f} mm, p99 <= "
          f"{s['p99_mm_max']:.2f} mm, max {s['max_mm']:.2f} mm; the bones make {s['share_min']:.0%} or more of "
          f"the muscles' motion; fitted in {rep['fit_s']:.1f} s")
    return 0


def add_parser(sub) -> None:
    """The `jiggle export` subcommand and its options."""
    p = sub.add_parser("export", help="a bake as a skinned glTF with jiggle bones any engine plays",
                       description="Read BAKE_DIR (bake.json, bake.npz), rebuild its setup, fit jiggle bones to what "
                                   "the muscles add to plain skinning and write one .glb: the character's mesh and "
                                   "material, its skeleton animated as baked, and the jiggle bones (children of the "
                                   "bones the muscles ride, named <muscle>_jiggle_<k>) with their weights.")
    p.add_argument("bake_dir", metavar="BAKE_DIR", help="a folder baked by `jiggle bake --out BAKE_DIR`")
    p.add_argument("--glb", required=True, metavar="OUT.glb", help="the file to write")
    glb_options(p)
    p.set_defaults(func=run)
