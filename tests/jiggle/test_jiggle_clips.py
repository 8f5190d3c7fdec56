"""Secondary motion over whole clips (sim/jiggle/secondary.py): integration that holds.

- Frame-rate and substep independence: the simple arm flexing fast, baked at 24, 30, 60 and 120 fps
  with 1 to 16 substeps, agrees with the 120 fps x 16 substeps bake within 2% of the peak jiggle.
- No explosion: every shared CMU clip (BVH and the ASF/AMC one) on a generated body with the human
  template, every muscle at jiggle strength 1 and goal weight 0.1 (soft goals: the fat rings at
  0.93 Hz with damping ratio 0.2): no NaN, no false cut, every particle within BOUND_M of its goal.
- Cuts: a clip with a spliced teleport is cut there and the particles restart, exactly as if the clip
  started at the cut; without cut detection they would fly metres off.

benchmarks/bench_jiggle.py prints the same independence measure as a table (with a body on 09_11) and
the speed figures.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import CMU_BVH, asset

from jiggle.rig.muscle.simple_arm import arm_world, simple_arm
from jiggle.sim.jiggle.params import JiggleSettings, override
from jiggle.sim.jiggle.materials import default_jiggles
from jiggle.sim.jiggle.secondary import jiggle_rig, knot_times

# ---------------------------------------------------------------------------------- frame rate
# CLIP_S is a whole number of frames at every rate, so every bake's goal track ends at the same time
# (sim/jiggle/secondary.py ends it at the last output frame; benchmarks/bench_jiggle.py shows the end effect)
FLEX_DEG, FLEX_S, HOLD_S, CLIP_S = 120.0, 0.2, 0.5, 1.5
RATES = (24, 30, 60, 120)
SUBSTEPS = (1, 2, 4, 8, 16)
REF = (120, 16)
RATE_TOL = 0.02


def smoothstep(a):
    a = np.clip(a, 0.0, 1.0)
    return a * a * (3.0 - 2.0 * a)


def flex_angle(t) -> np.ndarray:
    """Elbow angle, degrees, at times t (s): 0 -> 120 deg over 0.2 s from 0.1 s (a smoothstep, peak
    angular speed 900 deg/s), held 0.5 s, then back over 0.2 s, then held to the clip's end (1.5 s)."""
    t = np.asarray(t, dtype=np.float64)
    return FLEX_DEG * (smoothstep((t - 0.1) / FLEX_S) - smoothstep((t - 0.1 - FLEX_S - HOLD_S) / FLEX_S))


def frames(fps: float, duration: float) -> np.ndarray:
    """(T,) output times k / fps from 0 through `duration` (seconds)."""
    return np.arange(int(np.floor(duration * fps + 1e-9)) + 1) / fps


@pytest.fixture(scope="module")
def arm_bakes():
    """{(fps, substeps): JiggleResult} of the simple arm's flex at every rate and substep count."""
    arm = simple_arm()
    jiggles = default_jiggles(arm.rig)
    world_at = lambda t: arm_world(flex_angle(t))   # noqa: E731
    return {(fps, sub): jiggle_rig(arm.rig, jiggles, world_at, frames(fps, CLIP_S), JiggleSettings(substeps=sub))
            for fps in RATES for sub in SUBSTEPS}


def test_arm_flex_is_independent_of_frame_rate_and_substeps(arm_bakes):
    """Every CV of every bake at each of its frames (all of them are frames of the 120 fps reference,
    a superset of the times common to all rates) within 2% of the peak amplitude max |dynamic - static|
    of the 120 fps x 16 substeps reference.

    Why 2% holds: the goal path is the same at every rate
    (knots at 120 Hz, sim/jiggle/secondary.py), and the goal springs' flow is exact for any step (without
    neighbour springs the bakes agree to 1e-5 of the peak, float32 rounding). What is left is the
    splitting error of the neighbour springs, first order in the step h because their damping is
    kicked explicitly: steps never exceed min(1/120 s, the solver's max_step 0.005 s here), and the
    coarsest bakes (h = 1/240 s) measure 1.4% of the peak against the h = 1/1920 s reference. The 2%
    is the issue's target; the margin over 1.4% is what that first-order error leaves."""
    ref = arm_bakes[REF]
    peak = np.linalg.norm(ref.dynamic - ref.static, axis=2).max()
    assert peak > 1e-3        # the flex jiggles the biceps by millimetres: the measure means something
    worst = {}
    for (fps, sub), r in arm_bakes.items():
        k = np.round(r.times * REF[0]).astype(int)
        assert np.allclose(ref.times[k], r.times, atol=1e-12)
        assert np.abs(r.static - ref.static[k]).max() < 1e-9     # same goals: the rate only changes steps
        worst[fps, sub] = np.linalg.norm(r.dynamic - ref.dynamic[k], axis=2).max() / peak
    print(f"\npeak {peak * 1e3:.2f} mm; worst |dynamic - ref| / peak per (fps, substeps): "
          + ", ".join(f"{k[0]}x{k[1]} {v:.2%}" for k, v in worst.items()))
    assert max(worst.values()) < RATE_TOL, worst


