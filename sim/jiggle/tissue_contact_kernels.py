"""Warp kernel of the contacts between muscles of different body parts (particle against particle), run
between the particle solver's steps (sim/jiggle/tissue_contacts.py launches it; its NumPy reference is
sim/jiggle/tissue_contacts.py: tissue_contact_numpy).

One thread per particle, a Jacobi projection: every thread reads the step's end positions and velocities
(x_in, v_in) and writes only its own corrected ones (x_out, v_out) and its own contact record, so the
result does not depend on the order threads run in (no atomics: a resumed bake repeats it bit for bit).
The neighbours come from a wp.HashGrid built on x_in (cell and query radius: twice the largest particle
radius, so every pair that can touch is seen). Broad phase first (muscle_boxes, near_boxes: a thread per
muscle): each muscle's box, then per muscle the union of the boxes (grown by the query radius) of the
muscles it may touch that come near it; a particle outside its muscle's union queries nothing, and a step
where no muscle is near another skips the grid's build (the launch wrapper reads the M flags back). Both only
skip what cannot touch, so the result is that of querying every particle.

For each pair (i, j) of muscles allowed to touch (mask) closer than their contact distance D_ij (the
rule of sim/jiggle/tissue_contacts.py: min(r_i + r_j, SHARE |X_i - X_j|), X the bind positions), depth
p = D_ij - |x_i - x_j| along the normal n from j to i:

- position: i moves by w_i / (w_i + w_j) p n (w = 1 / mass, 0 for glued particles), j by its own share
  the other way in its own thread: one pair alone is exactly separated, momentum kept;
- velocity: the relative velocity's inward normal part is removed (inelastic) and its tangential part
  slowed by Coulomb friction (|dv_t| <= mu |dv_n|), split by the same mass shares (the capsules' rule,
  sim/jiggle/contact_kernels.py: surface_velocity, with the other particle as the moving surface);
- a particle in several contacts takes the mean of its corrections (constraint averaging): summed, k
  neighbours pushing the same way would move it k times too far and set it ringing.

The record per particle merges the solver's capsule / floor record of the step (caps_in) and this pass
into the frame's record (acc): the largest depth before correction, the summed impulse m |dv| (N s),
and the hit id of the deepest (hit_base + the other muscle's index for a tissue contact).
"""
from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})

NO_HIT = -1.0
"""The hit id of a particle that touched nothing (as sim/jiggle/contact_kernels.py: NO_HIT)."""
FAR = 1.0e30
"""metres: beyond any position (an empty box's bounds)."""


@wp.func
def merge_record(rec: wp.vec3, depth: float, impulse: float, hit: float):
    """A contact record (largest depth, summed impulse, hit id of the deepest) with one more contact."""
    if depth > rec[0]:
        return wp.vec3(depth, rec[1] + impulse, hit)
    return wp.vec3(rec[0], rec[1] + impulse, rec[2])


@wp.kernel
def muscle_boxes(
    # model
    muscle_offsets: wp.array(dtype=wp.int32),
    # state in
    x_in: wp.array(dtype=wp.vec3),
    # out: (M,) each muscle's box
    lo_out: wp.array(dtype=wp.vec3), hi_out: wp.array(dtype=wp.vec3),
):
    """The box of each muscle's particles (a thread per muscle)."""
    m = wp.tid()
    lo = wp.vec3(FAR)
    hi = wp.vec3(-FAR)
    for i in range(int(muscle_offsets[m]), int(muscle_offsets[m + 1])):
        lo = wp.min(lo, x_in[i])
        hi = wp.max(hi, x_in[i])
    lo_out[m] = lo
    hi_out[m] = hi


@wp.kernel
def near_boxes(
    # model
    mask: wp.array(dtype=wp.int32), num_muscles: int, query_radius: float,
    # in: (M,) the muscles' boxes
    lo_in: wp.array(dtype=wp.vec3), hi_in: wp.array(dtype=wp.vec3),
    # out: (M,) per muscle the union of the boxes, grown by the query radius, of the muscles it may touch whose
    # grown box overlaps its own (empty: nothing near), and 1 where it is not empty
    near_lo_out: wp.array(dtype=wp.vec3), near_hi_out: wp.array(dtype=wp.vec3), near_out: wp.array(dtype=wp.int32),
):
    """The broad phase of the contact pass, a thread per muscle: a particle of muscle m outside its near box is
    farther than the query radius from every particle it may touch (M^2 box tests a step, a few microseconds
    for tens of muscles)."""
    m = wp.tid()
    a_lo = lo_in[m]
    a_hi = hi_in[m]
    r = wp.vec3(query_radius)
    lo = wp.vec3(FAR)
    hi = wp.vec3(-FAR)
    near = int(0)
    for b in range(num_muscles):
        if mask[m * num_muscles + b] != 0:
            b_lo = lo_in[b] - r
            b_hi = hi_in[b] + r
            if b_lo[0] <= a_hi[0] and b_lo[1] <= a_hi[1] and b_lo[2] <= a_hi[2] and \
                    b_hi[0] >= a_lo[0] and b_hi[1] >= a_lo[1] and b_hi[2] >= a_lo[2]:
                lo = wp.min(lo, b_lo)
                hi = wp.max(hi, b_hi)
                near = 1
    near_lo_out[m] = lo
    near_hi_out[m] = hi
    near_out[m] = near


