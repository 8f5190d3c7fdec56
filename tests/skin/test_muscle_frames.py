"""Muscle ellipsoid frames for the shell deformer (rig/skin/shell/frames.py).

A synthetic two-bone arm (tests/arm_muscles.py). References: solid moments against
trimesh's mass properties; the affine fit against np.linalg.lstsq per muscle; the nearest curve
parameter against a dense sampling; the star tables against a brute-force NumPy ray-triangle test
(Moller-Trumbore) of every ray against every triangle.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from arm_muscles import ARM_BIND, arm_world, biceps, brachio, fibonacci_sphere, spec_from_ellipsoid
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.model import MuscleSpec, build_muscle_rig, curve_basis
from jiggle.rig.skin.shell.frames import (
    REASONS,
    TRAJECTORY_U,
    MuscleFrames,
    curve_points,
    nearest_parameter,
    rest_ellipsoids,
    solid_ellipsoids,
    solid_moments,
    star_directions,
    star_tables,
    trajectory,
)
from jiggle.rig.skin.shell.shells import STAR_PHI, STAR_THETA, TRAJECTORY_SAMPLES, ShellFrames, star_lookup


def rigid(rotvec, t) -> np.ndarray:
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    g[:3, 3] = t
    return g


def frame_of(frames, rig, world, cvs=None):
    """ShellFrames and skipped records for joint transforms `world`, static CVs unless `cvs` given."""
    s = rig.static(world)
    return frames.frame(world, s.cvs if cvs is None else cvs, s.curve)


@pytest.fixture(scope="module")
def arm():
    """Three muscles: biceps (straight action curve), brachio (bends across the elbow) and a biceps
    copy riding the forearm as its bone."""
    rig = build_muscle_rig([biceps(), brachio(), dataclasses.replace(biceps(), name="fore", bone=1)], ARM_BIND)
    return rig, MuscleFrames.build(rig, ARM_BIND)


# ---------------------------------------------------------------------------------- rest ellipsoids
def test_solid_moments_match_trimesh():
    rng = np.random.default_rng(3)
    theta = 2 * np.pi * np.arange(8) / 8
    cvs = np.zeros((2, 5, 8, 3))
    cvs[..., 0] = 0.03 * np.cos(theta)
    cvs[..., 1] = 0.02 * np.sin(theta)
    cvs[..., 2] = 0.05 * np.arange(5)[:, None]
    cvs += rng.normal(scale=0.004, size=cvs.shape) + (0.5, -1.0, 2.0)      # far from the origin
    pts = loft.points(cvs)
    volume, centre, cov = solid_moments(pts, loft.FACES)
    for m in range(2):
        mesh = trimesh.Trimesh(pts[m], loft.FACES, process=False)
        # trimesh's inertia (density 1) about the centre of mass: I = tr(C) Id - C, C = int x x^T dV
        C = np.trace(mesh.moment_inertia) / 2 * np.eye(3) - mesh.moment_inertia
        assert volume[m] == pytest.approx(mesh.volume, rel=1e-12)
        assert np.abs(centre[m] - mesh.center_mass).max() < 1e-12
        assert np.abs(cov[m] * volume[m] - C).max() < 1e-12 * np.abs(C).max()


def test_solid_ellipsoid_of_an_ellipsoid_mesh_is_exact_up_to_tessellation():
    """radii = sqrt(5 lambda): exact for a solid ellipsoid; a fine icosphere mesh is within 0.2%."""
    axes = Rotation.from_rotvec([0.4, -0.7, 0.2]).as_matrix()             # columns: the true axes
    radii = np.array([0.05, 0.02, 0.12])                                  # x middle, y short, z long
    sphere = trimesh.creation.icosphere(subdivisions=5)
    pts = (np.asarray(sphere.vertices) * radii) @ axes.T + (0.3, 0.1, -0.2)
    E = solid_ellipsoids(pts[None], np.asarray(sphere.faces), axes[:, 2][None], axes[:, 0][None])[0]
    assert np.abs(E[:3, 3] - (0.3, 0.1, -0.2)).max() < 1e-9
    assert np.allclose(np.linalg.norm(E[:3, :3], axis=0), radii, rtol=2e-3)
    assert np.allclose(E[:3, :3] / np.linalg.norm(E[:3, :3], axis=0), axes, atol=1e-6)
    assert np.array_equal(E[3], [0, 0, 0, 1])


def test_rest_ellipsoid_of_a_lofted_ellipsoid():
    """A muscle fitted to an analytic ellipsoid (tilted in space) gives back its centre, axes and radii;
    the radii within 3% (the loft's 16-sided rings hold ~97% of the volume, and its 8-CV rings
    round an eccentric section a little)."""
    R = Rotation.from_rotvec([0.3, 0.2, -0.5]).as_matrix()
    centre = np.array([0.01, 0.04, -0.16])
    long_axis, up = R @ (0, 0, -1.0), R @ (0, 1.0, 0)
    radii = np.array([0.10, 0.03, 0.025])                                 # long, along up, across
    ends = [centre - radii[0] * long_axis, centre + radii[0] * long_axis]
    spec = spec_from_ellipsoid("e", ends, up, radii[1:], bones=(0, 0, 0, 1), origin=ends[0] - 0.02 * long_axis,
                               insertion=ends[1] + 0.05 * long_axis)
    rig = build_muscle_rig([spec], ARM_BIND)
    E = rest_ellipsoids(rig)[0]
    cols = E[:3, :3]
    got = np.linalg.norm(cols, axis=0)
    unit = cols / got
    print(f"\nlofted ellipsoid: radii / true {got / radii[[1, 2, 0]]}, centre off by "
          f"{np.linalg.norm(E[:3, 3] - centre) * 1e3:.4f} mm")
    assert np.linalg.norm(E[:3, 3] - centre) < 1e-3 * radii[2]
    # convention: z the long axis toward the insertion, x the middle axis toward `up`, y = z x x
    angle = lambda a, b: np.degrees(np.arccos(np.clip(a @ b, -1, 1)))  # noqa: E731
    assert angle(unit[:, 2], long_axis) < 2 and angle(unit[:, 0], up) < 2
    assert angle(unit[:, 1], np.cross(long_axis, up)) < 2
    assert np.allclose(np.cross(unit[:, 2], unit[:, 0]), unit[:, 1], atol=1e-12)
    assert np.allclose(got, radii[[1, 2, 0]], rtol=0.03)


# ---------------------------------------------------------------------------------- per frame
def test_bind_pose_gives_no_change(arm):
    rig, frames = arm
    sf, skipped = frame_of(frames, rig, ARM_BIND)
    assert isinstance(sf, ShellFrames) and skipped == ()
    assert np.abs(sf.E_ref - frames.E_rest).max() < 1e-12
    assert np.abs(sf.E_cur - sf.E_ref).max() < 1e-12
    assert np.abs(sf.E_cur_inv - sf.E_ref_inv).max() < 1e-9      # local units: 1/radius ~ 50 per metre
    assert sf.active.all()
    # the three muscles are symmetric along their action curves: their centres sit at its middle
    assert np.abs(frames.t0 - 0.5).max() < 1e-3
    assert sf.curve.shape == (3, TRAJECTORY_SAMPLES, 3)
    assert np.abs(sf.curve - sf.E_ref[:, None, :3, 3]).max() < 1e-12
    for E, Einv in ((sf.E_ref, sf.E_ref_inv), (sf.E_cur, sf.E_cur_inv)):
        assert np.abs(E @ Einv - np.eye(4)).max() < 1e-12


def test_rigid_motion_of_the_whole_skeleton_changes_nothing_relative(arm):
    rig, frames = arm
    g = rigid([0.3, -1.1, 0.7], (0.4, -2.0, 1.1))
    sf, _ = frame_of(frames, rig, arm_world(0, root=g))
    # the deformer sees no change when nothing moves relative to its bone
    assert np.abs(sf.E_ref - g @ frames.E_rest).max() < 1e-9
    assert np.abs(sf.E_cur - g @ frames.E_rest).max() < 1e-9
    assert np.abs(sf.curve - (g[:3, :3] @ frames.E_rest[:, :3, 3, None])[:, None, :, 0] - g[:3, 3]).max() < 1e-9
    # a bent pose moved as a whole moves its frames rigidly too
    bent, _ = frame_of(frames, rig, arm_world(75))
    moved, _ = frame_of(frames, rig, arm_world(75, root=g))
    for k in ("E_ref", "E_cur"):
        assert np.abs(getattr(moved, k) - g @ getattr(bent, k)).max() < 1e-9
    assert np.abs(moved.curve - (bent.curve @ g[:3, :3].T + g[:3, 3])).max() < 1e-9


def test_bent_elbow_moves_the_frames(arm):
    """E_ref rides the bone: the biceps' (bone 0, the upper arm) stays put, the forearm muscle's turns
    with the forearm; E_cur follows the CVs: the biceps shortens and bulges."""
    rig, frames = arm
    w = arm_world(90)
    sf, skipped = frame_of(frames, rig, w)
    assert skipped == () and sf.active.all()
    assert np.abs(sf.E_ref[0] - frames.E_rest[0]).max() < 1e-12
    K = w[1] @ np.linalg.inv(ARM_BIND[1])
    assert np.abs(sf.E_ref[2] - K @ frames.E_rest[2]).max() < 1e-12
    L_ref, L_cur = sf.E_ref[0, :3, :3], sf.E_cur[0, :3, :3]
    along = np.linalg.norm(L_cur[:, 2]) / np.linalg.norm(L_ref[:, 2])
    across = np.linalg.norm(L_cur[:, :2], axis=0) / np.linalg.norm(L_ref[:, :2], axis=0)
    assert along < 0.9 and np.all(across > 1.05)


def test_affine_fit_matches_least_squares(arm):
    rig, frames = arm
    rng = np.random.default_rng(7)
    rest = rig.rest_cvs.reshape(3, 40, 3)
    # an affine map per muscle is reproduced exactly: E_cur = A @ E_rest
    A = np.tile(np.eye(4), (3, 1, 1))
    A[:, :3, :3] += rng.normal(scale=0.2, size=(3, 3, 3))
    A[:, :3, 3] = rng.normal(scale=0.1, size=(3, 3))
    cvs = np.einsum("mij,mkj->mki", A[:, :3, :3], rest) + A[:, None, :3, 3]
    sf, skipped = frame_of(frames, rig, ARM_BIND, cvs.reshape(-1, 3))
    assert skipped == ()
    assert np.abs(sf.E_cur - A @ frames.E_rest).max() < 1e-12
    assert np.abs(sf.E_cur @ sf.E_cur_inv - np.eye(4)).max() < 1e-10
    # any motion: the least-squares affine map, as lstsq finds it on homogeneous rest CVs
    cvs = rest + rng.normal(scale=0.005, size=rest.shape)
    sf, _ = frame_of(frames, rig, ARM_BIND, cvs.reshape(-1, 3))
    for m in range(3):
        X = np.hstack([rest[m], np.ones((40, 1))])
        sol = np.linalg.lstsq(X, cvs[m], rcond=None)[0]                   # (4, 3): y = [x, 1] @ sol
        ref = np.eye(4)
        ref[:3] = sol.T
        assert np.abs(sf.E_cur[m] - ref @ frames.E_rest[m]).max() < 1e-12


def test_scaled_muscle_gives_a_scaled_ellipsoid(arm):
    rig, frames = arm
    c = frames.E_rest[1, :3, 3]
    cvs = np.array(rig.rest_cvs)
    cvs[40:80] = c + 1.1 * (cvs[40:80] - c)
    sf, _ = frame_of(frames, rig, ARM_BIND, cvs)
    expect = np.array(sf.E_ref[1])
    expect[:3, :3] *= 1.1                                                 # scaled about the centre
    assert np.abs(sf.E_cur[1] - expect).max() < 1e-12
    assert np.abs(sf.E_cur[[0, 2]] - sf.E_ref[[0, 2]]).max() < 1e-12


def collapse(kind: str, cvs: np.ndarray) -> np.ndarray:
    """One muscle's CVs (40, 3) made unusable in one way."""
    cvs = np.array(cvs)
    c = cvs.mean(axis=0)
    if kind == "nan":
        cvs[7, 1] = np.nan
    elif kind == "inf":
        cvs[0, 0] = np.inf
    elif kind == "point":
        cvs[:] = c
    elif kind == "plane":                                                 # flattened onto a plane
        n = np.array([0.0, 1.0, 0.0])
        cvs -= np.outer((cvs - c) @ n, n)
    elif kind == "mirror":
        cvs[:, 0] = 2 * c[0] - cvs[:, 0]
    elif kind == "blown":
        cvs = c + 2000.0 * (cvs - c)
    return cvs


