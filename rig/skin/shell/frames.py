"""Per-frame ellipsoid frames of the thesis muscles, the state the shell deformer reads.

The shell deformer (Pratscher et al. 2005, section 4) works in each muscle's local space, where the
muscle is the unit sphere at the origin. This module turns a muscle rig (rig/muscle/model.py) into
those spaces: once at bind, and then per frame from the joint transforms and the (simulated) CVs.
All matrices are 4 x 4 affine maps for column vectors, metres in world, local units (multiples of
the muscle's radius in a direction) in the muscle's space.

Rest ellipsoid E_rest (built once, `rest_ellipsoids`)
    The solid moments of the muscle's closed rest loft mesh (rig.surface(rig.rest_cvs),
    rig.surface_faces), by the divergence theorem: the mesh is cut into signed tetrahedra from a
    point near it, whose volume, centroid and second moments are exact. Centre = volume centroid,
    axes = eigenvectors of the solid covariance, radii = sqrt(5 x eigenvalue), exact for a solid
    ellipsoid (its covariance along an axis of half-length a is a^2 / 5). Solid rather than surface
    moments, so the ellipsoid measures what the muscle holds and not how its mesh is sampled. The loft's
    16-sided rings hold ~97% of an ellipsoid's volume, which reads as radii ~1% short.
Local axes (one convention for every muscle)
    local z = the longest axis, signed from the origin end toward the insertion end (the loft's
    first section toward its last), so the star table's poles (theta = 0, pi) are the muscle's ends
    and its rows are rings around the muscle.
    local x = the middle axis, signed toward the loft's v = 0 side of its middle section (the side
    the muscle's up vector U points to: the section fit starts v = 0 at U).
    local y = z x x, the shortest axis; the frame is right-handed, E_rest = [[x a, y b, z c, centre],
    [0, 0, 0, 1]] with radii (a, b, c), c the largest.
Reference ellipsoid E_ref (per frame)
    The rest ellipsoid carried rigidly by the muscle's bone (rig.joints[m, 8], the joint whose
    rotation carries the muscle's up vector and middle offset):
    ``E_ref = world[bone] @ inv(bind_world[bone]) @ E_rest``. It is where the muscle would be if it
    only rode its bone; the deformer moves the skin by the difference between it and E_cur.
Current ellipsoid E_cur (per frame)
    ``E_cur = A @ E_rest``, A the least-squares affine map of the muscle's 40 rest CVs onto its 40
    current CVs (centroid-centred normal equations: L = Y0^T X0 (X0^T X0)^-1, t = mean(Y) - L mean(X),
    with the rest pieces X0 (X0^T X0)^-1 precomputed, so a frame is one batched product over all
    muscles). An affine map carries an ellipsoid to an ellipsoid, and A is exact whenever the CVs
    move affinely (rigidly, scaled, sheared); for the bulging, bending motion of a real muscle it
    is the best affine summary of the 40 CVs. At bind (cvs == rig.rest_cvs) A is the identity to
    ~1e-15, so E_cur == E_ref to rounding and every deformer gives 0.
Skipped muscles
    A muscle is skipped (active = False, E_cur = E_ref so that nothing is NaN) when its CVs or
    action-curve CVs hold NaN or inf, or A is degenerate: the smallest singular value of its 3 x 3
    part below MIN_SINGULAR (collapsed to a point, line or plane), the largest above MAX_SINGULAR,
    or det <= 0 (mirrored). `frame` / `frames` return them as `Skipped` records naming frame, muscle
    and reason, so the caller can warn.
Trajectory path (the paper's "trajectory" option, section 4.3)
    The paper moves a deformed point from the rest to the current ellipsoid along a curve rather than
    straight, so skin over a muscle that slides around a joint follows the muscle. The curve used
    here is the muscle's own current action curve C (5 CVs, rig.muscle.model.curve_basis): t_ref and
    t_cur are the parameters of the points of the current C nearest centre_ref and centre_cur (a few
    Newton steps from t0, the rest centre's parameter on the rest curve, fixed at bind; clamped to
    [0, 1]), and with centre_ref, centre_cur the centres of E_ref, E_cur
        c(u) = C(t_ref + u (t_cur - t_ref)) + (1 - u) (centre_ref - C(t_ref)) + u (centre_cur - C(t_cur)),
    sampled at u_k = k / (K - 1), K = TRAJECTORY_SAMPLES. The two offsets from the curve are blended
    linearly, so c(0) = centre_ref and c(1) = centre_cur exactly (they are also stored exactly), and
    c(u) minus the straight chord is C's own bow between t_ref and t_cur: a straight action curve gives
    the straight segment, a bent one a path bowed like the muscle. Projecting both centres on the
    current curve (rather than keeping the rest parameter t0 for the reference end) matters: the
    static muscle's centre stays at the middle of its curve, so with t0 at the reference end the
    interval would be empty and the path straight; the reference centre, carried by the bone while
    the muscle bends with the joint, projects elsewhere on the bent curve.
Star tables (built once; Pratscher et al. 2005, section 4.4: star-shaped muscles)
    Per muscle a (STAR_THETA, STAR_PHI) = (17, 32) float32 grid of delta(theta_i, phi_j): polar angle
    theta_i = pi i / 16 about local +z, azimuth phi_j = -pi + 2 pi j / 32 from local +x toward +y.
    A ray from E_rest's centre along E_rest's image of the unit direction meets the rest loft mesh
    (embree through trimesh); at its FURTHEST hit, delta = |E_rest^-1 hit| - 1, the muscle's real
    surface measured from the unit sphere (> 0 where the muscle bulges past its ellipsoid). A ray
    that misses gives 0. The deformer reads delta by bilinear interpolation (rig.skin.shell.shells.star_lookup).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.model import _MIDDLE as BONE_SLOT
from jiggle.rig.muscle.model import curve_basis
from jiggle.rig.skin.shell.shells import STAR_PHI, STAR_THETA, TRAJECTORY_SAMPLES, ShellFrames

MIN_SINGULAR = 1e-3   # a fitted map squashing some direction below this is a collapsed muscle
MAX_SINGULAR = 1e3    # ... or stretching one beyond this a blown-up one
NEWTON_STEPS = 6      # foot point of the current centre on the action curve, from t0
STAR_THETAS = np.pi * np.arange(STAR_THETA) / (STAR_THETA - 1)
STAR_PHIS = -np.pi + 2.0 * np.pi * np.arange(STAR_PHI) / STAR_PHI
TRAJECTORY_U = np.linspace(0.0, 1.0, TRAJECTORY_SAMPLES)
for _a in (STAR_THETAS, STAR_PHIS, TRAJECTORY_U):
    _a.setflags(write=False)

REASONS = ("", "its CVs or action curve hold NaN or inf", "collapsed", "over-stretched", "mirrored")
"""Why a muscle was skipped, indexed by the reason code of `Skipped` (0: active)."""


class Skipped(NamedTuple):
    """A muscle left out of one frame (active = False).

    frame : frame number (the batch index plus `first_frame`).
    muscle : muscle index; name : its name.
    reason : code into REASONS (1 non-finite, 2 collapsed, 3 over-stretched, 4 mirrored).
    singular : (smallest, largest) singular value of the fitted map's 3 x 3 part (NaN for code 1).
    """

    frame: int
    muscle: int
    name: str
    reason: int
    singular: tuple

    @property
    def message(self) -> str:
        """One line for a warning, e.g. "frame 12: muscle 'biceps' skipped: collapsed (...)"."""
        s_min, s_max = self.singular
        detail = {2: f" (smallest singular value of its fitted map {s_min:.3g} < {MIN_SINGULAR:g})",
                  3: f" (largest singular value of its fitted map {s_max:.3g} > {MAX_SINGULAR:g})",
                  4: " (the fitted map has det <= 0)"}.get(self.reason, "")
        return f"frame {self.frame}: muscle {self.name!r} skipped: {REASONS[self.reason]}{detail}"


# ---------------------------------------------------------------------------------- solid moments
def solid_moments(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Volume, centroid and covariance of the solids bounded by closed, outward triangle meshes.

    points : (..., P, 3) vertices (any batch shape, e.g. (M, P, 3) for all muscles), metres.
    faces : (F, 3) int triangles shared by every mesh of the batch, outward.
    Returns volume (...) m^3, centroid (..., 3) m, covariance (..., 3, 3) m^2 of the uniform solid.

    Divergence theorem: every face (a, b, c) and a point o span a signed tetrahedron; their signed
    volumes, centroids and second moments sum to the solid's. For a tetrahedron with one corner at
    the origin, V = a . (b x c) / 6, centroid (a + b + c) / 4 and
    int x x^T dV = V / 20 (a a^T + b b^T + c c^T + s s^T), s = a + b + c. o is each mesh's vertex
    mean, so the products stay small whatever the mesh's place in the world.
    """
    p = np.asarray(points, dtype=np.float64)
    ref = p.mean(axis=-2, keepdims=True)
    tri = (p - ref)[..., np.asarray(faces), :]                                  # (..., F, 3, 3)
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    vol = np.einsum("...i,...i->...", a, np.cross(b, c)) / 6.0                 # (..., F)
    s = a + b + c
    volume = vol.sum(axis=-1)
    first = np.einsum("...f,...fi->...i", vol, s) / 4.0
    second = (np.einsum("...f,...fki,...fkj->...ij", vol, tri, tri)
              + np.einsum("...f,...fi,...fj->...ij", vol, s, s)) / 20.0
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = first / volume[..., None]
        cov = second / volume[..., None, None] - mean[..., :, None] * mean[..., None, :]
    return volume, mean + ref[..., 0, :], cov


