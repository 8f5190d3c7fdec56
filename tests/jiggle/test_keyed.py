"""Keyable jiggle parameters (sim/jiggle/keyed.py, sim/jiggle/keyed_solver.py, sim/jiggle/keyed_kernels.py):
curves and their checks, globs, the batched matrix exponential against SciPy's, the keyed one-launch run
against its NumPy reference, and the physics of keyed muscles: a strength going to 0 glues the muscle, a
frequency curve moves the ringing's frequency, and 24 and 120 fps agree with keyed parameters."""
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.simple_arm import FLEX_HOLD, FLEX_RISE, FLEX_START, simple_arm
from jiggle.sim.jiggle.goal_flow import expm_batch, goal_flow, goal_flow_batch
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.keyed import (
    Curve,
    goal_springs,
    parse_assignment,
    parse_curve,
    parse_text,
    resolve_tables,
)
from jiggle.sim.jiggle.keyed_solver import KeyedSolver, integrate_keyed_numpy
from jiggle.sim.jiggle.params import MuscleJiggle
from jiggle.sim.jiggle.materials import default_jiggles
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.secondary import knot_times
from jiggle.sim.jiggle.simulate import goals, run, step_times
from jiggle.sim.jiggle.solver import ParticleSolver


# ------------------------------------------------------------------------------------------ curves
def test_a_number_or_equal_keys_are_the_plain_number():
    assert parse_curve(0.5, "strength") == 0.5
    assert parse_curve([[0, 0.5], [2, 0.5]], "strength") == 0.5          # a keyed constant is the number
    c = parse_curve([[0, 1], [2, 0.2]], "strength")
    assert isinstance(c, Curve) and c.interpolation == "linear"
    np.testing.assert_allclose(c([-1, 0, 1, 2, 3]), [1, 1, 0.6, 0.2, 0.2])   # linear, held outside the keys


def test_smooth_curves_stay_within_their_keys():
    c = parse_curve({"keys": [[0, 0], [1, 1], [1.1, 1], [3, 0.2]], "interpolation": "smooth"}, "strength")
    t = np.linspace(-1, 4, 2001)
    v = c(t)
    assert v.min() >= 0 and v.max() <= 1                                   # monotone cubic: no overshoot
    assert c(0.5) != pytest.approx(0.5)                                     # not the straight line
    assert parse_text("smooth:[[0,1],[2,0.2]]", "strength", "--jiggle") == \
        parse_curve({"keys": [[0, 1], [2, 0.2]], "interpolation": "smooth"}, "strength")


def test_step_curves_hold_each_key_until_the_next():
    c = parse_text("step:[[0,1],[1,0.5],[2,0.2]]", "strength", "--strength")
    assert isinstance(c, Curve) and c.interpolation == "step"
    np.testing.assert_array_equal(c([-1, 0, 0.5, 0.999, 1, 1.5, 2, 3]), [1, 1, 1, 1, 0.5, 0.5, 0.2, 0.2])
    assert c.lo == 0.2 and c.hi == 1.0
    assert parse_curve(c.to_json(), "strength") == c                       # bake.json's record reads back


