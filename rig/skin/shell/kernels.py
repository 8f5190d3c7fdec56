"""Warp kernel for the shell deformers of all muscles, applied in series per vertex.

The launch wrapper is :class:`rig.skin.shell.deformer.ShellDeformer`; the NumPy reference is
:func:`rig.skin.shell.shells.shell_numpy` and the math (relative basic / stretch / trajectory displacements,
shells, star offsets) is in the docstring of :mod:`rig.skin.shell.shells`. Everything is float32. The
(vertex, muscle) pairs are CSR: vertex ``v`` owns pairs ``pair_offsets[v] .. pair_offsets[v+1] - 1``
in ascending muscle order. Ellipsoids are 4x4 affine matrices (local unit sphere -> world, metres);
``wp.transform_point`` applies the full 3x4 part of a mat44.

The per-vertex maths is :func:`shell_point` in the single-frame kernel :func:`shells` (dim V); the
batched kernels :func:`shells_batch` (full skins) and :func:`shells_displace` (the paired vertices'
displacements, the spread's layout) run S sets of muscle states over T frames of skinned points through
:func:`shell_sets`, the same per-pair code with the reference part (which the sets share) computed once
per pair and frame for every set whose point is the same.
"""
from __future__ import annotations

import math

import warp as wp

from jiggle.rig.skin.gather_kernels import csr_span, entry

# forward only: these kernels are never differentiated (no adjoint code to compile)
wp.set_module_options({"enable_backward": False})

MODE_BASIC = wp.constant(0)
MODE_STRETCH = wp.constant(1)
MODE_TRAJECTORY = wp.constant(2)

TINY_R = wp.constant(1.0e-9)
"""Below this local radius a point has no direction: no projection term (as in rig.skin.shell.shells)."""
STAR_NT = wp.constant(17)
STAR_NP = wp.constant(32)
THETA_SCALE = wp.constant((17 - 1) / math.pi)
PHI_SCALE = wp.constant(32 / (2.0 * math.pi))
PI = wp.constant(math.pi)
LIMIT_KNEE = wp.constant(0.5)   # rig.skin.shell.shells.LIMIT_KNEE
LIMIT_REACH = wp.constant(0.5)  # rig.skin.shell.shells.LIMIT_REACH


@wp.struct
class ShellArrays:
    """What the kernels read of the deformers' model (rig.skin.shell.deformer.ShellModel), built once:
    the CSR (vertex, muscle) pairs with their painted weights, each muscle's shell parameters (M,)
    and the star tables (max(S, 1), 17, 32) with their largest offsets."""

    pair_offsets: wp.array(dtype=wp.int32)
    pair_muscle: wp.array(dtype=wp.int32)
    pair_weight: wp.array(dtype=wp.float32)
    sticky: wp.array(dtype=wp.float32)
    hard: wp.array(dtype=wp.float32)
    drop_off: wp.array(dtype=wp.float32)
    weight: wp.array(dtype=wp.float32)
    slippage: wp.array(dtype=wp.float32)
    mode: wp.array(dtype=wp.int32)
    star_index: wp.array(dtype=wp.int32)
    star: wp.array3d(dtype=wp.float32)
    star_max: wp.array(dtype=wp.float32)


@wp.struct
class ShellState:
    """The muscles' state the kernels read per frame (see :func:`shell_point` for the indexing):
    reference ellipsoids and their inverses, dE = E_cur - E_ref, the current inverses, the reference
    centres, the trajectory curves (rows of K samples) and whether each muscle is active."""

    E_ref: wp.array(dtype=wp.mat44)
    E_ref_inv: wp.array(dtype=wp.mat44)
    dE: wp.array(dtype=wp.mat44)
    E_cur_inv: wp.array(dtype=wp.mat44)
    centre: wp.array(dtype=wp.vec3)
    curve: wp.array2d(dtype=wp.vec3)
    active: wp.array(dtype=wp.int32)


@wp.func
def falloff(x: float):
    """(1 - x^2)^2 with x clamped to [0, 1]: 1 below 0, 0 above 1, C1 at both ends."""
    c = wp.clamp(x, 0.0, 1.0)
    return (1.0 - c * c) * (1.0 - c * c)