@pytest.mark.parametrize("kind, reason", [("nan", 1), ("inf", 1), ("point", 2), ("plane", 2), ("mirror", 4),
                                          ("blown", 3)])
def test_degenerate_muscle_is_skipped(arm, kind, reason):
    rig, frames = arm
    w = arm_world(40)
    s = rig.static(w)
    good, _ = frames.frame(w, s.cvs, s.curve)
    cvs = np.array(s.cvs)
    cvs[40:80] = collapse(kind, cvs[40:80])
    sf, skipped = frames.frame(w, cvs, s.curve, frame=12)
    assert list(sf.active) == [True, False, True]
    for k in ("E_ref", "E_ref_inv", "E_cur", "E_cur_inv", "curve"):
        x = getattr(sf, k)
        assert np.isfinite(x).all()
        assert np.array_equal(x[[0, 2]], getattr(good, k)[[0, 2]])         # the others are unaffected
    assert np.array_equal(sf.E_cur[1], sf.E_ref[1]) and np.array_equal(sf.E_cur_inv[1], sf.E_ref_inv[1])
    assert np.array_equal(sf.curve[1], np.broadcast_to(sf.E_ref[1, :3, 3], (TRAJECTORY_SAMPLES, 3)))
    (rec,) = skipped
    assert (rec.frame, rec.muscle, rec.name, rec.reason) == (12, 1, "brachio", reason)
    assert rec.message.startswith("frame 12: muscle 'brachio' skipped: " + REASONS[reason])


