"""Feature and marker vertices (rig/anatomy/features.py) and inserting vertices into a mesh (rig/anatomy/resample.py).

Simmons et al. 2002, section 2: rays from each bone and muscle along its normal meet the skin; a hit
close enough to its component and not grazing becomes a (new) feature vertex anchored to it; markers
anchor to the closest point of the nearest component. Synthetic skins (a cylinder around a straight
bone, a saw-toothed tube, the simple arm with its biceps) give known answers; CesiumMan with its
fitted muscles checks the real case (skipped without the shared assets).
"""
from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh
from conftest import asset
from scipy.spatial import cKDTree

from jiggle.rig.anatomy.features import BONE, MUSCLE, Anchors, FeatureOptions, _thin, anchor_points, find_features
from jiggle.rig.anatomy.resample import Resampled, carry, carry_weights, insert_points, resample_character
from jiggle.rig.base.errors import InputError
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.muscle.loft_attach import closest_points
from jiggle.rig.muscle.segmentation import bone_segments
from jiggle.rig.muscle.simple_arm import RADIUS, capped_tube, simple_arm
from jiggle.rig.skin.influence import _attach


# ---------------------------------------------------------------------------------- helpers
def area2(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F, 3) twice-area normal vectors (p1 - p0) x (p2 - p0)."""
    f = np.asarray(f)
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points (n, 3) of triangles (a, b, c) (n, 3) each to points p (n, 3) (Ericson, Real-Time
    Collision Detection 5.1.5), the brute-force reference for "lies on the surface"."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    den = np.where(va + vb + vc != 0, va + vb + vc, 1.0)
    v, w = vb / den, vc / den
    out = a + v[:, None] * ab + w[:, None] * ac                                   # inside the face
    with np.errstate(divide="ignore", invalid="ignore"):
        on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.where(on_bc[:, None], b + t[:, None] * (c - b), out)
        on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        out = np.where(on_ac[:, None], a + t[:, None] * ac, out)
        on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        out = np.where(on_ab[:, None], a + t[:, None] * ab, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return out


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int = 32) -> np.ndarray:
    """(n,) distance of each point to the mesh, over the k faces with the nearest centroids."""
    tri = vertices[faces]
    _, near = cKDTree(tri.mean(axis=1)).query(points, k=k)
    p = np.repeat(points, k, axis=0)
    t = tri[near.ravel()]
    q = closest_on_triangles(p, t[:, 0], t[:, 1], t[:, 2])
    return np.linalg.norm(p - q, axis=1).reshape(len(points), k).min(axis=1)


def tube_character(radius, length: float = 0.3, rings: int = 31, around: int = 48) -> Character:
    """A closed surface of revolution r(z) around one bone from the origin down to (0, 0, -length),
    both joints at identity rotation, every vertex weighted to the root. radius: callable of z (<= 0)."""
    z = -np.linspace(0.0, length, rings)
    v, f = capped_tube(z, radius(z), around)
    names, parents = ("root", "tip"), np.array([-1, 0], np.int32)
    bind = np.tile(np.eye(4), (2, 1, 1))
    bind[1, 2, 3] = -length
    return Character(vertices=v, faces=f, normals=vertex_normals(v, f), uvs=None, joint_names=names,
                     parents=parents, bind_world=bind, bind_matrices=bind,
                     joints=np.zeros((len(v), 1), np.int32), weights=np.ones((len(v), 1), np.float32),
                     skeleton=bind_clip(names, parents, bind), name="tube")


def rigid(angle: float, axis, translation) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(angle * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()
    m[:3, 3] = translation
    return m


@pytest.fixture(scope="module")
def arm():
    return simple_arm()


@pytest.fixture(scope="module")
def arm_segments(arm):
    return bone_segments(arm.character)


# ---------------------------------------------------------------------------------- resample
@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def test_inserted_points_are_vertices_at_the_given_places_and_the_surface_is_kept(sphere):
    V, F = sphere
    rng = np.random.default_rng(1)
    n = 60
    face = rng.integers(0, len(F), n)
    face[:7] = 3                       # several points in one triangle
    bary = rng.dirichlet([1.0, 1.0, 1.0], n)
    r, new = insert_points(V, F, face, bary)
    target = np.einsum("nk,nkx->nx", bary, V[F[face]])
    np.testing.assert_allclose(r.vertices[new], target, atol=1e-14)
    assert len(np.unique(new)) == n and new.min() >= len(V)
    assert r.original == len(V) and r.inserted == n
    np.testing.assert_array_equal(r.vertices[:len(V)], V)
    # each original face is covered by its children: sum of child areas == parent area; each child is
    # wound as its parent (twice-area vectors point the same way, all in the parent's plane)
    nf = area2(V, F)
    nc = area2(r.vertices, r.faces)
    assert len(r.faces) == len(F) + 2 * n
    np.testing.assert_allclose(np.bincount(r.face_origin, np.linalg.norm(nc, axis=1)),
                               np.linalg.norm(nf, axis=1), rtol=1e-12)
    parent = nf[r.face_origin]
    cos = (nc * parent).sum(1) / (np.linalg.norm(nc, axis=1) * np.linalg.norm(parent, axis=1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-9)
    assert np.bincount(r.face_origin)[3] == 1 + 2 * 7
    # the mesh stays closed and consistently oriented: every directed edge once, its reverse once
    e = np.concatenate([r.faces[:, [0, 1]], r.faces[:, [1, 2]], r.faces[:, [2, 0]]]).astype(np.int64)
    key = e[:, 0] * len(r.vertices) + e[:, 1]
    assert len(np.unique(key)) == len(key)
    assert np.isin(e[:, 1] * len(r.vertices) + e[:, 0], key).all()
    # every vertex is its barycentric blend of original vertices
    np.testing.assert_allclose(np.einsum("vk,vkx->vx", r.bary, V[r.source]), r.vertices, atol=1e-14)


def test_points_on_edges_split_both_neighbours_and_corners_map_to_vertices(sphere):
    V, F = sphere
    face = np.array([0, 0, 5, 9])
    bary = np.array([[0.5, 0.5, 0.0],        # on edge (F0[0], F0[1]) shared with a neighbour
                     [0.2, 0.8, 0.0],        # the same edge again
                     [0.0, 0.0, 1.0],        # a corner
                     [0.3, 0.3, 0.4]])
    r, new = insert_points(V, F, face, bary)
    assert new[2] == F[5, 2]
    assert r.inserted == 3
    # the two edge points split both faces on the edge (1 -> 3 each), the interior one (1 -> 3)
    assert len(r.faces) == len(F) + 2 + 2 + 2
    e = np.concatenate([r.faces[:, [0, 1]], r.faces[:, [1, 2]], r.faces[:, [2, 0]]]).astype(np.int64)
    key = e[:, 0] * len(r.vertices) + e[:, 1]
    assert len(np.unique(key)) == len(key) and np.isin(e[:, 1] * len(r.vertices) + e[:, 0], key).all()
    np.testing.assert_allclose(r.vertices[new], np.einsum("nk,nkx->nx", bary, V[F[face]]), atol=1e-14)
    assert np.all(np.linalg.norm(area2(r.vertices, r.faces), axis=1) > 1e-6)


def test_carry_interpolates_and_weights_are_top_k(sphere):
    V, F = sphere
    rng = np.random.default_rng(2)
    face = rng.integers(0, len(F), 40)
    r, new = insert_points(V, F, face, rng.dirichlet([1.0, 1.0, 1.0], 40))
    # a linear attribute (uv = affine map of position) is reproduced exactly
    A = rng.normal(size=(3, 2))
    uv = (V @ A + 0.5).astype(np.float32)
    got = carry(r, uv)
    assert got.dtype == np.float32 and got.shape == (len(r.vertices), 2)
    np.testing.assert_allclose(got, r.vertices @ A + 0.5, atol=1e-6)
    np.testing.assert_array_equal(got[:len(V)], uv)
    # weights: compare with a dense reference of the blended influences
    J, k = 7, 3
    joints = np.stack([rng.choice(J, k, replace=False) for _ in range(len(V))]).astype(np.int32)
    w = rng.random((len(V), k))
    w /= w.sum(1, keepdims=True)
    order = np.argsort(-w, axis=1)                      # descending, as a Character holds them
    joints, w = np.take_along_axis(joints, order, 1), np.take_along_axis(w, order, 1)
    oj, ow = carry_weights(r, joints, w.astype(np.float32))
    assert oj.shape == ow.shape == (len(r.vertices), k) and oj.dtype == np.int32 and ow.dtype == np.float32
    np.testing.assert_allclose(ow.sum(1), 1.0, atol=1e-6)
    assert np.all(np.diff(ow, axis=1) <= 0)
    np.testing.assert_array_equal(oj[:len(V)], joints)
    dense = np.zeros((len(V), J))
    np.put_along_axis(dense, joints.astype(np.int64), w, axis=1)
    blend = np.einsum("vk,vkj->vj", r.bary, dense[r.source])
    for i in range(len(V), len(r.vertices)):
        top = np.sort(blend[i])[::-1][:k]
        np.testing.assert_allclose(ow[i], top / top.sum(), atol=1e-6)
        np.testing.assert_allclose(blend[i, oj[i]][ow[i] > 0], top[top > 0], atol=1e-12)
    with pytest.raises(InputError, match="attribute"):
        carry(r, uv[:-1])
    with pytest.raises(InputError, match="weights"):
        carry_weights(r, joints, -w)


def test_insert_points_rejects_bad_input(sphere):
    V, F = sphere
    with pytest.raises(InputError, match="face"):
        insert_points(V, F, [len(F)], [[1.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="bary"):
        insert_points(V, F, [0], [[0.5, 0.6, 0.0]])
    with pytest.raises(InputError, match="bary"):
        insert_points(V, F, [0, 1], [[1.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="vertices"):
        insert_points(V[:, :2], F, [0], [[1.0, 0.0, 0.0]])


def test_resample_character_carries_everything(arm):
    ch = arm.character
    rng = np.random.default_rng(3)
    face = rng.integers(0, len(ch.faces), 30)
    r, new = insert_points(ch.vertices, ch.faces, face, rng.dirichlet([2.0, 2.0, 2.0], 30))
    c2 = resample_character(ch, r)
    assert c2.num_vertices == ch.num_vertices + 30 and c2.meta["resampled"] == {"inserted": 30}
    np.testing.assert_array_equal(c2.faces, r.faces)
    np.testing.assert_allclose(np.linalg.norm(c2.normals, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(c2.normals[:ch.num_vertices], ch.normals)
    np.testing.assert_allclose(c2.weights.sum(1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(c2.joints[:ch.num_vertices], ch.joints)
    # the cylinder's side: a new vertex's normal is radial like its neighbours'
    side = np.abs(c2.normals[ch.num_vertices:, 2]) < 0.5
    radial = c2.vertices[ch.num_vertices:][side, :2]
    cos = (c2.normals[ch.num_vertices:][side, :2] * radial).sum(1) / np.linalg.norm(radial, axis=1)
    assert cos.min() > 0.98
    with pytest.raises(InputError, match="resampled"):
        resample_character(ch, Resampled(np.zeros((3, 3)), [[0, 1, 2]], np.zeros((3, 3)), np.ones((3, 3)) / 3,
                                         3, [0]))


# ---------------------------------------------------------------------------------- features, synthetic
def test_thinning_is_the_sequential_greedy_pass():
    rng = np.random.default_rng(4)
    p = rng.random((400, 3)) * np.array([1.0, 1.0, 0.1])
    key = rng.random(400)
    key[:50] = 0.5                                        # ties go by index
    r = 0.08
    got = np.sort(_thin(p, key, r))
    kept = []
    for i in np.lexsort((np.arange(400), key)):
        if all(np.linalg.norm(p[i] - p[j]) > r for j in kept):
            kept.append(i)
    np.testing.assert_array_equal(got, np.sort(kept))


def test_bone_features_all_around_a_cylinder_at_the_reach(arm, arm_segments):
    ch = arm.character
    h = ch.height
    fs = find_features(ch, arm_segments, None, FeatureOptions(bone_reach=0.12))
    assert len(fs) > 40 and np.all(fs.source == BONE) and fs.counts["shoulder>elbow"] > 10
    p = fs.positions
    np.testing.assert_array_equal(p, fs.skin.vertices[fs.vertex])
    # on the cylinder (radius between the facets' inner radius and RADIUS), away from the joints
    rad = np.linalg.norm(p[:, :2], axis=1)
    assert rad.min() > RADIUS * np.cos(np.pi / 48) - 1e-9 and rad.max() < RADIUS + 1e-9
    assert np.all(fs.distance <= 0.12 * h) and np.all(fs.distance > 0.05)
    assert fs.counts["elbow>wrist"] > 10
    for s, (a, b) in enumerate(zip(arm_segments.start, arm_segments.end)):
        z = -p[fs.anchors.segment == s, 2]
        if z.size == 0:                     # wrist>end (estimated past the skin's end)
            continue
        lo, hi = -a[2] + 0.15 * (a[2] - b[2]), -a[2] + 0.85 * (a[2] - b[2])
        snap = 0.4 * 0.02 * h
        assert z.min() > lo - snap and z.max() < hi + snap
    # all around: every 45 degree sector holds features
    sector = np.floor((np.arctan2(p[:, 1], p[:, 0]) + np.pi) / (np.pi / 4)).astype(int) % 8
    assert np.all(np.bincount(sector, minlength=8) >= 3)
    # spacing respected and no vertex shared
    assert len(np.unique(fs.vertex)) == len(fs)
    d = cKDTree(p).query(p, k=2)[0][:, 1]
    assert d.min() >= 0.02 * h
    # the default reach (0.06 x 0.56 m = 3.4 cm) is under the radius (5.5 cm): no feature
    none = find_features(ch, arm_segments, None)
    assert len(none) == 0 and none.skin.inserted == 0 and none.candidates == 0 and none.rays == fs.rays


def test_grazing_hits_are_dropped():
    """A saw-toothed tube around a bone: its faces' normals are 70 deg from the radial direction, so
    a radial ray meets every face at |cos| = cos 70 deg = 0.34 (times cos 3.75 deg at most for the
    48 facets around): dropped at grazing 0.4, kept at 0.3."""
    period, slope = 0.02, np.tan(np.radians(70.0))
    amp = slope * period / 4.0
    tri = lambda z: 2.0 * np.abs(np.mod(z / period, 1.0) - 0.5) * 2.0 - 1.0      # noqa: E731 (-1..1)
    ch = tube_character(lambda z: 0.05 + amp * tri(z), rings=31)
    seg = bone_segments(ch)
    opts = dict(bone_reach=0.3, spacing=0.03)
    kept = find_features(ch, seg, None, FeatureOptions(grazing=0.3, **opts))
    dropped = find_features(ch, seg, None, FeatureOptions(grazing=0.4, **opts))
    assert len(kept) > 20 and len(dropped) == 0 and dropped.rays == kept.rays
    # a straight tube of the same size keeps its hits at grazing=0.4
    straight = tube_character(lambda z: 0.05 + 0.0 * z, rings=31)
    assert len(find_features(straight, bone_segments(straight), None, FeatureOptions(grazing=0.4, **opts))) > 20


def test_snap_and_insert_counts(arm, arm_segments):
    ch = arm.character
    V = ch.num_vertices
    base = dict(bone_reach=0.12)
    counts = {}
    for snap in (0.0, 0.4, 10.0):
        fs = find_features(ch, arm_segments, arm.rig, FeatureOptions(snap=snap, **base))
        assert fs.snapped + fs.inserted == len(fs)
        assert fs.skin.num_vertices == V + fs.inserted
        assert np.all(fs.vertex[fs.vertex >= V] < fs.skin.num_vertices)
        assert np.count_nonzero(fs.vertex < V) == fs.snapped
        counts[snap] = (fs.snapped, fs.inserted, len(fs))
    assert counts[0.0][0] <= 2 < counts[0.0][1]                 # no snapping (but a hit exactly at a vertex)
    assert counts[0.0][0] < counts[0.4][0] < counts[10.0][0]
    assert counts[10.0][1] == 0                                  # everything within 10 x spacing of a corner
    fixed = find_features(ch, arm_segments, arm.rig, FeatureOptions(insert=False, **base))
    assert fixed.inserted == 0 and fixed.skin.num_vertices == V and len(fixed.skin.faces) == len(ch.faces)
    assert len(fixed) > 20 and np.all(fixed.vertex < V)
    np.testing.assert_array_equal(fixed.positions, ch.vertices[fixed.vertex])


def test_muscle_features_over_the_biceps(arm, arm_segments):
    """The biceps lies 3 mm under the front of the upper arm: its rays find the skin there, and win
    over the bone's (which are 5.5 cm from the skin)."""
    ch = arm.character
    h = ch.height
    fs = find_features(ch, arm_segments, arm.rig, FeatureOptions(bone_reach=0.12))
    mus = fs.source == MUSCLE
    assert mus.sum() >= 10 and (~mus).sum() >= 10 and fs.counts["biceps"] == mus.sum()
    assert np.all(np.abs(fs.distance[mus]) <= 0.03 * h)
    p = fs.positions[mus]
    assert np.all(p[:, 1] > 0.0) and np.all((p[:, 2] < -0.05) & (p[:, 2] > -0.26))
    # near the biceps no bone feature survives: within the spacing of a muscle feature only muscles
    near = cKDTree(p).query(fs.positions[~mus])[0]
    assert near.min() >= 0.02 * h
    X = arm.rig.rest_cvs.reshape(5, 8, 3)
    assert closest_points(p, X)[2].max() <= 0.03 * h + 0.4 * 0.02 * h


