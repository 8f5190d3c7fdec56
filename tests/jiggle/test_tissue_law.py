"""The tissue law (sim/jiggle/tissue_law.py): a goal spring that stiffens smoothly toward the reach.

Reference equations (per unit mass, offset y from a still goal, r = |y|, rho = r / R):

    y'' = -k y - c y' - kappa phi(rho) y,   E = |y'|^2 / 2 + k r^2 / 2 + kappa R^2 Phi(rho)

dE/dt = -c |y'|^2: without damping E is constant, with it E never grows. Below ONSET R the law is the
linear spring, whose free ring-down has frequency f sqrt(1 - zeta^2) and log decrement 2 pi zeta / sqrt(1 - zeta^2).
"""
import math

import numpy as np
import pytest
import warp as wp

from jiggle.sim.jiggle import particle_kernels, tissue_law
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.params import JiggleSettings, MuscleJiggle
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run, step_times
from jiggle.sim.jiggle.solver import ParticleSolver, integrate_numpy

R = 0.02                               # metres: the reach of the test particles


def single_particles(omegas, zetas, reach=R):
    """Free particles (no springs) at the origin with goal frequencies omegas (rad/s), damping ratios zetas."""
    b = ParticleBuilder()
    for w, z in zip(omegas, zetas):
        b.add_particle([0.0, 0.0, 0.0], 0.01, w * w, 2.0 * z * w, reach=reach)
    return b.finalize()


def still_track(n, duration):
    """A goal track holding n goals at the origin for `duration` seconds (knots at 120 Hz)."""
    knots = np.linspace(0.0, duration, int(round(duration * 120)) + 1)
    return build_track(knots, np.zeros((len(knots), n, 3)))


def ring(model, y0, u0, duration, fps=240.0, substeps=1):
    """Offsets (T, N, 3) and offset velocities after every step of a free run from offsets y0, u0 (N, 3)."""
    track = still_track(model.num_particles, duration)
    solver = ParticleSolver(model)
    out = np.arange(0.0, duration + 1e-9, 1.0 / fps)
    grid = step_times(out, track.times, substeps, solver.max_step)
    a, b = model.state(), model.state()
    a.assign(y0, u0)
    ys, vs = [], []
    control = track.to_device()
    for k in range(len(grid) - 1):
        solver.integrate(a, b, control, grid[k:k + 2])
        x, v = b.numpy()
        ys.append(x)
        vs.append(v)
        a, b = b, a
    return grid[1:], np.array(ys), np.array(vs), solver


def test_phi_is_zero_below_the_onset_smooth_and_growing():
    rho = np.linspace(0.0, 1.5, 3001)
    p = tissue_law.phi(rho)
    assert np.all(p[rho <= tissue_law.ONSET] == 0.0)
    f = rho * p                                                   # the stiffening force in kappa R units
    df = np.gradient(f, rho)
    assert np.all(np.diff(f) >= 0) and np.all(df >= -1e-9)
    np.testing.assert_allclose(df[1:-1], tissue_law.tangent(rho)[1:-1], rtol=2e-2, atol=2e-2)
    # the potential's derivative is the force (rho phi), continuous at the onset and the reach
    np.testing.assert_allclose(np.gradient(tissue_law.potential(rho), rho)[1:-1], f[1:-1], atol=2e-3)
    at = np.searchsorted(rho, 1.0)
    step = rho[1] - rho[0]
    assert abs(f[at + 1] - f[at - 1]) < 3 * tissue_law.SLOPE * step          # no jump at the reach


