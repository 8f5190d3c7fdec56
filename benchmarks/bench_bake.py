"""The bake's cost against plain skinning, measured in one run: ratios per frame, launches, Python, memory.

    .venv/bin/python benchmarks/bench_bake.py [--quick] [--memory-frames 10000] [--no-memory]

For each mesh (CesiumMan, 3,273 vertices, ../shared/assets, the default template on 02_03.bvh retargeted;
a 29.9k-vertex generated body on the demo's jumping jacks), both at 30 fps in chunks of 64 frames:

1. Frame loop: the bake's compute for every chunk (sim.bake.baker.Baker.chunk and its finish: drive,
   static muscles, particles, blend, LBS + shells of the static and the final skin, the smooth skin,
   the spread), no files, on one thread and as the bake runs it (each chunk's spread in a second
   thread while the next chunk is computed); against an LBS-only loop (drive + LBS of the same frames,
   one launch per chunk). Targets: CesiumMan <= 3x, 30k body <= 2x.
2. With caches: a whole `jiggle bake` (sim.bake.baker.bake: the loop above, with each chunk written into
   bake.npz, bake.usdc (both skins and the muscle meshes, with normals) and bake.pc2 by a second thread
   while the next chunk is computed), wall time; against the LBS-only loop writing its skin and joints
   to an npz filled in place, its skin (with normals) to a USD crate saved per chunk and to a pc2, the
   same writers, serially. Targets: CesiumMan <= 2x, 30k body <= 1.5x.
3. Launches per chunk (every Warp launch the bake makes, counted by wrapping wp.launch and
   wp.Launch.launch), and the share of the main thread's time spent in Python code itself (cProfile's
   own time of Python functions over the total, one extra profiled bake; cProfile's overhead makes it
   an upper bound).
4. Activation: a whole bake of CesiumMan on 02_03 and 02_04 (setup and caches) with --activation on against off,
   alternating, and their frame loops. Target: at most 1.15x.
5. Memory: a bake of --memory-frames frames of the 30k body (the jumping jacks looped) against one of
   100 frames, each in a fresh process, peak RSS (resource.getrusage) and frames per second. Target:
   peak RSS within 1.5x and time per frame within 10%.

Setup (reading, retargeting, generating the body, fitting, binding) is timed apart and left out; the
first compile of the Warp kernels too (an untimed warm-up bake). Figures are the best of several runs.
"""
from __future__ import annotations

import argparse
import contextlib
import cProfile
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))


# ---------------------------------------------------------------------------------- LBS only
def lbs_loop(setup) -> None:
    """Drive + LBS of every chunk, no files."""
    skin, times, C = setup.skin, setup.times, setup.chunk
    for a in range(0, len(times), C):
        world = np.asarray(setup.world_at(times[a:a + C]), dtype=np.float64)
        skin.lbs_batch(world)


def lbs_with_caches(setup, out_dir: str) -> None:
    """Drive + LBS of every chunk, each chunk written as it comes into an npz filled in place (skin and
    joint transforms), a USD crate of the one skin with normals and extent, saved per chunk, and a pc2."""
    from pxr import Sdf, Usd, UsdGeom

    from jiggle.rig.character.normals import VertexNormals
    from jiggle.sim.bake.caches import (
        PC2_HEADER_BYTES,
        NpzInPlace,
        _author_samples,
        _define_mesh_prim,
        _save_layer,
        pc2_header,
    )
    skin, times, C, T = setup.skin, setup.times, setup.chunk, len(setup.times)
    V, faces = setup.character.num_vertices, setup.character.faces
    J = np.asarray(setup.world_at(times[:1])).shape[1]          # the character's joints
    npz = NpzInPlace(os.path.join(out_dir, "lbs.npz"), {"skin": ((T, V, 3), np.float32),
                                                         "joint_world": ((T, J, 4, 4), np.float32),
                                                         "faces": faces, "times": times})
    layer = Sdf.Layer.CreateNew(os.path.join(out_dir, "lbs.usdc"))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(setup.fps)
    _define_mesh_prim(stage, "/lbs/skin", faces)
    del stage
    normals = VertexNormals(faces, V)
    pc2 = open(os.path.join(out_dir, "lbs.pc2"), "wb")
    pc2.write(pc2_header(V, T, setup.fps, float(times[0])))
    for a in range(0, T, C):
        world = np.asarray(setup.world_at(times[a:a + C]), dtype=np.float64)
        pts = skin.lbs_batch(world)
        npz.write("skin", a, pts)
        npz.write("joint_world", a, world.astype(np.float32))
        with Sdf.ChangeBlock():
            _author_samples(layer, "/lbs/skin", pts, normals.batch(pts), a)
        _save_layer(layer)
        pc2.seek(PC2_HEADER_BYTES + a * V * 12)
        pc2.write(memoryview(np.ascontiguousarray(pts, "<f4")).cast("B"))
    pc2.close()
    npz.finish()


