"""One muscle part's closed rest surface -> a tetrahedral mesh, its bone-attached vertices, and the CVs' embedding.

Surface: the part's loft (rig/muscle/loft.py, the surface X(w, v) of its 40 CVs) sampled on a coarser grid than
the loft's own 17 x 16 (ROWS x COLS here, default 9 x 16) and closed by the two cap centroids, the same layout
as rig.muscle.loft.FACES: a watertight, consistently oriented triangle surface (checked with pyvista's
`is_manifold`). The coarse grid keeps the tet count to a few hundred to ~2k (the reference must run in seconds
on a CPU); a 16-sided ring holds ~97% of a round section's area, as the loft mesh does, so the tet volume
stays within ~1-2% of `MuscleRig.volumes`.

Tets: TetGen (`tetgen.TetGen(points, faces).tetrahedralize(order=1, mindihedral, minratio, maxvolume)`);
the quality bounds add interior (Steiner) vertices, which the attachment needs (a mesh of the surface
vertices alone has nothing inside to hold). Tets are returned positively oriented (det [b-a, c-a, d-a] > 0).

Attachment (which vertices ride the bone rigidly): the part's central axis (the polyline through its five
section centres) stands in for the bone-attached core: a muscle lies on bone and fascia along its length,
fat on the muscle under it, and both are held at their two ends by tendons / the skin's fold. So a vertex is
attached when it lies within `core` x the local mean section radius of the axis, or within `end` x the axis
length of either end (the end caps, where the tendons are). This is the honest cheap choice: the wobble of
a part is then the shear of the layer between core and surface, whose frequency goes as sqrt(mu / rho) over
the layer's thickness, the scaling the particles' goal springs are calibrated to (benchmarks/fem_reference.py).

Goal map (loft coordinates): every vertex gets coordinates (w, v, rho) in the part's lofted parametrisation, w in
[0, 4] across the sections, v in [0, 8) around them, rho in [0, 1] from the axis to the surface, so that

    x = (1 - rho) c(w) + rho X(w, v),      c(w) = sum_k N_k(w) mean_j CV[k, j],  X(w, v) = sum_kj N_k(w) B_j(v) CV[k, j]

(c(w): the loft's centre curve, the ring means interpolated across the sections as the surface is; X: the surface,
rig.muscle.loft). For fixed coordinates x is linear in the 40 CVs: a row of `goal_map` (N, 40), so the goal of
every vertex at a frame is goal_map @ static_cvs (one product for all frames). Why this map: it is exact on the
surface (its grid vertices are loft points, rho = 1; the caps are c(0), c(4)), it follows everything the static
shape does (the action curve bending, sections bulging or thinning to keep the volume) in the same parameters the
loft uses, and it needs no cage (the 40 CVs are not a closed polyhedron, so mean-value coordinates would not be
defined); barycentric coordinates in a tet mesh of the CVs would be only piecewise linear across the part.
Interior vertices are found by a dense sample of (w, v, rho) and a few Levenberg-Marquardt steps; the mesh's
rest points are then set to goal_map @ rest_cvs (they move by the inversion's residual, ~1e-9 m), so the rest
mesh is exactly its own goal.

Embedding: each query point (the 40 CVs, surface points) gets the tet that contains it (the one whose
smallest barycentric coordinate is largest) and its barycentric coordinates there; for a point outside every
tet (the CVs sit on or just off the surface, the loft being a B-spline that does not pass through its CVs)
the coordinates in that nearest tet are kept unclamped, so the embedding reproduces the point exactly at
rest and moves it with that tet's affine map.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle import loft

ROWS, COLS = 9, 16
"""Default surface grid of a part: rows across the sections (w in [0, 4]) x columns around them."""
MINDIHEDRAL, MINRATIO = 5.0, 2.0
"""TetGen quality bounds (degrees, radius-edge ratio): good enough tets for VBD, a bounded count."""


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A part's tetrahedral rest mesh (arrays read-only).

    points : (N, 3) float64 metres, rest positions (world at bind).
    tets : (T, 4) int32, vertex indices, positively oriented.
    volumes : (T,) float64 m^3, rest volume of each tet (all > 0).
    faces : (F, 3) int32, the closed surface triangles (indices into points; the input surface's vertices
        are points[:S], S = surface_count).
    surface_count : S, the first S points are the input surface's vertices.
    centres : (5, 3) metres, the section centres (the axis polyline). radii : (5,) metres, section mean radii.
    attached : (N,) bool, vertices that ride the bone rigidly (see the module).
    cv_tet : (40,) int64, the tet of each CV. cv_bary : (40, 4) float64, its barycentric coordinates there.
    goal_map : (N, 40) float64, each vertex's loft coordinates as weights of the 40 CVs (see the module): the
        goal of vertex n for CVs (40, 3) is goal_map[n] @ cvs; rows sum to 1 (it moves rigidly with the CVs).
    mesher : "TetGen" (part_mesh) or "structured" (structured_part_mesh: a loft that folds into itself).
    """

    points: np.ndarray
    tets: np.ndarray
    volumes: np.ndarray
    faces: np.ndarray
    surface_count: int
    centres: np.ndarray
    radii: np.ndarray
    attached: np.ndarray
    cv_tet: np.ndarray
    cv_bary: np.ndarray
    goal_map: np.ndarray | None = None
    mesher: str = "TetGen"

    def __post_init__(self):
        types = {"tets": np.int32, "faces": np.int32, "attached": bool, "cv_tet": np.int64}
        for k in ("points", "tets", "volumes", "faces", "centres", "radii", "attached", "cv_tet", "cv_bary",
                  "goal_map"):
            if getattr(self, k) is None:
                continue
            object.__setattr__(self, k, frozen_array(getattr(self, k), types.get(k, np.float64)))

    @property
    def volume(self) -> float:
        """m^3, the mesh's rest volume."""
        return float(self.volumes.sum())

    def interpolate(self, x: np.ndarray, tet: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Embedded points (..., n, 3) from vertex positions x (..., N, 3) and an embedding (tet (n,), bary (n, 4))."""
        return np.einsum("...nkc,nk->...nc", x[..., self.tets[tet], :], bary)

    def cvs(self, x: np.ndarray) -> np.ndarray:
        """(..., 40, 3): the CVs carried by vertex positions x (..., N, 3)."""
        return self.interpolate(x, self.cv_tet, self.cv_bary)

    def goals(self, cvs: np.ndarray) -> np.ndarray:
        """(..., N, 3) metres: every vertex's goal for the part's CVs (..., 40, 3) (goal_map @ cvs)."""
        return np.einsum("nc,...cd->...nd", self.goal_map, np.asarray(cvs, dtype=np.float64))


def grid_faces(rows: int, cols: int) -> np.ndarray:
    """(F, 3) int32 triangles of a capped tube grid of rows x cols points (point r * cols + c) plus two caps
    (rows * cols, rows * cols + 1), oriented as rig.muscle.loft.FACES."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = np.roll(idx[1:], -1, axis=1), idx[1:]
    quads = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    first, last = rows * cols, rows * cols + 1
    cap0 = np.stack([np.full(cols, first), np.roll(idx[0], -1), idx[0]], -1)
    cap1 = np.stack([np.full(cols, last), idx[-1], np.roll(idx[-1], -1)], -1)
    return np.concatenate([quads, cap0, cap1]).astype(np.int32)


def part_surface(cvs: np.ndarray, rows: int = ROWS, cols: int = COLS) -> tuple[np.ndarray, np.ndarray]:
    """The closed loft surface of one part's CVs (40, 3) metres (section-major, 8 per ring) on a rows x cols
    grid: points (rows * cols + 2, 3) float64 and faces (F, 3) int32."""
    cvs = np.asarray(cvs, dtype=np.float64).reshape(loft.SECTIONS * loft.RING, 3)
    w = np.repeat(np.linspace(0.0, loft.SECTIONS - 1, rows), cols)
    v = np.tile(np.arange(cols) * loft.RING / cols, rows)
    pts = loft.surface_weights(w, v).reshape(len(w), -1) @ cvs
    grid = pts.reshape(rows, cols, 3)
    pts = np.concatenate([pts, grid[0].mean(axis=0, keepdims=True), grid[-1].mean(axis=0, keepdims=True)])
    return pts, grid_faces(rows, cols)


def is_watertight(points: np.ndarray, faces: np.ndarray) -> bool:
    """pyvista's check that the triangle surface is closed and manifold."""
    import pyvista as pv
    faces = np.asarray(faces)
    mesh = pv.PolyData(np.asarray(points, dtype=np.float64),
                       np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
    return bool(mesh.is_manifold)


def tet_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) signed volumes det[b - a, c - a, d - a] / 6 of tets (T, 4) over points (N, 3)."""
    p = np.asarray(points, dtype=np.float64)[np.asarray(tets)]
    return np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6.0


def tetrahedralize(points: np.ndarray, faces: np.ndarray, *, mindihedral: float = MINDIHEDRAL,
                   minratio: float = MINRATIO, maxvolume: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
    """TetGen of a watertight surface (points (P, 3), faces (F, 3)): nodes (N, 3) float64 (the first P are the
    surface points, TetGen keeps them in order) and tets (T, 4) int32, positively oriented. maxvolume in
    m^3 (-1: none) bounds the tet size. ValueError when the surface is not watertight. The points go in snapped
    (`snapped`): TetGen's mesh is then the same on any CPU."""
    import tetgen
    if not is_watertight(points, faces):
        raise ValueError("the part's surface is not watertight (pyvista is_manifold is False)")
    import os
    tg = tetgen.TetGen(snapped(points), np.asarray(faces, dtype=np.int32))
    leftovers = [f for f in ("_skipped.face", "_skipped.node") if not os.path.exists(f)]
    try:
        nodes, tets, *_ = tg.tetrahedralize(order=1, mindihedral=mindihedral, minratio=minratio, maxvolume=maxvolume)
    finally:                                        # TetGen writes the faces it skipped into the working folder
        for f in leftovers:
            if os.path.exists(f):
                os.remove(f)
    nodes, tets = np.asarray(nodes, dtype=np.float64), np.asarray(tets, dtype=np.int32)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]          # TetGen's orientation convention, made ours
    return nodes, tets


