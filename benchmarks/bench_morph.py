"""The paper's figures on our pipeline (Simmons et al. 2002, section 5: about one minute for an 87k-vertex
skin in Matlab), in one run on an ~87k-vertex character with about 1,500 feature points:

- the morph: prepare the canonical (fit, features, zones, markers), then the component morph and the
  skin by exact zoned RBF (solve + evaluate, budget 2 s), with the marker rms against a stretched target;
- animation with `skinning = "rbf"`: bind (features, zones, cardinal weights), then per frame the
  feature points on their components and one Warp product (budget 10 ms), against the NumPy reference
  of the same product and against LBS on the same mesh.

    .venv/bin/python benchmarks/bench_morph.py [path/to/character.glb]

The character is CesiumMan (../shared/assets) subdivided until its edges are under a length that
gives ~87k vertices, its weights and UVs carried to the new vertices (rig.anatomy.resample).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "anatomy"))

from timing import best  # noqa: E402

DEFAULT = ROOT.parent / "shared" / "assets" / "characters" / "CesiumMan.glb"
TARGET_VERTICES = 87_000


def subdivided(character, target: int = TARGET_VERTICES):
    """The character on its skin subdivided (trimesh.remesh.subdivide_to_size) to about `target` vertices."""
    import trimesh

    from jiggle.rig.anatomy.resample import Resampled, resample_character
    v, f = np.asarray(character.vertices), np.asarray(character.faces)
    edge = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1).mean()
    lo, hi = edge / 64, edge
    for _ in range(12):  # bisect the edge length for the vertex count
        mid = 0.5 * (lo + hi)
        nv, nf, idx = trimesh.remesh.subdivide_to_size(v, f, mid, max_iter=12, return_index=True)
        if len(nv) > target:
            lo = mid
        else:
            hi = mid
        if abs(len(nv) - target) < 0.03 * target:
            break
    # every new vertex as barycentric coordinates in an original face that holds it
    owner = np.zeros(len(nv), np.int64)
    owner[nf.ravel()] = np.repeat(idx, 3)
    corners = v[f[owner]]
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, nv - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    y = (d11 * d20 - d01 * d21) / den
    z = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.stack([1 - y - z, y, z], axis=1), 0, 1)
    bary /= bary.sum(1, keepdims=True)
    assert np.array_equal(nv[:len(v)], v)          # subdivision appends: the originals come first
    src = f[owner].astype(np.int64)
    src[:len(v)] = np.arange(len(v))[:, None]
    bary[:len(v)] = [1.0, 0.0, 0.0]
    rs = Resampled(vertices=nv, faces=nf.astype(np.int32), source=src, bary=bary,
                   original=len(v), face_origin=np.asarray(idx, np.int64))
    return resample_character(character, rs)


def main(path: Path = DEFAULT) -> None:
    if not path.exists():
        print(f"skipped: {path} not found (../shared/assets is absent)")
        return
    from test_morph import stretched

    from jiggle.rig.anatomy.features import FeatureOptions
    from jiggle.rig.anatomy.morph import MorphOptions, morph, prepare_canonical
    from jiggle.rig.character.load import load_character
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    from jiggle.rig.skin.rbf_skin import RBFSkinOptions

    base = load_character(path)
    t = time.perf_counter()
    c = subdivided(base)
    print(f"{path.name} subdivided: {c.num_vertices} vertices, {len(c.faces)} faces "
          f"({time.perf_counter() - t:.1f} s)")

    # --- morph
    features = FeatureOptions(spacing=0.0105)
    opts = MorphOptions(features=features)
    t = time.perf_counter()
    canon = prepare_canonical(c, opts, source=str(path))
    prep = time.perf_counter() - t
    target = dict(zip(canon.markers.names, stretched(canon.markers.positions)))
    morph(canon, target, opts)                                   # warm-up (imports)
    t = time.perf_counter()
    res = morph(canon, target, opts)
    total = time.perf_counter() - t
    r = res.report
    s = r["seconds"]
    print(f"morph: {r['features']['count']} feature points ({r['features']['inserted']} inserted), "
          f"{len(canon.zones.names)} zones; prepare {prep:.1f} s "
          f"(fit {s['fit']:.1f}, features {s['features']:.2f}, zones+markers {s['zones+markers']:.2f})")
    print(f"  morph {total:.2f} s: components {s['components']:.3f} s, skin RBF solve + evaluate "
          f"{s['skin rbf']:.2f} s (budget 2 s; the paper: ~60 s in Matlab)")
    print(f"  marker rms {1e3 * r['marker_rms_m']:.1f} mm = {100 * r['marker_rms_fraction']:.2f}% of the height "
          f"(< 1%), flipped triangles {r['flipped']}, condition up to {max(r['rbf']['condition']):.3g}")

    # --- animation
    from jiggle.rig.muscle.fit import fit_musculature
    mus = canon.musculature if canon.character.num_vertices == c.num_vertices else fit_musculature(c)
    t = time.perf_counter()
    sk = MuscleSkin.from_musculature(mus, skinning="rbf",
                                     rbf=RBFSkinOptions(features=FeatureOptions(spacing=0.0105)))
    bind = time.perf_counter() - t
    rbf = sk.deformer
    print(f"rbf skin: {rbf.num_features} feature points, support {rbf.weights.index.shape[1]}, bind {bind:.1f} s")
    from jiggle.rig.motion.quat import from_axis_angle, to_matrix
    T = 32
    world = np.repeat(np.asarray(c.bind_world)[None], T, axis=0)
    for i in range(T):  # a turning body: every frame different
        R = to_matrix(from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.05 * i))
        world[i, :, :3, :3] = R @ world[i, :, :3, :3]
        world[i, :, :3, 3] = world[i, :, :3, 3] @ R.T
    st = mus.rig.static(world)
    feats = rbf.feature_positions(world, st.cvs)
    t_feat, _ = best(lambda: rbf.feature_positions(world[0], st.cvs[0]), repeats=20, warmup=True)
    t_one, _ = best(lambda: rbf.skinner.apply(feats[0]), repeats=20, warmup=True)
    t_np, _ = best(lambda: rbf.weights.apply(feats[0]), repeats=5, warmup=True)
    t_batch, _ = best(lambda: rbf.skinner.apply_batch(feats), repeats=5, warmup=True)
    t_pose, _ = best(lambda: sk.pose(world[0], st.cvs[0], st.curve[0]), repeats=10, warmup=True)
    t_lbs, _ = best(lambda: sk.lbs(world[0]), repeats=10, warmup=True)
    print(f"  per frame: features {1e3 * t_feat:.2f} ms + product {1e3 * t_one:.2f} ms (Warp) = pose "
          f"{1e3 * t_pose:.2f} ms (budget 10 ms); batch of {T}: {1e3 * t_batch / T:.2f} ms/frame")
    print(f"  product: Warp {1e3 * t_one:.2f} ms vs NumPy {1e3 * t_np:.1f} ms -> {t_np / t_one:.1f}x; "
          f"pose vs LBS on the same mesh {1e3 * t_lbs:.2f} ms -> {t_pose / t_lbs:.1f}x")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