@wp.func
def shell_beta(rho: float, h: float, d: float):
    inner = 1.0 + h * d
    if rho <= inner:
        return 1.0
    if rho >= 1.0 + d:
        return 0.0
    # here inner < rho < 1 + d, so (1 - h) d > 0 up to rounding; the max keeps h ~ 1 finite
    return falloff((rho - inner) / wp.max((1.0 - h) * d, 1.0e-30))


@wp.func
def shell_alpha(rho: float, d: float):
    if rho <= 1.0:
        return 1.0
    if rho >= 1.0 + d:
        return 0.0
    return falloff((rho - 1.0) / d)


@wp.func
def star_delta(star: wp.array3d(dtype=wp.float32), table: int, u: wp.vec3):
    """Bilinear delta(u) of star table `table` (-1: none -> 0) in (theta, phi), phi periodic."""
    if table < 0:
        return 0.0
    # atan2(|u_xy|, u_z) == acos(u_z) for unit u, without acos's float32 error near the poles
    theta = wp.atan2(wp.sqrt(u[0] * u[0] + u[1] * u[1]), u[2])
    phi = wp.atan2(u[1], u[0])
    ti = theta * THETA_SCALE
    i0 = wp.clamp(int(wp.floor(ti)), 0, STAR_NT - 2)
    ft = wp.clamp(ti - float(i0), 0.0, 1.0)
    pj = (phi + PI) * PHI_SCALE
    j0f = wp.floor(pj)
    fp = wp.clamp(pj - j0f, 0.0, 1.0)
    j0 = ((int(j0f) % STAR_NP) + STAR_NP) % STAR_NP
    j1 = (j0 + 1) % STAR_NP
    a = (1.0 - fp) * star[table, i0, j0] + fp * star[table, i0, j1]
    b = (1.0 - fp) * star[table, i0 + 1, j0] + fp * star[table, i0 + 1, j1]
    return (1.0 - ft) * a + ft * b


@wp.func
def limit(D: wp.vec3, reach: float):
    """The drop-off limit (rig.skin.shell.shells.limit): |D| unchanged below reach / 2, saturating toward reach."""
    n = wp.length(D)
    if reach <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    x = n / reach
    if x <= LIMIT_KNEE:
        return D
    s = LIMIT_KNEE + (1.0 - LIMIT_KNEE) * wp.tanh((x - LIMIT_KNEE) / (1.0 - LIMIT_KNEE))
    return D * (reach * s / n)


@wp.func
def pull(p_l: wp.vec3, star: wp.array3d(dtype=wp.float32), table: int, s: float, h: float, d: float):
    """(q, rho) of a local point: q(p_l) = p_l + beta(rho) (r_s - r) u (unweighted) and the radius
    rho = r - delta(u) measured from the muscle surface. Below r = TINY_R there is no direction:
    u = 0, q = p_l."""
    r = wp.length(p_l)
    u = wp.vec3(0.0, 0.0, 0.0)
    if r >= TINY_R:
        u = p_l / r
    delta = star_delta(star, table, u)
    rho = r - delta
    r_s = 1.0 + delta + (1.0 - s) * d
    return p_l + (shell_beta(rho, h, d) * (r_s - r)) * u, rho