@wp.kernel
def tissue_contact(
    # model
    grid: wp.uint64, query_radius: float, inv_mass: wp.array(dtype=float), radius: wp.array(dtype=float),
    muscle: wp.array(dtype=wp.int32), muscle_offsets: wp.array(dtype=wp.int32), rest: wp.array(dtype=wp.vec3),
    mask: wp.array(dtype=wp.int32), num_muscles: int, share: float, friction: float, hit_base: float,
    # state in: the step's end (the hash grid is built on x_in), each muscle's near box (near_boxes)
    x_in: wp.array(dtype=wp.vec3), v_in: wp.array(dtype=wp.vec3), near_lo: wp.array(dtype=wp.vec3),
    near_hi: wp.array(dtype=wp.vec3),
    # records in: the step's capsule / floor records; fresh = 1 starts a new frame's record in acc
    caps_in: wp.array(dtype=wp.vec3), fresh: int,
    # out
    x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3), acc: wp.array(dtype=wp.vec3),
):
    """Particles of different body parts pushed apart (module docstring), a thread per particle."""
    i = wp.tid()
    xi = x_in[i]
    vi = v_in[i]
    wi = inv_mass[i]
    ri = radius[i]
    mi = int(muscle[i])
    row = mi * num_muscles
    own_lo = int(muscle_offsets[mi])
    own_hi = int(muscle_offsets[mi + 1])
    dx = wp.vec3(0.0)
    dv = wp.vec3(0.0)
    n = int(0)
    deepest = float(0.0)
    hit = float(NO_HIT)
    lo = near_lo[mi]
    hi = near_hi[mi]
    near = xi[0] >= lo[0] and xi[1] >= lo[1] and xi[2] >= lo[2] and xi[0] <= hi[0] and xi[1] <= hi[1] and \
        xi[2] <= hi[2]
    # outside its muscle's near box (most particles of a body): nothing to query
    if near:
        query = wp.hash_grid_query(grid, xi, query_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            if j >= own_lo and j < own_hi:                  # its own muscle's (most neighbours): no load
                continue
            mj = int(muscle[j])
            if mask[row + mj] != 0:
                d = xi - x_in[j]
                d2 = wp.dot(d, d)
                reach = ri + radius[j]
                if d2 < reach * reach:                        # cheap test first: most neighbours are farther
                    sep = rest[i] - rest[j]
                    D = wp.min(reach, share * wp.length(sep))
                    if d2 < D * D:
                        dist = wp.sqrt(d2)
                        nrm = wp.vec3(0.0, 0.0, 1.0)
                        if dist > 1.0e-9:
                            nrm = d / dist
                        elif wp.length(sep) > 0.0:            # on top of each other: apart as at bind (odd in i, j)
                            nrm = wp.normalize(sep)
                        p = D - dist
                        if p > deepest:
                            deepest = p
                            hit = hit_base + float(mj)
                        wsum = wi + inv_mass[j]
                        if wsum > 0.0:
                            k = wi / wsum
                            dx += (k * p) * nrm
                            vr = vi - v_in[j]
                            vn = wp.dot(vr, nrm)
                            if vn < 0.0:
                                vt = vr - vn * nrm
                                st = wp.length(vt)
                                keep = float(0.0)
                                if st > 0.0:
                                    keep = wp.max(0.0, st + friction * vn) / st
                                dv += k * ((keep - 1.0) * vt - vn * nrm)
                            n += 1
    rec = acc[i]
    if fresh != 0:
        rec = wp.vec3(0.0, 0.0, NO_HIT)
    caps = caps_in[i]
    if caps[2] != NO_HIT:
        rec = merge_record(rec, caps[0], caps[1], caps[2])
    if n > 0:
        s = 1.0 / float(n)
        dvi = s * dv
        x_out[i] = xi + s * dx
        v_out[i] = vi + dvi
        impulse = float(0.0)
        if wi > 0.0:
            impulse = wp.length(dvi) / wi
        rec = merge_record(rec, deepest, impulse, hit)
    else:
        x_out[i] = xi
        v_out[i] = vi
        if hit != NO_HIT:                                 # touching glued particles only: depth, no impulse
            rec = merge_record(rec, deepest, 0.0, hit)
    acc[i] = rec
