"""Secondary motion of a whole rig (sim/jiggle/secondary.py) on the thesis's simple arm: blend, start, gravity,
goal track, and the skin seeing the blended CVs."""
import math
from dataclasses import replace

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.simple_arm import arm_world, simple_arm
from jiggle.rig.skin.muscle_skin import MuscleSkin
from jiggle.sim.jiggle.goal_track import build_track, find_cuts
from jiggle.sim.jiggle.params import BlendCurve, JiggleSettings, override
from jiggle.sim.jiggle.materials import default_jiggles
from jiggle.sim.jiggle.particles import muscle_model
from jiggle.sim.jiggle.secondary import jiggle_rig, knot_times
from jiggle.sim.jiggle.simulate import equilibrium, step_times


def flex(t):
    """Elbow angle (degrees): 0 -> 110 over 0.1-0.25 s (smoothstep), held."""
    a = np.clip((np.asarray(t) - 0.1) / 0.15, 0.0, 1.0)
    return 110.0 * a * a * (3.0 - 2.0 * a)


def world_at(t):
    return arm_world(flex(t))


@pytest.fixture(scope="module")
def arm():
    return simple_arm()


@pytest.fixture(scope="module")
def flexed(arm):
    times = np.arange(0, 31) / 30.0
    return jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, times, JiggleSettings(substeps=4))


def test_the_muscle_lags_overshoots_and_settles(flexed):
    amp = flexed.amplitude()[:, 0]
    peak = int(np.argmax(amp))
    assert amp[0] < 1e-6                                  # starts settled on its goals
    assert amp[peak] > 1e-3                               # a visible jiggle (> 1 mm)
    assert 0.1 < flexed.times[peak] < 0.5
    assert amp[-1] < 0.2 * amp[peak]                      # and it settles once the arm holds still


def test_blend_one_is_the_dynamics_and_zero_is_static(arm, flexed):
    np.testing.assert_array_equal(flexed.cvs, flexed.dynamic)
    zero = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, flexed.times,
                      JiggleSettings(blend=BlendCurve.constant(0.0)))
    np.testing.assert_array_equal(zero.cvs, zero.static)
    np.testing.assert_array_equal(zero.static, flexed.static)


def test_blend_zero_reproduces_the_static_skin_on_every_vertex(arm):
    # the whole pipeline: the shells fed the blended CVs at b = 0 equal the static pipeline (cvs=None)
    times = np.arange(0, 10) / 30.0
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, times, JiggleSettings(blend=0.0))
    skin = MuscleSkin(arm.character, arm.rig)
    worst = 0.0
    for k, t in enumerate(times):
        w = world_at(t)
        static_skin = skin.pose(w)
        blended_skin = skin.pose(w, cvs=res.cvs[k], curve=res.curve[k], frame=k)
        worst = max(worst, float(np.abs(blended_skin - static_skin).max()))
    assert worst <= 1e-6


def test_the_skin_sees_the_dynamic_muscle(arm, flexed):
    skin = MuscleSkin(arm.character, arm.rig)
    k = int(np.argmax(flexed.amplitude()[:, 0]))
    w = world_at(flexed.times[k])
    moved = np.abs(skin.pose(w, cvs=flexed.cvs[k], curve=flexed.curve[k]) - skin.pose(w)).max()
    assert moved > 2e-4


def test_per_muscle_keyed_blend(arm, flexed):
    jig = [override(default_jiggles(arm.rig)[0], {"blend": [[0.0, 0.0], [0.5, 1.0]]})]
    res = jiggle_rig(arm.rig, jig, world_at, flexed.times, JiggleSettings(substeps=4, blend=0.0))
    b = np.clip(flexed.times / 0.5, 0, 1)
    np.testing.assert_allclose(res.blend[:, 0], b)
    expect = flexed.static + b[:, None, None] * (flexed.dynamic - flexed.static)
    np.testing.assert_allclose(res.cvs, expect, atol=1e-12)


def test_jiggle_strength_zero_is_static(arm, flexed):
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, flexed.times, JiggleSettings(strength=0.0))
    assert np.abs(res.dynamic - res.static).max() < 2e-6            # float32 state


def test_jiggle_strength_scales_the_jiggle(arm, flexed):
    half = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, flexed.times,
                      JiggleSettings(substeps=4, strength=0.5))
    ratio = half.amplitude().max() / flexed.amplitude().max()
    assert 0.3 < ratio < 0.75                   # offsets ~ J; the faster wobble changes the peak a little


