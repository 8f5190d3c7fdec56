"""Collisions of the particles with bone capsules and the floor (sim/jiggle/colliders.py,
sim/jiggle/contact_kernels.py): synthetic scenes with the physics each one expects, the kernels
against their NumPy references, bit-exactness (no contact: a run without colliders; chunked: an
unbroken run) and frame-rate independence with contacts."""
import math

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.capsules import BoneCapsules, segment_distance
from jiggle.sim.jiggle.colliders import (
    ColliderModel,
    contact_numpy,
    integrate_contact_numpy,
    muscle_contacts,
    skin_inside_numpy,
)
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run
from jiggle.sim.jiggle.solver import ParticleSolver


def capsules(ends, radius):
    """Capsules riding joint 0 of a one-joint skeleton at the identity: ends (C, 2, 3) world metres."""
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 3)
    return BoneCapsules(joint=np.zeros(len(ends)), child=np.full(len(ends), -1), local=ends,
                        radius=np.asarray(radius, dtype=np.float64).reshape(-1), names=[f"cap{c}" for c in range(len(ends))],
                        parents=np.array([-1]))


def still(model_caps: ColliderModel, times):
    """The capsules standing still over knots `times`."""
    ends = model_caps.capsules.local.reshape(1, -1, 3)
    return model_caps.on_track(times, np.repeat(ends, len(times), axis=0))


# ------------------------------------------------------------------------------------ the floor
def test_a_particle_dropped_on_the_floor_rests_on_it():
    """A free particle (no goal spring) falling at 5 m/s onto z = 0, gravity on, 24 fps, 1 substep: a
    step carries it 21 cm, twice its height above the floor; the projection stops it on the floor
    (no tunnelling, however long the step: the floor is a half-space) and it then rests there,
    z = 0 exactly, its downward velocity dropped (inelastic)."""
    b = ParticleBuilder()
    b.begin_group("drop")
    b.add_particle([0.0, 0.0, 1.0], 1.0, goal_stiffness=0.0)
    model = b.finalize("cpu", gravity=True)
    cm = ColliderModel.from_pairs(capsules(np.zeros((0, 2, 3)), []), np.zeros((1, 0), bool), floor=0.0)
    times = np.arange(49) / 24.0
    track = build_track(times, np.ones((len(times), 1, 3)), cuts=np.zeros(len(times) - 1, bool))
    sink = {}
    x = run(model, track, times, substeps=1, colliders=still(cm, times), contacts=sink,
            start=(np.array([[0.0, 0.0, 0.1]], np.float32), np.array([[0.0, 0.0, -5.0]], np.float32)))
    assert x[:, 0, 2].min() >= 0.0                        # never below the floor, at any frame
    np.testing.assert_array_equal(x[2:, 0, 2], 0.0)       # landed in the first step, then rests on it
    rec = sink["records"]
    assert rec[1, 0, 2] == 0.0                            # hit id 0: the floor (no capsules)
    # depth before correction: 0.1 - 5 h - g h^2 / 2 below the floor, h = 1/24
    h = 1.0 / 24.0
    assert rec[1, 0, 0] == pytest.approx(5.0 * h + 0.5 * 9.81 * h * h - 0.1, rel=1e-4)
    assert rec[1, 0, 1] == pytest.approx(5.0 + 9.81 * h, rel=1e-4)    # impulse m |dv|: the speed it had


# ------------------------------------------------------------------------------------ a forward bend
HIP = np.zeros(3)
BEND = math.radians(80.0)
BEND_START, BEND_END = 0.1, 0.3


def fat_pad(centre, radius=0.03, width=0.12):
    """(40, 3) CVs of a fat pad: 5 rings of 8 about the y axis (across the body) around `centre`."""
    ys = np.linspace(-0.5, 0.5, 5) * width
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * radius, np.zeros(8), np.sin(a) * radius], axis=1)
    return np.concatenate([ring + [0.0, y, 0.0] for y in ys]) + centre


