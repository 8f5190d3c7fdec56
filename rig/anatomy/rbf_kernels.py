"""Warp kernel of the precomputed zoned RBF skin; the launch wrapper is :class:`rig.anatomy.rbf.RBFSkinner`,
the NumPy reference :meth:`rig.anatomy.rbf.ZoneRBF.apply`.

Each skin vertex is a fixed linear combination of the current feature positions,
``out[t, v] = sum_j weight[v, j] * points[t, index[v, j]]``, whose weights sum to 1 (they reproduce
affine maps). Float32 throughout.
"""
from __future__ import annotations

import warp as wp


@wp.kernel
def rbf_gather(
    # model
    index: wp.array2d(dtype=wp.int32),
    weight: wp.array2d(dtype=wp.float32),
    # state in
    points: wp.array2d(dtype=wp.vec3),
    # out
    positions_out: wp.array2d(dtype=wp.vec3),
):
    """positions_out[t, v] = sum_j weight[v, j] points[t, index[v, j]], metres; launch dim (T, V).

    Evaluated as ``p0 + sum_j weight[v, j] (points[t, index[v, j]] - p0)`` with p0 the feature of the
    largest weight (index[v, 0]): equal since the weights sum to 1, and in float32 the rounding then
    scales with the size of the vertex's neighbourhood rather than with its distance from the origin
    (padded entries have weight 0 and add nothing).
    """
    t, v = wp.tid()
    p0 = points[t, index[v, 0]]
    acc = wp.vec3(0.0, 0.0, 0.0)
    for j in range(index.shape[1]):
        acc += weight[v, j] * (points[t, index[v, j]] - p0)
    positions_out[t, v] = p0 + acc
