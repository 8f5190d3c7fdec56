"""How well each fitted muscle fits, and whether it can be trusted (rig.muscle.fit).

Three numbers per muscle, all at bind and in world metres:

local radius R
    The area-weighted mean distance of the skin triangles the muscle was fitted to (its region,
    FittedMuscle.region) from its template bone's straight segment (start joint to end joint, the
    foot clamped to the segment). It is the thickness of the body part the muscle sits in: a limb's
    radius, or for a trunk muscle the distance from the spine to its patch of skin. Errors are stated
    as shares of R so that one threshold serves a finger-thin forearm and a broad back alike.
loft error (rms, max)
    The distance of the muscle's conformed mesh (FittedMuscle.vertices: its ellipsoid inflated toward
    the skin region by the conform rays, i.e. the shape the skin asks for) to the lofted thesis
    muscle at bind (5 sections x 8 CVs, rig.muscle.model.MuscleRig; its `fit_rms` / `fit_max`,
    the nearer of each point's foot on the smooth loft and the end caps). A shape the loft cannot
    follow (a fold the conform rays slipped into, a region torn across two limbs) shows here.
inside share
    The share of the loft's surface points (rig.muscle.loft: 17 x 16 grid and 2 caps) that lie inside
    the closed skin, or outside it by no more than INSIDE_TOLERANCE x R: a fat mass or a muscle
    conformed to 95% of the way to the skin lies just under it, and the loft's smooth surface may
    poke through the skin's facets by a millimetre. Inside/outside is the majority of the ray
    parities along RAY_DIRECTIONS (embree via trimesh): one ray leaving through a hole of an open
    mesh (CesiumMan has ~1900 border edges: eyes, seams between parts) is outvoted; on CesiumMan the
    vote agrees with the generalized winding number on every loft point. The depth of a point
    outside is its distance to the nearest skin triangle.

Verdict (thresholds are module constants, written with the results to `jiggle fit`'s JSON)
    "ok"       rms <= RMS_OK R and inside share >= INSIDE_OK.
    "warn"     worse than ok but not refused: kept, with a JiggleWarning naming the muscle.
    "refused"  rms > RMS_REFUSE R or inside share < INSIDE_REFUSE (mostly outside the body): dropped
               from the rig, listed in Musculature.skipped with the reason (or InputError when
               FitOptions.strict).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.frozen import frozen_array

RMS_OK = 0.15          # share of the local radius: rms loft error at or below this is ok
RMS_REFUSE = 0.50      # above: refused
INSIDE_TOLERANCE = 0.05  # share of the local radius a loft point may stand outside the skin and count as inside
INSIDE_OK = 0.95       # share of loft points inside: at or above this is ok
INSIDE_REFUSE = 0.50   # below: the muscle is mostly outside the body, refused

# 7 unit directions spread over the sphere (a golden-angle spiral), none along an axis, so no ray runs
# along a symmetric character's mirror plane or a grid's edges
_K = np.arange(7) + 0.5
_Z = 1.0 - 2.0 * _K / 7
RAY_DIRECTIONS = np.stack([np.sqrt(1 - _Z ** 2) * np.cos(np.pi * (3 - np.sqrt(5)) * _K),
                           np.sqrt(1 - _Z ** 2) * np.sin(np.pi * (3 - np.sqrt(5)) * _K), _Z], axis=1)


def thresholds() -> dict:
    """The verdict's thresholds (shares of the local radius, or of loft points) by name."""
    return {"rms_ok": RMS_OK, "rms_refuse": RMS_REFUSE, "inside_tolerance": INSIDE_TOLERANCE,
            "inside_ok": INSIDE_OK, "inside_refuse": INSIDE_REFUSE}


@dataclass(frozen=True, eq=False)
class MuscleQuality:
    """One muscle's fit measures (see the module docstring).

    name : the muscle.
    radius : local body radius R, metres.
    rms, max : loft error, metres.
    inside : share of loft points inside the skin (within the tolerance), in [0, 1].
    depth : metres, how far the loft's farthest point stands outside the skin (0 when none is).
    status : "ok" | "warn" | "refused".
    reasons : why it is not ok (empty when ok), e.g. "rms loft error 21% of the local radius (> 15%)".
    surface : (P, 3) the loft's points at bind, metres (kept so a refused muscle can still be drawn).
    """

    name: str
    radius: float
    rms: float
    max: float
    inside: float
    depth: float
    status: str
    reasons: tuple[str, ...]
    surface: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "surface", frozen_array(self.surface))

    @property
    def rms_share(self) -> float:
        """rms loft error / local radius."""
        return self.rms / self.radius

    @property
    def max_share(self) -> float:
        """max loft error / local radius."""
        return self.max / self.radius

    @property
    def brief(self) -> str:
        """A few words of measures, e.g. "rms 3.1% of R, 100% inside"."""
        return f"rms {self.rms_share:.1%} of R, {self.inside:.0%} inside"

    def facts(self) -> dict:
        """JSON-ready measures (millimetres and shares, rounded)."""
        return {"status": self.status, "reasons": list(self.reasons), "radius_mm": round(self.radius * 1e3, 2),
                "loft_rms_share": round(self.rms_share, 4), "loft_max_share": round(self.max_share, 4),
                "inside_share": round(self.inside, 4), "outside_depth_mm": round(self.depth * 1e3, 2)}