def bend_angle(t):
    s = np.clip((np.asarray(t) - BEND_START) / (BEND_END - BEND_START), 0, 1)
    return BEND * s * s * (3 - 2 * s)


def rotate(points, angle):
    """points (..., 3) turned by `angle` about the y axis through HIP, the torso bending forward (+x)."""
    c, s = np.cos(angle), np.sin(angle)
    p = points - HIP
    x, z = c * p[..., 0] + s * p[..., 2], -s * p[..., 0] + c * p[..., 2]
    return np.stack([x, np.broadcast_to(p[..., 1], x.shape), z], axis=-1) + HIP


def bend_scene():
    """A belly fat pad over the hip and a chest pad higher up the torso, bending forward 80 deg in 0.2 s,
    and a thigh capsule reaching forward from the hip (the legs of a body folding at the hips) just
    under where the belly ends up: 1 cm of clearance below its bent pad."""
    belly, chest = fat_pad([0.14, 0.0, 0.10]), fat_pad([0.14, 0.0, 0.40])
    jiggle = MuscleJiggle(name="belly_fat", frequency_hz=2.5, damping_ratio=0.25, goal=section_goals(0.3, 0.15),
                          density=900.0, spring_frequency_hz=6.0, spring_damping_ratio=0.3)
    b = ParticleBuilder()
    b.add_muscles(np.concatenate([belly, chest]), np.array([4e-4, 4e-4]),
                  [jiggle, MuscleJiggle(**{**jiggle.__dict__, "name": "chest_fat"})])
    model = b.finalize("cpu")
    bent = rotate(belly, BEND)
    r = 0.06
    # the thigh runs along the bent belly's underside, 1 cm below its lowest CV
    low = bent[:, 2].min()
    thigh = np.array([[0.0, 0.0, low - 0.01 - r], [0.3, 0.0, low - 0.01 - r]])
    caps = capsules(thigh[None], [r])
    cm = ColliderModel.from_pairs(caps, np.array([[True], [True]]), muscle_names=["belly_fat", "chest_fat"])
    knots = np.arange(0, 1.2 + 1e-9, 1 / 120)
    rest = np.concatenate([belly, chest])
    goals = rotate(rest[None], bend_angle(knots)[:, None])
    track = build_track(knots, goals, cuts=np.zeros(len(knots) - 1, bool))
    return model, cm, track, caps


def penetration(x, caps):
    """(T, N) metres each particle is inside the capsule (0 outside)."""
    a, b = caps.local[0]
    d, _ = segment_distance(x.reshape(-1, 3), a, b)
    return np.maximum(caps.radius[0] - d, 0.0).reshape(x.shape[:2])


def test_belly_fat_stays_out_of_the_thigh_in_a_fast_forward_bend():
    """Bending 80 deg in 0.2 s, the belly pad (2.5 Hz, goal weights 0.15-0.3) overshoots its goal by
    several cm when the bend stops: without collisions it swings into the thigh capsule, 1 cm below
    its bent goal; with them no particle ends a frame inside it (beyond 0.1 mm, float32 round-off
    on a projection), the pad rests on the thigh, and the chest pad, which touches nothing, jiggles as
    before (amplitude within 10%, here to the bit)."""
    model, cm, track, caps = bend_scene()
    times = np.arange(0, 1.2 + 1e-9, 1 / 60)
    free = run(model, track, times, substeps=4)
    sink = {}
    held = run(model, track, times, substeps=4, colliders=still(cm, track.times), contacts=sink)
    belly = slice(0, 40)
    assert penetration(free[:, belly], caps).max() > 0.01            # 1 cm and more into the thigh
    assert penetration(held[:, belly], caps).max() < 1e-4
    goal = np.stack([track.sample(t)[0] for t in times])
    amp = lambda x, s: np.linalg.norm(x[:, s] - goal[:, s], axis=2).max()    # noqa: E731
    chest = slice(40, 80)
    assert amp(held, chest) == pytest.approx(amp(free, chest), rel=0.10)
    per = muscle_contacts(sink["records"], model.group_offsets)
    assert per["depth"][:, 0].max() > 0.001 and (per["hit"][:, 0] == 0).any()     # the belly hit capsule 0
    assert per["depth"][:, 1].max() == 0.0 and (per["hit"][:, 1] == -1).all()
    # the pad's far side (the top ring, away from the thigh) jiggles about as before
    top = slice(0, 40)
    assert amp(held, top) <= amp(free, top) * 1.10