def test_results_do_not_depend_on_frame_rate_or_substeps(arm):
    # the full table is in benchmarks/bench_jiggle.py and tests/jiggle/test_jiggle_clips.py; here one pair
    ref = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, np.arange(0, 61) / 60.0, JiggleSettings(substeps=8))
    low = jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, np.arange(0, 25) / 24.0, JiggleSettings(substeps=1))
    peak = np.linalg.norm(ref.dynamic - ref.static, axis=2).max()
    common = np.arange(0, 13) / 12.0                           # the times both frame rates hit
    a = np.searchsorted(ref.times, common - 1e-9)
    b = np.searchsorted(low.times, common - 1e-9)
    err = np.linalg.norm(low.dynamic[b] - ref.dynamic[a], axis=2).max()
    assert err < 0.02 * peak


def test_a_still_pose_stays_still_with_and_without_gravity(arm):
    times = np.arange(0, 16) / 30.0
    still = lambda t: arm_world(np.full(len(t), 40.0))  # noqa: E731
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), still, times, JiggleSettings())
    assert np.abs(res.dynamic - res.static).max() < 2e-6
    grav = jiggle_rig(arm.rig, default_jiggles(arm.rig), still, times, JiggleSettings(gravity=True))
    sag = grav.dynamic - grav.static
    assert sag[0, :, 2].min() < -1e-5                             # it hangs below its goals...
    # ...and starts settled there: the split step's own equilibrium differs from the exact one by
    # O((omega h)^2) of the sag for the stiff tendon particles (omega h ~ 1 at h = 1/120 s)
    assert np.abs(sag - sag[0]).max() < 0.15 * np.abs(sag).max()


def test_equilibrium_balances_gravity(arm):
    from jiggle.sim.jiggle.solver import spring_force_numpy
    model = muscle_model(arm.rig, default_jiggles(arm.rig), gravity=True)
    y = equilibrium(model)
    f = spring_force_numpy(model, y, np.zeros_like(y)) - (model.mass * model.goal_k)[:, None] * np.where(
        model.glued[:, None], 0.0, y)
    f[:, 2] -= 9.81 * model.mass
    free = ~model.glued
    assert np.abs(f[free]).max() < 1e-9 * (9.81 * model.mass.max())
    assert np.all(y[model.glued] == 0)


def test_preroll_starts_from_the_bind_pose_and_settles(arm):
    # the first frame is far from bind (elbow at 90 deg); a 1 s preroll moves the particles there and lets them settle
    times = np.arange(0, 6) / 30.0
    bent = lambda t: arm_world(np.full(len(t), 90.0))  # noqa: E731
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), bent, times, JiggleSettings(preroll=1.0))
    moved = np.linalg.norm(res.static[0] - arm.rig.rest_cvs, axis=1).max()
    assert moved > 0.05
    assert np.linalg.norm(res.dynamic - res.static, axis=2).max() < 0.01 * moved
    short = jiggle_rig(arm.rig, default_jiggles(arm.rig), bent, times, JiggleSettings(preroll=0.1))
    assert np.linalg.norm(short.dynamic - short.static, axis=2).max() > \
        np.linalg.norm(res.dynamic - res.static, axis=2).max()


def test_a_cut_resets_the_particles_to_their_goals(arm):
    # a teleport of 1 m at t = 0.5 s while the arm flexes: the particles restart on their goals, as a
    # run that starts there (at the quasi-static offset of the goals' motion: well under a millimetre)
    def jumpy(t):
        w = arm_world(60 + 50 * np.sin(9 * np.asarray(t)))
        w[:, :, 0, 3] += np.where(np.asarray(t) >= 0.5, 1.0, 0.0)[:, None]
        return w
    times = np.arange(0, 31) / 60.0 + 0.1
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), jumpy, times, JiggleSettings(substeps=2))
    assert len(res.cuts) == 1 and 0.49 < res.cuts[0] < 0.5
    after = int(np.searchsorted(res.times, 0.5 - 1e-9))
    fresh = jiggle_rig(arm.rig, default_jiggles(arm.rig), jumpy, times[after:], JiggleSettings(substeps=2))
    np.testing.assert_allclose(res.dynamic[after:], fresh.dynamic, atol=1e-6)
    assert np.abs(res.dynamic[after] - res.static[after]).max() < 1e-3
    assert np.abs(res.dynamic[after + 3] - res.static[after + 3]).max() > 1e-5     # and jiggles on
    assert np.linalg.norm(res.dynamic - res.static, axis=2).max() < 0.02


def test_knot_grid_is_shared_by_the_usual_frame_rates():
    k24 = knot_times(np.arange(0, 25) / 24.0, 120.0)
    k60 = knot_times(np.arange(0, 61) / 60.0, 120.0)
    np.testing.assert_allclose(k24, k60)
    assert len(k24) == 121 + 2 and k24[-1] == pytest.approx(1.0 + 2 / 120)