def test_options_are_checked(arm, arm_segments):
    for field, kw in (("spacing", dict(spacing=0.0)), ("bone_reach", dict(bone_reach=-1.0)),
                      ("muscle_reach", dict(muscle_reach=float("nan"))), ("grazing", dict(grazing=1.0)),
                      ("snap", dict(snap=-0.1)), ("insert", dict(insert=1)), ("bone_span", dict(bone_span=(0.8, 0.2))),
                      ("rays_around", dict(rays_around=0)), ("ray_step", dict(ray_step=0.0)),
                      ("muscle_span", dict(muscle_span=(0.5, 4.5))), ("facing", dict(facing="yes"))):
        with pytest.raises(InputError) as e:
            FeatureOptions(**kw)
        assert e.value.field == field
    with pytest.raises(InputError, match="segments"):
        find_features(arm.character, None)
    with pytest.raises(InputError, match="exclude_faces"):
        find_features(arm.character, arm_segments, exclude_faces=[10 ** 6])


def test_excluded_faces_get_no_feature(arm, arm_segments):
    ch = arm.character
    front = area2(ch.vertices, ch.faces)[:, 1] > 0            # the front half of the cylinder
    fs = find_features(ch, arm_segments, None, FeatureOptions(bone_reach=0.12), exclude_faces=front)
    assert len(fs) > 10 and np.all(fs.positions[:, 1] < 1e-9)


