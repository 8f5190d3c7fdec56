"""Conform an ellipsoidal muscle to the skin (Pratscher et al. 2005, section 3.3).

For each vertex p of the ellipsoid's mesh and its projection p' on the major axis, a ray from p'
through p meets the skin at p_i (embree, the first hit). The reshaped vertex is

    p_r = p' + (1 - exp((d - 1) nu)) (p_i - p')

with d = |p' - centre| / major radius in [0, 1]: near the middle the muscle reaches almost to the
skin (1 - e^-nu), toward the tips it falls back to the axis, so the muscle stays fusiform. `nu`
(default 3) sets how fast.

Muscle pairs share a partition plane through the bone's centre. A ray pointing away from the plane
(toward this muscle's own side) is not changed. A ray pointing toward the plane would, taken to the
skin, run through the partner muscle to the far side of the limb; the paper attenuates it by
|(p - p').theta|. Read literally (a weight equal to the ray's alignment with theta) that inflates a ray
aimed straight at the plane fully, through the partner, and drops to zero for rays along the plane,
where rays on the other side get full weight: a crease. We read "attenuate by" as "reduce by": the
adjustment p_r - p of such a ray is scaled by 1 - |dir . theta| (1 along the plane, 0 straight at it,
continuous with the rays that point away), and its target is clipped at the plane, so the two
muscles of a pair never cross it.

Rays that miss the skin, hit it farther than `reach` times the ellipsoid's radius in that direction
(a thin muscle's inward rays would otherwise cross the body to the far side), or hit skin outside
the muscle's own bone region (a deltoid's rays reaching the neck), keep the ellipsoid's vertex. Last,
no vertex may lie past the first skin along its ray (whichever bone's skin that is): one that does is
moved back onto it, so a muscle lies inside the body even where the body is thinner than the
ellipsoid of its region.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.muscle.ellipsoid import Ellipsoid


@dataclass(frozen=True)
class ConformReport:
    """hits: rays that reached the skin and were used; misses: rays that kept the ellipsoid."""

    hits: int
    misses: int


def first_hits(mesh, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (N,) along each unit ray (origins, directions (N, 3)) to its first hit on the trimesh
    `mesh` (inf where it misses) and the triangle hit (N,) (-1 where it misses). Uses embree through
    trimesh when it is installed."""
    dist = np.full(len(origins), np.inf)
    tri = np.full(len(origins), -1, dtype=np.int64)
    if len(origins) == 0:
        return dist, tri
    loc, ray, index_tri = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    if len(ray):
        d = np.einsum("ij,ij->i", loc - origins[ray], directions[ray])
        dist[ray] = np.where(d >= 0, d, np.inf)
        tri[ray] = index_tri
    return dist, tri


def conform(ellipsoid: Ellipsoid, points: np.ndarray, skin_mesh, *, nu: float = 3.0,
            plane: tuple[np.ndarray, np.ndarray] | None = None, reach: float = 3.0,
            allowed: np.ndarray | None = None, faces: np.ndarray | None = None, smoothing: int = 0
            ) -> tuple[np.ndarray, ConformReport]:
    """Reshape the ellipsoid's mesh vertices `points` (N, 3) toward the skin.

    skin_mesh : trimesh.Trimesh of the character's rest skin.
    nu : attenuation along the major axis (> 0).
    plane : (point, normal) of a pair's partition plane, normal unit and pointing to this muscle's side.
    reach : hits farther than `reach` x the ellipsoid's radius along the ray are ignored.
    allowed : (F,) bool over the skin's triangles: hits elsewhere are ignored (the muscle conforms to
        the skin of its own bone, not to a neighbouring limb or the trunk seen past a joint).
    faces, smoothing : the mesh's triangles and a number of smoothing passes over the displacement
        (each vertex's move averaged half-and-half with its neighbours'): a ray that slips into a fold
        of the skin makes a spike that the lofted muscle cannot follow; smoothing keeps it a bulge.
    Returns the conformed points (N, 3) and a ConformReport.
    """
    p = np.asarray(points, dtype=np.float64)
    c, a = ellipsoid.centre, ellipsoid.axes[0]
    s = (p - c) @ a
    foot = c + s[:, None] * a
    d = np.clip(np.abs(s) / ellipsoid.radii[0], 0.0, 1.0)
    radial = p - foot
    r = np.linalg.norm(radial, axis=1)
    ok = r > 1e-9 * ellipsoid.radii[0]
    direction = np.zeros_like(p)
    direction[ok] = radial[ok] / r[ok, None]
    dist = np.full(len(p), np.inf)
    tri = np.full(len(p), -1, dtype=np.int64)
    dist[ok], tri[ok] = first_hits(skin_mesh, foot[ok], direction[ok])
    skin_at = dist.copy()  # the first skin along each ray, whichever bone's: the muscle stays inside it
    if allowed is not None:
        dist[(tri < 0) | ~np.asarray(allowed, bool)[np.maximum(tri, 0)]] = np.inf
    # the ellipsoid's own extent along each ray, to judge how far a hit may be
    local_dir = (direction @ ellipsoid.axes.T) / ellipsoid.radii
    own = 1.0 / np.maximum(np.linalg.norm(local_dir, axis=1), 1e-12)
    weight = np.ones(len(p))
    if plane is not None:
        origin, theta = np.asarray(plane[0], float), np.asarray(plane[1], float)
        toward = direction @ theta
        into = toward < 0
        # distance along the ray to the partition plane, from a foot on this muscle's side
        gap = (foot - origin) @ theta
        to_plane = np.where(into & (gap > 0), gap / np.maximum(-toward, 1e-12), np.inf)
        dist = np.where(into, np.minimum(dist, to_plane), dist)
        weight = np.where(into, 1.0 - np.abs(toward), 1.0)
    hit = np.isfinite(dist) & (dist <= reach * own) & ok
    target = foot + direction * np.where(hit, dist, 0.0)[:, None]
    conformed = foot + (1.0 - np.exp((d - 1.0) * nu))[:, None] * (target - foot)
    # the pair attenuation scales the adjustment (the change from the ellipsoid), so an attenuated
    # ray keeps the ellipsoid's vertex rather than collapsing onto the axis
    move = np.zeros_like(p)
    move[hit] = weight[hit, None] * (conformed[hit] - p[hit])
    if smoothing and faces is not None and len(p):
        import scipy.sparse as sp
        f = np.asarray(faces)
        i, j = np.concatenate([f[:, 0], f[:, 1], f[:, 2]]), np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        adj = sp.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(len(p), len(p))).tocsr()
        adj.data[:] = 1.0
        adj = sp.diags(1.0 / np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)) @ adj
        for _ in range(smoothing):
            move = 0.5 * move + 0.5 * (adj @ move)
    out = p + move
    # no vertex beyond the skin: a ray that kept the ellipsoid's vertex (its hit was on another bone's
    # skin, past the reach, or across the partition plane) may start out past the skin where the body is
    # thinner than the region's ellipsoid (a dog's upper foreleg inside its chest); pull it back onto the
    # first skin along its ray
    along = np.einsum("ij,ij->i", out - foot, direction)
    over = ok & np.isfinite(skin_at) & (along > skin_at)
    out[over] -= (along[over] - skin_at[over])[:, None] * direction[over]
    return out, ConformReport(hits=int(hit.sum()), misses=int(len(p) - hit.sum()))