def test_contacts_agree_at_24_and_120_fps():
    """The same bend with collisions at 24 and 120 fps: the steps differ (1/96 s and the 120 Hz knots
    against 1/480 s), the projections happen at other times, and the positions at the shared frames
    agree within 2% of the peak jiggle."""
    model, cm, track, caps = bend_scene()
    t24 = np.arange(0, 1.2 + 1e-9, 1 / 24)
    t120 = np.arange(0, 1.2 + 1e-9, 1 / 120)
    x24 = run(model, track, t24, substeps=4, colliders=still(cm, track.times))
    x120 = run(model, track, t120, substeps=4, colliders=still(cm, track.times))[::5]
    goal = np.stack([track.sample(t)[0] for t in t24])
    peak = np.linalg.norm(x120 - goal, axis=2).max()
    assert np.linalg.norm(x24 - x120, axis=2).max() <= 0.02 * peak


def test_chunked_run_with_contacts_repeats_bit_for_bit():
    """A bake's chunks go on from the state the chunk before stored: run in two parts, the second from the
    first's end state, the same positions come out bit for bit every time (fresh solvers; the contact
    records start afresh with every run), and they stay within 0.1 mm of an unbroken run (which merges
    the kicks at the seam, sim/jiggle/solver.py)."""
    model, cm, track, caps = bend_scene()
    times = np.arange(0, 1.2 + 1e-9, 1 / 30)
    col = still(cm, track.times)
    whole = run(model, track, times, substeps=4, colliders=col)

    def chunked():
        a, state = run(model, track, times[:13], substeps=4, colliders=col, return_state=True)
        b = run(model, track, times[12:], substeps=4, colliders=col, start=state)
        return np.concatenate([a, b[1:]])
    first = chunked()
    np.testing.assert_array_equal(chunked(), first)
    assert np.abs(first - whole).max() < 1e-4


def test_no_contact_is_a_run_without_colliders_bit_for_bit():
    """Colliders that nothing touches (a capsule far away, a floor far below) change nothing: the contact
    pass writes the same float32 positions the plain run writes."""
    model, cm, track, caps = bend_scene()
    far = ColliderModel.from_pairs(capsules([[[5.0, 5.0, 5.0], [6.0, 5.0, 5.0]]], [0.05]),
                                   np.array([[True], [True]]), floor=-10.0)
    times = np.arange(0, 1.2 + 1e-9, 1 / 30)
    plain = run(model, track, times, substeps=4)
    np.testing.assert_array_equal(run(model, track, times, substeps=4, colliders=still(far, track.times)), plain)