SNAP_BITS = 20
"""The points TetGen is given are snapped to a grid 2^-SNAP_BITS of their extent (a power of two: ~0.2 um on a 20 cm
part, far below any tet). Why: TetGen's mesh (its Steiner points and every tet) changes completely when an input
coordinate changes in its last bit, and the same part's surface differs in its last bits from one CPU to another
(NumPy's vectorised loops sum in a different order on AVX-512 than on AVX2; FMA): the reference solid's sway then
spread 5.0-8.5 Hz over meshes of inputs 1e-12 apart (benchmarks/results/fem_mesh_spread.md), and a test of it failed
on one machine only. Snapped, inputs that differ by less than the grid give the one mesh (unless a coordinate sits
within their difference of a grid line: ~1e-6 per coordinate for last-bit differences)."""


def snapped(points: np.ndarray) -> np.ndarray:
    """(P, 3) float64: points (P, 3) rounded to multiples of q = 2^(floor(log2(extent)) - SNAP_BITS), extent the
    largest side of their bounding box (q a power of two: the rounding is exact arithmetic)."""
    p = np.asarray(points, dtype=np.float64)
    extent = float(np.ptp(p, axis=0).max()) if len(p) else 0.0
    if not extent > 0.0 or not np.isfinite(extent):
        return p.copy()
    q = math.ldexp(1.0, math.floor(math.log2(extent)) - SNAP_BITS)
    return np.round(p / q) * q


