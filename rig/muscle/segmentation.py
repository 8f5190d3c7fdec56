"""Skin segmentation by bone proximity and a surface normal test (Pratscher et al. 2005, section 3.1).

The skin is split into regions, one per bone segment, so that a muscle pair can be fitted to each
region. A vertex p goes to the closest bone segment among those that pass the normal test

    n' . (p - p') >= 0          p' = the closest point of the segment to p,
                                n' = p's low-frequency normal,

i.e. the skin there faces away from the bone. This keeps the trunk off the arm bones in a "da Vinci"
pose: the side of the trunk under a hanging arm is closer to the arm bone than to the spine, but it
faces the arm bone, so the arm rejects it. A vertex that no bone accepts falls back to the nearest
bone (`Segmentation.accepted` is False there). `normal_test=False` gives plain proximity. Exact ties
(the closest point is a joint that ends one bone and starts another: the outer side of every bend)
go to a bone starting at that joint, see `assign`.

Low-frequency normals: the paper's Laplacian smoothing of the normals, iterated (25 passes, lam = 1,
tuned by the paper on humans of ~10,000 vertices):

    n'_{k+1} = normalise((1 - lam_v) n'_k + lam_v normalise(sum_{i in one-ring of v} n'_k,i)),  n'_0 = n

The one-ring comes from a sparse vertex adjacency of the mesh welded by position (glTF splits
vertices along UV seams; without the weld the smoothing would stop at every seam). A vertex with no
neighbours keeps its normal.

One reading of the paper is ours: lam_v = lam where the mesh is at least as fine as the paper's
(`reference_vertices` = 10,000 vertices spread over the same surface area), and
lam (h_ref / h_v)^2 where its edges h_v are longer than that mesh's h_ref. A pass of one-ring
averaging spreads a normal over about one edge length, so on a coarse mesh 25 passes smooth over a
far wider area than the paper meant: on a limb only a few edges around, the radial part of the normals
cancels pass after pass and the normals end up pointing along the limb (CesiumMan's 2,338 positions:
median |n' . radial| 0.04 on the upper arm after 25 literal passes), which turns the test against
the limb's own bone (inner knees went to the other leg). Scaling lam by the squared edge ratio makes
each pass diffuse as far (in metres) as at the paper's density. At that density or finer it is the
paper's formula as written; `reference_vertices=None` applies the formula as written everywhere.

Bone segments (`bone_segments`): one per (joint, child) with non-zero length, from the joint's bind
position to the child's. A child at its parent's place (a zero-length link such as CMU's LHipJoint
below Hips) is collapsed: its own children become the parent's targets (Hips>LeftUpLeg), and the
collapsed joint starts no segment of its own (its bone would repeat the collapsed one). A leaf joint
(no child) gets a segment to its end site (`rig.character.character.end_sites`) when it has one; otherwise the
end is estimated from the skin the leaf dominates (`Character.joints[:, 0]`), see `_leaf_end`.

Region -> joint mapping (how a segmentation is compared with an artist's skin weights): a segment
from joint j to a child belongs to joint j, the joint whose frame it moves with (as in linear blend
skinning and in rig.character.bone_heat); a joint collapsed into its parent by a zero-length link maps to the
parent's segments. A vertex's region matches the artist when the segment's parent joint is the
vertex's dominant joint. On CesiumMan, among the 2,298 vertices whose dominant weight is >= 0.8:
99.96% for the normal test (defaults), 99.96% for plain proximity, 98.96% for the literal 25 passes
(`reference_vertices=None`); over all 3,273 vertices 94.5% against 94.3% for plain proximity.
tests/muscle/test_segmentation.py prints the figures.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array

PAPER_VERTICES = 10_000
"""Vertex count of the human meshes the paper tuned 25 passes with lam = 1 on."""
LEAF_MIN_FRACTION = 0.2
"""A leaf bone estimated from the skin is at least this share of its incoming bone's length."""
PARALLEL_SIN = 0.1
"""When the character's front is within asin(0.1) ~ 5.7 deg of a bone, the frame uses world +Z
made perpendicular to the bone instead (see `BoneSegments.frames`)."""
TIE_FRACTION = 1e-7
"""Distances to two bones equal within this share of the skeleton's size are a tie (see `assign`)."""
_CHUNK = 1 << 21
"""Elements of one (rows, S) block in the vertex x segment passes (bounds the scratch memory)."""