@pytest.mark.parametrize("value, name, expect", [
    ([[0, 1], [0, 0.5]], "strength", "key times must increase"),
    ([[0, 1], [1, 1.5]], "strength", "strength must be in [0, 1], got 1.5 at t = 1 s (key 2)"),
    ([[0, 7], [1, 0]], "frequency", "frequency must be in (0, inf) Hz, got 0"),
    (-0.1, "damping", "damping must be in [0, inf), got -0.1"),
    ([[0, 1, 2]], "goal_scale", "expected a number"),
    ({"keys": [[0, 1], [1, 2]], "interpolation": "cubic"}, "goal_scale", "interpolation must be one of"),
    ([[0, float("nan")], [1, 1]], "blend", "NaN"),
])
def test_bad_keys_are_named(value, name, expect):
    with pytest.raises(InputError, match=expect.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        parse_curve(value, name, "jiggle.muscles.belly_fat." + name)


def test_command_line_assignments():
    assert parse_assignment("0.8", "strength", "--jiggle") == (None, 0.8)
    assert parse_assignment("belly_fat=0.8", "strength", "--jiggle") == ("belly_fat", 0.8)
    pat, c = parse_assignment("*_fat=[[0,1],[2,0.2]]", "strength", "--jiggle")
    assert pat == "*_fat" and isinstance(c, Curve) and c.values.tolist() == [1, 0.2]
    assert parse_assignment("5", "frequency", "--frequency", global_ok=False) == ("*", 5.0)
    with pytest.raises(InputError, match=r"--jiggle \*_fat=\[\[0,1\],\[2,3\]\]: strength must be in \[0, 1\]"):
        parse_assignment("*_fat=[[0,1],[2,3]]", "strength", "--jiggle")
    with pytest.raises(InputError, match="--jiggle belly_fat=x"):
        parse_assignment("belly_fat=x", "strength", "--jiggle")


# ------------------------------------------------------------------------------------------- globs
def test_globs_most_specific_wins_per_key():
    names = ["belly_fat", "glute_fat", "left_biceps", "right_biceps"]
    out = resolve_tables([("*_fat", {"damping": 0.3, "strength": 0.5}, "a"),
                          ("belly_fat", {"strength": 0.9}, "b"),
                          ("*", {"strength": 0.1, "friction": 1.0}, "c"),     # a later glob beats an earlier one
                          ("glute_*", {"damping": 0.2}, "d")], names)
    assert out["belly_fat"] == {"damping": (0.3, "a"), "strength": (0.9, "b"), "friction": (1.0, "c")}
    assert out["glute_fat"] == {"damping": (0.2, "d"), "strength": (0.1, "c"), "friction": (1.0, "c")}
    assert out["left_biceps"] == {"strength": (0.1, "c"), "friction": (1.0, "c")}


def test_unknown_names_and_empty_globs_are_errors_naming_the_entry():
    with pytest.raises(InputError, match="jiggle.muscles.tail_fat: the rig has no muscle 'tail_fat'") as e:
        resolve_tables([("tail_fat", {"damping": 0.3}, ("jiggle.muscles.tail_fat", "s.toml", 12))], ["belly_fat"])
    assert e.value.path == "s.toml" and e.value.line == 12
    with pytest.raises(InputError, match=r"--jiggle left_\*=\.\.\.: the glob 'left_\*' matches no muscle"):
        resolve_tables([("left_*", {"strength": 0.3}, "--jiggle left_*=...")], ["belly_fat"])


# --------------------------------------------------------------------------------------- the flow
def test_expm_batch_matches_scipy():
    rng = np.random.default_rng(0)
    a = rng.normal(0, 1, (50, 5, 5)) * rng.uniform(0.01, 8, (50, 1, 1))          # norms from 0.05 to ~40
    ours = expm_batch(a)
    for m in range(len(a)):
        ref = expm(a[m])
        assert np.abs(ours[m] - ref).max() <= 1e-10 * np.abs(ref).max()


def test_goal_flow_batch_matches_goal_flow():
    """The keyed flow coefficients against goal_flow's (SciPy expm per distinct pair): equal to float32 round-off."""
    rng = np.random.default_rng(1)
    k = np.concatenate([rng.uniform(1, 2e5, 300), [np.inf, 0.0]])
    c = np.concatenate([rng.uniform(0, 400, 300), [0.0, 0.0]])
    h = rng.choice([1 / 120, 1 / 96, 1 / 480, 1 / 24], len(k))
    ours = goal_flow_batch(k, c, h)
    ref = np.stack([goal_flow(k[i:i + 1], c[i:i + 1], h[i])[0] for i in range(len(k))])
    scale = np.abs(ref).max(axis=1, keepdims=True) + 1e-300
    assert np.abs(ours - ref).max() / 1 <= 1e-7 * scale.max()
    assert np.all(np.abs(ours - ref) <= 1e-7 * scale)
    assert not ours[-2].any()                                              # glued: no flow


# ------------------------------------------------------------------------------ the keyed run
def keyed_jiggle(mj: MuscleJiggle, **curves) -> MuscleJiggle:
    return replace(mj, **curves)


def reference_jiggle(mj: MuscleJiggle, kj: MuscleJiggle) -> MuscleJiggle:
    """What the model of a keyed muscle is built with (ParticleBuilder.add_muscles takes kj.reference() itself)."""
    return kj


def random_keyed(rng, n=4):
    base = [MuscleJiggle(f"m{g}", rng.uniform(2, 8), rng.uniform(0, 1), rng.uniform(0, 0.9, 40), 1000.0,
                         strength=rng.uniform(0.3, 1), spring_frequency_hz=rng.uniform(1, 8),
                         spring_damping_ratio=rng.uniform(0, 0.5), friction=rng.uniform(0, 2),
                         max_offset=0.01 if g % 2 else math.inf) for g in range(n)]
    curves = [dict(strength=parse_curve([[0, 1.0], [0.1, 0.2]], "strength")), {},
              dict(frequency_hz=parse_curve([[0, 3.0], [0.2, 9.0]], "frequency"),
                   goal_scale=parse_curve([[0, 1.0], [0.2, 2.0]], "goal_scale")),
              dict(damping_ratio=parse_curve({"keys": [[0, 0.1], [0.2, 1.0]], "interpolation": "smooth"}, "damping"))]
    keyed = [keyed_jiggle(b, **c) for b, c in zip(base, curves[:n])]
    return base, keyed, [reference_jiggle(b, k) for b, k in zip(base, keyed)]


def test_keyed_run_matches_its_numpy_reference():
    rng = np.random.default_rng(3)
    base, keyed, ref = random_keyed(rng)
    rest = rng.normal(0, 0.05, (160, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, rng.uniform(1e-5, 1e-4, 4), ref)
    model = b.finalize("cpu", gravity=True)
    knots = np.arange(0, 37) / 120.0
    wave = np.sin(knots[:, None, None] * np.array([7.0, 11.0, 5.0]) + rest[None])
    track = build_track(knots, rest[None] + 0.05 * wave)
    solver = KeyedSolver(model, keyed)
    assert solver.schedule.keyed_threads.tolist() == [0, 2, 3]
    grid = step_times(np.arange(10) / 30.0, track.times, 3, solver.max_step)     # uneven steps across knots
    x0, v0 = (a.astype(np.float32) for a in track.sample(0.0)[:2])
    a, out = model.state(), model.state()
    a.assign(x0, v0)
    xs = solver.integrate(a, out, track.to_device("cpu"), grid, record=np.arange(1, len(grid)))
    assert solver.launches == 1
    x, v = out.numpy()
    xr, vr = integrate_keyed_numpy(model, solver.schedule, track, x0.astype(np.float64), v0.astype(np.float64), grid)
    amp = np.abs(xr - track.sample(grid[-1])[0]).max()
    assert amp > 1e-3
    assert np.abs(x - xr).max() < 1e-5 * amp and np.array_equal(xs[-1], x)
    assert np.abs(v - vr).max() < 1e-5 * np.abs(vr).max()


def test_a_model_without_curves_runs_the_plain_solver_bit_for_bit():
    rng = np.random.default_rng(4)
    base, _, _ = random_keyed(rng)
    rest = rng.normal(0, 0.05, (160, 3))
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(4, 5e-5), base)
    model = b.finalize("cpu")
    knots = np.arange(0, 25) / 120.0
    track = build_track(knots, rest[None] + 0.03 * np.sin(9 * knots[:, None, None] + rest[None]))
    grid = step_times(np.arange(6) / 30.0, track.times, 4, 1.0)
    outs = []
    for solver in (ParticleSolver(model), KeyedSolver(model, [keyed_jiggle(j) for j in base])):
        a, o = model.state(), model.state()
        a.assign(*track.sample(0.0)[:2])
        outs.append(solver.integrate(a, o, track.to_device("cpu"), grid, record=np.arange(1, len(grid))))
    assert np.array_equal(*outs)


def test_goal_springs_at_plain_values_are_the_models():
    """goal_springs with numbers: MuscleJiggle.goal_stiffness and add_muscles' damping and reach, bit for bit."""
    mj = default_jiggles(simple_arm().rig)[0]
    mj = replace(mj, strength=0.7)
    k, c, reach = goal_springs(mj.goal, mj.strength, mj.frequency_hz, mj.damping_ratio, 1.0, mj.max_offset,
                               np.array([0.0, 1.0]))
    b = ParticleBuilder()
    b.add_muscles(simple_arm().rig.rest_cvs, simple_arm().rig.rest_volume, [mj])
    m = b.finalize()
    assert np.array_equal(k[1], m.goal_k) and np.array_equal(c[1], m.goal_c) and np.array_equal(reach[1], m.reach)


# ------------------------------------------------------------------------------------- the physics
@pytest.fixture(scope="module")
def arm():
    return simple_arm()


def arm_run(arm, fps=120.0, substeps=4, base=None, **curves):
    """The simple arm's fast flex with the biceps' parameters keyed: (times (T,), offsets (T, 40, 3) metres of
    the dynamic CVs from the static ones)."""
    from jiggle.rig.muscle.simple_arm import FLEX_DURATION, flex_world
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.particles import muscle_model
    mj = base or default_jiggles(arm.rig)[0]
    kj = keyed_jiggle(mj, **curves)
    model = muscle_model(arm.rig, [reference_jiggle(mj, kj)])
    solver = KeyedSolver(model, [kj])
    times = np.arange(int(round(FLEX_DURATION * fps)) + 1) / fps
    knots = knot_times(times, 120.0)
    static = arm.rig.static(flex_world(knots)).cvs
    track = goals(arm.rig, knots, static, JiggleSettings())
    dyn = run(model, track, times, substeps, 0.0, solver)
    return times, dyn - static[np.searchsorted(knots, times - 1e-9)]


def test_a_strength_going_to_zero_glues_the_muscle_after_its_key(arm):
    t, y = arm_run(arm, strength=parse_curve([[0, 1], [0.4, 1], [0.5, 0]], "strength"))
    _, y_plain = arm_run(arm)
    amp, plain = np.linalg.norm(y, axis=2).max(axis=1), np.linalg.norm(y_plain, axis=2).max(axis=1)
    before, after = t < 0.4, t >= 0.5 + 1 / 120
    np.testing.assert_array_equal(amp[before], plain[before])       # the same muscle until the key moves
    assert plain[after].max() > 5e-3                                 # the return stroke would swing mm
    assert amp[after].max() < 1e-6                                   # glued: on the static shape (float32)
    # in between the reach (J max_offset) shrinks with J and holds the offsets within it
    mj = default_jiggles(arm.rig)[0]
    mid = (t > 0.4) & (t < 0.5)
    J = np.interp(t[mid] - 1 / 240, [0.4, 0.5], [1, 0])             # the interval's J (its midpoint)
    assert np.all(amp[mid] <= (J + 1 / 120 / 0.1) * mj.max_offset + 1e-6)


def dominant_hz(t, y):
    """The peak of the spectrum (Hz) of offsets y (T, 40, 3) over times t: the largest CV's offset
    projected on its main direction, Hann window, zero-padded to 0.05 Hz."""
    i = np.argmax(np.linalg.norm(y, axis=2).max(axis=0))
    s = y[:, i] - y[:, i].mean(axis=0)
    s = s @ np.linalg.svd(s, full_matrices=False)[2][0]
    dt = t[1] - t[0]
    n = int(round(1 / (0.05 * dt)))
    spec = np.abs(np.fft.rfft(s * np.hanning(len(s)), n))
    return np.fft.rfftfreq(n, dt)[np.argmax(spec[1:]) + 1]


def test_a_frequency_curve_moves_the_ringing_frequency(arm):
    """f keyed 4 Hz -> 10 Hz between the two stops: each stop rings as a plain 4 Hz or 10 Hz muscle does (no
    reach: the tissue law's stiffening would make the ringing frequency depend on the swing, which the 4 Hz
    stretch makes larger in the keyed run than in the plain 10 Hz one)."""
    base = replace(default_jiggles(arm.rig)[0], damping_ratio=0.1, max_offset=math.inf)
    stop1 = (FLEX_START + FLEX_RISE, FLEX_START + FLEX_RISE + FLEX_HOLD)
    stop2 = (stop1[1] + FLEX_RISE, stop1[1] + FLEX_RISE + FLEX_HOLD)
    t, y = arm_run(arm, base=base, frequency_hz=parse_curve([[0, 4], [0.6, 4], [0.7, 10]], "frequency"))
    hz = {}
    for f in (4, 10):
        tp, yp = arm_run(arm, base=replace(base, frequency_hz=float(f)))
        hz[f] = [dominant_hz(tp[(tp >= a) & (tp < b)], yp[(tp >= a) & (tp < b)]) for a, b in (stop1, stop2)]
    keyed = [dominant_hz(t[(t >= a) & (t < b)], y[(t >= a) & (t < b)]) for a, b in (stop1, stop2)]
    assert keyed[0] == pytest.approx(hz[4][0], rel=0.05)
    assert keyed[1] == pytest.approx(hz[10][1], rel=0.05)
    assert keyed[1] / keyed[0] > 2.0           # 10 / 4 Hz, less what the goal weights and springs add


def test_keyed_parameters_agree_at_24_and_120_fps(arm):
    """The parameters are held per goal knot interval (120 Hz whatever the output rate): 24 fps with 2
    substeps and 120 fps with 4 agree within 2% of the peak jiggle."""
    curves = dict(strength=parse_curve([[0, 1], [0.9, 0.4]], "strength"),
                  frequency_hz=parse_curve({"keys": [[0, 5], [1.0, 9]], "interpolation": "smooth"}, "frequency"),
                  damping_ratio=parse_curve([[0, 0.2], [1.2, 0.6]], "damping"),
                  goal_scale=parse_curve([[0, 1.2], [1.5, 0.8]], "goal_scale"))
    t120, y120 = arm_run(arm, 120.0, 4, **curves)
    t24, y24 = arm_run(arm, 24.0, 2, **curves)
    np.testing.assert_allclose(t24, t120[::5], atol=1e-12)
    peak = np.linalg.norm(y120, axis=2).max()
    assert peak > 3e-3
    assert np.linalg.norm(y24 - y120[::5], axis=2).max() <= 0.02 * peak


# ------------------------------------------------------------------------------------ with collisions
def test_keyed_run_with_contacts_matches_the_numpy_reference():
    """Keyed muscles collide (sim/jiggle/keyed_kernels.py: integrate_run_contact_keyed): curves constant over
    the run (so the reference model's flow is theirs) through 3 capsules and above a floor, against
    integrate_contact_numpy within float32 round-off; and where nothing touches, the keyed run with colliders
    writes the keyed run's positions bit for bit."""
    from jiggle.rig.character.capsules import BoneCapsules
    from jiggle.sim.jiggle.colliders import ColliderModel, integrate_contact_numpy
    rng = np.random.default_rng(3)
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * 0.03, np.zeros(8), np.sin(a) * 0.03], axis=1)

    def pad(centre):
        return np.concatenate([ring + [0.0, y, 0.0] for y in np.linspace(-0.06, 0.06, 5)]) + centre

    def caps_of(ends, radius):
        ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 3)
        return BoneCapsules(joint=np.zeros(len(ends)), child=np.full(len(ends), -1), local=ends,
                            radius=np.asarray(radius, dtype=np.float64), names=[f"c{c}" for c in range(len(ends))],
                            parents=np.array([-1]))
    jig = MuscleJiggle(name="m", frequency_hz=3.0, damping_ratio=0.3, goal=np.full(40, 0.3), density=1000.0,
                       spring_frequency_hz=5.0, spring_damping_ratio=0.2, max_offset=0.05)
    later = parse_curve([[0, 1.0], [5, 1.0], [6, 0.5]], "strength")       # 1 throughout the run, a curve still
    keyed = [replace(jig, strength=later), replace(jig, name="n", frequency_hz=parse_curve([[0, 3], [5, 3], [6, 9]],
                                                                                            "frequency"))]
    rest = np.concatenate([pad([0.0, 0.0, 0.05]), pad([0.0, 0.3, 0.05])])
    b = ParticleBuilder()
    b.add_muscles(rest, np.array([3e-4, 3e-4]), keyed)
    model = b.finalize("cpu", gravity=True)
    ends = rng.normal(scale=0.05, size=(3, 2, 3)) + np.array([0.0, 0.15, 0.03])
    pairs = np.array([[True, True, False], [True, False, True]])
    cm = ColliderModel.from_pairs(caps_of(ends, [0.03, 0.04, 0.02]), pairs, floor=0.0)
    knots = np.linspace(0, 0.1, 5)
    track = build_track(knots, rest[None] + np.cumsum(rng.normal(scale=0.02, size=(5, 1, 3)), axis=0),
                        cuts=np.zeros(4, bool))
    col = cm.on_track(knots, ends.reshape(1, 6, 3) + np.cumsum(rng.normal(scale=0.01, size=(5, 1, 3)), axis=0))
    x0 = (rest + rng.normal(scale=0.01, size=rest.shape)).astype(np.float32)
    v0 = rng.normal(scale=0.5, size=rest.shape).astype(np.float32)
    solver = KeyedSolver(model, keyed)
    state, out = model.state(), model.state()
    state.assign(x0, v0)
    grid = np.linspace(0, 0.1, 9)
    solver.integrate(state, out, track.to_device(), grid, record=[8], colliders=col)
    xr, vr, deep = integrate_contact_numpy(model, cm, lambda h: ParticleSolver(model).flow(h)[0], track,
                                           col.control.track, x0.astype(np.float64), v0.astype(np.float64), grid)
    assert deep.max() > 0.001
    x, v = out.numpy()
    np.testing.assert_allclose(x, xr, atol=2e-5)
    np.testing.assert_allclose(v, vr, atol=2e-3)
    far = ColliderModel.from_pairs(caps_of([[[5.0, 5.0, 5.0], [6.0, 5.0, 5.0]]], [0.05]), np.array([[True], [True]]),
                                   floor=-10.0)
    far_col = far.on_track(knots, np.repeat(far.capsules.local.reshape(1, -1, 3), len(knots), axis=0))
    outs = []
    for c in (None, far_col):
        state.assign(x0, v0)
        outs.append(solver.integrate(state, out, track.to_device(), grid, record=np.arange(1, 9), colliders=c))
    np.testing.assert_array_equal(*outs)