@wp.func
def shell_point(
    # model
    model: ShellArrays,
    # state in
    state: ShellState,
    ref: int,
    cur: int,
    v: int,
    p_in: wp.vec3,
):
    """Point p_in of vertex v with the vertex's pairs applied in series: p <- p + D_pair(p); metres.

    Muscle m's reference state is read at ref + m (E_ref, E_ref_inv, centre), its current state at
    cur + m (dE, E_cur_inv, active, the rows of curve): ref = cur = 0 for one frame; in a batch,
    ref = t * M for frame t and cur = (s * T + t) * M for set s at frame t.
    dE = E_cur - E_ref, formed in float64 by the wrapper (exactly 0 for a muscle at rest, and the
    stretch needs only the difference); centre = E_ref's translation. star_max[i] is the largest
    offset of star table i (an upper bound of delta for the early out).
    """
    p = p_in
    K = state.curve.shape[1]
    first, end = csr_span(model.pair_offsets, v)
    for i in range(first, end):
        m, pw = entry(model.pair_muscle, model.pair_weight, i)
        mr = ref + m
        mc = cur + m
        # inactive muscles (NaN CVs, degenerate frames) may hold NaN matrices: never read them
        if state.active[mc] != 0:
            d = model.drop_off[m]
            table = model.star_index[m]
            # beyond this local radius rho >= 1 + d for any direction: beta = alpha = 0 and D = 0.
            # Culling keeps a margin beyond the drop-off shell, so many pairs stop here, before the
            # star lookup (the most expensive part)
            reach = 1.0 + d
            if table >= 0:
                reach = reach + model.star_max[table]
            mo = model.mode[m]
            p_l = wp.transform_point(state.E_ref_inv[mr], p)
            r2 = wp.dot(p_l, p_l)
            D = wp.vec3(0.0, 0.0, 0.0)
            moved = False
            if mo == MODE_BASIC:
                pc_l = wp.transform_point(state.E_cur_inv[mc], p)
                if r2 < reach * reach or wp.dot(pc_l, pc_l) < reach * reach:
                    q, rho = pull(p_l, model.star, table, model.sticky[m], model.hard[m], d)
                    qc, rho_c = pull(pc_l, model.star, table, model.sticky[m], model.hard[m], d)
                    E_cur = state.E_ref[mr] + state.dE[mc]
                    D = wp.transform_point(E_cur, qc) - wp.transform_point(state.E_ref[mr], q)
                    moved = True
            elif r2 < reach * reach:
                q, rho = pull(p_l, model.star, table, model.sticky[m], model.hard[m], d)
                al = shell_alpha(rho, d)
                # a = 0 wherever alpha = 0 (also for l = 0): nothing beyond the drop-off shell moves
                a = float(0.0)
                if al > 0.0:
                    l = model.slippage[m]
                    a = al
                    if l != 1.0:    # pow is the costliest step of a pair; l = 1 is the default
                        a = wp.pow(al, l)
                    if mo == MODE_STRETCH:
                        # (E_cur - E_ref) (q, 1): the difference first, exactly 0 when they are equal
                        D = a * wp.transform_point(state.dE[mc], q)
                    else:
                        x = a * float(K - 1)
                        j = wp.min(int(x), K - 2)
                        f = x - float(j)
                        c0 = state.curve[mc, j]
                        c = c0 + f * (state.curve[mc, j + 1] - c0)
                        D = (c - state.curve[mc, 0]) + a * wp.transform_vector(state.dE[mc], q)
                    moved = True
            if moved:
                # the limit's reach, LIMIT_REACH x the drop-off distance along the point's direction
                # d |L_ref u| = d |p - c_ref| / r (L_ref p_l = p - c_ref): no second matrix product
                r = wp.sqrt(r2)
                reach_w = float(0.0)
                if r >= TINY_R:
                    reach_w = LIMIT_REACH * d * wp.length(p - state.centre[mr]) / r
                p = p + (model.weight[m] * pw) * limit(D, reach_w)
    return p


@wp.kernel
def shells(
    # model
    model: ShellArrays,
    # state in
    state: ShellState,
    points: wp.array(dtype=wp.vec3),
    # out
    points_out: wp.array(dtype=wp.vec3),
):
    """One frame, dim V: points_out[v] = points[v] with the vertex's pairs applied in series
    (:func:`shell_point`); the state arrays hold the M muscles of this frame."""
    v = wp.tid()
    points_out[v] = shell_point(model, state, 0, 0, v, points[v])