def test_non_finite_action_curve_skips_the_muscle(arm):
    rig, frames = arm
    s = rig.static(ARM_BIND)
    curve = np.array(s.curve)
    curve[2, 3, 2] = np.nan
    sf, skipped = frames.frame(ARM_BIND, s.cvs, curve)
    assert list(sf.active) == [True, True, False] and np.isfinite(sf.curve).all()
    assert [(r.muscle, r.reason) for r in skipped] == [(2, 1)]


def test_batch_equals_single_frames(arm):
    rig, frames = arm
    world = np.stack([arm_world(a) for a in (0, 30, 75, 120, 140)])
    s = rig.static(world)
    cvs = np.array(s.cvs)
    cvs[3, 45] = np.nan                                                   # brachio, batch frame 3
    batch, skipped = frames.frames(world, cvs, s.curve, first_frame=100)
    assert len(batch) == 5
    assert [(r.frame, r.muscle) for r in skipped] == [(103, 1)]
    for t in range(5):
        one, _ = frames.frame(world[t], cvs[t], s.curve[t])
        for k in ("E_ref", "E_ref_inv", "E_cur", "E_cur_inv", "curve", "active"):
            assert np.abs(getattr(batch[t], k).astype(float) - getattr(one, k)).max() < 1e-13


# ---------------------------------------------------------------------------------- trajectory
def random_curves(rng, n):
    """(n, 5, 3) mildly bent action curves: CVs along a ~0.35 m chord with ~1 cm sideways offsets."""
    base = np.linspace(0, 1, 5)[:, None] * rng.normal(size=(n, 1, 3)) * 0.2
    return base + rng.normal(scale=0.01, size=(n, 5, 3))


