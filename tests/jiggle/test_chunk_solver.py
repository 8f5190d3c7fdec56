"""The one-launch run of ParticleSolver.integrate (a thread per group of particles looping over all the
steps of a cut-free stretch) against the per-step launches of integrate_steps: the same float32
operations in the same order, so equal bit for bit, whatever the steps (uneven lengths, knots,
output steps, odd or even counts) and the groups. Also: one launch per cut-free stretch in run(), the
groups the run steps apart, and a NaN named by its muscle."""
import math

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.simple_arm import arm_world, simple_arm
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.params import MuscleJiggle
from jiggle.sim.jiggle.materials import default_jiggles
from jiggle.sim.jiggle.particles import ParticleBuilder, muscle_model
from jiggle.sim.jiggle.simulate import run, step_times
from jiggle.sim.jiggle.solver import ParticleSolver, thread_groups


def both_paths(model, track, grid, x0=None, v0=None):
    """Positions after every step (K, N, 3) and the end state (x, v), from integrate (one launch) and
    from integrate_steps (a launch per step), each on its own solver."""
    control = track.to_device(model.device)
    if x0 is None:
        x0, v0 = track.sample(float(grid[0]))[:2]
    res = []
    for one_launch in (True, False):
        solver = ParticleSolver(model)
        a, b = model.state(), model.state()
        a.assign(x0, v0)
        if one_launch:
            xs = solver.integrate(a, b, control, grid, record=np.arange(1, len(grid)))
            assert solver.launches == 1
        else:
            seen = []
            solver.integrate_steps(a, b, control, grid, on_step=lambda k, x: seen.append(x.numpy().copy()))
            xs = np.array(seen)
            assert solver.launches == len(grid) + 1          # offsets, a step each, the closing kick
        res.append((xs, *b.numpy()))
    return res


def assert_bit_equal(res):
    (xs1, x1, v1), (xs2, x2, v2) = res
    assert np.array_equal(xs1, xs2) and np.array_equal(x1, x2) and np.array_equal(v1, v2)
    assert np.array_equal(xs1[-1], x1)


@pytest.fixture(scope="module")
def arm():
    return simple_arm()


def test_one_launch_equals_the_per_step_launches_on_the_simple_arm(arm):
    model = muscle_model(arm.rig, default_jiggles(arm.rig), gravity=True)
    knots = np.arange(0, 31) / 120.0
    angle = 110.0 * np.clip(knots / 0.1, 0.0, 1.0) ** 2
    track = build_track(knots, arm.rig.static(arm_world(angle)).cvs)
    solver = ParticleSolver(model)
    grid = step_times(np.arange(7) / 30.0, track.times, 3, solver.max_step)   # knots split the steps unevenly
    assert len(np.unique(np.round(np.diff(grid), 12))) > 1
    for g in (grid, grid[:-1]):                              # an even and an odd number of steps
        res = both_paths(model, track, g)
        assert_bit_equal(res)
        assert np.abs(res[0][0][-1] - track.sample(g[-1])[0]).max() > 1e-4      # it does jiggle


