"""Bone heat skin weights (rig.character.bone_heat): a tube with a bone chain, seams, blind components,
degenerate input, and CesiumMan's artist weights as the judge."""
import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.bone_heat import LEAF_FRACTION, bone_heat_weights, bone_segments, weld
from jiggle.rig.character.load import load_character

# A tube along x, radius 0.1 m, from x = 0 to 1.4 m, capped; a 3-joint chain inside it. Joint 2 is a
# leaf at x = 1.1, so the tube past it (x > 1.1) can only be weighted through the leaf's own bone.
CHAIN = np.array([[0.05, 0.0, 0.0], [0.6, 0.0, 0.04], [1.1, 0.0, 0.0]])
CHAIN_PARENTS = np.array([-1, 0, 1])


def tube(n_around=24, n_along=57, length=1.4, radius=0.1, seam=False):
    """Closed tube along x: (V, 3) vertices, (F, 3) faces. With `seam`, the first column of the side
    is repeated as an extra column (as a glTF exporter splits vertices along a UV seam) and the faces
    of the last strip use the copies. Returns vertices, faces, and for each vertex the index of the
    same position in the seamless tube."""
    cols = n_around + 1 if seam else n_around
    th = 2 * np.pi * np.arange(cols) / n_around
    x = np.linspace(0.0, length, n_along)
    side = np.stack([np.repeat(x, cols), radius * np.tile(np.cos(th), n_along),
                     radius * np.tile(np.sin(th), n_along)], axis=1)
    ends = np.array([[0.0, 0, 0], [length, 0, 0]])
    v = np.concatenate([side, ends])
    idx = lambda i, a: i * cols + a  # noqa: E731
    f = []
    for i in range(n_along - 1):
        for a in range(n_around):
            b = a + 1 if seam else (a + 1) % n_around
            f += [(idx(i, a), idx(i + 1, a), idx(i + 1, b)), (idx(i, a), idx(i + 1, b), idx(i, b))]
    c0, c1 = len(side), len(side) + 1
    for a in range(n_around):
        b = a + 1 if seam else (a + 1) % n_around
        f += [(c0, idx(0, b), idx(0, a)), (c1, idx(n_along - 1, a), idx(n_along - 1, b))]
    plain = np.arange(len(v))
    if seam:
        i, a = np.divmod(np.arange(len(side)), cols)
        plain = np.concatenate([i * n_around + a % n_around, n_along * n_around + np.arange(2)])
    return v, np.array(f), plain


def icosphere(center, radius):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    return np.asarray(s.vertices) + center, np.asarray(s.faces)


def dense(joints, weights, J):
    """(V, J) weight matrix from top-k joints and weights."""
    W = np.zeros((len(joints), J))
    np.add.at(W, (np.arange(len(joints))[:, None], joints), weights)
    return W


def check_rows(joints, weights, J):
    assert np.isfinite(weights).all()
    assert weights.dtype == np.float32 and joints.dtype == np.int32
    assert (joints >= 0).all() and (joints < J).all()
    assert weights.min() >= 0.0 and weights.max() <= 1.0 + 1e-6
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-5)
    assert (np.diff(weights, axis=1) <= 0).all(), "weights must be sorted descending"


# ---------------------------------------------------------------------------------- synthetic
def test_tube_chain_dominant_joints_follow_the_bones_and_weights_are_smooth():
    v, f, _ = tube()
    joints, weights, report = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=3)
    check_rows(joints, weights, 3)
    x, top = v[:, 0], joints[:, 0]
    # bone 0 (x 0.05..0.6) belongs to joint 0, bone 1 (0.6..1.1) to joint 1, the leaf's (1.1..) to 2
    assert (top[(x > 0.1) & (x < 0.45)] == 0).all()
    assert (top[(x > 0.75) & (x < 1.0)] == 1).all()
    assert (top[x > 1.25] == 2).all(), "the leaf joint must take the tube beyond it"
    assert (weights[(x > 0.1) & (x < 0.35), 0] > 0.9).all()  # far from joints: nearly rigid
    # smooth: heat diffuses, so weights change little across one edge (0.025 m long along x;
    # a hard nearest-bone assignment would jump by 1)
    W = dense(joints, weights, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    jump = np.abs(W[e[:, 0]] - W[e[:, 1]]).max()
    assert jump < 0.2, jump
    # blending happens around the middle joint: both joints share the ring at x = 0.6
    ring = np.abs(x - 0.6) < 1e-9
    assert (W[ring, 0] > 0.2).all() and (W[ring, 1] > 0.2).all()
    assert report.components == 1 and report.unseen == 0 and report.blind_components == 0
    assert report.welded == len(v) and report.dropped_faces == 0


def test_seam_duplicates_get_identical_weights_equal_to_the_seamless_mesh():
    v, f, _ = tube()
    vs, fs, plain = tube(seam=True)
    assert len(vs) > len(v)
    j0, w0, _ = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=3)
    j1, w1, report = bone_heat_weights(vs, fs, CHAIN, CHAIN_PARENTS, k=3)
    assert report.welded == len(v)
    W0, W1 = dense(j0, w0, 3), dense(j1, w1, 3)
    # the copies of each seam position agree with each other and with the seamless solve
    np.testing.assert_allclose(W1, W0[plain], atol=1e-5)
    first = np.arange(0, 57 * 25, 25)
    np.testing.assert_array_equal(W1[first], W1[first + 24])


