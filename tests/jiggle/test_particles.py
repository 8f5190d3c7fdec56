"""The particle model and solver: physics against closed forms, kernels against the NumPy reference,
bad input. Tolerances are tied to the step h where the scheme has an error; the goal-spring flow is
exact, so single-particle tests hold to float32 round-off at any h."""
import math
from dataclasses import replace

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle.goal_flow import flow_numpy, goal_flow
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.params import BlendCurve, MuscleJiggle, section_goals
from jiggle.sim.jiggle.particles import GRAVITY, ParticleBuilder, muscle_springs, section_masses
from jiggle.sim.jiggle.solver import ParticleSolver, integrate_numpy, spring_force_numpy, step_numpy


def still_track(points, t1=10.0):
    """Goals held at `points` (N, 3) from 0 to t1 s."""
    p = np.asarray(points, dtype=np.float64)
    return build_track([0.0, t1], np.stack([p, p]))


def simulate(model, track, x0, v0, h, steps):
    """(steps + 1, N, 3) positions and velocities from single steps of the Warp solver."""
    solver = ParticleSolver(model)
    control = track.to_device(model.device)
    a, b = model.state(), model.state()
    a.assign(x0, v0)
    xs, vs = [np.asarray(x0, float)], [np.asarray(v0, float)]
    for k in range(steps):
        solver.step(a, b, control, k * h, h)
        a, b = b, a
        x, v = a.numpy()
        xs.append(x)
        vs.append(v)
    return np.array(xs), np.array(vs)


def oscillator(f=3.0, zeta=0.05, mass=0.7):
    b = ParticleBuilder()
    b.begin_group("osc")
    w = 2 * math.pi * f
    b.add_particle([0, 0, 0], mass, w * w, 2 * zeta * w)
    return b.finalize(), w


# ------------------------------------------------------------------ exact goal flow
def test_goal_flow_matches_the_closed_form_damped_oscillator_for_any_step():
    # y'' + 2 zeta w y' + w^2 y = 0, y(0) = 1, y'(0) = 0:
    # y(t) = e^{-zeta w t} (cos(wd t) + zeta w / wd sin(wd t)), wd = w sqrt(1 - zeta^2)
    w, z = 2 * math.pi * 4.0, 0.15
    wd = w * math.sqrt(1 - z * z)
    for h in (1e-3, 1 / 24, 0.3):
        c = goal_flow(np.array([w * w]), np.array([2 * z * w]), h)
        y, u = flow_numpy(c, np.ones((1, 3)), np.zeros((1, 3)), *np.zeros((3, 1, 3)))
        exact = math.exp(-z * w * h) * (math.cos(wd * h) + z * w / wd * math.sin(wd * h))
        assert y[0, 0] == pytest.approx(exact, abs=1e-12)


def test_goal_flow_takes_polynomial_forcing_exactly():
    # y'' = b0 + b1 t + b2 t^2 (k = c = 0): y(h) = b0 h^2/2 + b1 h^3/6 + b2 h^4/12, u(h) = b0 h + b1 h^2/2 + b2 h^3/3
    h = 0.37
    c = goal_flow(np.zeros(1), np.zeros(1), h)
    b0, b1, b2 = (np.full((1, 3), v) for v in (1.5, -2.0, 0.75))
    y, u = flow_numpy(c, np.zeros((1, 3)), np.zeros((1, 3)), b0, b1, b2)
    assert y[0, 0] == pytest.approx(1.5 * h**2 / 2 - 2.0 * h**3 / 6 + 0.75 * h**4 / 12, rel=1e-12)
    assert u[0, 0] == pytest.approx(1.5 * h - 2.0 * h**2 / 2 + 0.75 * h**3 / 3, rel=1e-12)
    # and a stiff, damped particle under constant forcing settles at b0 / k
    c = goal_flow(np.array([400.0]), np.array([40.0]), 10.0)
    y, _ = flow_numpy(c, np.zeros((1, 3)), np.zeros((1, 3)), b0, np.zeros((1, 3)), np.zeros((1, 3)))
    assert y[0, 0] == pytest.approx(1.5 / 400.0, rel=1e-9)


def test_glued_particles_have_a_zero_flow():
    c = goal_flow(np.array([np.inf, 1.0]), np.array([0.0, 0.0]), 0.1)
    assert np.all(c[0] == 0) and np.any(c[1] != 0)


