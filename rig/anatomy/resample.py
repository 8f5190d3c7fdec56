"""Put new vertices into a triangle mesh at given surface points, keeping the surface and its winding.

The paper (Simmons et al. 2002, section 2) re-samples the skin "to ensure that it contains vertices
corresponding to nearby underlying components": a feature point found on a triangle becomes a vertex.
:func:`insert_points` does that by splitting triangles; the surface does not change (every new face
lies in its parent's plane, and the parent's area is the sum of its children's).

Splits
    A point inside triangle (c0, c1, c2) splits it 1-to-3 into (c0, c1, p), (c1, c2, p), (c2, c0, p);
    a point on an edge (its barycentric coordinate opposite corner k below `edge_tol`, set to 0) splits
    it 1-to-2 into (ck, ck+1, p), (ck, p, ck+2), and every other face sharing that edge (by vertex
    index) the same way, so no T-junction is left. Both keep the parent's winding: each child is the
    parent with one corner replaced by a point of the parent's closed triangle. A point at a corner
    (two coordinates below `edge_tol`) is not inserted: it maps to that corner's vertex. An edge
    shared only by position (glTF splits vertices at UV seams) is a boundary to this module: an edge
    point there splits one side, a T-junction that is closed at rest.
Several points in one triangle
    are inserted in rounds: each round splits every triangle holding pending points at one of them
    (at most one operation per face per round), then re-locates the triangle's other points into the
    child that contains them.
Representation
    Every vertex of the new mesh is a barycentric combination of ORIGINAL vertices, three (source,
    bary) pairs of the original face it lies in (an original vertex i is (i, i, i), (1, 0, 0)). Points
    are located in a child by solving for their coordinates in the child's corners, all expressed in
    the original face's corners, so positions are never rebuilt from rounded intermediate positions:
    a new vertex is ``sum_k bary[k] vertices[source[k]]``, the given point to rounding.

:func:`carry` interpolates any per-vertex attribute (positions, uvs, normals) onto the new mesh with
those weights; :func:`carry_weights` combines skin weights (top-k of the blended influences);
:func:`resample_character` gives a Character on the new skin.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array

EDGE_TOL = 1e-9
"""Barycentric coordinate below which a point counts as on the opposite edge (or at a corner)."""


@dataclass(frozen=True, eq=False)
class Resampled:
    """A mesh with inserted vertices, each expressed over the original mesh. Arrays are read-only.

    vertices : (V', 3) float64, metres; the first `original` rows are the original vertices, in order.
    faces : (F', 3) int32, the new triangles, wound as their parents.
    source : (V', 3) int64, original vertices each new-mesh vertex blends ((i, i, i) for original i).
    bary : (V', 3) float64, their weights (rows sum to 1; (1, 0, 0) for an original vertex).
    original : V, the number of original vertices.
    face_origin : (F',) int64, the original face each new face lies in.
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: np.ndarray
    bary: np.ndarray
    original: int
    face_origin: np.ndarray

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("vertices", frozen_array(np.reshape(self.vertices, (-1, 3))))
        set_("faces", frozen_array(np.reshape(self.faces, (-1, 3)), np.int32))
        set_("source", frozen_array(np.reshape(self.source, (-1, 3)), np.int64))
        set_("bary", frozen_array(np.reshape(self.bary, (-1, 3))))
        set_("face_origin", frozen_array(self.face_origin, np.int64))
        set_("original", int(self.original))
        n = len(self.vertices)
        assert self.source.shape == self.bary.shape == (n, 3) and 0 <= self.original <= n
        assert self.face_origin.shape == (len(self.faces),)

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    @property
    def inserted(self) -> int:
        """Number of vertices added to the original mesh."""
        return len(self.vertices) - self.original


def identity(vertices, faces) -> Resampled:
    """The mesh itself as a Resampled with nothing inserted."""
    v = _check_vertices(vertices)
    f = _check_faces(faces, len(v))
    i = np.arange(len(v), dtype=np.int64)
    b = np.zeros((len(v), 3))
    b[:, 0] = 1.0
    return Resampled(v, f, np.stack([i, i, i], axis=1), b, len(v), np.arange(len(f), dtype=np.int64))


# ---------------------------------------------------------------------------------- checks
def _check_vertices(vertices) -> np.ndarray:
    v = np.asarray(vertices)
    if v.ndim != 2 or v.shape[1] != 3 or not np.issubdtype(v.dtype, np.number):
        raise InputError(f"expected a (V, 3) float array, got shape {v.shape} dtype {v.dtype}", field="vertices")
    v = v.astype(np.float64)
    if not np.isfinite(v).all():
        raise InputError("vertex positions contain NaN or inf", field="vertices")
    return v


def _check_faces(faces, num_vertices: int) -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not (f.size == 0 or np.issubdtype(f.dtype, np.integer)):
        raise InputError(f"expected an (F, 3) int array, got shape {f.shape} dtype {f.dtype}", field="faces")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= num_vertices):
        raise InputError(f"indices must lie in [0, {num_vertices}), found [{f.min()}, {f.max()}]", field="faces")
    return f


# ---------------------------------------------------------------------------------- insertion
def insert_points(vertices, faces, face, bary, *, edge_tol: float = EDGE_TOL) -> tuple[Resampled, np.ndarray]:
    """Insert points given on the mesh's triangles as new vertices (see the module docstring).

    Parameters
    ----------
    vertices : (V, 3) float, metres; faces : (F, 3) int.
    face : (n,) int, the triangle each point lies in.
    bary : (n, 3) float, the point's barycentric coordinates in that triangle's corners (>= 0 up to
        1e-6, renormalised to sum 1; small negative rounding is clipped to 0).
    edge_tol : a coordinate below this counts as 0 (the point is on an edge, or at a corner).

    Returns
    -------
    (Resampled, new_vertex (n,) int64): the vertex of each point in the new mesh. Points at a corner
    map to that corner's vertex; two points at the same place share one vertex (the second finds the
    first at a corner).
    """
    V0 = _check_vertices(vertices)
    F0 = _check_faces(faces, len(V0))
    fc, b = _check_points(face, bary, F0, edge_tol)
    mesh = _Refinement.start(V0, F0, fc, b)
    while True:
        pending = np.nonzero(mesh.new_vertex < 0)[0]
        if pending.size == 0:
            break
        where = mesh.locate(pending, edge_tol)
        mesh.snap_to_corners(where)
        ops = mesh.claim_splits(where)
        if not ops:
            continue                                # only corner points this round: all resolved
        ids = mesh.add_vertices(where, ops)
        mesh.relocate(mesh.split_faces(ops, ids))

    V = len(V0)
    S, W = mesh.blends()
    verts = np.einsum("vk,vkx->vx", W, V0[S])
    verts[:V] = V0                                  # the original vertices exactly
    return Resampled(verts, mesh.cur, S, W, V, mesh.origin), mesh.new_vertex


def _check_points(face, bary, F0: np.ndarray, edge_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The points checked: their faces (n,) int64 in `F0` (F, 3) and their barycentric coordinates (n, 3)
    float64, clipped to >= 0 and renormalised to sum 1."""
    fc = np.asarray(face)
    if fc.ndim != 1 or not (fc.size == 0 or np.issubdtype(fc.dtype, np.integer)):
        raise InputError(f"expected an (n,) int array, got shape {fc.shape} dtype {fc.dtype}", field="face")
    fc = fc.astype(np.int64)
    if fc.size and (fc.min() < 0 or fc.max() >= len(F0)):
        raise InputError(f"face indices must lie in [0, {len(F0)}), found [{fc.min()}, {fc.max()}]", field="face")
    b = np.asarray(bary)
    if b.shape != (len(fc), 3) or not np.issubdtype(b.dtype, np.number):
        raise InputError(f"expected ({len(fc)}, 3) float coordinates, got shape {b.shape} dtype {b.dtype}",
                         field="bary")
    b = b.astype(np.float64)
    if not np.isfinite(b).all() or (b < -1e-6).any() or (np.abs(b.sum(1) - 1.0) > 1e-6).any():
        raise InputError("barycentric coordinates must be finite, >= 0 and sum to 1", field="bary")
    if not 0.0 <= edge_tol < 1.0 / 3.0:
        raise InputError(f"expected a tolerance in [0, 1/3), got {edge_tol!r}", field="edge_tol")
    if fc.size:
        rep = F0[fc]
        bad = (rep[:, 0] == rep[:, 1]) | (rep[:, 1] == rep[:, 2]) | (rep[:, 0] == rep[:, 2])
        if bad.any():
            raise InputError(f"points lie in faces with a repeated vertex (first: face {int(fc[bad][0])})",
                             field="face")
    b = np.maximum(b, 0.0)
    b /= b.sum(1, keepdims=True)
    return fc, b


@dataclass(frozen=True, eq=False)
class _Located:
    """Where the pending points lie at the start of a round, and the vertex blends then."""

    pending: np.ndarray     # (m,) int64, the points without a vertex yet
    local: np.ndarray       # (m, 3) float64, their barycentric coordinates in their current face
    small: np.ndarray       # (m, 3) bool, the coordinates below edge_tol
    zeros: np.ndarray       # (m,) int, how many: 0 inside, 1 on an edge, 2 or 3 at a corner
    S: np.ndarray           # (nv, 3) int64 and (nv, 3) float64: every vertex's (source, bary)
    W: np.ndarray


@dataclass(eq=False)
class _Refinement:
    """The mesh while points go in, round by round. Every vertex is a blend of original vertices (the
    batches of `src` (m, 3) int64 / `bw` (m, 3) float64, original vertices first); `cur` (F', 3) int64
    are the current faces, `origin` (F',) int64 the original face of each; `new_vertex` (n,) int64 is
    each point's vertex (-1 while pending) and `pf` (n,) int64 its current face, a descendant of the
    original face `b` (n, 3) float64 gives its coordinates in."""

    V0: np.ndarray
    F0: np.ndarray
    b: np.ndarray
    src: list
    bw: list
    nv: int
    cur: np.ndarray
    origin: np.ndarray
    new_vertex: np.ndarray
    pf: np.ndarray

    @classmethod
    def start(cls, V0: np.ndarray, F0: np.ndarray, fc: np.ndarray, b: np.ndarray) -> _Refinement:
        """The original mesh (V0 (V, 3), F0 (F, 3)) with the points (faces fc (n,), coordinates b (n, 3))
        all pending."""
        V = len(V0)
        iv = np.arange(V, dtype=np.int64)
        return cls(V0=V0, F0=F0, b=b, src=[np.stack([iv, iv, iv], axis=1)], bw=[np.tile([1.0, 0.0, 0.0], (V, 1))],
                   nv=V, cur=F0.copy(), origin=np.arange(len(F0), dtype=np.int64),
                   new_vertex=np.full(len(fc), -1, dtype=np.int64),
                   pf=fc.copy())            # current face of each pending point (a descendant of fc)

    def blends(self) -> tuple[np.ndarray, np.ndarray]:
        """Every vertex's (source (nv, 3) int64, bary (nv, 3) float64) over the original vertices."""
        return np.concatenate(self.src), np.concatenate(self.bw)

    def locate(self, pending: np.ndarray, edge_tol: float) -> _Located:
        """Where the `pending` points lie in their current faces."""
        S, W = self.blends()
        pf, F0, origin = self.pf, self.F0, self.origin
        l = _local(self.cur[pf[pending]], F0[origin[pf[pending]]], S, W, self.b[pending])
        small = l <= edge_tol
        return _Located(pending, l, small, small.sum(1), S, W)

    def snap_to_corners(self, at: _Located) -> None:
        """Give the points at a corner that corner's vertex (no insertion)."""
        corner = at.zeros >= 2
        if corner.any():
            k = np.argmax(at.local[corner], axis=1)
            self.new_vertex[at.pending[corner]] = self.cur[self.pf[at.pending[corner]], k]

    def claim_splits(self, at: _Located) -> list:
        """This round's insertions, at most one per face: [(point, [(face, kind, k)])], kind 3 a point inside
        the face, 2 a point on its edge opposite corner k (every face on that edge split with it)."""
        cur, pf, pending, l, nv = self.cur, self.pf, at.pending, at.local, self.nv
        claimed = np.zeros(len(cur), bool)
        ops = []                                   # (point, [(face, kind, k)]) kinds: 3 split, 2 edge split
        inner = np.nonzero(at.zeros == 0)[0]
        if inner.size:
            _, first = np.unique(pf[pending[inner]], return_index=True)
            chosen = inner[first]
            claimed[pf[pending[chosen]]] = True
            ops.extend((int(pending[i]), [(int(pf[pending[i]]), 3, -1)]) for i in chosen)
        on_edge = np.nonzero(at.zeros == 1)[0]
        if on_edge.size:
            keys, owner = _edge_index(cur, nv)
            for i in on_edge:
                p = int(pending[i])
                f = int(pf[p])
                k = int(np.argmin(l[i]))
                a, c = cur[f, (k + 1) % 3], cur[f, (k + 2) % 3]
                key = min(a, c) * nv + max(a, c)
                lo, hi = np.searchsorted(keys, [key, key + 1])
                group = [int(g) for g in owner[lo:hi]]
                if claimed[group].any():
                    continue                        # next round
                claimed[group] = True
                parts = [(f, 2, k)]
                for g in group:
                    if g != f:
                        kg = int(np.nonzero((cur[g] != a) & (cur[g] != c))[0][0])
                        parts.append((g, 2, kg))
                ops.append((p, parts))
        return ops

    def add_vertices(self, at: _Located, ops: list) -> np.ndarray:
        """New vertices (ids (m,) int64) for the points of `ops`, blended in their original faces: an edge
        point by its coordinates in the current face's corners, an inner one by its given coordinates."""
        cur, pf, F0, origin = self.cur, self.pf, self.F0, self.origin
        pts = np.array([p for p, _ in ops], dtype=np.int64)
        pos = np.searchsorted(at.pending, pts)
        lw = at.local[pos].copy()
        lw[at.small[pos]] = 0.0
        lw /= lw.sum(1, keepdims=True)
        edge = at.zeros[pos] == 1
        cw = _corner_weights(cur[pf[pts]], F0[origin[pf[pts]]], at.S, at.W)        # (m, 3 corners, 3)
        weights = np.where(edge[:, None], np.einsum("mc,mcj->mj", lw, cw), self.b[pts])
        ids = self.nv + np.arange(len(pts), dtype=np.int64)
        self.src.append(F0[origin[pf[pts]]])
        self.bw.append(weights)
        self.nv += len(pts)
        self.new_vertex[pts] = ids
        return ids

    def split_faces(self, ops: list, ids: np.ndarray) -> dict:
        """Split the faces of `ops` at their new vertices `ids`, each keeping its winding; returns {face:
        [face, its new children]}."""
        add, add_origin, children = [], [], {}
        cur, origin = self.cur, self.origin
        F = len(cur)
        for (p, parts), q in zip(ops, ids):
            for g, kind, k in parts:
                c0, c1, c2 = cur[g]
                kids = [g]
                if kind == 3:
                    new = [(c1, c2, q), (c2, c0, q)]
                    cur[g] = (c0, c1, q)
                else:
                    ck, ck1, ck2 = cur[g, k], cur[g, (k + 1) % 3], cur[g, (k + 2) % 3]
                    new = [(ck, q, ck2)]
                    cur[g] = (ck, ck1, q)
                for tri in new:
                    kids.append(F + len(add))
                    add.append(tri)
                    add_origin.append(origin[g])
                children[g] = kids
        self.cur = np.concatenate([cur, np.array(add, dtype=np.int64).reshape(-1, 3)])
        self.origin = np.concatenate([origin, np.array(add_origin, dtype=np.int64)])
        return children

    def relocate(self, children: dict) -> None:
        """Move the still pending points of split faces into the child holding them (the child where their
        smallest coordinate is largest)."""
        pf, F0 = self.pf, self.F0
        moved = np.nonzero((self.new_vertex < 0) & np.isin(pf, np.fromiter(children, np.int64)))[0]
        if moved.size:
            S, W = self.blends()
            kids = np.full((moved.size, 3), -1, dtype=np.int64)
            for r, p in enumerate(moved):
                kk = children[int(pf[p])]
                kids[r, :len(kk)] = kk
            best = np.full(moved.size, -np.inf)
            pick = pf[moved].copy()
            for c in range(3):
                ok = np.nonzero(kids[:, c] >= 0)[0]
                if ok.size == 0:
                    continue
                g = kids[ok, c]
                m = _local(self.cur[g], F0[self.origin[g]], S, W, self.b[moved[ok]]).min(1)
                better = m > best[ok]
                best[ok[better]] = m[better]
                pick[ok[better]] = g[better]
            pf[moved] = pick


def _edge_index(faces: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted undirected edge keys min * nv + max of every face edge, and the face owning each."""
    a = faces[:, [1, 2, 0]].ravel()
    c = faces[:, [2, 0, 1]].ravel()
    keys = np.minimum(a, c) * nv + np.maximum(a, c)
    order = np.argsort(keys, kind="stable")
    return keys[order], np.repeat(np.arange(len(faces)), 3)[order]


def _corner_weights(tri: np.ndarray, orig: np.ndarray, S: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(m, 3, 3) weights over the original face's corners orig (m, 3) of the corners tri (m, 3) of
    current faces lying in it: a corner's (source, bary) entries matched to the original corners."""
    s = S[tri]                                                       # (m, 3 corners, 3 entries)
    w = W[tri]
    match = s[:, :, :, None] == orig[:, None, None, :]               # (m, corner, entry, slot)
    return np.einsum("mce,mces->mcs", w, match.astype(np.float64))


def _local(tri: np.ndarray, orig: np.ndarray, S: np.ndarray, W: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(m, 3) barycentric coordinates in the current faces tri (m, 3) of points given by their
    weights target (m, 3) over the original faces orig (m, 3): solve l @ C = target."""
    C = _corner_weights(tri, orig, S, W)
    if len(C) == 0:
        return np.zeros((0, 3))
    return np.linalg.solve(C.transpose(0, 2, 1), target[:, :, None])[:, :, 0]


# ---------------------------------------------------------------------------------- attributes
def carry(resampled: Resampled, attribute) -> np.ndarray:
    """A per-vertex attribute (V, ...) of the original mesh interpolated onto the new one: (V', ...),
    ``sum_k bary[:, k] attribute[source[:, k]]`` in float64 (cast back to the input's float dtype);
    the original vertices keep their values exactly."""
    a = np.asarray(attribute)
    if a.ndim < 1 or len(a) != resampled.original or not np.issubdtype(a.dtype, np.number):
        raise InputError(f"expected a numeric ({resampled.original}, ...) array, got shape {a.shape} dtype "
                         f"{a.dtype}", field="attribute")
    out_dtype = a.dtype if np.issubdtype(a.dtype, np.floating) else np.float64
    a64 = a.astype(np.float64)
    B = resampled.bary.reshape(resampled.bary.shape + (1,) * (a.ndim - 1))
    out = (B * a64[resampled.source]).sum(axis=1)
    out[:resampled.original] = a64
    return out.astype(out_dtype)


def carry_weights(resampled: Resampled, joints, weights, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Skin weights on the new mesh: each new vertex blends its source vertices' influences by its
    barycentric weights (the same joint from several sources is summed), keeps the k largest
    (default: the input's k), renormalised, descending; slots left empty hold joint 0 with weight 0.
    The original vertices keep their rows exactly. Returns joints (V', k) int32, weights (V', k) float32.
    """
    j = np.asarray(joints)
    w = np.asarray(weights)
    V = resampled.original
    if j.ndim != 2 or len(j) != V or not np.issubdtype(j.dtype, np.integer):
        raise InputError(f"expected ({V}, k) int joints, got shape {j.shape} dtype {j.dtype}", field="joints")
    if w.shape != j.shape or not np.issubdtype(w.dtype, np.number) or not np.isfinite(w).all() or (w < 0).any():
        raise InputError(f"expected {j.shape} finite non-negative weights, got shape {w.shape}", field="weights")
    k = j.shape[1] if k is None else int(k)
    if k < 1:
        raise InputError(f"expected k >= 1, got {k}", field="k")
    Vn = resampled.num_vertices
    out_j = np.zeros((Vn, k), np.int32)
    out_w = np.zeros((Vn, k), np.float32)
    if k >= j.shape[1]:
        out_j[:V, :j.shape[1]] = j
        out_w[:V, :j.shape[1]] = w
    else:                   # fewer slots than the input: the originals are cut to top-k too
        out_j[:V], out_w[:V] = _top_k(np.repeat(np.arange(V), j.shape[1]), j.ravel().astype(np.int64),
                                      w.astype(np.float64).ravel(), V, k)
    new = np.arange(V, Vn)
    if new.size == 0:
        return out_j, out_w
    src = resampled.source[new]                                                    # (n, 3)
    cj = j[src].reshape(len(new), -1).astype(np.int64)                             # (n, 3 kin)
    cw = (resampled.bary[new][:, :, None] * w[src].astype(np.float64)).reshape(len(new), -1)
    rows = np.repeat(np.arange(len(new)), cj.shape[1])
    out_j[V:], out_w[V:] = _top_k(rows, cj.ravel(), cw.ravel(), len(new), k)
    return out_j, out_w


def _top_k(rows: np.ndarray, joint: np.ndarray, weight: np.ndarray, n: int, k: int):
    """Per row, sum the weights of equal joints, keep the k largest, renormalise: (n, k) int32, float32."""
    J = int(joint.max()) + 1 if joint.size else 1
    key, inv = np.unique(rows * J + joint, return_inverse=True)
    total = np.bincount(inv, weight, minlength=len(key))
    r, jj = key // J, key % J
    order = np.lexsort((jj, -total, r))            # by row, then weight descending, then joint
    r, jj, total = r[order], jj[order], total[order]
    start = np.searchsorted(r, np.arange(n))
    rank = np.arange(len(r)) - start[r]
    keep = (rank < k) & (total > 0)
    oj = np.zeros((n, k), np.int32)
    ow = np.zeros((n, k), np.float64)
    oj[r[keep], rank[keep]] = jj[keep]
    ow[r[keep], rank[keep]] = total[keep]
    s = ow.sum(1, keepdims=True)
    if (s <= 0).any():
        raise InputError(f"{int((s <= 0).sum())} new vertices get no weight (their sources have none)",
                         field="weights")
    return oj, (ow / s).astype(np.float32)


def resample_character(character, resampled: Resampled):
    """The same character on the resampled skin: vertices and faces from `resampled`, normals, uvs and
    skin weights carried (normals renormalised), meta["resampled"] = {"inserted": n}."""
    V = character.num_vertices
    if not isinstance(resampled, Resampled) or resampled.original != V:
        got = resampled.original if isinstance(resampled, Resampled) else type(resampled).__name__
        raise InputError(f"expected a Resampled of this character's {V} vertices, got {got}", field="resampled")
    if not np.array_equal(resampled.vertices[:V], character.vertices):
        raise InputError("the resampled mesh's original vertices differ from the character's rest skin",
                         field="resampled")
    from jiggle.rig.character.normals import FALLBACK
    n = carry(resampled, character.normals)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 1e-12, n / np.where(length > 1e-12, length, 1.0), FALLBACK)
    n[:V] = character.normals
    uvs = None if character.uvs is None else carry(resampled, character.uvs)
    joints, weights = carry_weights(resampled, character.joints, character.weights)
    joints[:V], weights[:V] = character.joints, character.weights
    return replace(character, vertices=resampled.vertices, faces=resampled.faces, normals=n, uvs=uvs,
                   joints=joints, weights=weights,
                   meta={**character.meta, "resampled": {"inserted": resampled.inserted}})
