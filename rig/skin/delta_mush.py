"""Delta Mush (Mancewicz, Derksen, Rijpkema and Wilson 2014; Maya's deltaMush): the clean-up pass on
top of any skinning.

A skinned mesh (LBS, shells, influence objects, RBF) creases and crumples where weights crowd or
deformers end. Delta Mush smooths the deformed mesh, which removes the creases and also the detail,
then puts the detail back: each vertex's offset from the smoothed REST mesh, stored once in a frame
of the smoothed rest surface (its normal, the edge to a neighbour, their cross product), is added
again in the same frame of the smoothed deformed mesh:

    bind:   S0 = smooth^N(rest),   delta_v = F_v(S0)^T (rest_v - S0_v)
    frame:  S  = smooth^N(p),      p'_v = p_v + w_v (S_v + F_v(S) delta_v - p_v)

smooth: N Laplacian steps p <- p + step (mean of the edge neighbours - p). At the rest pose p' = rest
(to float32 rounding); under a rigid motion of the whole mesh, p' is that rigid motion of rest; a
bulge wider than the smoothing's reach (about sqrt(N) edges) survives, a crease a few edges wide does
not. w: a per-vertex envelope in [0, 1] (1: full mush; 0: the vertex keeps its skinned position).

Cost: N + 1 launches per batch of frames, each a gather over a vertex's neighbours (or faces).
Kernels: rig/skin/delta_mush_kernels.py.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_neighbours

DEFAULT_ITERATIONS = 6
"""Smoothing steps of the skin's clean-up pass by default (the bake, deform, play): enough to remove
the creases of automatic weights and shell boundaries a few edges wide, few enough to keep a
muscle's bulge (tests/skin/test_delta_mush.py and benchmarks/bench_quality.py measure both)."""
STEP = 0.5
"""Laplacian step: each iteration moves a vertex half way to its neighbours' mean."""


class DeltaMush:
    """The bind of one mesh (see the module).

    rest : (V, 3) metres, the rest mesh (the skin at bind). faces : (F, 3).
    iterations : N >= 1 smoothing steps. step : in (0, 1]. weights : (V,) envelope in [0, 1] or None
    for 1. device : Warp device.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, iterations: int = DEFAULT_ITERATIONS,
                 step: float = STEP, weights: np.ndarray | None = None, device: str = "cpu"):
        rest = np.asarray(rest, dtype=np.float32)
        faces = np.asarray(faces)
        V = len(rest)
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise InputError(f"expected (V, 3) rest vertices, got {rest.shape}", field="rest")
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise InputError(f"expected a whole number >= 1, got {iterations!r}", field="mush")
        if not (np.isfinite(step) and 0.0 < step <= 1.0):
            raise InputError(f"expected a number in (0, 1], got {step}", field="step")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.min() < 0 or faces.max() >= V:
            raise InputError(f"expected (F >= 1, 3) faces indexing {V} vertices", field="faces")
        w = np.ones(V, np.float32) if weights is None else np.asarray(weights, np.float32)
        if w.shape != (V,) or not np.all((w >= 0.0) & (w <= 1.0)):
            raise InputError(f"expected ({V},) weights in [0, 1]", field="weights")
        self.iterations, self.step, self.num_vertices = int(iterations), float(step), V
        self.device = wp.get_device(device)
        graph = mesh_neighbours(faces, V)
        graph.sort_indices()                       # a vertex's tangent goes to its lowest-numbered neighbour
        offsets, b = graph.indptr.astype(np.int32), graph.indices.astype(np.int32)
        tangent_to = np.where(np.diff(offsets) > 0, b[np.minimum(offsets[:-1], max(len(b) - 1, 0))], -1)
        tangent_to = tangent_to.astype(np.int32)
        fv = np.asarray(faces, np.int64).ravel()
        forder = np.argsort(fv, kind="stable")
        face_offsets = np.zeros(V + 1, np.int32)
        np.add.at(face_offsets, fv + 1, 1)
        face_offsets = np.cumsum(face_offsets).astype(np.int32)
        d = self.device
        self._offsets = wp.array(offsets, dtype=wp.int32, device=d)
        self._neighbours = wp.array(b.astype(np.int32), dtype=wp.int32, device=d)
        self._tangent_to = wp.array(tangent_to, dtype=wp.int32, device=d)
        self._faces = wp.array(np.asarray(faces, np.int32), dtype=wp.vec3i, device=d)
        self._face_offsets = wp.array(face_offsets, dtype=wp.int32, device=d)
        self._face_of = wp.array((forder // 3).astype(np.int32), dtype=wp.int32, device=d)
        self._weight = wp.array(w, dtype=wp.float32, device=d)
        self.launches = 0
        """Warp launches made so far (`launch`: iterations + 1 per call)."""

        from jiggle.rig.skin import delta_mush_kernels as k
        pts = wp.array(rest[None], dtype=wp.vec3, device=d)
        smoothed = self._smooth(pts)
        self._delta = wp.empty(V, dtype=wp.vec3, device=d)
        self._ok = wp.empty(V, dtype=wp.int32, device=d)
        wp.launch(k.encode, dim=(1, V), device=d, inputs=[pts, smoothed, *self._topology()],
                  outputs=[self._delta, self._ok])

    def _topology(self) -> list:
        return [self._faces, self._face_offsets, self._face_of, self._tangent_to]

    def _smooth(self, pts: wp.array) -> wp.array:
        from jiggle.rig.skin import delta_mush_kernels as k
        a = wp.clone(pts)
        b = wp.empty_like(pts)
        for _ in range(self.iterations):
            wp.launch(k.smooth_step, dim=pts.shape, device=self.device,
                      inputs=[a, self._offsets, self._neighbours, self.step], outputs=[b])
            a, b = b, a
        return a

    @property
    def deltas(self) -> np.ndarray:
        """(V, 3) float32 metres: each vertex's rest offset from the smoothed rest, in its frame."""
        return self._delta.numpy().copy()

    def launch(self, points: wp.array) -> wp.array:
        """Mushed points (T, V) vec3 on the device for skinned points (T, V) vec3 on the device."""
        from jiggle.rig.skin import delta_mush_kernels as k
        if points.ndim != 2 or points.shape[1] != self.num_vertices:
            raise InputError(f"expected (T, {self.num_vertices}) points, got {points.shape}", field="points")
        out = wp.empty_like(points)
        if points.shape[0] == 0:
            return out
        smoothed = self._smooth(points)
        self.launches += self.iterations + 1
        wp.launch(k.decode, dim=points.shape, device=self.device,
                  inputs=[points, smoothed, *self._topology(), self._delta, self._ok, self._weight], outputs=[out])
        return out

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Mushed copies of skinned points (V, 3) or (T, V, 3) metres, float32, the same shape."""
        p = np.asarray(points, dtype=np.float32)
        if p.shape[-2:] != (self.num_vertices, 3) or p.ndim not in (2, 3):
            raise InputError(f"expected (V, 3) or (T, V, 3) with V = {self.num_vertices}, got {p.shape}",
                             field="points")
        batch = wp.array(np.ascontiguousarray(p.reshape(-1, self.num_vertices, 3)), dtype=wp.vec3, device=self.device)
        return self.launch(batch).numpy().reshape(p.shape).copy()
