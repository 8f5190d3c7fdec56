"""Shell deformers (rig/skin/shell/shells.py, rig/skin/shell/kernels.py, rig/skin/shell/deformer.py).

References (module docstring of rig.skin.shell.shells): f(x) = (1 - x^2)^2 on [0, 1];
beta = 1 for rho <= 1 + h d, 0 for rho >= 1 + d, f((rho - 1 - h d) / ((1 - h) d)) between;
alpha = 1 for rho <= 1, 0 for rho >= 1 + d, f((rho - 1) / d) between;
q(p_l) = p_l + beta(rho) (r_s - r) u with r_s = 1 + delta + (1 - s) d; the paper's absolute basic
deformation p'_l = p_l + w w_i (q - p_l); the skin gets relative displacements
basic D = k [E_cur q(E_cur^-1 p) - E_ref q(E_ref^-1 p)], stretch D = k a (E_cur - E_ref) (q, 1),
trajectory D = k [c(a) - c(0) + a (L_cur - L_ref) q], a = alpha^l (0 where alpha = 0), k = w w_i,
applied in series over a vertex's pairs. The kernel runs in float32: against the float64 reference
it is held to 1e-5 of the scene size (~1 m here).
"""
from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.shell_params import MODES, ShellParams
from jiggle.rig.skin.shell.deformer import ShellDeformer
from jiggle.rig.skin.shell.shells import (
    STAR_PHI,
    STAR_THETA,
    TRAJECTORY_SAMPLES,
    ShellFrames,
    alpha,
    basic_local,
    beta,
    cull_pairs,
    falloff,
    pair_displacement,
    project,
    shell_numpy,
    shell_table,
    star_lookup,
)

K = TRAJECTORY_SAMPLES
SCENE_TOL = 1e-5  # metres, for a scene ~1 m across (float32 kernel vs float64 reference)


# ---------------------------------------------------------------------------------------------
# helpers


