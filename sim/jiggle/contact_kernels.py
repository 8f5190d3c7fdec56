"""Warp kernels of the contacts: particles against bone capsules and the floor, inside the one-launch
run of the particle solver (sim/jiggle/particle_kernels.py: integrate_run), and skin vertices counted
inside capsules (sim/jiggle/colliders.py launches them; the NumPy references are
sim/jiggle/colliders.py: contact_numpy, integrate_contact_numpy and skin_inside_numpy).

Contact is a projection with friction, done after each step's goal flow (the tissue law), on
the step's end positions: a particle found inside a capsule (or below the floor), deeper than its goal
lies (see below), is put back on that surface along the normal, its velocity relative to the surface loses
its inward normal part (an inelastic stop: a surface, unlike the tissue's reach, is a wall) and its
tangential part is slowed by Coulomb friction (|dv_t| <= mu |dv_n|). Why a projection rather than a
stiff penalty spring: the goal flow is exact for any step, and the only explicit parts are the neighbour
springs, kept stable by the solver's step limit; a penalty stiff enough to hold a fat pad against a
landing (tens of g) would need a step limit of its own, ~10x smaller, and would let the pad sink in by
(m a / k) whatever the step; a projection never lets a particle end a step inside, costs nothing when
nothing touches, and is the right thing for a bone or the floor, which do not give. The floor is a
half-space, so nothing tunnels through it at any speed or step.

The rest state defines the contact. A particle is held outside its capsule only as far as its goal (the
static shape: the animation's tissue at rest, the bind pose at bind) is: per (particle, capsule) pair at the
step's end the surface has radius min(r, |goal - axis|), and the floor is at min(floor, goal z). The
penetration of the goal is the pair's allowance; the contact acts on the jiggle's penetration beyond it,
never on the animation's. Why: a capsule is a rough stand-in for a bone, fitted once at bind; thin limbs
with tight capsules, a leg swung against the chest, a gallop's hind leg under the flank put the goals of
tissue inside another part's capsule, and a surface at the full radius then pushed the particle out by
that depth, away from its goal, every step: the projection did work against the goal spring and the
tissue law (the shared horse's gallop pushed a flank 69 mm out of a hind leg's capsule), and the spring
gave it back as a fling when the capsule moved on. With the allowance, a particle resting on its goal is
never pushed, a push moves it toward its goal's depth (less spring energy, not more), and the response to
the velocity keeps its rule: the relative normal velocity into the surface is dropped and friction only
shortens the tangential part, so no contact leaves a particle faster relative to the collider than it
came. The allowance is a function of the frozen goal and capsule tracks at the step's end only (no
history), so a resumed chunk and another frame rate see the same surfaces; it equals the bind-pose depth
at bind (pairs touching at bind are left out altogether, sim/jiggle/colliders.py) and the first frame's
when a bake starts settled on it. The skin's side (skin_keep_out_clusters) has the same rule: skin the
animation puts inside stays, the jiggle is pulled back.

The capsules move with their joints: their two ends are a second goal track on the same knots as the
particles' goals (cubic Hermite between knots, sim/jiggle/goal_track.py), so a capsule's position at
any step's end is the same arithmetic as a goal's.

Broad phase, per muscle and block of BROAD_BLOCK knot intervals, on the host before the launch
(sim/jiggle/colliders.py: Colliders.active): the box of the muscle's goal curves over the block (the
hull of their Bezier control points), grown by tissue_law.BROAD x the muscle's reach (the tissue law turns
particles back before their reach) and its largest capsule radius (a push out of one capsule moves a particle at most that
far), against each candidate capsule's box over the block grown by its radius; the floor when the box
reaches below it. A muscle's candidates (capsules of bones that are not its own chain, not touched at
rest) are listed once. A muscle nothing is near costs one lookup per step. In the kernel, per step, the
listed capsules' boxes at the step's end and their union: a particle outside the union costs one box
test, the rest a box test per capsule before the exact one (contact_pass).

The skin check (skin vertices of one body part inside another part's capsule, every frame) is one
launch over (frame, cluster of a part's vertices, a few centimetres across, riding the part's joint):
the cluster's reach from its centre, the capsules of its part's list within reach of it (most clusters
have none), the cluster's vertices against those only (skin_keep_out_clusters, which also pulls the final
skin's vertices back out of capsules the jiggle took them into); skin_inside is the plain
per-vertex test over the part's whole list, its reference.
"""
from __future__ import annotations