# ------------------------------------------------------------------ physics
def test_goal_spring_frequency_and_decay_match_the_damped_oscillator():
    # m y'' = -m w^2 y - 2 m zeta w y': peaks every Td = 2 pi / (w sqrt(1 - zeta^2)), each peak
    # e^{-zeta w Td} times the last. Peaks are located by a parabola through the three samples around
    # each maximum: error O(h^2) in time, so h = 1/2000 s keeps the estimates well inside 1%.
    model, w = oscillator(f=3.0, zeta=0.05)
    h = 1 / 2000
    xs, _ = simulate(model, still_track([[0, 0, 0]]), [[0.02, 0, 0]], [[0, 0, 0]], h, 6000)
    y = xs[:, 0, 0]
    k = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])) + 1
    a, b, c = y[k - 1], y[k], y[k + 1]
    shift = 0.5 * (a - c) / (a - 2 * b + c)
    t_peak = (k + shift) * h
    y_peak = b - 0.25 * (a - c) * shift
    td = np.diff(t_peak)
    wd_measured = 2 * math.pi / td.mean()
    decay_measured = -np.log(y_peak[1:] / y_peak[:-1]).mean() / td.mean()
    zeta = 0.05
    assert len(k) >= 6
    assert wd_measured == pytest.approx(w * math.sqrt(1 - zeta**2), rel=0.01)
    assert decay_measured == pytest.approx(zeta * w, rel=0.01)


def test_goal_spring_follows_the_closed_form_at_a_coarse_step():
    # the flow is exact: at h = 1/24 s the samples sit on the analytic curve to float32 round-off
    model, w = oscillator(f=2.0, zeta=0.3)
    h = 1 / 24
    xs, _ = simulate(model, still_track([[0, 0, 0]]), [[0.05, 0, 0]], [[0, 0, 0]], h, 48)
    t = np.arange(49) * h
    wd = w * math.sqrt(1 - 0.09)
    exact = 0.05 * np.exp(-0.3 * w * t) * (np.cos(wd * t) + 0.3 * w / wd * np.sin(wd * t))
    assert np.abs(xs[:, 0, 0] - exact).max() < 1e-7


def test_free_fall_matches_g_t_squared_over_two():
    # goal weight 0 (k = 0), no springs, gravity: z(t) = z0 + v0 t - g t^2 / 2, exactly for any step
    b = ParticleBuilder()
    b.begin_group("ball")
    b.add_particle([0, 0, 1.0], 0.3, 0.0, 0.0)
    model = b.finalize(gravity=True)
    h = 1 / 30
    xs, vs = simulate(model, still_track([[0, 0, 1.0]]), [[0, 0, 1.0]], [[0.5, 0, 2.0]], h, 30)
    t = np.arange(31) * h
    np.testing.assert_allclose(xs[:, 0, 2], 1.0 + 2.0 * t - GRAVITY * t**2 / 2, atol=2e-6)
    np.testing.assert_allclose(xs[:, 0, 0], 0.5 * t, atol=2e-6)
    np.testing.assert_allclose(vs[:, 0, 2], 2.0 - GRAVITY * t, atol=2e-5)


def chain(n=12, k=400.0, c=0.0, goal_k=0.0, mass=0.05, spacing=0.02):
    b = ParticleBuilder()
    b.begin_group("chain")
    for i in range(n):
        b.add_particle([i * spacing, 0, 0], mass * (1 + 0.3 * (i % 3)), goal_k, 0.0)
    for i in range(n - 1):
        b.add_spring(i, i + 1, k, c)
    return b.finalize()


def test_a_free_chain_conserves_momentum():
    # no goal, no damping: internal spring forces are equal and opposite, so sum m v is constant
    # (velocity Verlet); float32 state: round-off ~1e-7 of the momentum scale
    model = chain()
    rng = np.random.default_rng(1)
    x0 = model.rest + rng.normal(0, 0.003, model.rest.shape)
    v0 = rng.normal(0, 0.2, model.rest.shape)
    _, vs = simulate(model, still_track(model.rest), x0, v0, 1 / 240, 400)
    p = np.einsum("i,tij->tj", model.mass, vs)
    scale = np.sum(model.mass[:, None] * np.abs(v0))
    assert np.abs(p - p[0]).max() < 1e-5 * scale
    assert np.abs(vs[-1] - v0).max() > 1e-3          # the chain did move