def test_curve_points_match_the_b_spline():
    rng = np.random.default_rng(2)
    curve = random_curves(rng, 4)
    t = np.concatenate([[0.0, 0.5, 1.0], rng.random(20)])
    for d in range(3):
        got = curve_points(curve, np.broadcast_to(t, (4, len(t))), 2)[d]
        assert np.abs(got - np.einsum("nj,mjc->mnc", curve_basis(t, d), curve)).max() < 1e-12


def test_nearest_parameter_finds_the_foot_point():
    """p = C(t*) + 1 cm along a normal of the curve at t*: t* is the foot point; Newton started within
    0.1 of it finds it. Beyond an end the end is nearest (clamped)."""
    rng = np.random.default_rng(5)
    curve = random_curves(rng, 200)
    t_true = rng.uniform(0.05, 0.95, 200)
    C, d1 = (x[:, 0] for x in curve_points(curve, t_true[:, None], 1))
    off = np.cross(d1, rng.normal(size=(200, 3)))
    p = C + 0.01 * off / np.linalg.norm(off, axis=1, keepdims=True)
    t = nearest_parameter(curve, p, np.clip(t_true + rng.uniform(-0.1, 0.1, 200), 0, 1))
    assert np.abs(t - t_true).max() < 1e-10
    # a dense sampling agrees (up to its spacing) where the foot point is the global nearest
    dense = np.linspace(0, 1, 4001)
    pts = curve_points(curve, np.broadcast_to(dense, (200, len(dense))))[0]
    best = dense[np.argmin(np.linalg.norm(pts - p[:, None], axis=2), axis=1)]
    assert np.mean(np.abs(best - t) < 5e-4) > 0.95
    end = 2 * curve[:, 4] - curve[:, 3]                                     # past the end, along its tangent
    assert np.all(nearest_parameter(curve, end, np.full(200, 0.9)) == 1.0)


