"""Batched skinning for the bake (MuscleSkin.pose_batch / lbs_batch) against the frame-by-frame calls,
and the full skin's cost against LBS alone, measured in one run.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_batch_skin.py [--quick] [--device cpu]

The bake skins every frame twice: the static skin (LBS + shell deformers from the static CVs) and the
final skin (the same LBS + shells from the jiggled and blended CVs), a chunk of frames at a time. Per
mesh, over the same N frames (the clip looped; per-frame figures are the chunk's time / its frames):

- lbs loop: MuscleSkin.lbs per frame; lbs_batch at chunk sizes 16 / 64 / 128.
- pose loop: MuscleSkin.pose per frame, S = 1 (static CVs) and S = 2 (static, then blended CVs).
- pose_batch S = 2 (static and blended CVs over one action curve, as the bake passes them) at chunk
  sizes 16 / 64 / 128.

Ratios: pose_batch S = 2 per frame / lbs_batch per frame at the same chunk size (the skinning part of
the full pipeline against the LBS-only one), and the speedups loop / batch; the bake's call (both sets
and the smooth skin, smooth=True) at chunk 64, also exactly as the bake makes it (defer=True,
reuse=True: the skin's kept buffers), and the Warp launches a chunk makes (MuscleSkin.launches).
The largest difference between batch and loop is printed too (the contract: <= 1e-6 m).

Meshes: CesiumMan (../shared/assets/characters/CesiumMan.glb, its own walk; skipped with a message
when absent) and a ~30k-vertex body generated around the default scene's skeleton (scenes/default.toml;
--quick: ~10k), both fitted with the default template (rig.muscle.fit.fit_musculature, "human").
The static CVs come from MuscleRig.static (not timed); the "blended" set is them plus 2 mm of fixed
noise per CV (a jiggle's size; the cost does not depend on the values). One core: OPENBLAS_NUM_THREADS=1
is set before NumPy loads; Warp's CPU kernels run on one thread. Times are the best of several
repeats after a warm-up (kernel compiles excluded); the machine may be shared, so repeat the run.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.motion.clip import transforms  # noqa: E402
from jiggle.rig.muscle.fit import FitOptions, fit_musculature  # noqa: E402
from jiggle.rig.skin.muscle_skin import MuscleSkin  # noqa: E402

CESIUM = ROOT.parent / "shared" / "assets" / "characters" / "CesiumMan.glb"
SCENE = ROOT / "scenes" / "default.toml"
CHUNKS = (16, 64, 128)
NOISE = 0.002            # metres: the blended CVs' offset from the static ones


def looped(world: np.ndarray, n: int) -> np.ndarray:
    """(n, J, 4, 4): the clip's frames repeated until there are n."""
    return world[np.arange(n) % len(world)]


def chunked(fn, n: int, size: int):
    """Call fn(start, stop) over [0, n) in chunks of `size` frames."""
    for a in range(0, n, size):
        fn(a, min(a + size, n))


