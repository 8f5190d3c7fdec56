"""Influence-object skinning: skin vertices attached to points of the muscles' lofted surfaces.

Hoehne's thesis (section 6.6) skins the character with Maya's smooth skinning and adds the muscles as
NURBS influence objects: "every point gets attached to one corresponding point on the surface of the
NURBS object", weighted by painted per-vertex muscle weights. Ours is the RELATIVE form of that, so the
artist's skin is reproduced exactly at bind and the deformer adds only what the muscles do beyond
their bones:

Bind (:func:`bind_influence`)
    For each (vertex, muscle) pair, the foot point of the vertex on the muscle's smooth loft
    ``X(w, v)`` (rig/loft.py; w in [0, 4] across the sections, clamped, so a vertex beyond an end
    attaches to the end ring; v in [0, 8) around, periodic) built from its 40 rest CVs: the nearest
    sample of a 33 x 64 grid, then Newton's method on ``|X(w, v) - p|^2`` with a step search and w
    held at a bound it presses against (:func:`closest_points`). The vertex's offset
    ``o = p - X(w, v)`` is stored in the loft frame at (w, v):
    ``e1 = unit(dX/dw)``, ``n = unit(dX/dv x dX/dw)`` (outward for the loft's orientation: sections
    from origin to insertion, v turning from a section's up vector U toward its side T x U, the
    orientation of rig.loft.FACES), ``e2 = n x e1``; offset = (o . e1, o . e2, o . n). Where a frame
    axis cannot be normalised (collapsed CVs: its vector under FRAME_EPS x the muscle's rest size) it
    is 0, at bind (with a JiggleWarning) and per frame alike: no NaN for finite input.
Per frame
    ``attach(cvs) = X(w, v) + offset[0] e1 + offset[1] e2 + offset[2] n`` evaluated from a CV array
    (the frame is right-handed and orthonormal, so attach follows any rigid motion of the CVs
    exactly). Vertex i moves by ``sum over its pairs of weight * (attach(cvs_cur) - attach(cvs_ref))``
    where cvs_ref are the rest CVs carried rigidly by each muscle's bone
    (rig.muscle_frames.MuscleFrames.carried_rest_cvs). At rest the displacement is exactly 0; a muscle
    moved rigidly by T relative to its bone carries a weight-1 vertex by exactly T. The pairs' terms
    are summed (not applied in series): each depends only on the CVs, not on the vertex's position.

Pairs are CSR, sorted by vertex: ``pair_offsets`` (V + 1,) int, ``pair_muscle`` (P,) int,
``pair_weight`` (P,) float in [0, 1] (painted). Flat CVs (N, 3), N = 40 M, muscle m owning rows
40 m .. 40 m + 39 section-major, as rig.muscle_model.MuscleRig.rest_cvs.

- :func:`bind_influence` -> :class:`InfluenceBinding` (frozen, per pair parameters and the kernel's
  precomputed basis).
- :class:`InfluenceDeformer`: the Warp launcher (kernel in :mod:`rig.influence_kernels`). (w, v) are
  fixed per pair, so the spline bases are evaluated once at bind: per pair the 5 section weights and
  their d/dw, and the 4 non-zero ring weights and their d/dv with the index of the first ring CV;
  the kernel then needs no spline code and reads 20 of a muscle's 40 CVs per evaluation.
- :func:`influence_numpy`: the vectorised float64 reference (no input checks), evaluating the loft
  from (w, v) with :func:`rig.loft.surface_weights` rather than the precomputed basis.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from rig import influence_kernels as kernels
from rig import loft
from rig.errors import InputError, JiggleWarning
from rig.frozen import frozen_array

CVS_PER_MUSCLE = loft.SECTIONS * loft.RING      # 40
FRAME_EPS = 1e-3                # a frame axis shorter than this x the muscle's size counts as collapsed
PROJECT_STEPS = 40              # Newton iterations at most (most points stop after ~5)
_STEP_SCALES = (1.0, 0.5, 0.25, 0.125, 0.0625)  # step search of each Newton iteration
_CHUNK = 32768                  # pairs per block in the NumPy reference (bounds its temporaries)


# ---------------------------------------------------------------------------------------------
# the loft and its frame


def _evaluate(X: np.ndarray, w: np.ndarray, v: np.ndarray, second: bool = False):
    """Loft of one muscle's CVs X (5, 8, 3) at parameters (w, v) (n,): points X(w, v) and the partial
    derivatives dX/dw, dX/dv, (n, 3) each; with `second` also d2X/dw2, d2X/dwdv, d2X/dv2."""
    Xr = X.transpose(1, 0, 2).reshape(loft.RING, -1)                    # ring CV j -> (section, xyz)
    n = len(w)
    ring = (loft.ring_weights(v) @ Xr).reshape(n, loft.SECTIONS, 3)
    ring_v = (loft.ring_weights(v, 1) @ Xr).reshape(n, loft.SECTIONS, 3)
    s0, s1 = loft.section_weights(w)[:, :, None], loft.section_weights(w, 1)[:, :, None]
    out = ((s0 * ring).sum(1), (s1 * ring).sum(1), (s0 * ring_v).sum(1))
    if not second:
        return out
    ring_vv = (_ring_second(v) @ Xr).reshape(n, loft.SECTIONS, 3)
    s2 = loft.section_weights(w, 2)[:, :, None]
    return out + ((s2 * ring).sum(1), (s1 * ring_v).sum(1), (s0 * ring_vv).sum(1))


def _ring_second(v: np.ndarray) -> np.ndarray:
    """(n, 8) second derivative d2/dv2 of rig.loft.ring_weights (the cubic's b'' = (1 - t, 3 t - 2,
    1 - 3 t, t) on CVs i - 1 .. i + 2)."""
    v = np.mod(v, loft.RING)
    i = np.floor(v).astype(np.int64)
    t = v - i
    out = np.zeros((len(v), loft.RING))
    cols = (i[:, None] - 1 + np.arange(4)) % loft.RING          # four distinct columns per row
    out[np.arange(len(v))[:, None], cols] = np.stack([1 - t, 3 * t - 2, 1 - 3 * t, t], axis=1)
    return out


def loft_frame(xw: np.ndarray, xv: np.ndarray, eps) -> np.ndarray:
    """(n, 3, 3) rows e1 = unit(dX/dw), e2 = n x e1, n = unit(dX/dv x dX/dw) (outward) from the
    partial derivatives (n, 3) each. eps (metres, scalar or (n,)): an axis too short to normalise is
    0 rather than noise, e1 where |dX/dw| <= eps, n where |dX/dv x dX/dw| <= eps |dX/dw| (collapsed
    CVs); the kernel's rule (rig.influence_kernels.frame_apply)."""
    eps = np.broadcast_to(np.asarray(eps, np.float64), xw.shape[:1])[:, None]
    lw = np.linalg.norm(xw, axis=1, keepdims=True)
    c = np.cross(xv, xw)
    lc = np.linalg.norm(c, axis=1, keepdims=True)
    ok_w = lw > eps
    ok_n = ok_w & (lc > eps * lw)
    e1 = np.where(ok_w, xw / np.where(ok_w, lw, 1.0), 0.0)
    n = np.where(ok_n, c / np.where(ok_n, lc, 1.0), 0.0)
    return np.stack([e1, np.cross(n, e1), n], axis=1)


