"""Skin quality over every shared clip, measured in one run: folds, jiggle tears, the start and the
muscles' offsets, with the generated body and with CesiumMan, default settings, as one table.

    .venv/bin/python benchmarks/bench_quality.py [--quick] [--clips 02_03,05_02] [--skinning shell,rbf,influence]

Per clip and character: a default `jiggle bake` (30 fps, npz only) in a temporary folder, then the
measures of `jiggle compare` (sim.app.report.skin_quality, rig.skin.quality) on its caches:

- folded edges (> 90 degrees) of the LBS skin and of the final skin, most in a frame; the budget
  (the rest mesh's own count + 0.1% of the edges) and whether the final skin stays in it;
- folds added over LBS: most in a frame beyond LBS's, and the clip's total of final over LBS;
- jiggle tears: edges the jiggle stretches or squeezes by more than their length (most in a frame) and
  the 99.9th percentile of the displacement gradient (worst frame; target < 0.5);
- the start: the largest muscle offset in the first two frames against the clip's median (target:
  no larger), and the largest muscle offset of each kind (mm) against its bound (sim.jiggle.params);
- the bake's frame loop in frames per second (bake.json), to weigh what quality costs.

The rows are the issue's targets as numbers; the test suite holds the synthetic cases.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CLIPS = ("cmu_bvh/01_01.bvh", "cmu_bvh/02_03.bvh", "cmu_bvh/02_04.bvh", "cmu_bvh/05_02.bvh", "cmu_bvh/09_11.bvh",
         "cmu_amc/01_01.amc")
CHARACTERS = {"body": None, "CesiumMan": "characters/CesiumMan.glb"}


def measure(out_dir: str) -> dict:
    """The row of one finished bake in out_dir."""
    from jiggle.sim.app.report.skin_quality import measure as skin_measure
    from jiggle.sim.app.report.skin_quality import summarise
    from jiggle.sim.bake.caches import read_npz
    data = read_npz(os.path.join(out_dir, "bake.npz"))
    m = skin_measure(data)
    q = summarise(m, data.times)
    lbs, fin = m["lbs"]["folded_edges"], m["final"]["folded_edges"]
    d = np.linalg.norm(data.muscle_cvs_dynamic.astype(np.float64) - data.muscle_cvs_static, axis=2)
    o = data.muscle_cv_offsets
    amp = np.stack([d[:, o[k]:o[k + 1]].max(axis=1) for k in range(len(o) - 1)], axis=1)       # (T, M)
    params = json.loads(data.params)
    kinds = [params["muscles"][n].get("kind", "muscle") for n in data.muscle_names]
    bounds = {n: params["muscles"][n].get("max_offset_m") for n in data.muscle_names}
    worst = {}
    for kind in sorted(set(kinds)):
        cols = [k for k, x in enumerate(kinds) if x == kind]
        k = cols[int(np.argmax(amp[:, cols].max(axis=0)))]
        worst[kind] = (data.muscle_names[k], float(amp[:, k].max()), bounds[data.muscle_names[k]])
    frame_amp = amp.max(axis=1)
    summary = json.loads(Path(out_dir, "bake.json").read_text())
    return {"frames": data.num_frames, "edges": q["edges"], "rest": q["rest"]["folded_edges"],
            "budget": q["targets"]["final_folded_edges"]["limit"], "lbs_max": int(lbs.max()),
            "final_max": int(fin.max()), "added_max": int((fin - lbs).max()),
            "added_total": float(fin.sum() / max(lbs.sum(), 1)), "torn": int(m["jiggle"]["torn_edges"].max()),
            "p999": float(m["jiggle"]["gradient_p999"].max()), "start": float(frame_amp[:2].max()),
            "median": float(np.median(frame_amp)), "worst": worst,
            "fps": summary["timings"]["frames_per_s"]}


def bake_one(clip: str, character: str | None, skinning: str, tmp: str) -> dict:
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import BakeRequest, prepare
    out = tempfile.mkdtemp(dir=tmp)
    req = BakeRequest(clip=str(ASSETS / "mocap" / clip), formats=("npz",), skinning=skinning,
                      character=None if character is None else str(ASSETS / character))
    bake(prepare(req), out)
    return measure(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the two short run clips only")
    ap.add_argument("--clips", help="comma-separated clip names (e.g. 02_03,05_02)")
    ap.add_argument("--skinning", default="shell", help="comma-separated: shell, influence, rbf (default: shell)")
    ap.add_argument("--characters", default="body,CesiumMan", help="comma-separated: body, CesiumMan")
    args = ap.parse_args(argv)
    if not ASSETS.is_dir():
        print(f"skipped: the shared assets are not at {ASSETS} (set JIGGLE_ASSETS)")
        return 0
    clips = [c for c in CLIPS if not args.quick or c.split("/")[1][:5] in ("02_03", "09_11")]
    if args.clips:
        want = args.clips.split(",")
        clips = [c for c in CLIPS if any(os.path.basename(c).startswith(w) for w in want)]
    import warp as wp
    wp.config.quiet = True
    print("| clip | character | skinning | frames | frames/s | folded LBS / final (budget) | added over LBS: "
          "worst frame, clip total | torn | gradient p99.9 | first 2 frames / median (mm) | worst muscle, fat "
          "(mm / bound) |")
    print("|---" * 11 + "|")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for character in args.characters.split(","):
            for skinning in args.skinning.split(","):
                for clip in clips:
                    r = bake_one(clip, CHARACTERS[character], skinning, tmp)
                    w = "; ".join(f"{kind} {name} {1e3 * a:.0f}" + ("" if b is None else f" / {1e3 * b:.0f}")
                                  for kind, (name, a, b) in r["worst"].items())
                    ok = "ok" if r["final_max"] <= r["budget"] else "OVER"
                    print(f"| {os.path.basename(clip)} | {character} | {skinning} | {r['frames']} | {r['fps']:.0f} | "
                          f"{r['lbs_max']} / {r['final_max']} ({r['budget']:.0f}, {ok}) | {r['added_max']:+d}, "
                          f"{r['added_total']:.2f}x | {r['torn']} | {r['p999']:.2f} | {1e3 * r['start']:.1f} / "
                          f"{1e3 * r['median']:.1f} | {w} |", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
