"""Influence-object skinning: skin vertices attached to points of the muscles' lofted surfaces.

Hoehne's thesis (section 6.6) skins the character with Maya's smooth skinning and adds the muscles as
NURBS influence objects: "every point gets attached to one corresponding point on the surface of the
NURBS object", weighted by painted per-vertex muscle weights. Ours is the RELATIVE form of that, so the
artist's skin is reproduced exactly at bind and the deformer adds only what the muscles do beyond
their bones:

Bind (:func:`rig.muscle.loft_attach.bind_influence`)
    For each (vertex, muscle) pair, the foot point of the vertex on the muscle's smooth loft
    ``X(w, v)`` (rig/muscle/loft.py; w in [0, 4] across the sections, clamped, so a vertex beyond an end
    attaches to the end ring; v in [0, 8) around, periodic) built from its 40 rest CVs: the nearest
    sample of a 33 x 64 grid, then Newton's method on ``|X(w, v) - p|^2`` with a step search and w
    held at a bound it presses against (:func:`rig.muscle.loft_attach.closest_points`). The vertex's offset
    ``o = p - X(w, v)`` is stored in the loft frame at (w, v):
    ``e1 = unit(dX/dw)``, ``n = unit(dX/dv x dX/dw)`` (outward for the loft's orientation: sections
    from origin to insertion, v turning from a section's up vector U toward its side T x U, the
    orientation of rig.muscle.loft.FACES), ``e2 = n x e1``; offset = (o . e1, o . e2, o . n). Where a frame
    axis cannot be normalised (collapsed CVs: its vector under FRAME_EPS x the muscle's rest size) it
    is 0, at bind (with a JiggleWarning) and per frame alike: no NaN for finite input.
Per frame
    ``attach(cvs) = X(w, v) + offset[0] e1 + offset[1] e2 + offset[2] n`` evaluated from a CV array
    (the frame is right-handed and orthonormal, so attach follows any rigid motion of the CVs
    exactly). Vertex i moves by ``sum over its pairs of weight * (attach(cvs_cur) - attach(cvs_ref))``
    where cvs_ref are the rest CVs carried rigidly by each muscle's bone
    (rig.skin.shell.frames.MuscleFrames.carried_rest_cvs), each pair's term held below the muscle's
    `reach` by the shells' smooth drop-off limit (rig.skin.shell.shells.limit; MuscleSkin gives d x the
    muscle's mean rest radius: on the generated body this took the folds influence objects add over LBS
    on the dance clip from 1.48x to 0.99x). At rest the displacement is exactly 0; a muscle
    moved rigidly by T relative to its bone carries a weight-1 vertex by exactly T. The pairs' terms
    are summed (not applied in series): each depends only on the CVs, not on the vertex's position.

Pairs are CSR, sorted by vertex: ``pair_offsets`` (V + 1,) int, ``pair_muscle`` (P,) int,
``pair_weight`` (P,) float in [0, 1] (painted). Flat CVs (N, 3), N = 40 M, muscle m owning rows
40 m .. 40 m + 39 section-major, as rig.muscle.model.MuscleRig.rest_cvs.

- :func:`rig.muscle.loft_attach.bind_influence` -> :class:`InfluenceBinding` (frozen, per pair
  parameters and the kernel's precomputed basis; the attachment is the muscle stage's, shared with
  the anatomy's feature points).
- :class:`InfluenceDeformer`: the Warp launcher (kernel in :mod:`rig.skin.influence_kernels`). (w, v) are
  fixed per pair, so the spline bases are evaluated once at bind: per pair the 5 section weights and
  their d/dw, and the 4 non-zero ring weights and their d/dv with the index of the first ring CV;
  the kernel then needs no spline code and reads 20 of a muscle's 40 CVs per evaluation.
- :func:`influence_numpy`: the vectorised float64 reference (no input checks), evaluating the loft
  from (w, v) with :func:`rig.muscle.loft.surface_weights` rather than the precomputed basis.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.loft_attach import CVS_PER_MUSCLE, InfluenceBinding, check_cvs, check_pairs, check_weights, loft_frame
from jiggle.rig.skin import influence_kernels as kernels
from jiggle.rig.skin.scratch import Scratch
from jiggle.rig.skin.shell.shells import limit

_CHUNK = 32768                  # pairs per block in the NumPy reference (bounds its temporaries)


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
                    cvs_cur, cvs_ref, reach=None) -> np.ndarray:
    """points + sum over each vertex's pairs of weight * limit(attach(cvs_cur) - attach(cvs_ref), reach).

    Parameters
    ----------
    points : (V, 3) float, metres, the positions to displace (the LBS / DQS skin).
    binding : from :func:`bind_influence` with the same pairs.
    pair_offsets : (V + 1,) int; pair_muscle : (P,) int; pair_weight : (P,) float in [0, 1].
    cvs_cur, cvs_ref : (N, 3) float, metres, current CVs and the rest CVs carried by the bones.
    reach : (M,) metres per muscle, the drop-off limit's reach (rig.skin.shell.shells.limit); None: no limit.

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
        d = _attach(cur, *args) - _attach(ref, *args)
        if reach is not None:
            d = limit(d, np.asarray(reach, np.float64)[mus[b]])
        d = wgt[b, None] * d
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
    reach : optional (M,) metres > 0, each muscle's drop-off limit (a pair's displacement saturates
        toward it, as the shells'; rig.skin.shell.shells.limit); None: no limit.

    The pairs and their basis are uploaded once; each call uploads the two CV arrays and reuses the
    output buffer.
    """

    def __init__(self, binding: InfluenceBinding, pair_offsets, pair_muscle, pair_weight, num_muscles: int,
                 device="cpu", names=None, reach=None):
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
                       f32(binding.muscle_eps), f32(self._reach(reach))]
        N = CVS_PER_MUSCLE * self.num_muscles
        self._cur = wp.empty(N, dtype=wp.vec3, device=d)
        self._ref = wp.empty(N, dtype=wp.vec3, device=d)
        self._points = wp.empty(self.num_vertices, dtype=wp.vec3, device=d)
        self._positions = wp.empty(self.num_vertices, dtype=wp.vec3, device=d)
        self.paired = np.nonzero(np.diff(off) > 0)[0]
        """(P,) the vertices owning pairs, ascending (the batched launch runs only these)."""
        self._paired = i32(self.paired)
        self._scratch = Scratch(d)
        self.thread_per_frame = not d.is_cpu   # as the shells' batched launch
        self.launches = 0
        """Warp launches made so far."""

    def _reach(self, reach) -> np.ndarray:
        if reach is None:
            return np.full(self.num_muscles, np.finfo(np.float32).max, np.float32)
        r = np.asarray(reach, np.float64).reshape(-1)
        if r.shape != (self.num_muscles,) or not np.all(r > 0):
            raise InputError(f"expected {self.num_muscles} reaches > 0 m, got {r.tolist()}", field="reach")
        return np.minimum(r, np.finfo(np.float32).max).astype(np.float32)

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
        self.launches += 1
        return self._positions

    def launch_batch(self, points: wp.array, cvs_cur, cvs_ref, displace: bool = False) -> wp.array:
        """T frames and S sets in one upload and one launch over the vertices owning pairs.

        points : (T, V) wp.vec3 on this device, metres, shared by the sets.
        cvs_cur : (S, T, 40 M, 3) float, metres, each set's CVs per frame (finite).
        cvs_ref : (T, 40 M, 3) float, metres, the rest CVs carried by the bones per frame.
        displace : False: returns (S, T, V) wp.vec3, [s, t] = :meth:`launch` of points[t] with set s's
            frame t; True: (S, P, T), the `paired` vertices' displacements from points (float32).
        The result is the wrapper's buffer, valid until the next batched call.
        """
        cur = np.asarray(cvs_cur, np.float64)
        ref = np.asarray(cvs_ref, np.float64)
        N = CVS_PER_MUSCLE * self.num_muscles
        if ref.ndim != 3 or ref.shape[1:] != (N, 3):
            raise InputError(f"expected (T, {N}, 3) CVs, got {ref.shape}", field="cvs_ref")
        T, V, P = ref.shape[0], self.num_vertices, len(self.paired)
        if cur.ndim != 4 or cur.shape[1:] != (T, N, 3):
            raise InputError(f"expected (S, {T}, {N}, 3) CVs, got {cur.shape}", field="cvs_cur")
        if (not isinstance(points, wp.array) or points.dtype != wp.vec3 or points.shape != (T, V)
                or points.device != self.device):
            raise InputError(f"expected a ({T}, {V}) wp.vec3 array on {self.device}", field="points")
        for name, a in (("cvs_cur", cur), ("cvs_ref", ref)):
            if not np.isfinite(a).all():
                raise InputError("NaN or inf in the CVs", field=name)
        S = cur.shape[0]
        out = (self._scratch("moved", (S, P, T), wp.vec3) if displace
               else self._scratch("positions", (S, T, V), wp.vec3))
        if S * T * V == 0:
            return out
        if not displace:
            for s in range(S):
                wp.copy(out, points, dest_offset=s * T * V, count=T * V)
        if P == 0:
            return out
        c = self._scratch("cur", (S * T * N,), wp.vec3)
        r = self._scratch("ref", (T * N,), wp.vec3)
        c.assign(cur.reshape(-1, 3).astype(np.float32))
        r.assign(ref.reshape(-1, 3).astype(np.float32))
        stride = T if self.thread_per_frame else 1
        wp.launch(kernels.influence_batch, dim=(stride, P), device=self.device,
                  inputs=[*self._model, self._paired, stride, int(displace), points, c, r], outputs=[out])
        self.launches += 1
        return out

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