def muscle_eps(cvs: np.ndarray) -> np.ndarray:
    """(M,) metres: FRAME_EPS x the rms distance of each muscle's CVs (40 M, 3) from their mean."""
    X = np.asarray(cvs, np.float64).reshape(-1, CVS_PER_MUSCLE, 3)
    return FRAME_EPS * np.sqrt(((X - X.mean(axis=1, keepdims=True)) ** 2).sum(axis=2).mean(axis=1))


def closest_points(p: np.ndarray, X: np.ndarray, steps: int = PROJECT_STEPS):
    """Foot points of p (n, 3) on the smooth loft of one muscle's CVs X (5, 8, 3).

    Returns w (n,) in [0, 4], v (n,) in [0, 8) and the distance (n,) |p - X(w, v)|, metres.
    The nearest sample of a 33 x 64 grid starts Newton's method on f = |X(w, v) - p|^2 / 2 (Hessian
    J^T J - r . X'', r = p - X; the Gauss-Newton matrix J^T J where that is not positive definite,
    e.g. for points inside the muscle): plain Gauss-Newton converges only by the factor
    distance / curvature radius and diverges beyond it, and skin can sit farther from a thin muscle
    than its radius. Where w is on a bound and the step pushes outward, w is held and v alone is
    solved. Each step is tried at scales 1, 1/2, .. 1/16 and the first that lowers f is taken; a point
    stops when none does (its minimum, to rounding) or its step falls below 1e-10.
    """
    p = np.asarray(p, np.float64)
    X = np.asarray(X, np.float64)
    _, idx = cKDTree(_SEED_WEIGHTS @ X.reshape(-1, 3)).query(p)
    w, v = _SEED_W[idx].copy(), _SEED_V[idx].copy()
    top = float(loft.SECTIONS - 1)
    active = np.arange(len(p))
    for _ in range(steps):
        if active.size == 0:
            break
        wa, va, pa = w[active], v[active], p[active]
        x, xw, xv, xww, xwv, xvv = _evaluate(X, wa, va, second=True)
        r = pa - x
        d2 = (r * r).sum(1)
        a, b, c = (xw * xw).sum(1), (xw * xv).sum(1), (xv * xv).sum(1)
        ha, hb, hc = a - (r * xww).sum(1), b - (r * xwv).sum(1), c - (r * xvv).sum(1)
        newton = (ha > 0.0) & (ha * hc - hb * hb > 1e-12 * (a * c + 1e-300))
        ha, hb, hc = np.where(newton, ha, a), np.where(newton, hb, b), np.where(newton, hc, c)
        damp = 1e-9 * (a + c) + 1e-30
        ha, hc = ha + damp, hc + damp
        gw, gv = (xw * r).sum(1), (xv * r).sum(1)
        det = ha * hc - hb * hb
        dw = (hc * gw - hb * gv) / det
        dv = (ha * gv - hb * gw) / det
        pinned = ((wa <= 0.0) & (dw < 0.0)) | ((wa >= top) & (dw > 0.0))
        dw = np.where(pinned, 0.0, np.clip(dw, -0.5, 0.5))
        dv = np.clip(np.where(pinned, gv / hc, dv), -1.0, 1.0)
        size = np.maximum(np.abs(dw), np.abs(dv))
        pending = np.arange(len(active))
        keep = np.zeros(len(active), bool)
        for s in _STEP_SCALES:
            q = pending
            wc, vc = np.clip(wa[q] + s * dw[q], 0.0, top), np.mod(va[q] + s * dv[q], loft.RING)
            better = ((pa[q] - _evaluate(X, wc, vc)[0]) ** 2).sum(1) < d2[q]
            take = q[better]
            w[active[take]], v[active[take]] = wc[better], vc[better]
            keep[take] = s * size[take] > 1e-10
            pending = q[~better]
            if pending.size == 0:
                break
        active = active[keep]
    dist = np.linalg.norm(p - _evaluate(X, w, v)[0], axis=1)
    return w, v, dist


