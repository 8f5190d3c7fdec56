"""Warp kernels of rig.skin.delta_mush: Laplacian smoothing steps and the delta encode / decode, for
many frames at once (dim (T, V): one thread per vertex and frame).

A vertex's frame on the smoothed mesh: n the area-weighted normal of the faces around it, t the edge
to its first neighbour projected off n, b = n x t. Float32 like the skinning it follows; the NumPy
reference is in tests/skin/test_delta_mush.py.
"""
import warp as wp


@wp.kernel
def smooth_step(points: wp.array2d(dtype=wp.vec3), offsets: wp.array(dtype=wp.int32),
                neighbours: wp.array(dtype=wp.int32), step: float, out: wp.array2d(dtype=wp.vec3)):
    """points (T, V) metres; offsets (V + 1,) / neighbours: each vertex's edge neighbours (CSR);
    step in (0, 1] -> out (T, V): p + step (mean of the neighbours - p); a lone vertex stays."""
    t, v = wp.tid()
    p = points[t, v]
    a, b = offsets[v], offsets[v + 1]
    if b == a:
        out[t, v] = p
        return
    s = wp.vec3(0.0, 0.0, 0.0)
    for k in range(a, b):
        s += points[t, neighbours[k]]
    out[t, v] = p + step * (s / float(b - a) - p)


@wp.func
def vertex_frame(points: wp.array2d(dtype=wp.vec3), t: int, v: int, faces: wp.array(dtype=wp.vec3i),
                 face_offsets: wp.array(dtype=wp.int32), face_of: wp.array(dtype=wp.int32),
                 tangent_to: int) -> wp.mat33:
    """Columns (t, b, n) of vertex v's frame at frame t of the smoothed points; the zero matrix when the
    normal or the tangent vanishes (the caller then leaves the vertex as it was)."""
    n = wp.vec3(0.0, 0.0, 0.0)
    for k in range(face_offsets[v], face_offsets[v + 1]):
        f = faces[face_of[k]]
        p0 = points[t, f[0]]
        n += wp.cross(points[t, f[1]] - p0, points[t, f[2]] - p0)
    ln = wp.length(n)
    if ln <= 0.0 or tangent_to < 0:
        return wp.mat33(0.0)
    n = n / ln
    e = points[t, tangent_to] - points[t, v]
    e = e - wp.dot(e, n) * n
    le = wp.length(e)
    if le <= 0.0:
        return wp.mat33(0.0)
    e = e / le
    b = wp.cross(n, e)
    return wp.mat33(e[0], b[0], n[0], e[1], b[1], n[1], e[2], b[2], n[2])


@wp.kernel
def encode(points: wp.array2d(dtype=wp.vec3), smoothed: wp.array2d(dtype=wp.vec3),
           faces: wp.array(dtype=wp.vec3i), face_offsets: wp.array(dtype=wp.int32),
           face_of: wp.array(dtype=wp.int32), tangent_to: wp.array(dtype=wp.int32),
           delta_out: wp.array(dtype=wp.vec3), ok_out: wp.array(dtype=wp.int32)):
    """dim (1, V). points, smoothed (1, V) metres: the rest mesh and its smoothing -> delta_out (V,):
    points - smoothed in the vertex's frame; ok_out (V,): 1 where the frame exists."""
    t, v = wp.tid()
    F = vertex_frame(smoothed, t, v, faces, face_offsets, face_of, tangent_to[v])
    if F[2, 2] == 0.0 and F[0, 2] == 0.0 and F[1, 2] == 0.0:
        delta_out[v] = wp.vec3(0.0, 0.0, 0.0)
        ok_out[v] = 0
        return
    delta_out[v] = wp.transpose(F) @ (points[t, v] - smoothed[t, v])
    ok_out[v] = 1


@wp.kernel
def decode(points: wp.array2d(dtype=wp.vec3), smoothed: wp.array2d(dtype=wp.vec3),
           faces: wp.array(dtype=wp.vec3i), face_offsets: wp.array(dtype=wp.int32),
           face_of: wp.array(dtype=wp.int32), tangent_to: wp.array(dtype=wp.int32),
           delta: wp.array(dtype=wp.vec3), ok: wp.array(dtype=wp.int32), weight: wp.array(dtype=wp.float32),
           out: wp.array2d(dtype=wp.vec3)):
    """points (T, V) the skinned mesh, smoothed (T, V) its smoothing, delta / ok (V,) from encode,
    weight (V,) in [0, 1] -> out (T, V) = points + weight (smoothed + F delta - points); a vertex
    without a frame (at rest or now) keeps its skinned position."""
    t, v = wp.tid()
    p = points[t, v]
    w = weight[v]
    if ok[v] == 0 or w <= 0.0:
        out[t, v] = p
        return
    F = vertex_frame(smoothed, t, v, faces, face_offsets, face_of, tangent_to[v])
    if F[2, 2] == 0.0 and F[0, 2] == 0.0 and F[1, 2] == 0.0:
        out[t, v] = p
        return
    mushed = smoothed[t, v] + F @ delta[v]
    out[t, v] = p + w * (mushed - p)
