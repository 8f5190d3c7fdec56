"""Zoned RBF interpolation (rig/anatomy/rbf.py) and its Warp kernel (rig/anatomy/rbf_kernels.py).

The interpolant (Simmons et al. 2002, eq. 1-2): f(v) = L(v) + sum_i c_i phi(|v - p_i|), with
sum c_i = 0 and sum c_i p_i^T = 0, solved as [[Phi, P], [P^T, 0]] [C; M^T] = [U; 0]. Geometry here is a
tube (a limb: radius 5 cm, 60 cm long, along z) with a duplicated seam column, as skins split at UV
seams have.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.distance import cdist

from jiggle.rig.anatomy.rbf import (
    KERNELS,
    RBFOptions,
    RBFSkinner,
    ZoneRBF,
    boundary_report,
    build_zone_rbf,
    interpolate,
    merge_centres,
    phi,
    solve_zone,
    weld_edges,
    zone_interpolants,
)
from jiggle.rig.base.errors import InputError


@dataclass(frozen=True, eq=False)
class Zones:
    """Stand-in with the fields of the contract's rig.anatomy.zones.Zones."""
    names: tuple
    vertex_zone: np.ndarray
    neighbours: np.ndarray
    blend: sp.csr_matrix

    @property
    def num_zones(self) -> int:
        return len(self.names)


def tube(around=24, along=41, radius=0.05, length=0.6, x=0.0):
    """(vertices (V, 3), faces) of an open cylinder along z from 0 to `length` at (x, 0); the seam
    column at angle 0 is duplicated (angle 2 pi), as at a UV seam."""
    a = np.linspace(0.0, 2 * np.pi, around + 1)
    z = np.linspace(0.0, length, along)
    A, Zc = np.meshgrid(a, z, indexing="ij")                 # (around + 1, along)
    v = np.stack([x + radius * np.cos(A), radius * np.sin(A), Zc], axis=-1).reshape(-1, 3)
    idx = np.arange((around + 1) * along).reshape(around + 1, along)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    faces = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return v, faces


def tube_features(around=24, along=41, step_a=2, step_z=3):
    """Feature vertices of `tube`: every step_a-th column (the seam copy excluded) x every step_z-th ring."""
    cols = np.arange(0, around, step_a)
    rows = np.arange(0, along, step_z)
    return (cols[:, None] * along + rows[None, :]).ravel()


def one_zone(V):
    return Zones(("limb",), np.zeros(V, np.int32), np.ones((1, 1), bool), sp.csr_matrix(np.ones((V, 1))))


def slab_zones(v, cuts, band=0.0, chain=True):
    """Zones by z between `cuts`, neighbours along the chain, blend: a smoothstep ramp of width `band`
    centred on each cut (0: each vertex its own zone)."""
    z = v[:, 2]
    vz = np.searchsorted(np.asarray(cuts), z).astype(np.int32)
    Z = len(cuts) + 1
    nb = np.eye(Z, dtype=bool)
    if chain:
        for i in range(Z - 1):
            nb[i, i + 1] = nb[i + 1, i] = True
    B = np.zeros((len(v), Z))
    B[np.arange(len(v)), vz] = 1.0
    if band > 0:
        for i, c in enumerate(cuts):
            t = np.clip((z - (c - band / 2)) / band, 0.0, 1.0)
            s = t * t * (3 - 2 * t)
            near = (np.abs(z - c) < band / 2) & ((vz == i) | (vz == i + 1))
            B[near] = 0.0
            B[near, i], B[near, i + 1] = 1 - s[near], s[near]
    return Zones(tuple(f"z{i}" for i in range(Z)), vz, nb, sp.csr_matrix(B))


def bend(p, angle=1.0, centre=(0.0, 0.0, 0.3)):
    """A smooth non-affine map: rotation about the x axis through `centre` by angle * (z - cz)."""
    d = p - np.asarray(centre)
    a = angle * d[:, 2]
    c, s = np.cos(a), np.sin(a)
    return np.asarray(centre) + np.stack([d[:, 0], c * d[:, 1] - s * d[:, 2], s * d[:, 1] + c * d[:, 2]], axis=1)