import warp as wp

from jiggle.sim.jiggle.particle_kernels import (
    Edge,
    close_velocity,
    cubic,
    flow_row,
    goal_pos,
    goal_vel,
    open_offsets,
    run_step,
    segment,
    set_cubic,
)

wp.set_module_options({"enable_backward": False})

NO_HIT = -1.0
"""The hit id of a particle that touched nothing (float: it travels in a vec3 with the depth and impulse)."""


@wp.func
def axis_point(x: wp.vec3, a: wp.vec3, b: wp.vec3):
    """(t, q): the parameter t in [0, 1] and the point q = a + t (b - a) of the segment a-b closest to x."""
    ab = b - a
    L2 = wp.dot(ab, ab)
    t = float(0.0)
    if L2 > 0.0:
        t = wp.clamp(wp.dot(x - a, ab) / L2, 0.0, 1.0)
    return t, a + t * ab


@wp.func
def capsule_push(x: wp.vec3, v: wp.vec3, g: wp.vec3, a: wp.vec3, b: wp.vec3, va: wp.vec3, vb: wp.vec3, r: float,
                 friction: float):
    """(x, v, depth) against the capsule of axis a-b and radius r for a particle whose goal is g: the surface
    it is held outside of has radius min(r, |g - axis|) (the allowance: as deep as the goal lies, the
    animation's tissue at rest, and no deeper; the module says why); x inside it is moved onto it along the
    normal, v loses its inward normal velocity relative to the capsule (the axis point's velocity
    va + t (vb - va)) and its tangential part is slowed by friction; depth > 0 how far inside that surface
    x was, else 0."""
    t, q = axis_point(x, a, b)
    d = x - q
    d2 = wp.dot(d, d)
    if d2 >= r * r:                          # outside the capsule (most calls): no square root
        return x, v, 0.0
    _tg, qg = axis_point(g, a, b)
    rs = wp.min(r, wp.length(g - qg))        # the surface the rest state (the goal) defines
    dist = wp.sqrt(d2)
    if dist >= rs:
        return x, v, 0.0
    n = wp.vec3(0.0, 0.0, 1.0)
    if dist > 1.0e-9:
        n = d / dist
    x_new = q + n * rs
    w = va + t * (vb - va)
    v_new = surface_velocity(v, w, n, friction)
    return x_new, v_new, rs - dist


@wp.func
def surface_velocity(v: wp.vec3, w: wp.vec3, n: wp.vec3, friction: float):
    """v after an inelastic stop against a surface of normal n moving at w: the inward normal part of
    the relative velocity dropped, the tangential part reduced by friction x that change (Coulomb)."""
    vr = v - w
    vn = wp.dot(vr, n)
    if vn >= 0.0:
        return v
    vt = vr - vn * n
    st = wp.length(vt)
    keep = float(0.0)
    if st > 0.0:
        keep = wp.max(0.0, st + friction * vn) / st
    return w + keep * vt


FAR = 1.0e30
"""metres: beyond any position (an empty box's bounds)."""


@wp.func
def end_pos(cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
            seg: int, k: int, H: float, s: float):
    """Capsule end k's position at s on knot interval seg (goal_pos's arithmetic)."""
    pa, pb, va, vb = segment(cap_pos, cap_vs, cap_ve, seg, k)
    return goal_pos(pa, pb, va, vb, H, s)