# ------------------------------------------------------------------------------------ references
def test_contact_kernel_run_equals_the_numpy_reference():
    """Small random model (2 muscles of 40 particles, springs, random goals moving through 3 capsules and
    above a floor), 6 steps: the one-launch kernel against integrate_contact_numpy (float64, no broad
    phase) within float32 round-off."""
    rng = np.random.default_rng(3)
    jig = MuscleJiggle(name="m", frequency_hz=3.0, damping_ratio=0.3, goal=np.full(40, 0.3), density=1000.0,
                       spring_frequency_hz=5.0, spring_damping_ratio=0.2)
    rest = np.concatenate([fat_pad([0.0, 0.0, 0.05]), fat_pad([0.0, 0.3, 0.05])])
    b = ParticleBuilder()
    b.add_muscles(rest, np.array([3e-4, 3e-4]), [jig, MuscleJiggle(**{**jig.__dict__, "name": "n"})])
    model = b.finalize("cpu", gravity=True)
    ends = rng.normal(scale=0.05, size=(3, 2, 3)) + np.array([0.0, 0.15, 0.03])
    caps = capsules(ends, [0.03, 0.04, 0.02])
    cm = ColliderModel.from_pairs(caps, np.array([[True, True, False], [True, False, True]]), floor=0.0)
    knots = np.linspace(0, 0.1, 5)
    shift = np.cumsum(rng.normal(scale=0.02, size=(5, 1, 3)), axis=0)
    goals = rest[None] + shift
    track = build_track(knots, goals, cuts=np.zeros(4, bool))
    cap_ends = ends.reshape(1, 6, 3) + np.cumsum(rng.normal(scale=0.01, size=(5, 1, 3)), axis=0)
    col = cm.on_track(knots, cap_ends)
    x0 = (rest + rng.normal(scale=0.01, size=rest.shape)).astype(np.float32)
    v0 = rng.normal(scale=0.5, size=rest.shape).astype(np.float32)
    solver = ParticleSolver(model)
    state, out = model.state(), model.state()
    state.assign(x0, v0)
    grid = np.linspace(0, 0.1, 9)
    solver.integrate(state, out, track.to_device(), grid, record=[8], colliders=col)
    xr, vr, deep = integrate_contact_numpy(model, cm, lambda h: solver.flow(h)[0], track, col.control.track,
                                           x0.astype(np.float64), v0.astype(np.float64), grid)
    assert deep.max() > 0.001                             # the test does test contacts
    x, v = out.numpy()
    np.testing.assert_allclose(x, xr, atol=2e-5)
    np.testing.assert_allclose(v, vr, atol=2e-3)


def test_contact_pass_reference_pushes_onto_the_surface():
    """contact_numpy on a particle inside a capsule moving into it: it ends on the surface, its inward
    velocity dropped and its sliding slowed by friction mu x the normal change (Coulomb)."""
    cm = ColliderModel.from_pairs(capsules([[[0, 0, 0], [1, 0, 0]]], [0.1]), np.array([[True]]), friction=0.5)
    x = np.array([[0.5, 0.0, 0.08]])
    v = np.array([[1.0, 0.0, -2.0]])
    xs, vs, d = contact_numpy(cm, np.array([0, 1]), np.array([False]), x, v, cm.capsules.local, np.zeros((1, 2, 3)))
    np.testing.assert_allclose(xs, [[0.5, 0.0, 0.1]])
    np.testing.assert_allclose(vs, [[0.0, 0.0, 0.0]], atol=1e-12)      # 1 m/s sliding, 0.5 x 2 m/s friction
    assert d[0] == pytest.approx(0.02)


def test_skin_inside_kernel_equals_numpy():
    """The skin check's kernel against its NumPy reference on random vertices and capsules."""
    from jiggle.sim.jiggle.colliders import SkinCheck
    rng = np.random.default_rng(5)
    ends = rng.normal(scale=0.2, size=(4, 2, 3))
    caps = BoneCapsules(joint=np.zeros(4), child=np.full(4, -1), local=ends, radius=rng.uniform(0.05, 0.15, 4),
                        names=list("abcd"), parents=np.array([-1]))
    part = rng.integers(0, 2, 500)
    offsets, flat = np.array([0, 2, 4]), np.array([0, 3, 1, 2])
    check = SkinCheck(caps, part, offsets, flat)
    world = np.repeat(np.eye(4)[None, None], 3, axis=0)
    skin = rng.normal(scale=0.25, size=(3, 500, 3))
    got = check.inside(world, skin)
    ref = skin_inside_numpy(np.repeat(ends[None], 3, axis=0), caps.radius, skin, part, offsets, flat)
    assert ref.any() and not ref.all()
    np.testing.assert_array_equal(got, ref)


def test_bad_collider_input_is_named():
    with pytest.raises(InputError, match="friction"):
        ColliderModel.from_pairs(capsules([[[0, 0, 0], [1, 0, 0]]], [0.1]), np.array([[True]]), friction=-1.0)
    with pytest.raises(InputError, match="true or false"):
        from jiggle.sim.jiggle.params import JiggleSettings
        JiggleSettings(collisions="yes")


