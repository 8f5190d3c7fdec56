"""Skin segmentation (rig.muscle.segmentation) of a generated body (~20k vertices, 25 bone segments): the
vectorised assignment (all vertices x all segments in blocks of matrix products) against a
straightforward per-vertex Python loop (NumPy over the segments of one vertex at a time), run on a
subset and scaled per vertex; all measured in this one run.

    .venv/bin/python benchmarks/bench_segmentation.py [subset]

Also the stages of `segment_skin` (bone segments, normal smoothing, assignment). Times are the best
of several repeats after one warm-up call.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.character.load import body_character  # noqa: E402
from jiggle.rig.motion.mocap import load_clip  # noqa: E402
from jiggle.rig.muscle.segmentation import TIE_FRACTION, assign, bone_segments, segment_skin, smoothed_normals  # noqa: E402


def assign_loop(points, normals, start, end, tol):
    """Reference: per vertex, the closest segment whose normal test passes, else the nearest; ties
    within tol to a bone starting at the shared joint, then the one the vertex lies least behind."""
    region = np.empty(len(points), np.int32)
    accepted = np.empty(len(points), bool)
    ab = end - start
    ll = np.einsum("sk,sk->s", ab, ab)
    for i, (p, n) in enumerate(zip(points, normals)):
        raw = np.einsum("sk,sk->s", p - start, ab) / ll
        t = np.clip(raw, 0.0, 1.0)
        foot = start + t[:, None] * ab
        dist = np.linalg.norm(p - foot, axis=1)
        ok = (p - foot) @ n >= 0.0
        accepted[i] = ok.any()
        d = np.where(ok, dist, np.inf) if accepted[i] else dist
        best = None
        for s in np.flatnonzero(d <= d.min() + tol):
            key = (t[s], max(-raw[s], 0.0) * np.sqrt(ll[s]))
            if best is None or key < best[0]:
                best = (key, s)
        region[i] = best[1]
    return region, accepted


def main(subset: int = 2000) -> None:
    t0 = time.perf_counter()
    c = body_character(load_clip(str(ROOT / "scenes/motions/jumping_jacks.toml")))
    t_build = time.perf_counter() - t0
    V = c.num_vertices

    t_segs, segs = best(lambda: bone_segments(c), repeats=3, warmup=True)
    t_smooth, low = best(lambda: smoothed_normals(c.vertices, c.faces, c.normals), repeats=3, warmup=True)
    t_assign, (region, accepted) = best(lambda: assign(c.vertices, low, segs), repeats=5, warmup=True)
    t_total, _ = best(lambda: segment_skin(c), repeats=3, warmup=True)

    tol = TIE_FRACTION * np.ptp(np.r_[segs.start, segs.end], axis=0).max()
    idx = np.random.default_rng(0).choice(V, size=min(subset, V), replace=False)
    t_loop, (ref_region, ref_accepted) = best(
        lambda: assign_loop(c.vertices[idx], low[idx], segs.start, segs.end, tol), repeats=1)
    t_loop_all = t_loop * V / len(idx)
    agree = np.mean(ref_region == region[idx])

    print(f"generated body: {V} vertices, {len(c.faces)} faces, {len(segs)} bone segments "
          f"(body and weights built in {t_build:.2f} s, not timed below)")
    print(f"{'stage':52s} {'seconds':>9s}")
    print(f"{'bone_segments':52s} {t_segs:9.4f}")
    print(f"{'smoothed_normals (25 passes, lam 1)':52s} {t_smooth:9.4f}")
    print(f"{'assign, vectorised, all vertices':52s} {t_assign:9.4f}")
    print(f"{'segment_skin, total':52s} {t_total:9.4f}")
    print(f"{f'assign, per-vertex loop, {len(idx)} vertices':52s} {t_loop:9.4f}")
    print(f"{'assign, per-vertex loop, scaled to all vertices':52s} {t_loop_all:9.4f}")
    print(f"ratio loop / vectorised (assignment): {t_loop_all / t_assign:7.1f}x")
    print(f"same region on the subset: {agree:.4%}; accepted: {np.mean(ref_accepted == accepted[idx]):.4%}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)
