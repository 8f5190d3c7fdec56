"""The bake's speed, measured in one run: frames per second and the cost against LBS alone.

    .venv/bin/python benchmarks/bench_bake.py [--quick]

1. CesiumMan (3,273 vertices, ../shared/assets) with the default template on 02_03.bvh at 30 fps,
   retargeted: `jiggle bake`'s frame loop (sim.bake.baker: drive, static muscles, particles, blend, skinning of
   the static and the final skin, chunk files) in frames per second, and the whole bake with its caches
   (bake.npz and bake.usdc with skins, normals and muscle meshes). The issue's target: >= 200 frames/s.
2. A 30k-vertex generated body on the demo's jumping jacks at 30 fps (91 frames). Target: >= 60 frames/s.
3. The same meshes through an LBS-only pipeline (drive, LBS, chunk files; caches: npz and a USD with the one
   skin), the same chunking: the ratio full / LBS-only per frame, loop and with caches. Target: <= 3x.

Setup (reading, retargeting, generating the body, fitting, binding) is timed apart and left out of the
frame rates, as is the first compile of the Warp kernels (one untimed warm-up bake). Frame rates are the
best of several bakes; both cores are free to the process (Warp launches run on one, NumPy's BLAS on one).
"""
from __future__ import annotations

import argparse
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


def lbs_only(setup, out_dir: str) -> tuple[float, float]:
    """(frame loop s, caches s) of the LBS-only pipeline: drive, LBS, chunk files, then npz + one-mesh USD."""
    from pxr import Usd, UsdGeom

    from sim.bake.caches import _define_mesh
    skin, times, C = setup.skin, setup.times, setup.chunk
    t0 = time.perf_counter()
    parts = []
    for a in range(0, len(times), C):
        ts = times[a:a + C]
        world = np.asarray(setup.world_at(ts), dtype=np.float64)
        pts = (skin.lbs_batch(world) if hasattr(skin, "lbs_batch")
               else np.stack([skin.lbs(w) for w in world]))
        path = os.path.join(out_dir, f"lbs_{a:06d}.npz")
        np.savez(path, skin=pts, joint_world=world.astype(np.float32))
        parts.append(path)
    loop = time.perf_counter() - t0
    t0 = time.perf_counter()
    skin_all = np.concatenate([np.load(p)["skin"] for p in parts])
    np.savez(os.path.join(out_dir, "lbs.npz"), skin=skin_all, faces=setup.character.faces, times=times)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(setup.fps)
    _define_mesh(stage, "/lbs/skin", skin_all, setup.character.faces)
    stage.GetRootLayer().Export(os.path.join(out_dir, "lbs.usdc"))
    return loop, time.perf_counter() - t0


def measure(label: str, request, repeats: int, target: float) -> dict:
    from sim.bake.baker import bake
    from sim.bake.setup import prepare
    t0 = time.perf_counter()
    setup = prepare(request)
    prep = time.perf_counter() - t0
    T = len(setup.times)
    with tempfile.TemporaryDirectory() as tmp:
        bake(setup, os.path.join(tmp, "warm"))                                  # compiles, imports pxr

        def full():
            s = bake(setup, os.path.join(tmp, "full"))["timings"]
            return s["frames_s"], s["caches_s"], s
        loop, caches, tm = min((full() for _ in range(repeats)), key=lambda r: r[0])
        lbs_runs = [lbs_only(setup, tmp) for _ in range(repeats)]
        l_loop = min(r[0] for r in lbs_runs)
        l_caches = min(r[1] for r in lbs_runs)
    per = {k: 1e3 * tm[k] / T for k in ("drive_s", "static_s", "simulate_s", "skin_s", "write_s")}
    print(f"\n## {label}: {T} frames, {setup.character.num_vertices} vertices, {setup.rig.M} muscles")
    print(f"setup (read, character, fit, bind): {prep:.2f} s, not in the rates below")
    print(f"frame loop: {T / loop:8.1f} frames/s ({1e3 * loop / T:.2f} ms/frame; target >= {target:g} frames/s: "
          f"{'met' if T / loop >= target else 'NOT met'})")
    print("  per frame: " + ", ".join(f"{k[:-2]} {v:.2f} ms" for k, v in per.items()))
    print(f"with caches (npz + usdc): {T / (loop + caches):8.1f} frames/s ({1e3 * caches / T:.2f} ms/frame of caches)")
    print(f"LBS-only pipeline: loop {1e3 * l_loop / T:.2f} ms/frame, with caches {1e3 * (l_loop + l_caches) / T:.2f} "
          f"ms/frame")
    r_loop, r_all = loop / l_loop, (loop + caches) / (l_loop + l_caches)
    print(f"ratio full / LBS-only per frame: loop {r_loop:.2f}x, with caches {r_all:.2f}x (target <= 3x)")
    return {"fps": T / loop, "fps_caches": T / (loop + caches), "ratio_loop": r_loop, "ratio_all": r_all}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, CesiumMan only")
    args = ap.parse_args()
    from sim.bake.setup import BakeRequest
    repeats = 1 if args.quick else 3
    cesium, clip = ASSETS / "characters" / "CesiumMan.glb", ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh"
    if cesium.exists() and clip.exists():
        measure("CesiumMan on 02_03.bvh at 30 fps", BakeRequest(clip=str(clip), character=str(cesium), fps=30,
                                                               formats=("npz", "usdc")), repeats, 200)
    else:
        print(f"CesiumMan or 02_03.bvh not found under {ASSETS}: skipped")
    if not args.quick:
        from types import MappingProxyType
        measure("30k-vertex generated body, jumping jacks at 30 fps",
                BakeRequest(scene=str(ROOT / "scenes" / "default.toml"), fps=30, formats=("npz", "usdc"),
                            body=MappingProxyType({"resolution": 30000})), repeats, 60)


if __name__ == "__main__":
    main()
