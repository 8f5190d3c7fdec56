"""Geodesic zones of a skin (Simmons et al. 2002, section 4): the skin split by body part, so that each
zone's RBF interpolant is built from the feature points of the zone and of its neighbours only.

"Euclidean distance within one geodesic zone or neighboring zones is a fair approximation of
geodesic distance": one leg never moves the other however close the two thighs are, because the two
thigh zones are not neighbours.

Zones. A bone segment (rig.muscle.segmentation.BoneSegments) belongs to the body part of the first joint
with a humanoid role (rig.motion.retarget.ROLES) on the way up from the segment's start joint:

    hips, spine, chest, left/right_shoulder   -> torso
    neck, head                                -> head
    <side>_upper_arm | _lower_arm | _hand     -> <side>_upper_arm | _lower_arm | _hand (fingers too)
    <side>_upper_leg | _lower_leg | _foot, _toe -> <side>_upper_leg | _lower_leg | _foot

and a skin vertex to the zone of its segmentation region. Without roles (a creature that is not a
humanoid) every bone segment is a zone of its own.

Neighbours come from the skeleton, not from the mesh: two zones are neighbours when a segment of one
starts where a segment of the other starts or ends (they share a joint). At the crotch the two
thigh zones touch on the mesh but share no joint, so they stay apart, as the paper wants.

Blend. Near a boundary between neighbouring zones each vertex mixes the zones' interpolants with
a partition of unity, so the skin has no step where the zone changes: a vertex of zone a at geodesic
distance d (along the welded mesh edges, Dijkstra, metres) from the nearest vertex of a neighbouring
zone b gives b the raw weight smoothstep(1 - d / band) (1 at d = 0, 0 at d >= band, C1), its own zone
raw weight 1, and the raw weights are normalised. Across a boundary edge the two ends then carry
almost the same mix (about one half each), and deep inside a zone only its own interpolant counts.
Mixing only neighbours keeps every feature point reproduced exactly: a neighbour's interpolant
interpolates the features of every zone it is a neighbour of.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array

ZONE_OF_ROLE = {"hips": "torso", "spine": "torso", "chest": "torso", "neck": "head", "head": "head"}
for _s in ("left", "right"):
    ZONE_OF_ROLE.update({f"{_s}_shoulder": "torso", f"{_s}_upper_arm": f"{_s}_upper_arm",
                         f"{_s}_lower_arm": f"{_s}_lower_arm", f"{_s}_hand": f"{_s}_hand",
                         f"{_s}_upper_leg": f"{_s}_upper_leg", f"{_s}_lower_leg": f"{_s}_lower_leg",
                         f"{_s}_foot": f"{_s}_foot", f"{_s}_toe": f"{_s}_foot"})
BAND = 0.04
"""Default blend band across zone boundaries, as a fraction of the body's height."""


@dataclass(frozen=True, eq=False)
class Zones:
    """The skin split into geodesic zones; arrays read-only.

    names : (Z,) zone names.
    vertex_zone : (V,) int32, zone of each skin vertex.
    neighbours : (Z, Z) bool, symmetric, diagonal True.
    blend : (V, Z) CSR float64, rows sum to 1; blend[v, z] > 0 only where neighbours[vertex_zone[v], z].
    segment_zone : (S,) int32 zone of each bone segment (-1 when none was given).
    band : metres, the blend band used (0: no blending).
    """

    names: tuple
    vertex_zone: np.ndarray
    neighbours: np.ndarray
    blend: sp.csr_matrix
    segment_zone: np.ndarray
    band: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "vertex_zone", frozen_array(self.vertex_zone, np.int32))
        object.__setattr__(self, "neighbours", frozen_array(self.neighbours, bool))
        object.__setattr__(self, "segment_zone", frozen_array(self.segment_zone, np.int32))
        Z = len(self.names)
        assert self.neighbours.shape == (Z, Z) and self.blend.shape == (len(self.vertex_zone), Z)

    @property
    def num_zones(self) -> int:
        return len(self.names)

    def counts(self) -> np.ndarray:
        """(Z,) vertices per zone."""
        return np.bincount(self.vertex_zone, minlength=self.num_zones)

    def index(self, name: str) -> int:
        if name not in self.names:
            raise InputError(f"no zone {name!r}; zones: {', '.join(self.names)}", field="zone")
        return self.names.index(name)