def test_skin_count_culls_nothing_it_should_count():
    """SkinCheck.count (clusters' reach from their centres -> candidate capsules -> per-vertex tests) equals
    the NumPy reference's count, with one cluster per part riding moving joints, without centres, and with
    vertex_clusters' small clusters, on random skins where some parts lie far from every capsule (culled)
    and some overlap them."""
    from jiggle.sim.jiggle.colliders import SkinCheck, vertex_clusters
    rng = np.random.default_rng(7)
    T, V, C = 4, 900, 5
    ends = rng.normal(scale=0.3, size=(C, 2, 3))
    caps = BoneCapsules(joint=np.zeros(C), child=np.full(C, -1), local=ends, radius=rng.uniform(0.05, 0.15, C),
                        names=list("abcde"), parents=np.array([-1, 0, 0]))
    part = rng.integers(0, 3, V)
    offsets, flat = np.array([0, 3, 5, 5]), np.array([0, 2, 4, 1, 3])     # part 2 is checked against nothing
    # joint 0 still; joints 1 and 2 move; part 1's vertices far off in the last frames (culled)
    world = np.repeat(np.eye(4)[None, None], T, axis=0).repeat(3, axis=1)
    world[:, 1, :3, 3] = np.linspace(0.0, 3.0, T)[:, None] * [1.0, 0.0, 0.0]
    world[:, 2, :3, 3] = [0.0, 0.5, 0.0]
    centre_local = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0]])
    skin = rng.normal(scale=0.3, size=(T, V, 3)) + world[:, :, :3, 3][:, part]
    ref = skin_inside_numpy(np.repeat(ends[None], T, axis=0), caps.radius, skin, part, offsets, flat).sum(axis=1)
    assert ref.min() > 0
    bind = np.repeat(np.eye(4)[None], 3, axis=0)
    clusters = vertex_clusters(part, skin[0] - world[0, :, :3, 3][part], bind, size=0.2)
    assert len(clusters[1]) > 10
    for cluster, centre in ((part, centre_local), (None, None), clusters):
        check = SkinCheck(caps, part, offsets, flat, cluster, centre)
        np.testing.assert_array_equal(check.count(world, skin), ref)
        np.testing.assert_array_equal(check.inside(world, skin).sum(axis=1), ref)