def test_trajectory_ends_are_exact_and_a_straight_curve_gives_a_segment():
    rng = np.random.default_rng(9)
    a, b = rng.normal(size=3), rng.normal(size=3)
    curve = a + np.array([0, 0.125, 0.5, 0.875, 1.0])[:, None] * (b - a)  # the rig's straight curve
    t0, t1 = 0.3, 0.8
    cr, cc = curve_points(curve, np.array([t0, t1]))[0]                    # centres on the curve
    c = trajectory(curve, np.array(t0), np.array(t1), cr, cc)
    assert c.shape == (TRAJECTORY_SAMPLES, 3)
    assert np.array_equal(c[0], cr) and np.array_equal(c[-1], cc)
    along = (c - cr) @ (cc - cr) / np.sum((cc - cr) ** 2)
    assert np.abs(c - (cr + along[:, None] * (cc - cr))).max() < 1e-12   # on the segment
    assert np.all(np.diff(along) > 0) and along[0] == 0 and abs(along[-1] - 1) < 1e-15
    # centres off the curve: the ends are still exact
    cr2, cc2 = cr + rng.normal(size=3), cc + rng.normal(size=3)
    c2 = trajectory(curve, np.array(t0), np.array(t1), cr2, cc2)
    assert np.array_equal(c2[0], cr2) and np.array_equal(c2[-1], cc2)


def test_trajectory_bows_with_the_bent_action_curve(arm):
    """Brachio's CVs slide 2 cm along its action curve (as a lagging simulated muscle might), so t_cur
    moves off the reference centre's foot t0 on the current curve. The path's middle sample leaves the chord by C's own bow between t0 and t_cur:
    d = c(1/2) - (c(0) + c(1)) / 2 = C((t0 + t_cur) / 2) - (C(t0) + C(t_cur)) / 2. Measure: d_perp, the
    part of d across the chord c(1) - c(0). With the elbow bent 110 deg it is > 0.4 mm and lies on
    the side away from C's centre of curvature (the side the curve bows to: -C'' across the chord);
    with the elbow straight (a straight curve) it is 0."""
    rig, frames = arm
    perp = {}
    for angle in (0, 110):
        w = arm_world(angle)
        s = rig.static(w)
        curve = s.curve[1]
        tangent = curve_points(curve, np.array([0.5]), 1)[1][0]
        cvs = np.array(s.cvs)
        cvs[40:80] += 0.02 * tangent / np.linalg.norm(tangent)
        sf, _ = frames.frame(w, cvs, s.curve)
        c = sf.curve[1]
        assert np.array_equal(c[0], sf.E_ref[1, :3, 3]) and np.array_equal(c[-1], sf.E_cur[1, :3, 3])
        t0 = nearest_parameter(curve, sf.E_ref[1, :3, 3], frames.t0[1])    # the reference centre's foot
        t_cur = nearest_parameter(curve, sf.E_cur[1, :3, 3], frames.t0[1])
        assert 0.05 < t_cur - t0 < 0.45
        C = lambda t, k=0: curve_points(curve, np.array([t]), 2)[k][0]  # noqa: E731
        d = c[TRAJECTORY_SAMPLES // 2] - (c[0] + c[-1]) / 2
        assert np.abs(d - (C((t0 + t_cur) / 2) - (C(t0) + C(t_cur)) / 2)).max() < 1e-12
        chord = (c[-1] - c[0]) / np.linalg.norm(c[-1] - c[0])
        across = lambda v: v - (v @ chord) * chord  # noqa: E731
        perp[angle] = across(d)
        if angle:
            out = -across(C((t0 + t_cur) / 2, 2))                         # away from the centre of curvature
            assert perp[angle] @ out > 0.9 * np.linalg.norm(perp[angle]) * np.linalg.norm(out)
    print(f"\ntrajectory bow across the chord (mm): elbow 0 deg {np.linalg.norm(perp[0]) * 1e3:.2e}, "
          f"110 deg {np.linalg.norm(perp[110]) * 1e3:.3f}")
    assert np.linalg.norm(perp[110]) > 4e-4
    assert np.linalg.norm(perp[0]) < 1e-12


# ---------------------------------------------------------------------------------- star tables
def star_reference(points, faces, E) -> np.ndarray:
    """(17, 32) star table of one mesh: every ray against every triangle (Moller-Trumbore), furthest hit."""
    u = star_directions().reshape(-1, 3)
    L = u @ E[:3, :3].T
    n = np.linalg.norm(L, axis=1)
    d = L / n[:, None]
    tri = points[faces]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d[:, None], e2[None])
    det = np.einsum("rfi,fi->rf", h, e1)
    s = E[:3, 3] - v0
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.einsum("fi,rfi->rf", s, h) / det
        q = np.cross(s, e1)
        b = np.einsum("ri,fi->rf", d, q) / det
        t = np.einsum("fi,fi->f", e2, q)[None] / det
        hit = (a >= 0) & (b >= 0) & (a + b <= 1) & (t > 0) & (np.abs(det) > 1e-18)
    far = np.where(hit, t, -np.inf).max(axis=1)
    # along the ray the local radius grows as distance / |L u|
    return np.where(np.isfinite(far), far / n - 1, 0.0).reshape(STAR_THETA, STAR_PHI)


