"""Contacts remove energy, never add it (issue 44; sim/jiggle/contact_kernels.py): the rest state defines
the contact (a particle is held out of a capsule only as deep as its goal lies, so tissue the animation puts
inside a capsule is never pushed out), an inelastic stop never leaves a particle faster relative to the
capsule than it came, and the energy measured in the capsule's frame does not rise in a contact.
capsule_push (the kernel function changed for it) against its NumPy reference on random inputs."""
import numpy as np
import pytest
import warp as wp

from jiggle.rig.character.capsules import BoneCapsules, segment_distance
from jiggle.sim.jiggle import contact_kernels as ck
from jiggle.sim.jiggle.colliders import ColliderModel, axis_distance_numpy, capsule_push_numpy
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run
from jiggle.sim.jiggle.solver import ParticleSolver

FRICTION = 0.5


def capsules(ends, radius):
    """Capsules riding joint 0 of a one-joint skeleton at the identity: ends (C, 2, 3) world metres."""
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 3)
    return BoneCapsules(joint=np.zeros(len(ends)), child=np.full(len(ends), -1), local=ends,
                        radius=np.asarray(radius, dtype=np.float64).reshape(-1),
                        names=[f"cap{c}" for c in range(len(ends))], parents=np.array([-1]))


# ------------------------------------------------------------------------------------ the kernel function
@wp.kernel
def push_kernel(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), g: wp.array(dtype=wp.vec3),
                a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), va: wp.array(dtype=wp.vec3),
                vb: wp.array(dtype=wp.vec3), r: wp.array(dtype=float), friction: float,
                x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3), depth_out: wp.array(dtype=float)):
    i = wp.tid()
    xn, vn, d = ck.capsule_push(x[i], v[i], g[i], a[i], b[i], va[i], vb[i], r[i], friction)
    x_out[i] = xn
    v_out[i] = vn
    depth_out[i] = d


def test_capsule_push_equals_its_numpy_reference():
    """capsule_push (float32) against capsule_push_numpy (float64) on 600 random particles, goals and capsules:
    outside the capsule, inside it but no deeper than the goal (left alone), and deeper (pushed onto the
    surface of radius min(r, |goal - axis|)), all three represented; equal within float32 round-off."""
    rng = np.random.default_rng(44)
    n = 600
    a = rng.normal(scale=0.1, size=(n, 3))
    b = a + rng.normal(scale=0.15, size=(n, 3))
    r = rng.uniform(0.04, 0.12, n)
    t = rng.uniform(-0.2, 1.2, (n, 2))
    x = a + t[:, :1] * (b - a) + rng.normal(scale=0.07, size=(n, 3))
    g = a + t[:, 1:] * (b - a) + rng.normal(scale=0.07, size=(n, 3))
    v, va, vb = (rng.normal(size=(n, 3)) for _ in range(3))
    f32 = [np.asarray(q, np.float32) for q in (x, v, g, a, b, va, vb)]
    dev = "cpu"
    arrays = [wp.array(q, dtype=wp.vec3, device=dev) for q in f32] + [wp.array(r.astype(np.float32), dtype=float,
                                                                                  device=dev)]
    outs = [wp.zeros(n, dtype=wp.vec3, device=dev), wp.zeros(n, dtype=wp.vec3, device=dev),
            wp.zeros(n, dtype=float, device=dev)]
    wp.launch(push_kernel, dim=n, inputs=[*arrays, FRICTION], outputs=outs, device=dev)
    xk, vk, dk = (o.numpy() for o in outs)
    x, v, g, a, b, va, vb = (q.astype(np.float64) for q in f32)
    r = r.astype(np.float32).astype(np.float64)
    ref = [capsule_push_numpy(x[i], v[i], a[i], b[i], va[i], vb[i], r[i], FRICTION, g[i]) for i in range(n)]
    xr, vr, dr = (np.array([q[k] for q in ref]) for k in range(3))
    dist_x = np.array([axis_distance_numpy(x[i], a[i], b[i])[2] for i in range(n)])
    dist_g = np.array([axis_distance_numpy(g[i], a[i], b[i])[2] for i in range(n)])
    pushed = dr > 1e-5
    held_back = (dist_x < r - 1e-5) & (dist_x > dist_g + 1e-5)           # inside, but no deeper than its goal
    allowance = pushed & (dist_g < r - 1e-5)                             # pushed onto the goal's depth
    assert (dist_x > r).sum() > 50 and held_back.sum() > 20
    assert allowance.sum() > 20 and (pushed & ~allowance).sum() > 20
    assert np.all(dk[held_back] == 0.0) and np.all(xk[held_back] == f32[0][held_back])
    np.testing.assert_allclose(xk, xr, atol=2e-6)
    np.testing.assert_allclose(vk, vr, atol=1e-4)                     # float32: a normal from a short d
    np.testing.assert_allclose(dk, dr, atol=2e-6)
    # pushed onto min(r, |goal - axis|), the goal's depth where the goal is inside
    on = np.array([axis_distance_numpy(xr[i], a[i], b[i])[2] for i in range(n)])
    np.testing.assert_allclose(on[pushed], np.minimum(r, dist_g)[pushed], atol=1e-12)
    # the relative velocity never grows: |v' - w| <= |v - w|, w the axis point's velocity
    for i in np.flatnonzero(pushed):
        tt = axis_distance_numpy(x[i], a[i], b[i])[0]
        w = va[i] + tt * (vb[i] - va[i])
        assert np.linalg.norm(vk[i] - w) <= np.linalg.norm(v[i] - w) * (1 + 1e-6) + 1e-6


