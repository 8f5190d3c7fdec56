"""Warp kernels of rig.skin.quality: per-edge and per-face measures of many frames of one mesh.

Each thread owns one face (or edge) of one frame; the reductions (counts, percentiles) run in NumPy
over the (T, F) and (T, E) results. Float32 throughout: the measures are thresholds and percentiles,
and this runs on every frame of every bake's report (tests/skin/test_quality.py holds them to a
float64 NumPy reference).
"""
import warp as wp


@wp.kernel
def face_measures(points: wp.array2d(dtype=wp.vec3), faces: wp.array(dtype=wp.vec3i),
                  rest_area: wp.array(dtype=wp.float32),
                  normal_out: wp.array2d(dtype=wp.vec3), area_out: wp.array2d(dtype=wp.float32)):
    """points (T, V) metres; faces (F,); rest_area (F,) m^2 -> normal_out (T, F): unit normals
    ((0, 0, 0) for a degenerate face); area_out (T, F): area / rest area."""
    t, i = wp.tid()
    f = faces[i]
    p0 = points[t, f[0]]
    n = wp.cross(points[t, f[1]] - p0, points[t, f[2]] - p0)
    length = wp.length(n)
    area_out[t, i] = 0.5 * length / rest_area[i]
    if length > 0.0:
        normal_out[t, i] = n / length
    else:
        normal_out[t, i] = wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def edge_measures(points: wp.array2d(dtype=wp.vec3), normals: wp.array2d(dtype=wp.vec3),
                  edges: wp.array(dtype=wp.vec2i), edge_faces: wp.array(dtype=wp.vec2i),
                  rest_length: wp.array(dtype=wp.float32),
                  cos_out: wp.array2d(dtype=wp.float32), strain_out: wp.array2d(dtype=wp.float32)):
    """points (T, V) metres; normals (T, F) the faces' unit normals (face_measures); edges (E,) vertex
    pairs; edge_faces (E,) the two faces of each edge (-1 for a boundary edge); rest_length (E,)
    metres -> cos_out (T, E): cosine of the angle between the two faces' normals (1 flat, < 0 folded
    past 90 degrees; 1 on a boundary edge); strain_out (T, E): length / rest length - 1."""
    t, e = wp.tid()
    ab = edges[e]
    strain_out[t, e] = wp.length(points[t, ab[1]] - points[t, ab[0]]) / rest_length[e] - 1.0
    ff = edge_faces[e]
    if ff[1] < 0:
        cos_out[t, e] = 1.0
    else:
        cos_out[t, e] = wp.dot(normals[t, ff[0]], normals[t, ff[1]])


@wp.kernel
def jiggle_gradient(still: wp.array2d(dtype=wp.vec3), moved: wp.array2d(dtype=wp.vec3),
                    edges: wp.array(dtype=wp.vec2i), rest_length: wp.array(dtype=wp.float32), floor: float,
                    out: wp.array2d(dtype=wp.float32)):
    """still, moved (T, V) metres (the static and the final skin); edges (E,), rest_length (E,) metres
    -> out (T, E): |d_a - d_b| / max(|s_a - s_b|, floor rest_length) with s = still and d = moved - still,
    how much the jiggle alone stretches or squeezes the edge relative to its own length (> 1: by more
    than its length). (`static` is a C++ keyword, hence the names.)"""
    t, e = wp.tid()
    ab = edges[e]
    sa = still[t, ab[0]]
    sb = still[t, ab[1]]
    d = (moved[t, ab[0]] - sa) - (moved[t, ab[1]] - sb)
    length = wp.max(wp.length(sb - sa), floor * rest_length[e])
    if length > 0.0:
        out[t, e] = wp.length(d) / length
    else:
        out[t, e] = 0.0
