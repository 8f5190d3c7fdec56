"""Feature vertices and marker vertices anchored to the bones and muscles (Simmons et al. 2002, section 2).

The paper re-samples the skin "to ensure that it contains vertices corresponding to nearby underlying
components: for each bone and muscle, rays are shot from points on the component in the normal
direction and intersected with the skin. A new vertex is added at the intersection point if the
component is sufficiently close to the surface to make a visual impact on the skin, and the ray
intersection does not occur at grazing angles." Each feature vertex is anchored in the local space of
its component and moves with it; the rest of the skin is interpolated from the features (section 4,
rig/anatomy/rbf.py). Marker vertices are anchored "by finding the closest point on the nearest muscle or bone".

Components
    Bones are the segments of rig.muscle.segmentation.bone_segments: rays start at stations along the part
    `bone_span` of each segment (away from the joints, so the interpolation blends across them) and go
    radially, `rays_around` directions perpendicular to the bone (every other station turned by half a
    step, so the hits interleave). Muscles are the lofts of a MuscleRig's rest CVs (rig/muscle/loft.py, the
    outward normal n = unit(dX/dv x dX/dw) of rig.muscle.loft_attach.loft_frame): rays start at loft samples
    w in `muscle_span` (not the tendon ends), v all around, along n. A muscle ray starts `muscle_reach`
    INSIDE the loft (p - reach n) because a conformed muscle may poke through the skin a little; its
    hit's signed distance from the loft (+ outside) must lie in [-reach, reach].
Acceptance
    All rays are cast at once (trimesh's embree intersector, first hit). A hit is kept when it is within
    the reach of its component (bone: distance from the bone's axis, the ray's length, at most
    `bone_reach`), not grazing (|cos| of the ray and the hit face's normal at least `grazing`), and,
    with `facing`, where the ray LEAVES the body (the face's outward normal along the ray: a ray from an
    arm bone that passes out of the arm and meets the trunk from outside is not the arm's skin).
Snapping and thinning
    A hit within `snap` x spacing of a corner of its triangle snaps to that vertex (with insert=False
    every hit snaps to its triangle's nearest corner: the topology is kept, which an animation cache
    needs); otherwise it is inserted (rig.anatomy.resample.insert_points). The candidates (at their snapped or
    hit positions) are thinned by a greedy Poisson-disk pass: taken in order of their component's
    distance to the skin (closest first), a candidate is kept when no kept one lies within `spacing`.
    The same rule settles a bone ray and a muscle ray that found the same place: the closer component
    wins. Kept features are thus at least `spacing` apart and never share a vertex.
Anchors (:class:`Anchors`)
    A bone row stores the feature's rest point in its bone's joint frame, inverse(bind_world[joint]) p,
    and follows world[joint]. A muscle row stores loft parameters (w, v) and the offset in the loft
    frame at the foot point, exactly as rig.muscle.loft_attach.bind_influence computes them, and follows the
    loft of the current CVs (rig.skin.influence's attach). Features are anchored at the FEATURE VERTEX's rest
    position (for a snapped hit that is the vertex, not the ray's hit point).

All lengths in :class:`FeatureOptions` are fractions of the character's height (rest skin extent along
Z), so the defaults fit any size of character.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from jiggle.rig.anatomy.resample import Resampled, identity, insert_points
from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.loft_attach import CVS_PER_MUSCLE, _evaluate, bind_influence, closest_points, loft_frame, muscle_eps
from jiggle.rig.muscle.segmentation import BoneSegments

BONE, MUSCLE = 0, 1
"""Values of `Anchors.kind` and `FeatureSet.source`."""
_FRAMES_CHUNK = 1 << 22
"""Elements (frames x muscle rows x 40 CVs x 3) gathered at once in Anchors.positions."""


# ---------------------------------------------------------------------------------- options
@dataclass(frozen=True)
class FeatureOptions:
    """How feature vertices are found. Lengths are FRACTIONS of the character's height.

    spacing : kept features are at least this far apart (greedy Poisson-disk thinning, closest
        component first).
    bone_reach : a bone ray's hit farther than this from the bone's axis is dropped.
    muscle_reach : a muscle ray's hit farther than this from the muscle's surface (either side) is
        dropped.
    grazing : minimum |cos| between the ray and the hit face's normal; below it the hit is grazing
        and dropped.
    snap : as a fraction of `spacing`: a hit within this distance of a corner of its triangle snaps
        to that vertex instead of being inserted.
    insert : False: every hit snaps to the nearest corner of its triangle (no vertex is added; the
        mesh's topology is kept, which is what an animation cache needs).
    interior : an inserted point is moved within its triangle so that each corner keeps at least
        this barycentric share (before renormalising), so the 1-to-3 split leaves no sliver: a
        sliver's normal flips under the slightest uneven motion (morph or animation). The point stays
        on the surface; the feature is anchored where it ends up.
    bone_span : (a, b), 0 <= a <= b <= 1, the part of each bone the rays start from.
    rays_around : rays per bone station, evenly around the bone.
    ray_step : distance between ray origins along a bone and over a muscle's loft (both directions).
    muscle_span : (w0, w1) within [0, 4], the loft parameters across the sections the muscle rays
        start from (0 and 4 are the tendon ends).
    facing : True: a hit counts only where the ray leaves the body (the hit face's outward normal
        along the ray); False accepts either side (for a mesh whose winding is unreliable).
    """

    spacing: float = 0.02
    bone_reach: float = 0.06
    muscle_reach: float = 0.03
    grazing: float = 0.4
    snap: float = 0.4
    insert: bool = True
    interior: float = 0.15
    bone_span: tuple[float, float] = (0.15, 0.85)
    rays_around: int = 16
    ray_step: float = 0.01
    muscle_span: tuple[float, float] = (0.5, 3.5)
    facing: bool = True

    def __post_init__(self):
        for k in ("spacing", "bone_reach", "muscle_reach", "ray_step"):
            x = getattr(self, k)
            if not _real(x) or not x > 0 or not np.isfinite(x):
                raise InputError(f"expected a fraction of the height > 0, got {x!r}", field=k)
        if not _real(self.grazing) or not 0.0 <= self.grazing < 1.0:
            raise InputError(f"expected a cosine in [0, 1), got {self.grazing!r}", field="grazing")
        if not _real(self.interior) or not 0.0 <= self.interior < 1.0 / 3.0:
            raise InputError(f"expected a barycentric share in [0, 1/3), got {self.interior!r}", field="interior")
        if not _real(self.snap) or not 0.0 <= self.snap < np.inf:
            raise InputError(f"expected a fraction of spacing >= 0, got {self.snap!r}", field="snap")
        for k in ("insert", "facing"):
            if not isinstance(getattr(self, k), (bool, np.bool_)):
                raise InputError(f"expected True or False, got {getattr(self, k)!r}", field=k)
        if not isinstance(self.rays_around, (int, np.integer)) or isinstance(self.rays_around, bool) \
                or self.rays_around < 1:
            raise InputError(f"expected an integer >= 1, got {self.rays_around!r}", field="rays_around")
        for k, hi in (("bone_span", 1.0), ("muscle_span", float(loft.SECTIONS - 1))):
            span = getattr(self, k)
            ok = (isinstance(span, (tuple, list)) and len(span) == 2 and all(_real(x) for x in span)
                  and 0.0 <= span[0] <= span[1] <= hi)
            if not ok:
                raise InputError(f"expected (a, b) with 0 <= a <= b <= {hi:g}, got {span!r}", field=k)


def _real(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)


# ---------------------------------------------------------------------------------- anchors
@dataclass(frozen=True, eq=False)
class Anchors:
    """Points anchored to bones (kind 0) or muscles (kind 1), one row per point. Arrays read-only.

    kind : (n,) int8, BONE (0) or MUSCLE (1).
    segment : (n,) int32, bone segment index (rig.muscle.segmentation.BoneSegments), -1 on muscle rows.
    joint : (n,) int32, the bone segment's parent joint (whose frame the point rides), -1 on muscle rows.
    muscle : (n,) int32, muscle index in the MuscleRig, -1 on bone rows.
    local : (n, 3) float64 metres, bone rows: the rest point in the joint's bind frame,
        inverse(bind_world[joint]) @ p (0 on muscle rows).
    w, v : (n,) float64, muscle rows: loft parameters of the foot point (0 on bone rows).
    offset : (n, 3) float64 metres, muscle rows: the point's offset from X(w, v) along the loft frame
        (e1, e2, n) (0 on bone rows).
    eps : (n,) float64 metres, muscle rows: the muscle's collapsed-frame threshold (rig.muscle.loft_attach.muscle_eps).
    rest : (n, 3) float64 metres, rest positions.
    """

    kind: np.ndarray
    segment: np.ndarray
    joint: np.ndarray
    muscle: np.ndarray
    local: np.ndarray
    w: np.ndarray
    v: np.ndarray
    offset: np.ndarray
    eps: np.ndarray
    rest: np.ndarray

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("kind", frozen_array(self.kind, np.int8))
        for k in ("segment", "joint", "muscle"):
            set_(k, frozen_array(getattr(self, k), np.int32))
        for k in ("local", "offset", "rest"):
            set_(k, frozen_array(np.reshape(getattr(self, k), (-1, 3))))
        for k in ("w", "v", "eps"):
            set_(k, frozen_array(getattr(self, k)))
        n = len(self.kind)
        assert all(getattr(self, k).shape == (n,) for k in ("segment", "joint", "muscle", "w", "v", "eps"))
        assert all(getattr(self, k).shape == (n, 3) for k in ("local", "offset", "rest"))

    def __len__(self) -> int:
        return len(self.kind)

    @classmethod
    def empty(cls) -> "Anchors":
        z, z3 = np.zeros(0), np.zeros((0, 3))
        return cls(z, z, z, z, z3, z, z, z3, z, z3)

    def take(self, index) -> "Anchors":
        """The rows `index` (int array or bool mask) as a new Anchors."""
        return Anchors(**{k: getattr(self, k)[index] for k in _FIELDS})

    @staticmethod
    def concatenate(parts) -> "Anchors":
        """Rows of several Anchors one after another (e.g. features, then markers)."""
        parts = list(parts)
        if not parts:
            return Anchors.empty()
        return Anchors(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in _FIELDS})

    def positions(self, world, cvs=None) -> np.ndarray:
        """Anchored positions for joint world transforms and muscle CVs.

        world : (J, 4, 4) or (T, J, 4, 4) float, metres, rigid joint transforms in the character's order.
        cvs : (N, 3) or (T, N, 3) float, metres, N = 40 M, the muscles' current CVs; may be None when no
            row is a muscle row. A single pose of one broadcasts over the other's T frames.
        Returns (n, 3) float64 (both single) or (T, n, 3), metres: bone rows world[joint] @ local, muscle
        rows the loft attach point X(w, v) + frame(w, v)^T offset of the current CVs. At the bind pose
        with the rest CVs this is `rest` (to rounding).
        """
        W = np.asarray(world, np.float64)
        if W.ndim not in (3, 4) or W.shape[-2:] != (4, 4):
            raise InputError(f"expected (J, 4, 4) or (T, J, 4, 4) transforms, got shape {W.shape}", field="world")
        bone = np.nonzero(self.kind == BONE)[0]
        mus = np.nonzero(self.kind == MUSCLE)[0]
        if bone.size and W.shape[-3] <= int(self.joint[bone].max()):
            raise InputError(f"the anchors ride joint {int(self.joint[bone].max())}, but world has "
                             f"{W.shape[-3]} joints", field="world")
        if not np.isfinite(W).all():
            raise InputError("world transforms hold NaN or inf", field="world")
        single = W.ndim == 3
        C = None
        if mus.size:
            if cvs is None:
                raise InputError(f"{mus.size} anchors ride muscles: give the muscles' CVs", field="cvs")
            C = np.asarray(cvs, np.float64)
            M = int(self.muscle[mus].max()) + 1
            if C.ndim not in (2, 3) or C.shape[-1] != 3 or C.shape[-2] % CVS_PER_MUSCLE \
                    or C.shape[-2] // CVS_PER_MUSCLE < M:
                raise InputError(f"expected (40 M, 3) or (T, 40 M, 3) CVs with M >= {M}, got shape {C.shape}",
                                 field="cvs")
            if not np.isfinite(C).all():
                raise InputError("the CVs hold NaN or inf", field="cvs")
            single = single and C.ndim == 2
        frames = [len(W)] if W.ndim == 4 else []
        frames += [len(C)] if C is not None and C.ndim == 3 else []
        if len(set(frames)) > 1:
            raise InputError(f"world has {frames[0]} frames but cvs {frames[1]}", field="cvs")
        T = frames[0] if frames else 1
        W = np.broadcast_to(W if W.ndim == 4 else W[None], (T,) + W.shape[-3:])
        out = np.zeros((T, len(self), 3))
        if bone.size:
            Wj = W[:, self.joint[bone]]                                                    # (T, nb, 4, 4)
            out[:, bone] = np.einsum("tnij,nj->tni", Wj[..., :3, :3], self.local[bone]) + Wj[..., :3, 3]
        if mus.size:
            C = np.broadcast_to(C if C.ndim == 3 else C[None], (T,) + C.shape[-2:])
            out[:, mus] = _attach_frames(C, self.muscle[mus], self.w[mus], self.v[mus], self.offset[mus],
                                         self.eps[mus])
        return out[0] if single else out


_FIELDS = ("kind", "segment", "joint", "muscle", "local", "w", "v", "offset", "eps", "rest")


def _attach_frames(cvs: np.ndarray, muscle, w, v, offset, eps) -> np.ndarray:
    """rig.skin.influence._attach over frames: cvs (T, N, 3) -> (T, n, 3), blocks of frames at a time."""
    bases = [loft.surface_weights(w, v, dw, dv).reshape(len(w), CVS_PER_MUSCLE)
             for dw, dv in ((0, 0), (1, 0), (0, 1))]
    T, n = len(cvs), len(w)
    out = np.empty((T, n, 3))
    step = max(1, _FRAMES_CHUNK // max(1, n * CVS_PER_MUSCLE * 3))
    for t0 in range(0, T, step):
        X = cvs[t0:t0 + step].reshape(-1, cvs.shape[1] // CVS_PER_MUSCLE, CVS_PER_MUSCLE, 3)[:, muscle]
        x, xw, xv = (np.einsum("nc,tncx->tnx", B, X) for B in bases)
        k = len(X)
        frame = loft_frame(xw.reshape(-1, 3), xv.reshape(-1, 3), np.tile(eps, k)).reshape(k, n, 3, 3)
        out[t0:t0 + step] = x + np.einsum("tnij,ni->tnj", frame, offset)
    return out


def _bone_rows(points: np.ndarray, segment: np.ndarray, segments: BoneSegments, bind_world: np.ndarray) -> dict:
    joint = segments.parent[segment].astype(np.int64)
    inv = np.linalg.inv(bind_world[joint])
    local = np.einsum("nij,nj->ni", inv[:, :3, :3], points) + inv[:, :3, 3]
    return dict(segment=segment, joint=joint, local=local)


def _anchor(points: np.ndarray, kind: np.ndarray, comp: np.ndarray, segments: BoneSegments, bind_world,
            rig) -> Anchors:
    """Anchors of points (n, 3) to components: kind (n,) BONE/MUSCLE, comp (n,) segment or muscle index."""
    n = len(points)
    segment = np.full(n, -1)
    joint = np.full(n, -1)
    muscle = np.full(n, -1)
    local = np.zeros((n, 3))
    w, v, offset, eps = np.zeros(n), np.zeros(n), np.zeros((n, 3)), np.zeros(n)
    b = np.nonzero(kind == BONE)[0]
    if b.size:
        rows = _bone_rows(points[b], comp[b], segments, np.asarray(bind_world, np.float64))
        segment[b], joint[b], local[b] = rows["segment"], rows["joint"], rows["local"]
    m = np.nonzero(kind == MUSCLE)[0]
    if m.size:
        order = m[np.argsort(comp[m], kind="stable")]
        binding = bind_influence(points[order], np.arange(order.size + 1), comp[order], rig.rest_cvs,
                                 names=rig.names)
        muscle[order] = comp[order]
        w[order], v[order], offset[order] = binding.w, binding.v, binding.offset
        eps[order] = binding.muscle_eps[comp[order]]
    return Anchors(kind, segment, joint, muscle, local, w, v, offset, eps, points)


# ---------------------------------------------------------------------------------- features
@dataclass(frozen=True, eq=False)
class FeatureSet:
    """Feature vertices of a character's skin. Arrays read-only; F features.

    skin : the resampled skin (rig.anatomy.resample.Resampled; resample_character(character, skin) gives the
        character on it).
    vertex : (F,) int64, each feature's vertex in `skin`, all distinct.
    anchors : Anchors of the features, at their vertices' rest positions (skin.vertices[vertex]).
    source : (F,) int8, BONE (0) or MUSCLE (1): the component whose ray found the feature.
    distance : (F,) float64 metres, the ray hit's distance from its component (bone: from the axis;
        muscle: signed from the loft surface, + outside).
    snapped, inserted : features on existing vertices / on inserted ones (snapped + inserted = F).
    counts : {component label: features}, every bone segment label then every muscle name (0 for a
        component that found none).
    rays : rays cast; hits : rays that hit the skin; candidates : hits within reach, not grazing
        (facing), before the thinning.
    """

    skin: Resampled
    vertex: np.ndarray
    anchors: Anchors
    source: np.ndarray
    distance: np.ndarray
    snapped: int
    inserted: int
    counts: dict
    rays: int
    hits: int
    candidates: int

    def __post_init__(self):
        object.__setattr__(self, "vertex", frozen_array(self.vertex, np.int64))
        object.__setattr__(self, "source", frozen_array(self.source, np.int8))
        object.__setattr__(self, "distance", frozen_array(self.distance))

    def __len__(self) -> int:
        return len(self.vertex)

    @property
    def positions(self) -> np.ndarray:
        """(F, 3) float64 metres, the features' rest positions."""
        return self.anchors.rest


