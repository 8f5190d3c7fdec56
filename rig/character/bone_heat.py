"""Automatic skin weights by bone heat diffusion (Baran & Popovic 2007, "Automatic rigging and
animation of 3D characters", section 4).

Each joint's weight is the equilibrium temperature of the surface when the joint's bones are held
at temperature 1 and every other bone at 0, heat flowing to a vertex only from the bones it sees:

    (-L + H) w_j = H p_j

- L: the cotangent Laplace-Beltrami operator of the surface, L = -M^-1 K, with K the cotangent
  stiffness matrix (symmetric, positive semidefinite) and M the lumped vertex areas. Multiplying by M
  gives the symmetric system (K + M H) w_j = M H p_j, factorised once for every joint.
- H: diagonal, H_ii = c / d_i^2 (c = 1) where d_i is the distance from vertex i to the closest bone
  it *sees* (the segment from the vertex to the nearest point of the bone does not cross the mesh).
- p_j: the share of vertex i's closest visible bones (those within 1.0001 d_i) that belong to joint j.

Bones. A bone is a segment; the segment from joint p to its child c moves with joint p's frame, so it
belongs to p (a joint with several children owns all of them; a root owns its child segments). A leaf
joint owns a segment to its end site when `end_positions` gives one, otherwise a segment continuing
its parent bone's direction for `LEAF_FRACTION` of that bone's length, otherwise (an isolated root)
the point at the joint. Zero-length bones (a child at its parent's position, like CMU's LHipJoint)
are points and need no special case.

Robustness, each a reading of the paper stated here once:
- Positions closer than `WELD_TOLERANCE` (glTF splits vertices at UV seams) are welded for the
  solve and the weights are scattered back, so both sides of a seam get identical weights.
- Faces of (nearly) zero area, or that lose a corner to the weld, are dropped.
- A vertex that sees no bone takes the nearest bone by distance, as Pinocchio does; so every
  vertex has H > 0, every connected component (even one that sees no bone at all) has a
  non-singular system, and no row of weights is empty. Any row that still comes out non-finite or
  empty is given its nearest joint (counted in the report; never expected).
- Negative and huge cotangent weights (obtuse and sliver triangles) are clamped, which keeps K an
  M-matrix, so the heat stays in [0, 1] (maximum principle) and rows sum to 1.

Two steps after the solve keep the skin from creasing (issue 18: with them the generated body's
plain LBS folds 29 edges past 90 degrees at worst on the CMU dance clip 05_02, without them 205):
- `smooth_heat`: steps of uniform Laplacian smoothing of every joint's heat over the mesh's edges, as
  many as reach SMOOTH_REACH of the skeleton's size (n steps of size `step` spread a value over about
  e sqrt(n step), e the mean edge length: ~34 steps, 4.5 cm, on the generated body), per connected
  component. Visibility makes neighbouring vertices see different bones where spine, clavicle and hip
  bones crowd, so the heat can jump between neighbours; LBS turns such a jump into a crease.
  Averaging keeps each row's sum (1) and the values in [0, 1].
- `_top_k` prunes continuously: each of the k largest weights loses the (k + 1)-th largest before
  renormalising, so a joint's weight reaches 0 exactly where it leaves a vertex's top k. Plain
  truncation and renormalisation makes the weights jump across that line, a crease in every pose.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_neighbours

LEAF_FRACTION = 0.5      # a leaf joint's bone continues its parent bone for this share of its length
WELD_TOLERANCE = 1e-6    # metres: positions closer than this are one vertex for the solve
TIE = 1.0001             # bones within TIE x the closest visible distance share the vertex (Baran)
HEAT_C = 1.0             # c in H_ii = c / d_i^2 (Baran)
_COT_MAX = 1e3           # clamp of one corner's cotangent (a sliver triangle's is unbounded)
_EDGE_MIN = 1e-8         # floor of an edge's cotangent weight: keeps every mesh edge connected
SMOOTH_REACH = 0.025     # the heat's smoothing reaches this fraction of the skeleton's largest extent
SMOOTH_STEP = 0.5        # each step moves a vertex's heat half way to its edge neighbours' mean
SMOOTH_MAX = 200         # at most this many smoothing steps (a very fine mesh)


@dataclass(frozen=True)
class HeatReport:
    """What `bone_heat_weights` did.

    vertices, welded : input vertices, and distinct positions solved for.
    faces, dropped_faces : input faces, and faces dropped as degenerate (zero area or collapsed by the weld).
    components : connected components of the welded mesh (an unreferenced vertex is one).
    blind_components : components in which no vertex sees any bone (solved from nearest-bone sources).
    segments : bone segments used (child bones, leaf bones, end sites).
    rays : visibility rays cast.
    unseen : welded vertices that see no bone (they took the nearest bone by distance).
    repaired : welded vertices whose solved row was non-finite or empty (given their nearest joint).
    laplacian_s, visibility_s, solve_s, total_s : seconds spent (laplacian: checks, weld and Laplacian;
        visibility: distances and rays; solve: factorise once, solve all joints, top-k excluded).
    """

    vertices: int
    welded: int
    faces: int
    dropped_faces: int
    components: int
    blind_components: int
    segments: int
    rays: int
    unseen: int
    repaired: int
    laplacian_s: float
    visibility_s: float
    solve_s: float
    total_s: float


# ---------------------------------------------------------------------------------- bones
def bone_segments(joint_positions, parents, end_positions=None, bone_mask=None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bone segments of a skeleton and the joint each belongs to (see the module docstring).

    Parameters
    ----------
    joint_positions : (J, 3) float, metres.
    parents : (J,) int, parent index or -1, parents first.
    end_positions : (J, 3) float metres or None; row j is the end site of joint j (the tip of its
        bone, e.g. a BVH "End Site" or a glTF leaf's tail), NaN rows where there is none.
    bone_mask : (J,) bool or None; joints allowed to take weight. A masked-out joint's segments go
        to its nearest allowed ancestor, or are dropped when it has none.

    Returns
    -------
    start, end : (S, 3) float64 metres, segment endpoints (equal for a point bone).
    owner : (S,) int64, joint each segment belongs to.
    """
    pos = np.asarray(joint_positions, np.float64)
    par = np.asarray(parents, np.int64)
    J = len(pos)
    ends = np.full((J, 3), np.nan) if end_positions is None else np.asarray(end_positions, np.float64)
    if ends.shape != (J, 3):
        raise InputError(f"end_positions must be ({J}, 3) with NaN rows for joints without an end site, "
                         f"got shape {ends.shape}", field="end_positions")
    allowed = np.ones(J, bool) if bone_mask is None else np.asarray(bone_mask, bool)
    if allowed.shape != (J,):
        raise InputError(f"bone_mask must be ({J},) bool, got shape {allowed.shape}", field="bone_mask")
    has_child = np.zeros(J, bool)
    has_child[par[par >= 0]] = True
    scale = max(float(np.ptp(pos, axis=0).max()) if J else 0.0, 1e-9)

    segs = []  # (start, end, owner)
    for c in range(J):
        if par[c] >= 0:
            segs.append((pos[par[c]], pos[c], par[c]))
    for j in range(J):
        if np.isfinite(ends[j]).all():
            segs.append((pos[j], ends[j], j))
        elif not has_child[j]:
            segs.append((pos[j], pos[j] + LEAF_FRACTION * _incoming_direction(pos, par, j, 1e-9 * scale), j))

    owner = np.array([_allowed_ancestor(par, allowed, int(o)) for _, _, o in segs], np.int64)
    keep = owner >= 0
    if not keep.any():
        raise InputError("no bone is left to take weight (bone_mask excludes every joint)", field="bone_mask")
    start = np.array([s for s, _, _ in segs], np.float64).reshape(-1, 3)[keep]
    end = np.array([e for _, e, _ in segs], np.float64).reshape(-1, 3)[keep]
    return start, end, owner[keep]


