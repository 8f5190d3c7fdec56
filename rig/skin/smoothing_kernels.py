"""Warp kernels of the surface spread on a GPU (rig.skin.surface_smoothing.SurfaceSmoothing.spread_device).

The same arithmetic as the CPU's spread_front + scatter (SciPy's CSR product, then smooth + displacement),
laid out for a GPU: a thread per (row, frame) of each step's front, the xyz of a vertex together.
"""
import warp as wp


@wp.kernel
def front_step(indptr: wp.array(dtype=wp.int32), indices: wp.array(dtype=wp.int32), data: wp.array(dtype=wp.float32),
               x: wp.array2d(dtype=wp.vec3), y: wp.array2d(dtype=wp.vec3)):
    """One step of the spread on its front: y[r, t] = sum over row r's entries e (stored order) of
    data[e] x[indices[e], t]. x (rows of the last front, T), y (rows of this front, T) displacements, m."""
    r, t = wp.tid()
    s = wp.vec3(0.0)
    for e in range(indptr[r], indptr[r + 1]):
        s += data[e] * x[indices[e], t]
    y[r, t] = s


@wp.kernel
def add_spread(smooth: wp.array2d(dtype=wp.vec3), order: wp.array(dtype=wp.int32), d: wp.array2d(dtype=wp.vec3),
               out: wp.array2d(dtype=wp.vec3)):
    """out[t, order[r]] = smooth[t, order[r]] + d[r, t]: the spread displacement (R, T) of the rows, in
    `order`, added to the smooth skin (T, V); out holds a copy of the smooth skin elsewhere."""
    r, t = wp.tid()
    v = order[r]
    out[t, v] = smooth[t, v] + d[r, t]