@wp.func
def capsule_contact(x: wp.vec3, v: wp.vec3, g: wp.vec3, a: wp.vec3, b: wp.vec3, cap_pos: wp.array2d(dtype=wp.vec3),
                    cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3), seg: int, c: int, H: float,
                    s: float, r: float, friction: float):
    """capsule_push against capsule c (ends a, b at s) of a particle with goal g, its ends' velocities evaluated
    only when x is inside the capsule."""
    _t, q = axis_point(x, a, b)
    d = x - q
    if wp.dot(d, d) >= r * r:
        return x, v, 0.0
    pa, pb, va, vb = segment(cap_pos, cap_vs, cap_ve, seg, 2 * c)
    wa = goal_vel(pa, pb, va, vb, H, s)
    pa, pb, va, vb = segment(cap_pos, cap_vs, cap_ve, seg, 2 * c + 1)
    wb = goal_vel(pa, pb, va, vb, H, s)
    return capsule_push(x, v, g, a, b, wa, wb, r, friction)


@wp.func
def contact_ends(
    e0: int, e1: int, num_capsules: int, floor: float, cap_radius: wp.array(dtype=float),
    active_id: wp.array(dtype=wp.int32),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s1: float,
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3),
):
    """What a muscle's contacts at s1 share, over its listed entries e0:e1: the capsules' ends and boxes (grown by
    the radius) into the scratch per entry, and (union lo, union hi, the floor's height when it is listed, else
    far below)."""
    ulo = wp.vec3(FAR)
    uhi = wp.vec3(-FAR)
    floor_live = float(-FAR)
    for e in range(e0, e1):
        c = active_id[e]
        if c < num_capsules:
            a = end_pos(cap_pos, cap_vs, cap_ve, seg, 2 * c, H, s1)
            b = end_pos(cap_pos, cap_vs, cap_ve, seg, 2 * c + 1, H, s1)
            r = cap_radius[c]
            clo = wp.min(a, b) - wp.vec3(r)
            chi = wp.max(a, b) + wp.vec3(r)
            # the ends and the capsule's box; its ends' velocities are needed only on a contact
            ends_a[e] = a
            ends_b[e] = b
            ends_va[e] = clo
            ends_vb[e] = chi
            ulo = wp.min(ulo, clo)
            uhi = wp.max(uhi, chi)
        else:
            floor_live = floor
    return ulo, uhi, floor_live


