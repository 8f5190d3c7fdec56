"""Warp kernel of the static muscle shape: action curve, section frames, volume rule and section CVs of
every muscle for every frame of a chunk, in one launch. The launch wrapper is
``rig.muscle.model._static_on_device`` (``MuscleRig.static(world, device=...)``, the rig's constants
uploaded once per device); the NumPy reference is ``MuscleRig.static(world, device=None)`` (rig/muscle/model.py: ``_pose``,
``_section_offsets``, ``_loft_volume``, ``_section_cvs``), whose docstring states the equations.

One thread per (frame, muscle). Float64 throughout, as the NumPy path, so the two agree to rounding
(~1e-16 m). The loft volume of the "exact" rule is the enclosed volume of the same closed mesh as
``loft.grid_volume(loft.grid_of(...))``: the 17 x 16 grid (rows across the sections, then columns
around them, with the weights of rig/muscle/loft.py) and the two centroid cap fans. A thread streams
the grid one row at a time, keeping only the previous row, so its locals stay a few kB.
"""
from __future__ import annotations

import warp as wp

from jiggle.rig.muscle import loft

# forward only: never differentiated (no adjoint code to compile)
wp.set_module_options({"enable_backward": False})

SECTIONS = wp.constant(loft.SECTIONS)
RING = wp.constant(loft.RING)
ROWS = wp.constant(loft.ROWS)
COLS = wp.constant(loft.COLS)
COLS_PER_CV = wp.constant(loft.COLS_PER_CV)
CVS = wp.constant(loft.SECTIONS * loft.RING)
COLS_F = wp.constant(wp.float64(loft.COLS))   # a float constant of its own: Warp types a constant once

RULE_NONE, RULE_THESIS, RULE_SQRT, RULE_EXACT = 0, 1, 2, 3
"""Codes of the volume rules ("none", "thesis", "sqrt", "exact") passed as the kernel's `rule`."""
_EXACT = wp.constant(RULE_EXACT)
_THESIS = wp.constant(RULE_THESIS)
_NONE = wp.constant(RULE_NONE)

mat53d = wp.types.matrix(shape=(loft.SECTIONS, 3), dtype=wp.float64)          # a vec3d per section
mat403d = wp.types.matrix(shape=(loft.SECTIONS * loft.RING, 3), dtype=wp.float64)  # a vec3d per CV
mat83d = wp.types.matrix(shape=(loft.RING, 3), dtype=wp.float64)              # one ring's CVs
matcold = wp.types.matrix(shape=(loft.COLS, 3), dtype=wp.float64)             # one grid row


@wp.func
def world_point(world: wp.array2d(dtype=wp.mat44d), joints: wp.array2d(dtype=wp.int32),
                local: wp.array2d(dtype=wp.vec4d), t: int, m: int, k: int):
    """Slot k of muscle m at frame t in world metres: its joint's transform applied to the homogeneous
    local coordinates (w = 1 for points, 0 for directions)."""
    p = world[t, joints[m, k]] * local[m, k]
    return wp.vec3d(p[0], p[1], p[2])


@wp.func
def unit_dir(d: wp.vec3d):
    return d / wp.max(wp.length(d), wp.float64(1e-12))


@wp.func
def frame_up(up: wp.vec3d, side: wp.vec3d, tangent: wp.vec3d):
    """Unit section up: `up` made perpendicular to the unit tangent; within ~0.06 deg of the tangent
    (|residual| < 1e-3) the side vector is used instead, as the NumPy path does."""
    U = up - wp.dot(up, tangent) * tangent
    n = wp.length(U)
    if n < wp.float64(1e-3):
        W = side - wp.dot(side, tangent) * tangent
        return W / wp.length(W)
    return U / n


@wp.func
def row_of(g: matcold, c: int):
    return wp.vec3d(g[c, 0], g[c, 1], g[c, 2])