def _incoming_direction(pos: np.ndarray, par: np.ndarray, j: int, eps: float) -> np.ndarray:
    """(3,) the nearest non-zero bone vector ending at j or above it (zeros for a lone joint), so a
    leaf behind a zero-length bone still continues the limb."""
    c = j
    while par[c] >= 0:
        d = pos[c] - pos[par[c]]
        if np.linalg.norm(d) > eps:
            return d
        c = par[c]
    return np.zeros(3)


def _allowed_ancestor(par: np.ndarray, allowed: np.ndarray, j: int) -> int:
    while j >= 0 and not allowed[j]:
        j = int(par[j])
    return j


def segment_distances(points: np.ndarray, start: np.ndarray, end: np.ndarray, chunk: int = 1 << 22
                      ) -> np.ndarray:
    """(N, S) distance in metres from every point (N, 3) to every segment (start, end: (S, 3))."""
    out = np.empty((len(points), len(start)))
    rows = max(1, chunk // max(len(start), 1))
    for i in range(0, len(points), rows):
        out[i:i + rows] = np.linalg.norm(points[i:i + rows, None] - _closest(points[i:i + rows, None], start, end),
                                         axis=-1)
    return out


def _closest(points: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Nearest point of segment start-end to each point (broadcast shapes, (..., 3)); a zero-length
    segment is its point."""
    ab = end - start
    ll = np.einsum("...k,...k->...", ab, ab)
    t = np.einsum("...k,...k->...", points - start, ab) / np.where(ll > 0, ll, 1.0)
    return start + np.clip(t, 0.0, 1.0)[..., None] * ab


# ---------------------------------------------------------------------------------- mesh
def weld(vertices: np.ndarray, faces: np.ndarray, tol: float = WELD_TOLERANCE
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge positions closer than `tol` metres (chains merge too).

    Returns points (P, 3) (first of each group), faces (F, 3) re-indexed to points (faces that lose a
    corner are dropped), and inverse (V,) int64 with vertices == points[inverse] within `tol`.
    """
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray")
    V = len(vertices)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(V, V))
    _, label = connected_components(graph, directed=False)
    first = np.full(label.max() + 1 if V else 0, V, np.int64)
    np.minimum.at(first, label, np.arange(V))
    # Renumber groups in order of their first vertex, so a mesh without duplicates keeps its indices.
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    inverse = rank[label].astype(np.int64)
    f = inverse[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    return vertices[first[order]], f, inverse


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Cotangent stiffness matrix K and lumped vertex areas.

    K = -M L, (V, V) csr: K_ij = -(cot a_ij + cot b_ij) / 2 for an edge, K_ii = -sum_j K_ij;
    symmetric positive semidefinite. Each corner's cotangent is clamped to +-`_COT_MAX` and each edge
    weight to at least `_EDGE_MIN`, so obtuse triangles cannot make weights negative (an M-matrix
    keeps the heat within [0, 1]) and every mesh edge stays connected.
    mass : (V,) m^2, a third of the area of each incident face (zero for unreferenced vertices).
    Faces must be non-degenerate (see `bone_heat_weights`).
    """
    V = len(vertices)
    tri = vertices[faces]                                       # (F, 3 corners, 3)
    cots = np.empty((len(faces), 3))
    for c in range(3):
        u = tri[:, (c + 1) % 3] - tri[:, c]
        w = tri[:, (c + 2) % 3] - tri[:, c]
        cross = np.linalg.norm(np.cross(u, w), axis=1)
        cots[:, c] = np.einsum("ij,ij->i", u, w) / np.maximum(cross, 1e-300)
    cots = np.clip(cots, -_COT_MAX, _COT_MAX)
    # corner c is opposite edge (c+1, c+2)
    i = np.concatenate([faces[:, (c + 1) % 3] for c in range(3)])
    j = np.concatenate([faces[:, (c + 2) % 3] for c in range(3)])
    w = 0.5 * cots.T.ravel()
    W = sp.coo_matrix((np.r_[w, w], (np.r_[i, j], np.r_[j, i])), shape=(V, V)).tocsr()
    W.sum_duplicates()
    W.data = np.maximum(W.data, _EDGE_MIN)
    K = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    mass = np.bincount(faces.ravel(), weights=np.repeat(area / 3.0, 3), minlength=V)
    return K, mass


# ---------------------------------------------------------------------------------- visibility
def _occluded(mesh, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(N,) bool: the segment origin -> target crosses the mesh before reaching the target.

    One batched first-hit query (embree through trimesh when installed). A ray is infinite, so it is
    cast from the bone point towards the vertex and the first hit's distance is compared with the
    vertex's: the vertex's own faces are hit at the full distance, up to a tolerance.
    """
    d = targets - origins
    dist = np.linalg.norm(d, axis=1)
    out = np.zeros(len(d), bool)
    live = dist > 1e-12
    if not live.any():
        return out
    o, u, dl = origins[live], d[live] / dist[live, None], dist[live]
    tri = mesh.ray.intersects_first(o, u)
    hit = tri >= 0
    n = mesh.face_normals[tri[hit]]
    v0 = mesh.vertices[mesh.faces[tri[hit], 0]]
    den = np.einsum("ij,ij->i", n, u[hit])
    # Plane distance; for a grazing hit (den ~ 0) use the triangle's centre projected on the ray.
    centre = mesh.triangles_center[tri[hit]]
    t_plane = np.einsum("ij,ij->i", n, v0 - o[hit]) / np.where(np.abs(den) > 1e-9, den, 1.0)
    t = np.where(np.abs(den) > 1e-9, t_plane, np.einsum("ij,ij->i", centre - o[hit], u[hit]))
    tol = 1e-3 * dl[hit] + 1e-6 * mesh.scale
    blocked = np.zeros(len(dl), bool)
    blocked[hit] = t < dl[hit] - tol
    out[live] = blocked
    return out


def closest_visible(mesh, points: np.ndarray, start: np.ndarray, end: np.ndarray, dist: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """Baran's heat sources: for each point the closest bones it sees.

    points (P, 3), segments start/end (S, 3), dist (P, S) from `segment_distances`.
    Returns sources (P, S) bool (the visible segments within TIE x the closest visible distance;
    the nearest ones by distance for a point that sees none), seen (P,) bool, and the rays cast.

    Two batched ray queries: first every point's nearest segments (and ties), then, for the points
    that see none of them, all their other segments.
    """
    dmin = dist.min(axis=1, keepdims=True)
    visible = np.zeros_like(dist, bool)
    first = dist <= TIE * dmin
    rays = 0
    for test in (first, None):
        if test is None:  # second round: the points still blind, every segment not yet tried
            blind = ~visible.any(axis=1)
            test = blind[:, None] & ~first
        pi, si = np.nonzero(test)
        if len(pi):
            q = _closest(points[pi], start[si], end[si])
            visible[pi, si] = ~_occluded(mesh, q, points[pi])
            rays += len(pi)
    seen = visible.any(axis=1)
    dvis = np.where(visible, dist, np.inf).min(axis=1, keepdims=True)
    sources = visible & (dist <= TIE * dvis)
    sources[~seen] = first[~seen]
    return sources, seen, rays


# ---------------------------------------------------------------------------------- weights
def bone_heat_weights(vertices, faces, joint_positions, parents, k: int = 4, *, end_positions=None,
                      bone_mask=None) -> tuple[np.ndarray, np.ndarray, HeatReport]:
    """Skin weights by bone heat diffusion (see the module docstring).

    Parameters
    ----------
    vertices : (V, 3) float, metres, the bind pose.
    faces : (F, 3) int, triangles.
    joint_positions : (J, 3) float, metres, bind-pose joint positions in the vertices' space.
    parents : (J,) int, parent index or -1 for roots, parents first.
    k : influences kept per vertex.
    end_positions : (J, 3) float metres or None, end site of each joint (NaN rows: none), see
        `bone_segments`.
    bone_mask : (J,) bool or None, joints allowed to take weight (see `bone_segments`).

    Returns
    -------
    joints : (V, k) int32, joint indices, by decreasing weight (index 0 with weight 0 pads rows
        when fewer than k joints exist).
    weights : (V, k) float32 in [0, 1], rows sum to 1, sorted descending.
    report : HeatReport.
    """
    t0 = time.perf_counter()
    verts, tris, pos, par = _check(vertices, faces, joint_positions, parents, k)
    J = len(pos)
    start, end, owner = bone_segments(pos, par, end_positions, bone_mask)
    if len(verts) == 0:
        return (np.zeros((0, k), np.int32), np.zeros((0, k), np.float32),
                HeatReport(0, 0, len(tris), len(tris), 0, 0, len(start), 0, 0, 0, 0.0, 0.0, 0.0, 0.0))

    points, f, inverse = weld(verts, tris)
    f = _drop_degenerate(points, f)
    K, mass = cotangent_laplacian(points, f)
    n_comp, comp = connected_components(K, directed=False)
    t1 = time.perf_counter()

    dist = segment_distances(points, start, end)
    mesh = trimesh.Trimesh(points, f, process=False)
    sources, seen, rays = closest_visible(mesh, points, start, end, dist)
    t2 = time.perf_counter()

    # H_ii = c / d_i^2, d_i the closest source distance, floored so a vertex on a bone stays finite.
    d = np.where(sources, dist, np.inf).min(axis=1)
    d = np.maximum(d, 1e-4 * max(mesh.scale, 1e-9))
    H = HEAT_C / d ** 2
    share = sources / sources.sum(axis=1, keepdims=True)            # (P, S)
    p = share @ np.eye(J)[owner]                                     # (P, J): shares per joint
    # An unreferenced vertex has no area; a tiny one makes its own row H_ii m_i w = H_ii m_i p.
    m = np.maximum(mass, 1e-9 * (mass.mean() if mass.any() else 1.0))
    heat = solve_heat(K, m * H, p)
    repaired = _repair(heat, dist, owner)
    size = float(np.ptp(pos, axis=0).max()) if len(pos) > 1 else float(np.ptp(points, axis=0).max())
    heat = smooth_heat(heat, f, smoothing_steps(points, f, size, comp))
    t3 = time.perf_counter()

    joints, weights = _top_k(heat, k)
    blind = len(np.setdiff1d(np.arange(n_comp), comp[seen]))
    report = HeatReport(
        vertices=len(verts), welded=len(points), faces=len(tris), dropped_faces=len(tris) - len(f),
        components=int(n_comp), blind_components=int(blind), segments=len(start), rays=int(rays),
        unseen=int((~seen).sum()), repaired=int(repaired), laplacian_s=t1 - t0, visibility_s=t2 - t1,
        solve_s=t3 - t2, total_s=time.perf_counter() - t0)
    return joints[inverse], weights[inverse], report


def _check(vertices, faces, joint_positions, parents, k):
    verts = np.asarray(vertices, np.float64)
    tris = np.asarray(faces)
    pos = np.asarray(joint_positions, np.float64)
    par = np.asarray(parents)
    if verts.ndim != 2 or verts.shape[1] != 3 or not np.isfinite(verts).all():
        raise InputError(f"vertices must be finite (V, 3), got shape {verts.shape}", field="vertices")
    if tris.size == 0:
        tris = np.zeros((0, 3), np.int64)
    if tris.ndim != 2 or tris.shape[1] != 3 or not np.issubdtype(tris.dtype, np.integer):
        raise InputError(f"faces must be (F, 3) integers, got {tris.dtype} {tris.shape}", field="faces")
    if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
        raise InputError(f"faces index vertices 0..{len(verts) - 1}, found {tris.min()}..{tris.max()}",
                         field="faces")
    if pos.ndim != 2 or pos.shape[1] != 3 or len(pos) == 0 or not np.isfinite(pos).all():
        raise InputError(f"joint_positions must be finite (J, 3), J >= 1, got shape {pos.shape}",
                         field="joint_positions")
    if par.shape != (len(pos),) or not np.issubdtype(par.dtype, np.integer) \
            or (par >= np.arange(len(pos))).any() or (par < -1).any():
        raise InputError("parents must be (J,) ints, -1 for a root, each parent listed before its child",
                         field="parents")
    if not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(f"k must be a positive integer, got {k!r}", field="k")
    return verts, tris.astype(np.int64), pos, par.astype(np.int64)


def _drop_degenerate(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces whose area is not negligible (relative to the mesh's size): zero-area faces have no
    cotangents and would only add noise."""
    tri = points[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    size = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    return faces[area2 > 1e-12 * size ** 2]


def solve_heat(K: sp.csr_matrix, mh: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(P, J) heat: solves (K + diag(mh)) w = mh * p for all joints with one factorisation.

    The matrix is symmetric positive definite (mh > 0 everywhere), so SuperLU runs in symmetric
    mode: a symmetric ordering and no pivoting beyond the diagonal.
    """
    A = (K + sp.diags(mh)).tocsc()
    lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return lu.solve(mh[:, None] * p)


def _repair(heat: np.ndarray, dist: np.ndarray, owner: np.ndarray) -> int:
    """Give rows that came out non-finite or empty their nearest joint (in place); returns how many.
    Not expected to happen (the system is positive definite); a safety net so NaN never escapes."""
    bad = ~np.isfinite(heat).all(axis=1) | (np.clip(heat, 0.0, None).sum(axis=1) < 1e-6)
    if bad.any():
        heat[bad] = 0.0
        heat[np.nonzero(bad)[0], owner[dist[bad].argmin(axis=1)]] = 1.0
    return int(bad.sum())


def smoothing_steps(points: np.ndarray, faces: np.ndarray, size: float, component: np.ndarray,
                    reach: float = SMOOTH_REACH, step: float = SMOOTH_STEP) -> np.ndarray:
    """(P,) int steps of `smooth_heat` per point, so that each connected component's smoothing spreads
    over r = `reach` x `size` (metres; the skeleton's largest extent): (r / e)^2 / step with e that
    component's mean edge length, at most SMOOTH_MAX (see the module). Per component, so a mesh's
    weights do not depend on what other pieces lie beside it."""
    P = len(points)
    if len(faces) == 0:
        return np.zeros(P, np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    length = np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1)
    n = int(component.max()) + 1
    total = np.bincount(component[e[:, 0]], weights=length, minlength=n)
    count = np.bincount(component[e[:, 0]], minlength=n)
    mean_edge = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    r = reach * size
    steps = np.where(mean_edge > 0, np.round((r / np.where(mean_edge > 0, mean_edge, 1.0)) ** 2 / step), 0)
    return np.minimum(steps, SMOOTH_MAX).astype(np.int64)[component]


def smooth_heat(heat: np.ndarray, faces: np.ndarray, steps: np.ndarray, step: float = SMOOTH_STEP) -> np.ndarray:
    """(P, J) heat after steps[i] steps h <- h + step (mean of the edge neighbours' h - h) at point i
    over the mesh `faces` (F, 3) (see the module; steps: (P,) int, equal within a connected
    component). Rows keep their sums; a point on no edge keeps its heat."""
    P = len(heat)
    steps = np.asarray(steps)
    if len(faces) == 0 or not steps.any():
        return heat
    A = mesh_neighbours(faces, P).astype(np.float64)
    deg = np.asarray(A.sum(axis=1)).ravel()
    mean = sp.diags(np.where(deg > 0, 1.0 / np.maximum(deg, 1), 0.0)) @ A
    h = heat
    for i in range(int(steps.max())):
        move = (steps > i) & (deg > 0)          # a component stops at its own count of steps
        h = h + step * np.where(move[:, None], mean @ h - h, 0.0)
    return h


def _top_k(heat: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, k) int32 joints and float32 weights: the k largest heats per row, negatives clamped to 0,
    each minus the row's (k + 1)-th largest (continuous pruning, see the module), renormalised to sum
    1, by decreasing weight; padded with joint 0 at weight 0 if k > J."""
    P, J = heat.shape
    h = np.clip(heat, 0.0, None)
    h = h / np.maximum(h.sum(axis=1, keepdims=True), 1e-300)
    if k < J:
        kth = -np.partition(-h, k, axis=1)[:, k:k + 1]          # the (k + 1)-th largest per row
        top = -np.partition(-h, 0, axis=1)[:, :1]
        # a row whose k + 1 largest are all equal would prune to nothing: keep it unpruned
        h = np.where(top > kth, np.clip(h - kth, 0.0, None), h)
    kk = min(k, J)
    idx = np.argpartition(-h, kk - 1, axis=1)[:, :kk] if kk < J else np.tile(np.arange(J), (P, 1))
    val = np.take_along_axis(h, idx, axis=1)
    order = np.argsort(-val, axis=1, kind="stable")
    idx = np.take_along_axis(idx, order, axis=1)
    val = np.take_along_axis(val, order, axis=1)
    val /= val.sum(axis=1, keepdims=True)
    joints = np.zeros((P, k), np.int32)
    weights = np.zeros((P, k), np.float32)
    joints[:, :kk] = idx
    weights[:, :kk] = val
    weights /= weights.sum(axis=1, keepdims=True, dtype=np.float64).astype(np.float32)
    return joints, weights
