"""Contacts between the particles of muscles of different body parts (sim/jiggle/tissue_contacts.py,
sim/jiggle/tissue_contact_kernels.py): the kernel against its NumPy reference, two fat pads driven into
each other with the physics each test expects, bit-exactness (off: the old run; chunked: an unbroken
run), frame-rate independence and the records."""
import math
from dataclasses import replace

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.capsules import BoneCapsules
from jiggle.sim.jiggle.colliders import ColliderModel, muscle_contacts
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.keyed import parse_curve
from jiggle.sim.jiggle.keyed_solver import KeyedSolver
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run
from jiggle.sim.jiggle.solver import ParticleSolver
from jiggle.sim.jiggle.tissue_contacts import (
    NO_HIT,
    SHARE,
    TissueContactModel,
    integrate_tissue,
    ring_radii,
    tissue_contact_numpy,
    tissue_contact_pass,
)


def fat_pad(centre, radius=0.03, width=0.12):
    """(40, 3) CVs of a fat pad: 5 rings of 8 about the y axis around `centre` (as test_collisions.py)."""
    ys = np.linspace(-0.5, 0.5, 5) * width
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * radius, np.zeros(8), np.sin(a) * radius], axis=1)
    return np.concatenate([ring + [0.0, y, 0.0] for y in ys]) + np.asarray(centre)


JIGGLE = MuscleJiggle(name="A", frequency_hz=3.0, damping_ratio=0.3, goal=section_goals(0.3, 0.15), density=900.0,
                      spring_frequency_hz=6.0, spring_damping_ratio=0.3)
PRESS_START, PRESS_END, SHIFT = 0.1, 0.3, 0.07


def smooth(t):
    s = np.clip((np.asarray(t) - PRESS_START) / (PRESS_END - PRESS_START), 0, 1)
    return s * s * (3 - 2 * s)


def press_scene(bones=(0, 1), extra=False, jiggles=None):
    """Pad A at x = -8 cm and pad B at x = +8 cm (rings of 3 cm about y) slide 7 cm toward each other in
    0.2 s and stop: their goals end overlapping by 4 cm. bones : each pad's body part. extra : a third pad
    (bone 2) far away, so the model has pairs that may touch even when A and B share a bone."""
    rest = [fat_pad([-0.08, 0.0, 0.0]), fat_pad([0.08, 0.0, 0.0])]
    names = ["A", "B"]
    if extra:
        rest.append(fat_pad([0.0, 0.0, 1.0]))
        names.append("C")
        bones = tuple(bones) + (2,)
    rest = np.concatenate(rest)
    jig = jiggles or [replace(JIGGLE, name=n) for n in names]
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(len(names), 3e-4), jig)
    model = b.finalize("cpu")
    knots = np.arange(0, 1.0 + 1e-9, 1 / 120)
    move = np.zeros((len(knots), len(rest), 3))
    move[:, :40, 0] = SHIFT * smooth(knots)[:, None]
    move[:, 40:80, 0] = -SHIFT * smooth(knots)[:, None]
    track = build_track(knots, rest[None] + move, cuts=np.zeros(len(knots) - 1, bool))
    tissue = TissueContactModel.build(rest, model.group_offsets, bones, muscle_names=names)
    return model, track, tissue


def penetration(x, tissue, a=slice(0, 40), b=slice(40, 80)):
    """(T,) metres: the largest D_ij - |x_i - x_j| over pairs i of pad a, j of pad b (D_ij the contact
    distance, min(r_i + r_j, SHARE |X_i - X_j|)); <= 0 when no pair is closer than it."""
    X, r = tissue.rest, tissue.radius
    D = np.minimum(r[a][:, None] + r[b][None], tissue.share * np.linalg.norm(X[a][:, None] - X[b][None], axis=2))
    d = np.linalg.norm(x[:, a][:, :, None] - x[:, b][:, None], axis=3)
    return (D[None] - d).max(axis=(1, 2))