AFFINE = (np.array([[1.1, 0.2, -0.1], [0.05, 0.9, 0.3], [0.2, -0.1, 1.05]]), np.array([3.0, -2.0, 1.5]))


@pytest.fixture(scope="module")
def limb():
    v, f = tube()
    fi = tube_features()
    return v, f, fi


# ----------------------------------------------------------------------------------------------
# kernels and one zone

def test_kernel_values():
    r = np.array([0.0, 0.1, 0.2])
    s = 0.1
    expected = {"soliton": [1.0, np.exp(-1.0), np.exp(-2.0)],
                "gaussian": [1.0, np.exp(-0.5), np.exp(-2.0)],
                "multiquadric": [1.0, np.sqrt(2.0), np.sqrt(5.0)],
                "inverse_multiquadric": [1.0, 1 / np.sqrt(2.0), 1 / np.sqrt(5.0)]}
    assert set(expected) == set(KERNELS)
    for k, want in expected.items():
        np.testing.assert_allclose(phi(r, k, s), want, rtol=1e-14, err_msg=k)
    assert phi(np.zeros((2, 3)), "soliton", 1.0).shape == (2, 3)
    with pytest.raises(InputError) as e:
        phi(r, "thin_plate", 1.0)
    assert e.value.field == "kernel"
    with pytest.raises(InputError):
        phi(r, "soliton", 0.0)


@pytest.mark.parametrize("kernel", KERNELS)
def test_solve_zone_interpolates_with_side_conditions(kernel):
    rng = np.random.default_rng(1)
    c = rng.uniform(-0.2, 0.2, (40, 3))
    u = rng.normal(0.0, 0.01, (40, 3))
    coeffs, affine, cond = solve_zone(c, u, RBFOptions(scale=0.15, kernel=kernel))
    # f(p_j) = sum_i c_i phi(|p_j - p_i|) + [p_j, 1] M  (eq. 1) must equal u_j at every centre
    f = phi(cdist(c, c), kernel, 0.15) @ coeffs + np.c_[c, np.ones(len(c))] @ affine
    np.testing.assert_allclose(f, u, atol=1e-12)
    np.testing.assert_allclose(coeffs.sum(axis=0), 0.0, atol=1e-10)        # sum c_i = 0
    np.testing.assert_allclose(c.T @ coeffs, 0.0, atol=1e-10)              # sum c_i p_i^T = 0
    assert 1.0 <= cond < 1e12
    # 1-D values and an affine field: C = 0, the affine part alone
    coeffs1, affine1, _ = solve_zone(c, c @ [1.0, 2.0, 3.0] + 4.0, RBFOptions(scale=0.15, kernel=kernel))
    assert coeffs1.shape == (40,)
    np.testing.assert_allclose(coeffs1, 0.0, atol=1e-9)
    np.testing.assert_allclose(affine1, [1.0, 2.0, 3.0, 4.0], atol=1e-9)


def test_merge_centres():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 5e-5], [2, 0, 0], [2, 0, 2e-4]], float)
    c, g = merge_centres(p, 1e-4)
    np.testing.assert_array_equal(g, [0, 1, 0, 1, 2, 3])
    np.testing.assert_allclose(c, [[0, 0, 0], [1, 0, 2.5e-5], [2, 0, 0], [2, 0, 2e-4]])
    c0, g0 = merge_centres(p, 0.0)
    assert len(c0) == 6 and (g0 == np.arange(6)).all()


# ----------------------------------------------------------------------------------------------
# affine reproduction, truncation