_SEED_W, _SEED_V = (a.ravel() for a in np.meshgrid(np.linspace(0.0, loft.SECTIONS - 1, 33),
                                                     np.arange(8 * loft.RING) / 8.0, indexing="ij"))
_SEED_WEIGHTS = loft.surface_weights(_SEED_W, _SEED_V).reshape(len(_SEED_W), CVS_PER_MUSCLE)
for _a in (_SEED_W, _SEED_V, _SEED_WEIGHTS):
    _a.setflags(write=False)


# ---------------------------------------------------------------------------------------------
# input checks


def _name(m: int, names) -> str:
    return f"muscle {names[m]!r} ({m})" if names is not None else f"muscle {m}"


def check_cvs(cvs, num_muscles: int, field: str, names=None) -> np.ndarray:
    """Flat CVs as (40 M, 3) float64; InputError naming `field` for a wrong shape and the first
    muscles whose CVs hold NaN or inf."""
    a = np.asarray(cvs)
    n = CVS_PER_MUSCLE * num_muscles
    if a.shape != (n, 3) or not np.issubdtype(a.dtype, np.number):
        raise InputError(f"expected ({n}, 3) float CVs (40 per muscle, {num_muscles} muscles), got "
                         f"shape {a.shape} dtype {a.dtype}", field=field)
    a = a.astype(np.float64)
    bad = ~np.isfinite(a).reshape(num_muscles, 3 * CVS_PER_MUSCLE).all(axis=1)
    if bad.any():
        which = np.nonzero(bad)[0]
        listed = ", ".join(_name(int(m), names) for m in which[:3])
        raise InputError(f"NaN or inf in the CVs of {listed}" + (f" and {which.size - 3} more"
                                                                  if which.size > 3 else ""), field=field)
    return a