@wp.func
def loft_volume(x: mat403d, row_weights: wp.array2d(dtype=wp.float64), col_weights: wp.array2d(dtype=wp.float64)):
    """Volume (cubic metres) enclosed by the loft mesh of the 40 CVs x (section-major): quads
    a . (c x (d - b)) of consecutive grid rows plus the two cap fans about the end rows' centroids, over 6
    (rig/muscle/loft.py: grid_volume)."""
    prev = matcold()
    quads = wp.float64(0.0)
    fans = wp.float64(0.0)
    for r in range(ROWS):
        # the row's ring: the 8 CVs of the not-a-knot spline across the sections at this row
        ring = mat83d()
        for j in range(RING):
            acc = wp.vec3d()
            for k in range(SECTIONS):
                acc += row_weights[r, k] * wp.vec3d(x[k * RING + j, 0], x[k * RING + j, 1], x[k * RING + j, 2])
            ring[j] = acc
        # its grid points: the periodic cubic B-spline around it touches 4 CVs per column
        cur = matcold()
        for c in range(COLS):
            i = c // COLS_PER_CV
            p = wp.vec3d()
            for e in range(4):
                j = (i - 1 + e + RING) % RING
                p += col_weights[c, j] * wp.vec3d(ring[j, 0], ring[j, 1], ring[j, 2])
            cur[c] = p
        if r > 0:
            for c in range(COLS):
                n = (c + 1) % COLS
                quads += wp.dot(row_of(prev, c), wp.cross(row_of(cur, n), row_of(cur, c) - row_of(prev, n)))
        if r == 0 or r == ROWS - 1:
            # cap fan from the ring's centroid; the first cap's triangles run the other way round
            centroid = wp.vec3d()
            turn = wp.vec3d()
            for c in range(COLS):
                centroid += row_of(cur, c)
                turn += wp.cross(row_of(cur, c), row_of(cur, (c + 1) % COLS))
            fan = wp.dot(centroid / COLS_F, turn)
            if r == 0:
                fans -= fan
            else:
                fans += fan
        prev = cur
    return (quads + fans) / wp.float64(6.0)