# ------------------------------------------------------------------------------------ the model
def test_ring_radii_cover_the_ring_and_are_capped():
    """A ring of 8 CVs of radius R has chords 2 R sin(pi / 8): each radius is half of it (the spheres of a
    ring touch), and a wide ring's are capped."""
    r = ring_radii(fat_pad([0, 0, 0], radius=0.03))
    np.testing.assert_allclose(r, 0.03 * math.sin(math.pi / 8))
    assert ring_radii(fat_pad([0, 0, 0], radius=0.3), cap=0.02).max() == 0.02


def test_mask_is_different_bones_only():
    """Muscles of one bone never touch (the mask is bone[a] != bone[b]); hit names extend the colliders'."""
    rest = np.concatenate([fat_pad([0, 0, z]) for z in (0.0, 0.2, 0.4)])
    tm = TissueContactModel.build(rest, [0, 40, 80, 120], [3, 3, 5], muscle_names=["q", "h", "c"])
    assert tm.mask.tolist() == [[False, False, True], [False, False, True], [True, True, False]]
    assert tm.hit_names(("cap0", "floor")) == ("cap0", "floor", "q", "h", "c")
    with pytest.raises(InputError):
        TissueContactModel.build(rest, [0, 40, 80, 120], [3, 3])


# ------------------------------------------------------------------------------------ the kernel
@pytest.mark.parametrize("fresh", [1, 0])
def test_kernel_equals_the_numpy_reference(fresh):
    """3 muscles of 15 particles (bones 0, 1, 1: muscle 0 touches 1 and 2, 1 and 2 never), random positions
    in a 4 cm box, radii 5-15 mm, bind positions in a 12 cm box (some pairs close: the SHARE rule), a few glued
    particles, random velocities, random capsule records and a frame's earlier record (fresh = 0): the
    kernel (hash grid, float32) against tissue_contact_numpy (every pair, float64)."""
    rng = np.random.default_rng(7)
    N = 45
    rest = rng.uniform(-0.06, 0.06, (N, 3))
    radius = rng.uniform(0.005, 0.015, N)
    tm = TissueContactModel.build(rest, [0, 15, 30, 45], [0, 1, 1], radius=radius, friction=0.4)
    x = rng.uniform(-0.02, 0.02, (N, 3)).astype(np.float32)
    v = rng.normal(scale=0.5, size=(N, 3)).astype(np.float32)
    inv_mass = rng.uniform(5.0, 50.0, N)
    inv_mass[[3, 20, 31]] = 0.0                                                 # glued
    caps = np.zeros((N, 3), np.float32)
    caps[:, 2] = NO_HIT
    hit = rng.random(N) < 0.3
    caps[hit] = np.stack([rng.uniform(0, 0.01, hit.sum()), rng.uniform(0, 0.1, hit.sum()),
                          rng.integers(0, 3, hit.sum())], axis=1)
    acc = np.zeros((N, 3), np.float32)
    acc[:, 2] = NO_HIT
    old = rng.random(N) < 0.3
    acc[old] = np.stack([rng.uniform(0, 0.01, old.sum()), rng.uniform(0, 0.1, old.sum()),
                         rng.integers(0, 6, old.sum())], axis=1)
    xo, vo, rec = tissue_contact_pass(tm, inv_mass, x, v, 4, caps=caps, acc=None if fresh else acc)
    xr, vr, rr = tissue_contact_numpy(tm, inv_mass, x, v, 4, caps=caps, acc=None if fresh else acc)
    assert (rr[:, 2] >= 4).sum() > 15                                           # the test does test contacts
    np.testing.assert_allclose(xo, xr, atol=2e-6)
    np.testing.assert_allclose(vo, vr, atol=2e-5)
    np.testing.assert_allclose(rec[:, :2], rr[:, :2], atol=2e-5)
    np.testing.assert_array_equal(rec[:, 2], rr[:, 2])