def test_star_table_of_an_ellipsoid_is_nearly_flat(arm):
    rig, frames = arm
    assert frames.star.shape == (3, STAR_THETA, STAR_PHI) and frames.star.dtype == np.float32
    assert list(frames.star_index) == [0, 1, 2]
    print(f"\nstar |delta| max per muscle {np.abs(frames.star).max(axis=(1, 2))}")
    assert np.abs(frames.star).max() < 0.05
    pts = rig.surface(rig.rest_cvs)
    for m in range(3):
        assert np.abs(frames.star[m] - star_reference(pts[m], rig.surface_faces, frames.E_rest[m])).max() < 1e-5
    # the poles: every azimuth of row 0 (and 16) is the same ray
    assert np.ptp(frames.star[:, 0], axis=1).max() < 1e-6 and np.ptp(frames.star[:, -1], axis=1).max() < 1e-6


def bumpy_spec() -> MuscleSpec:
    """The biceps with a bump on its up side (local +x) halfway along: surface points within ~0.45
    (unit-sphere distance) of that spot pushed out by up to 60% of the up radius."""
    spec = biceps()
    centre, axis = spec.ends.mean(axis=0), spec.ends[1] - spec.ends[0]
    axis = axis / np.linalg.norm(axis)
    up = spec.up - (spec.up @ axis) * axis
    up /= np.linalg.norm(up)
    radii = np.array([np.linalg.norm(spec.ends[1] - spec.ends[0]) / 2, 0.025, 0.02])
    axes = np.stack([axis, up, np.cross(axis, up)])
    q = fibonacci_sphere(1500)
    bump = 0.6 * radii[1] * np.exp(-np.sum((q - (0, 1, 0)) ** 2, axis=1) / (2 * 0.3 ** 2))
    surface = centre + (q * radii) @ axes + bump[:, None] * up
    return dataclasses.replace(spec, name="bumpy", surface=surface)


