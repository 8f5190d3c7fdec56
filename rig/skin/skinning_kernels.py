"""Warp kernels for skinning: linear blend (LBS) and dual-quaternion (DQS).

Each kernel does one thing on flat arrays; the launch wrapper is :class:`rig.skin.skinning.Skinner`,
the NumPy references are :func:`rig.skin.skinning.lbs_numpy` and :func:`rig.skin.skinning.dqs_numpy`.
Everything is float32. Influences are flat: vertex ``v`` owns entries ``v*k .. v*k + k - 1`` of
``joints`` and ``weights``. Quaternions here are Warp's ``wp.quat`` (x, y, z, w).

The per-vertex maths is one ``@wp.func`` per method (:func:`lbs_point`, :func:`dqs_point`), shared by
the single-frame kernels (dim V) and the batched ones (T frames in one launch, the frames' matrices
or dual quaternions flattened to (T * J,) and read from ``t * J``). A vertex's influences are read
through rig/skin/gather_kernels.py, as in the shell and influence kernels.
"""
from __future__ import annotations

import warp as wp

from jiggle.rig.skin.gather_kernels import entry, fixed_span


@wp.func
def lbs_point(
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    matrices: wp.array(dtype=wp.mat44),
    base: int,
    v: int,
):
    """sum_i w_i * (M_{base + j_i} @ [rest[v], 1])[:3], metres: vertex v skinned by the matrices
    matrices[base .. base + J - 1] (base = 0 for one frame, t * J for frame t of a batch)."""
    p = rest[v]
    acc = wp.vec3(0.0, 0.0, 0.0)
    first, end = fixed_span(k, v)
    for e in range(first, end):
        j, w = entry(joints, weights, e)
        # padded influences (weight 0) are common after top-k; skipping them saves the matrix load
        if w != 0.0:
            acc += w * wp.transform_point(matrices[base + j], p)
    return acc


@wp.kernel
def lbs(
    # model
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    # state in
    matrices: wp.array(dtype=wp.mat44),
    # out
    positions_out: wp.array(dtype=wp.vec3),
):
    """positions_out[v] = sum_i w_i * (M_{j_i} @ [rest[v], 1])[:3]; metres."""
    v = wp.tid()
    positions_out[v] = lbs_point(rest, joints, weights, k, matrices, 0, v)


@wp.kernel
def lbs_batch(
    # model
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    # state in
    matrices: wp.array(dtype=wp.mat44),
    num_joints: int,
    frame_stride: int,
    # out
    positions_out: wp.array2d(dtype=wp.vec3),
):
    """LBS of T = positions_out.shape[0] frames, dim (B, V): thread (b, v) skins vertex v at frames
    t = b, b + B, ... (B = frame_stride), frame t reading matrices[t * num_joints ..] (the (T, J) skin
    matrices flattened) and writing positions_out[t, v]; metres. The wrapper picks B = 1 on the CPU
    (a thread runs its vertex through every frame: no index division per (frame, vertex)) and B = T
    on a GPU (a thread per frame and vertex)."""
    b, v = wp.tid()
    for t in range(b, positions_out.shape[0], frame_stride):
        positions_out[t, v] = lbs_point(rest, joints, weights, k, matrices, t * num_joints, v)


@wp.kernel
def dual_quats_from_matrices(
    # state in
    matrices: wp.array(dtype=wp.mat44),
    # out
    real_out: wp.array(dtype=wp.quat),
    dual_out: wp.array(dtype=wp.quat),
):
    """Unit dual quaternion (real, dual) of each skin matrix's rigid part.

    The rotation is the polar factor of the upper 3x3 block (exporters leave scales of 1 +- 1e-6
    there, and quat_from_matrix needs an orthonormal matrix); a mirrored block (det < 0) gets the
    nearest rotation, its smallest singular direction flipped. dual = 0.5 * (t, 0) * real.
    """
    j = wp.tid()
    m = matrices[j]
    a = wp.mat33(m[0, 0], m[0, 1], m[0, 2],
                 m[1, 0], m[1, 1], m[1, 2],
                 m[2, 0], m[2, 1], m[2, 2])
    u = wp.mat33()
    sigma = wp.vec3()
    vm = wp.mat33()
    # Warp's svd3 returns proper rotations U, V and signed singular values sorted by magnitude,
    # so U V^T is the polar factor, and for a mirror the rotation nearest to it
    wp.svd3(a, u, sigma, vm)
    r = u * wp.transpose(vm)
    q = wp.quat_from_matrix(r)
    t = wp.quat(m[0, 3], m[1, 3], m[2, 3], 0.0)
    real_out[j] = q
    dual_out[j] = 0.5 * (t * q)


@wp.func
def dqs_point(
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    real: wp.array(dtype=wp.quat),
    dual: wp.array(dtype=wp.quat),
    base: int,
    v: int,
):
    """Vertex v skinned by the dual quaternions real/dual[base .. base + J - 1] (metres).

    The first influence of each vertex must be its largest (the wrapper sorts them): the other
    joints' quaternions are flipped into its hemisphere so the blend takes the short way round.
    """
    first, end = fixed_span(k, v)
    pivot = real[base + joints[first]]
    br = wp.quat(0.0, 0.0, 0.0, 0.0)
    bd = wp.quat(0.0, 0.0, 0.0, 0.0)
    for e in range(first, end):
        jj, w = entry(joints, weights, e)
        j = base + jj
        if wp.dot(real[j], pivot) < 0.0:
            w = -w
        br += w * real[j]
        bd += w * dual[j]
    n = wp.length(br)
    r = br / n
    d = bd / n
    rv = wp.vec3(r[0], r[1], r[2])
    dv = wp.vec3(d[0], d[1], d[2])
    # translation = vector part of 2 * d * conj(r); exact for the blended, non-unit dual part too
    t = 2.0 * (r[3] * dv - d[3] * rv + wp.cross(rv, dv))
    return wp.quat_rotate(r, rest[v]) + t


@wp.kernel
def dqs(
    # model
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    # state in
    real: wp.array(dtype=wp.quat),
    dual: wp.array(dtype=wp.quat),
    # out
    positions_out: wp.array(dtype=wp.vec3),
):
    """Dual-quaternion skinning of rest positions (metres), see :func:`dqs_point`."""
    v = wp.tid()
    positions_out[v] = dqs_point(rest, joints, weights, k, real, dual, 0, v)


@wp.kernel
def dqs_batch(
    # model
    rest: wp.array(dtype=wp.vec3),
    joints: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    k: int,
    # state in
    real: wp.array(dtype=wp.quat),
    dual: wp.array(dtype=wp.quat),
    num_joints: int,
    frame_stride: int,
    # out
    positions_out: wp.array2d(dtype=wp.vec3),
):
    """DQS of T = positions_out.shape[0] frames, dim (B, V), frames as in :func:`lbs_batch`: frame t
    reads real/dual[t * num_joints ..] (the (T, J) dual quaternions flattened, from
    :func:`dual_quats_from_matrices` over the T * J matrices)."""
    b, v = wp.tid()
    for t in range(b, positions_out.shape[0], frame_stride):
        positions_out[t, v] = dqs_point(rest, joints, weights, k, real, dual, t * num_joints, v)