def test_reference_separates_a_pair_and_stops_it():
    """Two particles of different muscles, equal masses, 1 cm deep, approaching at 2 m/s and sliding past
    each other at 1 m/s: each moves half the depth apart (they end exactly at the contact distance), the
    approach stops (inelastic) and the sliding loses mu x the normal change on the relative velocity,
    split equally; momentum is kept."""
    tm = TissueContactModel.build(np.array([[0.0, 0, 0], [1.0, 0, 0]]), [0, 1, 2], [0, 1], radius=[0.02, 0.02],
                                  friction=0.25)
    x = np.array([[0.0, 0, 0], [0.03, 0, 0]])
    v = np.array([[1.0, 0.5, 0], [-1.0, -0.5, 0]])
    xo, vo, rec = tissue_contact_numpy(tm, np.ones(2), x, v, 1)
    np.testing.assert_allclose(xo, [[-0.005, 0, 0], [0.035, 0, 0]])
    # relative: (2, 1, 0) -> normal part gone, tangential 1 - 0.25 x 2 = 0.5 m/s; each takes half
    np.testing.assert_allclose(vo, [[0.0, 0.25, 0], [0.0, -0.25, 0]], atol=1e-12)
    np.testing.assert_allclose(vo.sum(axis=0), v.sum(axis=0), atol=1e-12)
    np.testing.assert_allclose(rec[:, 0], 0.01)
    assert rec[:, 2].tolist() == [2.0, 1.0]                                     # hit base 1 + the other muscle


# ------------------------------------------------------------------------------------ pads pressed together
def under_the_pads() -> BoneCapsules:
    """A capsule of 2 cm radius along y at x = 0, 4.5 cm below the pads' centres: the pressed pads touch it."""
    ends = np.array([[[0.0, -0.1, -0.045], [0.0, 0.1, -0.045]]])
    return BoneCapsules(joint=np.zeros(1), child=np.full(1, -1), local=ends,
                        radius=np.array([0.02]), names=["c0"], parents=np.array([-1]))


TIMES = np.arange(0, 1.0 + 1e-9, 1 / 60)


@pytest.fixture(scope="module")
def pressed():
    model, track, tissue = press_scene()
    free = run(model, track, TIMES, substeps=4)
    sink = {}
    held = run(model, track, TIMES, substeps=4, tissue=tissue, contacts=sink)
    return model, track, tissue, free, held, sink["records"]


def test_pads_of_different_bones_do_not_pass_through_each_other(pressed):
    """The goals of A and B end 4 cm into each other: without tissue contacts their particles pass through
    each other (pairs 1.5 cm and more inside their contact distance, the sum of the radii: 2.3 cm); with
    them no pair ends a frame closer than its contact distance by more than 0.5 mm (one Jacobi pass per
    step, 4+ steps per frame; the goal springs push back in between), the pads flatten against each other."""
    model, track, tissue, free, held, _ = pressed
    assert penetration(free, tissue).max() > 0.015
    assert penetration(held, tissue).max() < 5e-4
    # pressed, they stand off their goals: the contact holds them where the goals would take them through
    goal = track.sample(TIMES[-1])[0]
    assert np.linalg.norm(held[-1] - goal, axis=1).max() > 0.01


def test_records_name_the_other_muscle(pressed):
    """Per frame, A's deepest contact is with B and B's with A: hit C + 1 + the other muscle (no colliders:
    C = 0), named by TissueContactModel.hit_names; nothing is recorded before the pads meet; impulses are
    positive while they press."""
    model, track, tissue, _, _, records = pressed
    per = muscle_contacts(records, model.group_offsets)
    names = tissue.hit_names()
    touching = per["depth"][:, 0] > 0
    assert touching.any() and not touching[TIMES < PRESS_START].any()
    assert {names[h] for h in per["hit"][touching, 0]} == {"B"}
    assert {names[h] for h in per["hit"][per["depth"][:, 1] > 0, 1]} == {"A"}
    assert per["impulse"][touching, 0].max() > 0


def test_pads_of_one_bone_pass_through_each_other_untouched():
    """A and B on the same bone (C, on another, far away, so the model has pairs): no contact is recorded
    and they pass through each other as deep as without the option; the positions are those of the
    stepwise run (unmerged kicks, sim/jiggle/tissue_contacts.py) and stay within 0.5 mm of the one-launch
    run."""
    model, track, tissue = press_scene(bones=(0, 0), extra=True)
    assert tissue.any_pairs
    sink = {}
    free = run(model, track, TIMES, substeps=4)
    same = run(model, track, TIMES, substeps=4, tissue=tissue, contacts=sink)
    assert (sink["records"][..., 2] == NO_HIT).all()
    assert penetration(same, tissue).max() == pytest.approx(penetration(free, tissue).max(), abs=5e-4)
    assert np.abs(same - free).max() < 5e-4