@pytest.mark.parametrize("support", [0, 32, 8])
def test_affine_maps_reproduced_exactly(limb, support):
    v, f, fi = limb
    feats = v[fi] + [0.0, 0.0, 1e-3]        # features off the vertices: no exact rows to hide behind
    zones = slab_zones(v, [0.2, 0.4], band=0.08)
    fz = zones.vertex_zone[fi]
    rbf = build_zone_rbf(v, feats, fz, zones, RBFOptions(scale=0.1, support=support))
    assert rbf.index.dtype == np.int32 and rbf.index.shape == rbf.weight.shape
    assert support == 0 or rbf.support == support
    assert support != 0 or rbf.support > 32
    np.testing.assert_allclose(rbf.weight.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rbf.apply(feats), v, atol=1e-9)
    A, t = AFFINE
    np.testing.assert_allclose(rbf.apply(feats @ A.T + t), v @ A.T + t, atol=1e-9)
    batch = rbf.apply(np.stack([feats, feats @ A.T + t]))
    np.testing.assert_allclose(batch[1], v @ A.T + t, atol=1e-9)
    # the exact morph too
    pos, info = interpolate(v, feats, feats @ A.T + t, fz, zones, RBFOptions(scale=0.1))
    np.testing.assert_allclose(pos, v @ A.T + t, atol=1e-9)
    assert len(info["condition"]) == 3 and info["merged"] == 0
    json.dumps(info)


def test_truncated_weights_close_to_dense(limb):
    """Support 32 against the dense interpolant on a bend (90 degrees over the limb's 60 cm).

    The truncation drops the cardinal functions' far tails and the affine correction puts their sum
    back on the kept features, so the error is a fraction of the displacement that is NOT affine
    (the affine part is reproduced exactly either way). Measured with scale 0.1 m (168 features, 32
    kept): max 3.8% of that part, at the open end ring beyond the last feature ring (the cardinal
    functions extrapolate there and have their longest tails: 14% of a row's |w| lies beyond the 32
    largest), mean 0.4%; asserted: max < 6%, mean < 1%. Support 16 is 3x worse at the max (12%).
    """
    v, f, fi = limb
    zones = one_zone(len(v))
    fz = np.zeros(len(fi), int)
    feats = v[fi]
    moved = bend(feats, angle=np.pi / 2 / 0.6)
    opts = RBFOptions(scale=0.1)
    dense, _ = interpolate(v, feats, moved, fz, zones, opts)
    sparse = build_zone_rbf(v, feats, fz, zones, opts).apply(moved)
    full = build_zone_rbf(v, feats, fz, zones, RBFOptions(scale=0.1, support=0)).apply(moved)
    np.testing.assert_allclose(full, dense, atol=1e-9)        # support 0: the dense interpolant
    q = np.c_[v, np.ones(len(v))]
    nonaffine = dense - q @ np.linalg.lstsq(q, dense, rcond=None)[0]
    err = np.linalg.norm(sparse - dense, axis=1)
    scale = np.linalg.norm(nonaffine, axis=1).max()
    assert scale > 0.05                                        # a real bend: > 5 cm off any affine map
    assert err.max() < 0.06 * scale, (err.max(), scale)
    assert err.mean() < 0.01 * scale, (err.mean(), scale)
    coarse = build_zone_rbf(v, feats, fz, zones, RBFOptions(scale=0.1, support=16)).apply(moved)
    assert np.linalg.norm(coarse - dense, axis=1).max() > 2 * err.max()   # the bound is not vacuous


def test_feature_vertices_exact(limb):
    v, f, fi = limb
    zones = slab_zones(v, [0.3], band=0.1)
    fz = zones.vertex_zone[fi]
    rbf = build_zone_rbf(v, v[fi], fz, zones, RBFOptions(scale=0.1), feature_vertex=fi)
    p = np.random.default_rng(2).normal(size=(len(fi), 3))
    np.testing.assert_array_equal(rbf.apply(p)[fi], p)
    pos, _ = interpolate(v, v[fi], p, fz, zones, RBFOptions(scale=0.1), feature_vertex=fi)
    np.testing.assert_array_equal(pos[fi], p)


# ----------------------------------------------------------------------------------------------
# zones