# ---------------------------------------------------------------------------------- ours
def bake_loop(baker) -> dict:
    """The bake's compute of every chunk (Baker.chunk + finish), one thread, no files; its stage timings.
    The Baker (the particle model and solver, built once per bake) is setup, built by the caller."""
    from jiggle.sim.bake.baker import num_chunks
    baker.timings = dict.fromkeys(baker.timings, 0.0)
    state = None
    for c in range(num_chunks(baker.setup)):
        arrays = baker.chunk(c, state)
        state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None
    return baker.timings


def bake_loop_threads(baker) -> None:
    """The bake's compute as `bake` runs it, with no files: each chunk's skins finished (the spread) in a
    worker thread while the next chunk is driven, shaped, simulated and skinned here. `baker` was built
    with defer=True."""
    from concurrent.futures import ThreadPoolExecutor

    from jiggle.sim.bake.baker import num_chunks
    state, pending = None, None
    with ThreadPoolExecutor(max_workers=1) as worker:
        for c in range(num_chunks(baker.setup)):
            arrays = baker.chunk(c, state)
            state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None
            if pending is not None:
                pending.result()
            pending = worker.submit(arrays.pop("finish"))
        if pending is not None:
            pending.result()


@contextlib.contextmanager
def counted_launches():
    """Count every Warp launch (direct and recorded) inside the block: yields a one-item list."""
    import warp as wp
    count = [0]
    launch, recorded = wp.launch, wp.Launch.launch

    def counting(*a, **k):
        if not k.get("record_cmd"):
            count[0] += 1
        return launch(*a, **k)

    def counting_recorded(self, *a, **k):
        count[0] += 1
        return recorded(self, *a, **k)
    wp.launch, wp.Launch.launch = counting, counting_recorded
    try:
        yield count
    finally:
        wp.launch, wp.Launch.launch = launch, recorded


def python_share(fn) -> float:
    """Share of the main thread's time in Python functions' own code while fn() runs (cProfile)."""
    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = sum(v[2] for v in stats.values())
    own = sum(v[2] for (filename, _, _), v in stats.items() if filename != "~" and not filename.startswith("<"))
    return own / total if total > 0 else float("nan")