# ---------------------------------------------------------------------------------- anchors
@pytest.fixture(scope="module")
def arm_features(arm, arm_segments):
    return find_features(arm.character, arm_segments, arm.rig, FeatureOptions(bone_reach=0.12))


def test_anchors_at_bind_give_the_rest_positions(arm, arm_features):
    a = arm_features.anchors
    np.testing.assert_allclose(a.positions(arm.character.bind_world, arm.rig.rest_cvs), a.rest, atol=1e-9, rtol=0)
    np.testing.assert_array_equal(a.rest, arm_features.positions)
    bone = a.kind == BONE
    np.testing.assert_array_equal(a.joint[bone], [0 if s == 0 else 1 for s in a.segment[bone]])
    assert np.all(a.muscle[bone] == -1) and np.all(a.segment[~bone] == -1) and np.all(a.muscle[~bone] == 0)


def test_bone_features_follow_their_joint_rigidly(arm, arm_features):
    a = arm_features.anchors
    bind = arm.character.bind_world
    T = rigid(0.7, (1.0, 2.0, -0.5), (0.1, -0.2, 0.3))
    world = bind.copy()
    world[0] = T @ bind[0]
    got = a.positions(world, arm.rig.rest_cvs)
    on0 = (a.kind == BONE) & (a.joint == 0)
    assert on0.sum() > 5
    np.testing.assert_allclose(got[on0], a.rest[on0] @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(got[~on0], a.rest[~on0], atol=1e-12)      # joint 1 and the muscle stay
    # the elbow bent by the arm's own transforms: forearm features ride joint 1's transform
    w90 = arm.world(90.0)
    on1 = (a.kind == BONE) & (a.joint == 1)
    S = w90[1] @ np.linalg.inv(bind[1])
    np.testing.assert_allclose(a.positions(w90, arm.rig.rest_cvs)[on1], a.rest[on1] @ S[:3, :3].T + S[:3, 3],
                               atol=1e-12)


def test_muscle_features_follow_the_muscle(arm, arm_features):
    a = arm_features.anchors
    bind, rest = arm.character.bind_world, arm.rig.rest_cvs
    mus = a.kind == MUSCLE
    # a rigid motion of the CVs carries the muscle rows rigidly (the loft frame is orthonormal)
    T = rigid(-0.4, (0.3, 1.0, 0.2), (0.05, 0.0, -0.1))
    moved = rest @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(a.positions(bind, moved)[mus], a.rest[mus] @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    # a scaled muscle: rig.skin.influence's attach of the same parameters, and the skin over it moves out
    c = rest.mean(axis=0)
    scaled = c + 1.3 * (rest - c)
    got = a.positions(bind, scaled)
    ref = _attach(scaled, a.muscle[mus], a.w[mus], a.v[mus], a.offset[mus], a.eps[mus])
    np.testing.assert_allclose(got[mus], ref, atol=1e-12)
    axis_d = lambda p: np.linalg.norm((p - c)[:, :2], axis=1)       # noqa: E731 (the biceps runs along z)
    assert np.all(axis_d(got[mus]) > axis_d(a.rest[mus]) + 1e-3)
    np.testing.assert_allclose(got[~mus], a.rest[~mus], atol=1e-12)
    # frames: (T, J, 4, 4) and (T, N, 3) at once equal frame by frame; a single pose broadcasts
    worlds = arm.world(np.array([0.0, 40.0, 90.0]))
    cvs = arm.rig.static(worlds).cvs
    batch = a.positions(worlds, cvs)
    assert batch.shape == (3, len(a), 3)
    for t in range(3):
        np.testing.assert_allclose(batch[t], a.positions(worlds[t], cvs[t]), atol=1e-12)
    np.testing.assert_allclose(a.positions(worlds, rest)[1], a.positions(worlds[1], rest), atol=1e-12)
    with pytest.raises(InputError, match="cvs"):
        a.positions(bind)
    with pytest.raises(InputError, match="cvs"):
        a.positions(worlds, cvs[:2])
    sub = a.take(np.nonzero(~mus)[0])
    np.testing.assert_allclose(sub.positions(bind), sub.rest, atol=1e-12)
    both = Anchors.concatenate([sub, a.take(mus)])
    assert len(both) == len(a)


def test_markers_anchor_to_the_nearest_component(arm, arm_segments):
    ch = arm.character
    pts = np.array([[0.0, 0.056, -0.15],     # just over the biceps (3 mm under the skin)
                    [0.0, -0.056, -0.15],    # back of the upper arm: bare bone (the biceps is 6 cm away)
                    [0.0, -0.056, -0.45],    # back of the forearm
                    [0.02, 0.05, -0.12]])    # inside the arm, by the biceps
    a = anchor_points(pts, ch, arm_segments, arm.rig)
    np.testing.assert_array_equal(a.kind, [MUSCLE, BONE, BONE, MUSCLE])
    np.testing.assert_array_equal(a.segment, [-1, 0, 1, -1])
    np.testing.assert_array_equal(a.joint, [-1, 0, 1, -1])
    np.testing.assert_allclose(a.positions(ch.bind_world, arm.rig.rest_cvs), pts, atol=1e-9)
    # the muscle rows' foot points are the closest points of the loft
    w, v, d = closest_points(pts[[0, 3]], arm.rig.rest_cvs.reshape(5, 8, 3))
    np.testing.assert_allclose(a.w[[0, 3]], w, atol=1e-12)
    assert d.max() < 0.01
    bones = anchor_points(pts, ch, arm_segments)
    assert np.all(bones.kind == BONE) and list(bones.segment) == [0, 0, 1, 0]
    with pytest.raises(InputError, match="points"):
        anchor_points(pts[:, :2], ch, arm_segments)


# ---------------------------------------------------------------------------------- CesiumMan
@pytest.fixture(scope="module")
def cesium():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    ch = load_character(asset("characters/CesiumMan.glb"))
    mus = fit_musculature(ch)
    segments = mus.segmentation.segments
    find_features(ch, segments, mus.rig)                # warm-up (imports, embree's first scene)
    t0 = time.perf_counter()
    fs = find_features(ch, segments, mus.rig)
    seconds = time.perf_counter() - t0
    return ch, mus, segments, fs, seconds


@pytest.mark.slow
def test_cesiumman_default_features(cesium):
    ch, mus, segments, fs, seconds = cesium
    h = ch.height
    F = len(fs)
    nb, nm = int((fs.source == BONE).sum()), int((fs.source == MUSCLE).sum())
    print(f"\nCesiumMan: {F} features ({nb} bone, {nm} muscle; {fs.snapped} snapped, {fs.inserted} inserted) "
          f"from {fs.rays} rays, {fs.candidates} candidates, in {seconds * 1e3:.0f} ms")
    assert 200 <= F <= 1500 and nb >= 50 and nm >= 50
    assert sum(fs.counts.values()) == F
    assert sum(fs.counts[m] > 0 for m in mus.rig.names) >= 20
    # every hit within its reach, and the feature vertex (a hit, or a vertex within the snap radius)
    snap = 0.4 * 0.02 * h
    b, m = fs.source == BONE, fs.source == MUSCLE
    assert np.all((fs.distance[b] > 0) & (fs.distance[b] <= 0.06 * h))
    assert np.all(np.abs(fs.distance[m]) <= 0.03 * h)
    t, d = segments.project(fs.positions[b])
    assert d[np.arange(b.sum()), fs.anchors.segment[b]].max() <= 0.06 * h + snap
    X = mus.rig.rest_cvs.reshape(-1, 5, 8, 3)
    for k in np.unique(fs.anchors.muscle[m]):
        sel = m & (fs.anchors.muscle == k)
        assert closest_points(fs.positions[sel], X[k])[2].max() <= 0.03 * h + snap
    # distinct vertices, spacing respected
    assert len(np.unique(fs.vertex)) == F
    assert cKDTree(fs.positions).query(fs.positions, k=2)[0][:, 1].min() >= 0.02 * h


def test_cesiumman_resampled_skin_is_the_same_surface(cesium):
    ch, mus, segments, fs, _ = cesium
    V = ch.num_vertices
    skin = fs.skin
    assert skin.num_vertices == V + fs.inserted and fs.inserted > 100
    a0 = np.linalg.norm(area2(ch.vertices, ch.faces), axis=1) / 2
    a1 = np.linalg.norm(area2(skin.vertices, skin.faces), axis=1) / 2
    tiny = 1e-12 * max(1.0, float(np.ptp(ch.vertices, axis=0).max())) ** 2
    assert (a1 <= tiny).sum() <= (a0 <= tiny).sum()
    np.testing.assert_allclose(np.bincount(skin.face_origin, a1, minlength=len(a0)), a0, rtol=1e-9, atol=1e-15)
    # feature vertices lie on the original surface
    assert distance_to_mesh(fs.positions, ch.vertices, ch.faces).max() < 1e-9
    # and every new vertex does
    assert distance_to_mesh(skin.vertices[V:], ch.vertices, ch.faces).max() < 1e-9
    # anchors at bind, the character on the new skin
    np.testing.assert_allclose(fs.anchors.positions(ch.bind_world, mus.rig.rest_cvs), fs.positions, atol=1e-9)
    c2 = resample_character(ch, skin)
    assert c2.num_vertices == skin.num_vertices and c2.uvs is not None and len(c2.uvs) == c2.num_vertices
    np.testing.assert_allclose(c2.weights.sum(1), 1.0, atol=1e-6)


def test_cesiumman_inserted_points_leave_no_sliver(cesium):
    ch, mus, segments, fs, _ = cesium
    V = ch.num_vertices
    # each inserted vertex keeps a share of every corner of its original triangle: the three children
    # of a split hold at least that share of its area each
    share = 0.15 / (1 + 2 * 0.15)
    assert fs.skin.bary[V:].min() >= share - 1e-9
    a0 = np.linalg.norm(area2(ch.vertices, ch.faces), axis=1)
    a1 = np.linalg.norm(area2(fs.skin.vertices, fs.skin.faces), axis=1)
    pieces = np.bincount(fs.skin.face_origin, minlength=len(a0))
    assert pieces.max() == 3                            # one inserted point per triangle at most
    child = (pieces == 3)[fs.skin.face_origin]
    assert (a1[child] / a0[fs.skin.face_origin[child]]).min() >= share * (1 - 1e-6)
    # without the inward move the ray hits near edges leave slivers
    raw = find_features(ch, segments, mus.rig, FeatureOptions(interior=0.0))
    a2 = np.linalg.norm(area2(raw.skin.vertices, raw.skin.faces), axis=1)
    assert (a2 / a0[raw.skin.face_origin]).min() < 0.02


def test_cesiumman_topology_kept_without_insertion(cesium):
    ch, mus, segments, _, _ = cesium
    fs = find_features(ch, segments, mus.rig, FeatureOptions(insert=False))
    assert fs.inserted == 0 and fs.skin.num_vertices == ch.num_vertices and len(fs) > 150
    np.testing.assert_array_equal(fs.skin.faces, ch.faces)


def test_cesiumman_markers_pick_the_nearest_component(cesium):
    """Markers at the feature vertices (over bones and muscles alike): each anchors to the component
    nearest to it, checked against every bone and every muscle without pruning."""
    ch, mus, segments, fs, _ = cesium
    p = fs.positions
    a = anchor_points(p, ch, segments, mus.rig)
    np.testing.assert_allclose(a.positions(ch.bind_world, mus.rig.rest_cvs), p, atol=1e-9)
    _, db = segments.project(p)
    X = mus.rig.rest_cvs.reshape(-1, 5, 8, 3)
    dm = np.stack([closest_points(p, x)[2] for x in X], axis=1)
    best = np.minimum(db.min(1), dm.min(1))
    got = np.where(a.kind == BONE, db[np.arange(len(p)), np.maximum(a.segment, 0)],
                   dm[np.arange(len(p)), np.maximum(a.muscle, 0)])
    np.testing.assert_allclose(got, best, atol=1e-9)
    assert (a.kind == MUSCLE).sum() > 100 and (a.kind == BONE).sum() > 20