def test_star_table_shows_a_bump():
    rig = build_muscle_rig([bumpy_spec()], ARM_BIND)
    frames = MuscleFrames.build(rig, ARM_BIND)
    table = frames.star[0]
    ref = star_reference(rig.surface(rig.rest_cvs)[0], rig.surface_faces, frames.E_rest[0])
    assert np.abs(table - ref).max() < 1e-5
    # the bump is at local +x (the up side): theta = pi / 2 (row 8), phi = 0 (column 16)
    ring = table[STAR_THETA // 2]
    print(f"\nbump: delta at +x {ring[16]:.3f}, at -x {ring[0]:.3f}, ring max at column {int(np.argmax(ring))}")
    assert ring[16] > 0.1
    assert ring[16] > ring[0] + 0.1 and ring[16] > ring[8] + 0.1 and ring[16] > ring[24] + 0.1
    assert abs(int(np.argmax(ring)) - 16) <= 1
    # the bilinear lookup reads the node values back
    th, ph = np.pi / 2, 0.0
    u = np.array([[np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]])
    assert star_lookup(frames.star, frames.star_index[:1], u)[0] == pytest.approx(ring[16], abs=1e-6)


def test_star_table_takes_the_furthest_hit():
    """A ray that crosses the surface several times reads its last crossing: a unit sphere with a
    second sphere (radius 0.5) centred 3 along +z, given as one mesh. The pole ray (theta = 0) leaves
    the first sphere at 1, then crosses the second at 2.5 and 3.5: delta = 2.5; the opposite pole
    reads the unit sphere (delta ~ 0)."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    points = np.concatenate([v, 0.5 * v + (0, 0, 3.0)])[None]
    faces = np.concatenate([f, f + len(v)])
    table = star_tables(points, faces, np.eye(4)[None])[0]
    assert table[0] == pytest.approx(np.full(STAR_PHI, 2.5), abs=1e-5)
    assert np.abs(table[-1]).max() < 1e-5
    assert np.abs(table - star_reference(points[0], faces, np.eye(4))).max() < 1e-5


def test_star_selection():
    rig = build_muscle_rig([biceps(), brachio()], ARM_BIND)
    none = MuscleFrames.build(rig, ARM_BIND, star=False)
    assert none.star.shape == (0, STAR_THETA, STAR_PHI) and list(none.star_index) == [-1, -1]
    some = MuscleFrames.build(rig, ARM_BIND, star=[False, True])
    assert list(some.star_index) == [-1, 0]
    full = MuscleFrames.build(rig, ARM_BIND)
    assert np.array_equal(some.star[0], full.star[1])
    with pytest.raises(InputError, match="star must be"):
        MuscleFrames.build(rig, ARM_BIND, star=[True])
    assert star_tables(np.zeros((0, loft.POINTS, 3)), loft.FACES, np.zeros((0, 4, 4))).shape == (0, 17, 32)


# ---------------------------------------------------------------------------------- carried rest CVs
def test_carried_rest_cvs(arm):
    rig, frames = arm
    assert np.abs(frames.carried_rest_cvs(ARM_BIND) - rig.rest_cvs).max() < 1e-15
    g = rigid([-0.5, 0.2, 1.3], (1.0, 0.5, -0.3))
    moved = arm_world(0, root=g)
    assert np.abs(frames.carried_rest_cvs(moved) - rig.static(moved).cvs).max() < 1e-9
    # each muscle rides its own bone rigidly: the forearm copy turns with the forearm
    world = np.stack([arm_world(a) for a in (0, 90)])
    carried = frames.carried_rest_cvs(world)
    assert carried.shape == (2, 120, 3)
    K = world[1, 1] @ np.linalg.inv(ARM_BIND[1])
    assert np.abs(carried[1, 80:] - (rig.rest_cvs[80:] @ K[:3, :3].T + K[:3, 3])).max() < 1e-15
    assert np.abs(carried[1, :80] - rig.rest_cvs[:80]).max() < 1e-15


# ---------------------------------------------------------------------------------- input
def test_bad_input_is_refused(arm):
    rig, frames = arm
    s = rig.static(ARM_BIND)
    with pytest.raises(InputError, match="bind_world must be"):
        MuscleFrames.build(rig, ARM_BIND[:2])
    with pytest.raises(InputError, match="world transforms must be"):
        frames.frame(ARM_BIND[:2], s.cvs, s.curve)
    with pytest.raises(InputError, match="world transforms must be"):
        frames.frame(ARM_BIND[None], s.cvs, s.curve)
    with pytest.raises(InputError, match="cvs must be"):
        frames.frame(ARM_BIND, s.cvs[:40], s.curve)
    with pytest.raises(InputError, match="curve must be"):
        frames.frames(ARM_BIND[None], s.cvs[None], s.curve)
    bad = ARM_BIND.copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        frames.frame(bad, s.cvs, s.curve)


def test_a_rig_without_muscles():
    rig = build_muscle_rig([], ARM_BIND)
    frames = MuscleFrames.build(rig, ARM_BIND)
    sf, skipped = frames.frame(ARM_BIND, np.zeros((0, 3)), np.zeros((0, 5, 3)))
    assert sf.E_ref.shape == (0, 4, 4) and sf.curve.shape == (0, TRAJECTORY_SAMPLES, 3) and skipped == ()
    assert frames.carried_rest_cvs(ARM_BIND).shape == (0, 3)
    assert len(TRAJECTORY_U) == TRAJECTORY_SAMPLES
