"""Skinning (rig/skin/skinning.py, rig/skin/skinning_kernels.py) and vertex normals (rig/character/normals.py).

References: LBS p = sum_i w_i M_i [v, 1]; DQS (Kavan et al. 2008) blends unit dual quaternions
(real q, dual 0.5 (0, t) q) in the hemisphere of the largest influence and normalises by |real|.
The Warp kernels run in float32, so they match the float64 NumPy references to ~1e-7 m on inputs
of ~0.1 m; the 1e-5 m tolerance leaves room for harder random draws.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jiggle.rig.character.character import normalise_weights
from jiggle.rig.character.normals import VertexNormals, vertex_normals
from jiggle.rig.motion import quat
from jiggle.rig.skin.skinning import Skinner, dqs_numpy, lbs_numpy, matrices_to_dual_quats

TOL = 1e-5  # metres


def rigid(rotations: Rotation, translations: np.ndarray) -> np.ndarray:
    m = np.tile(np.eye(4), (len(rotations), 1, 1))
    m[:, :3, :3] = rotations.as_matrix()
    m[:, :3, 3] = translations
    return m


def random_rig(seed: int, V: int = 1000, k: int = 4, J: int = 12):
    """Rest positions within ~0.2 m, random joints and weights summing to 1, rigid matrices."""
    rng = np.random.default_rng(seed)
    rest = rng.normal(scale=0.1, size=(V, 3))
    joints = rng.integers(0, J, size=(V, k))
    weights = rng.random((V, k)) + 1e-3
    weights /= weights.sum(axis=1, keepdims=True)
    matrices = rigid(Rotation.random(J, random_state=seed), rng.normal(scale=0.3, size=(J, 3)))
    return rest, joints, weights, matrices


# ---------------------------------------------------------------------------------------------
# NumPy references


def test_lbs_numpy_matches_a_per_vertex_loop():
    rest, joints, weights, matrices = random_rig(0, V=7, k=3, J=4)
    expected = np.zeros((7, 3))
    for v in range(7):
        for i in range(3):
            m = matrices[joints[v, i]]
            expected[v] += weights[v, i] * (m[:3, :3] @ rest[v] + m[:3, 3])
    np.testing.assert_allclose(lbs_numpy(rest, joints, weights, matrices), expected, atol=1e-14)


def test_dual_quats_layout_and_values():
    rot = Rotation.from_rotvec([[0.0, 0.0, np.pi / 2], [0.3, -0.2, 0.9]])
    t = np.array([[1.0, 2.0, 3.0], [-0.1, 0.0, 0.2]])
    dq = matrices_to_dual_quats(rigid(rot, t))
    real = quat.from_xyzw(rot.as_quat())
    np.testing.assert_allclose(np.abs(np.sum(dq[:, :4] * real, axis=1)), 1.0, atol=1e-12)
    # the translation comes back as the vector part of 2 * dual * conj(real)
    back = 2.0 * quat.mul(dq[:, 4:], quat.conj(dq[:, :4]))
    np.testing.assert_allclose(back[:, 1:], t, atol=1e-12)
    np.testing.assert_allclose(back[:, 0], 0.0, atol=1e-12)


def test_dual_quats_drop_exporter_scale():
    rot = Rotation.from_rotvec([[0.4, 0.1, -0.7]])
    m = rigid(rot, np.array([[0.1, 0.2, 0.3]]))
    scaled = m.copy()
    scaled[:, :3, :3] *= np.array([1.0 + 1e-6, 1.0 - 1e-6, 1.0 + 2e-6])
    np.testing.assert_allclose(matrices_to_dual_quats(scaled), matrices_to_dual_quats(m),
                               atol=1e-12)


def test_mirrored_matrix_gets_the_nearest_rotation():
    # R diag(1, 1.1, -0.9) is a reflection; flipping its smallest singular direction gives back R
    rot = Rotation.from_rotvec([[0.5, -0.3, 1.1]])
    m = rigid(rot, np.array([[0.1, 0.0, -0.2]]))
    mirrored = m.copy()
    mirrored[0, :3, :3] = m[0, :3, :3] @ np.diag([1.0, 1.1, -0.9])
    np.testing.assert_allclose(matrices_to_dual_quats(mirrored), matrices_to_dual_quats(m),
                               atol=1e-12)
    rest = np.random.default_rng(0).normal(scale=0.1, size=(20, 3))
    ones = (np.zeros((20, 1), int), np.ones((20, 1)))
    got = Skinner(rest, *ones).dqs(mirrored)
    np.testing.assert_allclose(got, dqs_numpy(rest, *ones, m), atol=1e-6)


def test_dqs_numpy_single_influence_is_the_rigid_transform():
    rest, joints, weights, matrices = random_rig(1, V=50, k=1, J=5)
    m = matrices[joints[:, 0]]
    expected = np.einsum("vab,vb->va", m[:, :3, :3], rest) + m[:, :3, 3]
    np.testing.assert_allclose(dqs_numpy(rest, joints, weights, matrices), expected, atol=1e-12)


def test_dqs_blend_takes_the_short_way():
    # joints at +2 and -2 rad about z: their w >= 0 quaternions have a negative dot product, so
    # without the hemisphere flip the half-half blend would be the identity (the long way round)
    # instead of a half turn
    m = rigid(Rotation.from_rotvec([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0]]), np.zeros((2, 3)))
    rest = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.0]])
    joints = np.array([[0, 1], [1, 0]])
    weights = np.full((2, 2), 0.5)
    expected = np.array([[-1.0, 0.0, 0.0], [0.0, -0.5, 0.0]])
    np.testing.assert_allclose(dqs_numpy(rest, joints, weights, m), expected, atol=1e-12)
    np.testing.assert_allclose(Skinner(rest, joints, weights).dqs(m), expected, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# Warp against the references


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_warp_lbs_matches_numpy(k):
    rest, joints, weights, matrices = random_rig(10 + k, k=k)
    got = Skinner(rest, joints, weights).lbs(matrices)
    assert got.shape == (1000, 3) and got.dtype == np.float32
    err = np.abs(got - lbs_numpy(rest, joints, weights, matrices)).max()
    assert err < TOL, f"max |Warp LBS - NumPy| = {err:.2e} m"


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_warp_dqs_matches_numpy(k):
    rest, joints, weights, matrices = random_rig(20 + k, k=k)
    got = Skinner(rest, joints, weights).dqs(matrices)
    assert got.shape == (1000, 3) and got.dtype == np.float32
    err = np.abs(got - dqs_numpy(rest, joints, weights, matrices)).max()
    assert err < TOL, f"max |Warp DQS - NumPy| = {err:.2e} m"


def test_warp_dqs_unsorted_influences_pivot_on_the_largest():
    # the wrapper sorts influences, the reference takes the argmax: both pivot on the same joint
    rest, joints, weights, matrices = random_rig(30, k=4)
    weights = weights[:, ::-1].copy()
    matrices[:, :3, :3] = Rotation.from_rotvec(
        np.random.default_rng(3).normal(scale=2.0, size=(len(matrices), 3))).as_matrix()
    got = Skinner(rest, joints, weights).skin(matrices, method="dqs")
    err = np.abs(got - dqs_numpy(rest, joints, weights, matrices)).max()
    assert err < TOL, f"max |Warp DQS - NumPy| = {err:.2e} m"


def test_warp_dqs_with_exporter_scale_matches_rigid():
    rest, joints, weights, matrices = random_rig(31, k=3)
    scaled = matrices.copy()
    scaled[:, :3, :3] *= 1.0 + 1e-6 * np.random.default_rng(0).choice([-1.0, 1.0], size=(1, 3))
    s = Skinner(rest, joints, weights)
    err = np.abs(s.dqs(scaled) - dqs_numpy(rest, joints, weights, matrices)).max()
    assert err < TOL, f"max |Warp DQS(scaled) - NumPy DQS(rigid)| = {err:.2e} m"


def test_identity_matrices_give_the_rest_pose():
    rest, joints, weights, _ = random_rig(4, k=4, J=6)
    s = Skinner(rest, joints, weights)
    eye = np.tile(np.eye(4), (6, 1, 1))
    for method in ("lbs", "dqs"):
        np.testing.assert_allclose(s.skin(eye, method), rest, atol=1e-6, err_msg=method)


def test_all_weight_on_one_joint_gives_its_rigid_transform():
    rest, joints, weights, matrices = random_rig(5, k=3, J=6)
    weights = np.zeros_like(weights)
    weights[:, 1] = 1.0
    m = matrices[joints[:, 1]]
    expected = np.einsum("vab,vb->va", m[:, :3, :3], rest) + m[:, :3, 3]
    s = Skinner(rest, joints, weights)
    for method in ("lbs", "dqs"):
        np.testing.assert_allclose(s.skin(matrices, method), expected, atol=1e-6, err_msg=method)


def test_dqs_equals_lbs_for_single_influences():
    rest, joints, weights, matrices = random_rig(6, k=1)
    s = Skinner(rest, joints, weights)
    err = np.abs(s.dqs(matrices) - s.lbs(matrices)).max()
    assert err < TOL, f"max |DQS - LBS| = {err:.2e} m"


def test_dqs_single_influence_keeps_distance_to_the_joint():
    rest, joints, weights, matrices = random_rig(7, k=1, J=8)
    centres = np.random.default_rng(7).normal(scale=0.1, size=(8, 3))  # joint positions at rest
    posed_centres = np.einsum("jab,jb->ja", matrices[:, :3, :3], centres) + matrices[:, :3, 3]
    got = Skinner(rest, joints, weights).dqs(matrices)
    before = np.linalg.norm(rest - centres[joints[:, 0]], axis=1)
    after = np.linalg.norm(got - posed_centres[joints[:, 0]], axis=1)
    np.testing.assert_allclose(after, before, atol=TOL)


def test_skinner_reuses_its_buffer_but_returns_fresh_arrays():
    rest, joints, weights, matrices = random_rig(8, V=100, k=2, J=3)
    s = Skinner(rest, joints, weights)
    buffer = s.launch(matrices)
    a = s.lbs(matrices)
    b = s.lbs(np.tile(np.eye(4), (3, 1, 1)))
    assert s.launch(matrices) is buffer
    np.testing.assert_allclose(a, lbs_numpy(rest, joints, weights, matrices), atol=TOL)
    np.testing.assert_allclose(b, rest, atol=1e-6)


def test_skinner_with_no_vertices():
    s = Skinner(np.zeros((0, 3)), np.zeros((0, 4), int), np.zeros((0, 4)))
    for method in ("lbs", "dqs"):
        out = s.skin(np.tile(np.eye(4), (2, 1, 1)), method)
        assert out.shape == (0, 3)


def test_skinner_normals_from_faces():
    rest, faces = icosphere(1)
    joints = np.zeros((len(rest), 1), int)
    s = Skinner(rest, joints, np.ones((len(rest), 1)), faces=faces)
    m = rigid(Rotation.from_rotvec([[0.0, 0.0, 1.0]]), np.zeros((1, 3)))
    n = s.normals(s.lbs(m))
    np.testing.assert_allclose(n, rest @ m[0, :3, :3].T, atol=0.1)
    with pytest.raises(ValueError, match="faces"):
        Skinner(rest, joints, np.ones((len(rest), 1))).normals(rest)


# ---------------------------------------------------------------------------------------------
# bad input


def test_joint_out_of_range_is_named_at_the_first_call():
    rest, joints, weights, matrices = random_rig(9, V=20, k=2, J=4)
    joints[3, 1] = 4
    s = Skinner(rest, joints, weights)
    with pytest.raises(ValueError, match="joints"):
        s.lbs(matrices)
    with pytest.raises(ValueError, match="joints"):
        s.dqs(matrices)
    s.lbs(np.concatenate([matrices, np.eye(4)[None]]))  # five matrices cover index 4


@pytest.mark.parametrize("value", [np.nan, -0.1, np.inf])
def test_bad_weights_are_rejected(value):
    rest, joints, weights, _ = random_rig(9, V=20, k=2, J=4)
    weights[5, 0] = value
    with pytest.raises(ValueError, match="weights"):
        Skinner(rest, joints, weights)


@pytest.mark.parametrize("case, name", [
    ("negative joint", "joints"), ("float joints", "joints"), ("rest shape", "rest"),
    ("weights shape", "weights"), ("zero row", "weights"), ("nan rest", "rest"),
])
def test_bad_model_is_rejected_by_name(case, name):
    rest, joints, weights, _ = random_rig(9, V=20, k=2, J=4)
    if case == "negative joint":
        joints[0, 0] = -1
    elif case == "float joints":
        joints = joints.astype(float)
    elif case == "rest shape":
        rest = rest[:, :2]
    elif case == "weights shape":
        weights = weights[:, :1]
    elif case == "zero row":
        weights[2] = 0.0
    elif case == "nan rest":
        rest[1, 1] = np.nan
    with pytest.raises(ValueError, match=name):
        Skinner(rest, joints, weights)


def test_bad_matrices_and_method_are_rejected():
    rest, joints, weights, matrices = random_rig(9, V=20, k=2, J=4)
    s = Skinner(rest, joints, weights)
    with pytest.raises(ValueError, match="matrices"):
        s.lbs(matrices[:, :3])
    bad = matrices.copy()
    bad[2, 0, 0] = np.nan
    with pytest.raises(ValueError, match="matrices"):
        s.dqs(bad)
    with pytest.raises(ValueError, match="method"):
        s.skin(matrices, method="cor")


# ---------------------------------------------------------------------------------------------
# candy wrapper: a twisted forearm


def capped_cylinder(radius=0.04, length=0.3, rings=41, segments=32):
    """Closed cylinder along +x from 0 to length, outward-facing triangles.

    Returns positions (V, 3) metres and faces (F, 3) int: rings x segments side vertices, then
    the two cap centres.
    """
    x = np.linspace(0.0, length, rings)
    a = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    side = np.stack(np.broadcast_arrays(x[:, None], radius * np.cos(a), radius * np.sin(a)), -1)
    positions = np.concatenate([side.reshape(-1, 3), [[0.0, 0.0, 0.0], [length, 0.0, 0.0]]])
    idx = np.arange(rings * segments).reshape(rings, segments)
    nxt = np.roll(idx, -1, axis=1)
    # walking +x then +angle: (i, j) -> (i+1, j) -> (i+1, j+1) turns outward (right-handed about x)
    quads_a = np.stack([idx[:-1], nxt[:-1], nxt[1:]], -1).reshape(-1, 3)
    quads_b = np.stack([idx[:-1], nxt[1:], idx[1:]], -1).reshape(-1, 3)
    c0, c1 = rings * segments, rings * segments + 1
    cap0 = np.stack([np.full(segments, c0), nxt[0], idx[0]], -1)
    cap1 = np.stack([np.full(segments, c1), idx[-1], nxt[-1]], -1)
    return positions, np.concatenate([quads_a, quads_b, cap0, cap1])


def enclosed_volume(positions, faces) -> float:
    """Signed volume of a closed triangle mesh, sum of p0 . (p1 x p2) / 6 (divergence theorem)."""
    p = positions[faces].astype(np.float64)
    return float(np.sum(np.einsum("fi,fi->f", p[:, 0], np.cross(p[:, 1], p[:, 2]))) / 6.0)


def twist_matrices(degrees: float, wrist=0.15) -> np.ndarray:
    """Elbow (joint 0) at rest; wrist (joint 1) twisted about the bone axis x through x = wrist."""
    twist = np.eye(4)
    twist[:3, :3] = Rotation.from_rotvec([np.radians(degrees), 0.0, 0.0]).as_matrix()
    to_wrist, back = np.eye(4), np.eye(4)
    to_wrist[0, 3], back[0, 3] = wrist, -wrist
    return np.stack([np.eye(4), to_wrist @ twist @ back])


def forearm():
    positions, faces = capped_cylinder()
    # the wrist's weight rises smoothly (smoothstep) across the middle half of the forearm
    s = np.clip((positions[:, 0] - 0.075) / 0.15, 0.0, 1.0)
    w1 = s * s * (3.0 - 2.0 * s)
    joints = np.tile([0, 1], (len(positions), 1))
    weights = np.stack([1.0 - w1, w1], axis=1)
    return positions, faces, joints, weights


def test_closed_cylinder_volume_is_right():
    positions, faces = capped_cylinder()
    # a 32-gon prism: area (n/2) r^2 sin(2 pi / n) times the length
    expected = 16 * 0.04 ** 2 * np.sin(2 * np.pi / 32) * 0.3
    assert enclosed_volume(positions, faces) == pytest.approx(expected, rel=1e-9)
    n = vertex_normals(positions, faces)
    side = np.abs(positions[:, 0] - 0.15) < 0.1
    radial = positions[side] * [0.0, 1.0, 1.0] / 0.04
    np.testing.assert_allclose(n[side], radial, atol=1e-9)  # outward


def lbs_twist_volume_ratio(degrees: float) -> float:
    """LBS volume / rest volume predicted for forearm(): a ring with wrist weight w maps by
    (1 - w) I + w R(theta) in its plane, a scaled rotation with area factor
    |1 - w + w e^(i theta)|^2 = 1 - 2 w (1 - w) (1 - cos theta); averaged along the length."""
    s = np.clip((np.linspace(0.0, 0.3, 100001) - 0.075) / 0.15, 0.0, 1.0)
    w = s * s * (3.0 - 2.0 * s)
    return float(np.mean(1.0 - 2.0 * w * (1.0 - w) * (1.0 - np.cos(np.radians(degrees)))))


@pytest.mark.parametrize("degrees", [150.0, 180.0])
def test_twisted_forearm_lbs_collapses_and_dqs_keeps_volume(degrees):
    positions, faces, joints, weights = forearm()
    s = Skinner(positions, joints, weights, faces=faces)
    m = twist_matrices(degrees)
    v0 = enclosed_volume(positions, faces)
    lbs_pose, dqs_pose = s.lbs(m), s.dqs(m)
    lbs = enclosed_volume(lbs_pose, faces) / v0
    dqs = enclosed_volume(dqs_pose, faces) / v0
    predicted = lbs_twist_volume_ratio(degrees)
    message = (f"twist {degrees:.0f} deg: volume / rest volume LBS {lbs:.3f} (predicted "
               f"{predicted:.3f}), DQS {dqs:.4f}")
    print(message)
    # measured on this mesh: LBS 0.759 (150 deg), 0.742 (180 deg); DQS 0.996, 0.995 (the facets
    # between twisted rings cut a little volume, less with finer rings)
    assert lbs < 0.8, message
    assert abs(lbs - predicted) < 0.005, message
    assert abs(dqs - 1.0) < 0.01, message
    # the candy wrapper itself: the middle ring (w = 1/2) shrinks to |cos(theta / 2)| under LBS
    middle = np.abs(positions[:, 0] - 0.15) < 1e-9
    assert middle.sum() == 32
    lbs_r = np.linalg.norm(lbs_pose[middle, 1:], axis=1)
    dqs_r = np.linalg.norm(dqs_pose[middle, 1:], axis=1)
    np.testing.assert_allclose(lbs_r, 0.04 * abs(np.cos(np.radians(degrees) / 2)), atol=1e-6)
    np.testing.assert_allclose(dqs_r, 0.04, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# normals


def icosphere(subdivisions: int):
    """Unit icosphere: positions (V, 3) on the sphere, outward faces (F, 3)."""
    t = (1.0 + 5 ** 0.5) / 2.0
    p = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
         [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    positions = [np.array(v, float) / np.linalg.norm(v) for v in p]
    faces = f
    for _ in range(subdivisions):
        mid, out = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                m = positions[a] + positions[b]
                positions.append(m / np.linalg.norm(m))
                mid[key] = len(positions) - 1
            return mid[key]

        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            out += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = out
    return np.array(positions), np.array(faces)


def test_icosphere_normals_point_outward():
    positions, faces = icosphere(3)
    n = vertex_normals(positions * 0.5, faces)
    # on a symmetric subdivision the area-weighted normal lies within a degree of the radius
    cos = np.sum(n * positions, axis=1)
    assert cos.min() > np.cos(np.radians(1.0)), f"worst angle {np.degrees(np.arccos(cos.min()))}"
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)


def test_flat_quad_normals_are_up():
    positions = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(vertex_normals(positions, faces), np.tile([0.0, 0.0, 1.0], (4, 1)))
    down = vertex_normals(positions, faces[:, ::-1])
    np.testing.assert_allclose(down, np.tile([0.0, 0.0, -1.0], (4, 1)))


def test_normals_weight_faces_by_area():
    # vertex 0 touches a large face in the z = 0 plane and a small one in the x = 0 plane
    positions = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 0.1], [0, 0.1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    n = vertex_normals(positions, faces)[0]
    expected = np.array([-0.01, 0.0, 4.0])  # the raw cross products, twice the areas
    np.testing.assert_allclose(n, expected / np.linalg.norm(expected), atol=1e-12)


def test_degenerate_and_unused_vertices_get_the_fallback_not_nan():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2], [3, 3, 3], [5, 5, 5],
                          [9, 9, 9]], float)
    faces = np.array([[0, 1, 2], [3, 4, 5], [3, 3, 4]])  # a collinear and a repeated-index face
    n = vertex_normals(positions, faces)
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (7, 1)))  # (0,0,1) is also the fallback
    collapsed = vertex_normals(np.zeros((3, 3), np.float32), [[0, 1, 2]])
    assert collapsed.dtype == np.float32 and np.all(np.isfinite(collapsed))


def test_batched_normals_equal_per_frame():
    positions, faces = icosphere(2)
    rng = np.random.default_rng(0)
    frames = positions[None] * rng.uniform(0.5, 2.0, size=(5, 1, 3))
    normals = VertexNormals(faces, len(positions))
    batched = normals(frames)
    assert batched.shape == frames.shape
    for f in range(5):
        np.testing.assert_allclose(batched[f], normals(frames[f]), atol=1e-12)
    assert not np.allclose(batched[0], batched[1])


def test_bad_faces_are_rejected():
    with pytest.raises(ValueError, match="faces"):
        VertexNormals([[0, 1, 5]], 5)
    with pytest.raises(ValueError, match="positions"):
        VertexNormals([[0, 1, 2]], 3)(np.zeros((4, 3)))


# ---------------------------------------------------------------------------------------------
# normalise_weights


def test_normalise_weights_keeps_the_largest_sorted():
    joints = np.array([[3, 1, 4, 1, 5, 9], [2, 6, 5, 3, 5, 8]])
    weights = np.array([[0.1, 0.5, 0.05, 0.2, 0.3, 0.0], [1.0, 0.0, 0.0, 2.0, 0.0, 0.0]])
    j, w = normalise_weights(joints, weights, k=3)
    assert j.dtype == np.int32 and w.dtype == np.float32
    np.testing.assert_array_equal(j, [[1, 5, 1], [3, 2, 0]])
    np.testing.assert_allclose(w, [[0.5 / 1.0, 0.3 / 1.0, 0.2 / 1.0], [2 / 3, 1 / 3, 0.0]],
                               rtol=1e-6)


def test_normalise_weights_pads_with_joint_zero():
    j, w = normalise_weights([[7], [2]], [[2.0], [0.5]], k=4)
    np.testing.assert_array_equal(j, [[7, 0, 0, 0], [2, 0, 0, 0]])
    np.testing.assert_array_equal(w, [[1, 0, 0, 0], [1, 0, 0, 0]])


def test_normalise_weights_rejects_all_zero_rows():
    with pytest.raises(ValueError, match="2 vertices"):
        normalise_weights([[0, 1], [1, 2], [2, 3]], [[0.0, 0.0], [0.5, 0.5], [0.0, 0.0]])
    with pytest.raises(ValueError, match="weights"):
        normalise_weights([[0, 1]], [[np.nan, 1.0]])


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 8), st.integers(1, 6), st.integers(0, 2 ** 32 - 1))
def test_normalise_weights_properties(m, k, seed):
    rng = np.random.default_rng(seed)
    weights = rng.random((30, m)) * (rng.random((30, m)) < 0.7)
    weights[:, 0] += 0.01  # no all-zero rows
    joints = rng.integers(0, 50, size=(30, m))
    j, w = normalise_weights(joints, weights, k=k)
    assert j.shape == w.shape == (30, k)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)
    assert np.all(np.diff(w, axis=1) <= 0.0)
    kept = min(k, m)
    top = -np.sort(-weights, axis=1)[:, :kept]
    np.testing.assert_allclose(w[:, :kept], top / top.sum(axis=1, keepdims=True), rtol=1e-5)
    for v in range(30):  # every kept joint carries the weight it had
        for i in range(kept):
            if w[v, i] > 0:
                assert np.any((joints[v] == j[v, i]) & (weights[v] == top[v, i]))


def test_vertex_normals_batch_equals_numpy():
    """The Warp gather (what the bake's USD writer uses) gives the NumPy normals, the fallback
    included, for a deforming sphere with a vertex no face touches."""
    import trimesh

    from jiggle.rig.character.normals import FALLBACK, VertexNormals
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v = np.vstack([sphere.vertices, [[5.0, 5.0, 5.0]]])            # the last vertex is in no face
    rng = np.random.default_rng(3)
    frames = (v[None] * (1.0 + 0.2 * rng.standard_normal((6, 1, 3)))).astype(np.float32)
    vn = VertexNormals(sphere.faces, len(v))
    got = vn.batch(frames)
    np.testing.assert_allclose(got, vn(frames), atol=1e-6)
    np.testing.assert_array_equal(got[:, -1], np.broadcast_to(FALLBACK, (6, 3)))
    assert np.all(np.einsum("tvi,tvi->tv", got[:, :-1], frames[:, :-1]) > 0)   # outward on a convex mesh
