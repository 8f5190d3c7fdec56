"""Skin 100k vertices with 4 influences each by 31 joints: Warp kernels (rig.skin.skinning.Skinner, on
the CPU unless a device is given) against the vectorised float64 NumPy references
(rig.skin.skinning.lbs_numpy / dqs_numpy), all measured in this one run; then the per-frame vertex normals
(rig.character.normals.VertexNormals) of a ~200k-triangle grid with as many vertices.

    .venv/bin/python benchmarks/bench_skinning.py [device]

Times are the best of several repeats after one warm-up call, so Warp's kernel compile (seconds,
once per module) and first-launch costs are excluded. A Warp call includes uploading the (31, 4, 4)
matrices and copying the (V, 3) float32 result back into a new NumPy array.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.character.normals import VertexNormals  # noqa: E402
from jiggle.rig.skin.skinning import Skinner, dqs_numpy, lbs_numpy  # noqa: E402

V, K, J = 100_000, 4, 31


def grid(n: int):
    """An n x n vertex grid in the unit square: positions (n*n, 3), faces (2 (n-1)^2, 3)."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    positions = np.stack([x.ravel(), y.ravel(), 0.01 * np.sin(8.0 * x.ravel())], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    return positions, faces


def main(device: str = "cpu") -> None:
    rng = np.random.default_rng(0)
    rest = rng.normal(scale=0.3, size=(V, 3))
    joints = rng.integers(0, J, size=(V, K))
    weights = rng.random((V, K))
    weights /= weights.sum(axis=1, keepdims=True)
    matrices = np.tile(np.eye(4), (J, 1, 1))
    matrices[:, :3, :3] = Rotation.random(J, random_state=0).as_matrix()
    matrices[:, :3, 3] = rng.normal(scale=0.2, size=(J, 3))

    t_build = time.perf_counter()
    skinner = Skinner(rest, joints, weights, device=device)
    t_build = time.perf_counter() - t_build
    t_lbs, lbs = best(lambda: skinner.lbs(matrices), repeats=5, warmup=True)
    t_lbs_np, lbs_ref = best(lambda: lbs_numpy(rest, joints, weights, matrices), repeats=5, warmup=True)
    t_dqs, dqs = best(lambda: skinner.dqs(matrices), repeats=5, warmup=True)
    t_dqs_np, dqs_ref = best(lambda: dqs_numpy(rest, joints, weights, matrices), repeats=5, warmup=True)
    t_launch, _ = best(lambda: skinner.launch(matrices, "lbs"), repeats=5, warmup=True)

    n = int(round(V ** 0.5))
    positions, faces = grid(n)
    normals = VertexNormals(faces, len(positions))
    t_normals, _ = best(lambda: normals(positions.astype(np.float32)), repeats=5, warmup=True)

    print(f"{V} vertices x {K} influences, {J} joints, device {skinner.device}")
    print(f"{'stage':46s} {'seconds':>9s}")
    print(f"{'Skinner construction (validate, sort, upload)':46s} {t_build:9.4f}")
    print(f"{'LBS Warp (Skinner.lbs, to NumPy)':46s} {t_lbs:9.4f}")
    print(f"{'LBS Warp on device only (Skinner.launch)':46s} {t_launch:9.4f}")
    print(f"{'LBS NumPy float64 (lbs_numpy)':46s} {t_lbs_np:9.4f}")
    print(f"{'DQS Warp (Skinner.dqs, to NumPy)':46s} {t_dqs:9.4f}")
    print(f"{'DQS NumPy float64 (dqs_numpy)':46s} {t_dqs_np:9.4f}")
    print(f"{f'vertex normals, {n * n} vertices {len(faces)} faces':46s} {t_normals:9.4f}")
    print(f"ratio LBS NumPy / Warp:  {t_lbs_np / t_lbs:7.1f}x   (target >= 5x)")
    print(f"ratio DQS NumPy / Warp:  {t_dqs_np / t_dqs:7.1f}x")
    print(f"max |Warp - NumPy|: LBS {np.abs(lbs - lbs_ref).max():.1e} m, "
          f"DQS {np.abs(dqs - dqs_ref).max():.1e} m")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "cpu")