def barycentric(points: np.ndarray, tets: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Embedding of query points (n, 3) in tets (T, 4) over points (N, 3): tet (n,) int64, the tet whose smallest
    barycentric coordinate is largest (the containing one, or the nearest in that measure for a point outside
    all), and bary (n, 4) float64, its coordinates there (unclamped: sum to 1, reproduce the point)."""
    p = np.asarray(points, dtype=np.float64)[np.asarray(tets)]                   # (T, 4, 3)
    q = np.asarray(query, dtype=np.float64)
    D = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=-1)   # (T, 3, 3) columns
    Dinv = np.linalg.inv(D)
    l123 = np.einsum("tij,ntj->nti", Dinv, q[:, None, :] - p[None, :, 0])       # (n, T, 3)
    bary = np.concatenate([1.0 - l123.sum(-1, keepdims=True), l123], axis=-1)   # (n, T, 4)
    tet = np.argmax(bary.min(axis=-1), axis=1)
    return tet.astype(np.int64), bary[np.arange(len(q)), tet]


def loft_map(w: np.ndarray, v: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(n, 40) weights of the CVs of the points with loft coordinates (w, v, rho) (n,) each (see the module):
    (1 - rho) c(w) + rho X(w, v)."""
    N = loft.section_weights(w)                                                   # (n, 5)
    B = loft.ring_weights(v)                                                      # (n, 8)
    rho = np.asarray(rho, dtype=np.float64).reshape(-1, 1, 1)
    W = (1.0 - rho) * N[:, :, None] / loft.RING + rho * N[:, :, None] * B[:, None, :]
    return W.reshape(len(N), loft.SECTIONS * loft.RING)


def loft_coordinates(points: np.ndarray, cvs: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, float]:
    """Loft coordinates (n, 3) = (w, v, rho) of points (n, 3) in the solid of the part's CVs (40, 3), and the
    largest residual |x(w, v, rho) - p| (metres): the nearest of a dense (w, v, rho) sample, refined by
    Levenberg-Marquardt on the three coordinates (w in [0, 4], rho in [-0.2, 1.3]: a point next to the axis may
    take a small negative rho, the other side's direction, rather than stall where d x / d v vanishes)."""
    X = np.asarray(cvs, dtype=np.float64).reshape(loft.SECTIONS * loft.RING, 3)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3)), 0.0
    ws, vs, rs = np.meshgrid(np.linspace(0, 4, 41), np.arange(32) / 4.0, np.linspace(0.05, 1, 11), indexing="ij")
    grid = np.stack([ws.ravel(), vs.ravel(), rs.ravel()], 1)
    gx = loft_map(*grid.T) @ X
    d2 = (p * p).sum(1)[:, None] - 2 * p @ gx.T + (gx * gx).sum(1)[None]
    q = grid[np.argmin(d2, axis=1)].copy()
    ring_mean = np.repeat(np.eye(loft.SECTIONS), loft.RING, axis=1) / loft.RING   # (5, 40)
    lam = np.full(len(p), 1e-3)
    for _ in range(iterations):
        w, v, rho = q.T
        Nw, dNw = loft.section_weights(w), loft.section_weights(w, 1)
        B, dB = loft.ring_weights(v), loft.ring_weights(v, 1)
        c, dc = Nw @ ring_mean @ X, dNw @ ring_mean @ X
        S = np.einsum("nk,nj,kjd->nd", Nw, B, X.reshape(5, 8, 3))
        Sw = np.einsum("nk,nj,kjd->nd", dNw, B, X.reshape(5, 8, 3))
        Sv = np.einsum("nk,nj,kjd->nd", Nw, dB, X.reshape(5, 8, 3))
        x = (1 - rho)[:, None] * c + rho[:, None] * S
        r = x - p
        J = np.stack([(1 - rho)[:, None] * dc + rho[:, None] * Sw, rho[:, None] * Sv, S - c], axis=-1)  # (n, 3, 3)
        JtJ = np.einsum("nki,nkj->nij", J, J)
        scale = np.einsum("nii->ni", JtJ).max(axis=1) + 1e-30
        A = JtJ + (lam * scale)[:, None, None] * np.eye(3)
        step = -np.linalg.solve(A, np.einsum("nki,nk->ni", J, r)[..., None])[..., 0]
        qn = q + step
        qn[:, 0] = np.clip(qn[:, 0], 0.0, 4.0)
        qn[:, 2] = np.clip(qn[:, 2], -0.2, 1.3)
        rn = loft_map(*qn.T) @ X - p
        better = (rn * rn).sum(1) < (r * r).sum(1)
        q[better] = qn[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
    q[:, 1] = np.mod(q[:, 1], loft.RING)
    res = float(np.linalg.norm(loft_map(*q.T) @ X - p, axis=1).max())
    return q, res


def attached_vertices(points: np.ndarray, centres: np.ndarray, radii: np.ndarray, core: float,
                      end: float) -> np.ndarray:
    """(N,) bool: vertices within core x the local section radius of the axis polyline `centres` (K, 3) (radii
    (K,) metres at its points, linear between), or within end x the axis length of either end of it."""
    x = np.asarray(points, dtype=np.float64)
    a, b = centres[:-1], centres[1:]
    ab = b - a
    seg_len = np.linalg.norm(ab, axis=1)
    t = np.clip(np.einsum("nkc,kc->nk", x[:, None] - a[None], ab) / np.maximum(seg_len ** 2, 1e-300), 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(x[:, None] - foot, axis=-1)                                   # (N, K - 1)
    k = np.argmin(d, axis=1)
    rows = np.arange(len(x))
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    arc = s[k] + t[rows, k] * seg_len[k]
    r_local = radii[k] + t[rows, k] * (radii[k + 1] - radii[k])
    length = s[-1]
    return (d[rows, k] <= core * r_local) | (arc <= end * length) | (arc >= (1.0 - end) * length)


CORE, END = 0.35, 0.1
"""Default attachment: the core within 0.35 local radii of the axis, and the end tenth of the axis at either end."""
LAYERS = (0.3, 0.65, 1.0)
"""rho of the structured mesh's rings (structured_mesh): the innermost inside the CORE, so it rides the bone."""


def _prism_tets(bottom, top) -> list:
    """3 tets of a prism with triangles bottom (a, b, c) and top (a', b', c') (vertex ids), split so that every quad
    face's diagonal runs from its smallest vertex id: neighbouring prisms split a shared quad alike (conforming)."""
    a, b, c = bottom
    d, e, f = top
    # rotate so the prism's smallest vertex is a bottom corner (or mirror top/bottom)
    ids = [a, b, c, d, e, f]
    k = ids.index(min(ids))
    if k >= 3:
        a, b, c, d, e, f = d, e, f, a, b, c
        k -= 3
    for _ in range(k):
        a, b, c, d, e, f = b, c, a, e, f, d
    # a is the smallest: the quads (a b e d) and (a c f d) split from a; the quad (b c f e) from its smallest
    if min(b, f) < min(c, e):
        return [(a, b, c, f), (a, b, f, e), (a, e, f, d)]
    return [(a, b, c, e), (a, e, c, f), (a, e, f, d)]


def structured_mesh(rows: int = ROWS, cols: int = COLS, layers=LAYERS) -> tuple[np.ndarray, np.ndarray, int]:
    """A tet mesh in loft coordinates (w, v, rho): the axis (rho 0) and `layers` rings of rows x cols points, the
    outermost (rho 1) the loft's surface. Returns coords (N, 3) (the outermost ring's rows x cols points first, then
    the axis's rows, then the inner rings), tets (T, 4) int32 (orientation not yet fixed: it depends on the CVs) and
    S, the count of surface ring points. Cells: prisms between the axis and the first ring, hexahedra (two prisms)
    between rings, each split into 3 tets conformingly (_prism_tets)."""
    layers = tuple(float(x) for x in layers)
    L = len(layers)
    w = np.linspace(0.0, loft.SECTIONS - 1, rows)
    v = np.arange(cols) * loft.RING / cols
    ring_id = np.zeros((L, rows, cols), np.int64)
    ring_id[L - 1] = np.arange(rows * cols).reshape(rows, cols)
    axis_id = rows * cols + np.arange(rows)
    nxt = rows * cols + rows
    for k in range(L - 1):
        ring_id[k] = nxt + np.arange(rows * cols).reshape(rows, cols)
        nxt += rows * cols
    coords = np.zeros((nxt, 3))
    for k in range(L):
        coords[ring_id[k].ravel()] = np.stack([np.repeat(w, cols), np.tile(v, rows), np.full(rows * cols, layers[k])], 1)
    coords[axis_id] = np.stack([w, np.zeros(rows), np.zeros(rows)], 1)
    tets = []
    for i in range(rows - 1):
        for j in range(cols):
            jn = (j + 1) % cols
            r0 = ring_id[0]
            tets += _prism_tets((axis_id[i], r0[i, j], r0[i, jn]), (axis_id[i + 1], r0[i + 1, j], r0[i + 1, jn]))
            for k in range(L - 1):
                lo, hi = ring_id[k], ring_id[k + 1]
                tets += _prism_tets((lo[i, j], lo[i, jn], hi[i, jn]), (lo[i + 1, j], lo[i + 1, jn], hi[i + 1, jn]))
                tets += _prism_tets((lo[i, j], hi[i, jn], hi[i, j]), (lo[i + 1, j], hi[i + 1, jn], hi[i + 1, j]))
    return coords, np.asarray(tets, np.int32), rows * cols


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """(F, 3) int32: the triangles of tets (T, 4) that belong to one tet only, oriented outward for positive tets."""
    t = np.asarray(tets)
    faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inv.reshape(-1)] == 1].astype(np.int32)