# ---------------------------------------------------------------------------------- shared clips
BOUND_M = 1.5
"""metres: no particle may stray farther than this from its goal on the shared clips at jiggle 1 and
goal weight 0.1. Measured worst (full clips at 30 fps, 4 substeps, bodies of 8000 vertices): 0.72 m, the
belly fat on 02_04 (the love handles reach 6.3 of their rest lengths, 0.67 m). At goal weight 0.1 the
fat is a 0.93 Hz oscillator with damping ratio 0.2 that the motion drives: a large swing, but the
physics of soft goals, not the integrator's (16 substeps give the same 0.719 m, and without neighbour
springs, where every step is the exact solution, it is 0.74 m). The bound keeps a 2x margin over it;
an unstable integration grows exponentially and passes it within frames, and a missed cut (test
below) leaves particles about the jump's length off."""
STRESS = {"goal": 0.1, "strength": 1.0}
CLIPS = [f"mocap/cmu_bvh/{n}.bvh" for n in CMU_BVH] + ["mocap/cmu_amc/01_01.amc"]
FPS = 30
BODY_VERTICES = 8000      # a coarse body: the muscles' fit needs no more, and it builds in ~1 s


@pytest.fixture(scope="module")
def musculatures():
    """musculature(clip) -> (Musculature, stress jiggles): one generated body and fit per distinct
    skeleton (joint names and rest offsets to the millimetre; 02_03 and 02_04 share one), cached."""
    from jiggle.rig.character.body import BodyOptions
    from jiggle.rig.character.load import body_character
    from jiggle.rig.muscle.fit import fit_musculature
    cache = {}

    def musculature(clip):
        key = (clip.joint_names, np.round(clip.offsets, 3).tobytes())
        if key not in cache:
            mus = fit_musculature(body_character(clip, BodyOptions(resolution=BODY_VERTICES)), "human")
            jiggles = default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles])
            cache[key] = mus, [override(j, STRESS) for j in jiggles]
        return cache[key]

    return musculature


def clip_world(clip):
    """world_at(times) -> (K, J, 4, 4) of `clip` (joints in the clip's order, as its body's)."""
    from jiggle.rig.motion.clip import transforms
    return lambda t: transforms(*clip.world(*clip.sample(t)))


def offsets(r) -> np.ndarray:
    """(T, N) metres: each particle's distance from its goal."""
    return np.linalg.norm(r.dynamic - r.static, axis=2)


@pytest.mark.slow
@pytest.mark.parametrize("rel", CLIPS, ids=[p.split("/")[-1] for p in CLIPS])
def test_shared_clip_stays_bounded_at_soft_goals(musculatures, rel):
    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip(asset(rel))
    mus, jiggles = musculatures(clip)
    times = frames(FPS, clip.duration)
    r = jiggle_rig(mus.rig, jiggles, clip_world(clip), times, JiggleSettings())   # NaN would raise here
    assert np.isfinite(r.dynamic).all()
    assert r.cuts.size == 0, f"continuous mocap cut at {r.cuts} s"
    d = offsets(r)
    per_muscle = d.reshape(len(times), mus.rig.M, -1).max(axis=(0, 2))
    m = int(np.argmax(per_muscle))
    rel_len = per_muscle / mus.rig.rest_length
    m_len = int(np.argmax(rel_len))
    print(f"\n{rel}: {clip.duration:.1f} s, worst offset {per_muscle[m]:.3f} m ({r.names[m]}, "
          f"{rel_len[m]:.2f} rest lengths); most in rest lengths {rel_len[m_len]:.2f} ({r.names[m_len]}); "
          f"bound {BOUND_M} m")
    assert per_muscle.max() < BOUND_M, (r.names[m], per_muscle[m])


