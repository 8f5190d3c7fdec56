"""LBS + shell deformers on 100k vertices, 40 muscles, about 2 muscles per vertex: Warp (Skinner +
ShellDeformer, one launch each) against the float64 NumPy references (lbs_numpy + shell_numpy), and the
shells' cost against LBS alone on the same mesh (benchmarks/bench_influence.py times influence objects
on this scene).

    .venv/bin/python benchmarks/bench_shells.py [device]

The scene: a limb-like tube (radius 6 cm, 1.2 m) of 100k vertices skinned to 41 joints along it with
4 influences, and 40 muscles in two rows (front and back) under its skin, each its rest ellipsoid;
each frame the muscles bulge (x1.08 across, x0.9 along) and slide 5 mm off their bones. Pairs are
culled at bind (rig.skin.shell.shells.cull_pairs, margin 0.25). Warp times include uploading the frame's
matrices; the result stays on the device (`launch`), as in the pipeline where the next stage reads it.
Best of several repeats after a warm-up, so kernel compiles are excluded.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.muscle.shell_params import ShellParams  # noqa: E402
from jiggle.rig.skin.shell.deformer import ShellDeformer  # noqa: E402
from jiggle.rig.skin.shell.shells import ShellFrames, cull_pairs, shell_numpy, shell_table
from jiggle.rig.skin.skinning import Skinner, lbs_numpy  # noqa: E402

V, M, J, K = 100_000, 40, 41, 4
LENGTH, RADIUS = 1.2, 0.06


def tube(n: int = V) -> np.ndarray:
    rings = int(np.sqrt(n * 4))
    around = n // rings
    z = np.repeat(np.linspace(0.0, LENGTH, rings), around)
    t = np.tile(2 * np.pi * np.arange(around) / around, rings)
    return np.column_stack([RADIUS * np.cos(t), RADIUS * np.sin(t), z])


def muscles() -> np.ndarray:
    """(M, 4, 4) rest ellipsoids: 20 along the tube in front (+x) and 20 behind, long axis along z."""
    E = np.tile(np.eye(4), (M, 1, 1))
    for m in range(M):
        side = 1.0 if m % 2 == 0 else -1.0
        E[m, :3, :3] = np.diag([0.022, 0.03, 0.05])
        E[m, :3, 3] = (side * 0.03, 0.0, 0.03 + (m // 2) * LENGTH / 20)
    return E


def skinned_tube():
    """The tube (V, 3), its 4 influences (joints, weights (V, K)) on the J joints along it, and a
    gently bent pose's skin matrices (J, 4, 4): each joint turned a little about x."""
    rng = np.random.default_rng(0)
    rest = tube()
    seg = np.clip((rest[:, 2] / LENGTH * (J - 1)).astype(int), 0, J - 2)
    joints = np.stack([seg, seg + 1, np.clip(seg - 1, 0, J - 1), np.clip(seg + 2, 0, J - 1)], axis=1)
    weights = rng.random((len(rest), K)) * np.array([1.0, 0.6, 0.1, 0.1])
    weights /= weights.sum(axis=1, keepdims=True)
    matrices = np.tile(np.eye(4), (J, 1, 1))
    a = 0.01 * np.arange(J)
    matrices[:, 1, 1], matrices[:, 1, 2], matrices[:, 2, 1], matrices[:, 2, 2] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a)
    return rest, joints, weights, matrices


def frame(E_rest: np.ndarray, matrices: np.ndarray, bones: np.ndarray) -> ShellFrames:
    E_ref = matrices[bones] @ E_rest
    bulge = np.diag([1.08, 1.08, 0.9, 1.0])
    E_cur = E_ref @ bulge
    E_cur[:, :3, 3] += 0.005
    curve = E_ref[:, None, :3, 3] + np.linspace(0, 1, 9)[None, :, None] * (E_cur - E_ref)[:, None, :3, 3]
    return ShellFrames(E_ref=E_ref, E_ref_inv=np.linalg.inv(E_ref), E_cur=E_cur, E_cur_inv=np.linalg.inv(E_cur),
                       curve=curve, active=np.ones(M, bool))


def main(device: str = "cpu") -> None:
    rest, joints, weights, matrices = skinned_tube()
    E_rest = muscles()
    bones = np.clip((E_rest[:, 2, 3] / LENGTH * (J - 1)).astype(int), 0, J - 1)
    table = shell_table([ShellParams()] * M)
    offsets, muscle = cull_pairs(rest, E_rest, table.drop_off, 0.25)
    pair_w = np.ones(len(muscle), np.float32)
    fr = frame(E_rest, matrices, bones)

    skinner = Skinner(rest, joints, weights, device=device)
    shells = ShellDeformer(table, offsets, muscle, pair_w, device=device)
    pts = skinner.launch(matrices)

    def warp_lbs():
        skinner.launch(matrices)
        wp.synchronize_device(device)

    def warp_shells_only():
        shells.launch(pts, fr)
        wp.synchronize_device(device)

    def warp_both():
        shells.launch(skinner.launch(matrices), fr)
        wp.synchronize_device(device)

    def numpy_both():
        return shell_numpy(lbs_numpy(rest, joints, weights, matrices), offsets, muscle, pair_w, table, fr)

    t_lbs, _ = best(warp_lbs, repeats=20, warmup=True)
    t_sh, _ = best(warp_shells_only, repeats=20, warmup=True)
    t_both, _ = best(warp_both, repeats=20, warmup=True)
    t_np, ref = best(numpy_both, repeats=3, warmup=False)
    out = shells.launch(skinner.launch(matrices), fr).numpy()
    err = np.abs(out - ref).max()
    moved = int((np.linalg.norm(ref - lbs_numpy(rest, joints, weights, matrices), axis=1) > 1e-6).sum())
    print(f"{len(rest)} vertices, {M} muscles, {len(muscle)} pairs ({len(muscle) / len(rest):.2f} per vertex), "
          f"{moved} vertices moved; device {device}")
    print(f"  LBS alone (Warp)            {t_lbs * 1e3:8.2f} ms")
    print(f"  shells alone (Warp)         {t_sh * 1e3:8.2f} ms   = {t_sh / t_lbs:.2f} x LBS (goal <= 2)")
    print(f"  LBS + shells (Warp)         {t_both * 1e3:8.2f} ms")
    print(f"  LBS + shells (NumPy ref)    {t_np * 1e3:8.2f} ms   Warp is {t_np / t_both:.1f}x faster (goal >= 5); "
          f"max difference {err * 1e6:.2f} um")


if __name__ == "__main__":
    main(*sys.argv[1:])