def part_mesh(cvs: np.ndarray, *, rows: int = ROWS, cols: int = COLS, core: float = CORE, end: float = END,
              mindihedral: float = MINDIHEDRAL, minratio: float = MINRATIO, max_tets: int = 2500) -> TetMesh:
    """The TetMesh of one part from its rest CVs (40, 3) metres (section-major, 8 per ring). max_tets bounds
    the count through TetGen's maxvolume only when the quality bounds alone make more (it then retries with
    a coarser surface grid)."""
    cvs = np.asarray(cvs, dtype=np.float64).reshape(loft.SECTIONS, loft.RING, 3)
    centres = cvs.mean(axis=1)
    radii = np.linalg.norm(cvs - centres[:, None], axis=-1).mean(axis=1)
    while True:
        surf, faces = part_surface(cvs.reshape(-1, 3), rows, cols)
        try:
            nodes, tets = tetrahedralize(surf, faces, mindihedral=mindihedral, minratio=minratio)
        except RuntimeError:                        # a surface TetGen cannot take (it folds into itself)
            if cols <= 8:                           # at every grid: the structured mesh of its loft coordinates
                return structured_part_mesh(cvs, rows=ROWS, cols=COLS, core=core, end=end)
            rows, cols = max(5, rows - 2), cols - 4
            continue
        if len(tets) <= max_tets or cols <= 8:
            break
        rows, cols = max(5, rows - 2), cols - 4
    vol = tet_volumes(nodes, tets)
    attached = attached_vertices(nodes, centres, radii, core, end)
    interior = np.arange(len(nodes)) >= len(surf)
    if not (attached & interior).any():             # no Steiner vertex near the axis: hold the nearest interior ones
        d = np.linalg.norm(nodes[:, None] - centres[None], axis=-1).min(axis=1)
        d[~interior] = np.inf
        attached[np.argsort(d)[:max(1, int(interior.sum()) // 4)]] = True
    # loft coordinates: the grid exactly, the caps on the axis, the Steiner vertices by inversion
    coords = np.zeros((len(nodes), 3))
    coords[:rows * cols] = np.stack([np.repeat(np.linspace(0.0, loft.SECTIONS - 1, rows), cols),
                                     np.tile(np.arange(cols) * loft.RING / cols, rows), np.ones(rows * cols)], 1)
    coords[rows * cols:len(surf)] = [[0.0, 0.0, 0.0], [loft.SECTIONS - 1, 0.0, 0.0]]
    coords[len(surf):], residual = loft_coordinates(nodes[len(surf):], cvs)
    goal_map = loft_map(*coords.T)
    moved = goal_map @ cvs.reshape(-1, 3)
    off = float(np.abs(moved - nodes).max())
    vol_moved = tet_volumes(moved, tets)
    # a vertex the inversion leaves a little off (a fold of the loft's solid near a thin end) is moved onto its
    # coordinates' point as long as no tet loses more than half its volume: the rest mesh stays exactly its own goal
    if off > 1e-3 * radii.mean() and not (vol_moved > 0.5 * vol).all():
        # a Steiner vertex outside the loft's solid (its chords cut inside the lofted surface): the structured mesh
        return structured_part_mesh(cvs, rows=ROWS, cols=COLS, core=core, end=end)
    nodes, vol = moved, vol_moved                   # the rest mesh is exactly its own goal
    cv_tet, cv_bary = barycentric(nodes, tets, cvs.reshape(-1, 3))
    return TetMesh(points=nodes, tets=tets, volumes=vol, faces=faces, surface_count=len(surf), centres=centres,
                   radii=radii, attached=attached, cv_tet=cv_tet, cv_bary=cv_bary, goal_map=goal_map)


def structured_part_mesh(cvs: np.ndarray, *, rows: int = ROWS, cols: int = COLS, core: float = CORE,
                         end: float = END, layers=LAYERS) -> TetMesh:
    """The TetMesh of a part whose lofted surface folds into itself (a short, wide part whose sections tilt into
    each other, as a pectoral's: TetGen refuses it): structured_mesh in its loft coordinates, every vertex's goal
    map known exactly (no inversion), the rest points the map of the rest CVs. Tets that the fold turns inside
    out at rest (or flattens below 1e-4 of the mean volume) are left out, and vertices no tet keeps with them; the
    vertices they shared with the tets kept ride the bone (held by fewer tets, they would be the first to fold)."""
    cvs = np.asarray(cvs, dtype=np.float64).reshape(loft.SECTIONS, loft.RING, 3)
    centres = cvs.mean(axis=1)
    radii = np.linalg.norm(cvs - centres[:, None], axis=-1).mean(axis=1)
    coords, tets, S = structured_mesh(rows, cols, layers)
    goal_map = loft_map(*coords.T)
    nodes = goal_map @ cvs.reshape(-1, 3)
    # orientation in the straight round tube of the same coordinates (x = rho cos, rho sin of the angle, w): a tet
    # the part's rest shape turns the other way lies across a fold of the loft, and is left out
    theta = 2.0 * np.pi * coords[:, 1] / loft.RING
    tube = np.stack([coords[:, 2] * np.cos(theta), coords[:, 2] * np.sin(theta), coords[:, 0]], 1)
    flip = tet_volumes(tube, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    vol = tet_volumes(nodes, tets)
    keep = vol > 1e-4 * np.abs(vol).mean()
    # the vertices of tets left out lie on the fold, held by fewer tets than the rest: they ride the bone
    folded = np.zeros(len(nodes), bool)
    folded[tets[~keep].reshape(-1)] = True
    tets, vol = tets[keep], vol[keep]
    used = np.zeros(len(nodes), bool)
    used[tets.reshape(-1)] = True
    new = np.cumsum(used) - 1
    surface_count = int(used[:S].sum())
    nodes, goal_map, coords, tets = nodes[used], goal_map[used], coords[used], new[tets].astype(np.int32)
    attached = (coords[:, 2] <= core + 1e-9) | attached_vertices(nodes, centres, radii, 0.0, end) | folded[used]
    cv_tet, cv_bary = barycentric(nodes, tets, cvs.reshape(-1, 3))
    return TetMesh(points=nodes, tets=tets, volumes=vol, faces=boundary_faces(tets), surface_count=surface_count,
                   centres=centres, radii=radii, attached=attached, cv_tet=cv_tet, cv_bary=cv_bary, goal_map=goal_map,
                   mesher="structured")


__all__ = ["TetMesh", "snapped", "SNAP_BITS", "part_mesh", "structured_part_mesh", "structured_mesh", "boundary_faces", "LAYERS", "part_surface", "grid_faces", "is_watertight", "tetrahedralize", "tet_volumes",
           "barycentric", "attached_vertices", "loft_map", "loft_coordinates", "ROWS", "COLS", "CORE", "END"]