@wp.func
def shell_sets(
    # model
    model: ShellArrays,
    # state in
    state: ShellState,
    points: wp.array2d(dtype=wp.vec3),
    num_muscles: int,
    v: int,
    first_frame: int,
    frame_stride: int,
    # out
    p_io: wp.array3d(dtype=wp.vec3),
    i: int,
    displace: int,
):
    """Vertex v at frames t = first_frame, first_frame + frame_stride, ... < T for every set s (S, T =
    p_io.shape[0], points.shape[0]): points[t, v] with set s's muscles at frame t applied in series,
    each pair exactly as :func:`shell_point` applies it (ref = t * M, cur = (s * T + t) * M), written
    to p_io[s, t, v] (displace = 0), or its displacement from points[t, v] to p_io[s, i, t]
    (displace = 1; float32, the difference the host would form). p_io holds each set's point while
    the pairs run.

    A pair's reference part (the point in E_ref's space, its pull and fall-off, the limit's reach)
    depends only on the point and E_ref, which the sets share: it is computed once and reused by
    every set whose point is still the same (bit for bit; always at a vertex's first pair), so the
    result is the same as the set-by-set loop and the star lookup runs once instead of S times.
    The pairs run in the outer loop and the frames in the inner one (each frame's sets in series
    over the pairs as before): a pair's parameters are read once per vertex, not once per frame, and
    one call runs all of a vertex's frames (a Warp function takes its structs by value).
    """
    S = p_io.shape[0]
    T = points.shape[0]
    K = state.curve.shape[1]
    for t in range(first_frame, T, frame_stride):
        x = t
        y = v
        if displace != 0:
            x = i
            y = t
        p_in = points[t, v]
        for s in range(S):
            p_io[s, x, y] = p_in
    first, end = csr_span(model.pair_offsets, v)
    for k in range(first, end):
        m, pw = entry(model.pair_muscle, model.pair_weight, k)
        d = model.drop_off[m]
        table = model.star_index[m]
        # beyond this local radius rho >= 1 + d for any direction: beta = alpha = 0 and D = 0
        reach = 1.0 + d
        if table >= 0:
            reach = reach + model.star_max[table]
        mo = model.mode[m]
        for t in range(first_frame, T, frame_stride):
            x = t
            y = v
            if displace != 0:
                x = i
                y = t
            mr = t * num_muscles + m
            # the reference part, for the point p_c (have_l: p_l, r2; have_q: the pull; have_w: the limit's reach)
            have_l = int(0)
            have_q = int(0)
            have_w = int(0)
            p_c = wp.vec3(0.0, 0.0, 0.0)
            p_l = wp.vec3(0.0, 0.0, 0.0)
            r2 = float(0.0)
            reach_w = float(0.0)
            q = wp.vec3(0.0, 0.0, 0.0)
            Eq = wp.vec3(0.0, 0.0, 0.0)
            a = float(0.0)
            for s in range(S):
                mc = (s * T + t) * num_muscles + m
                # inactive muscles (NaN CVs, degenerate frames) may hold NaN matrices: never read them
                if state.active[mc] != 0:
                    p = p_io[s, x, y]
                    if have_l == 0 or p[0] != p_c[0] or p[1] != p_c[1] or p[2] != p_c[2]:
                        p_c = p
                        have_l = 1
                        have_q = 0
                        p_l = wp.transform_point(state.E_ref_inv[mr], p)
                        r2 = wp.dot(p_l, p_l)
                        have_w = 0
                    D = wp.vec3(0.0, 0.0, 0.0)
                    moved = False
                    if mo == MODE_BASIC:
                        pc_l = wp.transform_point(state.E_cur_inv[mc], p)
                        if r2 < reach * reach or wp.dot(pc_l, pc_l) < reach * reach:
                            if have_q == 0:
                                q0, rho0 = pull(p_l, model.star, table, model.sticky[m], model.hard[m], d)
                                q = q0
                                Eq = wp.transform_point(state.E_ref[mr], q0)
                                have_q = 1
                            qc, rho_c = pull(pc_l, model.star, table, model.sticky[m], model.hard[m], d)
                            E_cur = state.E_ref[mr] + state.dE[mc]
                            D = wp.transform_point(E_cur, qc) - Eq
                            moved = True
                    elif r2 < reach * reach:
                        if have_q == 0:
                            q1, rho = pull(p_l, model.star, table, model.sticky[m], model.hard[m], d)
                            q = q1
                            al = shell_alpha(rho, d)
                            # a = 0 wherever alpha = 0 (also for l = 0): nothing beyond the drop-off shell moves
                            a = float(0.0)
                            if al > 0.0:
                                l = model.slippage[m]
                                a = al
                                if l != 1.0:    # pow is the costliest step of a pair; l = 1 is the default
                                    a = wp.pow(al, l)
                            have_q = 1
                        if a > 0.0:
                            if mo == MODE_STRETCH:
                                # (E_cur - E_ref) (q, 1): the difference first, exactly 0 when they are equal
                                D = a * wp.transform_point(state.dE[mc], q)
                            else:
                                xk = a * float(K - 1)
                                j = wp.min(int(xk), K - 2)
                                f = xk - float(j)
                                c0 = state.curve[mc, j]
                                c = c0 + f * (state.curve[mc, j + 1] - c0)
                                D = (c - state.curve[mc, 0]) + a * wp.transform_vector(state.dE[mc], q)
                            moved = True
                    if moved:
                        if have_w == 0:
                            # the limit's reach, LIMIT_REACH x the drop-off distance along the point's
                            # direction d |L_ref u| = d |p - c_ref| / r (L_ref p_l = p - c_ref)
                            r = wp.sqrt(r2)
                            reach_w = float(0.0)
                            if r >= TINY_R:
                                reach_w = LIMIT_REACH * d * wp.length(p - state.centre[mr]) / r
                            have_w = 1
                        p_io[s, x, y] = p + (model.weight[m] * pw) * limit(D, reach_w)
    if displace != 0:
        for t in range(first_frame, T, frame_stride):
            p_in = points[t, v]
            for s in range(S):
                p_io[s, i, t] = p_io[s, i, t] - p_in


