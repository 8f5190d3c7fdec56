"""Batched skinning for the bake: MuscleSkin.pose_batch / lbs_batch (rig/skin/muscle_skin.py), the batched
launches under them (Skinner.skin_batch / launch_batch in rig/skin/skinning.py, ShellDeformer.launch_batch in
rig/skin/shell/deformer.py) and MuscleFrames.frame_sets (rig/skin/shell/frames.py).

A batch must equal the frame-by-frame calls: set s at frame t of pose_batch is
pose(world[t], cvs_sets[s][t], curves[s][t], frame=first_frame + t) to float32 rounding (contract:
1e-6 m); the batched kernels run the same per-vertex code as the single-frame ones, so the difference
is in practice 0. The kernels are also compared with the float64 NumPy references on random inputs.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import warp as wp
from conftest import asset
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.muscle.shell_params import MODES, ShellParams
from jiggle.rig.muscle.simple_arm import simple_arm
from jiggle.rig.skin.muscle_skin import MuscleSkin
from jiggle.rig.skin.shell.deformer import ShellBatch, ShellDeformer
from jiggle.rig.skin.shell.shells import ShellFrames, shell_numpy, shell_table
from jiggle.rig.skin.skinning import Skinner, dqs_numpy, lbs_numpy

TOL = 1e-6          # metres: batch against loop (the contract's bound)
REF_TOL = 1e-5      # metres: float32 kernels against the float64 NumPy references, scenes ~1 m across


def rigid(rng, J: int) -> np.ndarray:
    m = np.tile(np.eye(4), (J, 1, 1))
    m[:, :3, :3] = Rotation.random(J, random_state=rng.integers(1 << 30)).as_matrix()
    m[:, :3, 3] = rng.normal(scale=0.3, size=(J, 3))
    return m


def loop(skin: MuscleSkin, world, cvs, curve, first_frame=0) -> np.ndarray:
    """(T, V, 3): pose frame by frame, the reference a batch must equal."""
    return np.stack([skin.pose(world[t], cvs[t], curve[t], frame=first_frame + t) for t in range(len(world))])


# ---------------------------------------------------------------------------------- simple arm
@pytest.fixture(scope="module")
def arm():
    return simple_arm()


@pytest.fixture(scope="module")
def skins(arm):
    return {(mode, method): MuscleSkin(arm.character, arm.rig, skinning=mode, method=method)
            for mode in ("shell", "influence") for method in ("lbs", "dqs")}


def sweep(arm, T: int = 12, seed: int = 0):
    """An elbow sweep 0 -> 110 deg: world (T, J, 4, 4), static CVs (T, N, 3) and curves (T, M, 5, 3),
    and a 'blended' set: the static CVs plus a smooth bulge-and-slide of a few mm (a jiggle's size)."""
    world = arm.world(np.linspace(0.0, 110.0, T))
    static = arm.rig.static(world)
    rng = np.random.default_rng(seed)
    wobble = 0.004 * np.sin(np.linspace(0.0, 3.0, T))[:, None, None] * rng.normal(size=(1,) + static.cvs.shape[1:])
    return world, static.cvs, static.curve, static.cvs + wobble


@pytest.mark.parametrize("mode", ["shell", "influence"])
@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_pose_batch_equals_pose_frame_by_frame(arm, skins, mode, method):
    skin = skins[mode, method]
    world, cvs, curve, blended = sweep(arm)
    out = skin.pose_batch(world, [cvs, blended], [curve, curve], first_frame=40)
    assert len(out) == 2
    for got, c in zip(out, (cvs, blended)):
        assert got.shape == (len(world), arm.character.num_vertices, 3) and got.dtype == np.float32
        assert np.abs(got - loop(skin, world, c, curve, 40)).max() <= TOL
    # the blended set really moves the skin, so equality is not trivially 0 == 0
    assert np.abs(out[1] - out[0]).max() > 1e-4
    assert np.abs(out[0] - skin.lbs_batch(world)).max() > 1e-3


@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_lbs_batch_equals_lbs_frame_by_frame(arm, skins, method):
    skin = skins["shell", method]
    world = arm.world(np.linspace(0.0, 130.0, 9))
    got = skin.lbs_batch(world)
    assert got.shape == (9, arm.character.num_vertices, 3) and got.dtype == np.float32
    assert np.abs(got - np.stack([skin.lbs(w) for w in world])).max() <= TOL


def test_one_set_and_none_for_the_static_shape(arm, skins):
    """S = 1 works, and None (CVs or curve) means the static shape for `world`, as in pose."""
    skin = skins["shell", "lbs"]
    world, cvs, curve, _ = sweep(arm, T=5)
    (got,) = skin.pose_batch(world, [None], [None])
    assert np.abs(got - np.stack([skin.pose(w) for w in world])).max() <= TOL
    (mixed,) = skin.pose_batch(world, [cvs], [None])
    np.testing.assert_array_equal(mixed, got)


def test_results_are_new_arrays(arm, skins):
    """The returned arrays are not views of the reused device buffers: the next call leaves them alone."""
    skin = skins["shell", "lbs"]
    world, cvs, curve, blended = sweep(arm, T=4)
    a, b = skin.pose_batch(world, [cvs, blended], [curve, curve])
    keep = a.copy(), b.copy()
    lbs = skin.lbs_batch(world)
    lbs_keep = lbs.copy()
    skin.pose_batch(world[::-1], [blended[::-1], cvs[::-1]], [curve[::-1], curve[::-1]])
    skin.lbs_batch(world[::-1])
    np.testing.assert_array_equal(a, keep[0])
    np.testing.assert_array_equal(b, keep[1])
    np.testing.assert_array_equal(lbs, lbs_keep)
    assert not np.shares_memory(a, b)


def test_chunks_of_any_size_agree(arm, skins):
    """The bake's chunks: one batch of T frames equals batches of 1, 3 and the rest (buffers resized)."""
    skin = skins["shell", "lbs"]
    world, cvs, curve, blended = sweep(arm, T=10)
    whole = skin.pose_batch(world, [cvs, blended], [curve, curve])
    parts = [skin.pose_batch(world[a:b], [cvs[a:b], blended[a:b]], [curve[a:b], curve[a:b]], first_frame=a)
             for a, b in ((0, 1), (1, 4), (4, 10))]
    for s in range(2):
        np.testing.assert_array_equal(np.concatenate([p[s] for p in parts]), whole[s])
    empty = skin.pose_batch(world[:0], [cvs[:0]], [curve[:0]])
    assert empty[0].shape == (0, arm.character.num_vertices, 3)
    assert skin.lbs_batch(world[:0]).shape == (0, arm.character.num_vertices, 3)


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_skipped_muscle_warns_naming_muscle_and_frame(arm, skins, mode):
    """NaN CVs of the biceps at one frame of the blended set: a JiggleWarning names the muscle and the
    frame (first_frame + batch index); the skin there follows the bones, no NaN, and both sets still
    equal the frame-by-frame poses (which warn the same)."""
    skin = skins[mode, "lbs"]
    world, cvs, curve, blended = sweep(arm, T=6)
    blended = blended.copy()
    blended[3, 5] = np.nan
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = skin.pose_batch(world, [cvs, blended], [curve, curve], first_frame=100)
    msgs = [str(c.message) for c in caught if issubclass(c.category, JiggleWarning)]
    assert len(msgs) == 1 and "biceps" in msgs[0] and "103" in msgs[0], msgs
    assert all(np.isfinite(o).all() for o in out)
    np.testing.assert_allclose(out[1][3], skin.lbs(world[3]), atol=TOL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        for got, c in zip(out, (cvs, blended)):
            assert np.abs(got - loop(skin, world, c, curve, 100)).max() <= TOL


def test_collapsed_muscle_is_skipped_in_its_set_only(arm, skins):
    skin = skins["shell", "lbs"]
    world, cvs, curve, _ = sweep(arm, T=3)
    flat = cvs.copy()
    flat[1] = flat[1].mean(axis=0)
    with pytest.warns(JiggleWarning, match=r"frame 1: muscle 'biceps' skipped: collapsed"):
        static, collapsed = skin.pose_batch(world, [cvs, flat], [curve, curve])
    np.testing.assert_allclose(collapsed[1], skin.lbs(world[1]), atol=TOL)
    assert np.abs(static[1] - skin.lbs(world[1])).max() > 1e-3


def test_bad_batches_are_named(arm, skins):
    skin = skins["shell", "lbs"]
    world, cvs, curve, _ = sweep(arm, T=3)
    with pytest.raises(InputError, match="curves"):
        skin.pose_batch(world, [cvs, cvs], [curve])
    with pytest.raises(InputError, match="curves"):
        skin.pose_batch(world, [], [])
    with pytest.raises(InputError, match="world"):
        skin.pose_batch(world[0], [cvs], [curve])
    with pytest.raises(InputError, match="world"):
        skin.lbs_batch(world[0])
    with pytest.raises(InputError, match="cvs"):
        skin.pose_batch(world, [cvs[:2]], [curve])
    with pytest.raises(InputError, match="curve"):
        skin.pose_batch(world, [cvs], [curve[:, :, :4]])
    with pytest.raises(InputError, match="cvs_sets"):
        skins["influence", "lbs"].pose_batch(world, [cvs[:2]], [curve])


# ---------------------------------------------------------------------------------- CesiumMan
@pytest.fixture(scope="module")
def cesium():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    path = asset("characters/CesiumMan.glb")
    ch = load_character(path)
    clip = load_clip(path)
    order = ch.joint_order(clip.joint_names)
    rot, pos = clip.world()
    skin = MuscleSkin.from_musculature(fit_musculature(ch, "human", FitOptions()))
    return skin, transforms(rot[:, order], pos[:, order])


def test_cesiumman_walk_batch_equals_loop(cesium):
    """CesiumMan (3,273 vertices, the default template's muscles) over its walk: static and blended
    CVs (static + 3 mm of noise per CV) in one batch equal pose frame by frame within 1e-6 m."""
    skin, world = cesium
    world = world[:24]
    static = skin.rig.static(world)
    blended = static.cvs + np.random.default_rng(1).normal(0.0, 0.003, static.cvs.shape)
    out = skin.pose_batch(world, [static.cvs, blended], [static.curve, static.curve], first_frame=7)
    for got, c in zip(out, (static.cvs, blended)):
        assert np.abs(got - loop(skin, world, c, static.curve, 7)).max() <= TOL
    assert np.abs(out[1] - out[0]).max() > 1e-4
    assert np.abs(skin.lbs_batch(world) - np.stack([skin.lbs(w) for w in world])).max() <= TOL


# ---------------------------------------------------------------------------------- kernels vs NumPy
@pytest.mark.parametrize("method,reference", [("lbs", lbs_numpy), ("dqs", dqs_numpy)])
def test_skin_batch_matches_the_numpy_reference(method, reference):
    rng = np.random.default_rng(3)
    V, k, J, T = 500, 4, 9, 5
    rest = rng.normal(scale=0.1, size=(V, 3))
    joints = rng.integers(0, J, size=(V, k))
    weights = rng.random((V, k)) + 1e-3
    weights /= weights.sum(axis=1, keepdims=True)
    matrices = np.stack([rigid(rng, J) for _ in range(T)])
    skinner = Skinner(rest, joints, weights)
    got = skinner.skin_batch(matrices, method)
    for t in range(T):
        np.testing.assert_allclose(got[t], reference(rest, joints, weights, matrices[t]), atol=REF_TOL)
        np.testing.assert_array_equal(got[t], skinner.skin(matrices[t], method))
    buf = skinner.launch_batch(matrices, method)
    assert isinstance(buf, wp.array) and buf.shape == (T, V) and buf.dtype == wp.vec3
    # the GPU's launch shape (a thread per frame and vertex), run here on the CPU, gives the same
    skinner.thread_per_frame = True
    np.testing.assert_array_equal(skinner.skin_batch(matrices, method), got)
    skinner.thread_per_frame = False
    with pytest.raises(InputError, match="matrices"):
        skinner.skin_batch(matrices[0], method)
    bad = matrices.copy()
    bad[2, 4, 0, 0] = np.nan
    with pytest.raises(InputError, match=r"\(2, 4\)"):
        skinner.skin_batch(bad, method)
    with pytest.raises(InputError, match="joints"):
        skinner.skin_batch(matrices[:, :3], method)


def random_frames(rng, E_rest: np.ndarray) -> ShellFrames:
    """One frame: the rest ellipsoids moved rigidly (the bones), then bulged and slid (the muscles),
    a bowed trajectory curve, one muscle in ten inactive with NaN current state."""
    M = len(E_rest)
    E_ref = rigid(rng, M) @ E_rest
    bulge = np.eye(4) + np.pad(rng.normal(scale=0.05, size=(M, 3, 4)), ((0, 0), (0, 1), (0, 0)))
    E_cur = E_ref @ bulge
    u = np.linspace(0.0, 1.0, 9)[None, :, None]
    curve = (E_ref[:, None, :3, 3] * (1 - u) + E_cur[:, None, :3, 3] * u
             + np.sin(np.pi * u) * rng.normal(scale=0.03, size=(M, 1, 3)))
    active = rng.random(M) > 0.1
    E_cur_inv = np.linalg.inv(E_cur)
    E_cur[~active] = np.nan
    E_cur_inv[~active] = np.nan
    return ShellFrames(E_ref, np.linalg.inv(E_ref), E_cur, E_cur_inv, curve, active)


def test_shell_batch_matches_the_reference_and_the_single_launch():
    """S = 2 sets x T = 4 frames of random muscle states over random skinned points, every mode and
    star tables: each [s, t] equals the single-frame launch exactly and the float64 reference
    (rig.skin.shell.shells.shell_numpy) to float32 rounding; vertices without pairs keep their points."""
    rng = np.random.default_rng(8)
    M, V, S, T = 6, 800, 2, 4
    E_rest = np.stack([np.diag([*rng.uniform(0.08, 0.2, 3), 1.0]) for _ in range(M)])
    E_rest[:, :3, 3] = rng.uniform(-0.3, 0.3, (M, 3))
    params = [ShellParams(mode=MODES[m % 3], sticky=rng.uniform(), hard=rng.uniform(0.0, 0.8),
                          drop_off=rng.uniform(0.3, 1.5), slippage=1.0 if m % 2 else rng.uniform(0.0, 2.0))
              for m in range(M)]
    table = shell_table(params, star=rng.uniform(-0.1, 0.1, (3, 17, 32)).astype(np.float32),
                        star_index=np.array([0, 1, 2, -1, 0, -1], np.int32))
    member = (rng.random((V, M)) < 0.4) & (rng.random((V, 1)) < 0.8)
    _, muscle = np.nonzero(member)
    offsets = np.concatenate([[0], np.cumsum(member.sum(axis=1))]).astype(np.int32)
    weight = rng.uniform(0.2, 1.0, len(muscle)).astype(np.float32)
    deformer = ShellDeformer(table, offsets, muscle.astype(np.int32), weight)
    frames = [[random_frames(rng, E_rest) for _ in range(T)] for _ in range(S)]
    for t in range(T):         # the sets share the reference ellipsoids (the bones)
        for s in range(1, S):
            f0, f = frames[0][t], frames[s][t]
            frames[s][t] = ShellFrames(f0.E_ref, f0.E_ref_inv, f.E_cur, f.E_cur_inv, f.curve, f.active)
    batch = ShellBatch(np.stack([f.E_ref for f in frames[0]]), np.stack([f.E_ref_inv for f in frames[0]]),
                       *(np.stack([np.stack([getattr(f, k) for f in row]) for row in frames])
                         for k in ("E_cur", "E_cur_inv", "curve", "active")))
    points = rng.uniform(-0.5, 0.5, (T, V, 3))
    got = deformer.deform_batch(points, batch)
    assert got.shape == (S, T, V, 3) and got.dtype == np.float32
    unpaired = ~member.any(axis=1)
    for s in range(S):
        for t in range(T):
            single = deformer.deform(points[t], frames[s][t])
            np.testing.assert_array_equal(got[s, t], single)
            ref = shell_numpy(points[t], offsets, muscle, weight, table, frames[s][t])
            np.testing.assert_allclose(got[s, t], ref, atol=REF_TOL, rtol=0.0)
            np.testing.assert_array_equal(got[s, t, unpaired], points[t, unpaired].astype(np.float32))
    assert np.abs(got[1] - got[0]).max() > 1e-3
    # the GPU's launch shape (a thread per frame and paired vertex), run here on the CPU, gives the same
    deformer.thread_per_frame = True
    np.testing.assert_array_equal(deformer.deform_batch(points, batch), got)
    # the paired vertices' displacements alone (the spread's input): the same points, minus the smooth ones
    paired = np.nonzero(~unpaired)[0]
    p32 = points.astype(np.float32)
    want = (got[:, :, paired] - p32[None, :, paired]).transpose(0, 2, 1, 3)
    for per_frame in (True, False):
        deformer.thread_per_frame = per_frame
        moved = deformer.launch_displace(wp.array(p32, dtype=wp.vec3), batch).numpy()
        assert moved.shape == (S, len(paired), T, 3)
        np.testing.assert_array_equal(moved, want)


def test_shell_batch_checks_its_state():
    rng = np.random.default_rng(2)
    T, M = 3, 2
    E = np.tile(np.eye(4), (T, M, 1, 1))
    curve = np.zeros((1, T, M, 9, 3))
    active = np.ones((1, T, M), bool)
    ShellBatch(E, E, E[None], E[None], curve, active)
    with pytest.raises(InputError, match="E_ref"):
        ShellBatch(E[0], E, E[None], E[None], curve, active)
    with pytest.raises(InputError, match="E_cur_inv"):
        ShellBatch(E, E, E[None], E, curve, active)
    with pytest.raises(InputError, match="curve"):
        ShellBatch(E, E, E[None], E[None], curve[:, :, :, :1], active)
    with pytest.raises(InputError, match="active"):
        ShellBatch(E, E, E[None], E[None], curve, active[0])
    table = shell_table([ShellParams()] * M)
    deformer = ShellDeformer(table, np.array([0, 2, 2, 3], np.int32), np.array([0, 1, 1], np.int32),
                             np.ones(3, np.float32))
    points = wp.array(rng.uniform(-1, 1, (T, 3, 3)).astype(np.float32), dtype=wp.vec3)
    nan = E.copy()
    nan[1, 0, 0, 0] = np.nan
    with pytest.raises(InputError, match="E_ref"):
        deformer.launch_batch(points, ShellBatch(nan, E, E[None], E[None], curve, active))
    inactive = active.copy()
    inactive[:, 1, 0] = False         # no set reads muscle 0 at frame 1: its NaN is never read
    out = deformer.launch_batch(points, ShellBatch(nan, E, E[None], E[None], curve, inactive))
    np.testing.assert_array_equal(out.numpy()[0], points.numpy())
    with pytest.raises(InputError, match="points"):
        deformer.launch_batch(wp.zeros(3, dtype=wp.vec3), ShellBatch(E, E, E[None], E[None], curve, active))
    with pytest.raises(InputError, match="batch"):
        deformer.launch_batch(points, "frames")


# ---------------------------------------------------------------------------------- smooth skin, launches
@pytest.mark.parametrize("mode", ["shell", "influence"])
@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_smooth_skin_and_launch_count(arm, skins, mode, method):
    """smooth=True appends lbs_batch's skin, equal bit for bit, at no extra launch; `launches` counts
    pose_batch's: the skinning (DQS: 2) and one deformer launch for all sets and frames."""
    skin = skins[mode, method]
    world, cvs, curve, blended = sweep(arm, T=7)
    before = skin.launches
    a, b = skin.pose_batch(world, [cvs, blended], [curve, curve])
    assert skin.launches - before == (2 if method == "lbs" else 3)
    before = skin.launches
    a2, b2, lbs = skin.pose_batch(world, [cvs, blended], [curve, curve], smooth=True)
    assert skin.launches - before == (2 if method == "lbs" else 3)
    np.testing.assert_array_equal(a2, a)
    np.testing.assert_array_equal(b2, b)
    assert lbs.shape == a.shape and lbs.dtype == np.float32
    np.testing.assert_array_equal(lbs, skin.lbs_batch(world))
    # deferred: the smooth skin survives the next call (a new array, not the device buffer)
    finish = skin.pose_batch(world, [cvs], [curve], defer=True, smooth=True)
    skin.pose_batch(world[::-1], [cvs[::-1]], [curve[::-1]], smooth=True)
    got = finish()
    assert len(got) == 2
    np.testing.assert_array_equal(got[0], a)
    np.testing.assert_array_equal(got[1], lbs)
    empty = skin.pose_batch(world[:0], [cvs[:0]], [curve[:0]], smooth=True)
    assert len(empty) == 2 and empty[1].shape == (0, arm.character.num_vertices, 3)


def test_skin_frames_smooth(arm, skins):
    """skin_frames(smooth=True): the sets, then the smooth skin; batched or frame by frame alike."""
    from jiggle.rig.skin.muscle_skin import skin_frames
    skin = skins["shell", "lbs"]
    world, cvs, curve, blended = sweep(arm, T=5)
    got = skin_frames(skin, world, (cvs, blended), curve, np.arange(5), smooth=True)
    assert len(got) == 3
    np.testing.assert_array_equal(got[2], skin.lbs_batch(world))
    loose = skin_frames(skin, world, (cvs, blended), curve, np.array([0, 2, 4, 6, 8]), smooth=True)
    for g, h in zip(got, loose):
        assert np.abs(g - h).max() <= TOL
    deferred = skin_frames(skin, world, (cvs, blended), curve, np.arange(5), defer=True, smooth=True)()
    for g, h in zip(got, deferred):
        np.testing.assert_array_equal(g, h)


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_without_spread_batch_equals_loop(arm, mode):
    """spread = 0: the deformers' full skins, no spread; still equal to pose frame by frame."""
    skin = MuscleSkin(arm.character, arm.rig, skinning=mode, spread=0.0)
    world, cvs, curve, blended = sweep(arm, T=6)
    out = skin.pose_batch(world, [cvs, blended], [curve, curve])
    for got, c in zip(out, (cvs, blended)):
        assert np.abs(got - loop(skin, world, c, curve)).max() <= TOL


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_gpu_launch_shape_gives_the_same_skins(arm, skins, mode):
    """A thread per frame and paired vertex (the GPU's shape of the batched launches), run here on the
    CPU, gives the same skins bit for bit, with and without the spread."""
    for skin in (skins[mode, "lbs"], MuscleSkin(arm.character, arm.rig, skinning=mode, spread=0.0)):
        world, cvs, curve, blended = sweep(arm, T=5)
        want = skin.pose_batch(world, [cvs, blended], [curve, curve])
        try:
            skin.deformer.thread_per_frame = skin.skinner.thread_per_frame = True
            got = skin.pose_batch(world, [cvs, blended], [curve, curve])
        finally:
            skin.deformer.thread_per_frame = skin.skinner.thread_per_frame = False
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("mode", ["shell", "influence"])
@pytest.mark.parametrize("spread", [None, 0.0])
def test_reuse_rotates_two_generations_of_buffers(arm, mode, spread):
    """reuse=True (the bake's call): the same skins bit for bit as new arrays, deferred or not; call n's
    arrays hold through call n + 1 (the bake's two chunks in flight: call n + 1 runs before n's deferred
    function) and come back at call n + 2; a shorter chunk takes a prefix of the kept buffers."""
    kw = {} if spread is None else {"spread": spread}
    skin = MuscleSkin(arm.character, arm.rig, skinning=mode, **kw)
    world, cvs, curve, blended = sweep(arm, T=9)
    chunks = [(0, 6), (6, 9), (0, 6), (6, 9), (2, 7)]

    def call(a, b, **k):
        return skin.pose_batch(world[a:b], [cvs[a:b], blended[a:b]], [curve[a:b], curve[a:b]], first_frame=a,
                               smooth=True, **k)
    want = [call(a, b) for a, b in chunks]
    pending = None
    kept = []
    for (a, b), w in zip(chunks, want):
        finish = call(a, b, defer=True, reuse=True)
        if pending is not None:
            kept.append(pending())
        pending = finish
        if len(kept) >= 1:                      # the previous chunk's arrays survive this call
            for g, h in zip(kept[-1], want[len(kept) - 1]):
                np.testing.assert_array_equal(g, h)
    kept.append(pending())
    for g, h in zip(kept[-1], want[-1]):
        np.testing.assert_array_equal(g, h)
    # not deferred: the same, and the arrays of two calls apart share memory (the rotation)
    first = call(0, 6, reuse=True)
    second = call(6, 9, reuse=True)
    third = call(0, 6, reuse=True)
    for g, h in zip(second, want[1]):
        np.testing.assert_array_equal(g, h)
    for g, h in zip(third, want[0]):
        np.testing.assert_array_equal(g, h)
    assert all(np.shares_memory(f, t) for f, t in zip(first, third))
    assert not any(np.shares_memory(f, t) for f, t in zip(second, third))
    assert len({id(a.base) for a in third}) == len(third)      # every array its own buffer


def test_skin_frames_reuse(arm, skins):
    """skin_frames(reuse=True) passes the flag to pose_batch: equal skins; ignored frame by frame."""
    from jiggle.rig.skin.muscle_skin import skin_frames
    skin = MuscleSkin(arm.character, arm.rig)
    world, cvs, curve, blended = sweep(arm, T=5)
    want = skin_frames(skin, world, (cvs, blended), curve, np.arange(5), smooth=True)
    got = skin_frames(skin, world, (cvs, blended), curve, np.arange(5), defer=True, smooth=True, reuse=True)()
    for g, h in zip(got, want):
        np.testing.assert_array_equal(g, h)
    loose = skin_frames(skin, world, (cvs, blended), curve, np.array([0, 2, 4, 6, 8]), reuse=True)
    assert len(loose) == 2


def test_launches_into_given_arrays(arm, skins):
    """Skinner.launch_batch and ShellDeformer.launch_displace write into `out` when given (a host array
    wrapped without a copy on the CPU) the same values as into their own buffers; a wrong one is named."""
    skin = skins["shell", "lbs"]
    world, cvs, curve, blended = sweep(arm, T=4)
    mats = skin.character.skin_matrices(world)
    own = skin.skinner.launch_batch(mats).numpy().copy()
    host = np.full(own.shape, np.nan, np.float32)
    got = skin.skinner.launch_batch(mats, out=wp.array(host, dtype=wp.vec3, device="cpu", copy=False))
    assert got.ptr == host.ctypes.data
    np.testing.assert_array_equal(host, own)
    with pytest.raises(InputError) as e:
        skin.skinner.launch_batch(mats, out=wp.empty(3, dtype=wp.vec3, device="cpu"))
    assert e.value.field == "out"
    arrays, _ = skin.frames.frame_sets(world, [cvs, blended], [curve, curve], 0)
    batch = ShellBatch(*arrays)
    points = wp.array(own, dtype=wp.vec3, device="cpu")
    moved = skin.deformer.launch_displace(points, batch).numpy().copy()
    held = np.full(moved.shape, np.nan, np.float32)
    skin.deformer.launch_displace(points, batch, out=wp.array(held, dtype=wp.vec3, device="cpu", copy=False))
    np.testing.assert_array_equal(held, moved)
    with pytest.raises(InputError) as e:
        skin.deformer.launch_displace(points, batch, out=wp.empty((1, 2, 3), dtype=wp.vec3, device="cpu"))
    assert e.value.field == "out"


@pytest.mark.parametrize("mode", ["shell", "influence"])
@pytest.mark.parametrize("defer", [False, True])
def test_the_spread_on_the_device_equals_the_host_spread(arm, mode, defer):
    """A GPU's pose_batch (spread_on_device: the spread and the sums on the device, finished skins copied
    back), run here on the CPU device: equal to the host spread's skins, with the smooth skin after them."""
    world, cvs, curve, blended = sweep(arm)
    host = MuscleSkin(arm.character, arm.rig, skinning=mode)
    dev = MuscleSkin(arm.character, arm.rig, skinning=mode)
    assert not host.spread_on_device and host.spread.steps > 0
    dev.spread_on_device = True
    want = host.pose_batch(world, [cvs, blended], [curve, curve], smooth=True)
    got = dev.pose_batch(world, [cvs, blended], [curve, curve], smooth=True, defer=defer, reuse=True)
    got = got() if defer else got
    assert len(got) == 3
    for g, w in zip(got, want):
        assert g.shape == w.shape and g.dtype == np.float32
        assert np.abs(g - w).max() <= TOL
    assert np.abs(got[1] - got[0]).max() > 1e-4