def test_off_is_the_old_run_bit_for_bit():
    """tissue=None is the one-launch run (with capsules and floor too), and a model whose muscles all share
    a bone (no pair may touch) is too: the positions and records of a run without the option, to the bit."""
    model, track, tissue = press_scene(bones=(0, 0))
    caps = under_the_pads()
    cm = ColliderModel.from_pairs(caps, np.ones((2, 1), bool), floor=-0.04)
    col = cm.on_track(track.times, np.repeat(caps.local.reshape(1, 2, 3), len(track.times), axis=0))
    old, new, none = {}, {}, {}
    x_old = run(model, track, TIMES, substeps=4, colliders=col, contacts=old)
    x_none = run(model, track, TIMES, substeps=4, colliders=col, contacts=none, tissue=None)
    x_new = run(model, track, TIMES, substeps=4, colliders=col, contacts=new, tissue=tissue)
    assert (old["records"][..., 2] >= 0).any()                                 # the capsule is touched
    for x, rec in ((x_none, none), (x_new, new)):
        np.testing.assert_array_equal(x, x_old)
        np.testing.assert_array_equal(rec["records"], old["records"])


def test_a_run_split_at_a_step_repeats_the_unbroken_run_bit_for_bit():
    """A bake resumes from the state the chunk before stored: the press with tissue contacts, capsules and
    a floor, run in two parts (the second from the first's end state) equals the unbroken run bit for bit,
    positions and records (every step is its own launch and the contact pass reads nothing but the state).
    The pads start on their goals moving down at 0.3 m/s onto a floor 5 mm below their bottom CVs (-3 cm):
    a floor only stops the jiggle below the goals (sim/jiggle/contact_kernels.py: the allowance)."""
    model, track, tissue = press_scene()
    caps = under_the_pads()
    cm = ColliderModel.from_pairs(caps, np.ones((2, 1), bool), floor=-0.035)
    col = cm.on_track(track.times, np.repeat(caps.local.reshape(1, 2, 3), len(track.times), axis=0))
    times = np.arange(0, 0.8 + 1e-9, 1 / 30)
    x0 = track.sample(0.0)[0].astype(np.float32)
    v0 = np.zeros_like(x0)
    v0[:, 2] = -0.3
    whole_rec, a_rec, b_rec = {}, {}, {}
    whole = run(model, track, times, substeps=4, colliders=col, tissue=tissue, contacts=whole_rec, start=(x0, v0))
    a, state = run(model, track, times[:10], substeps=4, colliders=col, tissue=tissue, contacts=a_rec,
                   return_state=True, start=(x0, v0))
    b = run(model, track, times[9:], substeps=4, colliders=col, tissue=tissue, contacts=b_rec, start=state)
    np.testing.assert_array_equal(np.concatenate([a, b[1:]]), whole)
    np.testing.assert_array_equal(np.concatenate([a_rec["records"], b_rec["records"][1:]]), whole_rec["records"])
    hits = whole_rec["records"][..., 2]
    assert (hits >= 2).any() and ((hits >= 0) & (hits < 2)).any()            # tissue and capsule / floor hits


def test_tissue_contacts_agree_at_24_and_120_fps():
    """The press at 24 and 120 fps (steps of 1/96 s against 1/480 s, the contact passes at other times):
    the positions at the shared frames agree within 2% of the peak jiggle (largest distance from the goal)."""
    model, track, tissue = press_scene()
    t24 = np.arange(0, 1.0 + 1e-9, 1 / 24)
    t120 = np.arange(0, 1.0 + 1e-9, 1 / 120)
    x24 = run(model, track, t24, substeps=4, tissue=tissue)
    x120 = run(model, track, t120, substeps=4, tissue=tissue)[::5]
    goal = np.stack([track.sample(t)[0] for t in t24])
    peak = np.linalg.norm(x120 - goal, axis=2).max()
    assert peak > 0.01
    assert np.linalg.norm(x24 - x120, axis=2).max() <= 0.02 * peak