def check_pairs(pair_offsets, pair_muscle, num_vertices: int | None, num_muscles: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Validated CSR pairs: pair_offsets (V + 1,) int64 from 0, non-decreasing, ending at P;
    pair_muscle (P,) int64 in [0, num_muscles). num_vertices None: V taken from pair_offsets."""
    off = np.asarray(pair_offsets)
    if off.ndim != 1 or len(off) < 1 or not np.issubdtype(off.dtype, np.integer):
        raise InputError(f"expected a (V + 1,) integer array, got shape {off.shape} dtype {off.dtype}",
                         field="pair_offsets")
    if num_vertices is not None and len(off) != num_vertices + 1:
        raise InputError(f"expected {num_vertices + 1} entries (V + 1, V = {num_vertices}), got {len(off)}",
                         field="pair_offsets")
    if off[0] != 0 or np.any(np.diff(off) < 0):
        raise InputError("must start at 0 and never decrease", field="pair_offsets")
    mus = np.asarray(pair_muscle)
    P = int(off[-1])
    if mus.shape != (P,) or not np.issubdtype(mus.dtype, np.integer):
        raise InputError(f"expected a ({P},) integer array (P = pair_offsets[-1]), got shape {mus.shape} "
                         f"dtype {mus.dtype}", field="pair_muscle")
    if P and (mus.min() < 0 or mus.max() >= num_muscles):
        bad = int(mus.min() if mus.min() < 0 else mus.max())
        raise InputError(f"muscle index {bad} is outside 0..{num_muscles - 1}", field="pair_muscle")
    return off.astype(np.int64), mus.astype(np.int64)


def check_weights(pair_weight, num_pairs: int) -> np.ndarray:
    """Painted pair weights as (P,) float64 in [0, 1]; InputError otherwise (NaN included)."""
    a = np.asarray(pair_weight)
    if a.shape != (num_pairs,) or not np.issubdtype(a.dtype, np.number):
        raise InputError(f"expected ({num_pairs},) float weights, got shape {a.shape} dtype {a.dtype}",
                         field="pair_weight")
    a = a.astype(np.float64)
    bad = ~((a >= 0.0) & (a <= 1.0))     # NaN fails both comparisons
    if bad.any():
        first = np.nonzero(bad)[0][:5]
        raise InputError(f"{int(bad.sum())} weights are outside [0, 1] or NaN (pairs {first.tolist()}, "
                         f"values {a[first].tolist()})", field="pair_weight")
    return a


# ---------------------------------------------------------------------------------------------
# bind


@dataclass(frozen=True, eq=False)
class InfluenceBinding:
    """Per (vertex, muscle) pair attachment on the muscle's rest loft; arrays read-only, P pairs.

    w : (P,) float64 in [0, 4], v : (P,) float64 in [0, 8): loft parameters of the foot point.
    offset : (P, 3) float64 metres, the vertex's offset from X(w, v) along (e1, e2, n).
    distance : (P,) float64 metres, |vertex - X(w, v)| at bind.
    section, section_dw : (P, 5) float64, the section weights at w and their d/dw.
    ring_first : (P,) int32, index (mod 8) of the first of the 4 ring CVs the cubic basis touches at v.
    ring, ring_dv : (P, 4) float64, weights of ring CVs ring_first + r (mod 8), r = 0..3, and d/dv.
    muscle_eps : (M,) float64 metres, per muscle FRAME_EPS x its rest size: below it a frame axis
        counts as collapsed (see :func:`loft_frame`); fixed at bind so the rule is the same every frame.

    The kernel evaluates X, dX/dw, dX/dv of a pair from these (w and v never change after bind), so
    it needs no spline code and touches 20 of the muscle's 40 CVs per evaluation.
    """

    w: np.ndarray
    v: np.ndarray
    offset: np.ndarray
    distance: np.ndarray
    section: np.ndarray
    section_dw: np.ndarray
    ring_first: np.ndarray
    ring: np.ndarray
    ring_dv: np.ndarray
    muscle_eps: np.ndarray

    @property
    def num_pairs(self) -> int:
        return len(self.w)


def _pair_basis(w: np.ndarray, v: np.ndarray):
    """The kernel's basis tables of parameters (P,): section (P, 5), section_dw (P, 5), ring_first
    (P,), ring (P, 4), ring_dv (P, 4), taken from rig.loft's own bases so the two cannot drift."""
    v = np.mod(v, loft.RING)
    first = (np.floor(v).astype(np.int64) - 1) % loft.RING
    cols = (first[:, None] + np.arange(4)) % loft.RING
    ring = np.take_along_axis(loft.ring_weights(v), cols, axis=1)
    ring_dv = np.take_along_axis(loft.ring_weights(v, 1), cols, axis=1)
    return loft.section_weights(w), loft.section_weights(w, 1), first, ring, ring_dv


def bind_influence(rest_vertices, pair_offsets, pair_muscle, rest_cvs, *, names=None) -> InfluenceBinding:
    """Attach every (vertex, muscle) pair to its foot point on the muscle's rest loft.

    Parameters
    ----------
    rest_vertices : (V, 3) float, metres, the skin at bind.
    pair_offsets : (V + 1,) int, CSR offsets of each vertex's pairs.
    pair_muscle : (P,) int, muscle of each pair, in [0, M).
    rest_cvs : (N, 3) float, metres, N = 40 M, the muscles' CVs at bind.
    names : optional (M,) muscle names for messages.

    Returns
    -------
    InfluenceBinding. One projection per muscle over all its pairs (a Python loop over muscles, at
    bind only). Warns (JiggleWarning) when pairs attach where a loft frame is degenerate (collapsed
    CVs): those pairs still deform without NaN, but lose the offset components along the missing axes.
    Raises InputError naming the parameter for wrong shapes, non-finite values, bad CSR or indices.
    """
    rest = np.asarray(rest_vertices)
    if rest.ndim != 2 or rest.shape[1] != 3 or not np.issubdtype(rest.dtype, np.number):
        raise InputError(f"expected a (V, 3) float array, got shape {rest.shape} dtype {rest.dtype}",
                         field="rest_vertices")
    rest = rest.astype(np.float64)
    if not np.isfinite(rest).all():
        raise InputError("rest positions contain NaN or inf", field="rest_vertices")
    cvs = np.asarray(rest_cvs)
    if cvs.ndim != 2 or cvs.shape[1] != 3 or len(cvs) % CVS_PER_MUSCLE:
        raise InputError(f"expected (40 M, 3) CVs, got shape {cvs.shape}", field="rest_cvs")
    M = len(cvs) // CVS_PER_MUSCLE
    cvs = check_cvs(cvs, M, "rest_cvs", names)
    off, mus = check_pairs(pair_offsets, pair_muscle, len(rest), M)
    P = len(mus)
    vertex = np.repeat(np.arange(len(rest)), np.diff(off))
    w, v, offset, distance = np.zeros(P), np.zeros(P), np.zeros((P, 3)), np.zeros(P)
    degenerate = []
    X_all = cvs.reshape(M, loft.SECTIONS, loft.RING, 3)
    eps = muscle_eps(cvs)
    for m in np.unique(mus):     # bind time: one vectorised projection per muscle
        sel = np.nonzero(mus == m)[0]
        p = rest[vertex[sel]]
        w[sel], v[sel], distance[sel] = closest_points(p, X_all[m])
        x, xw, xv = _evaluate(X_all[m], w[sel], v[sel])
        frame = loft_frame(xw, xv, eps[m])
        offset[sel] = np.einsum("nij,nj->ni", frame, p - x)
        lost = np.count_nonzero(np.abs(np.linalg.det(frame) - 1.0) > 1e-6)
        if lost:
            degenerate.append(f"{_name(int(m), names)}: {lost}")
    if degenerate:
        warnings.warn("pairs attached where the loft frame is degenerate (collapsed CVs), their offsets "
                      "lose the missing axes: " + "; ".join(degenerate), JiggleWarning, stacklevel=2)
    section, section_dw, first, ring, ring_dv = _pair_basis(w, v)
    return InfluenceBinding(
        w=frozen_array(w), v=frozen_array(v), offset=frozen_array(offset),
        distance=frozen_array(distance),
        section=frozen_array(section), section_dw=frozen_array(section_dw),
        ring_first=frozen_array(first, np.int32), ring=frozen_array(ring), ring_dv=frozen_array(ring_dv),
        muscle_eps=frozen_array(eps))


# ---------------------------------------------------------------------------------------------
# NumPy reference


def _attach(cvs: np.ndarray, muscle: np.ndarray, w: np.ndarray, v: np.ndarray, offset: np.ndarray,
            eps: np.ndarray):
    """attach(cvs) (n, 3) of pairs with muscles (n,), parameters (n,), offsets (n, 3), frame eps (n,)."""
    X = cvs.reshape(-1, CVS_PER_MUSCLE, 3)[muscle]                                  # (n, 40, 3)
    weights = [loft.surface_weights(w, v, dw, dv).reshape(len(w), CVS_PER_MUSCLE)
               for dw, dv in ((0, 0), (1, 0), (0, 1))]
    x, xw, xv = (np.einsum("nc,ncx->nx", W, X) for W in weights)
    return x + np.einsum("nij,ni->nj", loft_frame(xw, xv, eps), offset)


def influence_numpy(points, binding: InfluenceBinding, pair_offsets, pair_muscle, pair_weight,
                    cvs_cur, cvs_ref) -> np.ndarray:
    """points + sum over each vertex's pairs of weight * (attach(cvs_cur) - attach(cvs_ref)).

    Parameters
    ----------
    points : (V, 3) float, metres, the positions to displace (the LBS / DQS skin).
    binding : from :func:`bind_influence` with the same pairs.
    pair_offsets : (V + 1,) int; pair_muscle : (P,) int; pair_weight : (P,) float in [0, 1].
    cvs_cur, cvs_ref : (N, 3) float, metres, current CVs and the rest CVs carried by the bones.

    Returns
    -------
    (V, 3) float64, metres. Vectorised over blocks of pairs; no input checks.
    """
    points = np.asarray(points, np.float64)
    off = np.asarray(pair_offsets, np.int64)
    mus = np.asarray(pair_muscle, np.int64)
    wgt = np.asarray(pair_weight, np.float64)
    cur, ref = np.asarray(cvs_cur, np.float64), np.asarray(cvs_ref, np.float64)
    vertex = np.repeat(np.arange(len(off) - 1), np.diff(off))
    out = points.copy()
    for s in range(0, len(mus), _CHUNK):
        b = slice(s, s + _CHUNK)
        args = (mus[b], binding.w[b], binding.v[b], binding.offset[b], binding.muscle_eps[mus[b]])
        d = wgt[b, None] * (_attach(cur, *args) - _attach(ref, *args))
        for k in range(3):
            out[:, k] += np.bincount(vertex[b], d[:, k], minlength=len(points))
    return out


# ---------------------------------------------------------------------------------------------
# Warp launcher


class InfluenceDeformer:
    """The influence-object deformer of one skin on a Warp device.

    Parameters
    ----------
    binding : InfluenceBinding of the pairs below (see :func:`bind_influence`).
    pair_offsets : (V + 1,) int, pair_muscle : (P,) int, pair_weight : (P,) float in [0, 1].
    num_muscles : M; the CV arrays each frame are (40 M, 3).
    device : Warp device of the model, the buffers and every launch.
    names : optional (M,) muscle names for error messages.

    The pairs and their basis are uploaded once; each call uploads the two CV arrays and reuses the
    output buffer.
    """

    def __init__(self, binding: InfluenceBinding, pair_offsets, pair_muscle, pair_weight, num_muscles: int,
                 device="cpu", names=None):
        if int(num_muscles) != num_muscles or num_muscles < 0:
            raise InputError(f"expected a count >= 0, got {num_muscles!r}", field="num_muscles")
        self.num_muscles = int(num_muscles)
        if names is not None and len(names) != self.num_muscles:
            raise InputError(f"expected {self.num_muscles} names, got {len(names)}", field="names")
        self.names = None if names is None else tuple(names)
        off, mus = check_pairs(pair_offsets, pair_muscle, None, self.num_muscles)
        P = len(mus)
        if not isinstance(binding, InfluenceBinding) or binding.num_pairs != P:
            got = binding.num_pairs if isinstance(binding, InfluenceBinding) else type(binding).__name__
            raise InputError(f"expected an InfluenceBinding of {P} pairs, got {got}", field="binding")
        if len(binding.muscle_eps) != self.num_muscles:
            raise InputError(f"the binding was made for {len(binding.muscle_eps)} muscles, not {self.num_muscles}",
                             field="num_muscles")
        wgt = check_weights(pair_weight, P)
        self.device = wp.get_device(device)
        self.num_vertices = len(off) - 1
        self.num_pairs = P
        d = self.device
        f32 = lambda a: wp.array(np.ascontiguousarray(a, np.float32), dtype=wp.float32, device=d)  # noqa: E731
        i32 = lambda a: wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=d)  # noqa: E731
        self._model = [i32(off), i32(mus), f32(wgt), f32(binding.section), f32(binding.section_dw),
                       i32(binding.ring_first), f32(binding.ring), f32(binding.ring_dv),
                       wp.array(binding.offset.astype(np.float32), dtype=wp.vec3, device=d),
                       f32(binding.muscle_eps)]
        N = CVS_PER_MUSCLE * self.num_muscles
        self._cur = wp.empty(N, dtype=wp.vec3, device=d)
        self._ref = wp.empty(N, dtype=wp.vec3, device=d)
        self._points = wp.empty(self.num_vertices, dtype=wp.vec3, device=d)
        self._positions = wp.empty(self.num_vertices, dtype=wp.vec3, device=d)

    def launch(self, points: wp.array, cvs_cur, cvs_ref) -> wp.array:
        """Displace device positions; returns the wrapper's (V,) wp.vec3 buffer, valid until the next call.

        points : (V,) wp.vec3 on this device (e.g. Skinner.launch's result), metres.
        cvs_cur, cvs_ref : (40 M, 3) float, metres (current CVs; rest CVs carried by the bones).
        """
        if (not isinstance(points, wp.array) or points.dtype != wp.vec3 or points.shape != (self.num_vertices,)
                or points.device != self.device):
            desc = (f"{points.dtype.__name__} {points.shape} on {points.device}" if isinstance(points, wp.array)
                    else type(points).__name__)
            raise InputError(f"expected a ({self.num_vertices},) wp.vec3 array on {self.device}, got {desc}",
                             field="points")
        cur = check_cvs(cvs_cur, self.num_muscles, "cvs_cur", self.names)
        ref = check_cvs(cvs_ref, self.num_muscles, "cvs_ref", self.names)
        if self.num_vertices == 0:
            return self._positions
        self._cur.assign(cur.astype(np.float32))
        self._ref.assign(ref.astype(np.float32))
        wp.launch(kernels.influence_displace, dim=self.num_vertices, device=self.device,
                  inputs=[*self._model, points, self._cur, self._ref], outputs=[self._positions])
        return self._positions

    def deform(self, points, cvs_cur, cvs_ref) -> np.ndarray:
        """Displaced positions (V, 3) float32, metres, a new array, from points (V, 3) float."""
        p = np.asarray(points)
        if p.shape != (self.num_vertices, 3) or not np.issubdtype(p.dtype, np.number):
            raise InputError(f"expected ({self.num_vertices}, 3) float points, got shape {p.shape} dtype {p.dtype}",
                             field="points")
        self._points.assign(p.astype(np.float32))
        out = self.launch(self._points, cvs_cur, cvs_ref).numpy()
        # on the CPU .numpy() is a view of the scratch buffer the next call overwrites
        return out.copy() if self.device.is_cpu else out