def local_radius(vertices: np.ndarray, faces: np.ndarray, start: np.ndarray, end: np.ndarray) -> float:
    """Area-weighted mean distance (metres) of the triangles (vertices (V, 3), faces (k, 3)) from the
    segment start -> end (3,) each: the local body radius about a bone (see the module docstring)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    c = tri.mean(axis=1)
    ab = np.asarray(end, np.float64) - start
    t = np.clip((c - start) @ ab / max(float(ab @ ab), 1e-30), 0.0, 1.0)
    r = np.linalg.norm(c - (start + t[:, None] * ab), axis=1)
    return float((r * area).sum() / max(area.sum(), 1e-30))


def inside_skin(skin_mesh, points: np.ndarray) -> np.ndarray:
    """(N,) bool: points (N, 3) inside the trimesh `skin_mesh` by the majority of the ray parities
    along RAY_DIRECTIONS (robust to holes in an open mesh, see the module docstring)."""
    p = np.asarray(points, np.float64)
    votes = np.zeros(len(p), int)
    for d in RAY_DIRECTIONS:
        _, ray = skin_mesh.ray.intersects_id(p, np.broadcast_to(d, p.shape).copy(), multiple_hits=True,
                                             return_locations=False)
        votes += np.bincount(ray, minlength=len(p)) % 2
    return votes * 2 > len(RAY_DIRECTIONS)


def closest_on_skin(skin_mesh, points: np.ndarray, candidates: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Nearest points (N, 3) on the trimesh `skin_mesh` to points (N, 3) and their distances (N,), metres,
    searched among the triangles around the `candidates` nearest skin vertices (exact for a point nearer
    the skin than its triangles' size, which is all this is asked about: points just outside the skin)."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    V = np.asarray(skin_mesh.vertices)
    k = min(candidates, len(V))
    _, near = cKDTree(V).query(p, k=k)
    vf = np.asarray(skin_mesh.vertex_faces)                        # (V, most) padded with -1
    tri = vf[np.asarray(near).reshape(len(p), k)].reshape(len(p), -1)  # (N, k * most)
    point = np.repeat(np.arange(len(p)), tri.shape[1])
    tri = tri.ravel()
    ok = tri >= 0
    point, tri = point[ok], tri[ok]
    q = closest_point(skin_mesh.triangles[tri], p[point])
    d = np.linalg.norm(q - p[point], axis=1)
    # the nearest candidate per point: sort by (point, distance), keep each point's first
    order = np.lexsort((d, point))
    first = order[np.r_[True, point[order][1:] != point[order][:-1]]]
    return q[first], d[first]


def assess(names, surfaces: np.ndarray, rms: np.ndarray, max_: np.ndarray, radii: np.ndarray, skin_mesh
           ) -> list[MuscleQuality]:
    """The fit measures and verdict of M muscles.

    names : M muscle names.
    surfaces : (M, P, 3) their lofts' points at bind, metres.
    rms, max_ : (M,) loft errors, metres (MuscleRig.fit_rms, fit_max).
    radii : (M,) local body radii, metres (`local_radius`).
    skin_mesh : trimesh.Trimesh of the skin at bind.
    """
    S = np.asarray(surfaces, np.float64)
    M, P = S.shape[:2]
    flat = S.reshape(-1, 3)
    inside = inside_skin(skin_mesh, flat)
    depth = np.zeros(len(flat))
    depth[~inside] = closest_on_skin(skin_mesh, flat[~inside])[1]
    depth = depth.reshape(M, P)
    out = []
    for i, name in enumerate(names):
        R = float(radii[i])
        share_in = float(np.mean(depth[i] <= INSIDE_TOLERANCE * R))
        rs = float(rms[i]) / R
        reasons, refused = [], False
        if rs > RMS_OK:
            reasons.append(f"rms loft error {rs:.0%} of the local radius (> {RMS_OK:.0%})")
            refused |= rs > RMS_REFUSE
        if share_in < INSIDE_OK:
            reasons.append(f"only {share_in:.0%} of its surface inside the skin (< {INSIDE_OK:.0%}; "
                           f"up to {depth[i].max() * 1e3:.1f} mm outside)")
            refused |= share_in < INSIDE_REFUSE
        status = "refused" if refused else "warn" if reasons else "ok"
        out.append(MuscleQuality(name=name, radius=R, rms=float(rms[i]), max=float(max_[i]), inside=share_in,
                                 depth=float(depth[i].max()), status=status, reasons=tuple(reasons),
                                 surface=S[i]))
    return out
