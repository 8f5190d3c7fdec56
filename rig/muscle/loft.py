"""The lofted surface of a thesis muscle: 5 cross-sections of 8 CVs each -> a closed triangle mesh.

A muscle's shape is 5 closed cross-section curves along its action curve (Hoehne's thesis, section
6.3), lofted into one surface. Everything here is a fixed linear map of the 40 CVs, the same for
every muscle, so the per-frame code evaluates all muscles with two small matrix products (across
the sections, then around them).

Parameters
----------
v in [0, 8) runs around a section: the section curve is the periodic uniform cubic B-spline of its
    8 CVs, ``ring(v) = sum_r b_r(t) CV[(i - 1 + r) mod 8]`` with i = floor(v), t = v - i, so ring(j)
    sits across from CV j (it equals (CV[j-1] + 4 CV[j] + CV[j+1]) / 6).
w in [0, 4] runs across the sections: the loft interpolates the 5 section curves with a cubic spline
    in the section index (as Maya's loft with uniform parameterisation: the surface passes through
    every section curve). Using the index rather than the curve parameter of each section keeps the
    map the same for all muscles whatever their bulge position (for the default bulge position 0.25
    the two agree). The spline's end condition is not-a-knot (the two end spans on each side share
    one cubic): it follows the rounded, steep ends of a fusiform muscle better than natural ends
    (fitting an ellipsoid: rms 1.3% of its minor radius against 2.1%, max 4% against 7%).

The surface ``X(w, v) = sum_k N_k(w) sum_j B_j(v) CV[k, j]`` is sampled on a grid of ROWS x COLS points
(17 x 16: ROWS_PER_SPAN rows per section span, COLS_PER_CV columns per section CV), and closed by two
cap points, the centroids of the first and the last row. The 16-sided rings cut a round section's
area by 2.6% (an ellipsoid's loft mesh holds ~97% of its volume); what matters for volume
preservation is that the same mesh is measured at rest and per frame. Point p = r * COLS + c for
row r, column c; caps at ROWS * COLS and ROWS * COLS + 1. FACES is consistently oriented with
outward normals when the sections run from origin (w = 0) to insertion (w = 4) and v turns from a
section's up vector U toward its side S = T x U (right-handed about the tangent T, as
rig.muscle.model builds them).

The enclosed volume follows from the divergence theorem, ``V = 1/6 sum_faces a . (b x c)``; for a
grid quad a, b, c, d (a = (r, c), b = (r, c + 1), c = (r + 1, c + 1), d = (r + 1, c)) its two
triangles (a, b, c) and (a, c, d) sum to ``a . (c x (d - b))``, which `grid_volume` evaluates on
whole grids at once.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

SECTIONS = 5          # cross-sections per muscle
RING = 8              # CVs per cross-section
ROWS_PER_SPAN = 4     # grid rows per span between two sections
COLS_PER_CV = 2       # grid columns per section CV
ROWS = ROWS_PER_SPAN * (SECTIONS - 1) + 1   # 17
COLS = COLS_PER_CV * RING                   # 16
POINTS = ROWS * COLS + 2                    # grid plus two caps


def ring_weights(v, derivative: int = 0) -> np.ndarray:
    """(n, 8) weights of the section CVs at ring parameters v (n,) (any real, periodic over 8):
    the periodic uniform cubic B-spline basis, or its first derivative d/dv when `derivative` = 1."""
    v = np.mod(np.asarray(v, dtype=np.float64).ravel(), RING)
    i = np.floor(v).astype(np.int64)
    t = v - i
    if derivative == 0:
        b = np.stack([(1 - t) ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1,
                      t ** 3], axis=1) / 6.0
    elif derivative == 1:
        b = np.stack([-3 * (1 - t) ** 2, 9 * t ** 2 - 12 * t, -9 * t ** 2 + 6 * t + 3, 3 * t ** 2],
                     axis=1) / 6.0
    else:
        raise ValueError(f"derivative must be 0 or 1, got {derivative}")
    out = np.zeros((len(v), RING))
    rows = np.arange(len(v))[:, None]
    np.add.at(out, (rows, (i[:, None] - 1 + np.arange(4)) % RING), b)
    return out


_ACROSS = CubicSpline(np.arange(SECTIONS, dtype=np.float64), np.eye(SECTIONS), bc_type="not-a-knot")


def section_weights(w, derivative: int = 0) -> np.ndarray:
    """(n, 5) weights of the sections at loft parameters w (n,) in [0, 4] (clipped): the not-a-knot
    cubic spline through the sections in their index, or its derivative d/dw."""
    w = np.clip(np.asarray(w, dtype=np.float64).ravel(), 0.0, SECTIONS - 1)
    return _ACROSS(w, derivative)


def surface_weights(w, v, dw: int = 0, dv: int = 0) -> np.ndarray:
    """(n, 5, 8) weights of the 40 CVs for surface points at parameters (w, v) (n,) each; dw, dv
    select partial derivatives (0 or 1)."""
    return section_weights(w, dw)[:, :, None] * ring_weights(v, dv)[:, None, :]


GRID_W = np.linspace(0.0, SECTIONS - 1, ROWS)                 # (ROWS,) loft parameter of each row
GRID_V = np.arange(COLS) / COLS_PER_CV                          # (COLS,) ring parameter of each column
ROW_WEIGHTS = section_weights(GRID_W)                          # (ROWS, 5)
COL_WEIGHTS = ring_weights(np.append(GRID_V, RING))            # (COLS + 1, 8), last column = first
for _a in (GRID_W, GRID_V, ROW_WEIGHTS, COL_WEIGHTS):
    _a.setflags(write=False)


def _faces() -> np.ndarray:
    idx = np.arange(ROWS * COLS).reshape(ROWS, COLS)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = np.roll(idx[1:], -1, axis=1), idx[1:]
    quads = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    first, last = ROWS * COLS, ROWS * COLS + 1
    r0, r1 = idx[0], idx[-1]
    cap0 = np.stack([np.full(COLS, first), np.roll(r0, -1), r0], -1)
    cap1 = np.stack([np.full(COLS, last), r1, np.roll(r1, -1)], -1)
    f = np.concatenate([quads, cap0, cap1]).astype(np.int32)
    f.setflags(write=False)
    return f


FACES = _faces()
"""(F, 3) int32 triangles of one muscle's closed loft mesh, outward."""


