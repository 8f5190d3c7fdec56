"""The thesis muscle (rig/muscle/model.py) and its loft (rig/muscle/loft.py).

Synthetic skeletons (a two-bone arm) except one test driven by a shared CMU clip. `reference_static`
is an independent per-muscle, per-frame implementation of the documented equations (scipy splines,
np.cross, the loft mesh built point by point); the vectorised MuscleRig.static must agree with it.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from arm_muscles import ARM_BIND, arm_world, biceps, brachio, spec_from_ellipsoid
from conftest import asset
from scipy.interpolate import BSpline, CubicSpline
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.clip import transforms
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.model import VOLUME_RULES, build_muscle_rig


@pytest.fixture(scope="module")
def arm_rig():
    return build_muscle_rig([biceps(), brachio()], ARM_BIND)


# ---------------------------------------------------------------------------------- reference
def reference_static(specs, bind_world, sections, world, rule="exact"):
    """Static CVs (M * 40, 3) and curve (M, 5, 3) for world (J, 4, 4), muscle by muscle, from the
    specs, the fitted sections (M, 5, 8, 2) and the equations of rig/muscle/model.py's docstring."""
    knots = [0, 0, 0, 0, 0.5, 1, 1, 1, 1]
    gx, gw = np.polynomial.legendre.leggauss(8)
    arc_u = np.concatenate([0.25 + 0.25 * gx, 0.75 + 0.25 * gx])
    arc_w = np.concatenate([0.25 * gw, 0.25 * gw])
    unit = lambda x: x / np.linalg.norm(x)  # noqa: E731

    def mesh_volume(cvs):
        # periodic uniform cubic B-spline around (knots -3..11, coefficient i = CV (i - 1) mod 8),
        # not-a-knot cubic spline across the sections, 17 x 16 grid plus centroid caps
        c = cvs - cvs.mean(axis=(0, 1))
        v = np.arange(16) / 2.0
        rings = np.stack([BSpline(np.arange(-3.0, 12.0), c[k][(np.arange(11) - 1) % 8], 3)(v) for k in range(5)])
        grid = CubicSpline(np.arange(5.0), rings, axis=0, bc_type="not-a-knot")(np.linspace(0, 4, 17))
        pts = np.concatenate([grid.reshape(-1, 3), grid[[0, -1]].mean(axis=1)])
        tri = pts[loft.FACES]
        return np.einsum("fi,fi->f", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0

    def pose(s, w):
        inv = np.linalg.inv(bind_world)
        to_w = lambda j, p: w[j, :3, :3] @ (inv[j, :3, :3] @ p + inv[j, :3, 3]) + w[j, :3, 3]  # noqa: E731
        rot = lambda j, v: w[j, :3, :3] @ (inv[j, :3, :3] @ v)  # noqa: E731
        (_, boh, bih, _), a = s.bones, s.bone
        o, oh, ih, ins = (to_w(j, p) for j, p in zip(s.bones, s.points))
        t_rest = unit(s.ends[1] - s.ends[0])
        u_rest = unit(s.points[2] - s.points[1])
        u = unit(ih - oh)
        ends = []
        for hinge_b, hinge, attach, hinge_rest, attach_rest, end_rest, default in (
                (boh, oh, o, s.points[1], s.points[0], s.ends[0], 1.0),
                (bih, ih, ins, s.points[2], s.points[3], s.ends[1], -1.0)):
            tendon = np.linalg.norm(attach_rest - hinge_rest) + np.linalg.norm(hinge_rest - end_rest)
            length = tendon - np.linalg.norm(attach - hinge)
            d_rest = end_rest - hinge_rest
            if np.linalg.norm(d_rest) < 1e-9 * np.linalg.norm(s.ends[1] - s.ends[0]):
                d = default * u
            else:
                along = unit(d_rest) @ u_rest
                perp = rot(hinge_b, unit(d_rest) - along * u_rest)
                d = unit(along * u + perp - (perp @ u) * u)
            ends.append(hinge + length * d)
        eo, ei = ends
        short = max(0.3 * np.linalg.norm(s.ends[1] - s.ends[0]) - (ei - eo) @ u, 0.0)
        eo, ei = eo - short / 2 * u, ei + short / 2 * u
        c = np.linalg.norm(ei - eo)
        Q = np.stack([eo, eo + 0.125 * c * rot(boh, t_rest), (eo + ei) / 2 + w[a, :3, :3] @ s.middle_offset,
                      ei - 0.125 * c * rot(bih, t_rest), ei])
        curve = BSpline(knots, Q, 3)
        length = np.linalg.norm(curve.derivative()(arc_u), axis=1) @ arc_w
        b = s.bulge_position
        uk = np.array([0, 0.5 - b, 0.5, 0.5 + b, 1])
        up = rot(a, unit(s.up - (s.up @ t_rest) * t_rest))
        frames = []
        for k in range(5):
            T = unit(curve.derivative()(uk[k]))
            U = unit(up - (up @ T) * T)
            frames.append((curve(uk[k]), U, np.cross(T, U)))
        return Q, length, frames

    def cvs_of(frames, ab, scales):
        return np.stack([[c + sk * (a * U + b * S) for a, b in ab[k]] for k, ((c, U, S), sk)
                         in enumerate(zip(frames, scales))])

    out_cvs, out_curve = [], []
    for s, ab in zip(specs, sections):
        attr = np.array([s.rim_scale, s.bulge_scale, s.main_scale, s.bulge_scale, s.rim_scale])
        _, Li, rest_frames = pose(s, bind_world)
        V_rest = mesh_volume(cvs_of(rest_frames, ab, attr))
        Q, Lc, frames = pose(s, world)
        if rule == "none":
            scale = 1.0
        elif rule == "thesis":
            scale = Li / Lc
        else:
            scale = np.sqrt(Li / Lc)
            if rule == "exact":
                V = mesh_volume(cvs_of(frames, ab, attr * scale))
                scale *= np.sqrt(np.clip(V_rest / V, 0.25, 4.0))
        scale = 1.0 + s.tone * (scale - 1.0)
        out_cvs.append(cvs_of(frames, ab, attr * scale).reshape(-1, 3))
        out_curve.append(Q)
    return np.concatenate(out_cvs), np.stack(out_curve)


# ---------------------------------------------------------------------------------- loft
def test_loft_mesh_is_closed_and_outward():
    rng = np.random.default_rng(1)
    theta = 2 * np.pi * np.arange(8) / 8
    cvs = np.zeros((5, 8, 3))
    cvs[..., 0] = np.cos(theta)
    cvs[..., 1] = np.sin(theta)
    cvs[..., 2] = np.arange(5)[:, None]
    cvs += rng.normal(scale=0.1, size=cvs.shape)
    mesh = trimesh.Trimesh(loft.points(cvs), loft.FACES, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert loft.volume(cvs) == pytest.approx(mesh.volume, rel=1e-12)
    # the section curves interpolate: row 0 of the grid is section 0's ring, (CV[j-1] + 4 CV[j] + CV[j+1]) / 6
    ring0 = loft.points(cvs)[:loft.COLS:loft.COLS_PER_CV]
    assert np.allclose(ring0, (np.roll(cvs[0], 1, 0) + 4 * cvs[0] + np.roll(cvs[0], -1, 0)) / 6, atol=1e-12)


# ---------------------------------------------------------------------------------- build and rest
def test_ellipsoid_is_reproduced():
    radii = np.array([0.10, 0.03, 0.025])
    spec = spec_from_ellipsoid("e", [(0, 0, -0.05), (0, 0, -0.25)], (0, 1, 0), radii[1:], bones=(0, 0, 0, 1),
                               origin=(0, 0, -0.02), insertion=(0, 0, -0.33))
    rig = build_muscle_rig([spec], ARM_BIND)
    exact = 4.0 / 3.0 * np.pi * radii.prod()
    mean_radius = radii[1:].mean()
    print(f"\nellipsoid fit: rms {rig.fit_rms[0] * 1e3:.3f} mm ({rig.fit_rms[0] / mean_radius:.1%} of the radius), "
          f"max {rig.fit_max[0] * 1e3:.3f} mm; loft volume / ellipsoid {rig.rest_volume[0] / exact:.4f}")
    assert rig.fit_rms[0] < 0.03 * mean_radius
    assert rig.fit_max[0] < 0.10 * mean_radius
    assert rig.rest_volume[0] == pytest.approx(exact, rel=0.05)


def test_rest_pose_gives_rest_cvs(arm_rig):
    cvs, curve = arm_rig.static(ARM_BIND)
    assert cvs.shape == (80, 3) and curve.shape == (2, 5, 3)
    assert np.abs(cvs - arm_rig.rest_cvs).max() < 1e-9
    assert np.abs(curve - arm_rig.rest_curve).max() < 1e-9
    assert np.allclose(arm_rig.volumes(arm_rig.rest_cvs), arm_rig.rest_volume, rtol=1e-12)
    assert list(arm_rig.cv_offsets) == [0, 40, 80] and arm_rig.M == 2 and arm_rig.CVS_PER_MUSCLE == 40
    assert arm_rig.names == ("biceps", "brachio")
    # the straight rest curve: CVs at 0, 12.5, 50, 87.5 and 100% of the chord
    q = arm_rig.rest_curve[0]
    f = (q - q[0]) @ (q[4] - q[0]) / np.sum((q[4] - q[0]) ** 2)
    assert np.allclose(f, [0, 0.125, 0.5, 0.875, 1], atol=1e-12)
    assert arm_rig.surface(cvs).shape == (2, loft.POINTS, 3)
    assert np.all(arm_rig.fit_rms < 0.03 * 0.02)


def test_hinges_away_from_the_belly_ride_their_bones():
    """Hinges off the belly ends: the rest pose is still reproduced and a flexed pose matches the
    reference (the hinge-to-belly directions ride the hinges' joints)."""
    spec = biceps(hinges=[(0, 0.02, -0.04), (0, 0.025, -0.27)])
    rig = build_muscle_rig([spec], ARM_BIND)
    assert np.abs(rig.static(ARM_BIND).cvs - rig.rest_cvs).max() < 1e-9
    ref, _ = reference_static([spec], ARM_BIND, rig.sections, arm_world(60))
    assert np.abs(rig.static(arm_world(60)).cvs - ref).max() < 1e-12


# ---------------------------------------------------------------------------------- motion
def section_radii(rig, cvs):
    """(M, 5) mean distance of each section's CVs from their centroid."""
    c = cvs.reshape(rig.M, 5, 8, 3)
    return np.linalg.norm(c - c.mean(axis=2, keepdims=True), axis=3).mean(axis=2)


def test_bending_the_elbow_shortens_the_biceps_and_it_bulges(arm_rig):
    rest = arm_rig.rest_curve[0]
    cvs, curve = arm_rig.static(arm_world(90))
    chord = lambda q: np.linalg.norm(q[4] - q[0])  # noqa: E731
    assert chord(curve[0]) < 0.8 * chord(rest)
    grow = section_radii(arm_rig, cvs)[0] / section_radii(arm_rig, arm_rig.rest_cvs)[0]
    assert np.all(grow > 1.05)
    # the muscle spanning the elbow bends: its end tangents follow their bones
    q = curve[1]
    t0, t1 = q[1] - q[0], q[4] - q[3]
    assert np.degrees(np.arccos(t0 @ t1 / np.linalg.norm(t0) / np.linalg.norm(t1))) > 60


def test_volume_is_kept_over_an_elbow_sweep(arm_rig):
    angles = np.arange(0, 141, 10)
    world = np.stack([arm_world(a) for a in angles])
    drift = {}
    for rule in VOLUME_RULES:
        cvs, _ = arm_rig.static(world, volume=rule)
        drift[rule] = arm_rig.volumes(cvs) / arm_rig.rest_volume - 1.0        # (T, M)
    print("\nelbow 0..140 deg, max |V / V_rest - 1| per muscle (biceps, brachio):")
    for rule, d in drift.items():
        print(f"  {rule:7s}", "  ".join(f"{x:.1e}" for x in np.abs(d).max(axis=0)))
    assert np.abs(drift["exact"]).max() < 1e-3
    assert np.abs(drift["thesis"]).max(axis=0).min() > 0.1
    assert np.all(np.abs(drift["thesis"]).max(axis=0) > 10 * np.abs(drift["exact"]).max(axis=0))


def test_rigid_motion_of_the_skeleton_moves_the_cvs_rigidly(arm_rig):
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    g[:3, 3] = (0.4, -2.0, 1.1)
    for angle in (0, 75):
        cvs, curve = arm_rig.static(arm_world(angle))
        moved, moved_curve = arm_rig.static(arm_world(angle, root=g))
        assert np.abs(moved - (cvs @ g[:3, :3].T + g[:3, 3])).max() < 1e-12
        assert np.abs(moved_curve - (curve @ g[:3, :3].T + g[:3, 3])).max() < 1e-12


def test_tone_zero_keeps_the_sections_unscaled():
    rig = build_muscle_rig([biceps(tone=0.0), brachio(tone=0.0)], ARM_BIND)
    rest = section_radii(rig, rig.rest_cvs)
    for rule in VOLUME_RULES:
        assert np.abs(section_radii(rig, rig.static(arm_world(110), volume=rule).cvs) - rest).max() < 1e-12
    half = build_muscle_rig([biceps(tone=0.5)], ARM_BIND, volume="thesis")
    full = build_muscle_rig([biceps()], ARM_BIND, volume="thesis")
    g_half = section_radii(half, half.static(arm_world(90)).cvs) / section_radii(half, half.rest_cvs)
    g_full = section_radii(full, full.static(arm_world(90)).cvs) / section_radii(full, full.rest_cvs)
    assert np.allclose(g_half - 1, 0.5 * (g_full - 1), atol=1e-12)


def test_attributes_scale_their_sections():
    plain = build_muscle_rig([biceps()], ARM_BIND)
    shaped = build_muscle_rig([biceps(rim_scale=0.5, bulge_scale=1.2, main_scale=1.5)], ARM_BIND)
    assert np.allclose(section_radii(shaped, shaped.rest_cvs) / section_radii(plain, plain.rest_cvs),
                       [[0.5, 1.2, 1.5, 1.2, 0.5]], rtol=1e-12)


def test_batch_equals_single_frames(arm_rig):
    world = np.stack([arm_world(a) for a in (0, 33, 66, 99, 132, 140, 12)])
    cvs, curve = arm_rig.static(world)
    assert cvs.shape == (7, 80, 3) and curve.shape == (7, 2, 5, 3)
    for t, w in enumerate(world):
        one = arm_rig.static(w)
        assert np.abs(cvs[t] - one.cvs).max() < 1e-13 and np.abs(curve[t] - one.curve).max() < 1e-13
    assert arm_rig.volumes(cvs).shape == (7, 2) and arm_rig.surface(cvs).shape == (7, 2, loft.POINTS, 3)


def test_a_rig_without_muscles_is_empty():
    rig = build_muscle_rig([], ARM_BIND)
    assert rig.M == 0 and rig.rest_cvs.shape == (0, 3)
    assert rig.static(ARM_BIND).cvs.shape == (0, 3) and rig.static(np.stack([ARM_BIND] * 5)).cvs.shape == (5, 0, 3)


@pytest.mark.parametrize("device", [None, "cpu"])
@pytest.mark.parametrize("rule", VOLUME_RULES)
def test_vectorised_static_equals_the_per_muscle_reference(rule, device):
    """Both the NumPy path (device None) and the Warp kernel (tests/muscle/test_static_kernels.py)."""
    specs = [biceps(), brachio(bulge_position=0.3, tone=0.7, middle_offset=(0.004, 0.01, 0.0)),
             biceps(rim_scale=0.8, main_scale=1.2, bone=1)]
    rig = build_muscle_rig(specs, ARM_BIND, volume=rule)
    for angle in (0, 45, 120):
        ref_cvs, ref_curve = reference_static(specs, ARM_BIND, rig.sections, arm_world(angle), rule)
        cvs, curve = rig.static(arm_world(angle), device=device)
        assert np.abs(cvs - ref_cvs).max() < 1e-12
        assert np.abs(curve - ref_curve).max() < 1e-12


# ---------------------------------------------------------------------------------- bad input
def test_bad_input_is_refused_clearly():
    good = biceps()
    with pytest.raises(InputError, match="zero-length belly"):
        dataclasses.replace(good, ends=np.stack([good.ends[0], good.ends[0]]))
    with pytest.raises(InputError, match="zero-length belly"):
        dataclasses.replace(good, points=np.stack([good.points[0], good.points[1], good.points[1], good.points[3]]))
    bad_points = np.array(good.points)
    bad_points[2, 1] = np.nan
    with pytest.raises(InputError, match="points holds NaN"):
        dataclasses.replace(good, points=bad_points)
    with pytest.raises(InputError, match="tone must be in"):
        biceps(tone=1.5)
    with pytest.raises(InputError, match="bulge_position"):
        biceps(bulge_position=0.5)
    with pytest.raises(InputError, match="rim_scale must be > 0"):
        biceps(rim_scale=0.0)
    with pytest.raises(InputError, match="parallel to the belly axis"):
        dataclasses.replace(good, up=good.ends[1] - good.ends[0])
    with pytest.raises(InputError, match="unknown volume rule 'cubic'"):
        build_muscle_rig([good], ARM_BIND, volume="cubic")
    with pytest.raises(InputError, match="joint index 7"):
        build_muscle_rig([dataclasses.replace(good, bones=(0, 0, 0, 7))], ARM_BIND)
    rig = build_muscle_rig([good], ARM_BIND)
    with pytest.raises(InputError, match="unknown volume rule"):
        rig.static(ARM_BIND, volume="thesis2")
    with pytest.raises(InputError, match=r"world transforms must be \(3, 4, 4\)"):
        rig.static(ARM_BIND[:2])
    nan_world = ARM_BIND.copy()
    nan_world[1, 0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        rig.static(nan_world)
    assert issubclass(InputError, ValueError)


# ---------------------------------------------------------------------------------- real motion
def limb_spec(name, pos, a, b, c, toward, depth=0.035, radii=(0.025, 0.02), span=(0.2, 0.85), spanning=False):
    """A muscle on bone a->b (joint positions pos (J, 3)), `depth` toward `toward`; its insertion rides
    bone b->c just past joint b. `spanning`: the belly crosses joint b (i_hinge rides bone b)."""
    axis = (pos[b] - pos[a]) / np.linalg.norm(pos[b] - pos[a])
    n = toward - (toward @ axis) * axis
    n /= np.linalg.norm(n)
    L = np.linalg.norm(pos[b] - pos[a])
    axis_b = (pos[c] - pos[b]) / np.linalg.norm(pos[c] - pos[b])
    if spanning:
        ends = [pos[a] + 0.6 * L * axis + depth * n, pos[b] + 0.35 * L * axis_b + depth * n]
        bones, insertion = (a, a, b, b), pos[b] + 0.6 * L * axis_b + 0.5 * depth * n
    else:
        ends = [pos[a] + span[0] * L * axis + depth * n, pos[a] + span[1] * L * axis + depth * n]
        bones, insertion = (a, a, a, b), pos[b] + 0.15 * L * axis_b + 0.6 * depth * n
    return spec_from_ellipsoid(name, ends, n, radii, bones=bones, bone=a,
                               origin=pos[a] + 0.05 * L * axis + 0.5 * depth * n, insertion=insertion)


def test_clip_keeps_every_muscles_volume():
    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip(asset("mocap/cmu_bvh/02_03.bvh")).frames(0, 300)
    bind = transforms(*clip.rest_world())
    world = transforms(*clip.world())
    pos = bind[:, :3, 3]
    j = clip.index
    front = np.array([0.0, -1.0, 0.0])      # the CMU rest pose faces -Y (its toes point there)
    specs = [limb_spec("l_biceps", pos, j("LeftArm"), j("LeftForeArm"), j("LeftHand"), front),
             limb_spec("l_triceps", pos, j("LeftArm"), j("LeftForeArm"), j("LeftHand"), -front),
             limb_spec("r_quadriceps", pos, j("RightUpLeg"), j("RightLeg"), j("RightFoot"), front, radii=(0.04, 0.03)),
             limb_spec("r_hamstring", pos, j("RightUpLeg"), j("RightLeg"), j("RightFoot"), -front, radii=(0.035, 0.03)),
             limb_spec("l_brachio", pos, j("LeftArm"), j("LeftForeArm"), j("LeftHand"), front, radii=(0.02, 0.015),
                       spanning=True)]
    rig = build_muscle_rig(specs, bind)
    assert np.abs(rig.static(bind).cvs - rig.rest_cvs).max() < 1e-9
    drift = {}
    for rule in ("exact", "thesis"):
        cvs, _ = rig.static(world, volume=rule)
        drift[rule] = np.abs(rig.volumes(cvs) / rig.rest_volume - 1.0).max(axis=0)
    print(f"\n{clip.name}, {clip.num_frames} frames: fit rms (mm) {(rig.fit_rms * 1e3).round(3)}")
    print(f"  max |V / V_rest - 1| per muscle {rig.names}")
    for rule, d in drift.items():
        print(f"  {rule:7s}", "  ".join(f"{x:.1e}" for x in d))
    assert drift["exact"].max() < 0.01
    assert drift["thesis"].max() > 0.05      # the motion does flex these joints