@wp.func
def contact_particle(
    i: int, m: int, e0: int, e1: int, ulo: wp.vec3, uhi: wp.vec3, floor_live: float,
    params: wp.array(dtype=wp.vec3), cap_radius: wp.array(dtype=float), floor: float, friction: float,
    num_capsules: int, active_id: wp.array(dtype=wp.int32),
    cubics: wp.array(dtype=cubic), cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3),
    cap_ve: wp.array2d(dtype=wp.vec3), seg: int, H: float, s1: float,
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    frame: int, last: bool, frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
):
    """Particle i (of muscle m, its listed entries e0:e1 and their union box from :func:`contact_ends`) pushed out
    of the capsules and above the floor at s1: its offsets corrected in place, its positions rewritten where
    read, its record kept, dirty[m] set when it touched something."""
    inv_m = params[i][0]
    cu = cubics[i]
    pa = wp.vec3(cu[0], cu[1], cu[2])
    va = wp.vec3(cu[3], cu[4], cu[5])
    c2 = wp.vec3(cu[6], cu[7], cu[8])
    c3 = wp.vec3(cu[9], cu[10], cu[11])
    g1 = pa + s1 * (va + s1 * (c2 + s1 * c3))
    x = g1 + y[i]                           # run_step's arithmetic: what it wrote
    # a particle outside every live capsule's box and above a live floor touches nothing
    near = x[0] >= ulo[0] and x[1] >= ulo[1] and x[2] >= ulo[2] and \
        x[0] <= uhi[0] and x[1] <= uhi[1] and x[2] <= uhi[2]
    if inv_m > 0.0 and (near or x[2] < floor_live):
        g_vel = va + s1 * (2.0 * c2 + 3.0 * s1 * c3)
        v1 = g_vel + u[i]
        v = v1
        deepest = float(0.0)
        hit = float(NO_HIT)
        for e in range(e0, e1):
            c = active_id[e]
            if c < num_capsules:
                clo = ends_va[e]
                chi = ends_vb[e]
                # outside the capsule's box (most particles): no push
                if x[0] >= clo[0] and x[1] >= clo[1] and x[2] >= clo[2] and \
                        x[0] <= chi[0] and x[1] <= chi[1] and x[2] <= chi[2]:
                    x, v, depth = capsule_contact(x, v, g1, ends_a[e], ends_b[e], cap_pos, cap_vs, cap_ve,
                                                  seg, c, H, s1, cap_radius[c], friction)
                    if depth > deepest:
                        deepest = depth
                        hit = float(c)
            elif x[2] < wp.min(floor, g1[2]):     # the floor, as deep as the goal lies and no deeper
                fs = wp.min(floor, g1[2])
                depth = fs - x[2]
                x = wp.vec3(x[0], x[1], fs)
                v = surface_velocity(v, wp.vec3(0.0), wp.vec3(0.0, 0.0, 1.0), friction)
                if depth > deepest:
                    deepest = depth
                    hit = float(num_capsules)
        if hit != NO_HIT:
            y[i] = x - g1
            u[i] = v - g_vel
            if frame >= 0:
                frames_out[frame, i] = x
            if last:
                x_out[i] = x
            rec = record[i]
            impulse = wp.length(v - v1) / inv_m
            if deepest > rec[0]:
                record[i] = wp.vec3(deepest, rec[1] + impulse, hit)
            else:
                record[i] = wp.vec3(rec[0], rec[1] + impulse, rec[2])
            dirty[m] = 1


@wp.func
def contact_pass(
    m0: int, m1: int,
    # model
    params: wp.array(dtype=wp.vec3), muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    # broad phase: what muscle m may touch on knot interval seg, active_id[active_offsets[seg M + m]:...]
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    # goals of the particles (cubics of the current interval) and of the capsule ends, at s1
    cubics: wp.array(dtype=cubic), cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3),
    cap_ve: wp.array2d(dtype=wp.vec3), seg: int, H: float, s1: float,
    # scratch per active entry at s1: capsule ends a, b and box lo, hi;
    # per-particle contact records; per-muscle "has records"
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    # in/out: the step's end offsets
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out (positions already written by run_step; rewritten where a contact moved them)
    frame: int, last: bool, frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    contacts_out: wp.array2d(dtype=wp.vec3),
):
    """The contacts of muscles m0:m1 at the end of a step (s1) against what the broad phase lists for them:
    positions pushed out of the capsules and above the floor, offsets y, u corrected in place, the
    positions rewritten where read, contact records kept (largest depth, summed impulse N s, what was
    hit) and written with each recorded frame (contacts_out holds "none" where a muscle has none).

    Per muscle and step, the listed capsules' ends at s1 and their boxes (grown by the radius) first, and
    the union of those boxes (:func:`contact_ends`); a particle outside the union (and above the floor, when
    the floor is listed) touches nothing and costs one box test, the others are tested against each capsule's
    box before its exact test (:func:`contact_particle`), and a capsule's end velocities are evaluated only on
    a contact. The host's broad phase lists what a muscle may reach over a block of knot intervals
    (sim/jiggle/colliders.py: Colliders.active), these tests what each particle reaches now; they skip only
    what cannot touch, so the result is that of testing every listed capsule. A GPU runs the same two
    functions a muscle (then a particle) per thread (sim/jiggle/step_kernels.py)."""
    for m in range(m0, m1):
        lo_p = int(muscle_offsets[m])
        hi_p = int(muscle_offsets[m + 1])
        e0 = int(active_offsets[seg * num_muscles + m])
        e1 = int(active_offsets[seg * num_muscles + m + 1])
        if e1 > e0:
            ulo, uhi, floor_live = contact_ends(e0, e1, num_capsules, floor, cap_radius, active_id, cap_pos, cap_vs,
                                                cap_ve, seg, H, s1, ends_a, ends_b, ends_va, ends_vb)
            for i in range(lo_p, hi_p):
                contact_particle(i, m, e0, e1, ulo, uhi, floor_live, params, cap_radius, floor, friction,
                                 num_capsules, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, H, s1, ends_a,
                                 ends_b, ends_va, ends_vb, record, dirty, y, u, frame, last, frames_out, x_out)
        if frame >= 0 and dirty[m] != 0:
            for i in range(lo_p, hi_p):
                contacts_out[frame, i] = record[i]
                record[i] = wp.vec3(0.0, 0.0, NO_HIT)
            dirty[m] = 0