def test_keyed_solver_steps_with_tissue_contacts():
    """integrate_tissue drives a KeyedSolver (pad A's frequency keyed 3 -> 5 Hz) as it drives the plain one:
    the pads are held apart all the same, and a keyed model without curves gives the plain solver's run
    to the bit."""
    model, track, tissue = press_scene()
    keyed = [replace(JIGGLE, frequency_hz=parse_curve([[0, 3.0], [0.5, 5.0]], "frequency")),
             replace(JIGGLE, name="B")]
    km, _, _ = press_scene(jiggles=keyed)
    x = run(km, track, TIMES, substeps=4, solver=KeyedSolver(km, keyed), tissue=tissue)
    assert penetration(x, tissue).max() < 5e-4
    plain = [replace(JIGGLE, name=n) for n in "AB"]
    a = run(model, track, TIMES[:20], substeps=4, solver=KeyedSolver(model, plain), tissue=tissue)
    b = run(model, track, TIMES[:20], substeps=4, solver=ParticleSolver(model), tissue=tissue)
    np.testing.assert_array_equal(a, b)


def test_integrate_tissue_checks_its_input():
    """A tissue model of other particles, and recorded steps outside the run, are errors naming the field."""
    model, track, tissue = press_scene()
    other = TissueContactModel.build(np.concatenate([tissue.rest, tissue.rest[:40]]), [0, 40, 80, 120], [0, 1, 2])
    s, out = model.state(), model.state()
    solver = ParticleSolver(model)
    with pytest.raises(InputError):
        integrate_tissue(solver, s, out, track.to_device(), np.array([0.0, 0.01]), tissue=other)
    with pytest.raises(InputError):
        integrate_tissue(solver, s, out, track.to_device(), np.array([0.0, 0.01, 0.02]), record=[3], tissue=tissue)
    assert SHARE == 0.5


# ------------------------------------------------------------------------------------ the rest rule, a fitted rig
def test_pads_overlapping_at_bind_are_not_pushed_apart_at_rest():
    """Two pads of different bones whose rings overlap at bind (centres 4 cm apart, rings of 3 cm), held
    still: pairs closer than the sum of their radii at bind touch only at SHARE of their bind distance, so
    nothing is pushed, no contact is recorded and the particles stay on their goals; then the goals press 1
    cm further in and the overlapping pairs push (contact recorded)."""
    rest = np.concatenate([fat_pad([-0.02, 0.0, 0.0]), fat_pad([0.02, 0.0, 0.0])])
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(2, 3e-4), [replace(JIGGLE, name=n) for n in "AB"])
    model = b.finalize("cpu")
    tm = TissueContactModel.build(rest, model.group_offsets, [0, 1], muscle_names=["A", "B"])
    X, r = tm.rest, tm.radius
    assert (np.linalg.norm(X[:40, None] - X[None, 40:], axis=2) < r[:40, None] + r[None, 40:]).any()
    knots = np.arange(0, 1.0 + 1e-9, 1 / 120)
    move = np.zeros((len(knots), 80, 3))
    move[:, :40, 0] = 0.01 * np.clip((knots - 0.5) / 0.2, 0, 1)[:, None]
    track = build_track(knots, rest[None] + move, cuts=np.zeros(len(knots) - 1, bool))
    times = np.arange(0, 1.0 + 1e-9, 1 / 30)
    sink = {}
    x = run(model, track, times, substeps=4, tissue=tm, contacts=sink)
    still = times < 0.5
    assert (sink["records"][still][..., 2] == NO_HIT).all()
    np.testing.assert_allclose(x[still], np.repeat(rest[None], still.sum(), axis=0), atol=1e-7)
    assert (sink["records"][~still][..., 2] >= 1).any()


