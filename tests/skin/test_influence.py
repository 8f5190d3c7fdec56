"""Influence-object skinning (rig/skin/influence.py, rig/skin/influence_kernels.py).

Reference equations (rig/skin/influence.py's docstring): at bind each (vertex, muscle) pair gets its foot
point (w, v) on the muscle's smooth loft X and its offset o = p - X(w, v) in the frame
e1 = unit(X_w), n = unit(X_v x X_w), e2 = n x e1; per frame
    p' = p + sum_pairs weight * (attach(cvs_cur) - attach(cvs_ref)),  attach = X + F^T offset.
The Warp kernel runs in float32 on positions of ~0.5 m, so it matches the float64 reference to
~1e-7 m; the 1e-5 m tolerance leaves room for harder random draws.
"""
from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from arm_muscles import ARM_BIND, arm_world, biceps, brachio
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.loft_attach import bind_influence, closest_points, loft_frame, muscle_eps
from jiggle.rig.muscle.model import build_muscle_rig
from jiggle.rig.skin.influence import InfluenceDeformer, influence_numpy

TOL = 1e-5  # metres, float32 kernel against the float64 reference


# ---------------------------------------------------------------------------------- fixtures
def spheroid(length: float = 0.2, radius: float = 0.04) -> np.ndarray:
    """(5, 8, 3) CVs of a fusiform, sphere-like loft centred at 0 along +Z, in the orientation
    rig.muscle.model builds (sections from origin to insertion along T = +Z, v turning from the up
    vector U = +X toward S = T x U = +Y). Ring CVs sit at radius R / k so the B-spline ring passes at
    ~R: at v = j the ring is (CV[j-1] + 4 CV[j] + CV[j+1]) / 6 = k CV[j] radially, k = (4 + 2 cos 45) / 6."""
    z = np.linspace(-0.5, 0.5, loft.SECTIONS) * length
    profile = radius * np.sqrt(np.clip(1.0 - (1.8 * z / length) ** 2, 0.05, 1.0))
    theta = 2.0 * np.pi * np.arange(loft.RING) / loft.RING
    k = (4.0 + 2.0 * np.cos(2.0 * np.pi / loft.RING)) / 6.0
    X = np.zeros((loft.SECTIONS, loft.RING, 3))
    X[..., 0] = profile[:, None] / k * np.cos(theta)
    X[..., 1] = profile[:, None] / k * np.sin(theta)
    X[..., 2] = z[:, None]
    return X


def rigid(rotation: Rotation, translation) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation.as_matrix()
    m[:3, 3] = translation
    return m