def many_muscles(n=5, seed=11, reach=True):
    rng = np.random.default_rng(seed)
    jig = [MuscleJiggle(f"m{g}", rng.uniform(2, 8), rng.uniform(0, 1), rng.uniform(0, 1, 40), 1000.0,
                        strength=rng.uniform(0.3, 1), spring_frequency_hz=rng.uniform(1, 8),
                        spring_damping_ratio=rng.uniform(0, 0.5), friction=rng.uniform(0, 2),
                        max_offset=0.01 if reach and g % 2 else math.inf) for g in range(n)]
    rest = rng.normal(0, 0.05, (40 * n, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, rng.uniform(1e-5, 1e-4, n), jig)
    return b, rest, rng


def test_one_launch_equals_the_per_step_launches_on_many_muscles():
    """Five muscles of random jiggles, goals jerked around (the tissue law's sub-stepped path taken, past the
    reach on the hardest jerks), uneven steps across knots, a start off the goals."""
    b, rest, rng = many_muscles()
    model = b.finalize(gravity=True)
    assert ParticleSolver(model).num_groups == 5
    t = np.linspace(0, 0.6, 9)
    track = build_track(t, rest[None] + np.cumsum(rng.normal(0, 0.05, (9, 1, 3)), axis=0))
    grid = np.unique(np.concatenate([np.sort(rng.uniform(0.05, 0.55, 40)), t[1:-1], [0.05, 0.55]]))
    x0 = track.sample(0.05)[0] + rng.normal(0, 0.003, rest.shape)
    v0 = rng.normal(0, 0.05, rest.shape)
    res = both_paths(model, track, grid, x0, v0)
    assert_bit_equal(res)
    off = np.stack([np.linalg.norm(x - track.sample(t)[0], axis=1) for x, t in zip(res[0][0], grid[1:])])
    assert (off > model.reach).any()                                     # the stiffening (and past the reach) runs


def test_a_spring_across_muscles_merges_their_groups():
    b, rest, rng = many_muscles(4, seed=12, reach=False)
    b.add_spring(45, 85, 50.0, 0.1)                          # joins muscles 1 and 2
    model = b.finalize()
    np.testing.assert_array_equal(thread_groups(model), [0, 40, 120, 160])
    t = np.linspace(0, 0.3, 4)
    track = build_track(t, rest[None] + 0.05 * np.sin(9 * t)[:, None, None])
    assert_bit_equal(both_paths(model, track, np.linspace(0, 0.3, 13)))
    # no groups at all (particles added without begin_group) or one spring across everything: one group
    b = ParticleBuilder()
    for p in rest[:3]:
        b.add_particle(p, 0.01, 100.0)
    b.add_spring(0, 2, 10.0)
    np.testing.assert_array_equal(thread_groups(b.finalize()), [0, 3])


def test_run_launches_once_per_cut_free_stretch(arm):
    model = muscle_model(arm.rig, default_jiggles(arm.rig))
    knots = np.arange(0, 41) / 120.0
    cvs = arm.rig.static(arm_world(60.0 * np.sin(8 * knots))).cvs
    cuts = np.zeros(40, bool)
    cuts[20] = True                                           # a cut between two stretches
    times = np.arange(0, 11) / 30.0
    solver = ParticleSolver(model)
    for track, stretches in ((build_track(knots, cvs, cuts=cuts), 2), (build_track(knots, cvs, cuts=~cuts & cuts), 1)):
        grid = step_times(times, track.times, 4, solver.max_step)
        glued = int(track.cut[track.intervals(0.5 * (grid[:-1] + grid[1:]))].sum())   # a glue per step in a cut
        before = solver.launches
        out = run(model, track, times, 4, solver=solver, start=track.sample(0.0)[:2])
        assert solver.launches - before == stretches + glued and np.isfinite(out).all()


def test_nan_in_a_run_names_the_muscle_and_frame():
    b, rest, _ = many_muscles(3, reach=False)
    model = b.finalize()
    track = build_track([0.0, 1.0], np.stack([rest, rest]))
    v = np.zeros_like(rest)
    v[47, 2] = np.nan                                         # muscle m1's velocity: its positions go NaN at frame 1
    with pytest.raises(FloatingPointError, match=r"m1: the simulation produced NaN at frame 1 \(t = 0.1000 s\)"):
        run(model, track, np.arange(5) / 10.0, 2, start=(rest, v))


def test_recorded_steps_are_checked(arm):
    model = muscle_model(arm.rig, default_jiggles(arm.rig))
    track = build_track([0.0, 1.0], np.stack([model.rest, model.rest]))
    solver = ParticleSolver(model)
    a, b = model.state(), model.state()
    for bad in ([0], [3, 2], [5]):
        with pytest.raises(InputError, match="recorded steps"):
            solver.integrate(a, b, track.to_device(), np.linspace(0, 0.1, 5), record=bad)


def test_the_stepwise_run_equals_the_one_launch_run():
    """The GPU's way (ParticleSolver.stepwise: a launch per step, a thread per particle, sim/jiggle/step_kernels.py)
    run here on the CPU: the same positions, end state and hard-stop counts as the one-launch run, bit for bit,
    on the jerked muscles of the test above (the tissue law's substeps taken), for an odd and an even count."""
    b, rest, rng = many_muscles()
    model = b.finalize(gravity=True)
    t = np.linspace(0, 0.6, 9)
    track = build_track(t, rest[None] + np.cumsum(rng.normal(0, 0.05, (9, 1, 3)), axis=0))
    control = track.to_device(model.device)
    grid = np.unique(np.concatenate([np.sort(rng.uniform(0.05, 0.55, 40)), t[1:-1], [0.05, 0.55]]))
    x0 = track.sample(0.05)[0] + rng.normal(0, 0.003, rest.shape)
    v0 = rng.normal(0, 0.05, rest.shape)
    for g in (grid, grid[:-1]):
        out = []
        for stepwise in (False, True):
            solver = ParticleSolver(model)
            assert not solver.stepwise                       # the CPU's default: one launch
            solver.stepwise = stepwise
            a, b_ = model.state(), model.state()
            a.assign(x0, v0)
            xs = solver.integrate(a, b_, control, g, record=np.arange(1, len(g)))
            assert solver.launches == (len(g) + 1 if stepwise else 1)     # open, a step each, close
            out.append((xs, *b_.numpy(), solver.hard_stops()))
        for u, w in zip(*out):
            np.testing.assert_array_equal(u, w)
        assert out[0][3].sum() >= 0 and np.abs(out[0][0][-1] - track.sample(g[-1])[0]).max() > 1e-3