def grid_of(x: np.ndarray) -> np.ndarray:
    """The loft grid (ROWS, COLS + 1, ...) of CVs laid out (5, 8, ...): across the sections first,
    then around them (two small products rather than one (ROWS * COLS, 40) map)."""
    rows = (ROW_WEIGHTS @ x.reshape(SECTIONS, -1)).reshape(ROWS, RING, -1)
    return (COL_WEIGHTS @ rows).reshape((ROWS, COLS + 1) + x.shape[2:])


def grid(cvs: np.ndarray) -> np.ndarray:
    """The loft grid of CVs (..., 5, 8, 3): (ROWS, COLS + 1, 3, ...) points, the periodic column
    repeated at the end (the layout `grid_volume` reads)."""
    cvs = np.asarray(cvs, dtype=np.float64)
    return grid_of(np.moveaxis(cvs, (-3, -2, -1), (0, 1, 2)))


def grid_points(g: np.ndarray) -> np.ndarray:
    """(..., POINTS, 3) surface points (grid then the two caps) from a grid (ROWS, COLS + 1, 3, ...)."""
    g = g[:, :-1]
    caps = g[[0, -1]].mean(axis=1)                                              # (2, 3, ...)
    pts = np.moveaxis(g.reshape((ROWS * COLS, 3) + g.shape[3:]), (0, 1), (-2, -1))
    return np.concatenate([pts, np.moveaxis(caps, (0, 1), (-2, -1))], axis=-2)


def grid_volume(g: np.ndarray) -> np.ndarray:
    """Volume (...) in cubic units enclosed by the loft mesh of a grid (ROWS, COLS + 1, 3, ...)
    (see `grid`): quads a . (c x (d - b)) plus the two cap fans, over 6.

    The grid is flattened row after row (with its repeated column) so that the corners a, b, c, d
    of all quads are four contiguous, shifted slices. The slices also hold one false quad per row,
    from the repeated column to the next row's first; it has d = b (the repeated column equals the
    first) and adds nothing. Components are kept apart and products are made in place: at this
    size the temporaries cost more than the arithmetic."""
    batch = g.shape[3:]
    f = np.ascontiguousarray(np.moveaxis(g, 2, 0)).reshape((3, ROWS * (COLS + 1)) + batch)
    n = (ROWS - 1) * (COLS + 1) - 1
    a, b = f[:, :n], f[:, 1:n + 1]
    c, d = f[:, COLS + 2:COLS + 2 + n], f[:, COLS + 1:COLS + 1 + n]
    c0, c1, c2 = c
    e0, e1, e2 = d[0] - b[0], d[1] - b[1], d[2] - b[2]
    q = c1 * e2
    q -= c2 * e1
    q *= a[0]
    r = c2 * e0
    r -= c0 * e2
    r *= a[1]
    q += r
    np.multiply(c0, e1, out=r)
    r -= c1 * e0
    r *= a[2]
    q += r
    # the cap fans from each end ring's centroid: sum_c cap . (ring[c] x ring[c + 1]), negated at
    # the start (its triangles run the other way round)
    ends = g[[0, -1]]                                                          # (2, C + 1, 3, ...)
    p0, p1, p2 = ends[:, :-1, 0], ends[:, :-1, 1], ends[:, :-1, 2]
    q0, q1, q2 = ends[:, 1:, 0], ends[:, 1:, 1], ends[:, 1:, 2]
    cap = ends[:, :-1].mean(axis=1)                                            # (2, 3, ...)
    fan = (cap[:, 0] * (p1 * q2 - p2 * q1).sum(axis=1) + cap[:, 1] * (p2 * q0 - p0 * q2).sum(axis=1)
           + cap[:, 2] * (p0 * q1 - p1 * q0).sum(axis=1))
    return (q.sum(axis=0) + fan[1] - fan[0]) / 6.0


def points(cvs: np.ndarray) -> np.ndarray:
    """(..., POINTS, 3) loft surface points of CVs (..., 5, 8, 3)."""
    return grid_points(grid(cvs))


def volume(cvs: np.ndarray) -> np.ndarray:
    """(...) volume enclosed by the loft of CVs (..., 5, 8, 3), measured about the CVs' mean (the
    mesh is closed, so any origin gives the same volume; a near one keeps the products small)."""
    cvs = np.asarray(cvs, dtype=np.float64)
    return grid_volume(grid(cvs - cvs.mean(axis=(-3, -2), keepdims=True)))
