"""Points attached to a muscle's lofted surface: the loft at (w, v), its frame, foot points, binding.

A skin vertex (or a feature point) is attached to a muscle by its foot point ``X(w, v)`` on the
muscle's smooth loft (rig/muscle/loft.py; w in [0, 4] across the sections, clamped; v in [0, 8)
around, periodic), found by :func:`closest_points`, and its offset from there in the loft frame
(:func:`loft_frame`: ``e1 = unit(dX/dw)``, ``n = unit(dX/dv x dX/dw)`` outward, ``e2 = n x e1``).
:func:`bind_influence` does this for CSR (vertex, muscle) pairs and precomputes the spline bases the
influence kernel needs (:class:`InfluenceBinding`). Used by the influence-object deformer
(rig/skin/influence.py) and the anatomy's feature points (rig/anatomy/features.py).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle import loft

CVS_PER_MUSCLE = loft.SECTIONS * loft.RING      # 40
FRAME_EPS = 1e-3                # a frame axis shorter than this x the muscle's size counts as collapsed
PROJECT_STEPS = 40              # Newton iterations at most (most points stop after ~5)
_STEP_SCALES = (1.0, 0.5, 0.25, 0.125, 0.0625)  # step search of each Newton iteration


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
    """(n, 8) second derivative d2/dv2 of rig.muscle.loft.ring_weights (the cubic's b'' = (1 - t, 3 t - 2,
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
    CVs); the kernel's rule (rig.skin.influence_kernels.frame_apply)."""
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
    (P,), ring (P, 4), ring_dv (P, 4), taken from rig.muscle.loft's own bases so the two cannot drift."""
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