@wp.kernel
def integrate_run_contact(
    # model
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    # colliders
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    # goals: the particles', the capsule ends' (same knots)
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    # steps (K,) as integrate_run
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    # state in
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    # scratch
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    # out
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """integrate_run (sim/jiggle/particle_kernels.py) with the contacts of :func:`contact_pass` after every
    step; contacts_out[step_frame[k]] gets each particle's contact record (depth m, impulse N s, hit id:
    a capsule, num_capsules for the floor, -1 none) since the previous recorded step (filled with "none"
    by the caller); stops_out as integrate_run's."""
    g = wp.tid()
    lo = int(group_offsets[g])
    hi = int(group_offsets[g + 1])
    m0 = int(group_muscles[g])
    m1 = int(group_muscles[g + 1])
    K = step_seg.shape[0]
    seg0 = int(step_seg[0])
    for i in range(lo, hi):
        open_offsets(i, pos, vel_start, vel_end, seg0, step_H[0], step_s0[0], x, v, y_a, u_a)
        record[i] = wp.vec3(0.0, 0.0, NO_HIT)
    for m in range(m0, m1):
        dirty[m] = 0
    for k in range(K):
        seg = int(step_seg[k])
        if k == 0 or seg != int(step_seg[wp.max(k - 1, 0)]):
            for i in range(lo, hi):
                set_cubic(i, pos, vel_start, vel_end, seg, step_H[k], cubics)
        last = k == K - 1
        s1 = step_s0[k] + step_h[k]
        frame = int(step_frame[k])
        if k % 2 == 0:
            run_step(lo, hi, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                     step_h[k], step_kick[k], y_a, u_a, frame, last, frames_out, x_out, y_b, u_b, stops_out)
            contact_pass(m0, m1, params, muscle_offsets, cap_radius, floor, friction, num_capsules, num_muscles,
                         active_offsets, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                         ends_b, ends_va, ends_vb, record, dirty, y_b, u_b, frame, last, frames_out, x_out,
                         contacts_out)
        else:
            run_step(lo, hi, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                     step_h[k], step_kick[k], y_b, u_b, frame, last, frames_out, x_out, y_a, u_a, stops_out)
            contact_pass(m0, m1, params, muscle_offsets, cap_radius, floor, friction, num_capsules, num_muscles,
                         active_offsets, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                         ends_b, ends_va, ends_vb, record, dirty, y_a, u_a, frame, last, frames_out, x_out,
                         contacts_out)
    for i in range(lo, hi):
        close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                       s_end, h_end, y_a, u_a, y_b, u_b, v_out)


@wp.func
def from_axis(x: wp.vec3, a: wp.vec3, b: wp.vec3):
    """x less its closest point on the segment a-b."""
    ab = b - a
    L2 = wp.dot(ab, ab)
    s = float(0.0)
    if L2 > 0.0:
        s = wp.clamp(wp.dot(x - a, ab) / L2, 0.0, 1.0)
    return x - (a + s * ab)


@wp.func
def inside_capsule(x: wp.vec3, a: wp.vec3, b: wp.vec3, r: float):
    """x strictly inside the capsule of axis a-b and radius r."""
    d = from_axis(x, a, b)
    return wp.dot(d, d) < r * r


