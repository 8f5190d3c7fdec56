"""Quaternion helpers against SciPy, and the Clip type: read-only, sampling, resampling, trimming."""
import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip

rng = np.random.default_rng(7)


def random_quats(n):
    return quat.from_xyzw(Rotation.random(n, random_state=3).as_quat())


def test_mul_rotate_matrix_match_scipy():
    a, b = random_quats(50), random_quats(50)[::-1]
    v = rng.normal(size=(50, 3))
    ra, rb = Rotation.from_quat(quat.to_xyzw(a)), Rotation.from_quat(quat.to_xyzw(b))
    np.testing.assert_allclose(quat.to_matrix(quat.mul(a, b)), (ra * rb).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(quat.rotate(a, v), ra.apply(v), atol=1e-12)
    back = quat.from_matrix(quat.to_matrix(a))
    np.testing.assert_allclose(np.abs(np.sum(back * a, axis=1)), 1.0, atol=1e-12)


def test_rotation_vectors_match_scipy():
    q = random_quats(50)
    want = Rotation.from_quat(quat.to_xyzw(q)).as_rotvec()
    np.testing.assert_allclose(quat.to_rotvec(q), want, atol=1e-12)
    np.testing.assert_allclose(quat.to_rotvec(-q), want, atol=1e-12)  # same rotation, either sign
    np.testing.assert_allclose(quat.to_rotvec(quat.identity((2,))), 0.0)


def test_euler_is_intrinsic_in_listed_order():
    # BVH "Zrotation Yrotation Xrotation" = Rz @ Ry @ Rx (column vectors)
    z, y, x = np.radians([30.0, -50.0, 70.0])
    Rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(x), -np.sin(x)], [0, np.sin(x), np.cos(x)]])
    q = quat.from_euler(np.degrees([z, y, x]), "ZYX")
    np.testing.assert_allclose(quat.to_matrix(q), Rz @ Ry @ Rx, atol=1e-12)


def test_between_and_slerp():
    a, b = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    q = quat.between(a, b)
    got = quat.rotate(q, a / np.linalg.norm(a, axis=1, keepdims=True))
    np.testing.assert_allclose(got, b / np.linalg.norm(b, axis=1, keepdims=True), atol=1e-12)
    opp = quat.between(np.array([[0.0, 0, 1]]), np.array([[0.0, 0, -1]]))
    np.testing.assert_allclose(quat.rotate(opp, np.array([[0.0, 0, 1]])), [[0, 0, -1]], atol=1e-12)
    # slerp of a rotation about a fixed axis is linear in angle
    axis = np.array([0.0, 0.0, 1.0])
    q0, q1 = quat.from_axis_angle(axis, 0.2), quat.from_axis_angle(axis, 1.4)
    np.testing.assert_allclose(quat.slerp(q0, q1, 0.25), quat.from_axis_angle(axis, 0.5), atol=1e-12)
    np.testing.assert_allclose(quat.to_xyzw(quat.from_xyzw(q0)), q0)


def spinning_clip(fps=30.0, seconds=2.0, rate=1.3):
    """Two joints; the root spins about Z at `rate` rad/s and rises 0.5 m/s."""
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    rot = np.stack([quat.from_axis_angle(np.array([0.0, 0, 1]), rate * t), quat.identity((len(t),))], axis=1)
    tra = np.zeros((len(t), 2, 3))
    tra[:, 0, 2] = 0.5 * t
    tra[:, 1] = [1.0, 0.0, 0.0]
    return Clip(["root", "arm"], [-1, 0], [[0, 0, 0], [1, 0, 0]], quat.identity((2,)), rot, tra, fps, name="spin")


def test_clip_arrays_are_read_only():
    c = spinning_clip()
    for name in ("parents", "offsets", "rotations", "translations", "rest_rotations"):
        with pytest.raises(ValueError):
            getattr(c, name)[...] = 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.fps = 10


def test_sample_interpolates_between_frames():
    c = spinning_clip(fps=10.0)
    rot, tra = c.sample(np.array([0.05, 0.75]))  # half-way between frames
    np.testing.assert_allclose(quat.angle(rot[:, 0]), 1.3 * np.array([0.05, 0.75]), atol=1e-12)
    np.testing.assert_allclose(tra[:, 0, 2], 0.5 * np.array([0.05, 0.75]), atol=1e-12)


def test_resample_speed_and_ranges():
    c = spinning_clip(fps=30.0)
    r = c.resample(120.0)
    assert r.num_frames == 241 and r.fps == 120.0
    np.testing.assert_allclose(quat.angle(r.rotations[:, 0]), 1.3 * r.times, atol=1e-9)
    fast = c.with_speed(2.0)
    assert fast.fps == 30.0 and fast.duration == pytest.approx(1.0)
    np.testing.assert_allclose(fast.translations[:, 0, 2], 0.5 * 2 * fast.times, atol=1e-12)
    part = c.between(0.5, 1.5)
    assert part.num_frames == 31
    np.testing.assert_allclose(part.translations[0, 0, 2], 0.25, atol=1e-12)
    assert c.frames(5, 10).num_frames == 5
    with pytest.raises(InputError):
        c.between(1.0, 5.0)
    with pytest.raises(InputError):
        c.frames(100, 200)
    with pytest.raises(InputError):
        c.resample(0.0)


def test_world_fk_and_end_sites():
    c = spinning_clip()
    r, p = c.world()
    ang = 1.3 * c.times
    np.testing.assert_allclose(p[:, 1, 0], np.cos(ang), atol=1e-12)
    np.testing.assert_allclose(p[:, 1, 1], np.sin(ang), atol=1e-12)


def test_clip_rejects_bad_values():
    c = spinning_clip()
    bad = np.array(c.translations)
    bad[3, 0, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        dataclasses.replace(c, translations=bad)
    with pytest.raises(InputError, match="frame rate"):
        dataclasses.replace(c, fps=-1.0)