def solid_ellipsoids(points: np.ndarray, faces: np.ndarray, along: np.ndarray, side: np.ndarray) -> np.ndarray:
    """(M, 4, 4) float64 ellipsoids of M closed outward meshes (points (M, P, 3) metres, shared faces
    (F, 3)) from their solid moments: centre = volume centroid, radii = sqrt(5 x covariance
    eigenvalue). Local z = the longest axis signed along `along` (M, 3), local x = the middle axis
    signed along `side` (M, 3), local y = z x x the shortest (right-handed)."""
    M = len(points)
    if M == 0:
        return np.zeros((0, 4, 4))
    _, centre, cov = solid_moments(points, faces)
    lam, vec = np.linalg.eigh(cov)                                              # ascending, columns
    radii = np.sqrt(5.0 * np.clip(lam, 1e-30, None))
    z, x = vec[:, :, 2], vec[:, :, 1]
    z = np.where(np.einsum("mi,mi->m", z, along)[:, None] < 0, -z, z)
    x = np.where(np.einsum("mi,mi->m", x, side)[:, None] < 0, -x, x)
    E = np.zeros((M, 4, 4))
    E[:, :3, 0] = x * radii[:, 1:2]
    E[:, :3, 1] = np.cross(z, x) * radii[:, 0:1]
    E[:, :3, 2] = z * radii[:, 2:3]
    E[:, :3, 3] = centre
    E[:, 3, 3] = 1.0
    return E