def test_zero_length_bone_and_roots_own_their_children():
    # CMU-style: joint 1 sits on the root (zero-length bone 0->1) and owns the bone to joint 2
    pos = np.array([[0.05, 0, 0], [0.05, 0, 0], [0.6, 0.02, 0], [1.1, 0, 0]])
    v, f, _ = tube()
    joints, weights, _ = bone_heat_weights(v, f, pos, [-1, 0, 1, 2], k=4)
    check_rows(joints, weights, 4)
    x = v[:, 0]
    assert (joints[(x > 0.1) & (x < 0.45), 0] == 1).all()
    assert (joints[(x > 0.75) & (x < 1.0), 0] == 2).all()
    assert (joints[x > 1.25, 0] == 3).all()


def test_masked_joint_takes_no_weight_its_bone_goes_to_the_parent():
    v, f, _ = tube()
    joints, weights, _ = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=3, bone_mask=[True, False, True])
    check_rows(joints, weights, 3)
    assert dense(joints, weights, 3)[:, 1].max() == 0.0
    x = v[:, 0]
    assert (joints[(x > 0.1) & (x < 1.0), 0] == 0).all()


def test_segments_leaf_continues_parent_end_sites_and_mask():
    pos = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.0, 0, 1.0], [0.0, 0, 1.0]])
    par = [-1, 0, 1, 2]  # 0 -> 1 zero length, 1 -> 2 up 1 m, 2 -> 3 zero length, 3 a leaf
    a, b, owner = bone_segments(pos, par)
    assert owner.tolist() == [0, 1, 2, 3]
    # the leaf looks past the zero-length bone 2 -> 3 for its direction: up
    np.testing.assert_allclose(b[3], [0, 0, 1 + LEAF_FRACTION])
    ends = np.full((4, 3), np.nan)
    ends[3] = [0, 0.2, 1.0]
    a, b, owner = bone_segments(pos, par, end_positions=ends)
    np.testing.assert_allclose(b[owner == 3][0], [0, 0.2, 1.0])
    # a masked joint's bones go to its nearest allowed ancestor
    _, _, owner = bone_segments(pos, par, bone_mask=[True, False, True, True])
    assert owner.tolist() == [0, 0, 2, 3]
    # a lone root is a point bone
    a, b, owner = bone_segments([[1.0, 2, 3]], [-1])
    np.testing.assert_allclose(a, b)
    with pytest.raises(InputError):
        bone_segments(pos, par, bone_mask=[False] * 4)


# ---------------------------------------------------------------------------------- robustness
def test_blind_component_and_loose_vertex_take_the_nearest_bone():
    # the tube holds the bones; a sphere far beyond its end sees no bone (every ray from a bone
    # leaves the tube first), and a loose vertex belongs to no face
    v, f, _ = tube()
    sv, sf = icosphere([3.0, 0.0, 0.0], 0.2)
    loose = np.array([[0.3, 0.5, 0.0]])  # nearest bone: 0's (x 0.05..0.6)
    verts = np.concatenate([v, sv, loose])
    faces = np.concatenate([f, sf + len(v)])
    joints, weights, report = bone_heat_weights(verts, faces, CHAIN, CHAIN_PARENTS, k=3)
    check_rows(joints, weights, 3)
    sphere = slice(len(v), len(v) + len(sv))
    # nearest bone of every sphere vertex is the leaf's bone (x 1.1..1.35), so joint 2 takes it all
    assert (joints[sphere, 0] == 2).all()
    np.testing.assert_allclose(weights[sphere, 0], 1.0, atol=1e-6)
    assert joints[-1, 0] == 0 and weights[-1, 0] == pytest.approx(1.0)
    assert report.components == 3 and report.blind_components == 2  # the sphere and the loose vertex
    assert report.unseen >= len(sv)
    # the tube's own weights do not change because of the other components
    j0, w0, _ = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=3)
    np.testing.assert_allclose(dense(joints[:len(v)], weights[:len(v)], 3), dense(j0, w0, 3), atol=1e-6)