def apply(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    return x @ m[:3, :3].T + m[:3, 3]


def carry(cvs: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Flat CVs (40 M, 3) with muscle m moved by transforms[m] (4, 4)."""
    return np.concatenate([apply(t, c) for t, c in zip(transforms, cvs.reshape(len(transforms), 40, 3))])


def random_setup(seed: int, V: int = 240, M: int = 3):
    """M spheroids placed around, V vertices on shells 0..6 cm outside them with 0..3 pairs (distinct
    muscles, ascending), random weights in [0, 1] with some exact 0 and 1."""
    rng = np.random.default_rng(seed)
    rots = Rotation.random(M, random_state=seed)
    place = np.stack([rigid(rots[m], rng.normal(scale=0.3, size=3)) for m in range(M)])
    rest_cvs = np.concatenate([apply(place[m], spheroid(0.15 + 0.1 * rng.random(), 0.02 + 0.03 * rng.random())
                                     .reshape(-1, 3)) for m in range(M)])
    counts = rng.integers(0, 4, size=V)
    counts = np.minimum(counts, M)
    muscles = [np.sort(rng.choice(M, size=c, replace=False)) for c in counts]
    home = np.array([m[0] if len(m) else rng.integers(M) for m in muscles])
    d = rng.normal(size=(V, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    local = d * np.array([0.05, 0.05, 0.12]) * (1.0 + rng.random((V, 1)))
    rest = np.stack([apply(place[h], x) for h, x in zip(home, local)])
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    pair_muscle = np.concatenate(muscles).astype(np.int64)
    weight = rng.random(len(pair_muscle))
    weight[rng.random(len(weight)) < 0.15] = 0.0
    weight[rng.random(len(weight)) < 0.15] = 1.0
    return rest, offsets, pair_muscle, weight, rest_cvs


@pytest.fixture(scope="module")
def arm_rig():
    return build_muscle_rig([biceps(), brachio()], ARM_BIND)


def carried_rest(rig, world: np.ndarray) -> np.ndarray:
    """Rest CVs carried rigidly by each muscle's bone (joint rig.joints[m, 8])."""
    bones = rig.joints[:, 8]
    return carry(rig.rest_cvs, world[bones] @ np.linalg.inv(ARM_BIND[bones]))


def arm_skin(n: int = 600) -> np.ndarray:
    """Points on a cylinder of radius 6 cm around the arm's axis (-Z), front half (the muscles' side)."""
    rng = np.random.default_rng(5)
    phi = rng.uniform(0.1, np.pi - 0.1, n)
    return np.stack([0.06 * np.cos(phi), 0.01 + 0.06 * np.sin(phi), rng.uniform(-0.45, -0.05, n)], axis=1)


# ---------------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("case", ["spheroid", "arm"])
def test_loft_frame_is_orthonormal_right_handed_and_outward(case, arm_rig):
    if case == "spheroid":
        Xs = [spheroid()]
    else:
        Xs = list(arm_rig.rest_cvs.reshape(-1, 5, 8, 3))
    w, v = np.meshgrid(np.linspace(0.2, 3.8, 9), np.arange(32) / 4.0, indexing="ij")
    w, v = w.ravel(), v.ravel()
    for X in Xs:
        W = [loft.surface_weights(w, v, dw, dv).reshape(len(w), 40) @ X.reshape(40, 3)
             for dw, dv in ((0, 0), (1, 0), (0, 1))]
        F = loft_frame(W[1], W[2], muscle_eps(X.reshape(40, 3)))
        np.testing.assert_allclose(F @ F.transpose(0, 2, 1), np.broadcast_to(np.eye(3), F.shape), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(F), 1.0, atol=1e-12)
        # outward: away from the centre of the ring through the point (the muscles are convex rings)
        centre = loft.section_weights(w) @ X.mean(axis=1)
        assert np.all(np.einsum("ni,ni->n", F[:, 2], W[0] - centre) > 0.0)


def brute_distance(p: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Distance of p to a 401 x 1600 sampling of the loft (w, v) (an upper bound of the true distance,
    over by at most ~h^2 / (8 d) for sample spacing h ~ 0.5 mm)."""
    w, v = np.meshgrid(np.linspace(0.0, 4.0, 401), np.arange(1600) / 200.0, indexing="ij")
    samples = loft.surface_weights(w.ravel(), v.ravel()).reshape(-1, 40) @ X.reshape(40, 3)
    return cKDTree(samples).query(p)[0]


def test_bind_attaches_at_the_closest_point():
    X = spheroid()
    rng = np.random.default_rng(1)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # surface point along d (roughly), then 5 mm .. 15 cm out: near and far (beyond the 2-4 cm
    # radius, where plain Gauss-Newton diverges), some beyond the ends (foot on an end ring)
    near = d * np.array([0.04, 0.04, 0.1])
    p = near + d * rng.uniform(0.005, 0.15, size=(400, 1))
    b = bind_influence(p, np.arange(401), np.zeros(400, np.int64), X.reshape(40, 3))
    truth = brute_distance(p, X)
    assert np.all(b.distance <= truth + 1e-12)
    assert np.all(b.distance >= truth - 1e-5)
    np.testing.assert_allclose(np.linalg.norm(b.offset, axis=1), b.distance, rtol=1e-12)
    inner = (b.w > 1e-9) & (b.w < 4.0 - 1e-9)
    assert inner.sum() > 250 and (~inner).sum() > 10
    # an interior foot point: the offset is along the outward normal only
    assert np.abs(b.offset[inner, :2]).max() < 1e-7
    np.testing.assert_allclose(b.offset[inner, 2], b.distance[inner], rtol=1e-9)
    # closest_points alone agrees and reports the same distance
    w, v, dist = closest_points(p, X)
    np.testing.assert_allclose(dist, b.distance, rtol=0, atol=1e-15)


def test_binding_basis_reproduces_the_loft():
    rest, off, mus, _, cvs = random_setup(2, V=60)
    b = bind_influence(rest, off, mus, cvs)
    # the kernel's tables (5 section weights x 4 ring weights from ring_first) are the loft's weights
    cols = (8 * np.arange(5)[None, :, None] + (b.ring_first[:, None, None] + np.arange(4)) % 8).reshape(len(b.w), -1)
    for dw, dv, sec, ring in ((0, 0, b.section, b.ring), (1, 0, b.section_dw, b.ring), (0, 1, b.section, b.ring_dv)):
        sparse = np.zeros((len(b.w), 40))
        np.put_along_axis(sparse, cols, (sec[:, :, None] * ring[:, None]).reshape(len(b.w), -1), axis=1)
        np.testing.assert_allclose(sparse, loft.surface_weights(b.w, b.v, dw, dv).reshape(-1, 40), atol=1e-14)
    full = loft.surface_weights(b.w, b.v).reshape(-1, 40)
    # the attachment at bind is the vertex itself
    vertex = np.repeat(np.arange(len(rest)), np.diff(off))
    pts = np.einsum("nc,ncx->nx", full, cvs.reshape(-1, 40, 3)[mus])
    Wd = [loft.surface_weights(b.w, b.v, dw, dv).reshape(-1, 40) for dw, dv in ((1, 0), (0, 1))]
    xw, xv = (np.einsum("nc,ncx->nx", W, cvs.reshape(-1, 40, 3)[mus]) for W in Wd)
    attach = pts + np.einsum("nij,ni->nj", loft_frame(xw, xv, b.muscle_eps[mus]), b.offset)
    np.testing.assert_allclose(attach, rest[vertex], atol=1e-14)


# ---------------------------------------------------------------------------------- deformation
def test_rest_gives_exactly_zero_displacement():
    rest, off, mus, wgt, cvs = random_setup(3)
    b = bind_influence(rest, off, mus, cvs)
    dev = InfluenceDeformer(b, off, mus, wgt, num_muscles=3)
    # the bones moved (LBS did its part): the reference CVs are carried; the muscles sit at rest on them
    moved = np.stack([rigid(Rotation.random(random_state=s), (0.1 * s, 0.2, -0.1)) for s in range(3)])
    ref = carry(cvs, moved)
    skin = np.random.default_rng(0).normal(size=rest.shape).astype(np.float32)
    np.testing.assert_array_equal(influence_numpy(skin, b, off, mus, wgt, ref, ref), skin)
    np.testing.assert_array_equal(dev.deform(skin, ref, ref), skin)


@pytest.mark.parametrize("weight", [1.0, 0.5])
def test_rigid_motion_relative_to_the_bone_carries_the_vertices(weight):
    """Muscle m's CVs are carried by its bone B_m (the reference) and moved on by T_m; a vertex paired
    with one muscle at weight 1 goes from B v to T B v, at weight 0.5 halfway for a translation."""
    rest, off, mus, _, cvs = random_setup(4, V=300)
    one = np.diff(off) == 1
    off1 = np.arange(one.sum() + 1)                          # keep single-pair vertices only
    mus1 = mus[off[:-1][one]]
    rest1 = rest[one]
    b = bind_influence(rest1, off1, mus1, cvs)
    wgt = np.full(len(mus1), weight)
    rng = np.random.default_rng(7)
    bone = np.stack([rigid(Rotation.random(random_state=10 + m), rng.normal(scale=0.2, size=3)) for m in range(3)])
    if weight == 1.0:
        T = np.stack([rigid(Rotation.random(random_state=20 + m), rng.normal(scale=0.05, size=3)) for m in range(3)])
    else:
        T = np.stack([rigid(Rotation.identity(), rng.normal(scale=0.05, size=3)) for m in range(3)])
    ref = carry(cvs, bone)
    cur = carry(cvs, T @ bone)
    skin = np.stack([apply(bone[m], x) for m, x in zip(mus1, rest1)])         # LBS by the bone
    carried = np.stack([apply(T[m] @ bone[m], x) for m, x in zip(mus1, rest1)])
    expected = skin + weight * (carried - skin)
    np.testing.assert_allclose(influence_numpy(skin, b, off1, mus1, wgt, cur, ref), expected, atol=1e-12)
    dev = InfluenceDeformer(b, off1, mus1, wgt, num_muscles=3)
    np.testing.assert_allclose(dev.deform(skin, cur, ref), expected, atol=TOL)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_matches_numpy(seed):
    rest, off, mus, wgt, cvs = random_setup(10 + seed)
    b = bind_influence(rest, off, mus, cvs)
    rng = np.random.default_rng(seed)
    bone = np.stack([rigid(Rotation.random(random_state=30 + m), rng.normal(scale=0.2, size=3)) for m in range(3)])
    ref = carry(cvs, bone)
    # the muscles bulge and wobble: smooth scaling plus per-CV noise, then a small rigid drift
    cur = carry(cvs * (1.0 + 0.2 * rng.random((len(cvs), 1))) + rng.normal(scale=0.01, size=cvs.shape),
                np.stack([rigid(Rotation.from_rotvec(rng.normal(scale=0.2, size=3)), rng.normal(scale=0.03, size=3))
                          for _ in range(3)]) @ bone)
    skin = rest + rng.normal(scale=0.02, size=rest.shape)
    expected = influence_numpy(skin, b, off, mus, wgt, cur, ref)
    assert np.abs(expected - skin).max() > 0.01          # the motion is not trivial
    dev = InfluenceDeformer(b, off, mus, wgt, num_muscles=3)
    np.testing.assert_allclose(dev.deform(skin, cur, ref), expected, atol=TOL)
    # launch on device buffers (the Skinner's output) returns the wrapper's reused buffer
    out = dev.launch(wp.array(skin.astype(np.float32), dtype=wp.vec3), cur, ref)
    assert out is dev.launch(wp.array(skin.astype(np.float32), dtype=wp.vec3), cur, ref)
    np.testing.assert_allclose(out.numpy(), expected, atol=TOL)
    # vertices without pairs are passed through untouched
    empty = np.diff(off) == 0
    assert empty.any()
    np.testing.assert_array_equal(out.numpy()[empty], skin[empty].astype(np.float32))


def test_reach_limits_each_pair_like_the_shells():
    """With a reach per muscle the kernel equals the NumPy reference with the shells' limit, and no
    pair moves its vertex farther than its weight x the reach."""
    rest, off, mus, wgt, cvs = random_setup(21)
    b = bind_influence(rest, off, mus, cvs)
    rng = np.random.default_rng(4)
    ref = cvs
    cur = cvs + np.repeat(rng.normal(scale=0.05, size=(3, 3)), 40, axis=0)     # each muscle slides ~5 cm
    reach = np.array([0.01, 0.02, 0.5])
    expected = influence_numpy(rest, b, off, mus, wgt, cur, ref, reach=reach)
    free = influence_numpy(rest, b, off, mus, wgt, cur, ref)
    dev = InfluenceDeformer(b, off, mus, wgt, num_muscles=3, reach=reach)
    np.testing.assert_allclose(dev.deform(rest, cur, ref), expected, atol=TOL)
    vertex = np.repeat(np.arange(len(rest)), np.diff(off))
    bound = np.zeros(len(rest))
    np.add.at(bound, vertex, wgt * reach[mus])
    assert np.all(np.linalg.norm(expected - rest, axis=1) <= bound + 1e-9)
    assert np.abs(expected - free).max() > 0.005                                  # the limit does bind
    with pytest.raises(InputError, match="reaches"):
        InfluenceDeformer(b, off, mus, wgt, num_muscles=3, reach=[0.1, -1.0, 0.1])


def test_displacement_is_continuous_in_the_cvs():
    """D(cvs + e d) - D(cvs) = e J d + O(e^2): the change is linear in a small CV step (ratio 2 between
    steps 2e and e to ~e) and bounded by a modest multiple of the step."""
    rest, off, mus, wgt, cvs = random_setup(5)
    b = bind_influence(rest, off, mus, cvs)
    rng = np.random.default_rng(9)
    cur = cvs + rng.normal(scale=0.005, size=cvs.shape)
    d = rng.normal(size=cvs.shape)
    d /= np.abs(d).max()
    base = influence_numpy(rest, b, off, mus, wgt, cur, cvs)
    eps = 1e-5
    one = influence_numpy(rest, b, off, mus, wgt, cur + eps * d, cvs) - base
    two = influence_numpy(rest, b, off, mus, wgt, cur + 2 * eps * d, cvs) - base
    assert np.abs(one).max() < 20 * eps
    np.testing.assert_allclose(two, 2 * one, atol=1e-3 * eps * 20)


def test_collapsed_cvs_warn_and_stay_finite():
    X = spheroid()
    X[0] = X[0].mean(axis=0)        # origin ring collapsed to a point: no normal there
    p = np.array([[0.0, 0.0, -0.2], [0.06, 0.0, 0.0]])       # beyond the collapsed end; beside the belly
    with pytest.warns(JiggleWarning, match="muscle 'flat' \\(0\\): 1"):
        b = bind_influence(p, np.array([0, 1, 2]), np.array([0, 0]), X.reshape(40, 3), names=["flat"])
    assert np.isfinite(b.offset).all()
    dev = InfluenceDeformer(b, [0, 1, 2], [0, 0], [1.0, 1.0], num_muscles=1)
    cur = np.tile(X.reshape(40, 3).mean(axis=0), (40, 1))   # every CV at one point: no frame at all
    for c in (X.reshape(40, 3) * 1.1, cur):
        out = dev.deform(p, c, X.reshape(40, 3))
        assert np.isfinite(out).all()
        np.testing.assert_allclose(out, influence_numpy(p, b, [0, 1, 2], [0, 0], [1.0, 1.0], c, X.reshape(40, 3)),
                                   atol=TOL)


def test_arm_rig_at_bind_and_flexed(arm_rig):
    """Skin around the arm paired with every muscle within 5 cm: nothing moves at bind; with the elbow
    flexed, the muscles' change beyond their bones moves the skin by a bounded amount, kernel == NumPy."""
    rig = arm_rig
    skin = arm_skin()
    surf = rig.surface(rig.rest_cvs)
    near = np.stack([cKDTree(surf[m]).query(skin)[0] < 0.05 for m in range(rig.M)], axis=1)   # (V, M)
    off = np.concatenate([[0], np.cumsum(near.sum(axis=1))])
    mus = np.nonzero(near)[1]
    wgt = np.full(len(mus), 0.8)
    b = bind_influence(skin, off, mus, rig.rest_cvs, names=rig.names)
    inner = (b.w > 0.1) & (b.w < 3.9)
    assert inner.sum() > 100 and np.all(b.offset[inner, 2] > 0.0)     # skin outside: outward normal
    dev = InfluenceDeformer(b, off, mus, wgt, rig.M, names=rig.names)
    at_bind = rig.static(ARM_BIND).cvs
    assert np.abs(influence_numpy(skin, b, off, mus, wgt, at_bind, carried_rest(rig, ARM_BIND)) - skin).max() < 1e-12
    np.testing.assert_array_equal(dev.deform(skin, at_bind, carried_rest(rig, ARM_BIND)), skin.astype(np.float32))
    world = arm_world(100.0)
    cur, ref = rig.static(world).cvs, carried_rest(rig, world)
    lbs = np.where((skin[:, 2] > -UPPER_SPLIT)[:, None], skin, apply(world[1] @ np.linalg.inv(ARM_BIND[1]), skin))
    expected = influence_numpy(lbs, b, off, mus, wgt, cur, ref)
    moved = np.linalg.norm(expected - lbs, axis=1)
    assert 0.005 < moved.max() < 0.3     # the brachio crosses the elbow: up to ~a forearm's reach
    np.testing.assert_allclose(dev.deform(lbs, cur, ref), expected, atol=TOL)


UPPER_SPLIT = 0.30    # metres: skin above the elbow rides the upper arm, below it the forearm


# ---------------------------------------------------------------------------------- errors
def _pairs():
    rest, off, mus, wgt, cvs = random_setup(6, V=20)
    return rest, off, mus, wgt, cvs


@pytest.mark.parametrize("case, field", [
    ("rest_shape", "rest_vertices"), ("rest_nan", "rest_vertices"), ("cvs_count", "rest_cvs"),
    ("cvs_nan", "rest_cvs"), ("offsets_start", "pair_offsets"), ("offsets_decrease", "pair_offsets"),
    ("offsets_length", "pair_offsets"), ("muscle_range", "pair_muscle"), ("muscle_length", "pair_muscle"),
])
def test_bad_bind_input_is_named(case, field):
    rest, off, mus, _, cvs = _pairs()
    args = dict(rest_vertices=rest, pair_offsets=off, pair_muscle=mus, rest_cvs=cvs)
    if case == "rest_shape":
        args["rest_vertices"] = rest[:, :2]
    elif case == "rest_nan":
        args["rest_vertices"] = np.where(np.arange(len(rest))[:, None] == 3, np.nan, rest)
    elif case == "cvs_count":
        args["rest_cvs"] = cvs[:-1]
    elif case == "cvs_nan":
        bad = cvs.copy()
        bad[45, 1] = np.nan
        args["rest_cvs"] = bad
    elif case == "offsets_start":
        args["pair_offsets"] = off + 1
    elif case == "offsets_decrease":
        o = off.copy()
        o[5] = o[6] + 1
        args["pair_offsets"] = o
    elif case == "offsets_length":
        args["pair_offsets"] = off[:-1]
    elif case == "muscle_range":
        m = mus.copy()
        m[0] = 3
        args["pair_muscle"] = m
    elif case == "muscle_length":
        args["pair_muscle"] = mus[:-1]
    with pytest.raises(InputError) as e:
        bind_influence(**args, names=["a", "b", "c"])
    assert e.value.field == field
    if case == "cvs_nan":
        assert "muscle 'b' (1)" in str(e.value)


@pytest.mark.parametrize("value", [1.5, -0.1, np.nan])
def test_bad_weights_are_rejected(value):
    rest, off, mus, wgt, cvs = _pairs()
    b = bind_influence(rest, off, mus, cvs)
    bad = wgt.copy()
    bad[2] = value
    with pytest.raises(InputError) as e:
        InfluenceDeformer(b, off, mus, bad, num_muscles=3)
    assert e.value.field == "pair_weight" and "pairs [2]" in str(e.value)
    with pytest.raises(InputError) as e:
        InfluenceDeformer(b, off, mus, wgt[:-1], num_muscles=3)
    assert e.value.field == "pair_weight"


def test_bad_frame_input_is_named():
    rest, off, mus, wgt, cvs = _pairs()
    b = bind_influence(rest, off, mus, cvs)
    dev = InfluenceDeformer(b, off, mus, wgt, num_muscles=3, names=["a", "b", "c"])
    bad = cvs.copy()
    bad[85] = np.inf                     # muscle 2
    with pytest.raises(InputError, match="muscle 'c' \\(2\\)") as e:
        dev.deform(rest, bad, cvs)
    assert e.value.field == "cvs_cur"
    with pytest.raises(InputError) as e:
        dev.deform(rest, cvs, cvs[:80])
    assert e.value.field == "cvs_ref"
    with pytest.raises(InputError) as e:
        dev.deform(rest[:-1], cvs, cvs)
    assert e.value.field == "points"
    with pytest.raises(InputError) as e:
        dev.launch(rest, cvs, cvs)       # a NumPy array where a device buffer is expected
    assert e.value.field == "points"
    with pytest.raises(InputError) as e:
        InfluenceDeformer(b, off, mus, wgt, num_muscles=2)     # muscle index 2 out of range
    assert e.value.field == "pair_muscle"
    with pytest.raises(InputError) as e:
        InfluenceDeformer(b, off, mus, wgt, num_muscles=4)     # the binding knows 3
    assert e.value.field == "num_muscles"
    other = bind_influence(rest[:5], off[:6], mus[:off[5]], cvs)
    with pytest.raises(InputError) as e:
        InfluenceDeformer(other, off, mus, wgt, num_muscles=3)
    assert e.value.field == "binding"


def test_no_vertices_and_no_pairs():
    cvs = spheroid().reshape(40, 3)
    b = bind_influence(np.zeros((0, 3)), [0], np.zeros(0, np.int64), cvs)
    dev = InfluenceDeformer(b, [0], np.zeros(0, np.int64), np.zeros(0), num_muscles=1)
    assert dev.deform(np.zeros((0, 3)), cvs, cvs).shape == (0, 3)
    p = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]])
    b = bind_influence(p, [0, 0, 0], np.zeros(0, np.int64), cvs)
    dev = InfluenceDeformer(b, [0, 0, 0], np.zeros(0, np.int64), np.zeros(0), num_muscles=1)
    np.testing.assert_array_equal(dev.deform(p, cvs + 0.1, cvs), p.astype(np.float32))