def test_broad_phase_boxes_hold_the_goal_curves():
    """group_boxes per block of knot intervals (strided reductions) against a brute-force hull: each block's
    box is the box of its groups' knot positions at both ends of every interval, grown by the largest
    |velocity| x (longest interval) / 3, and it holds the goal curves sampled densely (the Hermite cubic lies
    in the hull of its Bezier control points)."""
    from types import SimpleNamespace

    from jiggle.sim.jiggle.colliders import group_boxes
    from jiggle.sim.jiggle.goal_track import hermite
    rng = np.random.default_rng(11)
    S, N = 30, 12
    starts = np.array([0, 5, 9])
    tr = SimpleNamespace(times=np.cumsum(rng.uniform(0.01, 0.02, S)), pos=rng.normal(size=(S, N, 3)),
                         vel_start=rng.normal(size=(S - 1, N, 3)), vel_end=rng.normal(size=(S - 1, N, 3)))
    for block in (1, 3, 8):
        lo, hi = group_boxes(tr, starts, block)
        assert lo.shape == (-(-(S - 1) // block), 3, 3)
        for b in range(len(lo)):
            j0, j1 = b * block, min((b + 1) * block, S - 1)
            H = np.diff(tr.times)[j0:j1].max() / 3
            for g, (a, e) in enumerate(zip(starts, [5, 9, N])):
                speed = np.maximum(abs(tr.vel_start[j0:j1, a:e]), abs(tr.vel_end[j0:j1, a:e])).max(axis=(0, 1)) * H
                np.testing.assert_allclose(lo[b, g], tr.pos[j0:j1 + 1, a:e].min(axis=(0, 1)) - speed)
                np.testing.assert_allclose(hi[b, g], tr.pos[j0:j1 + 1, a:e].max(axis=(0, 1)) + speed)
                for j in range(j0, j1):
                    h = tr.times[j + 1] - tr.times[j]
                    for s in np.linspace(0.0, h, 7):
                        p, _, _, _ = hermite(tr.pos[j, a:e], tr.pos[j + 1, a:e], tr.vel_start[j, a:e],
                                             tr.vel_end[j, a:e], h, s)
                        assert np.all(p >= lo[b, g] - 1e-12) and np.all(p <= hi[b, g] + 1e-12)


def test_skin_keep_out_pulls_the_jiggle_back_to_the_capsule():
    """SkinCheck.keep_out: a final vertex the jiggle took into another part's capsule (its static vertex
    outside) ends on the capsule's surface along its jiggle, as the NumPy reference puts it (within float32
    and the bisection's 2^-24 of the jiggle); a vertex whose static vertex is already inside keeps its
    jiggle; a vertex outside everything is untouched bit for bit. Per frame the final count is then at most
    the static count, and both equal SkinCheck.count's."""
    from jiggle.sim.jiggle.colliders import SkinCheck, keep_out_numpy, vertex_clusters
    rng = np.random.default_rng(11)
    T, V, C = 3, 1200, 4
    ends = rng.normal(scale=0.25, size=(C, 2, 3))
    caps = BoneCapsules(joint=np.zeros(C), child=np.full(C, -1), local=ends, radius=rng.uniform(0.06, 0.14, C),
                        names=list("abcd"), parents=np.array([-1, 0]))
    part = rng.integers(0, 2, V)
    offsets, flat = np.array([0, 3, 4]), np.array([0, 1, 2, 3])
    world = np.repeat(np.eye(4)[None, None], T, axis=0).repeat(2, axis=1)
    static = rng.normal(scale=0.3, size=(T, V, 3)).astype(np.float32)
    final = (static + rng.normal(scale=0.04, size=(T, V, 3))).astype(np.float32)
    bind = np.repeat(np.eye(4)[None], 2, axis=0)
    cluster, centre = vertex_clusters(part, static[0], bind, size=0.15)
    check = SkinCheck(caps, part, offsets, flat, cluster, centre)
    E = np.repeat(ends[None], T, axis=0)
    s_in = skin_inside_numpy(E, caps.radius, static, part, offsets, flat, all_pairs=True)   # (T, V, C)
    f_in = skin_inside_numpy(E, caps.radius, final, part, offsets, flat, all_pairs=True)
    mask = np.zeros((2, C), bool)
    mask[0, [0, 1, 2]] = mask[1, 3] = True
    new = (f_in & ~s_in & mask[part][None]).any(axis=2)            # (T, V) the jiggle went in
    both = (f_in & s_in & mask[part][None]).any(axis=2) & ~new
    assert new.sum() > 20 and both.sum() > 20
    before = final.copy()
    ref = keep_out_numpy(E, caps.radius, static, final, part, offsets, flat)
    got = check.keep_out(world, static, final)
    moved = np.any(final != before, axis=2)
    np.testing.assert_array_equal(moved, new)
    np.testing.assert_allclose(final, ref, atol=2e-6)
    assert np.array_equal(final[both], before[both])
    # on the surface: the capsule the segment entered first is within ~2^-24 |jiggle| of the radius
    np.testing.assert_array_equal(got["kept"], new.sum(axis=1))
    assert np.all(got["final"] <= got["static"])
    np.testing.assert_array_equal(got["static"], check.count(world, static))
    np.testing.assert_array_equal(got["final"], check.count(world, final))
    assert got["pulled_m"].max() == pytest.approx(np.linalg.norm(before - final, axis=2).max(), rel=1e-6)
    # in float64 a pulled-back vertex is at most float32 round-off inside (the kernel tests in float32)
    deep = [caps.radius[c] - segment_distance(final[t, v].astype(np.float64)[None], *ends[c])[0][0]
            for t, v, c in zip(*np.nonzero(~s_in & mask[part][None]))]
    assert max(deep) < 1e-6


def test_the_stepwise_contact_run_equals_the_one_launch_run():
    """The GPU's way with contacts (ParticleSolver.stepwise: per step a launch over the particles and one over
    the muscles, sim/jiggle/step_kernels.py) run here on the CPU: the positions and the contact records of the
    forward bend equal the one-launch run's bit for bit."""
    from jiggle.sim.jiggle.solver import ParticleSolver
    model, cm, track, caps = bend_scene()
    times = np.arange(0, 1.2 + 1e-9, 1 / 60)
    out = []
    for stepwise in (False, True):
        solver = ParticleSolver(model)
        solver.stepwise = stepwise
        sink = {}
        x = run(model, track, times, substeps=4, solver=solver, colliders=still(cm, track.times), contacts=sink)
        out.append((x, sink["records"]))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])
    assert (out[1][1][..., 2] == 0).any()                 # the belly hit the thigh: contacts were made