def test_two_far_components_no_nan_rows_sum_to_one():
    # each sphere holds one joint; each sees its own bones only
    a_v, a_f = icosphere([0.0, 0.0, 0.0], 0.3)
    b_v, b_f = icosphere([5.0, 0.0, 0.0], 0.3)
    verts = np.concatenate([a_v, b_v])
    faces = np.concatenate([a_f, b_f + len(a_v)])
    pos = np.array([[0.0, 0, 0], [0.1, 0, 0], [5.0, 0, 0]])
    joints, weights, report = bone_heat_weights(verts, faces, pos, [-1, 0, -1])
    check_rows(joints, weights, 3)
    assert report.components == 2
    assert (joints[len(a_v):, 0] == 2).all()
    assert (joints[:len(a_v), 0] != 2).all()


def test_degenerate_faces_and_duplicate_vertices_are_harmless():
    v, f, _ = tube()
    extra = np.array([[0.2, 0.1, 0.0], [0.2, 0.1, 0.0], [0.2, 0.1, 0.0]])  # three copies of one point
    verts = np.concatenate([v, extra, [[0.3, 0.1, 0.0], [0.4, 0.1, 0.0], [0.5, 0.1, 0.0]]])
    n = len(v)
    bad = np.array([[n, n + 1, n + 2],          # zero area after the weld (one point)
                    [n + 3, n + 4, n + 5],      # collinear
                    [0, 0, 1]])                 # repeated corner
    joints, weights, report = bone_heat_weights(verts, np.concatenate([f, bad]), CHAIN, CHAIN_PARENTS)
    check_rows(joints, weights, 3)
    assert report.dropped_faces == 3
    np.testing.assert_array_equal(joints[n], joints[n + 2])
    j0, w0, _ = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS)
    np.testing.assert_allclose(dense(joints[:n], weights[:n], 3), dense(j0, w0, 3), atol=1e-6)


def test_k_larger_than_joints_pads_and_bad_input_raises():
    v, f, _ = tube(n_around=8, n_along=9)
    joints, weights, _ = bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=5)
    assert joints.shape == (len(v), 5)
    check_rows(joints, weights, 3)
    assert (weights[:, 3:] == 0).all()
    with pytest.raises(InputError):
        bone_heat_weights(v, f, CHAIN, [1, -1, 0])  # child before parent
    with pytest.raises(InputError):
        bone_heat_weights(v, f + len(v), CHAIN, CHAIN_PARENTS)
    with pytest.raises(InputError):
        bone_heat_weights(v, f, CHAIN, CHAIN_PARENTS, k=0)
    joints, weights, report = bone_heat_weights(np.zeros((0, 3)), np.zeros((0, 3), int), CHAIN, CHAIN_PARENTS)
    assert joints.shape == weights.shape == (0, 4) and report.vertices == 0


def test_weld_maps_every_vertex_to_its_position():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 1, 0], [1 + 4e-7, 0, 0]])
    f = np.array([[0, 1, 3], [2, 4, 3], [0, 2, 1]])
    points, faces, inverse = weld(v, f)
    assert len(points) == 3 and inverse.tolist() == [0, 1, 0, 2, 1]
    np.testing.assert_allclose(points[inverse], v, atol=1e-6)
    assert faces.tolist() == [[0, 1, 2], [0, 1, 2]]  # the third face collapses


# ---------------------------------------------------------------------------------- against an artist
def test_cesium_man_dominant_joints_match_the_artist(capsys):
    # the artist's weights are read from the file, then recomputed from the skeleton alone
    c = load_character(asset("characters/CesiumMan.glb"))
    v, names = c.vertices, c.joint_names
    joints, weights, report = bone_heat_weights(v, c.faces, c.bind_positions, c.parents)
    check_rows(joints, weights, len(names))
    artist = dense(c.joints, c.weights, len(names))
    art = artist.argmax(axis=1)
    sure = artist.max(axis=1) >= 0.8
    match = joints[:, 0] == art
    head = art == names.index("Skeleton_neck_joint_2")  # the head holds 2/3 of the vertices
    sure_share, all_share = match[sure].mean(), match.mean()
    body_share = match[sure & ~head].mean()
    msg = (f"CesiumMan bone heat vs artist, dominant joint equal: {sure_share:.1%} of {sure.sum()} vertices "
           f"with artist weight >= 0.8 ({body_share:.1%} of the {(sure & ~head).sum()} outside the head), "
           f"{all_share:.1%} of all {len(v)}; {report.total_s:.2f} s")
    with capsys.disabled():
        print("\n" + msg)
    assert sure_share >= 0.85, msg
    assert body_share >= 0.85, msg  # the head alone must not carry the figure
    assert all_share >= 0.8, msg