def unit_dirs(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def affine(rotation=np.eye(3), scale=(1.0, 1.0, 1.0), centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 ellipsoid: local unit sphere -> world, E = [R diag(scale) | centre]."""
    E = np.eye(4)
    E[:3, :3] = np.asarray(rotation) @ np.diag(scale)
    E[:3, 3] = centre
    return E


def translated(E, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T @ E


def straight_curve(E_ref, E_cur) -> np.ndarray:
    """(M, K, 3) samples of the straight path between the two centres."""
    u = np.linspace(0.0, 1.0, K)[None, :, None]
    return E_ref[:, None, :3, 3] * (1.0 - u) + E_cur[:, None, :3, 3] * u


def make_frames(E_ref, E_cur, curve=None, active=None) -> ShellFrames:
    E_ref, E_cur = np.asarray(E_ref, float), np.asarray(E_cur, float)
    M = E_ref.shape[0]
    return ShellFrames(E_ref, np.linalg.inv(E_ref), E_cur, np.linalg.inv(E_cur),
                       straight_curve(E_ref, E_cur) if curve is None else curve,
                       np.ones(M, bool) if active is None else active)


def all_pairs(V, M):
    """CSR with every vertex paired with every muscle, in muscle order."""
    return (np.arange(V + 1, dtype=np.int32) * M, np.tile(np.arange(M, dtype=np.int32), V),
            np.ones(V * M, np.float32))


def random_star(rng, S, amplitude=0.15):
    """Small random star tables whose pole rows are constant (one direction has one offset)."""
    star = rng.uniform(-amplitude, amplitude, size=(S, STAR_THETA, STAR_PHI))
    star[:, 0, :] = star[:, 0, :1]
    star[:, -1, :] = star[:, -1, :1]
    return star.astype(np.float32)


def points_at_local(E, p_l):
    return p_l @ E[:3, :3].T + E[:3, 3]


# ---------------------------------------------------------------------------------------------
# falloff, beta, alpha


def test_falloff_values_and_ends():
    x = np.array([-3.0, 0.0, 0.5, 1.0, 4.0])
    np.testing.assert_allclose(falloff(x), [1.0, 1.0, 0.5625, 0.0, 0.0], atol=0.0)


def test_beta_is_one_inside_hard_zero_beyond_drop_off():
    h, d = 0.4, 0.8
    rho = np.linspace(-1.0, 1.0 + h * d, 50)
    assert np.all(beta(rho, h, d) == 1.0)
    rho = np.linspace(1.0 + d, 5.0, 50)
    assert np.all(beta(rho, h, d) == 0.0)
    between = beta(np.linspace(1.0 + h * d, 1.0 + d, 50)[1:-1], h, d)
    assert np.all((between > 0.0) & (between < 1.0)) and np.all(np.diff(between) < 0.0)


@pytest.mark.parametrize("fn,edges", [
    (lambda r: beta(r, 0.3, 0.7), (1.0 + 0.3 * 0.7, 1.7)),
    (lambda r: alpha(r, 0.7), (1.0, 1.7)),
])
def test_beta_alpha_continuous_and_c1_at_the_shells(fn, edges):
    # f(0) = 1, f(1) = 0 and f'(0) = f'(1) = 0 (f''(0) = -4, f''(1) = 8): across a shell the value
    # changes by O(eps^2) and one-sided difference quotients vanish like <= 4 eps / w^2 (w the width
    # of the transition); a kink would leave them ~ 1 / w, a jump ~ 1 / eps
    w = edges[1] - edges[0]
    for edge in edges:
        f0 = fn(np.array([edge]))[0]
        for eps in (1e-3, 1e-4):
            left = (f0 - fn(np.array([edge - eps]))[0]) / eps
            right = (fn(np.array([edge + eps]))[0] - f0) / eps
            assert abs(left) <= 4.5 * eps / w ** 2 and abs(right) <= 4.5 * eps / w ** 2
            jump = abs(fn(np.array([edge + eps]))[0] - fn(np.array([edge - eps]))[0])
            assert jump <= 4.5 * eps ** 2 / w ** 2
    # inside the transition the slope is the analytic one: d/drho f((rho - a) / w) = f'(x) / w
    a, b = edges
    mid = 0.5 * (a + b)
    x = 0.5
    slope = (fn(np.array([mid + 1e-6]))[0] - fn(np.array([mid - 1e-6]))[0]) / 2e-6
    np.testing.assert_allclose(slope, -4.0 * x * (1.0 - x * x) / (b - a), rtol=1e-6)


def test_beta_without_transition_region_is_a_clean_step():
    rho = np.concatenate([np.linspace(0.0, 3.0, 301), [1.5, 1.5 + 1e-15]])
    with np.errstate(all="raise"):
        b = beta(rho, 1.0, 0.5)
    assert np.all(np.isfinite(b))
    np.testing.assert_array_equal(b, np.where(rho <= 1.5, 1.0, 0.0))


def test_beta_alpha_broadcast_per_point_parameters():
    rho = np.array([1.2, 1.2, 1.2])
    h = np.array([0.0, 0.5, 1.0])
    d = np.array([1.0, 0.4, 0.1])
    np.testing.assert_allclose(beta(rho, h, d), [falloff(0.2), 1.0, 0.0])
    np.testing.assert_allclose(alpha(rho, d), [falloff(0.2), falloff(0.5), 0.0])


# ---------------------------------------------------------------------------------------------
# Figure 7 behaviours of the paper's absolute basic deformation (basic_local)


def inside_hard(rng, params, n=200):
    """Random local points strictly inside the hard shell (not at the centre)."""
    r = rng.uniform(0.05, 1.0 + params.hard * params.drop_off - 1e-6, n)
    return unit_dirs(rng, n) * r[:, None]


@pytest.mark.parametrize("s", [0.0, 0.3, 1.0])
def test_fig7_rest_points_inside_hard_land_on_the_sticky_shell(s):
    # (a) with w = wi = 1 every point inside the hard shell lands on radius 1 + (1 - s) d;
    # (b) s = 0 is the drop-off shell 1 + d; (c) s = 1 collapses them onto the unit sphere
    rng = np.random.default_rng(1)
    params = ShellParams(sticky=s, hard=0.5, drop_off=0.8)
    p = inside_hard(rng, params)
    out = basic_local(p, params)
    r_out = np.linalg.norm(out, axis=1)
    np.testing.assert_allclose(r_out, 1.0 + (1.0 - s) * 0.8, atol=1e-12)
    # moved radially: same direction
    np.testing.assert_allclose(out / r_out[:, None], p / np.linalg.norm(p, axis=1)[:, None], atol=1e-12)
    # and nothing beyond the drop-off shell moves
    far = unit_dirs(rng, 50) * rng.uniform(1.8, 4.0, 50)[:, None]
    np.testing.assert_array_equal(basic_local(far, params), far)


def test_fig7_star_offsets_move_the_sticky_shell_with_the_muscle_surface():
    rng = np.random.default_rng(2)
    star = np.full((STAR_THETA, STAR_PHI), 0.2)
    params = ShellParams(sticky=0.5, hard=0.5, drop_off=1.0)
    p = unit_dirs(rng, 100) * rng.uniform(0.1, 1.69, 100)[:, None]  # rho <= 1.5 (hard, from 1.2)
    r = np.linalg.norm(basic_local(p, params, star=star), axis=1)
    np.testing.assert_allclose(r, 1.2 + 0.5, atol=1e-12)


def test_fig7_larger_drop_off_widens_the_attenuation_region():
    # (d) radial sweep: a point between the old (1 + 0.5) and the new (1 + 1) drop-off shell moves
    # only with the larger d, and the set of moved points grows
    rng = np.random.default_rng(3)
    u = unit_dirs(rng, 1)
    r = np.linspace(0.05, 3.0, 400)
    p = r[:, None] * u
    small, large = ShellParams(sticky=0.5, drop_off=0.5), ShellParams(sticky=0.5, drop_off=1.0)
    moved_small = np.linalg.norm(basic_local(p, small) - p, axis=1) > 0.0
    moved_large = np.linalg.norm(basic_local(p, large) - p, axis=1) > 0.0
    between = (r > 1.5) & (r < 2.0)
    assert np.all(moved_large[between]) and not np.any(moved_small[between])
    assert np.all(moved_large[moved_small]) and moved_large.sum() > moved_small.sum()
    assert not np.any(moved_large[r >= 2.0])


@pytest.mark.parametrize("mode", MODES)
def test_fig7_half_weight_halves_every_displacement(mode):
    # (e) w = 0.5 (and, the same, a painted wi = 0.5) halves the displacement of every point
    rng = np.random.default_rng(4)
    p = unit_dirs(rng, 300) * rng.uniform(0.05, 2.5, 300)[:, None]
    full = ShellParams(sticky=0.2, hard=0.3, drop_off=1.0, mode=mode)
    half = ShellParams(sticky=0.2, hard=0.3, drop_off=1.0, weight=0.5, mode=mode)
    d_full = basic_local(p, full) - p
    assert np.abs(d_full).max() > 0.1
    np.testing.assert_allclose(basic_local(p, half) - p, 0.5 * d_full, atol=1e-14)
    np.testing.assert_allclose(basic_local(p, full, wi=0.5) - p, 0.5 * d_full, atol=1e-14)


def test_project_leaves_the_centre_and_far_points_alone():
    p = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    np.testing.assert_array_equal(project(p, 0.5, 0.5, 1.0), p)


# ---------------------------------------------------------------------------------------------
# star lookup


def test_star_lookup_nodes_wrap_and_missing_tables():
    rng = np.random.default_rng(5)
    star = random_star(rng, 2)
    i, j = np.meshgrid(np.arange(1, STAR_THETA - 1), np.arange(STAR_PHI), indexing="ij")
    theta, phi = np.pi * i.ravel() / 16, -np.pi + 2 * np.pi * j.ravel() / 32
    u = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    got = star_lookup(star, np.ones(len(u), int), u)
    np.testing.assert_allclose(got, star[1, i.ravel(), j.ravel()], atol=1e-12)
    # azimuth +-pi is one direction: both sides of the seam give column 0
    eps = 1e-9
    seam = np.array([[-np.cos(eps), np.sin(eps), 0.0], [-np.cos(eps), -np.sin(eps), 0.0]])
    np.testing.assert_allclose(star_lookup(star, [0, 0], seam), star[0, 8, 0], atol=1e-7)
    # half-way between two nodes: the mean
    th, ph = np.pi * 5.5 / 16, -np.pi + 2 * np.pi * 7.5 / 32
    mid = [[np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]]
    np.testing.assert_allclose(star_lookup(star, [0], mid), star[0, 5:7, 7:9].mean(), atol=1e-12)
    assert np.all(star_lookup(star, [-1, -1], u[:2]) == 0.0)


# ---------------------------------------------------------------------------------------------
# relative deformers (reference and kernel)


def scene(rng, M=3, star=False, modes=MODES, **kw):
    """M muscles around the origin with random ellipsoids ~0.1-0.3 m, one pair per vertex and muscle."""
    E_ref = np.stack([affine(Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(),
                             rng.uniform(0.1, 0.3, 3), rng.uniform(-0.2, 0.2, 3)) for _ in range(M)])
    params = [ShellParams(mode=modes[m % len(modes)], **kw) for m in range(M)]
    table = shell_table(params, star=random_star(rng, M) if star else None)
    return E_ref, table


def run_both(points, offsets, muscle, weight, table, frames):
    ref = shell_numpy(points, offsets, muscle, weight, table, frames)
    out = ShellDeformer(table, offsets, muscle, weight).deform(points, frames)
    return ref, out


@pytest.mark.parametrize("star", [False, True])
def test_rest_gives_exactly_zero_in_every_mode(star):
    rng = np.random.default_rng(6)
    E_ref, table = scene(rng, M=3, star=star, sticky=0.3, hard=0.2, drop_off=1.2, slippage=0.5)
    points = rng.uniform(-0.5, 0.5, (500, 3))
    offsets, muscle, weight = all_pairs(500, 3)
    ref, out = run_both(points, offsets, muscle, weight, table, make_frames(E_ref, E_ref.copy()))
    np.testing.assert_array_equal(ref, points)
    np.testing.assert_array_equal(out, points.astype(np.float32))


def test_stretch_translation_moves_the_inside_rigidly_and_the_outside_not_at_all():
    rng = np.random.default_rng(7)
    E_ref, _ = scene(rng, M=1)
    d, w, wi = 0.6, 0.8, 0.5
    table = shell_table([ShellParams(sticky=0.4, hard=0.3, drop_off=d, weight=w, slippage=2.0)])
    t = np.array([0.03, -0.02, 0.05])
    # keep |t| under the knee of the drop-off limit (half its reach), where it leaves D unchanged
    from jiggle.rig.skin.shell.shells import LIMIT_KNEE, LIMIT_REACH
    t *= 0.9 * LIMIT_KNEE * LIMIT_REACH * d * np.linalg.norm(E_ref[0, :3, :3], axis=0).min() / np.linalg.norm(t)
    inside = points_at_local(E_ref[0], unit_dirs(rng, 100) * rng.uniform(0.0, 0.999, 100)[:, None])
    outside = points_at_local(E_ref[0], unit_dirs(rng, 100) * rng.uniform(1 + d, 3.0, 100)[:, None])
    points = np.concatenate([inside, outside])
    offsets, muscle, _ = all_pairs(200, 1)
    weight = np.full(200, wi, np.float32)
    ref, out = run_both(points, offsets, muscle, weight, table, make_frames(E_ref, translated(E_ref[0], t)[None]))
    k = w * wi
    np.testing.assert_allclose(ref[:100] - inside, np.broadcast_to(k * t, (100, 3)), atol=1e-14)
    np.testing.assert_array_equal(ref[100:], outside)
    np.testing.assert_allclose(out[:100] - inside, np.broadcast_to(k * t, (100, 3)), atol=1e-6)
    np.testing.assert_array_equal(out[100:], outside.astype(np.float32))


@pytest.mark.parametrize("sticky", [1.0, 0.3])
def test_trajectory_along_a_straight_line_equals_stretch(sticky):
    # c(a) - c(0) = a (t_cur - t_ref) on the straight path, so D_trajectory = a [(L_cur - L_ref) q
    # + t_cur - t_ref] = a (E_cur - E_ref) (q, 1) = D_stretch
    rng = np.random.default_rng(8)
    E_ref, _ = scene(rng, M=2)
    E_cur = np.stack([affine(Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix(), (1.2, 0.9, 1.1),
                             (0.05, 0.0, -0.03)) @ E for E in E_ref])
    points = rng.uniform(-0.5, 0.5, (800, 3))
    offsets, muscle, weight = all_pairs(800, 2)
    frames = make_frames(E_ref, E_cur)
    kw = dict(sticky=sticky, hard=0.4, drop_off=1.0, slippage=1.7)
    stretch = shell_table([ShellParams(mode="stretch", **kw)] * 2)
    trajectory = shell_table([ShellParams(mode="trajectory", **kw)] * 2)
    a = shell_numpy(points, offsets, muscle, weight, stretch, frames)
    b = shell_numpy(points, offsets, muscle, weight, trajectory, frames)
    assert np.abs(a - points).max() > 0.01
    np.testing.assert_allclose(b, a, atol=1e-13)
    out = ShellDeformer(trajectory, offsets, muscle, weight).deform(points, frames)
    np.testing.assert_allclose(out, a, atol=SCENE_TOL)


def test_trajectory_follows_a_bent_curve():
    rng = np.random.default_rng(9)
    E_ref, _ = scene(rng, M=1)
    d = 0.8
    table = shell_table([ShellParams(mode="trajectory", sticky=0.5, hard=0.2, drop_off=d, slippage=1.0)])
    # |t| + |bend| under half the drop-off distance, where the drop-off limit leaves D unchanged
    size = 0.45 * d * np.linalg.norm(E_ref[0, :3, :3], axis=0).min()
    t = np.array([0.7, 0.0, 0.0]) * size
    bend = np.array([0.0, 0.28, 0.0]) * size
    u = np.linspace(0.0, 1.0, K)[:, None]
    curve = (E_ref[0, :3, 3] + u * t + np.sin(np.pi * u) * bend)[None]
    frames = make_frames(E_ref, translated(E_ref[0], t)[None], curve=curve)
    # inside the muscle alpha = 1: the point follows the whole curve, c(1) - c(0) = t;
    # where alpha = f(x) = 0.5 (x = sqrt(1 - sqrt(0.5))), a = 0.5: it stops at c(0.5), off the chord
    x = np.sqrt(1.0 - np.sqrt(0.5))
    dirs = unit_dirs(rng, 2)
    p_l = np.stack([0.5 * dirs[0], (1.0 + d * x) * dirs[1]])
    points = points_at_local(E_ref[0], p_l)
    offsets, muscle, weight = all_pairs(2, 1)
    ref, out = run_both(points, offsets, muscle, weight, table, frames)
    np.testing.assert_allclose(ref[0] - points[0], t, atol=1e-12)
    np.testing.assert_allclose(ref[1] - points[1], 0.5 * t + bend, atol=1e-12)
    np.testing.assert_allclose(out, ref, atol=1e-6)


@pytest.mark.parametrize("mode", MODES)
def test_half_weight_halves_the_relative_displacement(mode):
    rng = np.random.default_rng(10)
    E_ref, _ = scene(rng, M=1)
    E_cur = affine(Rotation.from_rotvec([0.0, 0.3, 0.1]).as_matrix(), (1.1, 0.8, 1.0), (0.02, 0.01, 0.0)) @ E_ref[0]
    frames = make_frames(E_ref, E_cur[None])
    points = rng.uniform(-0.4, 0.4, (400, 3))
    offsets, muscle, weight = all_pairs(400, 1)
    kw = dict(mode=mode, sticky=0.6, hard=0.5, drop_off=1.0, slippage=0.7)
    full = shell_numpy(points, offsets, muscle, weight, shell_table([ShellParams(**kw)]), frames) - points
    half_table = shell_table([ShellParams(weight=0.5, **kw)])
    half = shell_numpy(points, offsets, muscle, weight, half_table, frames) - points
    assert np.abs(full).max() > 0.01
    np.testing.assert_allclose(half, 0.5 * full, atol=1e-15)
    out = ShellDeformer(half_table, offsets, muscle, weight).deform(points, frames) - points
    np.testing.assert_allclose(out, 0.5 * full, atol=SCENE_TOL)


def test_pairs_apply_in_series():
    rng = np.random.default_rng(11)
    E_ref = np.stack([affine(scale=(0.2, 0.2, 0.2), centre=(0.0, 0.0, 0.0)),
                      affine(scale=(0.15, 0.25, 0.2), centre=(0.1, 0.05, 0.0))])
    E_cur = np.stack([affine(scale=(0.26, 0.2, 0.18), centre=(0.03, 0.0, 0.0)),
                      affine(Rotation.from_rotvec([0, 0, 0.4]).as_matrix(), (0.15, 0.3, 0.2), (0.1, 0.08, 0.0))])
    table = shell_table([ShellParams(mode="basic", sticky=0.5, drop_off=1.0),
                         ShellParams(mode="stretch", sticky=0.8, drop_off=1.0)])
    frames = make_frames(E_ref, E_cur)
    points = rng.uniform(-0.3, 0.4, (600, 3))
    offsets, muscle, weight = all_pairs(600, 2)
    weight = rng.uniform(0.3, 1.0, 1200).astype(np.float32)
    ref = shell_numpy(points, offsets, muscle, weight, table, frames)
    zeros, ones = np.zeros(600, int), np.ones(600, int)
    first = points + pair_displacement(points, zeros, weight[0::2], table, frames)
    series = first + pair_displacement(first, ones, weight[1::2], table, frames)
    np.testing.assert_allclose(ref, series, atol=1e-15)
    # the order matters: the second pair sees the point the first one moved
    parallel = first + pair_displacement(points, ones, weight[1::2], table, frames)
    assert np.abs(parallel - series).max() > 1e-3
    out = ShellDeformer(table, offsets, muscle, weight).deform(points, frames)
    np.testing.assert_allclose(out, ref, atol=SCENE_TOL)


def test_inactive_muscle_contributes_nothing_even_with_nan_frames():
    rng = np.random.default_rng(12)
    E_ref, table = scene(rng, M=3, star=True, sticky=0.5, drop_off=1.0)
    E_cur = np.stack([translated(E, rng.normal(scale=0.03, size=3)) for E in E_ref])
    points = rng.uniform(-0.5, 0.5, (500, 3))
    offsets, muscle, weight = all_pairs(500, 3)
    off = make_frames(E_ref, E_cur, active=np.array([True, False, True]))
    nan = ShellFrames(*(np.where(np.arange(3)[(slice(None),) + (None,) * (a.ndim - 1)] == 1, np.nan, a)
                        for a in (off.E_ref, off.E_ref_inv, off.E_cur, off.E_cur_inv, off.curve)),
                      off.active)
    keep = muscle != 1
    offsets2 = np.concatenate([[0], np.cumsum(np.full(500, 2))]).astype(np.int32)
    expected = shell_numpy(points, offsets2, muscle[keep], weight[keep], table, off)
    assert np.abs(expected - shell_numpy(points, offsets, muscle, weight, table,
                                         make_frames(E_ref, E_cur))).max() > 1e-3
    ref, out = run_both(points, offsets, muscle, weight, table, nan)
    np.testing.assert_array_equal(ref, expected)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, expected, atol=SCENE_TOL)


# ---------------------------------------------------------------------------------------------
# kernel == reference on random scenes


def random_affine(rng, size):
    return affine(Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(),
                  rng.uniform(0.08, 0.3, 3) * size, rng.uniform(-0.4, 0.4, 3))


@pytest.mark.parametrize("seed,far", [(20, False), (21, True), (22, True)])
def test_kernel_matches_the_reference_on_random_scenes(seed, far):
    rng = np.random.default_rng(seed)
    M, V, S = 10, 3000, 6
    E_ref = np.stack([random_affine(rng, 1.0) for _ in range(M)])
    if far:  # large motions: rotations up to ~1 rad, scales 0.7-1.4, translations ~0.1 m
        change = [affine(Rotation.from_rotvec(rng.normal(scale=0.6, size=3)).as_matrix(),
                         rng.uniform(0.7, 1.4, 3), rng.normal(scale=0.1, size=3)) for _ in range(M)]
    else:
        change = [np.eye(4) + np.pad(rng.normal(scale=1e-2, size=(3, 4)), ((0, 1), (0, 0))) for _ in range(M)]
    # the change acts about each rest centre, as a muscle bulging and sliding would
    E_cur = np.stack([translated(c @ translated(E, -E[:3, 3]), E[:3, 3]) for c, E in zip(change, E_ref)])
    u = np.linspace(0.0, 1.0, K)[None, :, None]
    curve = (straight_curve(E_ref, E_cur)
             + np.sin(np.pi * u) * rng.normal(scale=0.05, size=(M, 1, 3)))
    params = [ShellParams(sticky=rng.uniform(), hard=1.0 if m % 4 == 0 else rng.uniform(0.0, 0.8),
                          drop_off=rng.uniform(0.2, 1.5), weight=rng.uniform(0.3, 1.0),
                          slippage=0.0 if m % 3 == 0 else rng.uniform(0.0, 3.0), mode=MODES[m % 3])
              for m in range(M)]
    star_index = np.where(rng.random(M) < 0.7, rng.integers(0, S, M), -1)
    table = shell_table(params, star=random_star(rng, S), star_index=star_index)
    active = rng.random(M) < 0.9
    frames = make_frames(E_ref, E_cur, curve=curve, active=active)
    points = rng.uniform(-0.6, 0.6, (V, 3))
    member = (rng.random((V, M)) < 0.5) & (rng.random((V, 1)) < 0.9)  # ~10 % of vertices unpaired
    v, muscle = np.nonzero(member)
    offsets = np.concatenate([[0], np.cumsum(member.sum(axis=1))]).astype(np.int32)
    weight = rng.uniform(0.0, 1.0, len(muscle)).astype(np.float32)
    assert (member.sum(axis=1) == 0).any() and member.sum(axis=1).max() >= 8
    ref = shell_numpy(points, offsets, muscle, weight, table, frames)
    out = ShellDeformer(table, offsets, muscle.astype(np.int32), weight).deform(points, frames)
    moved = np.linalg.norm(ref - points, axis=1)
    assert moved.max() > (0.05 if far else 1e-3) and (moved > 0).mean() > 0.3
    np.testing.assert_array_equal(out[~member.any(axis=1)], points[~member.any(axis=1)].astype(np.float32))
    np.testing.assert_allclose(out, ref, atol=SCENE_TOL, rtol=0.0)


def test_kernel_guards_degenerate_values():
    # h = 1 (no transition), a drop-off of 1e-30 (1 + d == 1 in float32), slippage 0, points at the
    # ellipsoid centre and exactly on the shells: finite, and equal to the reference except on the
    # h = 1 step itself (r = 1.5 for the first muscle), where rounding decides the side
    E_ref = np.stack([affine(scale=(0.2, 0.2, 0.2))] * 3)
    E_cur = np.stack([affine(scale=(0.25, 0.2, 0.2), centre=(0.01, 0, 0))] * 3)
    table = shell_table([ShellParams(hard=1.0, drop_off=0.5, mode="basic"),
                         ShellParams(hard=1.0, drop_off=1e-30, slippage=0.0, mode="stretch"),
                         ShellParams(hard=0.999999, drop_off=1e-6, slippage=0.0, mode="trajectory")])
    r = np.array([0.0, 1.0, 1.5, 2.0, 1.0 + 1e-6, 0.2])
    points = r[:, None] * np.array([0.2, 0.0, 0.0])
    offsets, muscle, weight = all_pairs(len(points), 3)
    frames = make_frames(E_ref, E_cur)
    ref, out = run_both(points, offsets, muscle, weight, table, frames)
    assert np.all(np.isfinite(ref)) and np.all(np.isfinite(out))
    np.testing.assert_allclose(out[r != 1.5], ref[r != 1.5], atol=SCENE_TOL)


def test_deformer_without_pairs_or_vertices_copies():
    table = shell_table([ShellParams()])
    frames = make_frames(np.eye(4)[None], translated(np.eye(4), [0.1, 0, 0])[None])
    points = np.random.default_rng(13).uniform(-1, 1, (50, 3))
    none = ShellDeformer(table, np.zeros(51, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32))
    np.testing.assert_array_equal(none.deform(points, frames), points.astype(np.float32))
    empty = ShellDeformer(table, np.zeros(1, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32))
    assert empty.deform(np.zeros((0, 3)), frames).shape == (0, 3)


def test_launch_takes_and_returns_device_arrays():
    rng = np.random.default_rng(14)
    E_ref, table = scene(rng, M=2, sticky=0.5)
    frames = make_frames(E_ref, np.stack([translated(E, (0.02, 0, 0)) for E in E_ref]))
    points = rng.uniform(-0.3, 0.3, (100, 3))
    offsets, muscle, weight = all_pairs(100, 2)
    deformer = ShellDeformer(table, offsets, muscle, weight)
    buf = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    out = deformer.launch(buf, frames)
    assert isinstance(out, wp.array) and out.shape == (100,) and out.dtype == wp.vec3
    np.testing.assert_allclose(out.numpy(), shell_numpy(points, offsets, muscle, weight, table, frames),
                               atol=SCENE_TOL)


# ---------------------------------------------------------------------------------------------
# continuity in time


def test_smooth_ellipsoid_motion_gives_smooth_skin_motion():
    # E_cur moves smoothly (translation + anisotropic scale + rotation) in 200 steps. Each deformed
    # point's per-step change is bounded by C times the per-step motion of the muscle surface (the
    # max over its points). Estimate for one pair: the local point moves by <= (1 + r) kappa times
    # the surface motion (r <= 2.2 local radii, kappa ~ 1.7 the ellipsoid's anisotropy) and q's
    # slope is <= 1 + max f' |r_s - r| / ((1 - h) d) ~ 2.5, so ~ 10 at worst, reached only by a few
    # points (the measured max is ~ 9, the median ~ 3, with three overlapping muscles in series).
    # C = 20 holds with room; a jump (a muscle's whole pull, ~ its radius / 4, in one step whose
    # surface motion is ~ 1/200 of the path) exceeds it several times over.
    C = 20.0
    rng = np.random.default_rng(15)
    M = 3
    E_ref = np.stack([affine(scale=(0.2, 0.15, 0.25), centre=(0.0, 0.0, 0.0)),
                      affine(Rotation.from_rotvec([0.3, 0, 0]).as_matrix(), (0.12, 0.2, 0.15), (0.1, 0.05, 0.0)),
                      affine(scale=(0.1, 0.1, 0.3), centre=(-0.05, 0.1, 0.05))])
    table = shell_table([ShellParams(mode=m, sticky=0.5, hard=0.4, drop_off=1.0, slippage=1.5) for m in MODES],
                        star=random_star(rng, M, 0.1))
    # skin-like points: local radius 0.6 .. 2.2 of the first muscle (away from its centre, where
    # the paper's projection has its one singular point)
    points = points_at_local(E_ref[0], unit_dirs(rng, 1500) * rng.uniform(0.6, 2.2, 1500)[:, None])
    offsets, muscle, weight = all_pairs(1500, M)
    deformer = ShellDeformer(table, offsets, muscle, weight)
    sphere = unit_dirs(rng, 400)
    steps = 200

    def E_cur_at(i):
        t = i / steps
        out = []
        for m in range(M):
            c = E_ref[m, :3, 3]
            A = affine(Rotation.from_rotvec([0.0, 0.5 * t, 0.3 * t]).as_matrix(),
                       (1.0 + 0.25 * np.sin(np.pi * t), 1.0 - 0.2 * t, 1.0),
                       c + np.array([0.06, -0.03, 0.02]) * t)
            out.append(A @ translated(E_ref[m], -c))
        return np.stack(out)

    def run(toggle_at=None):
        prev_p = prev_s = None
        ratios = []
        for i in range(steps + 1):
            E_cur = E_cur_at(i)
            active = np.ones(M, bool)
            if i == toggle_at:
                active[0] = False
            p = deformer.deform(points, make_frames(E_ref, E_cur, active=active)).astype(np.float64)
            surf = np.einsum("mij,nj->mni", E_cur[:, :3, :3], sphere) + E_cur[:, None, :3, 3]
            if prev_p is not None:
                ratios.append(np.abs(p - prev_p).max() / np.linalg.norm(surf - prev_s, axis=2).max())
            prev_p, prev_s = p, surf
        return np.array(ratios)

    ratios = run()
    assert ratios.max() < C, ratios.max()
    # the bound is not vacuous: dropping one muscle for a single frame breaks it
    jumped = run(toggle_at=steps // 2)
    assert jumped.max() > 3 * C, jumped.max()


# ---------------------------------------------------------------------------------------------
# culling


def test_cull_pairs_keeps_the_drop_off_shell_with_margin_and_sorts_csr():
    rng = np.random.default_rng(16)
    M, margin = 3, 0.25
    E_rest = np.stack([random_affine(rng, 1.0) for _ in range(M)])
    d = np.array([0.5, 1.0, 0.8])
    star = np.full((1, STAR_THETA, STAR_PHI), 0.1, np.float32)
    star_index = np.array([-1, 0, -1])
    delta = np.array([0.0, 0.1, 0.0])
    limit = (1.0 + d) * (1.0 + margin) + delta  # local radius
    # per muscle: points just inside and just outside its culling radius, plus random points
    pts, expect_in = [], []
    for m in range(M):
        u = unit_dirs(rng, 20)
        pts += [points_at_local(E_rest[m], u * limit[m] * (1 - 1e-6)),
                points_at_local(E_rest[m], u * limit[m] * (1 + 1e-6))]
        expect_in += [(m, True)] * 20 + [(m, False)] * 20
    pts.append(rng.uniform(-1, 1, (300, 3)))
    points = np.concatenate(pts)
    offsets, muscle = cull_pairs(points, E_rest, d, margin, star=star, star_index=star_index)
    assert offsets.dtype == np.int32 and muscle.dtype == np.int32
    pairs = {(v, int(m)) for v in range(len(points)) for m in muscle[offsets[v]:offsets[v + 1]]}
    for v, (m, inside) in enumerate(expect_in):
        assert ((v, m) in pairs) == inside
    # brute force over every (vertex, muscle), and the CSR order: by vertex, then by muscle
    expected = []
    for v, p in enumerate(points):
        for m in range(M):
            r = np.linalg.norm(np.linalg.solve(E_rest[m], np.append(p, 1.0))[:3])
            if r - delta[m] < limit[m] - delta[m]:
                expected.append((v, m))
    got = [(v, int(m)) for v in range(len(points)) for m in muscle[offsets[v]:offsets[v + 1]]]
    assert got == expected
    assert 0 < len(got) < len(points) * M


# ---------------------------------------------------------------------------------------------
# bad input


@pytest.mark.parametrize("field,value", [
    ("sticky", -0.1), ("sticky", 1.5), ("hard", 1.01), ("hard", -1.0), ("drop_off", 0.0),
    ("drop_off", -1.0), ("drop_off", float("inf")), ("weight", 2.0), ("slippage", -0.5),
    ("slippage", float("nan")), ("mode", "wobble"), ("sticky", "a"), ("weight", True),
])
def test_shell_params_out_of_range_name_the_field(field, value):
    with pytest.raises(InputError) as e:
        ShellParams(**{field: value})
    assert e.value.field == field and field in str(e.value)


def test_shell_table_checks_star_tables():
    params = [ShellParams(), ShellParams(mode="basic")]
    star = np.zeros((3, STAR_THETA, STAR_PHI))
    for kw, field in [(dict(star=star), "star_index"),  # 3 tables for 2 muscles, no index
                      (dict(star=star, star_index=[0, 1, 2]), "star_index"),
                      (dict(star=star, star_index=[0, 3]), "star_index"),
                      (dict(star=star, star_index=[-2, 0]), "star_index"),
                      (dict(star=star, star_index=[0.0, 1.0]), "star_index"),
                      (dict(star_index=[0, 1]), "star_index"),  # indices but no tables
                      (dict(star=np.zeros((2, 16, 32))), "star"),
                      (dict(star=np.full((2, STAR_THETA, STAR_PHI), np.nan)), "star")]:
        with pytest.raises(InputError) as e:
            shell_table(params, **kw)
        assert e.value.field == field, kw
    with pytest.raises(InputError, match="params"):
        shell_table([ShellParams(), {"sticky": 1.0}])
    t = shell_table(params, star=star[:2])
    assert t.star_index.tolist() == [0, 1] and t.mode.tolist() == [1, 0]
    assert not t.sticky.flags.writeable


def test_shell_deformer_rejects_bad_arrays():
    table = shell_table([ShellParams(), ShellParams()])
    ok = (np.array([0, 2, 3], np.int32), np.array([0, 1, 1], np.int32), np.ones(3, np.float32))
    ShellDeformer(table, *ok)
    bad = [
        ((np.array([[0, 2, 3]]), ok[1], ok[2]), "pair_offsets"),
        ((np.array([0.0, 2.0, 3.0]), ok[1], ok[2]), "pair_offsets"),
        ((np.array([0, 2, 4]), ok[1], ok[2]), "pair_offsets"),
        ((np.array([1, 2, 3]), ok[1], ok[2]), "pair_offsets"),
        ((np.array([0, 3, 2, 3]), ok[1], ok[2]), "pair_offsets"),
        ((ok[0], np.array([0, 2, 1]), ok[2]), "pair_muscle"),
        ((ok[0], np.array([1, 0, 1]), ok[2]), "pair_muscle"),
        ((ok[0], np.array([0, 0, 1]), ok[2]), "pair_muscle"),
        ((ok[0], ok[1], np.ones(2)), "pair_weight"),
        ((ok[0], ok[1], np.array([0.5, 1.5, 1.0])), "pair_weight"),
        ((ok[0], ok[1], np.array([0.5, np.nan, 1.0])), "pair_weight"),
    ]
    for args, field in bad:
        with pytest.raises(InputError) as e:
            ShellDeformer(table, *args)
        assert e.value.field == field, (args, field)
    with pytest.raises(InputError) as e:
        ShellDeformer("table", *ok)
    assert e.value.field == "table"


def test_shell_frames_and_launch_reject_bad_state():
    I2 = np.tile(np.eye(4), (2, 1, 1))
    curve = np.zeros((2, K, 3))
    for args, field in [((I2[:, :3], I2, I2, I2, curve, [1, 1]), "E_ref"),
                        ((I2, I2[:1], I2, I2, curve, [1, 1]), "E_ref_inv"),
                        ((I2, I2, I2, I2, curve[:, :, :2], [1, 1]), "curve"),
                        ((I2, I2, I2, I2, curve[:, :1], [1, 1]), "curve"),
                        ((I2, I2, I2, I2, curve, [1, 1, 1]), "active")]:
        with pytest.raises(InputError) as e:
            ShellFrames(*args)
        assert e.value.field == field
    table = shell_table([ShellParams(), ShellParams()])
    deformer = ShellDeformer(table, np.array([0, 2, 3]), np.array([0, 1, 1]), np.ones(3))
    frames = ShellFrames(I2, I2, I2, I2, curve, [True, True])
    with pytest.raises(InputError) as e:
        deformer.deform(np.zeros((3, 3)), frames)
    assert e.value.field == "points"
    with pytest.raises(InputError) as e:
        deformer.launch(wp.zeros(3, dtype=wp.vec3), frames)
    assert e.value.field == "points"
    with pytest.raises(InputError) as e:
        deformer.deform(np.zeros((2, 3)), ShellFrames(I2[:1], I2[:1], I2[:1], I2[:1], curve[:1], [True]))
    assert e.value.field == "frames"
    nan = I2.copy()
    nan[1, 0, 0] = np.nan
    with pytest.raises(InputError) as e:
        deformer.deform(np.zeros((2, 3)), ShellFrames(I2, I2, nan, I2, curve, [True, True]))
    assert e.value.field == "E_cur"
    # the same NaN in an inactive muscle is fine: it is skipped
    out = deformer.deform(np.ones((2, 3)), ShellFrames(I2, I2, nan, I2, curve, [True, False]))
    np.testing.assert_array_equal(out, np.ones((2, 3), np.float32))


def test_drop_off_limit_keeps_every_move_within_the_drop_off_distance():
    """A muscle that leaves its bone far behind (translated by 5 drop-off distances) moves no skin
    point farther than its drop-off distance along the point's direction, d |L_ref u|; small moves
    (under half of it) are untouched, and the limit is continuous (C1 at the knee)."""
    rng = np.random.default_rng(31)
    E_ref, _ = scene(rng, M=1)
    d = 0.7
    radii = np.linalg.norm(E_ref[0, :3, :3], axis=0)
    big = translated(E_ref[0], np.array([5.0 * d * radii.max(), 0.0, 0.0]))
    p_l = unit_dirs(rng, 300) * rng.uniform(0.2, 1.0 + d, 300)[:, None]
    points = points_at_local(E_ref[0], p_l)
    offsets, muscle, weight = all_pairs(300, 1)
    for mode in MODES:
        table = shell_table([ShellParams(mode=mode, drop_off=d)])
        ref, out = run_both(points, offsets, muscle, weight, table, make_frames(E_ref, big[None]))
        u = p_l / np.linalg.norm(p_l, axis=1, keepdims=True)
        reach = d * np.linalg.norm(u @ E_ref[0, :3, :3].T, axis=1)
        assert np.all(np.linalg.norm(ref - points, axis=1) < reach + 1e-12), mode
        assert np.all(np.linalg.norm(out - points, axis=1) < reach + 1e-5), mode
    # the limit itself: identity below the knee, below reach above it, continuous slope at the knee
    from jiggle.rig.skin.shell.shells import LIMIT_KNEE, limit
    D = np.array([[1.0, 0.0, 0.0]]) * np.linspace(0.0, 10.0, 2001)[:, None]
    n = np.linalg.norm(limit(D, np.ones(len(D))), axis=1)
    x = D[:, 0]
    np.testing.assert_allclose(n[x <= LIMIT_KNEE], x[x <= LIMIT_KNEE], atol=1e-15)
    assert np.all(n <= 1.0) and np.all(np.diff(n) >= -1e-15) and np.all(np.diff(n[x < 3]) > 0)
    slope = np.diff(n) / np.diff(x)
    assert np.abs(np.diff(slope)).max() < 1e-2     # no kink