@wp.kernel
def skin_inside(
    # model: capsules and, per vertex part, the capsules it is checked against (CSR)
    part: wp.array(dtype=wp.int32), part_offsets: wp.array(dtype=wp.int32), part_capsule: wp.array(dtype=wp.int32),
    cap_radius: wp.array(dtype=float),
    # in: capsule ends per frame (T, 2C) and skin vertices (T, V)
    ends: wp.array2d(dtype=wp.vec3), skin: wp.array2d(dtype=wp.vec3),
    # out: 1 where vertex v of frame t lies inside another part's capsule
    inside_out: wp.array2d(dtype=wp.int32),
):
    """Skin vertices of one body part inside another part's capsule, per frame (thread per (t, v))."""
    t, i = wp.tid()
    p = int(part[i])
    x = skin[t, i]
    hit = int(0)
    for e in range(part_offsets[p], part_offsets[p + 1]):
        c = part_capsule[e]
        if inside_capsule(x, ends[t, 2 * c], ends[t, 2 * c + 1], cap_radius[c]):
            hit = 1
    inside_out[t, i] = hit


@wp.func
def near_capsules(t: int, k: int, x0: wp.vec3, reach: float, e0: int, e1: int,
                  part_capsule: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
                  ends: wp.array2d(dtype=wp.vec3), cand: wp.array3d(dtype=wp.int32)):
    """How many of the capsules part_capsule[e0:e1] have their axis within reach + radius of a cluster's
    centre x0 in frame t, listed in cand[t, k, :n]: the only ones a vertex within reach of x0 can be inside."""
    n = int(0)
    for e in range(e0, e1):
        c = part_capsule[e]
        d = from_axis(x0, ends[t, 2 * c], ends[t, 2 * c + 1])
        lim = reach + cap_radius[c]
        if wp.dot(d, d) <= lim * lim:
            cand[t, k, n] = c
            n += 1
    return n


KEEP_OUT_PASSES = 4
"""Pull-backs per vertex (a pulled-back vertex may lie in a third capsule the segment crossed; then the
vertex is pulled back again, and after this many passes it is put on its static position)."""
KEEP_OUT_BISECTIONS = 24
"""Bisection steps of a pull-back: the entry point along static -> final to 2^-24 of the segment."""


@wp.func
def first_outside(s: wp.vec3, f: wp.vec3, a: wp.vec3, b: wp.vec3, r: float):
    """The parameter u in [0, 1) of the last point s + u (f - s) found outside the capsule a-b, r before
    the segment enters it (s outside, f inside: the distance to the axis is convex along the segment, so
    the inside part is one interval and bisection finds its start)."""
    lo = float(0.0)
    hi = float(1.0)
    d = f - s
    for _ in range(KEEP_OUT_BISECTIONS):
        mid = 0.5 * (lo + hi)
        if inside_capsule(s + mid * d, a, b, r):
            hi = mid
        else:
            lo = mid
    return lo