def test_a_fitted_arm_flexing():
    """The two-bone arm's biceps (fitted to the upper arm) and brachialis-like muscle (to the forearm):
    tissue_contact_model lets them touch (different bones) with the ring rule's radii; held in the bind pose
    nothing touches; flexing the elbow 110 deg in 0.15 s (jiggle_rig, tissue=True) they meet at the elbow
    and each one's records name the other."""
    from arm_muscles import ARM_BIND, arm_world, biceps, brachio

    from jiggle.rig.muscle.model import build_muscle_rig
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.materials import default_jiggles
    from jiggle.sim.jiggle.particles import muscle_model
    from jiggle.sim.jiggle.secondary import jiggle_rig
    from jiggle.sim.jiggle.tissue_contacts import RADIUS_MAX, tissue_contact_model
    rig = build_muscle_rig([biceps(), brachio(bone=1)], ARM_BIND)
    model = muscle_model(rig, default_jiggles(rig))
    tm = tissue_contact_model(rig, model)
    assert tm.mask.tolist() == [[False, True], [True, False]]
    np.testing.assert_allclose(tm.radius, ring_radii(rig.rest_cvs))
    assert 0 < tm.radius.max() <= RADIUS_MAX
    times = np.arange(0, 31) / 30.0
    sink = {}
    track = build_track(times, np.repeat(rig.rest_cvs[None], len(times), axis=0), cuts=np.zeros(len(times) - 1, bool))
    run(model, track, times, substeps=4, tissue=tm, contacts=sink)
    assert (sink["records"][..., 2] == NO_HIT).all()

    def world_at(t):
        a = np.clip((np.asarray(t) - 0.1) / 0.15, 0.0, 1.0)
        return np.stack([arm_world(110.0 * s * s * (3.0 - 2.0 * s)) for s in a])
    res = jiggle_rig(rig, default_jiggles(rig), world_at, times, JiggleSettings(substeps=4), tissue=True)
    names = tm.hit_names()
    c = res.contacts
    assert c["depth"][:, 0].max() > 0 and c["depth"][:, 1].max() > 0
    assert {names[h] for h in c["hit"][c["depth"][:, 0] > 0, 0]} == {"brachio"}
    assert {names[h] for h in c["hit"][c["depth"][:, 1] > 0, 1]} == {"biceps"}


@pytest.mark.parametrize("keyed", [False, True])
def test_a_step_plan_step_is_integrate_over_that_step(keyed):
    """ParticleSolver.step_plan (the stretch's arrays on the device once, one launch per step over views of
    them; what integrate_tissue steps with when there are colliders) equals solver.integrate over
    [grid[k], grid[k + 1]] bit for bit, step after step, positions, velocities and the step's capsule
    records, for the plain and the keyed solver."""
    from jiggle.sim.jiggle.simulate import step_times
    jig = [replace(JIGGLE, name="A", frequency_hz=parse_curve([[0, 3.0], [0.5, 5.0]], "frequency")),
           replace(JIGGLE, name="B")] if keyed else None
    model, track, tissue = press_scene(jiggles=jig)
    solver = KeyedSolver(model, jig) if keyed else ParticleSolver(model)
    cm = ColliderModel.from_pairs(under_the_pads(), np.ones((2, 1), bool), floor=-0.2)
    col = cm.on_track(track.times, np.repeat(cm.capsules.local.reshape(1, -1, 3), track.num_knots, axis=0))
    control = track.to_device()
    grid = step_times(TIMES[:40], track.times, 4, solver.max_step)
    plan = solver.step_plan(control, grid, col)
    a_in, a_out, b_in, b_out = (model.state() for _ in range(4))
    x0 = track.sample(0.0)[0]
    a_in.assign(x0, np.zeros_like(x0))
    b_in.assign(x0, np.zeros_like(x0))
    touched = 0
    for k in range(len(grid) - 1):
        plan.step(k, a_in, a_out)
        rec_a = plan.record.numpy().copy()           # on the CPU numpy() is a view the next launch rewrites
        solver.integrate(b_in, b_out, control, grid[k:k + 2], record=[1], colliders=col)
        np.testing.assert_array_equal(a_out.x.numpy(), b_out.x.numpy(), err_msg=f"step {k}")
        np.testing.assert_array_equal(a_out.v.numpy(), b_out.v.numpy(), err_msg=f"step {k}")
        np.testing.assert_array_equal(rec_a, solver.contact_records[0], err_msg=f"step {k}")
        touched += int((rec_a[:, 2] >= 0).sum())
        a_in, a_out = a_out, a_in
        b_in, b_out = b_out, b_in
    assert touched > 0