def bench_mesh(label: str, skin: MuscleSkin, world: np.ndarray, frames: int, repeats: int,
               device: str) -> None:
    world = looped(world, frames)
    static = skin.rig.static(world)
    cvs, curve = static.cvs, static.curve
    blended = cvs + np.random.default_rng(0).normal(0.0, NOISE, cvs.shape)
    V, M, P = skin.character.num_vertices, skin.rig.M, skin.num_pairs
    print(f"\n{label}: {V} vertices, {skin.character.num_joints} joints, {M} muscles, {P} (vertex, muscle) "
          f"pairs, {frames} frames; device {device}")

    def per_frame(fn, reps=repeats):
        t, _ = best(fn, repeats=reps, warmup=True)
        return t / frames * 1e3

    def lbs_loop():
        for t in range(frames):
            skin.lbs(world[t])

    def pose_loop(sets):
        def run():
            for t in range(frames):
                for c in sets:
                    skin.pose(world[t], c[t], curve[t], frame=t)
        return run

    def lbs_batch(size):
        return lambda: chunked(lambda a, b: skin.lbs_batch(world[a:b]), frames, size)

    def pose_batch(size):
        return lambda: chunked(lambda a, b: skin.pose_batch(world[a:b], [cvs[a:b], blended[a:b]],
                                                            [curve[a:b], curve[a:b]], first_frame=a),
                               frames, size)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # a skipped muscle would warn each call
        ms = {"lbs loop": per_frame(lbs_loop), "pose loop S=1": per_frame(pose_loop([cvs])),
              "pose loop S=2": per_frame(pose_loop([cvs, blended]))}
        for size in CHUNKS:
            ms[f"lbs_batch {size}"] = per_frame(lbs_batch(size))
            ms[f"pose_batch S=2 {size}"] = per_frame(pose_batch(size))
        # batch against loop, one chunk of the largest size
        n = min(CHUNKS[-1], frames)
        out = skin.pose_batch(world[:n], [cvs[:n], blended[:n]], [curve[:n], curve[:n]])
        err = max(float(np.abs(out[s][t] - skin.pose(world[t], c[t], curve[t], frame=t)).max())
                  for s, c in enumerate((cvs, blended)) for t in range(n))
        err_lbs = float(np.abs(skin.lbs_batch(world[:n]) - np.stack([skin.lbs(w) for w in world[:n]])).max())
        # the bake's call: both sets and the smooth skin (skin_lbs) from one pose_batch; its launches
        launches = {}
        for size in CHUNKS:
            before = skin.launches
            skin.pose_batch(world[:size], [cvs[:size], blended[:size]], [curve[:size], curve[:size]], smooth=True)
            launches[size] = skin.launches - before
        ms["pose_batch S=2 + smooth 64"] = per_frame(lambda: chunked(
            lambda a, b: skin.pose_batch(world[a:b], [cvs[a:b], blended[a:b]], [curve[a:b], curve[a:b]],
                                         first_frame=a, smooth=True), frames, 64))
        # exactly as sim/bake/baker.py calls it: deferred, into the skin's two generations of kept buffers
        ms["bake call 64"] = per_frame(lambda: chunked(
            lambda a, b: skin.pose_batch(world[a:b], [cvs[a:b], blended[a:b]], [curve[a:b], curve[a:b]],
                                         first_frame=a, smooth=True, defer=True, reuse=True)(), frames, 64))

    print(f"  {'lbs loop':28s} {ms['lbs loop']:8.3f} ms/frame")
    print(f"  {'pose loop, S=1':28s} {ms['pose loop S=1']:8.3f} ms/frame")
    print(f"  {'pose loop, S=2':28s} {ms['pose loop S=2']:8.3f} ms/frame")
    for size in CHUNKS:
        lb, pb = ms[f"lbs_batch {size}"], ms[f"pose_batch S=2 {size}"]
        print(f"  chunk {size:3d}: lbs_batch {lb:7.3f} ms/frame ({ms['lbs loop'] / lb:5.1f}x the loop), "
              f"pose_batch S=2 {pb:7.3f} ms/frame ({ms['pose loop S=2'] / pb:5.1f}x the loop) "
              f"= {pb / lb:5.2f} x lbs_batch  ({1e3 / pb:6.0f} frames/s)")
    print(f"  pose_batch S=2 + smooth skin, chunk 64: {ms['pose_batch S=2 + smooth 64']:7.3f} ms/frame "
          f"= {ms['pose_batch S=2 + smooth 64'] / ms['lbs_batch 64']:5.2f} x lbs_batch (the bake's skin stage)")
    print(f"  the same as the bake calls it (defer, reuse: kept buffers), chunk 64: {ms['bake call 64']:7.3f} ms/frame")
    print("  Warp launches per chunk (pose_batch S=2 + smooth): "
          + ", ".join(f"{size} frames: {launches[size]}" for size in CHUNKS))
    print(f"  batch vs loop, max |difference|: pose {err:.2e} m, lbs {err_lbs:.2e} m (contract <= 1e-6)")


def cesium(device: str):
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.mocap import load_clip
    ch = load_character(CESIUM)
    clip = load_clip(CESIUM)
    order = ch.joint_order(clip.joint_names)
    rot, pos = clip.world()
    world = transforms(rot[:, order], pos[:, order])
    return MuscleSkin.from_musculature(fit_musculature(ch, "human", FitOptions()), device=device), world


def body(resolution: int, device: str):
    from jiggle.rig.character.body import BodyOptions
    from jiggle.rig.character.load import body_character
    from jiggle.sim.bake.scene import load_scene
    clip = load_scene(SCENE).clip
    ch = body_character(clip, BodyOptions(resolution=resolution))
    world = transforms(*clip.world())          # the body's joints are the clip's, in its order
    return MuscleSkin.from_musculature(fit_musculature(ch, "human", FitOptions()), device=device), world


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames and repeats, a ~10k-vertex body")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    wp.init()
    t_run = time.perf_counter()
    frames, repeats = (128, 3) if args.quick else (256, 5)
    blas = os.environ.get("OPENBLAS_NUM_THREADS") or "default"
    print(f"{os.cpu_count()} CPUs; BLAS threads: {blas}")
    if CESIUM.exists():
        t = time.perf_counter()
        skin, world = cesium(args.device)
        print(f"(CesiumMan fitted in {time.perf_counter() - t:.1f} s, not timed below)")
        bench_mesh("CesiumMan", skin, world, frames, repeats, args.device)
    else:
        print(f"skipped CesiumMan: {CESIUM} not found (../shared/assets is absent)")
    resolution = 10000 if args.quick else 30000
    t = time.perf_counter()
    skin, world = body(resolution, args.device)
    print(f"\n(body generated and fitted in {time.perf_counter() - t:.1f} s, not timed below)")
    bench_mesh(f"generated body, resolution {resolution}", skin, world, frames, repeats, args.device)
    print(f"\n(benchmark ran {time.perf_counter() - t_run:.1f} s)")


if __name__ == "__main__":
    main()