# ---------------------------------------------------------------------------------- cuts
CUT_CLIP = "mocap/cmu_bvh/09_11.bvh"
T_CUT = 0.6     # s: a frame at 30 fps and a goal knot at 120 Hz, so the cut interval ends on a frame


def spliced(world_at, jump: float):
    """world_at with every joint moved `jump` metres along +X from T_CUT on (a teleport of the root)."""
    def at(t):
        w = np.array(world_at(t))
        w[np.asarray(t) >= T_CUT, :, 0, 3] += jump
        return w
    return at


@pytest.fixture(scope="module")
def cut_scene(musculatures):
    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip(asset(CUT_CLIP))
    mus, jiggles = musculatures(clip)
    return mus, jiggles, clip_world(clip), frames(FPS, clip.duration)


@pytest.mark.parametrize("jump", [0.5, 5.0])
def test_spliced_teleport_resets_the_particles_to_their_goals(cut_scene, jump):
    """A root jump of 0.5 m or 5 m within one 1/120 s knot interval (the clip moves < 5 cm per
    interval there): one cut, ending at the frame T_CUT; from that frame on the bake equals a fresh
    start of the spliced clip at T_CUT (a reset is a restart: the particles at the quasi-static offset
    of their goals' motion there, whatever they did before; float32 rounding of positions ~5 m: < 1e-5
    m), an offset far below the jump; before it, the bake of the clip without the splice (frames up to
    two knots before the cut see the same goals)."""
    mus, jiggles, world_at, times = cut_scene
    r = jiggle_rig(mus.rig, jiggles, spliced(world_at, jump), times, JiggleSettings())
    assert r.cuts.size == 1 and abs(r.cuts[0] - T_CUT) <= 1.0 / 120 + 1e-9, r.cuts
    k = int(np.flatnonzero(np.isclose(times, T_CUT))[0])
    at_cut = offsets(r)[k].max()
    assert at_cut < 0.2 * min(jump, 1.0), at_cut

    fresh = jiggle_rig(mus.rig, jiggles, spliced(world_at, jump), times[k:], JiggleSettings())
    after = np.abs(r.dynamic[k:] - fresh.dynamic).max()
    assert after < 1e-5, after

    clean = jiggle_rig(mus.rig, jiggles, world_at, times, JiggleSettings())
    early = times <= T_CUT - 2.0 / 120 + 1e-9
    assert np.abs(r.dynamic[early] - clean.dynamic[early]).max() < 1e-9
    assert offsets(r).max() < BOUND_M
    print(f"\njump {jump} m: cut at {r.cuts[0]:.4f} s, offset at the frame after it {at_cut:.1e} m, "
          f"vs a fresh start {after:.1e} m, worst offset {offsets(r).max():.3f} m")


def test_without_cut_detection_the_teleport_flings_the_particles(cut_scene):
    """The same 5 m splice with cut detection off (cuts all False) and no reach (max_offset inf): the
    goals sweep 5 m in 1/120 s on the C1 curve and the particles, held by soft springs, are left metres
    behind, far beyond BOUND_M: the two tests above can fail. With their default reach the tissue law
    stiffens them, but a goal sweeping at 600 m/s flings them past BOUND_M all the same (a law of forces
    cannot stop that within centimetres, and must not remove the velocity): the cut is what saves the jump."""
    mus, jiggles, world_at, times = cut_scene
    held_by_reach = jiggles
    reach = max(j.reach for j in jiggles)
    jiggles = [replace(j, max_offset=math.inf) for j in jiggles]
    knots = knot_times(times, 120.0)
    r = jiggle_rig(mus.rig, jiggles, spliced(world_at, 5.0), times, JiggleSettings(),
                   cuts=np.zeros(len(knots) - 1, bool))
    assert np.array_equal(r.knots, knots) and r.cuts.size == 0
    k = int(np.flatnonzero(np.isclose(times, T_CUT))[0])
    d = offsets(r)
    print(f"\nno cut detection: offset at the frame after the jump {d[k].max():.2f} m, worst {d.max():.2f} m "
          f"(bound {BOUND_M} m)")
    assert d[k].max() > 2 * BOUND_M
    held = jiggle_rig(mus.rig, held_by_reach, spliced(world_at, 5.0), times, JiggleSettings(),
                      cuts=np.zeros(len(knots) - 1, bool))
    assert reach < BOUND_M < offsets(held).max() < d.max()