def test_one_leg_never_moves_the_other():
    """Two parallel legs 2 cm apart under a pelvis: legs are the pelvis's neighbours, not each
    other's. Leg vertices blend only in their own zone (the band lies on the pelvis's side), so
    moving the right leg's features leaves every left-leg vertex exactly where it was."""
    parts, faces, fis = [], [], []
    n = 0
    for x, z0 in [(-0.06, 0.0), (0.06, 0.0), (0.0, 0.6)]:         # left leg, right leg, pelvis
        v, f = tube(radius=0.05 if z0 == 0 else 0.12, length=0.6 if z0 == 0 else 0.3, x=x)
        v[:, 2] += z0
        parts.append(v), faces.append(f + n), fis.append(tube_features() + n)
        n += len(v)
    v, fi = np.concatenate(parts), np.concatenate(fis)
    vz = np.repeat([0, 1, 2], [len(p) for p in parts]).astype(np.int32)
    nb = np.array([[1, 0, 1], [0, 1, 1], [1, 1, 1]], bool)
    B = np.zeros((len(v), 3))
    B[np.arange(len(v)), vz] = 1.0
    low = (vz == 2) & (v[:, 2] < 0.7)                              # pelvis band: mixes the nearer leg
    leg = np.where(v[low, 0] < 0, 0, 1)
    B[low, 2], B[low, leg] = 0.5, 0.5
    zones = Zones(("left_leg", "right_leg", "pelvis"), vz, nb, sp.csr_matrix(B))
    fz = vz[fi]
    moved = v[fi].copy()
    right = fz == 1
    moved[right] = bend(moved[right], 1.5, centre=(0.06, 0.0, 0.6)) + [0.02, 0.0, 0.0]
    opts = RBFOptions(scale=0.1)
    pos, _ = interpolate(v, v[fi], moved, fz, zones, opts)
    rbf = build_zone_rbf(v, v[fi], fz, zones, opts)
    skinned = rbf.apply(moved)
    left = vz == 0
    assert (pos[left] == v[left]).all()
    assert (skinned[left] == rbf.apply(v[fi])[left]).all()
    assert not np.isin(rbf.index[left], np.flatnonzero(right)).any()
    np.testing.assert_allclose(skinned[left], v[left], atol=1e-9)
    assert np.abs(pos[vz == 1] - v[vz == 1]).max() > 0.05          # the right leg did move
    assert np.abs(pos[low] - v[low]).max() > 1e-3                  # and the pelvis near it
    # a crotch: one triangle joining the legs' facing sides is an "apart" edge pair in the report,
    # where the legs' interpolants differ and nothing blends them
    i = np.flatnonzero(vz == 0)[np.argmax(v[vz == 0, 0] - np.abs(v[vz == 0, 2] - 0.45))]
    j = np.flatnonzero(vz == 1)[np.argmin(v[vz == 1, 0] + np.abs(v[vz == 1, 2] - 0.45))]
    crotch = np.concatenate(faces + [[[i, j, i + 1]]])
    report = boundary_report(v, crotch, pos - v, zones, zone_interpolants(v, v[fi], moved - v[fi], fz, zones, opts))
    assert report["apart_edges"] == 2
    assert report["raw_jump"]["apart"]["max"] > 1e-3 and report["gradient"]["apart"]["max"] > 0


