"""Bake every clip of a folder on one character, spread over the cores with Dask: `jiggle.bake` mapped over the
clips on a local cluster of worker processes, then each bake read back.

    python examples/bake_a_folder_with_dask.py CLIP_FOLDER CHARACTER [OUT_DIR] [--workers N] [--frames N]

OUT_DIR/<clip>/ holds each bake (default OUT_DIR: out/dask). For a library with resumable jobs, a report per clip
and an index page, `jiggle batch CLIP_FOLDER --character CHARACTER --out OUT_DIR` does the same on Dask.
"""
import argparse
from pathlib import Path

from dask.distributed import Client, LocalCluster

import jiggle


def bake_one(clip: Path, character: Path, out: Path, frames: int | None) -> str:
    """One clip's bake, on a worker: its folder (a Bake's arrays stay on the worker; the folder travels)."""
    jiggle.bake(clip, character, out=out / clip.stem, frames=frames, progress=False)
    return str(out / clip.stem)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips", type=Path)
    ap.add_argument("character", type=Path)
    ap.add_argument("out", type=Path, nargs="?", default=Path("out/dask"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--frames", type=int, default=None, help="only the first N frames of each clip")
    a = ap.parse_args()
    clips = sorted(p for p in a.clips.iterdir() if p.suffix.lower() in (".bvh", ".amc", ".fbx"))
    # one thread per worker process: each bake uses its core fully (Warp kernels, NumPy)
    with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        futures = client.map(bake_one, clips, character=a.character.resolve(), out=a.out.resolve(), frames=a.frames)
        for clip, future in zip(clips, futures):
            bake = jiggle.Bake.open(future.result())
            print(f"{clip.name}: {len(bake.times)} frames, largest jiggle "
                  f"{1000 * abs(bake.skin_final - bake.skin_static).max():.1f} mm -> {bake.folder}")