# ------------------------------------------------------------------------------------ the rest state
def fat_pad(centre, radius=0.03, width=0.12):
    """(40, 3) CVs of a fat pad: 5 rings of 8 about the y axis around `centre`."""
    ys = np.linspace(-0.5, 0.5, 5) * width
    ang = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(ang) * radius, np.zeros(8), np.sin(ang) * radius], axis=1)
    return np.concatenate([ring + [0.0, y, 0.0] for y in ys]) + centre


def pad_model():
    jiggle = MuscleJiggle(name="flank", frequency_hz=2.5, damping_ratio=0.25, goal=section_goals(0.3, 0.15),
                          density=900.0, spring_frequency_hz=6.0, spring_damping_ratio=0.3)
    rest = fat_pad([0.0, 0.0, 0.0])
    b = ParticleBuilder()
    b.add_muscles(rest, np.array([4e-4]), [jiggle])
    return b.finalize("cpu"), rest


@pytest.mark.parametrize("sweep", [0.0, 2.0])
def test_tissue_inside_a_capsule_at_rest_stays_where_it_is(sweep):
    """A still pad (no gravity: rest stays at rest, x = goal at every step) with a capsule of 2.5 cm radius
    lying across it (along y) through its lower half: 15 of its 40 CVs lie inside, up to 2.5 cm deep (a flank
    against a hind leg's capsule, a thin limb in a tight one). sweep 0: the capsule still, as at bind; sweep
    2 m/s: it passes through the pad's goals along x, as a leg swings under a flank. No CV is pushed: the
    positions are those of the run without colliders and no contact deeper than 1 nm is recorded (the
    allowance, each CV's goal depth, is never exceeded beyond round-off: a CV on the axis has a goal depth of
    r and moves by 1e-18 m about it). The old rule pushed each CV inside out to the surface: 2.5 cm from its
    goal, 80% of a 3 cm reach, a fling when the capsule let go."""
    model, rest = pad_model()
    r = 0.025
    knots = np.arange(0, 0.6 + 1e-9, 1 / 120)
    track = build_track(knots, np.repeat(rest[None], len(knots), axis=0), cuts=np.zeros(len(knots) - 1, bool))
    ends = np.array([[0.0, -0.2, -0.03], [0.0, 0.2, -0.03]])
    shift = np.zeros((len(knots), 1, 3))
    shift[:, 0, 0] = sweep * (knots - 0.3)                               # in the middle of the pad at 0.3 s
    cm = ColliderModel.from_pairs(capsules(ends[None], [r]), np.array([[True]]), friction=FRICTION)
    col = cm.on_track(knots, ends[None] + shift)
    d, _ = segment_distance(rest, *(ends + shift[len(knots) // 2]))
    assert (d < r).sum() == 15 and r - d.min() > 0.02                   # CVs deep inside at the start / midway
    times = np.arange(0, 0.6 + 1e-9, 1 / 60)
    sink = {}
    held = run(model, track, times, substeps=4, colliders=col, contacts=sink)
    free = run(model, track, times, substeps=4)
    np.testing.assert_allclose(held, free, rtol=0, atol=1e-9)
    np.testing.assert_allclose(held, np.repeat(rest[None], len(times), axis=0), rtol=0, atol=1e-8)
    assert sink["records"][..., 0].max() < 1e-9


# ------------------------------------------------------------------------------------ a moving capsule
def one_particle(omega: float):
    """A particle of 10 g on a goal spring omega rad/s (0: free), undamped, no reach, no gravity."""
    b = ParticleBuilder()
    b.begin_group("p")
    b.add_particle([0.0, 0.0, 0.0], 0.01, goal_stiffness=omega * omega)
    return b.finalize("cpu")


def stepped(model, goal, cap_ends, W, x0, v0, radius=0.05, duration=0.5, h=1 / 240):
    """Steps of h from (x0, v0), the particle's goal at goal + W t, a capsule of `radius` along y with ends
    cap_ends (2, 3) + W t (both translating at W, m/s): positions, velocities (K + 1, 3) and contact depths
    (K,) after each step."""
    knots = np.arange(0, duration + 1e-9, 1 / 60)
    W = np.asarray(W, dtype=np.float64)
    move = knots[:, None, None] * W
    track = build_track(knots, np.asarray(goal, dtype=np.float64)[None, None] + move,
                        cuts=np.zeros(len(knots) - 1, bool))
    cm = ColliderModel.from_pairs(capsules(np.asarray(cap_ends)[None], [radius]), np.array([[True]]),
                                  friction=FRICTION)
    col = cm.on_track(knots, np.asarray(cap_ends, dtype=np.float64)[None] + move)
    control = track.to_device()
    solver = ParticleSolver(model)
    s, o = model.state(), model.state()
    s.assign(np.array([x0], np.float32), np.array([v0], np.float32))
    grid = np.arange(0, duration + 1e-9, h)
    xs, vs, depth = [np.asarray(x0, np.float64)], [np.asarray(v0, np.float64)], []
    for k in range(len(grid) - 1):
        solver.integrate(s, o, control, grid[k:k + 2], record=[1], colliders=col)
        x, v = o.numpy()
        xs.append(x[0].astype(np.float64))
        vs.append(v[0].astype(np.float64))
        depth.append(float(solver.contact_records[0, 0, 0]))
        s, o = o, s
    return np.array(xs), np.array(vs), np.array(depth), grid


@pytest.mark.parametrize("v0", [[0.0, 0.0, 0.0], [-1.0, 0.0, -0.3]])
def test_a_particle_hit_by_a_moving_capsule_leaves_no_faster_relative_to_it(v0):
    """A free particle (no goal spring, no gravity: it moves in straight lines between contacts) and a capsule
    of 5 cm radius along y sweeping along +x at W = 2 m/s, its axis 3 cm below the particle (an oblique hit):
    the particle at rest, or coming at it at 1 m/s. The reference equation of an inelastic stop with Coulomb
    friction, in the capsule's frame: v' - W = keep (v - W)_t, keep in [0, 1], the normal part dropped; so
    |v - W| never rises from step to step, and once in contact the particle does not move into the capsule
    (its relative normal velocity >= 0). The particle is then carried along (friction stops its sliding):
    never faster relative to the capsule than it came, never faster than the capsule plus its own speed."""
    W = np.array([2.0, 0.0, 0.0])
    model = one_particle(0.0)
    xs, vs, depth, grid = stepped(model, [5.0, 0.0, 0.0], [[-0.3, -0.2, -0.03], [-0.3, 0.2, -0.03]], W,
                                  [0.0, 0.0, 0.0], v0)
    assert (depth > 0).any()                                              # it was hit
    rel = np.linalg.norm(vs - W, axis=1)
    assert np.all(np.diff(rel) <= 1e-5)                                   # float32 round-off
    assert rel.max() <= np.linalg.norm(np.asarray(v0) - W) + 1e-5
    assert np.linalg.norm(vs, axis=1).max() <= np.linalg.norm(W) + np.linalg.norm(v0) + 1e-5


@pytest.mark.parametrize("inside", [False, True])
def test_energy_in_the_capsules_frame_does_not_rise_in_a_contact(inside):
    """A particle on an undamped goal spring (4 Hz, 10 g; the exact goal flow keeps its energy to round-off)
    whose goal and a capsule (5 cm radius, along y) both translate at W = (1.5, 0, -0.5) m/s: in their common
    frame E = m |v - W|^2 / 2 + m omega^2 |x - g|^2 / 2 is conserved until a contact, then may only fall. The
    particle starts on its goal moving toward the capsule's axis: at 1 m/s, its goal 5 mm outside the surface
    (inside False), or at 0.1 m/s, its goal 1 cm inside it (inside True: the allowance, it meets the surface
    at its goal's depth at once; pushed out to the capsule's radius, as before the allowance, its spring
    would hold m omega^2 (1 cm)^2 / 2, six times its start energy). E never rises above its start (float32
    round-off), and the inelastic stop takes at least a third of it."""
    omega = 2 * np.pi * 4.0
    W = np.array([1.5, 0.0, -0.5])
    model = one_particle(omega)
    gap = -0.01 if inside else 0.005
    goal = np.array([0.0, 0.0, 0.05 + gap])
    v0 = W + [0.0, 0.0, -0.1 if inside else -1.0]
    xs, vs, depth, grid = stepped(model, goal, [[0.0, -0.2, 0.0], [0.0, 0.2, 0.0]], W, goal, v0)
    g = goal + grid[:, None] * W
    m = 0.01
    E = 0.5 * m * np.sum((vs - W) ** 2, axis=1) + 0.5 * m * omega * omega * np.sum((xs - g) ** 2, axis=1)
    assert (depth > 0).any()                                              # the contact happened
    assert E.max() <= E[0] * (1 + 1e-4)
    assert E[-1] < E[0] * 2 / 3
    # never deeper than its goal's depth (beyond float32 round-off), never pushed out past it
    d = np.array([segment_distance(x[None], [0.0, -0.2, 0.0] + t * W, [0.0, 0.2, 0.0] + t * W)[0][0]
                  for x, t in zip(xs, grid)])
    assert d.min() >= min(0.05, 0.05 + gap) - 1e-5