def _perpendiculars(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (S, 3) each completing unit axes (S, 3) to right-handed frames."""
    helper = np.eye(3)[np.argmin(np.abs(axis), axis=1)]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(axis, e1)


def _bone_rays(segments: BoneSegments, opt: FeatureOptions, step: float):
    """Origins, unit directions (R, 3) and segment index (R,) of the bone rays."""
    a0, a1 = opt.bone_span
    L = segments.lengths
    ok = np.nonzero(L > 0)[0]
    if ok.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    axis = (segments.end[ok] - segments.start[ok]) / L[ok, None]
    e1, e2 = _perpendiculars(axis)
    stations = np.maximum(1, np.ceil(L[ok] * (a1 - a0) / step).astype(np.int64) + 1)
    seg = np.repeat(np.arange(ok.size), stations)                          # per station, index into ok
    first = np.cumsum(stations) - stations
    i = np.arange(len(seg)) - first[seg]
    frac = np.where(stations[seg] > 1, a0 + (a1 - a0) * i / np.maximum(stations[seg] - 1, 1), 0.5 * (a0 + a1))
    centre = segments.start[ok][seg] + frac[:, None] * (segments.end[ok] - segments.start[ok])[seg]
    K = opt.rays_around
    theta = 2.0 * np.pi * (np.arange(K)[None, :] + 0.5 * (i % 2)[:, None]) / K          # (stations, K)
    d = np.cos(theta)[..., None] * e1[seg][:, None] + np.sin(theta)[..., None] * e2[seg][:, None]
    return np.repeat(centre, K, axis=0), d.reshape(-1, 3), np.repeat(ok[seg], K)


def _muscle_rays(rest_cvs: np.ndarray, opt: FeatureOptions, step: float):
    """Loft points p, outward normals n (R, 3) and muscle index (R,) of the muscle rays."""
    X_all = np.asarray(rest_cvs, np.float64).reshape(-1, loft.SECTIONS, loft.RING, 3)
    eps = muscle_eps(rest_cvs)
    w0, w1 = opt.muscle_span
    P, N, idx = [], [], []
    for m, X in enumerate(X_all):              # bind only: a handful of muscles
        centres = X.mean(axis=1)
        length = np.linalg.norm(np.diff(centres, axis=0), axis=1).sum() * (w1 - w0) / (loft.SECTIONS - 1)
        ring = np.linalg.norm(X - np.roll(X, 1, axis=1), axis=2).sum(axis=1).max()
        nw = int(np.clip(np.ceil(length / step) + 1, 1, 256))
        nv = int(np.clip(np.ceil(ring / step), 8, 256))
        ws = np.linspace(w0, w1, nw) if nw > 1 else np.array([0.5 * (w0 + w1)])
        w, j = np.repeat(ws, nv), np.tile(np.arange(nv), nw)
        v = loft.RING * (j + 0.5 * (np.repeat(np.arange(nw), nv) % 2)) / nv
        x, xw, xv = _evaluate(X, w, v)
        n = loft_frame(xw, xv, eps[m])[:, 2]
        good = np.linalg.norm(n, axis=1) > 0.5          # a collapsed frame has no normal to shoot along
        P.append(x[good])
        N.append(n[good])
        idx.append(np.full(int(good.sum()), m))
    if not P:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(P), np.concatenate(N), np.concatenate(idx)


def _cast(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, dirs: np.ndarray):
    """First hits of the rays: ray index (h,), location (h, 3), face (h,) index into `faces`, t (h,)."""
    import trimesh
    if len(origins) == 0 or len(faces) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    # embree (trimesh.ray.has_embree) when installed: thousands of rays in milliseconds
    loc, ray, tri = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    ray = np.asarray(ray, np.int64)
    t = np.einsum("ij,ij->i", loc - origins[ray], dirs[ray])
    return ray, np.asarray(loc, np.float64), np.asarray(tri, np.int64), t


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(n, 3) barycentric coordinates of points p (n, 3) in triangles tri (n, 3, 3), clipped to the
    triangle (the hits lie on it to rounding) and summing to 1."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(den > 0, den, 1.0)
    y = (d11 * d20 - d01 * d21) / den
    z = (d00 * d21 - d01 * d20) / den
    out = np.maximum(np.stack([1.0 - y - z, y, z], axis=1), 0.0)
    return out / out.sum(1, keepdims=True)


def _thin(points: np.ndarray, key: np.ndarray, radius: float) -> np.ndarray:
    """Indices kept by the greedy Poisson-disk pass: in order of key (ties by index), a point is kept
    when no kept point lies within `radius`. Computed in rounds (a point is decided once every
    neighbour ranked before it is), which gives the sequential greedy result without a Python loop
    over points."""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    rank = np.empty(n, np.int64)
    rank[np.lexsort((np.arange(n), key))] = np.arange(n)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    i, j = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
    alive = np.ones(n, bool)
    kept = np.zeros(n, bool)
    while alive.any():
        live = alive[i] & alive[j]
        best = np.full(n, n, np.int64)
        np.minimum.at(best, i[live], rank[j[live]])
        win = alive & (rank < best)
        kept |= win
        alive &= ~win
        alive[j[win[i]]] = False          # neighbours of a kept point are out
    return np.nonzero(kept)[0]


def find_features(character, segments: BoneSegments, rig=None, options: FeatureOptions = FeatureOptions(), *,
                  exclude_faces=None) -> FeatureSet:
    """Feature vertices of `character`'s skin (see the module docstring).

    character : rig.character.character.Character at bind.
    segments : rig.muscle.segmentation.BoneSegments of the character (bone_segments(character)).
    rig : a rig.muscle.model.MuscleRig (its rest_cvs and names), or None for bones only.
    options : FeatureOptions (lengths as fractions of the character's height).
    exclude_faces : (k,) int face indices or (F,) bool mask of faces rays ignore (e.g. the head).
    Returns a FeatureSet; resample_character(character, fs.skin) gives the character on the new skin.
    """
    if not isinstance(options, FeatureOptions):
        raise InputError(f"expected FeatureOptions, got {type(options).__name__}", field="options")
    if not isinstance(segments, BoneSegments):
        raise InputError(f"expected rig.muscle.segmentation.BoneSegments, got {type(segments).__name__}", field="segments")
    if rig is not None and not hasattr(rig, "rest_cvs"):
        raise InputError(f"expected a MuscleRig or None, got {type(rig).__name__}", field="rig")
    V = np.asarray(character.vertices, np.float64)
    Fc = np.asarray(character.faces, np.int64)
    h = character.height
    if not h > 0:
        raise InputError("the character's rest skin has no height to scale the options by", field="character")
    keep_face = np.ones(len(Fc), bool)
    if exclude_faces is not None:
        ex = np.asarray(exclude_faces)
        if ex.dtype == bool and ex.shape == (len(Fc),):
            keep_face &= ~ex
        elif ex.ndim == 1 and (ex.size == 0 or np.issubdtype(ex.dtype, np.integer)):
            if ex.size and (ex.min() < 0 or ex.max() >= len(Fc)):
                raise InputError(f"face indices must lie in [0, {len(Fc)})", field="exclude_faces")
            keep_face[ex] = False
        else:
            raise InputError(f"expected (k,) int face indices or a ({len(Fc)},) bool mask, got shape {ex.shape} "
                             f"dtype {ex.dtype}", field="exclude_faces")
    step, spacing = options.ray_step * h, options.spacing * h
    bone_reach, muscle_reach = options.bone_reach * h, options.muscle_reach * h

    # rays: bones from their axis outward, muscles from just inside their loft along its normal
    bo, bd, bseg = _bone_rays(segments, options, step)
    if rig is not None:
        mp, mn, mmus = _muscle_rays(rig.rest_cvs, options, step)
    else:
        mp, mn, mmus = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    origins = np.concatenate([bo, mp - muscle_reach * mn])
    dirs = np.concatenate([bd, mn])
    kind = np.concatenate([np.full(len(bo), BONE), np.full(len(mp), MUSCLE)]).astype(np.int8)
    comp = np.concatenate([bseg, mmus]).astype(np.int64)
    sub = np.nonzero(keep_face)[0]
    ray, loc, tri, t = _cast(V, Fc[sub], origins, dirs)
    face = sub[tri]

    # acceptance: reach, grazing, facing
    dist = np.where(kind[ray] == BONE, t, t - muscle_reach)
    reach = np.where(kind[ray] == BONE, bone_reach, muscle_reach)
    corners = V[Fc[face]]
    nrm = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    ln = np.linalg.norm(nrm, axis=1)
    cos = np.einsum("ij,ij->i", nrm, dirs[ray]) / np.where(ln > 0, ln, np.inf)
    ok = (t >= 0) & (np.abs(dist) <= reach) & ((cos if options.facing else np.abs(cos)) >= options.grazing)
    ray, loc, face, dist, corners = ray[ok], loc[ok], face[ok], dist[ok], corners[ok]

    # snap or insert, then thin by distance of the component to the skin
    bary = _barycentric(loc, corners)
    on = np.einsum("nk,nkx->nx", bary, corners)
    dc = np.linalg.norm(corners - on[:, None], axis=2)
    near = np.argmin(dc, axis=1)
    snap = ~np.full(len(ray), options.insert) | (dc[np.arange(len(ray)), near] <= options.snap * spacing)
    vid = Fc[face, near]
    inward = np.maximum(bary, options.interior)
    bary = np.where(snap[:, None], bary, inward / inward.sum(axis=1, keepdims=True))
    on = np.einsum("nk,nkx->nx", bary, corners)
    cand = np.where(snap[:, None], V[vid], on)
    kept = _thin(cand, np.abs(dist), spacing)
    # one inserted point per triangle (the one whose component is closest): a second point would
    # split a child triangle again and could leave a sliver after all
    ins = kept[~snap[kept]]
    ranked = ins[np.lexsort((ins, np.abs(dist)[ins]))]
    _, first = np.unique(face[ranked], return_index=True)
    kept = np.setdiff1d(kept, np.setdiff1d(ins, ranked[first]))
    ins = kept[~snap[kept]]
    if ins.size:
        skin, new = insert_points(V, Fc, face[ins], bary[ins])
    else:
        skin, new = identity(V, Fc), np.zeros(0, np.int64)
    vertex = np.where(snap[kept], vid[kept], 0)
    vertex[~snap[kept]] = new
    # features in vertex order (snapped ones are original vertices, before the inserted ones)
    order = np.argsort(vertex, kind="stable")
    kept, vertex = kept[order], vertex[order]
    fk, fc = kind[ray[kept]], comp[ray[kept]]
    anchors = _anchor(skin.vertices[vertex], fk, fc, segments, character.bind_world, rig)
    labels = list(segments.labels) + (list(rig.names) if rig is not None else [])
    lab = np.where(fk == BONE, fc, len(segments) + fc)
    tally = np.bincount(lab, minlength=len(labels))
    return FeatureSet(skin=skin, vertex=vertex, anchors=anchors, source=fk, distance=dist[kept],
                      snapped=int(len(kept) - skin.inserted), inserted=int(skin.inserted),
                      counts={k: int(c) for k, c in zip(labels, tally)}, rays=int(len(origins)),
                      hits=int(ok.size), candidates=int(ok.sum()))


# ---------------------------------------------------------------------------------- markers
def anchor_points(points, character, segments: BoneSegments, rig=None) -> Anchors:
    """Marker anchoring: each point (n, 3) metres, at bind, to the NEAREST component, bone segment
    (distance from the segment) or muscle (distance from its rest loft, rig.muscle.loft_attach.closest_points),
    the bone on a tie. Muscles are tried only for points whose bound on the distance (from the loft
    points' bounding sphere) beats the best so far."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3 or not np.issubdtype(p.dtype, np.number) or not np.isfinite(p).all():
        raise InputError(f"expected finite (n, 3) points, got shape {p.shape} dtype {p.dtype}", field="points")
    p = p.astype(np.float64)
    if not isinstance(segments, BoneSegments):
        raise InputError(f"expected rig.muscle.segmentation.BoneSegments, got {type(segments).__name__}", field="segments")
    n = len(p)
    kind = np.full(n, BONE, np.int8)
    if len(segments):
        _, d = segments.project(p)
        comp = np.argmin(d, axis=1) if n else np.zeros(0, np.int64)
        best = d[np.arange(n), comp] if n else np.zeros(0)
    else:
        comp, best = np.zeros(n, np.int64), np.full(n, np.inf)
    if rig is not None and n:
        X_all = np.asarray(rig.rest_cvs, np.float64).reshape(-1, loft.SECTIONS, loft.RING, 3)
        pts = loft.points(X_all)                                            # (M, P, 3)
        centre = pts.mean(axis=1)
        radius = 1.1 * np.linalg.norm(pts - centre[:, None], axis=2).max(axis=1)   # margin: between samples
        lower = np.linalg.norm(p[:, None] - centre[None], axis=2) - radius[None]     # (n, M)
        for m in np.argsort(lower.min(axis=0)):
            try_ = np.nonzero(lower[:, m] < best)[0]
            if try_.size == 0:
                continue
            _, _, dm = closest_points(p[try_], X_all[m])
            win = dm < best[try_]
            sel = try_[win]
            best[sel], comp[sel], kind[sel] = dm[win], m, MUSCLE
    elif not len(segments):
        raise InputError("no bone segment and no muscle to anchor to", field="segments")
    return _anchor(p, kind, np.asarray(comp, np.int64), segments, character.bind_world, rig)
