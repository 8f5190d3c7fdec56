"""Warp kernel of rig.character.normals: area-weighted vertex normals of many frames, gathered per vertex.

Each thread owns one vertex of one frame and sums the raw cross products of the faces around it
(CSR lists, the rows of VertexNormals.incidence), in float64 like the NumPy path; no atomics, so the
sum's order, and the result, are the same on every device and every run.
"""
import warp as wp


@wp.kernel
def gather_normals(points: wp.array2d(dtype=wp.vec3), faces: wp.array(dtype=wp.vec3i),
                   offsets: wp.array(dtype=wp.int32), face_of: wp.array(dtype=wp.int32),
                   fallback: wp.vec3d, out: wp.array2d(dtype=wp.vec3)):
    """points (T, V) metres, faces (F,), offsets (V + 1,) / face_of: faces around each vertex ->
    out (T, V) unit normals (fallback where the sum vanishes)."""
    t, v = wp.tid()
    n = wp.vec3d(0.0, 0.0, 0.0)
    for k in range(offsets[v], offsets[v + 1]):
        f = faces[face_of[k]]
        p0 = wp.vec3d(points[t, f[0]])
        e1 = wp.vec3d(points[t, f[1]]) - p0
        e2 = wp.vec3d(points[t, f[2]]) - p0
        n += wp.cross(e1, e2)
    length = wp.length(n)
    if length > wp.float64(0.0):
        out[t, v] = wp.vec3(n / length)
    else:
        out[t, v] = wp.vec3(fallback)