def test_skin_keep_out_pulls_a_rigid_piece_back_whole():
    """SkinCheck.keep_out with the gear's Ride (rig.character.gear): a rigid piece whose jiggle (one translation)
    took a vertex into a capsule is pulled back as a whole, by that vertex's share of the jiggle, so its edges keep
    their length; a piece nothing pulled back stays bit for bit; a soft vertex is pulled back alone."""
    from types import SimpleNamespace

    from jiggle.sim.jiggle.colliders import SkinCheck, vertex_clusters
    T = 2
    caps = BoneCapsules(joint=np.zeros(1), child=np.full(1, -1), local=np.array([[[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]]),
                        radius=np.array([0.1]), names=["post"], parents=np.array([-1, 0]))
    # part 1's skin: a rigid box of 8 corners beside the post (x from 0.12 to 0.16), a far rigid box, a soft vertex
    box = np.array([[x, y, z] for x in (0.12, 0.16) for y in (-0.02, 0.02) for z in (-0.02, 0.02)])
    static = np.concatenate([box, box + [1.0, 0.0, 0.0], [[0.13, 0.1, 0.0]]])
    static = np.repeat(static[None], T, axis=0).astype(np.float32)
    final = static.copy()
    final[:, :16] -= np.float32([0.04, 0.0, 0.0])              # both boxes ride 40 mm toward the post
    final[:, 16] -= np.float32([0.0, 0.05, 0.0])               # the soft vertex into it too
    part = np.ones(17, np.int64)
    offsets, flat = np.array([0, 0, 1]), np.array([0])
    world = np.repeat(np.eye(4)[None, None], T, axis=0).repeat(2, axis=1)
    cluster, centre = vertex_clusters(part, static[0], np.repeat(np.eye(4)[None], 2, axis=0), size=2.0)
    check = SkinCheck(caps, part, offsets, flat, cluster, centre)
    ride = SimpleNamespace(rows=np.arange(16), piece=np.repeat([0, 1], 8))
    alone = final.copy()
    check.keep_out(world, static, alone)
    whole = final.copy()
    check.keep_out(world, static, whole, rigid=ride)
    assert not np.allclose(alone[:, :8] - final[:, :8], (alone - final)[:, :1])          # alone: the box bent
    move = whole[:, :8] - static[:, :8]
    np.testing.assert_allclose(move, np.repeat(move[:, :1], 8, axis=1), atol=1e-6)       # whole: one translation
    # its nearest corners (y = +-0.02) on the post's surface: x = sqrt(0.1^2 - 0.02^2)
    np.testing.assert_allclose(move[:, 0], [[np.sqrt(0.01 - 0.0004) - 0.12, 0.0, 0.0]] * T, atol=1e-5)
    assert np.array_equal(whole[:, 8:16], final[:, 8:16]) and np.array_equal(whole[:, 16], alone[:, 16])