def test_blend_band_hides_the_zone_boundary():
    """A limb split at z = 0.3 into neighbouring zones a (below) and b (above); a second tube c, 2 cm
    beside b (like the other thigh), is b's neighbour but not a's. Only c's features move (3 cm
    sideways), so f_a (features of a, b: all still) is 0 while f_b (a, b, c) leaks some of c's motion:
    at the cut the two differ by the raw jump J (the zones' interpolants, before blending).

    Blended over a band of width w, d = f_a + s (f_b - f_a) with the smoothstep s (slope <= 1.5 / w),
    so a boundary edge's gradient is at most the interior's plus 1.5 J / w: the bound asserted, with
    the 99th percentiles too. Without the band the step J falls on one edge of length h and shows as
    ~J / h, w / 1.5 h ~ 4x the band's share (measured 3.9x).
    """
    v1, f1 = tube()
    v2, f2 = tube(along=21, length=0.3, x=0.12)
    v2[:, 2] += 0.3
    v, f = np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)])
    fi = np.concatenate([tube_features(), tube_features(along=21) + len(v1)])
    vz = np.where(np.arange(len(v)) >= len(v1), 2, (v[:, 2] >= 0.3).astype(int)).astype(np.int32)
    nb = np.array([[1, 1, 0], [1, 1, 1], [0, 1, 1]], bool)
    feats = v[fi]
    moved = feats + np.where(vz[fi] == 2, 0.03, 0.0)[:, None] * [1.0, 0.0, 0.0]
    opts = RBFOptions(scale=0.1)
    out = {}
    for w in (0.0, 0.1):
        B = np.zeros((len(v), 3))
        B[np.arange(len(v)), vz] = 1.0
        if w > 0:
            t = np.clip((v[:, 2] - (0.3 - w / 2)) / w, 0.0, 1.0)
            s = t * t * (3 - 2 * t)
            near = (np.abs(v[:, 2] - 0.3) < w / 2) & (vz < 2)
            B[near] = 0.0
            B[near, 0], B[near, 1] = 1 - s[near], s[near]
        zones = Zones(("a", "b", "c"), vz, nb, sp.csr_matrix(B))
        pos, _ = interpolate(v, feats, moved, vz[fi], zones, opts)
        interp = zone_interpolants(v, feats, moved - feats, vz[fi], zones, opts)
        out[w] = boundary_report(v, f, pos - v, zones, interp)
        json.dumps(out[w])
    on, off = out[0.1], out[0.0]
    J = on["raw_jump"]["boundary"]["max"]
    assert J > 1e-3 and off["raw_jump"]["boundary"]["max"] == pytest.approx(J)   # the raw jump does not depend on blending
    g_in, g_on, g_off = on["gradient"]["interior"], on["gradient"]["boundary"], off["gradient"]["boundary"]
    assert on["boundary_edges"] == 48 and on["interior_edges"] > 1000    # the cut: a ring of 24 quads
    assert on["apart_edges"] == 0 and on["raw_jump"]["apart"]["max"] == 0.0
    assert g_on["max"] <= g_in["max"] + 1.5 * J / 0.1
    assert g_on["p99"] <= g_in["p99"]
    h = 0.6 / 40                                                   # the limb's edge length along z
    assert g_off["max"] >= 0.5 * J / h                             # the step shows on one edge
    assert g_off["max"] > 3 * g_on["max"] and g_off["p99"] > g_in["p99"]


def test_weld_edges_closes_the_seam():
    v, f = tube(around=8, along=3)
    edges, rep = weld_edges(v, f)
    # welded: 8 x 3 vertices, 8 x 3 ring edges + 8 x 2 along + 8 x 2 diagonals
    assert len(np.unique(rep)) == 24 and len(edges) == 24 + 16 + 16
    assert len(weld_edges(v, f, tol=0.0)[0]) == len(edges) + 2       # open seam: its column's 2 edges twice


# ----------------------------------------------------------------------------------------------
# merging, errors, condition