def best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def measure(label: str, request, repeats: int, targets: tuple[float, float]) -> dict:
    from jiggle.sim.bake.baker import Baker, bake, num_chunks
    from jiggle.sim.bake.setup import prepare
    t0 = time.perf_counter()
    setup = prepare(request)
    prep = time.perf_counter() - t0
    T, n = len(setup.times), num_chunks(setup)
    with tempfile.TemporaryDirectory() as tmp:
        bake(setup, os.path.join(tmp, "warm"))                                  # compiles, imports pxr
        lbs_with_caches(setup, tmp)
        baker = Baker(setup, defer=False)
        loop = best(lambda: bake_loop(baker), repeats)
        threaded = Baker(setup, defer=True)
        loop2 = best(lambda: bake_loop_threads(threaded), repeats)
        l_loop = best(lambda: lbs_loop(setup), repeats)
        whole = best(lambda: bake(setup, os.path.join(tmp, "full")), repeats)
        l_whole = best(lambda: lbs_with_caches(setup, tmp), repeats)
        timings = bake_loop(baker)
        with counted_launches() as count:
            bake(setup, os.path.join(tmp, "count"))
        share = python_share(lambda: bake(setup, os.path.join(tmp, "profiled")))
    per = {k: 1e3 * v / T for k, v in timings.items() if k != "write_s"}
    r_loop, r_loop2, r_all = loop / l_loop, loop2 / l_loop, whole / l_whole
    print(f"\n## {label}: {T} frames in {n} chunks, {setup.character.num_vertices} vertices, {setup.rig.M} muscles")
    print(f"setup (read, character, fit, bind): {prep:.2f} s, not in the figures below")
    print(f"frame loop: {1e3 * loop / T:.2f} ms/frame ({T / loop:.0f} frames/s); LBS-only loop {1e3 * l_loop / T:.3f} "
          f"ms/frame: ratio {r_loop:.2f}x (target <= {targets[0]:g}x: {'met' if r_loop <= targets[0] else 'NOT met'})")
    print("  per frame: " + ", ".join(f"{k[:-2]} {v:.3f} ms" for k, v in per.items()))
    print(f"frame loop as the bake runs it (the spread in a second thread), no files: {1e3 * loop2 / T:.2f} ms/frame: "
          f"ratio {r_loop2:.2f}x (target <= {targets[0]:g}x: {'met' if r_loop2 <= targets[0] else 'NOT met'})")
    print(f"with caches (npz + usdc + pc2, written while the next chunk is computed): {1e3 * whole / T:.2f} ms/frame "
          f"({T / whole:.0f} frames/s); LBS-only with its caches {1e3 * l_whole / T:.2f} ms/frame: ratio {r_all:.2f}x "
          f"(target <= {targets[1]:g}x: {'met' if r_all <= targets[1] else 'NOT met'})")
    print(f"Warp launches: {count[0] / n:.1f} per chunk ({count[0]} in the bake); time in Python code itself "
          f"(main thread, cProfile): {100 * share:.0f}%")
    return {"loop_ratio": r_loop, "loop_ratio_threads": r_loop2, "all_ratio": r_all, "launches_per_chunk": count[0] / n, "python_share": share}


# ---------------------------------------------------------------------------------- memory
def memory_child(frames: int, out_dir: str) -> None:
    """In a fresh process: bake `frames` frames of the 30k body (jumping jacks looped), print JSON."""
    import resource
    from types import MappingProxyType

    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import BakeRequest, prepare
    cycles = int(np.ceil(frames / 30.0)) + 1             # one jumping-jacks cycle lasts 1 s
    src = (ROOT / "scenes" / "motions" / "jumping_jacks.toml").read_text()
    motion = Path(out_dir) / "jumping_jacks_long.toml"
    motion.write_text(src.replace("cycles = 3", f"cycles = {cycles}"))
    scene = Path(out_dir) / "long.toml"
    scene.write_text((ROOT / "scenes" / "default.toml").read_text().replace(
        'file = "motions/jumping_jacks.toml"', f'file = "{motion}"'))
    setup = prepare(BakeRequest(scene=str(scene), fps=30, frames=frames, formats=("npz", "usdc", "pc2"),
                                body=MappingProxyType({"resolution": 30000})))
    rss_setup = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    summary = bake(setup, os.path.join(out_dir, "bake"))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    sizes = {f: os.path.getsize(os.path.join(out_dir, "bake", p)) for f, p in summary["files"].items()}
    print(json.dumps({"frames": summary["frames"], "rss_mb": rss, "rss_setup_mb": rss_setup,
                      "loop_s": summary["timings"]["frames_s"], "caches_s": summary["timings"]["caches_s"],
                      "bytes": sizes}))


def memory(frames: int) -> None:
    runs = {}
    for n in (100, frames):
        with tempfile.TemporaryDirectory(dir=os.environ.get("JIGGLE_BENCH_TMP")) as tmp:
            out = subprocess.run([sys.executable, __file__, "--memory-child", str(n), tmp], capture_output=True,
                                 text=True, check=True)
            runs[n] = json.loads(out.stdout.strip().splitlines()[-1])
    a, b = runs[100], runs[frames]
    print(f"\n## Memory: the 30k body, {a['frames']} against {b['frames']} frames (npz + usdc + pc2), fresh processes")
    print("| frames | peak RSS MB | of which setup | s per frame (loop + caches) | caches GB |")
    print("| --- | --- | --- | --- | --- |")
    for r in (a, b):
        per = (r["loop_s"] + r["caches_s"]) / r["frames"]
        print(f"| {r['frames']} | {r['rss_mb']:.0f} | {r['rss_setup_mb']:.0f} | {1e3 * per:.2f} ms | "
              f"{sum(r['bytes'].values()) / 1e9:.2f} |")
    ratio = b["rss_mb"] / a["rss_mb"]
    pa, pb = ((r["loop_s"] + r["caches_s"]) / r["frames"] for r in (a, b))
    print(f"peak RSS {ratio:.2f}x (target <= 1.5x: {'met' if ratio <= 1.5 else 'NOT met'}); time per frame "
          f"{pb / pa:.2f}x (target within 10%: {'met' if abs(pb / pa - 1) <= 0.1 else 'NOT met'})")