def test_small_offsets_move_exactly_as_the_linear_spring():
    """Swings below 30% of the reach: the same motion as with no reach (no stiffening) to within 1% of the
    peak (here bit for bit: the linear path is the same arithmetic)."""
    w = 2 * np.pi * np.array([3.0, 6.0, 12.0])
    model, linear = single_particles(w, [0.2, 0.0, 0.5]), single_particles(w, [0.2, 0.0, 0.5], reach=math.inf)
    u0 = np.zeros((3, 3))
    u0[:, 0] = 0.25 * R * w                                        # amplitude 0.25 R
    _, y, _, _ = ring(model, np.zeros((3, 3)), u0, 1.0)
    _, y_lin, _, _ = ring(linear, np.zeros((3, 3)), u0, 1.0)
    peak = np.abs(y_lin).max()
    assert 0.2 * R < peak < tissue_law.ONSET * R
    assert np.abs(y - y_lin).max() <= 0.01 * peak
    np.testing.assert_array_equal(y, y_lin)


def test_energy_is_conserved_without_damping_and_never_grows_with_it():
    """A particle launched to 0.5-0.95 of its reach (linear swings of 0.6-2.5 reaches), 10 s of free motion:
    undamped, the tissue law's energy stays within 1%; damped, it never grows."""
    w = 2 * np.pi * np.array([2.0, 4.0, 8.0, 8.0])
    swings = np.array([0.6, 1.2, 2.5, 1.0])
    u0 = np.zeros((4, 3))
    u0[:, 0] = swings * R * w
    u0[3, 1] = 0.5 * swings[3] * R * w[3]                          # off-axis: an orbit, not a line
    model = single_particles(w, np.zeros(4))
    t, y, v, solver = ring(model, np.zeros((4, 3)), u0, 10.0, fps=120.0)
    e = np.stack([tissue_law.energy_numpy(yy, vv, model.goal_k, model.reach) for yy, vv in zip(y, v)])
    e0 = tissue_law.energy_numpy(np.zeros((4, 3)), u0, model.goal_k, model.reach)
    rho = np.linalg.norm(y, axis=2) / R
    assert rho.max(axis=0).min() > 0.5 and rho.max() < 1.0          # into the stiffening, never at the reach
    assert np.abs(e / e0 - 1.0).max() < 0.01
    assert solver.hard_stops().sum() == 0

    damped = single_particles(w, np.full(4, 0.1))
    _, yd, vd, _ = ring(damped, np.zeros((4, 3)), u0, 3.0, fps=120.0)
    ed = np.stack([tissue_law.energy_numpy(yy, vv, damped.goal_k, damped.reach) for yy, vv in zip(yd, vd)])
    ed = np.concatenate([e0[None], ed])
    assert np.all(np.diff(ed, axis=0) <= 1e-6 * e0)                # never grows (float32 round-off)
    assert np.all(ed[-1] < 0.1 * e0)


def peaks_and_crossings(t, s):
    """Times of the zero crossings (upward) and the |s| peaks between crossings of a ring-down s (T,)."""
    up = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    tc = t[up] - s[up] * (t[up + 1] - t[up]) / (s[up + 1] - s[up])
    zc = np.flatnonzero(np.sign(s[:-1]) != np.sign(s[1:]))
    peaks = [np.abs(s[a + 1:b + 1]).max() for a, b in zip(zc[:-1], zc[1:])]
    return tc, np.array(peaks)


@pytest.mark.parametrize("f, zeta", [(4.0, 0.1), (7.0, 0.3)])
def test_ring_down_has_the_set_frequency_and_damping_and_a_large_pulse_decays_without_a_plateau(f, zeta):
    """A pulse (an offset velocity) then free motion. Small (0.2 R): the measured frequency and damping ratio
    equal the parameters within 5%. Ten times larger (a linear swing of 2 R): bounded below the reach, the
    peaks fall every half cycle, and no peak is a plateau (the offset stays within 1% of a peak for less
    than a tenth of a period)."""
    w = 2 * np.pi * f
    model = single_particles([w, w], [zeta, zeta])
    u0 = np.zeros((2, 3))
    u0[0, 0] = 0.2 * R * w
    u0[1, 0] = 2.0 * R * w
    t, y, _, solver = ring(model, np.zeros((2, 3)), u0, 2.0, fps=1000.0)
    tc, peaks = peaks_and_crossings(t, y[:, 0, 0])
    f_meas = 1.0 / np.diff(tc[:3]).mean()
    delta = np.log(peaks[0] / peaks[2])                            # two half cycles: one period
    zeta_meas = delta / math.sqrt(4 * math.pi ** 2 + delta ** 2)
    assert f_meas == pytest.approx(f * math.sqrt(1 - zeta ** 2), rel=0.05)
    assert zeta_meas == pytest.approx(zeta, rel=0.05)

    big = y[:, 1, 0]
    rho = np.abs(big) / R
    assert 0.6 < rho.max() < 1.0
    _, bp = peaks_and_crossings(t, big)
    assert np.all(np.diff(bp) < 0)
    top = np.abs(big) >= 0.99 * np.abs(big).max()
    assert top.sum() * (t[1] - t[0]) < 0.1 / f
    assert solver.hard_stops().sum() == 0