def test_merged_centres_equal_the_merged_solve(limb):
    v, f, fi = limb
    zones = slab_zones(v, [0.3], band=0.1)
    feats = v[fi]
    rng = np.random.default_rng(3)
    dup = rng.choice(len(fi), 6, replace=False)
    feats2 = np.concatenate([feats, feats[dup] + rng.uniform(-3e-5, 3e-5, (6, 3)) * [1, 1, 0]])
    fz2 = zones.vertex_zone[np.concatenate([fi, fi[dup]])]
    moved2 = bend(feats2, 1.0) + rng.normal(0, 1e-3, feats2.shape)
    opts = RBFOptions(scale=0.1)
    pos, info = interpolate(v, feats2, moved2, fz2, zones, opts)
    assert info["merged"] == 6
    # reference: the merged centres themselves with the averaged displacements
    centres, group = merge_centres(feats2, opts.merge)
    assert len(centres) == len(fi)
    count = np.bincount(group)
    u = np.stack([np.bincount(group, weights=(moved2 - feats2)[:, a]) for a in range(3)], 1) / count[:, None]
    ref, _ = interpolate(v, centres, centres + u, zones.vertex_zone[fi], zones, opts)
    np.testing.assert_allclose(pos, ref, atol=1e-10)
    rbf = build_zone_rbf(v, feats2, fz2, zones, RBFOptions(scale=0.1, support=0))
    assert rbf.merged == 6
    np.testing.assert_allclose(rbf.apply(moved2), ref, atol=1e-9)
    # without merging, exact duplicates make Phi singular
    feats3 = np.concatenate([feats, feats[dup]])
    with pytest.raises(InputError, match=r"zone 'z[01]'.*singular") as e:
        interpolate(v, feats3, feats3, fz2, zones, RBFOptions(scale=0.1, merge=0.0))
    assert "merge" in str(e.value)


def test_too_few_features_names_the_zone(limb):
    v, f, fi = limb
    zones = slab_zones(v, [0.2, 0.4], band=0.0, chain=False)      # three isolated zones
    fz = zones.vertex_zone[fi]
    keep = (fz != 2) | (np.arange(len(fi)) % 20 == 0)              # zone z2 keeps only a few features
    with pytest.raises(InputError, match=r"zone 'z2' \(2\) has \d feature points and its neighbours 0") as e:
        build_zone_rbf(v, v[fi[keep]], fz[keep], zones, RBFOptions(scale=0.1))
    assert "smaller feature spacing" in str(e.value) and e.value.field == "feature_zone"


def test_bad_input_raises(limb):
    v, f, fi = limb
    zones = one_zone(len(v))
    fz = np.zeros(len(fi), int)
    feats = v[fi].copy()
    feats[3, 1] = np.nan
    with pytest.raises(InputError) as e:
        build_zone_rbf(v, feats, fz, zones, RBFOptions(scale=0.1))
    assert e.value.field == "features"
    with pytest.raises(InputError) as e:
        interpolate(v, v[fi], feats, fz, zones, RBFOptions(scale=0.1))
    assert e.value.field == "displaced"
    with pytest.raises(InputError) as e:
        build_zone_rbf(v, v[fi], fz + 1, zones, RBFOptions(scale=0.1))
    assert e.value.field == "feature_zone"
    bad_blend = Zones(zones.names, zones.vertex_zone, zones.neighbours, sp.csr_matrix(np.full((len(v), 1), 0.5)))
    with pytest.raises(InputError) as e:
        build_zone_rbf(v, v[fi], fz, bad_blend, RBFOptions(scale=0.1))
    assert e.value.field == "zones.blend"
    for field, kw in [("scale", {"scale": 0.0}), ("scale", {"scale": -1.0}), ("scale", {"scale": float("nan")}),
                      ("kernel", {"kernel": "cubic"}), ("support", {"support": -1}), ("support", {"support": 1.5}),
                      ("merge", {"merge": -1e-4}), ("min_features", {"min_features": 3}),
                      ("max_condition", {"max_condition": 0.0}), ("max_condition", {"max_condition": 0.5})]:
        with pytest.raises(InputError) as e:
            RBFOptions(**{"scale": 0.1, **kw})
        assert e.value.field == field, kw
    with pytest.raises(TypeError):
        RBFOptions()                                               # scale is required