def rest_ellipsoids(rig) -> np.ndarray:
    """(M, 4, 4) float64 E_rest of every muscle of `rig` (a MuscleRig) from its rest loft's solid
    moments: local unit sphere -> world metres, local z the longest axis (origin -> insertion), local
    x the middle axis (toward the loft's v = 0 side), y = z x x the shortest (module docstring)."""
    pts = rig.surface(rig.rest_cvs)                                             # (M, P, 3)
    # sign references taken from the loft itself (no bind transforms needed): its two cap points are
    # the first and last sections' centroids; its middle row's column 0 sits at v = 0, opposite v = 4
    mid = (loft.ROWS // 2) * loft.COLS
    return solid_ellipsoids(pts, rig.surface_faces, pts[:, -1] - pts[:, -2],
                            pts[:, mid] - pts[:, mid + loft.COLS // 2])


# ---------------------------------------------------------------------------------- star tables
def star_directions() -> np.ndarray:
    """(STAR_THETA, STAR_PHI, 3) local unit directions of the star table's nodes:
    (sin theta cos phi, sin theta sin phi, cos theta)."""
    th, ph = np.meshgrid(STAR_THETAS, STAR_PHIS, indexing="ij")
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)


def star_tables(points: np.ndarray, faces: np.ndarray, E: np.ndarray) -> np.ndarray:
    """(S, STAR_THETA, STAR_PHI) float32 star offsets delta of S closed meshes.

    points : (S, P, 3) vertices metres, faces (F, 3) shared; E : (S, 4, 4) each mesh's ellipsoid.
    A ray leaves E's centre along E's image of each node's direction; delta = |E^-1 hit| - 1 at its
    furthest hit with the mesh (0 when it misses). Build time only: one small embree scene per
    mesh (trimesh picks embree when installed). One scene holding every muscle would be queried
    once, but neighbours' hits then crowd each ray's multiple-hit walk, which loses own hits where
    muscles overlap, and it is slower."""
    import trimesh

    S = len(points)
    u = star_directions().reshape(-1, 3)                                        # (R, 3) local
    out = np.zeros((S, len(u)))
    for s in range(S):          # build time: one scene per muscle
        mesh = trimesh.Trimesh(np.asarray(points[s], np.float64), np.asarray(faces), process=False)
        d = u @ E[s, :3, :3].T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        origins = np.broadcast_to(E[s, :3, 3], d.shape)
        loc, ray, _ = mesh.ray.intersects_location(origins, d, multiple_hits=True)
        Einv = np.linalg.inv(E[s])
        radius = np.full(len(u), -np.inf)
        np.maximum.at(radius, ray, np.linalg.norm(loc @ Einv[:3, :3].T + Einv[:3, 3], axis=1))   # FURTHEST hit
        out[s] = np.where(np.isfinite(radius), radius - 1.0, 0.0)
    return out.reshape(S, STAR_THETA, STAR_PHI).astype(np.float32)


# ---------------------------------------------------------------------------------- action curve
def _span_polynomials() -> np.ndarray:
    """(2, 4, 5) power-basis coefficients of the 5 curve weights on the action curve's two knot spans:
    weights(t) = sum_k P[s, k] x^k, s = 0 for t < 0.5 else 1, x = t - 0.5 s. The same cubic
    B-spline as curve_basis, evaluated with a few products instead of a scipy call per Newton step."""
    out = np.zeros((2, 4, 5))
    x = np.array([0.0, 0.5 / 3.0, 1.0 / 3.0, 0.5])
    V = x[:, None] ** np.arange(4)
    for s in range(2):
        out[s] = np.linalg.solve(V, curve_basis(0.5 * s + x))
    return out


_SPANS = frozen_array(_span_polynomials())


def curve_points(curve: np.ndarray, t: np.ndarray, derivatives: int = 0) -> list[np.ndarray]:
    """Points of action curves and their derivatives: curve (..., 5, 3) CVs, t (..., n) parameters in
    [0, 1] (clipped). Returns [C, dC/dt, ...] up to `derivatives` (<= 2), each (..., n, 3)."""
    curve = np.asarray(curve, dtype=np.float64)
    lead = curve.shape[:-2]
    t = np.asarray(t, dtype=np.float64)
    t = np.broadcast_to(t, lead + t.shape[-1:])
    n = t.shape[-1]
    out = _span_points(_power(curve), t.reshape(-1, n).T, derivatives)        # (3, n, N) each
    return [np.moveaxis(x, 0, -1).swapaxes(0, 1).reshape(lead + (n, 3)) for x in out]


def _power(curve: np.ndarray) -> np.ndarray:
    """(2, 4, 3, N) power coefficients Q[span, power, component, curve] of N action curves
    (..., 5, 3) (flattened): on span s, C(t) = sum_k Q[s, k] x^k, x = t - 0.5 s. Component-major,
    so a Newton step works on contiguous (N,) rows (~3x faster than curve-major); one BLAS product."""
    c = np.asarray(curve, dtype=np.float64).reshape(-1, 5, 3)
    return (_SPANS.reshape(8, 5) @ c.transpose(1, 2, 0).reshape(5, -1)).reshape(2, 4, 3, -1)


def _span_points(Q: np.ndarray, t: np.ndarray, derivatives: int) -> list[np.ndarray]:
    """[C, dC/dt, ...] up to `derivatives` (<= 2) of the N curves of Q (2, 4, 3, N) (`_power`) at
    parameters t (..., N) (clipped to [0, 1]), each (3, ..., N): Horner's rule on each point's span."""
    t = np.clip(t, 0.0, 1.0)
    second = t >= 0.5
    x = t - np.where(second, 0.5, 0.0)
    shape = (3,) + (1,) * (t.ndim - 1) + t.shape[-1:]
    q0, q1, q2, q3 = (np.where(second, Q[1, k].reshape(shape), Q[0, k].reshape(shape)) for k in range(4))
    out = [q0 + x * (q1 + x * (q2 + x * q3))]
    if derivatives >= 1:
        out.append(q1 + x * (2.0 * q2 + 3.0 * x * q3))
    if derivatives >= 2:
        out.append(2.0 * q2 + 6.0 * x * q3)
    return out


def nearest_parameter(curve: np.ndarray, p: np.ndarray, t: np.ndarray, steps: int = NEWTON_STEPS) -> np.ndarray:
    """(...) parameter in [0, 1] of the point of each action curve (..., 5, 3) nearest p (..., 3),
    by Newton's method on g(t) = (C(t) - p) . C'(t) from t (...). Where the curve's curvature term
    would make g' <= 0.1 |C'|^2 (p far on the concave side) the Gauss-Newton slope |C'|^2 is used;
    steps are limited to 0.25 and clamped to [0, 1] (beyond an end the end is nearest)."""
    curve, p, t = (np.asarray(a, dtype=np.float64) for a in (curve, p, t))
    lead = np.broadcast_shapes(curve.shape[:-2], p.shape[:-1], t.shape)
    Q = _power(np.broadcast_to(curve, lead + (5, 3)))
    t = _nearest(Q, np.broadcast_to(p, lead + (3,)).reshape(-1, 3).T, np.broadcast_to(t, lead).ravel(), steps)
    return t.reshape(lead)


def _nearest(Q: np.ndarray, p: np.ndarray, t: np.ndarray, steps: int = NEWTON_STEPS) -> np.ndarray:
    """nearest_parameter (N,) of the N curves of Q (2, 4, 3, N) (`_power`), points p (3, N), from t (N,)."""
    t = np.clip(t, 0.0, 1.0)
    for _ in range(steps):
        C, d1, d2 = _span_points(Q, t, 2)
        r = C - p
        g = (r * d1).sum(axis=0)
        speed2 = (d1 * d1).sum(axis=0)
        h = speed2 + (r * d2).sum(axis=0)
        h = np.where(h > 0.1 * speed2, h, speed2) + 1e-300
        t = np.clip(t - np.clip(g / h, -0.25, 0.25), 0.0, 1.0)
    return t


def trajectory(curve: np.ndarray, t0: np.ndarray, t_cur: np.ndarray, centre_ref: np.ndarray,
               centre_cur: np.ndarray, u: np.ndarray = TRAJECTORY_U) -> np.ndarray:
    """(..., K, 3) samples c(u_k) of the trajectory path (module docstring) for action curves
    (..., 5, 3), parameters t0, t_cur (...), centres (..., 3) and path parameters u (K,)."""
    curve, t0, t_cur, centre_ref, centre_cur = (np.asarray(a, dtype=np.float64)
                                                for a in (curve, t0, t_cur, centre_ref, centre_cur))
    lead = np.broadcast_shapes(curve.shape[:-2], t0.shape, t_cur.shape, centre_ref.shape[:-1],
                               centre_cur.shape[:-1])
    flat = [np.broadcast_to(a, lead).ravel() for a in (t0, t_cur)]
    centres = [np.broadcast_to(c, lead + (3,)).reshape(-1, 3).T for c in (centre_ref, centre_cur)]
    c = _trajectory(_power(np.broadcast_to(curve, lead + (5, 3))), *flat, *centres, np.asarray(u, np.float64))
    return _curve_major(c, lead)


def _curve_major(c: np.ndarray, lead: tuple) -> np.ndarray:
    """(3, K, N) component-major samples -> (*lead, K, 3), N = prod(lead)."""
    return np.ascontiguousarray(c.transpose(2, 1, 0)).reshape(lead + c.shape[1:2] + (3,))


def _trajectory(Q: np.ndarray, t0: np.ndarray, t_cur: np.ndarray, centre_ref: np.ndarray,
                centre_cur: np.ndarray, u: np.ndarray = TRAJECTORY_U) -> np.ndarray:
    """trajectory of the N curves of Q (2, 4, 3, N) (`_power`): parameters t0, t_cur (N,), centres
    (3, N); returns the samples component-major, (3, K, N)."""
    t = t0 + u[:, None] * (t_cur - t0)                                          # (K, N)
    Ck, = _span_points(Q, t, 0)                                                 # (3, K, N)
    C01, = _span_points(Q, np.stack([t0, t_cur]), 0)                            # (3, 2, N)
    w = u[:, None]
    c = Ck + (1.0 - w) * (centre_ref - C01[:, 0])[:, None, :] + w * (centre_cur - C01[:, 1])[:, None, :]
    c[:, 0] = centre_ref      # exact ends, whatever the rounding of the sums above
    c[:, -1] = centre_cur
    return c


# ---------------------------------------------------------------------------------- frames
@dataclass(frozen=True, eq=False)
class MuscleFrames:
    """What the shell deformer needs of a muscle rig, built once (`MuscleFrames.build`); read-only.

    names : (M,) muscle names (for warnings).
    num_joints : J, the joints `world` must hold.
    E_rest, E_rest_inv : (M, 4, 4) float64, rest ellipsoids (local unit sphere -> world metres) and
        their inverses; local z the long axis (module docstring).
    bone : (M,) int64, the joint each muscle rides (rig.joints[:, 8]).
    bind_inv : (M, 4, 4) float64, inv(bind_world[bone]) per muscle.
    bind_bone : (M, 4, 4) float64, bind_world[bone] per muscle.
    rest_cvs : (M, 40, 3) float64 metres, each muscle's rest CVs (rig.rest_cvs by muscle).
    rest_mean : (M, 3) their centroids.
    fit_weights : (M, 40, 3) X0 (X0^T X0)^-1, X0 the centred rest CVs: the current CVs Y give the
        affine fit's 3 x 3 part as L = (Y - mean Y)^T fit_weights.
    t0 : (M,) parameter of the rest action curve's point nearest each rest centre.
    star : (S, STAR_THETA, STAR_PHI) float32 star offsets; star_index : (M,) int32 row of each
        muscle in `star` (-1: none).
    """

    names: tuple
    num_joints: int
    E_rest: np.ndarray
    E_rest_inv: np.ndarray
    bone: np.ndarray
    bind_inv: np.ndarray
    bind_bone: np.ndarray
    rest_cvs: np.ndarray
    rest_mean: np.ndarray
    fit_weights: np.ndarray
    t0: np.ndarray
    star: np.ndarray
    star_index: np.ndarray

    @property
    def M(self) -> int:
        """Number of muscles."""
        return len(self.names)

    @classmethod
    def build(cls, rig, bind_world: np.ndarray, star=True) -> MuscleFrames:
        """Frames of `rig` (a MuscleRig) whose joints have rigid bind transforms `bind_world` (J, 4, 4)
        metres (the ones the rig was built with). `star`: True (a star table for every muscle), False
        (none) or a sequence of M bools."""
        bind_world = np.asarray(bind_world, dtype=np.float64)
        J, M = rig.num_joints, rig.M
        if bind_world.shape != (J, 4, 4):
            raise InputError(f"bind_world must be ({J}, 4, 4), got {bind_world.shape}", field="bind_world")
        if not np.isfinite(bind_world).all():
            raise InputError("bind_world holds NaN or inf", field="bind_world")
        want = np.broadcast_to(np.asarray(star, dtype=bool), (M,)) if np.ndim(star) == 0 else np.asarray(star)
        if want.shape != (M,) or want.dtype != bool:
            raise InputError(f"star must be a bool or {M} bools, got {np.asarray(star)!r}", field="star")

        E = rest_ellipsoids(rig)
        bone = np.asarray(rig.joints[:, BONE_SLOT], dtype=np.int64)
        X = np.asarray(rig.rest_cvs, dtype=np.float64).reshape(M, rig.CVS_PER_MUSCLE, 3)
        mean = X.mean(axis=1)
        X0 = X - mean[:, None]
        gram = np.einsum("mki,mkj->mij", X0, X0)
        fit = np.linalg.solve(gram, X0.transpose(0, 2, 1)).transpose(0, 2, 1) if M else np.zeros((0, 40, 3))
        rest_curve = np.asarray(rig.rest_curve, dtype=np.float64)
        # t0: nearest of a dense sampling of the rest curve, then Newton
        dense = np.linspace(0.0, 1.0, 65)
        pts, = curve_points(rest_curve, np.broadcast_to(dense, (M, len(dense))))
        start = dense[np.argmin(np.linalg.norm(pts - E[:, None, :3, 3], axis=-1), axis=1)] if M else np.zeros(0)
        t0 = nearest_parameter(rest_curve, E[:, :3, 3], start, steps=2 * NEWTON_STEPS)
        index = np.full(M, -1, np.int32)
        index[want] = np.arange(int(want.sum()), dtype=np.int32)
        surface = rig.surface(rig.rest_cvs)
        table = star_tables(surface[want], rig.surface_faces, E[want])
        return cls(names=tuple(rig.names), num_joints=J, E_rest=frozen_array(E),
                   E_rest_inv=frozen_array(np.linalg.inv(E) if M else E), bone=frozen_array(bone, np.int64),
                   bind_inv=frozen_array(np.linalg.inv(bind_world)[bone]), bind_bone=frozen_array(bind_world[bone]),
                   rest_cvs=frozen_array(X), rest_mean=frozen_array(mean), fit_weights=frozen_array(fit),
                   t0=frozen_array(t0), star=frozen_array(table, np.float32), star_index=frozen_array(index, np.int32))

    # ------------------------------------------------------------------ per frame
    def frame(self, world: np.ndarray, cvs: np.ndarray, curve: np.ndarray, frame: int = 0
              ) -> tuple[ShellFrames, tuple[Skipped, ...]]:
        """Ellipsoids of one frame.

        world : (J, 4, 4) rigid joint world transforms, metres.
        cvs : (N, 3) current section CVs of all muscles (static, simulated or blended), metres.
        curve : (M, 5, 3) current action-curve CVs (rig.static(world).curve), metres.
        frame : frame number put into the Skipped records.
        Returns (ShellFrames, skipped): skipped muscles have active = False (see `Skipped.message`).
        """
        world, cvs, curve = self._check(world, cvs, curve, single=True)
        out, skipped = self._compute(world[None], cvs[None], curve[None], frame)
        return ShellFrames(*(x[0] for x in out)), skipped

    def frames(self, world: np.ndarray, cvs: np.ndarray, curve: np.ndarray, first_frame: int = 0
               ) -> tuple[list[ShellFrames], tuple[Skipped, ...]]:
        """Ellipsoids of T frames at once: world (T, J, 4, 4), cvs (T, N, 3), curve (T, M, 5, 3).
        Returns (list of T ShellFrames, skipped); Skipped.frame = first_frame + batch index."""
        world, cvs, curve = self._check(world, cvs, curve, single=False)
        out, skipped = self._compute(world, cvs, curve, first_frame)
        return [ShellFrames(*(x[t] for x in out)) for t in range(len(world))], skipped

    def frame_sets(self, world: np.ndarray, cvs_sets, curves, first_frame: int = 0, paths: bool = True):
        """Ellipsoids of S sets of muscle states over the same T frames (e.g. the static and the
        blended CVs of a bake chunk), the bones' part computed once.

        world : (T, J, 4, 4) rigid joint world transforms, metres.
        cvs_sets : S arrays (T, N, 3) of section CVs, metres. curves : S arrays (T, M, 5, 3) of
            action-curve CVs, metres (sets over the same curve also share its reference parameters).
        Returns (arrays, skipped): arrays = (E_ref, E_ref_inv) (T, M, 4, 4) shared by the sets, then
        E_cur, E_cur_inv (S, T, M, 4, 4), curve (S, T, M, K, 3) trajectory samples, active (S, T, M);
        skipped = S tuples of Skipped (frame = first_frame + batch index). Set s at frame t equals
        `frame(world[t], cvs_sets[s][t], curves[s][t], first_frame + t)`.
        paths : False: no trajectory paths (no muscle is in "trajectory" mode, the only reader): each
            muscle's K samples are its current centre, the curve's nearest points are not searched.
        """
        if len(cvs_sets) != len(curves) or not len(cvs_sets):
            raise InputError(f"expected as many curves as CVs sets (at least one), got {len(curves)} and "
                             f"{len(cvs_sets)}", field="curves")
        checked = [self._check(world, c, k, single=False) for c, k in zip(cvs_sets, curves)]
        world = checked[0][0]
        E_ref, E_ref_inv = self._reference(world)
        sets, skipped, shared = [], [], []          # shared: (curve, its `along`) already computed
        for _, cvs, curve in checked:
            along = next((a for k, a in shared if k is curve or np.array_equal(k, curve, equal_nan=True)), None)
            cur, sk, along = self._current(E_ref, E_ref_inv, cvs, curve, first_frame, along, paths)
            shared.append((curve, along))
            sets.append(cur)
            skipped.append(sk)
        stacked = tuple(np.stack(x) for x in zip(*sets))
        return (E_ref, E_ref_inv) + stacked, tuple(skipped)

    def carried_rest_cvs(self, world: np.ndarray) -> np.ndarray:
        """The rest CVs moved rigidly with each muscle's bone, world[bone] @ inv(bind_world[bone]) @ cv:
        (N, 3) for world (J, 4, 4), (T, N, 3) for (T, J, 4, 4), metres. The muscle as it would be if
        it only rode its bone (the reference surface of influence objects)."""
        world = self._check_world(world)
        K = world[..., self.bone, :, :] @ self.bind_inv                           # (..., M, 4, 4)
        cvs = np.einsum("...mij,mkj->...mki", K[..., :3, :3], self.rest_cvs) + K[..., None, :3, 3]
        return cvs.reshape(world.shape[:-3] + (-1, 3))

    def _check_world(self, world: np.ndarray) -> np.ndarray:
        world = np.asarray(world, dtype=np.float64)
        if world.ndim not in (3, 4) or world.shape[-3:] != (self.num_joints, 4, 4):
            raise InputError(f"world transforms must be ({self.num_joints}, 4, 4) or (T, {self.num_joints}, 4, 4), "
                             f"got {world.shape}", field="world")
        if not np.isfinite(world).all():
            raise InputError("world transforms hold NaN or inf", field="world")
        return world

    def _check(self, world, cvs, curve, single: bool):
        world = self._check_world(world)
        cvs = np.asarray(cvs, dtype=np.float64)
        curve = np.asarray(curve, dtype=np.float64)
        lead = () if single else world.shape[:1]
        if world.ndim != (3 if single else 4):
            raise InputError(f"world transforms must be {'' if single else '(T, '}({self.num_joints}, 4, 4)"
                             f"{'' if single else ')'}, got {world.shape}", field="world")
        if cvs.shape != lead + (40 * self.M, 3):
            raise InputError(f"cvs must be {lead + (40 * self.M, 3)}, got {cvs.shape}", field="cvs")
        if curve.shape != lead + (self.M, 5, 3):
            raise InputError(f"curve must be {lead + (self.M, 5, 3)}, got {curve.shape}", field="curve")
        return world, cvs, curve

    def _compute(self, world: np.ndarray, cvs: np.ndarray, curve: np.ndarray, first_frame: int):
        """Arrays (T, M, ...) in ShellFrames' field order, and the Skipped records, for world
        (T, J, 4, 4), cvs (T, N, 3), curve (T, M, 5, 3)."""
        E_ref, E_ref_inv = self._reference(world)
        cur, skipped, _ = self._current(E_ref, E_ref_inv, cvs, curve, first_frame)
        return (E_ref, E_ref_inv) + cur, skipped

    def _reference(self, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """E_ref, E_ref_inv (T, M, 4, 4) for world (T, J, 4, 4): the rest ellipsoid riding the bone,
        its inverse without a 4 x 4 inverse per muscle."""
        K = world[:, self.bone] @ self.bind_inv                                    # (T, M, 4, 4)
        E_ref = K @ self.E_rest
        E_ref_inv = self.E_rest_inv @ (self.bind_bone @ np.linalg.inv(world)[:, self.bone])
        return E_ref, E_ref_inv

    def _along(self, curve: np.ndarray, centre_ref: np.ndarray) -> tuple:
        """What the trajectory needs of the action curves (T, M, 5, 3) and the bones alone: whether each
        curve is finite (T, M), the power coefficients (`_power`) of the curves with non-finite ones
        zeroed, and the parameters t_ref (T M,) of the reference centres (3, T M) on them. Sets of CVs
        over one curve share it."""
        ok = np.isfinite(curve).all(axis=(2, 3))
        C = curve if ok.all() else np.where(ok[..., None, None], curve, 0.0)
        Q = _power(C)
        t_ref = _nearest(Q, centre_ref, np.broadcast_to(self.t0, ok.shape).ravel())
        return ok, Q, t_ref

    def _current(self, E_ref: np.ndarray, E_ref_inv: np.ndarray, cvs: np.ndarray, curve: np.ndarray,
                 first_frame: int, along: tuple | None = None, paths: bool = True):
        """(E_cur, E_cur_inv, path, active), the Skipped records and `along` (see `_along`) for the
        reference ellipsoids (T, M, 4, 4), cvs (T, N, 3) and curve (T, M, 5, 3). `along`: already
        computed for this curve and these frames (another set of CVs over the same curve). paths:
        False: each path is its muscle's current centre K times (see `frame_sets`)."""
        T, M = len(E_ref), self.M
        centre_ref = E_ref[..., :3, 3].reshape(-1, 3).T                             # (3, T M)
        # the curves alone decide C (a muscle skipped for its CVs gets its path replaced below), so
        # t_ref depends on the curves and the bones only and sets of CVs over one curve share it
        if along is None:
            along = self._along(curve, centre_ref) if paths else (np.isfinite(curve).all(axis=(2, 3)), None, None)
        curve_ok, Q, t_ref = along
        Y = cvs.reshape(T, M, self.rest_cvs.shape[1], 3)
        finite = np.isfinite(Y).all(axis=(2, 3)) & curve_ok                         # (T, M)
        # a non-finite muscle is fitted to its rest CVs instead, so no NaN reaches the SVD
        if not finite.all():
            Y = np.where(finite[..., None, None], Y, self.rest_cvs)
        ybar = np.einsum("tmkc->tmc", Y) / Y.shape[2]           # the mean; einsum's sum is the fastest
        L = np.swapaxes(Y - ybar[:, :, None], -1, -2) @ self.fit_weights            # (T, M, 3, 3)
        det = np.linalg.det(L) if M else np.zeros((T, 0))
        # singular values (an SVD) only where they may decide or be reported: s_max <= |L|_F and
        # s_min >= 2 det / |L|_F^2 (s_1 s_2 <= |L|_F^2 / 2), so a map with det > 0 inside these
        # bounds (1% margin for rounding) is neither collapsed, over-stretched nor mirrored
        fro2 = np.einsum("tmij,tmij->tm", L, L)
        unsure = ~((fro2 < (0.99 * MAX_SINGULAR) ** 2) & (2.0 * det > 1.01 * MIN_SINGULAR * fro2))
        sv = np.ones((T, M, 3))
        if unsure.any():
            sv[unsure] = np.linalg.svd(L[unsure], compute_uv=False)
        reason = np.select([~finite, sv[..., -1] < MIN_SINGULAR, sv[..., 0] > MAX_SINGULAR, det <= 0.0],
                           [1, 2, 3, 4], 0)
        active = reason == 0
        eye = np.eye(3)
        L = np.where(active[..., None, None], L, eye)                               # keep inverses finite
        t = ybar - np.einsum("tmij,mj->tmi", L, self.rest_mean)
        Linv = np.linalg.inv(L)
        E_cur = np.zeros_like(E_ref)
        E_cur[..., :3, :3] = L @ self.E_rest[:, :3, :3]
        E_cur[..., :3, 3] = np.einsum("tmij,mj->tmi", L, self.E_rest[:, :3, 3]) + t
        E_cur[..., 3, 3] = 1.0
        A_inv = np.zeros_like(E_ref)
        A_inv[..., :3, :3] = Linv
        A_inv[..., :3, 3] = -np.einsum("tmij,tmj->tmi", Linv, t)
        A_inv[..., 3, 3] = 1.0
        E_cur_inv = self.E_rest_inv @ A_inv
        E_cur = np.where(active[..., None, None], E_cur, E_ref)
        E_cur_inv = np.where(active[..., None, None], E_cur_inv, E_ref_inv)

        centre_cur = E_cur[..., :3, 3].reshape(-1, 3).T
        if paths:
            t_cur = _nearest(Q, centre_cur, np.broadcast_to(self.t0, (T, M)).ravel())
            path = _curve_major(_trajectory(Q, t_ref, t_cur, centre_ref, centre_cur), (T, M))
        else:
            path = np.repeat(E_cur[..., None, :3, 3], TRAJECTORY_SAMPLES, axis=2)
        # a skipped muscle stands still on its reference centre
        if not active.all():
            path = np.where(active[..., None, None], path, E_ref[..., None, :3, 3])

        skipped = tuple(Skipped(first_frame + int(f), int(m), self.names[m], int(reason[f, m]),
                                (float(sv[f, m, -1]), float(sv[f, m, 0])) if finite[f, m] else (np.nan, np.nan))
                        for f, m in zip(*np.nonzero(~active)))
        return (E_cur, E_cur_inv, path, active), skipped, along