@wp.kernel
def shells_batch(
    # model
    model: ShellArrays,
    paired: wp.array(dtype=wp.int32),
    num_muscles: int,
    frame_stride: int,
    # state in
    state: ShellState,
    points: wp.array2d(dtype=wp.vec3),
    # out
    points_out: wp.array3d(dtype=wp.vec3),
):
    """S sets x T frames (S, T = points_out.shape[:2]) in one launch, dim (B, P) over the P vertices
    owning pairs (`paired`): thread (b, i) deforms vertex v = paired[i] at frames t = b, b + B, ...
    (B = frame_stride) for every set s: points_out[s, t, v] is points[t, v] (frame t's skinned points,
    shared by the sets) with set s's muscles at frame t applied (:func:`shell_sets`). The wrapper has
    copied the smooth skin into points_out for the vertices no muscle moves, and picks B = 1 on the
    CPU (a thread runs its vertex through every frame and set: no index division per item, the
    vertex's pairs stay in cache) and B = T on a GPU.

    E_ref, E_ref_inv, centre : (T * M,) the frames' reference state, shared by the sets.
    dE, E_cur_inv, active : (S * T * M,); curve : (S * T * M, K): set s, frame t, muscle m at
    (s * T + t) * M + m.
    """
    b, i = wp.tid()
    shell_sets(model, state, points, num_muscles, paired[i], b, frame_stride, points_out, i, 0)


@wp.kernel
def shells_displace(
    # model
    model: ShellArrays,
    paired: wp.array(dtype=wp.int32),
    num_muscles: int,
    frame_stride: int,
    # state in
    state: ShellState,
    points: wp.array2d(dtype=wp.vec3),
    # out
    moved_out: wp.array3d(dtype=wp.vec3),
):
    """As :func:`shells_batch`, but only the paired vertices' displacements from the smooth skin:
    moved_out[s, i, t] = deformed - points[t, paired[i]] (float32, the same difference the host would
    form), (S, P, T): for each set, the vertices as rows and the frames' xyz side by side, the layout
    the surface spread smooths (rig.skin.surface_smoothing.SurfaceSmoothing.spread_front)."""
    b, i = wp.tid()
    shell_sets(model, state, points, num_muscles, paired[i], b, frame_stride, moved_out, i, 1)