def test_condition_reported_and_grows_with_scale(limb):
    v, f, fi = limb
    zones = slab_zones(v, [0.3], band=0.1)
    fz = zones.vertex_zone[fi]
    conds = []
    for s in (0.05, 0.1, 0.3):
        rbf = build_zone_rbf(v, v[fi], fz, zones, RBFOptions(scale=s))
        assert rbf.condition.shape == (2,) and np.isfinite(rbf.condition).all()
        assert list(rbf.zone_features) == [len(fi)] * 2            # neighbours: both sets hold all features
        conds.append(rbf.condition)
    assert (conds[0] < conds[1]).all() and (conds[1] < conds[2]).all()
    # Lanczos' extreme eigenvalues against the SVD: the 2-norm condition number of the block matrix
    c = v[fi]
    n = len(c)
    A = np.zeros((n + 4, n + 4))
    A[:n, :n] = phi(cdist(c, c), "soliton", 0.1)
    A[:n, n:] = np.c_[c - c.mean(axis=0), np.ones(n)]
    A[n:, :n] = A[:n, n:].T
    assert conds[1][0] == pytest.approx(np.linalg.cond(A), rel=1e-4)
    with pytest.raises(InputError, match=r"zone 'z0' \(0\).*condition number.*max_condition.*smaller scale"):
        build_zone_rbf(v, v[fi], fz, zones, RBFOptions(scale=0.1, max_condition=conds[1][0] / 2))


# ----------------------------------------------------------------------------------------------
# Warp kernel

def _random_rbf(rng, V=300, F=50, k=7):
    index = rng.integers(0, F, (V, k)).astype(np.int32)
    weight = rng.normal(0.0, 0.3, (V, k))
    weight[:5, 4:] = 0.0                                # padded rows
    index[:5, 4:] = 0
    weight[:, 0] += 1.0 - weight.sum(axis=1)           # rows sum to 1, as every ZoneRBF row does
    return ZoneRBF(index, weight, np.ones(1), np.array([F]), 0, ("z",), F)


def test_warp_matches_numpy_reference():
    rng = np.random.default_rng(4)
    rbf = _random_rbf(rng)
    sk = RBFSkinner(rbf, device="cpu")
    p = rng.normal(0.0, 0.5, (rbf.num_features, 3)) + [2.0, -1.0, 0.5]
    ref = rbf.apply(p)
    out = sk.apply(p)
    assert out.dtype == np.float32 and out.shape == (rbf.num_vertices, 3)
    tol = 1e-5 * np.abs(ref).max()
    np.testing.assert_allclose(out, ref, atol=tol)
    frames = rng.normal(0.0, 0.5, (4, rbf.num_features, 3))
    batch = sk.apply_batch(frames)
    assert batch.shape == (4, rbf.num_vertices, 3)
    np.testing.assert_allclose(batch, rbf.apply(frames), atol=1e-5 * np.abs(frames).max() * 4)
    out2 = sk.apply(p)                                   # a new array each call, buffers reused
    np.testing.assert_array_equal(out, out2)
    import warp as wp
    dev = sk.launch(wp.array(p.astype(np.float32), dtype=wp.vec3, device="cpu"))
    assert dev.shape == (rbf.num_vertices,)
    np.testing.assert_allclose(dev.numpy(), ref, atol=tol)
    with pytest.raises(InputError):
        sk.apply(p[:-1])
    with pytest.raises(InputError):
        sk.launch(wp.zeros(3, dtype=wp.vec3, device="cpu"))


def test_warp_built_weights_far_from_origin(limb):
    """The kernel sums relative to the row's largest feature, so a limb 100 m from the origin is
    skinned to float32 round-off of its own size (not of 100 m)."""
    v, f, fi = limb
    zones = slab_zones(v, [0.3], band=0.1)
    fz = zones.vertex_zone[fi]
    rbf = build_zone_rbf(v, v[fi] + 0.0, fz, zones, RBFOptions(scale=0.1))
    moved = bend(v[fi], 1.0) + [100.0, 0.0, 0.0]
    out = RBFSkinner(rbf).apply(moved).astype(np.float64)
    ref = rbf.apply(moved)
    assert np.abs(out - ref).max() < 2e-5                  # float32 spacing at 100 m is 7.6e-6 m
