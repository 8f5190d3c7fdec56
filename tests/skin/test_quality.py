"""Skin quality (rig/skin/quality.py): the Warp measures against a float64 NumPy reference, and each
measure against a case where the answer is known (a fold, a tear, a stretch)."""
import meshes
import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_edges
from jiggle.rig.skin.quality import GRADIENT_FLOOR, JIGGLE_MEASURES, SKIN_MEASURES, SkinQuality


def grid(n=6, size=1.0):
    return meshes.grid(n, size)


def reference(rest, faces, skins, static=None):
    """The measures in float64 NumPy, written out edge by edge from their definitions."""
    rest = rest.astype(np.float64)
    edge_faces = {}
    for f, tri in enumerate(faces):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(f)
    edges = sorted(edge_faces)

    def normals(p):
        n = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
        return n / np.linalg.norm(n, axis=1, keepdims=True), 0.5 * np.linalg.norm(n, axis=1)
    _, rest_area = normals(rest)
    out = {k: [] for k in SKIN_MEASURES + JIGGLE_MEASURES}
    for t, p in enumerate(skins.astype(np.float64)):
        n, area = normals(p)
        cos = np.array([n[fs[0]] @ n[fs[1]] if len(fs) > 1 else 1.0 for fs in (edge_faces[e] for e in edges)])
        strain = np.array([abs(np.linalg.norm(p[b] - p[a]) / np.linalg.norm(rest[b] - rest[a]) - 1) for a, b in edges])
        out["folded_edges"].append((cos < 0).sum())
        out["sharp_edges"].append((cos < 0.5).sum())
        out["edge_strain_p99"].append(np.percentile(strain, 99))
        out["edge_strain_max"].append(strain.max())
        out["area_ratio_min"].append((area / rest_area).min())
        out["area_ratio_max"].append((area / rest_area).max())
        if static is not None:
            s = static[t].astype(np.float64)
            d = p - s
            g = np.array([np.linalg.norm(d[a] - d[b]) / max(np.linalg.norm(s[a] - s[b]),
                                                            GRADIENT_FLOOR * np.linalg.norm(rest[a] - rest[b]))
                          for a, b in edges])
            out["gradient_p99"].append(np.percentile(g, 99))
            out["gradient_p999"].append(np.percentile(g, 99.9))
            out["gradient_max"].append(g.max())
            out["torn_edges"].append((g > 1).sum())
    return {k: np.array(v, float) for k, v in out.items() if v}


def test_mesh_edges_finds_each_edge_once_with_its_faces():
    verts, faces = grid(3)
    edges, edge_faces = mesh_edges(faces)
    assert len(edges) == 16                          # 2 x 2 quads: 12 sides + 4 diagonals
    assert np.all(edges[:, 0] < edges[:, 1])
    assert len({tuple(e) for e in edges}) == len(edges)
    boundary = edge_faces[:, 1] < 0
    assert boundary.sum() == 8                       # the grid's rim
    for (a, b), (f, g) in zip(edges, edge_faces):
        assert a in faces[f] and b in faces[f]
        if g >= 0:
            assert a in faces[g] and b in faces[g] and f != g


def test_kernels_equal_the_numpy_reference_on_random_frames():
    rng = np.random.default_rng(3)
    rest, faces = grid(6)
    static = rest[None] + 0.03 * rng.standard_normal((4, len(rest), 3))
    final = static + 0.08 * rng.standard_normal(static.shape)
    q = SkinQuality(rest, faces)
    ref = reference(rest, faces, final, static)
    got = {**q.skin(final), **q.jiggle(static, final)}
    for k in SKIN_MEASURES + JIGGLE_MEASURES:
        np.testing.assert_allclose(got[k], ref[k], rtol=2e-4, atol=1e-5, err_msg=k)
    assert ref["folded_edges"].max() > 0 and ref["torn_edges"].max() > 0       # the case exercises both


def test_a_fold_a_tear_and_a_stretch_are_counted_where_they_are():
    rest, faces = grid(6, size=0.5)
    q = SkinQuality(rest, faces)
    assert q.mesh.rest_folded == 0 and q.mesh.rest_sharp == 0
    flat = q.skin(rest[None])
    assert flat["folded_edges"][0] == 0 and flat["edge_strain_max"][0] == pytest.approx(0, abs=1e-6)
    assert flat["area_ratio_min"][0] == pytest.approx(1, abs=1e-5)
    # fold the sheet along x = 0.3 by 120 degrees: one row of edges folds past 90 (and is sharp)
    folded = rest.copy()
    hinge = 0.3
    right = folded[:, 0] > hinge + 1e-9
    a = np.radians(120)
    dx = folded[right, 0] - hinge
    folded[right, 0] = hinge + dx * np.cos(a)
    folded[right, 2] = dx * np.sin(a)
    m = q.skin(folded[None])
    hinge_edges = int(np.sum(np.isclose(rest[q.mesh.edges[:, 0], 0], hinge) & np.isclose(rest[q.mesh.edges[:, 1], 0],
                                                                                          hinge)))
    assert m["folded_edges"][0] == m["sharp_edges"][0] == hinge_edges == 5
    assert m["edge_strain_max"][0] == pytest.approx(0, abs=1e-5)                # a fold stretches nothing
    # a jiggle that moves one vertex by twice its edges' length tears exactly its edges
    v = 14
    moved = rest.copy()
    moved[v, 2] += 2.0 * 0.1
    j = q.jiggle(rest[None], moved[None])
    around = int(np.sum(np.any(q.mesh.edges == v, axis=1)))
    assert j["torn_edges"][0] == around == 6 and j["gradient_max"][0] == pytest.approx(2.0, rel=1e-5)
    # an edge the skinning squashed to 1% of its rest length is measured against the floor, a tenth of
    # its rest length: a jiggle of a twentieth of that length is not a tear; one of twice the floor is
    squashed = rest.copy()
    a, b = q.mesh.edges[0]
    squashed[b] = squashed[a] + 0.01 * (rest[b] - rest[a])
    rest_len = np.linalg.norm(rest[b] - rest[a])
    for push, torn in ((0.05 * rest_len, False), (2.0 * GRADIENT_FLOOR * rest_len, True)):
        moved = squashed.copy()
        moved[b, 2] += push
        g = q.gradient(squashed[None], moved[None])[0, 0]
        assert g == pytest.approx(push / (GRADIENT_FLOOR * rest_len), rel=1e-4) and (g > 1) == torn
    # a uniform stretch by 1.5 reads as strain 0.5 everywhere and area 2.25
    m = q.skin(1.5 * rest[None])
    assert m["edge_strain_p99"][0] == pytest.approx(0.5, rel=1e-5)
    assert m["area_ratio_min"][0] == pytest.approx(2.25, rel=1e-4) == m["area_ratio_max"][0]
    assert q.worst_vertex(folded) in set(np.nonzero(np.isclose(rest[:, 0], hinge, atol=0.11))[0])


def test_bad_input_names_what_is_wrong():
    rest, faces = grid(3)
    with pytest.raises(InputError, match="face indices"):
        SkinQuality(rest, faces + 100)
    q = SkinQuality(rest, faces)
    with pytest.raises(InputError, match=r"\(T, 9, 3\)"):
        q.skin(rest)
    with pytest.raises(InputError, match="differ in shape"):
        q.jiggle(rest[None], np.stack([rest, rest]))