@dataclass(frozen=True, eq=False)
class BoneSegments:
    """The bone segments of a character at bind, in world metres. Arrays are read-only.

    Attributes
    ----------
    parent : (S,) int32, joint index of each bone's start joint.
    child : (S,) int32, joint index of the end joint, -1 for a leaf bone ending at an estimated end.
    start, end : (S, 3) float64 metres, bind world positions of the bone's ends.
    labels : S names, "parentname>childname" or "parentname>end".
    """

    parent: np.ndarray
    child: np.ndarray
    start: np.ndarray
    end: np.ndarray
    labels: tuple[str, ...]

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("parent", frozen_array(self.parent, np.int32))
        set_("child", frozen_array(self.child, np.int32))
        set_("start", frozen_array(np.reshape(self.start, (-1, 3))))
        set_("end", frozen_array(np.reshape(self.end, (-1, 3))))
        set_("labels", tuple(self.labels))
        S = len(self.labels)
        assert self.parent.shape == self.child.shape == (S,) and self.start.shape == self.end.shape == (S, 3)

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def lengths(self) -> np.ndarray:
        """(S,) float64 metres."""
        return np.linalg.norm(self.end - self.start, axis=1)

    def index(self, label: str) -> int:
        """Segment index of `label`; InputError listing the known labels otherwise."""
        try:
            return self.labels.index(label)
        except ValueError:
            raise InputError(f"no bone segment {label!r}; known: {', '.join(self.labels)}",
                             field="segment") from None

    def frames(self, front) -> np.ndarray:
        """(S, 3, 3) float64 bone frames at bind, rows (e_along, e_front, e_side).

        e_along = unit(end - start); e_front = `front` (3,) (the character's front) made perpendicular
        to e_along (Gram-Schmidt), or world +Z made perpendicular when front lies within
        asin(PARALLEL_SIN) of the bone; e_side = cross(e_along, e_front), never flipped (it points to
        the character's left for the upright trunk, to its right for a downward leg).
        """
        f = np.asarray(front, np.float64)
        if f.shape != (3,) or not np.isfinite(f).all() or np.linalg.norm(f) == 0:
            raise InputError(f"front must be a finite non-zero (3,) vector, got {front!r}", field="front")
        f = f / np.linalg.norm(f)
        along = _unit(self.end - self.start)
        e_front = f - (along @ f)[:, None] * along
        up = np.array([0.0, 0.0, 1.0])
        e_up = up - (along @ up)[:, None] * along
        e_front = _unit(np.where((np.linalg.norm(e_front, axis=1) < PARALLEL_SIN)[:, None], e_up, e_front))
        return np.stack([along, e_front, np.cross(along, e_front)], axis=1)

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Closest points of every segment to points (N, 3) metres.

        Returns t (N, S) float64, the clamped fraction along each segment (0 at start, 1 at end) of
        the closest point p' = start + t (end - start), and dist (N, S) float64 metres, |p - p'|.
        """
        p = np.asarray(points, np.float64).reshape(-1, 3)
        t = np.empty((len(p), len(self)))
        d = np.empty_like(t)
        for rows in _blocks(len(p), len(self)):
            t[rows], d2 = _project(p[rows], self.start, self.end)
            d[rows] = np.sqrt(d2)
        return t, d


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _blocks(n: int, s: int):
    step = max(1, _CHUNK // max(s, 1))
    for i in range(0, n, step):
        yield slice(i, min(n, i + step))


def _project(p: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """t (N, S) clamped fraction and squared distance (N, S) from points p (N, 3) to the segments.

    Expanded into dot products so that no (N, S, 3) array is formed:
    |p - s - t ab|^2 = |p - s|^2 - 2 t (p - s).ab + t^2 |ab|^2, with (p - s).ab = p.ab - s.ab.
    In float64 at body scale (~1 m) the cancellation costs up to ~3e-8 m of distance (at a bone).
    """
    ab = end - start
    ll = np.einsum("sk,sk->s", ab, ab)
    ps_ab = p @ ab.T - np.einsum("sk,sk->s", start, ab)                               # (N, S)
    t = np.clip(ps_ab / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
    ps2 = np.einsum("nk,nk->n", p, p)[:, None] - 2.0 * p @ start.T + np.einsum("sk,sk->s", start, start)
    return t, np.maximum(ps2 - 2.0 * t * ps_ab + t * t * ll, 0.0)


# ---------------------------------------------------------------------------------- segments
def bone_segments(character, exclude: Iterable[str] = ()) -> BoneSegments:
    """The bone segments of `character` (a rig.character.character.Character) at bind; see the module docstring.

    exclude : joint names (drop every segment starting at that joint, or running through it when it
        was collapsed by a zero-length link) or segment labels (drop that segment). A name that is
        neither raises InputError; so does a skeleton without any bone of non-zero length, or an
        exclude that leaves none.
    """
    from jiggle.rig.character.character import end_sites

    pos = np.asarray(character.bind_positions, np.float64)
    par = np.asarray(character.parents, np.int64)
    names = tuple(character.joint_names)
    J = len(names)
    verts = np.asarray(character.vertices, np.float64)
    size = max(float(np.ptp(pos, axis=0).max()) if J else 0.0,
               float(np.ptp(verts, axis=0).max()) if len(verts) else 0.0)
    eps = 1e-6 * max(size, 1e-9)
    children = [[] for _ in range(J)]
    for c in range(J):
        if par[c] >= 0:
            children[par[c]].append(c)
    zero = np.array([par[c] >= 0 and np.linalg.norm(pos[c] - pos[par[c]]) <= eps for c in range(J)], bool)

    def reach(j: int, via: tuple[int, ...] = ()) -> list[tuple[int, tuple[int, ...]]]:
        """(target, collapsed joints passed) of the segments from j: its children, through zero-length links."""
        out = []
        for c in children[j]:
            out.extend(reach(c, via + (c,)) if zero[c] else [(c, via)])
        return out

    ends = end_sites(character.skeleton)
    dominant = np.asarray(character.joints[:, 0]) if len(verts) else np.zeros(0, np.int64)
    rows = []  # (parent, child, start, end, label, joints the segment belongs to)
    for j in range(J):
        if zero[j]:
            continue  # collapsed into its parent, which starts its bones
        targets = reach(j)
        for c, via in targets:
            rows.append((j, c, pos[j], pos[c], f"{names[j]}>{names[c]}", {j, *via}))
        if not targets:
            tip = _leaf_end(j, pos, par, ends, verts, dominant, eps)
            if tip is not None:
                rows.append((j, -1, pos[j], tip, f"{names[j]}>end", {j}))
    if not rows:
        raise InputError(f"the skeleton of {J} joints has no bone of non-zero length to segment the skin by",
                         character.source or None, field="skeleton")
    drop = _excluded(rows, names, exclude)
    kept = [r for r, d in zip(rows, drop) if not d]
    if not kept:
        raise InputError(f"exclude={tuple(exclude)!r} leaves no bone segment", field="exclude")
    return BoneSegments(np.array([r[0] for r in kept]), np.array([r[1] for r in kept]),
                        np.array([r[2] for r in kept]), np.array([r[3] for r in kept]), tuple(r[4] for r in kept))


def _excluded(rows, names: tuple[str, ...], exclude) -> list[bool]:
    if isinstance(exclude, str):
        exclude = (exclude,)
    labels = [r[4] for r in rows]
    drop = [False] * len(rows)
    for e in exclude:
        if e in labels:
            drop[labels.index(e)] = True
        elif e in names:
            j = names.index(e)
            drop = [d or j in r[5] for d, r in zip(drop, rows)]
        else:
            raise InputError(f"{e!r} is neither a joint nor a bone segment; segments: {', '.join(labels)}",
                             field="exclude")
    return drop


def _leaf_end(j, pos, par, ends, vertices, dominant, eps) -> np.ndarray | None:
    """(3,) end point of leaf joint j's bone, or None when it has none (a lone joint).

    Its end site when it has one. Otherwise the bone points from the joint to the centroid of the
    skin it dominates (a toe runs forward although the foot bone ending at it points down), or
    continues the incoming bone when that centroid is too close to tell a direction, and it reaches
    the dominated skin's farthest extent along that direction less the skin's median distance from
    the bone line, at least LEAF_MIN_FRACTION of the incoming bone. A bone ending at the very tip would
    leave the tip's cap square to the bone (n . (p - p') ~ 0: on CesiumMan, crown vertices failed the
    head bone's test and went to the neck); one ending a radius short sees the cap from inside, as a
    sphere's centre sees its surface.
    """
    if np.isfinite(ends[j]).all() and np.linalg.norm(ends[j] - pos[j]) > eps:
        return ends[j]
    c = j  # the nearest non-zero bone ending at j or above it, so a leaf behind a zero-length link works
    incoming = np.zeros(3)
    while par[c] >= 0:
        d = pos[c] - pos[par[c]]
        if np.linalg.norm(d) > eps:
            incoming = d
            break
        c = par[c]
    length_in = float(np.linalg.norm(incoming))
    if length_in <= eps:
        return None
    least = LEAF_MIN_FRACTION * length_in
    rel = vertices[dominant == j] - pos[j]
    if len(rel) == 0:
        return pos[j] + least * incoming / length_in
    centre = rel.mean(axis=0)
    u = centre / np.linalg.norm(centre) if np.linalg.norm(centre) >= least else incoming / length_in
    along = rel @ u
    radius = float(np.median(np.linalg.norm(rel - along[:, None] * u, axis=1)))
    return pos[j] + max(float(along.max()) - radius, least) * u


# ---------------------------------------------------------------------------------- normals
def _one_ring(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray, float]:
    """The welded mesh's one-ring, for the original vertices.

    Returns R (V, V) csr with (R n)_v = the sum of the normals of v's one-ring neighbours (a
    neighbour position shared by seam duplicates counts once, with their mean normal), edge (V,) the
    mean length in metres of the edges at each vertex's position (0 when it has none), and the welded
    mesh's area in m^2.
    """
    from jiggle.rig.character.bone_heat import weld

    V = len(vertices)
    pts, wf, inverse = weld(vertices, faces)
    P = len(pts)
    i = wf.ravel()
    j = np.roll(wf, -1, axis=1).ravel()
    A = sp.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(P, P)).tocsr()
    A.data[:] = 1.0  # an edge shared by two faces is one neighbour
    count = np.bincount(inverse, minlength=P).astype(np.float64)
    mean = sp.csr_matrix((1.0 / count[inverse], (inverse, np.arange(V))), shape=(P, V))
    scatter = sp.csr_matrix((np.ones(V), (np.arange(V), inverse)), shape=(V, P))
    # each undirected edge appears in one or two faces; the mean over (edge, face) pairs is close enough
    length = np.linalg.norm(pts[i] - pts[j], axis=1)
    total = np.bincount(np.r_[i, j], weights=np.r_[length, length], minlength=P)
    n = np.bincount(np.r_[i, j], minlength=P)
    edge = np.where(n > 0, total / np.maximum(n, 1), 0.0)
    tri = pts[wf]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    return (scatter @ A @ mean).tocsr(), edge[inverse], area


def smoothed_normals(vertices, faces, normals, iterations: int = 25, lam: float = 1.0, *,
                     reference_vertices: int | None = PAPER_VERTICES) -> np.ndarray:
    """(V, 3) float64 unit low-frequency normals (see the module docstring).

    vertices : (V, 3) metres; faces : (F, 3) int; normals : (V, 3), need not be unit.
    iterations : passes of n' = normalise((1 - lam_v) n' + lam_v normalise(sum of the one-ring's n')).
    lam : in [0, 1]; 0 returns the (normalised) input.
    reference_vertices : lam_v = lam min(1, (h_ref / h_v)^2), h_v the mean edge length at v and h_ref
        the edge length of an equilateral mesh with this many vertices over the same area; None:
        lam_v = lam (the formula as written, at any density).
    Vertices without neighbours keep their normal; a zero input normal stays zero.
    """
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces).reshape(-1, 3)
    n = np.array(normals, np.float64)
    if n.shape != v.shape or not np.isfinite(n).all():
        raise InputError(f"normals must be finite {v.shape}, got shape {n.shape}", field="normals")
    if len(f) and (not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= len(v)):
        raise InputError(f"faces must be (F, 3) integers indexing 0..{len(v) - 1}", field="faces")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise InputError(f"iterations must be an integer >= 0, got {iterations!r}", field="iterations")
    if not 0.0 <= float(lam) <= 1.0:
        raise InputError(f"lam must lie in [0, 1], got {lam!r}", field="lam")
    if reference_vertices is not None and not reference_vertices > 0:
        raise InputError(f"reference_vertices must be positive or None, got {reference_vertices!r}",
                         field="reference_vertices")
    n = _normalise(n)
    if iterations == 0 or lam == 0.0 or len(n) == 0 or len(f) == 0:
        return n
    R, edge, area = _one_ring(v, f.astype(np.int64))
    lam_v = np.full((len(n), 1), float(lam))
    if reference_vertices is not None:
        # an equilateral triangle of side h has area sqrt(3)/4 h^2 and a closed mesh has ~2 V faces
        h_ref = np.sqrt(2.0 * area / (np.sqrt(3.0) * reference_vertices))
        coarse = edge > h_ref
        lam_v[coarse, 0] *= (h_ref / edge[coarse]) ** 2
    for _ in range(iterations):
        ring = _normalise(R @ n)
        # no neighbour (or a ring that cancels exactly): keep the vertex's own normal
        ring = np.where(np.any(ring != 0.0, axis=1, keepdims=True), ring, n)
        n = _normalise((1.0 - lam_v) * n + lam_v * ring)
    return n


def _normalise(n: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)


# ---------------------------------------------------------------------------------- segmentation
@dataclass(frozen=True, eq=False)
class Segmentation:
    """The skin split into bone regions. Arrays are read-only.

    Attributes
    ----------
    segments : BoneSegments, the bones the regions belong to.
    region : (V,) int32, segment index of each vertex.
    accepted : (V,) bool, False where no bone passed the normal test and the nearest bone was used
        (vertices placed by `overrides` count as accepted).
    low_normals : (V, 3) float64 unit, the low-frequency normals the test used.
    """

    segments: BoneSegments
    region: np.ndarray
    accepted: np.ndarray
    low_normals: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "region", frozen_array(self.region, np.int32))
        object.__setattr__(self, "accepted", frozen_array(self.accepted, bool))
        object.__setattr__(self, "low_normals", frozen_array(self.low_normals))

    def vertices_of(self, s) -> np.ndarray:
        """(n,) int64 indices of the vertices in segment `s` (an index or a label)."""
        if isinstance(s, str):
            s = self.segments.index(s)
        return np.flatnonzero(self.region == s)

    def counts(self) -> np.ndarray:
        """(S,) int64 vertices per segment."""
        return np.bincount(self.region, minlength=len(self.segments))


def assign(points, normals, segments: BoneSegments, normal_test: bool = True
           ) -> tuple[np.ndarray, np.ndarray]:
    """Region (N,) int32 and accepted (N,) bool for points (N, 3) metres with unit normals (N, 3).

    Each point takes the closest segment whose test n . (p - p') >= 0 passes (any segment when
    `normal_test` is False: plain proximity), else the nearest segment with accepted False. Ties (the
    closest point is a joint that ends one bone and starts others: the skin around a bend's outer
    side; distances equal within TIE_FRACTION of the skeleton's size) go to a bone starting at that
    joint, the joint that moves that skin, and among several, to the one the point lies least far
    behind. Vectorised over (points, segments) blocks: n . (p - p') = n.p - n.s - t n.ab, all matrix
    products.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    start, ab = segments.start, segments.end - segments.start
    length = np.linalg.norm(ab, axis=1)
    tol = TIE_FRACTION * max(float(np.ptp(np.r_[start, segments.end], axis=0).max()), 1e-9)
    region = np.empty(len(p), np.int32)
    accepted = np.ones(len(p), bool)
    for rows in _blocks(len(p), len(segments)):
        t, d2 = _project(p[rows], start, segments.end)
        dist = np.sqrt(d2)
        # metres the point lies behind each segment's start (0 when it is level with or past it)
        behind = np.maximum(-(p[rows] @ ab.T - np.einsum("sk,sk->s", start, ab)) / np.maximum(length, 1e-300), 0.0)
        nearest = _closest_of(dist, t, behind, None, tol)
        if not normal_test:
            region[rows] = nearest
            continue
        nr = n[rows]
        facing = np.einsum("nk,nk->n", nr, p[rows])[:, None] - nr @ start.T - t * (nr @ ab.T) >= 0.0
        ok = facing.any(axis=1)
        region[rows] = np.where(ok, _closest_of(dist, t, behind, facing, tol), nearest)
        accepted[rows] = ok
    return region, accepted


def _closest_of(dist, t, behind, allowed, tol) -> np.ndarray:
    """(N,) the allowed column of least distance per row; among distances within tol of it, the least
    t (a bone starting at the shared joint), then the least `behind`. Rows with nothing allowed: 0."""
    d = dist if allowed is None else np.where(allowed, dist, np.inf)
    tie = d <= d.min(axis=1, keepdims=True) + tol
    t_tie = np.where(tie, t, np.inf)
    tie &= t_tie <= t_tie.min(axis=1, keepdims=True)
    return np.where(tie, behind, np.inf).argmin(axis=1)


def segment_skin(character, *, iterations: int = 25, lam: float = 1.0, exclude: Iterable[str] = (),
                 overrides: Mapping[str, Iterable[int]] | None = None, normal_test: bool = True,
                 reference_vertices: int | None = PAPER_VERTICES) -> Segmentation:
    """Segment `character`'s rest skin into bone regions (see the module docstring).

    iterations, lam, reference_vertices : normal smoothing (`smoothed_normals`).
    exclude : joint names or segment labels left out (`bone_segments`).
    overrides : {segment label: vertex indices} forced into that region after the test; a vertex
        named under two labels, an unknown label or an index out of range raise InputError.
    normal_test : False gives plain proximity (the nearest bone), for comparison.
    """
    segs = bone_segments(character, exclude)
    v = np.asarray(character.vertices, np.float64)
    low = smoothed_normals(v, character.faces, character.normals, iterations=iterations, lam=lam,
                           reference_vertices=reference_vertices)
    region, accepted = assign(v, low, segs, normal_test=normal_test)
    if overrides:
        taken = np.zeros(len(v), bool)
        for label, idx in overrides.items():
            s = segs.index(label)
            idx = np.asarray(idx if isinstance(idx, np.ndarray) else list(idx)).ravel()
            if idx.size and (not np.issubdtype(idx.dtype, np.integer) or idx.min() < 0 or idx.max() >= len(v)):
                raise InputError(f"overrides[{label!r}]: vertex indices must be integers in [0, {len(v)})",
                                 field="overrides")
            idx = idx.astype(np.int64)
            if taken[idx].any():
                raise InputError(f"overrides[{label!r}]: vertex {int(idx[taken[idx]][0])} is already given to "
                                 "another segment", field="overrides")
            taken[idx] = True
            region[idx] = s
            accepted[idx] = True
    return Segmentation(segs, region, accepted, low)
