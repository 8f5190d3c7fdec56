"""LBS + influence objects on 100k vertices, 40 muscles, about 2 muscles per vertex: Warp (Skinner +
InfluenceDeformer, one launch each) against the float64 NumPy references (lbs_numpy + influence_numpy),
and the influence objects' cost against LBS alone on the same mesh.

    .venv/bin/python benchmarks/bench_influence.py [device]

The scene is bench_shells.py's: a limb-like tube (radius 6 cm, 1.2 m) of 100k vertices skinned to 41
joints along it with 4 influences, and 40 muscles in two rows (front and back) under its skin. Each
muscle is lofted from 40 CVs (rig.muscle.loft: 5 sections x 8 CVs, section-major) approximating its rest
ellipsoid: section k at local z = -0.9 + 1.8 k / 4 along the long axis, ring CV j at angle 2 pi j / 8
from the section's up axis (local x) toward its side (local y), on the ellipse scaled by
sqrt(1 - z^2). Each frame the CVs bulge 8% across about the muscle's centre and slide 5 mm along
its long axis; the reference CVs are the rest CVs. Pairs are culled at bind as in bench_shells
(rig.skin.shell.shells.cull_pairs, drop-off 1, margin 0.25), weight 1 each. Warp times include uploading the
frame's matrices and CVs; the result stays on the device (`launch`), as in the pipeline where the
next stage reads it. Best of several repeats after a warm-up, so kernel compiles are excluded; the
bind (closest points on the lofts, once per rig) is timed once.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_shells import M, muscles, skinned_tube  # noqa: E402  (the same scene)
from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.muscle import loft  # noqa: E402
from jiggle.rig.muscle.loft_attach import bind_influence  # noqa: E402
from jiggle.rig.skin.influence import InfluenceDeformer, influence_numpy
from jiggle.rig.skin.shell.shells import cull_pairs  # noqa: E402
from jiggle.rig.skin.skinning import Skinner, lbs_numpy  # noqa: E402

BULGE, SLIDE = 1.08, 0.005


def ellipsoid_cvs(E: np.ndarray) -> np.ndarray:
    """(40 M, 3) CVs lofting each rest ellipsoid E (M, 4, 4), row 40 m + 8 k + j (section k, ring CV j)."""
    z = -0.9 + 1.8 * np.arange(loft.SECTIONS) / (loft.SECTIONS - 1)
    a = 2 * np.pi * np.arange(loft.RING) / loft.RING
    r = np.sqrt(1.0 - z ** 2)[:, None]
    zz = np.broadcast_to(z[:, None], (loft.SECTIONS, loft.RING))
    local = np.stack([r * np.cos(a), r * np.sin(a), zz], axis=-1).reshape(-1, 3)   # (40, 3) on the unit sphere
    return (np.einsum("mij,cj->mci", E[:, :3, :3], local) + E[:, None, :3, 3]).reshape(-1, 3)


def frame_cvs(E: np.ndarray, rest_cvs: np.ndarray) -> np.ndarray:
    """Current CVs: the rest CVs scaled by BULGE across each muscle's long axis about its centre, then
    slid SLIDE metres along that axis."""
    X = rest_cvs.reshape(M, -1, 3)
    c = E[:, None, :3, 3]
    axis = E[:, :3, 2] / np.linalg.norm(E[:, :3, 2], axis=1, keepdims=True)  # long axis (local z), (M, 3)
    d = X - c
    along = (d * axis[:, None]).sum(-1, keepdims=True) * axis[:, None]
    return (c + along + BULGE * (d - along) + SLIDE * axis[:, None]).reshape(-1, 3)


def main(device: str = "cpu") -> None:
    rest, joints, weights, matrices = skinned_tube()
    E_rest = muscles()
    offsets, muscle = cull_pairs(rest, E_rest, np.ones(M), margin=0.25)
    pair_w = np.ones(len(muscle), np.float32)
    cvs_ref = ellipsoid_cvs(E_rest)
    cvs_cur = frame_cvs(E_rest, cvs_ref)

    t_bind, binding = best(lambda: bind_influence(rest, offsets, muscle, cvs_ref), repeats=1, warmup=False)
    skinner = Skinner(rest, joints, weights, device=device)
    influence = InfluenceDeformer(binding, offsets, muscle, pair_w, M, device=device)
    pts = skinner.launch(matrices)

    def warp_lbs():
        skinner.launch(matrices)
        wp.synchronize()

    def warp_influence_only():
        influence.launch(pts, cvs_cur, cvs_ref)
        wp.synchronize()

    def warp_both():
        influence.launch(skinner.launch(matrices), cvs_cur, cvs_ref)
        wp.synchronize()

    def numpy_both():
        return influence_numpy(lbs_numpy(rest, joints, weights, matrices), binding, offsets, muscle, pair_w,
                               cvs_cur, cvs_ref)

    t_lbs, _ = best(warp_lbs, repeats=20, warmup=True)
    t_inf, _ = best(warp_influence_only, repeats=20, warmup=True)
    t_both, _ = best(warp_both, repeats=20, warmup=True)
    t_np, ref = best(numpy_both, repeats=3, warmup=False)
    out = influence.launch(skinner.launch(matrices), cvs_cur, cvs_ref).numpy()
    err = np.abs(out - ref).max()
    move = np.linalg.norm(ref - lbs_numpy(rest, joints, weights, matrices), axis=1)
    moved = int((move > 1e-6).sum())
    print(f"{len(rest)} vertices, {M} muscles x {loft.SECTIONS * loft.RING} CVs, {len(muscle)} pairs "
          f"({len(muscle) / len(rest):.2f} per vertex), {moved} vertices moved (at most {move.max() * 1e3:.2f} mm); "
          f"device {device}")
    print(f"  bind (closest points)           {t_bind:8.2f} s")
    print(f"  LBS alone (Warp)                {t_lbs * 1e3:8.2f} ms")
    print(f"  influence alone (Warp)          {t_inf * 1e3:8.2f} ms   = {t_inf / t_lbs:.2f} x LBS")
    print(f"  LBS + influence (Warp)          {t_both * 1e3:8.2f} ms")
    print(f"  LBS + influence (NumPy ref)     {t_np * 1e3:8.2f} ms   Warp is {t_np / t_both:.1f}x faster "
          f"(goal >= 5); max difference {err * 1e6:.2f} um")


if __name__ == "__main__":
    main(*sys.argv[1:])