@wp.kernel
def skin_keep_out_clusters(
    # model: clusters (CSR over the vertices sorted by cluster), each cluster's part, the parts' capsule lists
    cluster_offsets: wp.array(dtype=wp.int32), cluster_vertex: wp.array(dtype=wp.int32),
    cluster_part: wp.array(dtype=wp.int32), part_offsets: wp.array(dtype=wp.int32),
    part_capsule: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    # in: capsule ends (T, 2C), the clusters' centres (T, K), the static skin (T, V)
    ends: wp.array2d(dtype=wp.vec3), centres: wp.array2d(dtype=wp.vec3), skin_static: wp.array2d(dtype=wp.vec3),
    # in and out: the final skin (T, V), its vertices pulled back where the jiggle took them into a capsule
    skin_final: wp.array2d(dtype=wp.vec3),
    # scratch: the candidate capsules of each thread (T, K, L)
    cand: wp.array3d(dtype=wp.int32),
    # out (zeroed by the caller): per frame the static and final vertices inside a capsule of their part's
    # list, the final vertices pulled back, and the longest pull-back (metres)
    static_out: wp.array(dtype=wp.int32), final_out: wp.array(dtype=wp.int32), kept_out: wp.array(dtype=wp.int32),
    pulled_out: wp.array(dtype=float),
):
    """The skin's side of the contacts, a thread per (frame t, cluster k): the cluster's reach from its centre
    over both skins (the segment between a static and a final vertex lies within the larger of their
    distances), the capsules of its part's list whose axis comes within reach + radius of the centre
    (near_capsules: a vertex inside a capsule is within its radius of the axis and within reach of the
    centre, so no other capsule can hold one; most clusters have none), then the cluster's vertices against
    those only. A final vertex inside a capsule its static vertex is not inside is pulled back along its
    jiggle (final - static) to just before the point where that segment enters the capsule: the jiggle
    never takes the skin into another part's capsule, and skin the animation itself puts inside (the static
    skin) stays. Then both skins are counted (a vertex once, whatever it is inside), so per frame the final
    count is at most the static one (a final vertex inside c has its static vertex inside c)."""
    t, k = wp.tid()
    p = int(cluster_part[k])
    e0 = int(part_offsets[p])
    e1 = int(part_offsets[p + 1])
    if e1 > e0:
        v0 = int(cluster_offsets[k])
        v1 = int(cluster_offsets[k + 1])
        x0 = centres[t, k]
        reach2 = float(0.0)
        for j in range(v0, v1):
            i = cluster_vertex[j]
            d0 = skin_static[t, i] - x0
            d1 = skin_final[t, i] - x0
            reach2 = wp.max(reach2, wp.max(wp.dot(d0, d0), wp.dot(d1, d1)))
        reach = wp.sqrt(reach2)
        n = near_capsules(t, k, x0, reach, e0, e1, part_capsule, cap_radius, ends, cand)
        if n > 0:
            n_static = int(0)
            n_final = int(0)
            n_kept = int(0)
            pulled = float(0.0)
            for j in range(v0, v1):
                i = cluster_vertex[j]
                s = skin_static[t, i]
                f0 = skin_final[t, i]
                f = f0
                for _ in range(KEEP_OUT_PASSES):
                    u = float(2.0)
                    for q in range(n):
                        c = cand[t, k, q]
                        a = ends[t, 2 * c]
                        b = ends[t, 2 * c + 1]
                        r = cap_radius[c]
                        if inside_capsule(f, a, b, r) and not inside_capsule(s, a, b, r):
                            u = wp.min(u, first_outside(s, f, a, b, r))
                    if u > 1.0:
                        break
                    f = s + u * (f - s)
                for q in range(n):                  # still inside after the passes: the static vertex
                    c = cand[t, k, q]
                    a = ends[t, 2 * c]
                    b = ends[t, 2 * c + 1]
                    r = cap_radius[c]
                    if inside_capsule(f, a, b, r) and not inside_capsule(s, a, b, r):
                        f = s
                if f[0] != f0[0] or f[1] != f0[1] or f[2] != f0[2]:
                    skin_final[t, i] = f
                    n_kept += 1
                    pulled = wp.max(pulled, wp.length(f0 - f))
                s_in = int(0)
                f_in = int(0)
                for q in range(n):
                    c = cand[t, k, q]
                    a = ends[t, 2 * c]
                    b = ends[t, 2 * c + 1]
                    r = cap_radius[c]
                    if inside_capsule(s, a, b, r):
                        s_in = 1
                    if inside_capsule(f, a, b, r):
                        f_in = 1
                n_static += s_in
                n_final += f_in
            if n_static > 0:
                wp.atomic_add(static_out, t, n_static)
            if n_final > 0:
                wp.atomic_add(final_out, t, n_final)
            if n_kept > 0:
                wp.atomic_add(kept_out, t, n_kept)
                wp.atomic_max(pulled_out, t, pulled)