def test_hard_stop_detector_finds_a_wall_and_not_a_smooth_turn():
    """hard_stop_numpy on the projection the solver used to make (offset put on the reach, outward velocity
    removed in one substep): counted; on a resolved smooth turn of the tissue law: not."""
    y0 = np.array([[0.95 * R, 0, 0]])
    u0 = np.array([[5.0, 0, 0]])
    wall = tissue_law.hard_stop_numpy(y0, u0, np.array([[R, 0, 0]]), np.array([[0.0, 0.3, 0]]), np.array([R]), 1e-3)
    assert wall.all()
    w = 2 * np.pi * 6.0
    model = single_particles([w], [0.0])
    t, y, v, solver = ring(model, np.zeros((1, 3)), np.array([[2.5 * R * w, 0, 0]]), 0.2, fps=2000.0)
    hs = t[1] - t[0]
    stops = tissue_law.hard_stop_numpy(y[:-1, 0], v[:-1, 0], y[1:, 0], v[1:, 0], np.full(len(y) - 1, R), hs)
    assert np.abs(y[:, 0, 0]).max() > 0.85 * R and not stops.any() and solver.hard_stops().sum() == 0


def test_tissue_flow_kernel_matches_the_numpy_reference_with_forcing_and_springs():
    """Muscles of random parameters driven hard (goals jerked): the one-launch kernels equal
    sim.jiggle.solver.integrate_numpy (tissue_law.step_numpy per step), the sub-stepped path taken."""
    rng = np.random.default_rng(5)
    jig = [MuscleJiggle(f"m{g}", rng.uniform(2, 8), rng.uniform(0, 0.5), rng.uniform(0.1, 0.9, 40), 1000.0,
                        strength=rng.uniform(0.3, 1), spring_frequency_hz=rng.uniform(1, 6),
                        spring_damping_ratio=0.2, max_offset=0.01) for g in range(3)]
    rest = rng.normal(0, 0.05, (120, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, [5e-5] * 3, jig)
    model = b.finalize(gravity=True)
    t = np.linspace(0, 0.5, 7)
    track = build_track(t, rest[None] + np.cumsum(rng.normal(0, 0.04, (7, 1, 3)), axis=0))
    grid = np.unique(np.concatenate([np.linspace(0, 0.5, 61), t]))
    solver = ParticleSolver(model)
    x0, v0 = track.sample(0.0)[:2]
    a, o = model.state(), model.state()
    a.assign(x0, v0)
    xs = solver.integrate(a, o, track.to_device(), grid, record=np.arange(1, len(grid)))
    xr, _ = integrate_numpy(model, lambda h: solver.flow(h)[0], track, x0, v0, grid)
    off = np.stack([np.linalg.norm(xx - track.sample(tk)[0], axis=1) for xx, tk in zip(xs, grid[1:])])
    assert (off > tissue_law.ONSET * model.reach).mean() > 0.1
    assert np.abs(o.numpy()[0] - xr).max() < 1e-5


def test_frame_rate_independent_in_the_stiffening():
    """A muscle driven into its stiffening: 24 and 120 fps agree within 2% of the peak at the 24 fps frames."""
    rng = np.random.default_rng(2)
    jig = [MuscleJiggle("m", 4.0, 0.2, np.full(40, 0.3), 1000.0, strength=0.6, spring_frequency_hz=4.0,
                        spring_damping_ratio=0.2, max_offset=0.02)]
    rest = rng.normal(0, 0.03, (40, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, [5e-5], jig)
    model = b.finalize()
    knots = np.arange(0, 121) / 120.0
    swing = 0.12 * np.sin(2 * np.pi * 1.5 * knots)[:, None, None] * np.array([1.0, 0.3, 0])
    track = build_track(knots, rest[None] + swing)
    settings = JiggleSettings()
    outs = {}
    for fps in (24, 120):
        times = np.arange(0, int(fps * 0.95)) / fps
        outs[fps] = run(model, track, times, settings.substeps)
    g24 = np.stack([track.sample(tt)[0] for tt in np.arange(0, int(24 * 0.95)) / 24])
    d24, d120 = outs[24] - g24, outs[120][::5][:len(g24)] - g24
    peak = np.linalg.norm(d120, axis=2).max()
    assert peak > 1.2 * tissue_law.ONSET * model.reach.max()       # well into the stiffening
    assert np.abs(d24 - d120).max() <= 0.02 * peak


@wp.kernel
def _probe(y0: wp.array(dtype=wp.vec3), u0: wp.array(dtype=wp.vec3), y1: wp.array(dtype=wp.vec3),
           u1: wp.array(dtype=wp.vec3), reach: wp.array(dtype=float), kap: float, h: float,
           accel_out: wp.array(dtype=wp.vec3), stop_out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    accel_out[i] = particle_kernels.tissue_accel(y0[i], kap, reach[i])
    stop_out[i] = particle_kernels.hard_stop(y0[i], u0[i], y1[i], u1[i], reach[i], h)


def test_tissue_accel_and_hard_stop_kernels_match_the_numpy_reference():
    """The kernels' tissue_accel (linear range, stiffening, past the reach) and hard_stop (walls made by a
    projection, smooth turns, slow or reversing particles) against tissue_law's NumPy reference."""
    rng = np.random.default_rng(3)
    n = 4000
    reach = rng.uniform(0.005, 0.05, n)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rho0 = rng.uniform(0.0, 1.6, n)
    y0 = d * (rho0 * reach)[:, None]
    u0 = d * rng.uniform(-3, 6, n)[:, None] + rng.normal(scale=0.3, size=(n, 3))
    h = 1e-3
    wall = rng.random(n) < 0.3                       # the old stop: onto the reach, outward velocity dropped
    y1 = np.where(wall[:, None], d * reach[:, None], y0 + h * u0)
    u1 = np.where(wall[:, None], u0 - np.maximum(np.sum(u0 * d, axis=1), 0)[:, None] * d, u0 * rng.uniform(-1, 1, (n, 1)))
    kap = 2500.0
    arrs = [wp.array(a.astype(np.float32), dtype=wp.vec3) for a in (y0, u0, y1, u1)]
    acc = wp.zeros(n, dtype=wp.vec3)
    stop = wp.zeros(n, dtype=wp.int32)
    wp.launch(_probe, dim=n, inputs=[*arrs, wp.array(reach.astype(np.float32)), kap, h], outputs=[acc, stop])
    f32 = [a.astype(np.float32).astype(np.float64) for a in (y0, u0, y1, u1)]
    ref = tissue_law.accel_numpy(f32[0], np.full(n, kap), reach.astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(acc.numpy(), ref, rtol=2e-4, atol=1e-6 * kap * reach.max())
    assert (np.linalg.norm(ref, axis=1) == 0).sum() > 0.2 * n and (rho0 > 1).sum() > 0.2 * n
    stops = tissue_law.hard_stop_numpy(*f32, reach.astype(np.float32).astype(np.float64), h)
    got = stop.numpy().astype(bool)
    assert stops.sum() > 100 and (got == stops).mean() > 0.999        # float32 edge cases aside
    assert got[wall & (np.sum(u0 * d, axis=1) * h > 0.1 * reach)].all()