def activation(repeats: int) -> dict | None:
    """A whole bake (setup and caches: `jiggle bake` as a user runs it) of CesiumMan on the shared run (02_03) and
    jump (02_04) with --activation on against off, the two alternating, best of `repeats`; and the frame loop of
    each (the keyed springs' cost)."""
    from jiggle.sim.bake.baker import Baker, bake
    from jiggle.sim.bake.setup import BakeRequest, prepare
    cesium = ASSETS / "characters" / "CesiumMan.glb"
    out = {}
    for name in ("02_03", "02_04"):
        clip = ASSETS / "mocap" / "cmu_bvh" / f"{name}.bvh"
        if not (cesium.exists() and clip.exists()):
            print(f"CesiumMan or {clip.name} not found under {ASSETS}: skipped")
            continue
        req = {a: BakeRequest(clip=str(clip), character=str(cesium), fps=30, formats=("npz", "usdc", "pc2"),
                              activation=a) for a in ("off", "on")}
        with tempfile.TemporaryDirectory() as tmp:
            for a in req:                                                         # compiles, imports
                bake(prepare(req[a]), os.path.join(tmp, f"warm_{a}"))
            wall = {a: [] for a in req}
            for _ in range(repeats):
                for a in req:
                    t = time.perf_counter()
                    bake(prepare(req[a]), os.path.join(tmp, a))
                    wall[a].append(time.perf_counter() - t)
            loops = {}
            for a in req:
                baker = Baker(prepare(req[a]), defer=False)
                loops[a] = best(lambda: bake_loop(baker), repeats)
        w = {a: min(v) for a, v in wall.items()}
        out[name] = {"wall_off_s": w["off"], "wall_on_s": w["on"], "wall_ratio": w["on"] / w["off"],
                     "loop_ratio": loops["on"] / loops["off"]}
        print(f"\n## --activation on against off, CesiumMan on {name}.bvh at 30 fps: a whole bake {w['on']:.2f} s "
              f"against {w['off']:.2f} s: {w['on'] / w['off']:.2f}x (target <= 1.15x: "
              f"{'met' if w['on'] <= 1.15 * w['off'] else 'NOT met'}); the frame loop "
              f"{loops['on'] / loops['off']:.2f}x")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, CesiumMan only, no memory run")
    ap.add_argument("--memory-frames", type=int, default=10000, help="frames of the long bake (default 10000)")
    ap.add_argument("--no-memory", action="store_true", help="skip the memory run")
    ap.add_argument("--memory-child", nargs=2, metavar=("FRAMES", "DIR"), help=argparse.SUPPRESS)
    ap.add_argument("--activation", action="store_true", help="only --activation on against off")
    args = ap.parse_args()
    if args.memory_child:
        memory_child(int(args.memory_child[0]), args.memory_child[1])
        return
    if args.activation:
        activation(1 if args.quick else 3)
        return
    from types import MappingProxyType

    from jiggle.sim.bake.setup import BakeRequest
    repeats = 1 if args.quick else 3
    formats = ("npz", "usdc", "pc2")
    cesium, clip = ASSETS / "characters" / "CesiumMan.glb", ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh"
    if cesium.exists() and clip.exists():
        measure("CesiumMan on 02_03.bvh at 30 fps", BakeRequest(clip=str(clip), character=str(cesium), fps=30,
                                                               formats=formats), repeats, (3.0, 2.0))
    else:
        print(f"CesiumMan or 02_03.bvh not found under {ASSETS}: skipped")
    if args.quick:
        return
    activation(repeats)
    measure("30k-vertex generated body, jumping jacks at 30 fps",
            BakeRequest(scene=str(ROOT / "scenes" / "default.toml"), fps=30, formats=formats,
                        body=MappingProxyType({"resolution": 30000})), repeats, (2.0, 1.5))
    if not args.no_memory:
        memory(args.memory_frames)


if __name__ == "__main__":
    main()