def test_step_times_cover_outputs_knots_and_the_step_limit():
    grid = step_times(np.array([0.0, 0.1, 0.2]), np.array([0.0, 0.05, 0.2]), 2, 0.03)
    for t in (0.0, 0.05, 0.1, 0.15, 0.2):
        assert np.min(np.abs(grid - t)) < 1e-12
    assert np.diff(grid).max() <= 0.03 + 1e-12


def test_goal_track_velocities_are_exact_for_quadratics():
    t = np.array([0.0, 0.1, 0.25, 0.3, 0.5])
    p = (3 * t**2 - t)[:, None, None] * np.ones((1, 2, 3))
    tr = build_track(t, p)
    np.testing.assert_allclose(tr.vel_start[:, 0, 0], 6 * t[:-1] - 1, atol=1e-12)
    np.testing.assert_allclose(tr.vel_end[:, 0, 0], 6 * t[1:] - 1, atol=1e-12)
    g, gv, ga = tr.sample(0.4)
    assert g[0, 0] == pytest.approx(3 * 0.16 - 0.4) and ga[0, 0] == pytest.approx(6.0)


def test_cuts_need_a_jump_far_beyond_the_motion():
    t = np.arange(20) / 30.0
    p = np.zeros((20, 3, 3))
    p[:, :, 0] = (2.0 * t)[:, None]                      # 2 m/s: 6.7 cm per knot, no cut
    assert not find_cuts(t, p).any()
    p[12:, :, 0] += 0.5
    cut = find_cuts(t, p)
    assert cut.tolist() == [i == 11 for i in range(19)]
    vs = build_track(t, p).vel_start
    np.testing.assert_allclose(vs[12, 0, 0], 2.0, atol=1e-9)   # one-sided after the cut


def test_bad_output_times_and_jiggle_counts(arm):
    with pytest.raises(InputError, match="increasing"):
        jiggle_rig(arm.rig, default_jiggles(arm.rig), world_at, np.array([0.0, 0.0]))
    with pytest.raises(InputError, match="one per muscle"):
        jiggle_rig(arm.rig, default_jiggles(arm.rig) * 2, world_at, np.array([0.0, 0.1]))
    with pytest.raises(InputError, match="substeps"):
        JiggleSettings(substeps=0)
    with pytest.raises(InputError, match=r"strength must be in \[0, 1\]"):
        JiggleSettings(strength=-1.0)


def test_nan_pose_names_the_muscle_and_frame(arm):
    def broken(t):
        w = world_at(t)
        w[np.asarray(t) > 0.2, 1, 0, 3] = np.nan
        return w
    with pytest.raises(InputError, match="NaN"):
        jiggle_rig(arm.rig, default_jiggles(arm.rig), broken, np.arange(0, 10) / 30.0)


def test_overrides_rebuild_goal_weights():
    arm = simple_arm()
    mj = default_jiggles(arm.rig)[0]
    o = override(mj, {"goal_tendon": 1.0, "goal_belly": 0.2, "frequency": 4.0})
    assert o.goal[0] == 1.0 and o.goal[16] == 0.2 and o.goal[8] == pytest.approx(0.6)
    assert o.frequency_hz == 4.0 and math.isinf(o.goal_stiffness()[0])
    assert override(mj, {"goal": [0.1] * 5}).goal.tolist() == [0.1] * 40
    with pytest.raises(InputError, match="unknown jiggle key"):
        override(mj, {"stiffness": 3.0})
    with pytest.raises(InputError, match="goal weight"):
        override(mj, {"goal": 2.0})
    assert replace(mj, strength=0.5).strength == 0.5


def test_a_clip_cut_mid_motion_starts_without_a_jolt(arm):
    """The arm accelerating steadily at 4 m/s^2 from the first frame on: the particles start at the
    quasi-static offset of their goals' acceleration (sim.jiggle.simulate.restart), so the muscle hangs
    back by that offset from the first frame and never swings past it. Starting at rest on the goals,
    it would swing to twice that offset and back (a spring driven by a step of force)."""
    acc = 4.0

    def pushed(t):
        w = arm_world(np.full(np.shape(t), 60.0))
        w[:, :, 0, 3] += 0.5 * acc * np.asarray(t)[:, None] ** 2
        return w
    times = np.arange(0, 31) / 30.0
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), pushed, times, JiggleSettings())
    amp = res.amplitude()[:, 0]
    steady = amp[-1]
    assert steady > 1e-4                                          # the muscle does hang back
    assert np.all(np.abs(amp - steady) < 0.05 * steady), amp / steady
