"""Warp kernel of the influence-object deformer; the launch wrapper is :class:`rig.skin.influence.InfluenceDeformer`,
the NumPy reference :func:`rig.skin.influence.influence_numpy`.

Everything is float32. Pairs (vertex, muscle) are CSR: vertex ``i`` owns pairs
``pair_offsets[i] .. pair_offsets[i + 1] - 1``. Muscle ``m`` owns CVs ``40 m .. 40 m + 39`` of the flat
CV arrays, section-major (section ``k``, ring CV ``j`` at ``8 k + j``).

A pair's loft parameters (w, v) are fixed at bind, so its basis is precomputed there (see
:class:`rig.muscle.loft_attach.InfluenceBinding`): the 5 section weights of the not-a-knot spline at w and their
d/dw, and the 4 non-zero weights of the periodic cubic ring basis at v (and d/dv) with the ring index
of the first (``ring0``). The kernel then evaluates, per section k,
``R_k = sum_r ring[r] CV[k, (ring0 + r) mod 8]`` (and ``Rv_k`` with ``ring_dv``) and
``X = sum_k sec[k] R_k``, ``Xw = sum_k sec_dw[k] R_k``, ``Xv = sum_k sec[k] Rv_k``.
"""
from __future__ import annotations

import warp as wp

from jiggle.rig.skin.gather_kernels import csr_span, entry
from jiggle.rig.skin.shell.kernels import limit


@wp.func
def frame_apply(xw: wp.vec3, xv: wp.vec3, eps: float, offset: wp.vec3):
    """offset (along e1, e2, n) in the loft frame e1 = unit(Xw), n = unit(Xv x Xw) (outward),
    e2 = n x e1, as a world vector. An axis is 0 where its vector is too short to normalise: e1 when
    |Xw| <= eps, n when |Xv x Xw| <= eps |Xw| (the ring's tangent across Xw under eps); eps is the
    muscle's FRAME_EPS x size (rig.muscle.loft_attach.loft_frame does the same)."""
    lw = wp.length(xw)
    e1 = wp.vec3(0.0, 0.0, 0.0)
    n = wp.vec3(0.0, 0.0, 0.0)
    if lw > eps:
        e1 = xw / lw
        c = wp.cross(xv, xw)
        lc = wp.length(c)
        if lc > eps * lw:
            n = c / lc
    e2 = wp.cross(n, e1)
    return offset[0] * e1 + offset[1] * e2 + offset[2] * n


