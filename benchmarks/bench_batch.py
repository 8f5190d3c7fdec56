"""`jiggle batch` on a LocalCluster of 2 single-threaded worker processes against the same clips baked one
after another in one process, measured in one run:

- the speed-up over the naive loop, each clip prepared from scratch (prepare + bake per clip, as
  running `jiggle bake` once per clip does), and over a serial loop that fits the character once (the
  rig cache of one process): the second is the cluster's own share (the issue's goal: >= 1.7x on 2 cores);
- the per-clip set-up saved by the per-worker rig cache: a job's set-up (prepare) when its worker had
  fitted the character already, against one that fitted it.

    .venv/bin/python benchmarks/bench_batch.py [--frames N] [--workers N] [--formats npz,usdc] [--report ...]

The 6 clips are the 5 CMU BVH clips and the CMU AMC of ../shared/assets, each retargeted onto CesiumMan,
the first --frames output frames (default 900: 30 s; 02_03 and 09_11 are shorter and are baked whole) at
30 fps, into the default caches (npz, usdc); no report (compare) by default. The serial bake is not
one-threaded: it skins and writes chunk c in a second thread while chunk c + 1 is simulated. The cluster's
start-up is counted in the batch's time. The assets' absence ends the benchmark with a message.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CLIPS = ("cmu_bvh/01_01.bvh", "cmu_bvh/02_03.bvh", "cmu_bvh/02_04.bvh", "cmu_bvh/05_02.bvh", "cmu_bvh/09_11.bvh",
         "cmu_amc/01_01.amc")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=900, help="output frames of each clip, at most (default 900)")
    ap.add_argument("--formats", default="npz,usdc", help="cache formats (default npz,usdc)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--report", choices=["none", "numbers", "render"], default="none")
    args = ap.parse_args()
    character = ASSETS / "characters" / "CesiumMan.glb"
    clips = [ASSETS / "mocap" / c for c in CLIPS]
    missing = [str(p) for p in (character, *clips) if not p.exists()]
    if missing:
        print(f"bench_batch: skipped, shared assets missing: {', '.join(missing)}")
        return 0
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    from jiggle.sim.app.batch import Job, dask_client, run_batch, run_job
    from jiggle.sim.bake.setup import BakeRequest
    jobs = [Job(p.stem + ("_amc" if p.suffix == ".amc" else ""),
                BakeRequest(clip=str(p), character=str(character), frames=args.frames,
                            formats=tuple(args.formats.split(","))), str(p))
            for p in clips]

    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        # serial: one process, one clip after another; the first job once untimed before, so Warp's
        # kernel loading stays out of every side alike
        import jiggle.sim.app.batch as batch
        run_job(jobs[0], os.path.join(tmp, "warm"), "none")
        serial = []
        t = time.perf_counter()
        for j in jobs:                      # naive: each clip prepared from scratch
            batch.RIGS.clear()
            serial.append(run_job(j, os.path.join(tmp, "serial"), args.report))
        serial_s = time.perf_counter() - t
        batch.RIGS.clear()                  # the character fitted once, for the first clip
        t = time.perf_counter()
        cached = [run_job(j, os.path.join(tmp, "cached"), args.report) for j in jobs]
        cached_s = time.perf_counter() - t

        t = time.perf_counter()
        with dask_client(None, args.workers) as client:
            start_s = time.perf_counter() - t
            records = run_batch(jobs, os.path.join(tmp, "batch"), client, report=args.report)
        batch_s = time.perf_counter() - t

    bad = [r for r in (*serial, *cached, *records) if r["status"] != "ok"]
    if bad:
        print("bench_batch: jobs failed:", *(f"{r['name']}: {r['error']}" for r in bad), sep="\n  ")
        return 1
    frames = sum(r["frames"] for r in records)
    print(f"{len(jobs)} clips on CesiumMan, at most {args.frames} frames each at 30 fps: {frames} frames; "
          f"report: {args.report}")
    print(f"  serial, one process, fit per clip : {serial_s:7.2f} s  ({frames / serial_s:6.1f} frames/s)")
    print(f"  serial, one process, fit once     : {cached_s:7.2f} s  ({frames / cached_s:6.1f} frames/s)")
    print(f"  batch, LocalCluster({args.workers})          : {batch_s:7.2f} s  ({frames / batch_s:6.1f} frames/s; "
          f"cluster start {start_s:.2f} s; a fit per worker)")
    print(f"  speed-up batch / serial fit per clip : {serial_s / batch_s:.2f}x")
    print(f"  speed-up batch / serial fit once     : {cached_s / batch_s:.2f}x  (goal >= 1.7x on 2 cores; "
          f"{os.cpu_count()} cores here; 1-min load average {load:.1f} before, {os.getloadavg()[0]:.1f} after: "
          "other processes on the machine take their share of the cores)")
    hit = [r["setup_s"] for r in records if r.get("rig_reused")]
    miss = [r["setup_s"] for r in records if not r.get("rig_reused")]
    per = sum(r["setup_s"] for r in serial) / len(serial)
    print(f"  set-up per clip: serial {per:.2f} s; batch {sum(miss) / max(len(miss), 1):.2f} s when the worker "
          f"fitted CesiumMan ({len(miss)} jobs), {sum(hit) / max(len(hit), 1):.2f} s when it had it cached "
          f"({len(hit)} jobs): {per - sum(hit) / max(len(hit), 1):.2f} s saved per cached clip")
    print(f"  bake per clip (mean): serial {sum(r['bake_s'] for r in serial) / len(serial):.2f} s, "
          f"batch {sum(r['bake_s'] for r in records) / len(records):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
