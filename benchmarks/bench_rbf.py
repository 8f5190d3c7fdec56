"""Zoned RBF skin (rig/anatomy/rbf.py) on an ~87k-vertex body with ~1,500 feature points, in one run:

- build_zone_rbf: every zone's solve plus the sparse cardinal weights (support 32);
- interpolate: the exact dense zoned morph (solve + evaluate), budget 2 s;
- per-frame apply: the Warp kernel (RBFSkinner, float32, one CPU core) against the NumPy reference
  (ZoneRBF.apply, float64), single frames and a batch of frames in one launch; budget 10 ms a frame;
- the truncation error of support 32 against the dense interpolant on a smooth bend.

    .venv/bin/python benchmarks/bench_rbf.py [path/to/character.glb]

Mesh: the CesiumMan skin welded and subdivided to edges <= 8 mm (86,916 vertices) when the shared
asset exists, else a body generated around the demo skeleton (rig.character.body) and subdivided likewise.
Features: 1,500 skin vertices by farthest-point sampling. Zones: a simple rule by position (head,
neck, torso slabs, upper/lower arms and legs per side, feet), neighbours where mesh edges cross,
and a blend band of diffused zone indicators; the lead's rig/anatomy/zones.py is the real thing.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.anatomy.rbf import RBFOptions, RBFSkinner, build_zone_rbf, interpolate, weld_edges  # noqa: E402

DEFAULT = ROOT.parent / "shared" / "assets" / "characters" / "CesiumMan.glb"
TARGET_VERTICES = 87_000
NUM_FEATURES = 1500


@dataclass(frozen=True, eq=False)
class Zones:
    """Stand-in with the fields of rig.anatomy.zones.Zones that rig.anatomy.rbf reads."""
    names: tuple
    vertex_zone: np.ndarray
    neighbours: np.ndarray
    blend: sp.csr_matrix


def skin(path: Path):
    """(vertices, faces, label): a welded skin subdivided to ~87k vertices."""
    import trimesh
    if path.exists():
        from jiggle.rig.character.load import load_character
        c = load_character(path)
        v, f, label = c.vertices, c.faces, path.name
    else:
        from jiggle.rig.character.body import BodyOptions, generate_body
        from jiggle.sim.bake.scene import load_scene
        print(f"skipped {path}: not found (../shared/assets is absent); using a generated body")
        body = generate_body(load_scene(str(ROOT / "scenes" / "default.toml")).clip, BodyOptions())
        v, f, label = body.vertices, body.faces, "generated body"
    m = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f), process=False)
    m.merge_vertices()
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    lo, hi = 1e-4, float(np.ptp(v, axis=0).max())
    for _ in range(20):     # bisect the edge length that gives ~TARGET_VERTICES
        mid = np.sqrt(lo * hi)
        n = len(trimesh.remesh.subdivide_to_size(v, f, max_edge=mid)[0])
        if abs(n - TARGET_VERTICES) < 0.03 * TARGET_VERTICES:
            break
        lo, hi = (mid, hi) if n > TARGET_VERTICES else (lo, mid)
    vv, ff = trimesh.remesh.subdivide_to_size(v, f, max_edge=mid)
    return np.asarray(vv), np.asarray(ff), label


def farthest_points(v: np.ndarray, n: int) -> np.ndarray:
    """(n,) vertex indices by farthest-point sampling (Euclidean)."""
    idx = np.empty(n, np.int64)
    idx[0] = int(np.argmin(v[:, 2]))
    d = np.linalg.norm(v - v[idx[0]], axis=1)
    for i in range(1, n):
        idx[i] = int(np.argmax(d))
        np.minimum(d, np.linalg.norm(v - v[idx[i]], axis=1), out=d)
    return idx


def rule_zones(v: np.ndarray, faces: np.ndarray, band_steps: int = 6) -> Zones:
    """Zones by position on a Z-up body centred on x = 0 (see the module docstring)."""
    h = float(v[:, 2].max() - v[:, 2].min())
    z = (v[:, 2] - v[:, 2].min()) / h
    x = v[:, 0] - np.median(v[:, 0])
    side = np.where(x < 0, "right", "left")
    width = np.abs(x) / h
    name = np.empty(len(v), object)
    name[:] = "torso"
    name[z > 0.80] = "neck"
    name[z > 0.86] = "head"
    name[z < 0.62] = "pelvis"
    legs = z < 0.47
    name[legs & (z >= 0.27)] = [f"{s}_upper_leg" for s in side[legs & (z >= 0.27)]]
    name[legs & (z < 0.27)] = [f"{s}_lower_leg" for s in side[legs & (z < 0.27)]]
    name[legs & (z < 0.05)] = [f"{s}_foot" for s in side[legs & (z < 0.05)]]
    arms = (width > 0.13) & ~legs
    name[arms] = [f"{s}_upper_arm" for s in side[arms]]
    fore = (width > 0.25) & ~legs
    name[fore] = [f"{s}_lower_arm" for s in side[fore]]
    names = tuple(sorted(set(name)))
    vz = np.array([names.index(s) for s in name], np.int32)
    edges, rep = weld_edges(v, faces)
    a, b = edges[:, 0], edges[:, 1]
    Z = len(names)
    nb = np.eye(Z, dtype=bool)
    nb[vz[a], vz[b]] = True
    nb |= nb.T
    # blend band: the zone indicator diffused a few steps along the mesh edges, kept on neighbours
    V = len(v)
    adj = sp.coo_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(V, V)).tocsr()
    adj = adj + sp.identity(V, format="csr")
    adj = sp.diags(1.0 / np.asarray(adj.sum(axis=1)).ravel()) @ adj
    B = sp.csr_matrix((np.ones(V), (np.arange(V), vz)), shape=(V, Z))
    for _ in range(band_steps):
        B = adj @ B
    B = B.tocoo()
    keep = (B.data > 1e-3) & nb[vz[B.row], B.col]
    B = sp.csr_matrix((B.data[keep], (B.row[keep], B.col[keep])), shape=(V, Z))
    B = sp.diags(1.0 / np.asarray(B.sum(axis=1)).ravel()) @ B
    return Zones(names, vz, nb, B.tocsr())


def bend(p: np.ndarray, centre: np.ndarray, angle: float) -> np.ndarray:
    """A smooth non-affine map: rotation about the x axis through `centre` by angle * (z - cz)."""
    d = p - centre
    a = angle * d[:, 2]
    c, s = np.cos(a), np.sin(a)
    return centre + np.stack([d[:, 0], c * d[:, 1] - s * d[:, 2], s * d[:, 1] + c * d[:, 2]], axis=1)


def main(path: Path = DEFAULT) -> None:
    import warp as wp
    wp.init()
    vertices, faces, label = skin(path)
    fidx = farthest_points(vertices, NUM_FEATURES)
    features = vertices[fidx]
    zones = rule_zones(vertices, faces)
    height = float(np.ptp(vertices[:, 2]))
    fz = zones.vertex_zone[fidx]
    options = RBFOptions(scale=height / 6)
    print(f"skin: {label}, {len(vertices)} vertices, {len(faces)} faces, height {height:.2f} m; "
          f"{NUM_FEATURES} features; {len(zones.names)} zones; {zones.blend.nnz - len(vertices)} extra blend entries")
    print(f"options: kernel {options.kernel}, scale {options.scale:.3f} m (height / 6), support {options.support}")

    t_build, rbf = best(lambda: build_zone_rbf(vertices, features, fz, zones, options, feature_vertex=fidx),
                        repeats=3)
    print(f"zone sets: {rbf.zone_features.tolist()} centres; max condition {np.nanmax(rbf.condition):.3g}")
    centre = vertices.mean(axis=0)
    moved = bend(features, centre, 0.6)
    runs = []

    def morph():
        runs.append(interpolate(vertices, features, moved, fz, zones, options, feature_vertex=fidx))
        return runs[-1]
    t_interp, (exact, _) = best(morph, repeats=5)
    sec = min((info["seconds"] for _, info in runs), key=lambda s: s["solve"] + s["evaluate"])

    ref_fn = lambda: rbf.apply(moved)  # noqa: E731
    t_ref, ref = best(ref_fn, repeats=3)
    # a peer: the same weights as a SciPy CSR matrix (V x F), one sparse product per frame
    W = sp.csr_matrix((rbf.weight.ravel(), rbf.index.ravel(), np.arange(0, rbf.weight.size + 1, rbf.support)),
                      shape=(rbf.num_vertices, rbf.num_features))
    t_csr, csr_out = best(lambda: W @ moved, repeats=5)
    assert np.allclose(csr_out, ref, atol=1e-12)
    skinner = RBFSkinner(rbf, device="cpu")
    t_wp, out = best(lambda: skinner.apply(moved), repeats=10, warmup=True)
    pts = wp.array(moved.astype(np.float32), dtype=wp.vec3, device="cpu")
    t_launch, _ = best(lambda: (skinner.launch(pts), wp.synchronize_device("cpu")), repeats=20, warmup=True)
    T = 32
    frames = np.stack([bend(features, centre, a) for a in np.linspace(0.0, 0.6, T)])
    t_batch, outs = best(lambda: skinner.apply_batch(frames), repeats=3, warmup=True)
    t_ref_batch, _ = best(lambda: rbf.apply(frames), repeats=1)

    disp = np.linalg.norm(exact - vertices, axis=1)
    trunc = np.linalg.norm(ref - exact, axis=1)
    nonaffine = np.linalg.norm(exact - _affine_fit(vertices, exact), axis=1)
    f32 = float(np.abs(out - ref).max())

    print(f"{'stage':58s} {'value':>10s}")
    print(f"{'build_zone_rbf (solve + weights), s':58s} {t_build:10.3f}")
    print(f"{'interpolate, exact (solve + evaluate), s, budget 2':58s} {t_interp:10.3f}"
          f"   (solve {sec['solve']:.3f}, evaluate {sec['evaluate']:.3f})")
    print(f"{'NumPy reference apply, ms / frame':58s} {1e3 * t_ref:10.2f}")
    print(f"{'SciPy CSR matrix @ points (a peer), ms / frame':58s} {1e3 * t_csr:10.2f}")
    print(f"{'Warp apply (upload + launch + copy back), ms / frame':58s} {1e3 * t_wp:10.2f}")
    print(f"{'Warp launch on device arrays, ms / frame, budget 10':58s} {1e3 * t_launch:10.2f}")
    print(f"{f'Warp apply_batch, {T} frames one launch, ms / frame':58s} {1e3 * t_batch / T:10.2f}")
    print(f"{f'NumPy reference apply of {T} frames, ms / frame':58s} {1e3 * t_ref_batch / T:10.2f}")
    print(f"ratio NumPy / Warp apply: {t_ref / t_wp:.1f}x single, {t_ref_batch / t_batch:.1f}x batch; "
          f"NumPy / Warp launch {t_ref / t_launch:.1f}x; SciPy CSR / Warp launch {t_csr / t_launch:.1f}x")
    print(f"bend: max displacement {disp.max():.3f} m, max non-affine part {nonaffine.max():.4f} m")
    print(f"support {rbf.support} vs dense: max {1e3 * trunc.max():.2f} mm, "
          f"p99 {1e3 * np.percentile(trunc, 99):.2f} mm, mean {1e3 * trunc.mean():.3f} mm; "
          f"max = {trunc.max() / nonaffine.max():.2%} of the max non-affine part")
    print(f"float32 Warp vs float64 NumPy: max {f32:.2e} m")


def _affine_fit(v: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The least-squares affine map of v onto x, applied to v."""
    q = np.c_[v, np.ones(len(v))]
    return q @ np.linalg.lstsq(q, x, rcond=None)[0]


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
