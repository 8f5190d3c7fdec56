"""Jiggle bones (`jiggle bake --formats glb`): the fit's time against the bake's own, the file against a pc2 of
the same frames, and how close the skin the file plays is to skin_final, measured in one run per case.

    .venv/bin/python benchmarks/bench_glb.py [--out benchmarks/results/bench_glb]

Cases (the issue's): the built-in demo; CesiumMan (../shared/assets) on two CMU clips retargeted; the 29.9k-vertex
generated body on the demo's jumping jacks. For each: the bake (sim.bake.baker.bake: frame loop and caches, npz +
pc2; setup left out, as in bench_bake.py) timed, then the glb (sim.bake.glb.write_for_bake: the decomposition,
the file written, the played skin measured) timed, side by side: glb_over_bake is glb / bake (frame loop and
caches), glb_over_command glb / (setup + bake), what `jiggle bake` costs the user without the glb; fit_over_* the
same for the decomposition alone (rig.skin.jiggle_bones.fit with its inputs).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))


def cases():
    from jiggle.sim.bake.setup import BakeRequest
    out = [("demo (built-in scene)", BakeRequest())]
    cm = ASSETS / "characters" / "CesiumMan.glb"
    for clip in ("02_04", "05_02"):
        bvh = ASSETS / "mocap" / "cmu_bvh" / f"{clip}.bvh"
        if cm.is_file() and bvh.is_file():
            out.append((f"CesiumMan on {clip}", BakeRequest(character=str(cm), clip=str(bvh))))
    out.append(("30k body, jumping jacks", BakeRequest(body=MappingProxyType({"resolution": 30000}))))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    a = ap.parse_args(argv)
    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.glb import write_for_bake
    from jiggle.sim.bake.setup import prepare
    warnings.simplefilter("ignore", JiggleWarning)
    rows = []
    for name, req in cases():
        t = time.perf_counter()
        setup = prepare(replace(req, formats=("npz", "pc2")))
        prepare_s = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as tmp:
            bake(setup, tmp)                                   # warm-up: kernels compiled and loaded
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            bake(setup, tmp)
            bake_s = time.perf_counter() - t
            t = time.perf_counter()
            rep = write_for_bake(setup, tmp)
            glb_s = time.perf_counter() - t
            pc2 = os.path.getsize(os.path.join(tmp, "bake.pc2"))
        s = rep["summary"]
        row = {"case": name, "frames": len(setup.times), "vertices": setup.character.num_vertices,
               "bones": rep["bones"], "bake_s": round(bake_s, 3), "glb_s": round(glb_s, 3),
               "fit_s": rep["fit_s"], "glb_over_bake": round(glb_s / bake_s, 2),
               "prepare_s": round(prepare_s, 3), "fit_over_bake": round(rep["fit_s"] / bake_s, 2),
               "fit_over_command": round(rep["fit_s"] / (prepare_s + bake_s), 2),
               "glb_over_command": round(glb_s / (prepare_s + bake_s), 2), "glb_bytes": rep["bytes"],
               "pc2_bytes": pc2, "glb_over_pc2": round(rep["bytes"] / pc2, 3),
               "rms_mm_max": round(s["rms_mm_max"], 3), "p99_mm_max": round(s["p99_mm_max"], 3),
               "max_mm": round(s["max_mm"], 2), "share_min": round(s["share_min"], 3),
               "explained_min": round(s["explained_min"], 3), "displacement_max_mm": round(s["displacement_max_mm"], 1)}
        rows.append(row)
        print(json.dumps(row))
    head = ["case", "frames", "vertices", "bones", "prepare_s", "bake_s", "fit_s", "glb_s", "fit_over_bake",
            "fit_over_command", "glb_over_bake", "glb_over_command", "glb_bytes", "pc2_bytes",
            "glb_over_pc2", "rms_mm_max", "p99_mm_max", "max_mm", "share_min", "explained_min"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lines += ["| " + " | ".join(str(r[k]) for k in head) + " |" for r in rows]
    print("\n".join(lines))
    if a.out:
        Path(a.out + ".json").write_text(json.dumps(rows, indent=1))
        Path(a.out + ".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