def segment_zones(segments, parents, joint_names, roles: dict | None) -> tuple[tuple, np.ndarray]:
    """(names, segment_zone (S,) int32): the body part of every bone segment (see the module docstring).
    Without roles, or for a segment with no role joint above it, the segment's own label."""
    role_of = {j: r for r, j in (roles or {}).items()}
    parents = np.asarray(parents)
    names: list[str] = []
    out = np.empty(len(segments.labels), np.int32)
    for s, j in enumerate(segments.parent):
        zone, k = None, int(j)
        while k >= 0 and roles:
            if k in role_of and role_of[k] in ZONE_OF_ROLE:
                zone = ZONE_OF_ROLE[role_of[k]]
                break
            k = int(parents[k])
        zone = zone or segments.labels[s]
        if zone not in names:
            names.append(zone)
        out[s] = names.index(zone)
    return tuple(names), out


def skeleton_neighbours(segments, segment_zone: np.ndarray, num_zones: int) -> np.ndarray:
    """(Z, Z) bool: zones whose segments share a joint (a segment starting where another starts or ends)."""
    nb = np.eye(num_zones, dtype=bool)
    start, end = np.asarray(segments.parent), np.asarray(segments.child)
    for a in range(len(start)):
        touch = (start == start[a]) | (start == end[a]) | ((end == start[a]) & (end >= 0))
        nb[segment_zone[a], segment_zone[touch]] = True
    return nb | nb.T


def edge_graph(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
    """(welded ids (V,), graph (W, W) CSR of edge lengths, metres) of a triangle mesh, its vertices
    welded by position (rig.character.bone_heat.weld), so a mesh split at UV seams is one surface again."""
    from jiggle.rig.character.bone_heat import weld
    pos, f, ids = weld(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    W = len(pos)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    length = np.linalg.norm(pos[e[:, 0]] - pos[e[:, 1]], axis=1)
    g = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(W, W)).tocsr()
    return ids, (g + g.T).tocsr()


def smoothstep(x: np.ndarray) -> np.ndarray:
    """3 x^2 - 2 x^3 on [0, 1], clamped."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def blend_weights(vertices, faces, vertex_zone: np.ndarray, neighbours: np.ndarray, band: float) -> sp.csr_matrix:
    """(V, Z) partition of unity mixing neighbouring zones within `band` metres of their boundary
    (geodesic along the welded mesh edges); band 0 gives each vertex its own zone alone."""
    V, Z = len(vertex_zone), len(neighbours)
    rows, cols, vals = [np.arange(V)], [np.asarray(vertex_zone, np.int64)], [np.ones(V)]
    if band > 0 and V:
        ids, graph = edge_graph(vertices, faces)
        W = graph.shape[0]
        # the zone of a welded vertex: a seam vertex's copies can differ; any copy's zone is a source
        for z in range(Z):
            src = np.unique(ids[vertex_zone == z])
            if not len(src):
                continue
            d = dijkstra(graph, directed=False, indices=src, limit=band, min_only=True)
            d = np.asarray(d).reshape(W)
            dv = d[ids]
            take = np.isfinite(dv) & (vertex_zone != z) & neighbours[vertex_zone, z]
            r = smoothstep(1.0 - dv[take] / band)
            keep = r > 0
            rows.append(np.nonzero(take)[0][keep])
            cols.append(np.full(int(keep.sum()), z))
            vals.append(r[keep])
    m = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(V, Z)).tocsr()
    m.sum_duplicates()
    s = np.asarray(m.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.where(s > 0, s, 1.0)) @ m


def body_zones(vertices, faces, vertex_segment: np.ndarray, segments, parents, joint_names,
               roles: dict | None, band: float) -> Zones:
    """Zones of a skin by body part.

    vertices : (V, 3) metres; faces : (F, 3) int.
    vertex_segment : (V,) int, bone segment (index into `segments`) of each vertex, e.g. the
        segmentation's region (rig.muscle.segmentation.segment_skin).
    segments : rig.muscle.segmentation.BoneSegments; parents, joint_names : the skeleton.
    roles : {role: joint index} (rig.motion.role_map.resolve_roles) or None for a zone per segment.
    band : metres, the blend band across boundaries (>= 0).
    """
    if not (np.isfinite(band) and band >= 0):
        raise InputError(f"expected a band >= 0 metres, got {band}", field="band")
    names, seg_zone = segment_zones(segments, parents, joint_names, roles)
    vs = np.asarray(vertex_segment, np.int64)
    if len(vs) != len(vertices) or (len(vs) and (vs.min() < 0 or vs.max() >= len(seg_zone))):
        raise InputError(f"expected ({len(vertices)},) segment indices in [0, {len(seg_zone)})", field="vertex_segment")
    vertex_zone = seg_zone[vs]
    nb = skeleton_neighbours(segments, seg_zone, len(names))
    blend = blend_weights(vertices, faces, vertex_zone, nb, band)
    return Zones(names, vertex_zone, nb, blend, seg_zone, float(band))
