"""Automatic skin weights by bone heat (rig.character.bone_heat) on a ~30k-vertex body around the 31-joint CMU
skeleton of 01_01.bvh, stage by stage, and the solve against a fresh factorisation per joint
(scipy.sparse.linalg.spsolve once per joint, the straightforward way), all measured in this one run.

    .venv/bin/python benchmarks/bench_auto_weights.py [path/to/clip.bvh] [--vertices 30000]

The body is the one jiggle generates for the skeleton (rig.character.body, `--vertices` as its resolution).
The issue's budget is 10 s in total for this size on 2 cores.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.character.body import BodyOptions, generate_body  # noqa: E402
from jiggle.rig.character.bone_heat import (
    bone_heat_weights,
    bone_segments,
    closest_visible,
    cotangent_laplacian,
    segment_distances,
    solve_heat,
    weld,
)
from jiggle.rig.motion.bvh import read_bvh  # noqa: E402

DEFAULT = ROOT.parent / "shared" / "assets" / "mocap" / "cmu_bvh" / "01_01.bvh"


def body_mesh(clip, vertices: int) -> tuple[np.ndarray, np.ndarray, str]:
    """The body to weight: the generated body (rig.character.body) at about `vertices` vertices."""
    body = generate_body(clip, BodyOptions(resolution=vertices))
    return body.vertices, body.faces, "generated body (rig.character.body)"


def main(path: Path = DEFAULT, vertices: int = 30000) -> None:
    if not path.exists():
        print(f"skipped: {path} not found (../shared/assets is absent)")
        return
    import scipy.sparse as sp
    import trimesh
    from scipy.sparse.linalg import spsolve

    clip = read_bvh(path)
    rest_rot, rest_pos = clip.rest_world()
    end_world = clip.end_world(rest_rot[None], rest_pos[None])[0]
    ends = np.full((clip.num_joints, 3), np.nan)
    ends[clip.end_parents] = end_world
    t = time.perf_counter()
    v, f, what = body_mesh(clip, vertices)
    t_body = time.perf_counter() - t

    # End to end, as a caller runs it.
    t_total, (joints, weights, rep) = best(lambda: bone_heat_weights(v, f, rest_pos, clip.parents,
                                                                      end_positions=ends))
    # The same stages one by one, for the breakdown and the reference solve.
    start, end, owner = bone_segments(rest_pos, clip.parents, ends)
    t_weld, (pts, faces, _) = best(lambda: weld(v, f))
    t_lap, (K, mass) = best(lambda: cotangent_laplacian(pts, faces))
    t_dist, dist = best(lambda: segment_distances(pts, start, end))
    mesh = trimesh.Trimesh(pts, faces, process=False)
    t_vis, (sources, seen, rays) = best(lambda: closest_visible(mesh, pts, start, end, dist))
    d = np.maximum(np.where(sources, dist, np.inf).min(axis=1), 1e-4 * mesh.scale)
    mh = np.maximum(mass, 1e-9 * mass.mean()) / d ** 2
    p = np.zeros((len(pts), clip.num_joints))
    np.add.at(p.T, owner, (sources / sources.sum(axis=1, keepdims=True)).T)
    t_solve, heat = best(lambda: solve_heat(K, mh, p))
    A = (K + sp.diags(mh)).tocsc()
    t_ref, ref = best(lambda: np.stack([spsolve(A, mh * p[:, j]) for j in range(p.shape[1])], axis=1), repeats=1)
    err = np.abs(ref - heat).max()

    print(f"body: {what}: {len(v)} vertices, {len(f)} faces (built in {t_body:.1f} s); "
          f"skeleton: {path.name}, {clip.num_joints} joints, {len(start)} bone segments")
    print(f"report: {rep.welded} welded vertices, {rep.components} component(s), {rep.rays} rays "
          f"(embree: {trimesh.ray.has_embree}), {rep.unseen} vertices see no bone")
    print(f"{'stage':52s} {'seconds':>9s}")
    print(f"{'weld coincident positions':52s} {t_weld:9.4f}")
    print(f"{'cotangent Laplacian + lumped mass':52s} {t_lap:9.4f}")
    print(f"{'distances vertex -> every bone segment':52s} {t_dist:9.4f}")
    print(f"{'visibility (batched rays)':52s} {t_vis:9.4f}")
    print(f"{'factorise once + solve all joints (splu)':52s} {t_solve:9.4f}")
    print(f"{'bone_heat_weights end to end (budget 10 s)':52s} {t_total:9.4f}")
    print(f"{'reference: spsolve per joint (fresh factorisation)':52s} {t_ref:9.4f}")
    print(f"ratio spsolve per joint / one factorisation:          {t_ref / t_solve:7.1f}x "
          f"(max heat difference {err:.1e})")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--vertices", type=int, default=30000)
    args = ap.parse_args()
    main(args.clip, args.vertices)