@wp.func
def influence_point(
    # model
    pair_offsets: wp.array(dtype=wp.int32),
    pair_muscle: wp.array(dtype=wp.int32),
    pair_weight: wp.array(dtype=wp.float32),
    section: wp.array2d(dtype=wp.float32),
    section_dw: wp.array2d(dtype=wp.float32),
    ring_first: wp.array(dtype=wp.int32),
    ring: wp.array2d(dtype=wp.float32),
    ring_dv: wp.array2d(dtype=wp.float32),
    offset: wp.array(dtype=wp.vec3),
    muscle_eps: wp.array(dtype=wp.float32),
    reach: wp.array(dtype=wp.float32),
    # state in
    cvs_cur: wp.array(dtype=wp.vec3),
    cur0: int,
    cvs_ref: wp.array(dtype=wp.vec3),
    ref0: int,
    i: int,
):
    """sum over vertex i's pairs of weight * limit(attach(cur) - attach(ref), reach[m]), metres, the CVs
    read from cvs_cur[cur0 ..] and cvs_ref[ref0 ..] (0 for one frame; a frame's and set's (40 M,)
    block in a batch). See :func:`influence_displace`."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    first, end = csr_span(pair_offsets, i)
    for p in range(first, end):
        m, weight = entry(pair_muscle, pair_weight, p)
        if weight != 0.0:
            base = m * 40
            ring0 = ring_first[p]
            c0 = cvs_cur[cur0 + base]
            f0 = cvs_ref[ref0 + base]
            dx = wp.vec3(0.0, 0.0, 0.0)
            xw_cur = wp.vec3(0.0, 0.0, 0.0)
            xv_cur = wp.vec3(0.0, 0.0, 0.0)
            xw_ref = wp.vec3(0.0, 0.0, 0.0)
            xv_ref = wp.vec3(0.0, 0.0, 0.0)
            for k in range(5):
                r_cur = wp.vec3(0.0, 0.0, 0.0)
                r_ref = wp.vec3(0.0, 0.0, 0.0)
                rv_cur = wp.vec3(0.0, 0.0, 0.0)
                rv_ref = wp.vec3(0.0, 0.0, 0.0)
                for r in range(4):
                    j = base + 8 * k + (ring0 + r) % 8
                    c = cvs_cur[cur0 + j] - c0
                    f = cvs_ref[ref0 + j] - f0
                    r_cur += ring[p, r] * c
                    r_ref += ring[p, r] * f
                    rv_cur += ring_dv[p, r] * c
                    rv_ref += ring_dv[p, r] * f
                # the section and ring weights each sum to 1: X = c0 + sum (section * ring) (CV - c0)
                dx += section[p, k] * (r_cur - r_ref)
                xw_cur += section_dw[p, k] * r_cur
                xw_ref += section_dw[p, k] * r_ref
                xv_cur += section[p, k] * rv_cur
                xv_ref += section[p, k] * rv_ref
            o = offset[p]
            eps = muscle_eps[m]
            D = c0 - f0 + dx + frame_apply(xw_cur, xv_cur, eps, o) - frame_apply(xw_ref, xv_ref, eps, o)
            acc += weight * limit(D, reach[m])
    return acc


@wp.kernel
def influence_displace(
    # model
    pair_offsets: wp.array(dtype=wp.int32),
    pair_muscle: wp.array(dtype=wp.int32),
    pair_weight: wp.array(dtype=wp.float32),
    section: wp.array2d(dtype=wp.float32),
    section_dw: wp.array2d(dtype=wp.float32),
    ring_first: wp.array(dtype=wp.int32),
    ring: wp.array2d(dtype=wp.float32),
    ring_dv: wp.array2d(dtype=wp.float32),
    offset: wp.array(dtype=wp.vec3),
    muscle_eps: wp.array(dtype=wp.float32),
    reach: wp.array(dtype=wp.float32),
    # state in
    points: wp.array(dtype=wp.vec3),
    cvs_cur: wp.array(dtype=wp.vec3),
    cvs_ref: wp.array(dtype=wp.vec3),
    # out
    positions_out: wp.array(dtype=wp.vec3),
):
    """positions_out[i] = points[i] + sum_pairs weight * limit(attach(cvs_cur) - attach(cvs_ref), reach[m]),
    metres, attach = X(w, v) + offset in the loft frame at (w, v), limit the shells' drop-off limit
    (rig.skin.shell.kernels.limit) with the muscle's reach.

    The point part is evaluated on the CV differences (X is linear in the CVs), and the derivatives
    on CVs relative to the muscle's first CV (their weights sum to 0): in float32 that keeps the
    result exact to the size of the muscle and its motion rather than to the distance from the
    origin, and exactly 0 where cvs_cur == cvs_ref.
    """
    i = wp.tid()
    positions_out[i] = points[i] + influence_point(pair_offsets, pair_muscle, pair_weight, section, section_dw,
                                                   ring_first, ring, ring_dv, offset, muscle_eps, reach,
                                                   cvs_cur, 0, cvs_ref, 0, i)


mat53 = wp.types.matrix(shape=(5, 3), dtype=wp.float32)


@wp.kernel
def influence_batch(
    # model
    pair_offsets: wp.array(dtype=wp.int32),
    pair_muscle: wp.array(dtype=wp.int32),
    pair_weight: wp.array(dtype=wp.float32),
    section: wp.array2d(dtype=wp.float32),
    section_dw: wp.array2d(dtype=wp.float32),
    ring_first: wp.array(dtype=wp.int32),
    ring: wp.array2d(dtype=wp.float32),
    ring_dv: wp.array2d(dtype=wp.float32),
    offset: wp.array(dtype=wp.vec3),
    muscle_eps: wp.array(dtype=wp.float32),
    reach: wp.array(dtype=wp.float32),
    paired: wp.array(dtype=wp.int32),
    frame_stride: int,
    displace: int,
    # state in
    points: wp.array2d(dtype=wp.vec3),
    cvs_cur: wp.array(dtype=wp.vec3),
    cvs_ref: wp.array(dtype=wp.vec3),
    # out
    out: wp.array3d(dtype=wp.vec3),
):
    """S sets x T frames in one launch, dim (B, P) over the P vertices owning pairs (`paired`):
    thread (b, j) runs vertex v = paired[j] at frames t = b, b + B, ... for every set s, each as
    :func:`influence_displace` with points[t] (shared by the sets), set s's CVs at frame t
    (cvs_cur[(s * T + t) * N ..], N = 40 M) and frame t's carried rest CVs (cvs_ref[t * N ..]).
    displace = 0: out (S, T, V), out[s, t, v] = the displaced point (the wrapper copied the smooth skin
    to the other vertices); 1: out (S, P, T), out[s, j, t] = displaced - points[t, v] (float32, the
    difference the host would form: the spread's layout).

    The same sums in the same order as :func:`influence_point`, with the pairs in the outer loop: a
    pair's reference part (its ring sums on the carried rest CVs, their derivatives and the rest
    frame's offset) is computed once per frame for all sets; out holds each set's running sum."""
    b, jj = wp.tid()
    v = paired[jj]
    T = points.shape[0]
    S = out.shape[0]
    N = cvs_ref.shape[0] // T
    for t in range(b, T, frame_stride):
        for s in range(S):
            if displace != 0:
                out[s, jj, t] = wp.vec3(0.0, 0.0, 0.0)
            else:
                out[s, t, v] = wp.vec3(0.0, 0.0, 0.0)
    first, end = csr_span(pair_offsets, v)
    for p in range(first, end):
        m, weight = entry(pair_muscle, pair_weight, p)
        if weight != 0.0:
            base = m * 40
            ring0 = ring_first[p]
            o = offset[p]
            eps = muscle_eps[m]
            for t in range(b, T, frame_stride):
                ref0 = t * N
                f0 = cvs_ref[ref0 + base]
                r_ref = mat53()
                xw_ref = wp.vec3(0.0, 0.0, 0.0)
                xv_ref = wp.vec3(0.0, 0.0, 0.0)
                for k in range(5):
                    rr = wp.vec3(0.0, 0.0, 0.0)
                    rv = wp.vec3(0.0, 0.0, 0.0)
                    for r in range(4):
                        f = cvs_ref[ref0 + base + 8 * k + (ring0 + r) % 8] - f0
                        rr += ring[p, r] * f
                        rv += ring_dv[p, r] * f
                    r_ref[k] = rr
                    xw_ref += section_dw[p, k] * rr
                    xv_ref += section[p, k] * rv
                fa_ref = frame_apply(xw_ref, xv_ref, eps, o)
                for s in range(S):
                    cur0 = (s * T + t) * N
                    c0 = cvs_cur[cur0 + base]
                    dx = wp.vec3(0.0, 0.0, 0.0)
                    xw_cur = wp.vec3(0.0, 0.0, 0.0)
                    xv_cur = wp.vec3(0.0, 0.0, 0.0)
                    for k in range(5):
                        r_cur = wp.vec3(0.0, 0.0, 0.0)
                        rv_cur = wp.vec3(0.0, 0.0, 0.0)
                        for r in range(4):
                            c = cvs_cur[cur0 + base + 8 * k + (ring0 + r) % 8] - c0
                            r_cur += ring[p, r] * c
                            rv_cur += ring_dv[p, r] * c
                        dx += section[p, k] * (r_cur - r_ref[k])
                        xw_cur += section_dw[p, k] * r_cur
                        xv_cur += section[p, k] * rv_cur
                    D = c0 - f0 + dx + frame_apply(xw_cur, xv_cur, eps, o) - fa_ref
                    add = weight * limit(D, reach[m])
                    if displace != 0:
                        out[s, jj, t] = out[s, jj, t] + add
                    else:
                        out[s, t, v] = out[s, t, v] + add
    for t in range(b, T, frame_stride):
        p_in = points[t, v]
        for s in range(S):
            if displace != 0:
                out[s, jj, t] = (p_in + out[s, jj, t]) - p_in
            else:
                out[s, t, v] = p_in + out[s, t, v]