def test_a_damped_chain_loses_energy_monotonically():
    # with spring dampers and goal springs, E = sum m u^2/2 + sum m k y^2/2 + sum k_s |dy|^2/2 never
    # grows; velocity Verlet's energy wobbles by O((w h)^2) of E per step, far below the damping loss
    # per step at w h ~ 0.1 (the slack allows float32 round-off)
    model = chain(k=300.0, c=0.4, goal_k=(2 * math.pi * 3) ** 2)
    rng = np.random.default_rng(2)
    x0 = model.rest + rng.normal(0, 0.004, model.rest.shape)
    xs, vs = simulate(model, still_track(model.rest), x0, np.zeros_like(x0), 1 / 600, 600)
    zero = np.zeros_like(model.rest)
    e = np.array([model.energy(x, v, model.rest, zero) for x, v in zip(xs, vs)])
    assert e[-1] < 0.05 * e[0]
    assert np.all(np.diff(e) <= 1e-6 * e[0])


def test_glued_particles_equal_their_goals_while_goals_move():
    # goal weight 1 (k = inf) or jiggle strength 0: the particle is its goal, whatever the springs do
    mj = MuscleJiggle("m", 5.0, 0.3, np.ones(40), 1000.0, spring_frequency_hz=5.0, spring_damping_ratio=0.2)
    assert np.all(np.isinf(mj.goal_stiffness()))
    mj0 = MuscleJiggle("m", 5.0, 0.3, section_goals(0.5, 0.2), 1000.0, strength=0.0)
    assert np.all(np.isinf(mj0.goal_stiffness()))
    rest = np.random.default_rng(3).normal(0, 0.05, (40, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, [1e-4], [mj])
    model = b.finalize(gravity=True)
    t = np.linspace(0, 1, 31)
    goals = rest[None] + np.stack([np.sin(7 * t), np.cos(5 * t), t * t], 1)[:, None, :] * 0.3
    track = build_track(t, goals)
    solver = ParticleSolver(model)
    control = track.to_device()
    a, b_ = model.state(), model.state()
    solver.glue(a, control, 0.0)
    grid = np.linspace(0, 1, 121)
    xs = solver.integrate(a, b_, control, grid, record=np.arange(1, len(grid)))
    for k, x in enumerate(xs, 1):
        np.testing.assert_allclose(x, track.sample(grid[k])[0], atol=2e-6)


def test_rest_stays_at_rest():
    # goals still, particles on them, no gravity: nothing moves, to the last bit of float32
    rest = np.random.default_rng(4).normal(0, 0.05, (40, 3))
    mj = MuscleJiggle("m", 5.0, 0.3, section_goals(0.9, 0.2), 1000.0, spring_frequency_hz=5.0,
                      spring_damping_ratio=0.2, friction=0.5)
    b = ParticleBuilder()
    b.add_muscles(rest, [1e-4], [mj])
    model = b.finalize()
    xs, vs = simulate(model, still_track(rest), rest, np.zeros_like(rest), 1 / 60, 60)
    assert np.abs(xs - rest).max() < 1e-6 and np.abs(vs).max() < 1e-5


# ------------------------------------------------------------------ kernels = NumPy reference
def random_model(n_groups=3, gravity=True, seed=5):
    rng = np.random.default_rng(seed)
    jig = [MuscleJiggle(f"m{g}", rng.uniform(2, 8), rng.uniform(0, 1), rng.uniform(0, 1, 40), 1000.0,
                        strength=rng.uniform(0.2, 1), spring_frequency_hz=rng.uniform(1, 8),
                        spring_damping_ratio=rng.uniform(0, 0.5), friction=rng.uniform(0, 2)) for g in range(n_groups)]
    jig[0] = MuscleJiggle("m0", 4.0, 0.4, np.where(np.arange(40) < 8, 1.0, 0.3), 1000.0, spring_frequency_hz=4.0)
    rest = rng.normal(0, 0.05, (40 * n_groups, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, rng.uniform(1e-5, 1e-4, n_groups), jig)
    return b.finalize(gravity=gravity), rest, rng


def test_step_kernel_matches_the_numpy_reference():
    model, rest, rng = random_model()
    t = np.linspace(0, 0.5, 7)
    goals = rest[None] + rng.normal(0, 0.02, (7,) + rest.shape)
    track = build_track(t, goals)
    solver = ParticleSolver(model)
    x0 = goals[1] + rng.normal(0, 0.005, rest.shape)
    v0 = rng.normal(0, 0.1, rest.shape)
    a, b = model.state(), model.state()
    a.assign(x0, v0)
    h = 0.02
    solver.step(a, b, track.to_device(), t[1] + 0.01, h)
    x_ref, v_ref = step_numpy(model, solver.flow(h)[0], track, x0, v0, t[1] + 0.01, h)
    x, v = b.numpy()
    assert np.abs(x - x_ref).max() < 2e-6
    assert np.abs(v - v_ref).max() < 2e-4 * max(1.0, np.abs(v_ref).max())


def integrate_both(model, track, grid, seen=None):
    """The kernels' and the NumPy reference's integration over `grid` from the track's start, moving
    with the goals: ((x, v) of the kernels, (x, v) of the reference), (N, 3) each. `seen`: a list to
    extend with the kernels' positions after every step."""
    solver = ParticleSolver(model)
    x0, v0 = track.sample(float(grid[0]))[:2]
    a, b = model.state(), model.state()
    a.assign(x0, v0)
    xs = solver.integrate(a, b, track.to_device(), grid, record=np.arange(1, len(grid)))
    if seen is not None:
        seen.extend(xs)
    return b.numpy(), integrate_numpy(model, lambda h: solver.flow(h)[0], track, x0, v0, grid)


def test_integrate_kernels_match_the_numpy_reference_across_knots():
    model, rest, rng = random_model(seed=6)
    t = np.linspace(0, 0.5, 7)
    goals = rest[None] + rng.normal(0, 0.02, (7,) + rest.shape)
    track = build_track(t, goals)
    grid = np.unique(np.concatenate([np.linspace(0, 0.5, 41), t]))
    (x, v), (x_ref, v_ref) = integrate_both(model, track, grid)
    assert np.abs(x - x_ref).max() < 1e-5
    assert np.abs(v - v_ref).max() < 1e-3 * max(1.0, np.abs(v_ref).max())


def test_tissue_law_turns_jerked_particles_back_near_their_reach_and_matches_the_numpy_reference():
    """Goals jerked 10 cm per knot: soft particles (1.5 Hz, goal weight 0.2) lag several of their reaches behind
    on a linear spring; under the tissue law (sim/jiggle/tissue_law.py) they slow down and turn back around
    their reach of 1-3 cm (no projection, nothing removed: up to a fifth past it on the hardest jerks), and
    the kernels equal the NumPy reference step for step, the sub-stepped path included."""
    rng = np.random.default_rng(8)
    jig = [MuscleJiggle(f"m{g}", 1.5, 0.2, np.full(40, 0.2), 1000.0, spring_frequency_hz=3.0,
                        max_offset=0.01 * (g + 1), strength=1.0) for g in range(3)]
    rest = rng.normal(0, 0.05, (120, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, [5e-5] * 3, jig)
    model = b.finalize()
    np.testing.assert_allclose(model.reach, np.repeat([0.01, 0.02, 0.03], 40))
    t = np.linspace(0, 0.6, 7)
    goals = rest[None] + np.cumsum(rng.normal(0, 0.1, (7, 1, 3)), axis=0)
    track = build_track(t, goals)
    grid = np.unique(np.concatenate([np.linspace(0, 0.6, 49), t]))
    seen = []
    (x, v), (x_ref, v_ref) = integrate_both(model, track, grid, seen)
    assert np.abs(x - x_ref).max() < 5e-5                          # float32 against float64 past the reach
    assert np.abs(v - v_ref).max() < 1e-3 * max(1.0, np.abs(v_ref).max())
    off = np.stack([np.linalg.norm(xs - track.sample(tk)[0], axis=1) for xs, tk in zip(seen, grid[1:])])
    rho = off / model.reach
    assert rho.max() > 0.9                                    # the law is what turns them back
    assert rho.max() < 1.25

    unbounded = ParticleBuilder()                             # the same particles with no reach: far beyond it
    unbounded.add_muscles(rest, [5e-5] * 3, [replace(j, max_offset=math.inf) for j in jig])
    free = []
    integrate_both(unbounded.finalize(), track, grid, free)
    off_free = np.stack([np.linalg.norm(xs - track.sample(tk)[0], axis=1) for xs, tk in zip(free, grid[1:])])
    assert (off_free / model.reach).max() > 2.0


def test_integrate_equals_single_steps_without_spring_damping():
    # merging the closing and opening half kicks changes nothing when the spring force does not
    # depend on velocity
    rest = np.random.default_rng(7).normal(0, 0.05, (40, 3))
    mj = MuscleJiggle("m", 5.0, 0.3, section_goals(0.9, 0.3), 1000.0, spring_frequency_hz=6.0)
    b = ParticleBuilder()
    b.add_muscles(rest, [1e-4], [mj])
    model = b.finalize()
    t = np.linspace(0, 1, 11)
    track = build_track(t, rest[None] + 0.1 * np.sin(6 * t)[:, None, None])
    solver = ParticleSolver(model)
    x0, v0 = track.sample(0.0)[:2]
    grid = np.linspace(0, 1, 61)
    x1, v1 = x0, v0
    for a, b_ in zip(grid[:-1], grid[1:]):
        x1, v1 = step_numpy(model, solver.flow(b_ - a)[0], track, x1, v1, a, b_ - a)
    x2, v2 = integrate_numpy(model, lambda h: solver.flow(h)[0], track, x0, v0, grid)
    np.testing.assert_allclose(x2, x1, atol=1e-12)
    np.testing.assert_allclose(v2, v1, atol=1e-9)


def test_spring_force_is_equal_and_opposite():
    model, rest, rng = random_model(seed=8)
    f = spring_force_numpy(model, rng.normal(size=rest.shape), rng.normal(size=rest.shape))
    assert np.abs(f.sum(axis=0)).max() < 1e-9 * np.abs(f).sum()


# ------------------------------------------------------------------ model building
def test_muscle_springs_hold_rings_lines_and_nearest_neighbours():
    rest = np.random.default_rng(9).normal(0, 0.05, (40, 3))
    pairs = {tuple(p) for p in muscle_springs(rest)}
    assert (0, 1) in pairs and (0, 7) in pairs and (0, 8) in pairs and (31, 39) in pairs
    d = np.linalg.norm(rest[:, None] - rest[None], axis=2)
    np.fill_diagonal(d, np.inf)
    for i in range(40):
        for j in np.argsort(d[i])[:2]:
            assert (min(i, j), max(i, j)) in pairs
    assert all(i < j for i, j in pairs)


def test_masses_add_up_to_density_times_volume():
    from jiggle.rig.muscle.simple_arm import simple_arm
    rig = simple_arm().rig
    m = section_masses(rig.rest_cvs.reshape(5, 8, 3), 1060.0 * rig.rest_volume[0])
    assert m.sum() == pytest.approx(1060.0 * rig.rest_volume[0])
    assert m[16] > m[0]                                 # the belly outweighs the tendon end


def test_jiggle_strength_scales_the_offset_linearly():
    # quasi-static offset a / w^2 with w^2 = k(J = 1) / J: proportional to J
    k1 = MuscleJiggle("m", 5.0, 0.3, np.full(40, 0.5), 1000.0, strength=1.0).goal_stiffness()
    k4 = MuscleJiggle("m", 5.0, 0.3, np.full(40, 0.5), 1000.0, strength=0.25).goal_stiffness()
    np.testing.assert_allclose(k1, (2 * math.pi * 5.0) ** 2)
    np.testing.assert_allclose(k4, 4 * k1)


def test_spring_rate_bound_holds_the_true_frequency():
    model, _, _ = random_model(gravity=False, seed=10)
    omega, gamma = model.spring_rate_bound()
    free = ~model.glued
    n = model.num_particles
    K = np.zeros((n, n))
    for (i, j), k in zip(model.springs, model.spring_k):
        K[i, i] += k
        K[j, j] += k
        K[i, j] -= k
        K[j, i] -= k
    s = 1 / np.sqrt(model.mass)
    A = (s[:, None] * K * s[None])[np.ix_(free, free)]
    assert np.sqrt(np.linalg.eigvalsh(A).max()) <= omega * (1 + 1e-9)


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kw, field", [
    (dict(mass=-1.0), "mass"), (dict(mass=0.0), "mass"), (dict(goal_stiffness=-5.0), "goal_stiffness"),
    (dict(goal_damping=-0.1), "goal_damping"), (dict(drag=float("nan")), "drag")])
def test_bad_particles_name_the_muscle(kw, field):
    b = ParticleBuilder()
    b.begin_group("left_biceps")
    args = dict(position=[0, 0, 0], mass=1.0)
    args.update(kw)
    with pytest.raises(InputError, match="left_biceps") as e:
        b.add_particle(**args)
    assert e.value.field == field


def test_bad_springs_name_the_muscle():
    b = ParticleBuilder()
    b.begin_group("belly_fat")
    b.add_particle([0, 0, 0], 1.0)
    b.add_particle([1, 0, 0], 1.0)
    with pytest.raises(InputError, match="belly_fat.*stiffness"):
        b.add_spring(0, 1, -3.0)
    with pytest.raises(InputError, match="belly_fat.*damping"):
        b.add_spring(0, 1, 3.0, -1.0)
    with pytest.raises(InputError, match="two different particles"):
        b.add_spring(0, 0, 3.0)


@pytest.mark.parametrize("kw, match", [
    (dict(frequency_hz=-1.0), "frequency_hz must be > 0"), (dict(damping_ratio=-0.5), "damping_ratio"),
    (dict(density=0.0), "density"), (dict(strength=1.5), "strength must be in"),
    (dict(spring_frequency_hz=-2.0), "spring_frequency_hz"), (dict(spring_damping_ratio=-1.0), "spring_damping"),
    (dict(friction=-1.0), "friction"), (dict(goal=np.full(40, 1.2)), "goal weight of CV 0 must be in"),
    (dict(goal=np.full(39, 0.5)), "40 values"), (dict(blend=1.5), "blend must be in")])
def test_bad_jiggle_parameters_name_the_muscle(kw, match):
    args = dict(name="right_calf", frequency_hz=5.0, damping_ratio=0.3, goal=np.full(40, 0.5), density=1000.0)
    args.update(kw)
    with pytest.raises(InputError, match=match) as e:
        MuscleJiggle(**args)
    assert "right_calf" in str(e.value)


def test_bad_blend_curves():
    with pytest.raises(InputError, match="blend must be in .* at t = 0.5"):
        BlendCurve.parse([[0.0, 0.0], [0.5, -0.1]], "blend")
    with pytest.raises(InputError, match="must increase"):
        BlendCurve.parse([[0.5, 0.0], [0.5, 1.0]], "blend")
    with pytest.raises(InputError, match="expected a number"):
        BlendCurve.parse("full", "blend")
    c = BlendCurve.parse([[0.0, 0.0], [1.0, 1.0]], "blend")
    np.testing.assert_allclose(c([-1.0, 0.25, 2.0]), [0.0, 0.25, 1.0])


@pytest.mark.parametrize("dt", [0.0, -0.01, float("nan")])
def test_non_positive_steps_are_refused(dt):
    model, _ = oscillator()
    track = still_track([[0, 0, 0]])
    solver = ParticleSolver(model)
    with pytest.raises(InputError, match="time step must be a finite number > 0") as e:
        solver.step(model.state(), model.state(), track.to_device(), 0.0, dt)
    assert e.value.field == "dt"


def test_steps_must_stay_inside_a_knot_interval():
    model, _ = oscillator()
    track = build_track([0.0, 0.1, 0.2], np.zeros((3, 1, 3)))
    with pytest.raises(InputError, match="inside one knot interval"):
        ParticleSolver(model).step(model.state(), model.state(), track.to_device(), 0.05, 0.1)


def test_nan_goals_name_the_muscle_and_frame():
    pos = np.zeros((5, 80, 3))
    pos[3, 47, 1] = np.nan
    with pytest.raises(InputError, match=r"muscle 'belly_fat' \(CV 7\).*frame 3 \(t = 0.3000 s\)"):
        build_track(np.arange(5) * 0.1, pos, names=("abdomen", "belly_fat"), offsets=np.array([0, 40, 80]))