@wp.kernel
def static_shape(
    # model (per muscle m; slots as rig.muscle.model: origin, insertion, o_hinge, i_hinge, q_o, q_i,
    # t_o, t_i, middle offset, up, side)
    joints: wp.array2d(dtype=wp.int32),            # (M, 11)
    local: wp.array2d(dtype=wp.vec4d),             # (M, 11) homogeneous local coordinates
    tendon: wp.array(dtype=wp.vec2d),              # (M,) metres, rest tendon lengths T_o, T_i
    along: wp.array(dtype=wp.vec2d),               # (M,) rest hinge -> belly-end direction along u
    rest_chord: wp.array(dtype=wp.float64),        # (M,) metres
    stations: wp.array3d(dtype=wp.float64),        # (M, 10, 5) centre (rows 0-4) and tangent (5-9) from Z
    sections: wp.array3d(dtype=wp.vec2d),          # (M, 5, 8) metres, fitted offsets (a, b) along (U, S)
    section_scale: wp.array2d(dtype=wp.float64),   # (M, 5) attribute scale per section
    tone: wp.array(dtype=wp.float64),              # (M,) in [0, 1]
    rest_length: wp.array(dtype=wp.float64),       # (M,) metres, Li
    rest_volume: wp.array(dtype=wp.float64),       # (M,) cubic metres
    # shared constants
    curve_from_z: wp.array2d(dtype=wp.float64),    # (5, 5) curve CVs from Z
    arc_from_z: wp.array2d(dtype=wp.float64),      # (16, 5) curve velocity at the quadrature nodes from Z
    arc_w: wp.array(dtype=wp.float64),             # (16,) quadrature weights
    row_weights: wp.array2d(dtype=wp.float64),     # (17, 5) loft.ROW_WEIGHTS
    col_weights: wp.array2d(dtype=wp.float64),     # (17, 8) loft.COL_WEIGHTS
    min_belly: wp.float64,
    rule: int,                                     # RULE_* code
    iterations: int,                               # measured-volume corrections of the exact rule
    # state in
    world: wp.array2d(dtype=wp.mat44d),            # (T, J) joint world transforms, metres
    # out
    cvs_out: wp.array2d(dtype=wp.vec3d),           # (T, 40 M) section CVs, metres
    curve_out: wp.array2d(dtype=wp.vec3d),         # (T, 5 M) action-curve CVs, metres
):
    """Static shape of muscle m at frame t; launch dim (T, M)."""
    t, m = wp.tid()
    origin = world_point(world, joints, local, t, m, 0)
    insertion = world_point(world, joints, local, t, m, 1)
    o_hinge = world_point(world, joints, local, t, m, 2)
    i_hinge = world_point(world, joints, local, t, m, 3)
    u = i_hinge - o_hinge
    u = u / wp.length(u)
    # tendons keep their rest length: what the origin (insertion) side gains, the belly gives
    T = tendon[m]
    a = along[m]
    q_o = world_point(world, joints, local, t, m, 4)
    q_i = world_point(world, joints, local, t, m, 5)
    d_o = unit_dir(a[0] * u + (q_o - wp.dot(q_o, u) * u))
    d_i = unit_dir(a[1] * u + (q_i - wp.dot(q_i, u) * u))
    e_o = o_hinge + (T[0] - wp.length(origin - o_hinge)) * d_o
    e_i = i_hinge + (T[1] - wp.length(insertion - i_hinge)) * d_i
    # a muscle cannot collapse: keep the belly's extent along u above MIN_BELLY x its rest chord
    short = wp.max(min_belly * rest_chord[m] - wp.dot(e_i - e_o, u), wp.float64(0.0))
    e_o = e_o - wp.float64(0.5) * short * u
    e_i = e_i + wp.float64(0.5) * short * u
    chord = wp.length(e_i - e_o)
    # Z = (e_o, e_i, c t_o, c t_i, middle offset): the curve, its speed and the stations are linear in it
    Z = mat53d()
    Z[0] = e_o
    Z[1] = e_i
    Z[2] = chord * world_point(world, joints, local, t, m, 6)
    Z[3] = chord * world_point(world, joints, local, t, m, 7)
    Z[4] = world_point(world, joints, local, t, m, 8)
    for i in range(5):
        q = wp.vec3d()
        for c in range(5):
            q += curve_from_z[i, c] * wp.vec3d(Z[c, 0], Z[c, 1], Z[c, 2])
        curve_out[t, m * 5 + i] = q
    length = wp.float64(0.0)
    for n in range(arc_w.shape[0]):
        v = wp.vec3d()
        for c in range(5):
            v += arc_from_z[n, c] * wp.vec3d(Z[c, 0], Z[c, 1], Z[c, 2])
        length += arc_w[n] * wp.length(v)
    # section frames: centre, unit up U and side S = T x U
    up = world_point(world, joints, local, t, m, 9)
    side = world_point(world, joints, local, t, m, 10)
    centre = mat53d()
    offsets = mat403d()
    for k in range(SECTIONS):
        p = wp.vec3d()
        tangent = wp.vec3d()
        for c in range(5):
            z = wp.vec3d(Z[c, 0], Z[c, 1], Z[c, 2])
            p += stations[m, k, c] * z
            tangent += stations[m, SECTIONS + k, c] * z
        tangent = tangent / wp.length(tangent)
        U = frame_up(up, side, tangent)
        S = wp.cross(tangent, U)
        centre[k] = p
        for j in range(RING):
            ab = sections[m, k, j]
            offsets[k * RING + j] = U * ab[0] + S * ab[1]
    # the volume rule's section scale s
    ratio = rest_length[m] / length
    s = wp.float64(1.0)
    if rule == _THESIS:
        s = ratio
    elif rule != _NONE:
        s = wp.sqrt(ratio)
        if rule == _EXACT:
            for _it in range(iterations):
                # the loft measured about the middle section's centre, as the NumPy path
                x = mat403d()
                for k in range(SECTIONS):
                    sc = section_scale[m, k] * s
                    rel = wp.vec3d(centre[k, 0] - centre[2, 0], centre[k, 1] - centre[2, 1],
                                   centre[k, 2] - centre[2, 2])
                    for j in range(RING):
                        o = offsets[k * RING + j]
                        x[k * RING + j] = wp.vec3d(o[0], o[1], o[2]) * sc + rel
                V = loft_volume(x, row_weights, col_weights)
                s = s * wp.sqrt(wp.clamp(rest_volume[m] / wp.max(V, wp.float64(1e-300)),
                                         wp.float64(0.25), wp.float64(4.0)))
    s = wp.float64(1.0) + tone[m] * (s - wp.float64(1.0))
    for k in range(SECTIONS):
        sc = section_scale[m, k] * s
        p = wp.vec3d(centre[k, 0], centre[k, 1], centre[k, 2])
        for j in range(RING):
            o = offsets[k * RING + j]
            cvs_out[t, m * CVS + k * RING + j] = wp.vec3d(o[0], o[1], o[2]) * sc + p
