"""`jiggle compare OUT_DIR`: a bake's static and dynamic skins compared in numbers, plots, renders
and one HTML report (sim/app/report/compare.py).
"""
from __future__ import annotations

import os


def run(args) -> int:
    res = compare_bake(args.out_dir, render=not args.no_render, video=not args.no_video)
    print(f"report: {res['files'].get('report', os.path.join(args.out_dir, 'report.html'))}")
    return 0


def compare_bake(out_dir: str, render: bool = True, video: bool = True) -> dict:
    from jiggle.sim.app.report.compare import compare
    res = compare(out_dir, render=render, video=video)
    m = res["metrics"]
    skin = m.get("skin", {})
    peak = skin.get("max_mm", skin.get("max_displacement_mm"))
    print(f"compared static and dynamic in {out_dir}" + (f": skin moved up to {peak:.1f} mm" if peak is not None else ""))
    targets = (m.get("skin_quality") or {}).get("targets")
    if targets:
        from jiggle.sim.app.report.skin_quality import fmt_targets
        print(f"skin quality: {fmt_targets(targets)}")
    for k, f in res["files"].items():
        print(f"  {k:13s} {f}")
    return res


def add_parser(sub) -> None:
    """The `jiggle compare` subcommand and its options."""
    p = sub.add_parser("compare", help="compare static and dynamic deformation of a bake",
                       description="Read OUT_DIR/bake.npz and write, into OUT_DIR: metrics.json (per-vertex "
                                   "maximum and RMS displacement of the final skin from the static one, per-muscle "
                                   "jiggle amplitude, energy and dominant frequency, the skin's quality per frame: "
                                   "folded edges of the LBS, static and final skins, edges torn by the jiggle), "
                                   "plots (amplitude, energy, spectrum, displacement, quality), renders (static | "
                                   "dynamic at the frame of peak jiggle with a displacement heat map, the worst "
                                   "frames for skin quality close up, a video of the clip) and report.html, one "
                                   "self-contained page showing them all.")
    p.add_argument("out_dir", metavar="OUT_DIR", help="a folder baked by `jiggle bake --out OUT_DIR`")
    p.add_argument("--no-render", action="store_true", help="skip the renders and the video")
    p.add_argument("--no-video", action="store_true", help="skip the video only")
    p.set_defaults(func=run)
