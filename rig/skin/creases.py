"""Creases: where the smooth skin squeezes the surface together, the jiggle is held together across it.

The muscles' displacement is spread over the REST surface (rig/skin/surface_smoothing.py), so the jiggle varies
over a rest length scale. Where the smooth skinning squeezes an edge to c of its rest length (the inside of a bent
hip or elbow, and above all a seam where a stylised rig's weights jump from one bone to the next, whose edges LBS
folds to a sixth of their length), the same difference of jiggle between the edge's ends is 1/c times steeper on
the posed skin: the jiggle tears the edge (gradient |d_a - d_b| / |s_a - s_b| > 1, rig/skin/quality.py) though
it tore nothing in rest space. Found on a CMU walk (02_03) of the generated Mixamo-named body and of CesiumMan,
both rebound bone by bone (every vertex to its strongest joint alone, tests/gear_builds.py abrupt): 2 and 1 torn
edges, gradient at most 1.29 and 1.24, at the seams of the hips and the spine, where LBS had squeezed 9-35 mm
edges to 1.5-3 mm.

So the skin stage couples the two ends of every squeezed edge, frame by frame (:class:`Creases`, called by
rig.skin.muscle_skin.skin_frames on every set's jiggle d = final - static): an edge squeezed below
1 / SQUEEZE of its rest length gets the weight w = rest / posed - SQUEEZE (at most 1 / GRADIENT_FLOOR - SQUEEZE,
where the gradient stops reading the length), and STEPS relaxation steps

    d_v <- d_v + 1/2 sum_e w_e (d_u - d_v) / (1 + sum_e w_e)

(a weighted Laplacian smoothing over the squeezed edges alone) shrink an edge's jiggle difference about as much
as the skinning shrank the edge, so its gradient stays what it was over the rest surface. Edges that are not
squeezed get no weight: where nothing is squeezed the skin is unchanged bit for bit, and where something is, only
the vertices of squeezed edges move. Fixed vertices (gear and hard shells, rig.character.gear) keep their
jiggle; a soft neighbour squeezed against one takes it. The tissue is not touched: its motion, its reach and
its amplitude elsewhere are what the simulation made them.
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.character.mesh_graph import mesh_edges

SQUEEZE = 1.5
"""An edge couples its ends' jiggle once the smooth skin squeezes it below 1 / SQUEEZE of its rest length."""
STEPS = 4
"""Relaxation steps over the squeezed edges per frame."""
WEIGHT_MAX = 10.0 - SQUEEZE
"""The largest coupling: at a tenth of the rest length (rig.skin.quality.GRADIENT_FLOOR) the gradient stops
reading the edge's length."""


class Creases:
    """The squeezed-edge coupling of one mesh (see the module).

    rest : (V, 3) metres, the rest skin. faces : (F, 3). fixed : (V,) bool, vertices whose jiggle is kept (gear),
    or None.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, fixed: np.ndarray | None = None):
        rest = np.asarray(rest, np.float64)
        edges, _ = mesh_edges(np.asarray(faces)) if len(faces) else (np.zeros((0, 2), np.int32), None)
        self.edges = np.asarray(edges, np.int64)
        """(E, 2) int64, every edge once."""
        self.rest_length = np.maximum(np.linalg.norm(rest[self.edges[:, 1]] - rest[self.edges[:, 0]], axis=1),
                                      1e-12) if len(self.edges) else np.zeros(0)
        """(E,) float64 metres."""
        # squared lengths below which an edge is squeezed, with a margin so float32 never misses one
        self._limit2 = ((self.rest_length / SQUEEZE) ** 2 * (1.0 + 1e-4)).astype(np.float32)
        self.fixed = None if fixed is None or not np.any(fixed) else np.asarray(fixed, bool)
        self.num_vertices = len(rest)

    def weights(self, static: np.ndarray, cols: np.ndarray | None = None) -> np.ndarray:
        """(T, E) float64: each edge's (or each of the edges `cols`') coupling in each frame of the static skin
        (T, V, 3), 0 where not squeezed."""
        edges = self.edges if cols is None else self.edges[cols]
        rest = self.rest_length if cols is None else self.rest_length[cols]
        length = np.linalg.norm(static[:, edges[:, 0]].astype(np.float64) - static[:, edges[:, 1]], axis=2)
        w = rest[None] / np.maximum(length, 1e-12) - SQUEEZE
        return np.clip(w, 0.0, WEIGHT_MAX)

    def hold(self, static: np.ndarray, sets) -> list:
        """Every skin of `sets` ((T, V, 3) float32 metres each, changed in place) with its jiggle against `static`
        (T, V, 3) held together across the squeezed edges (see the module); returns `sets`."""
        if not len(self.edges) or not len(sets) or not len(static):
            return sets
        a, b = self.edges[:, 0], self.edges[:, 1]
        e = static[:, a] - static[:, b]                                        # float32 (T, E, 3): the cheap pass
        squeezed = np.einsum("tei,tei->te", e, e) < self._limit2[None]
        cols = np.nonzero(squeezed.any(axis=0))[0]
        if not len(cols):
            return sets
        T = static.shape[0]
        w = self.weights(static, cols)
        verts, local = np.unique(self.edges[cols], return_inverse=True)
        ia, ib = local.reshape(-1, 2).T
        n = len(verts)
        we = w                                                                  # (T, Ec)
        frame = (np.arange(T) * n)[:, None]
        at_a, at_b = (frame + ia[None]).ravel(), (frame + ib[None]).ravel()
        total = (np.bincount(at_a, we.ravel(), T * n) + np.bincount(at_b, we.ravel(), T * n)).reshape(T, n)
        step = 0.5 / (1.0 + total)
        if self.fixed is not None:
            step = step * ~self.fixed[verts][None]
        base = static[:, verts].astype(np.float64)
        for sk in sets:
            old = sk[:, verts]
            d0 = old.astype(np.float64) - base
            d = d0.copy()
            for _ in range(STEPS):
                f = we[..., None] * (d[:, ib] - d[:, ia])                       # (T, Ec, 3): pull of b on a
                acc = np.stack([np.bincount(at_a, f[..., k].ravel(), T * n) - np.bincount(at_b, f[..., k].ravel(), T * n)
                                for k in range(3)], axis=-1).reshape(T, n, 3)
                d += step[..., None] * acc
            sk[:, verts] = np.where(d != d0, (base + d).astype(sk.dtype), old)
        return sets


__all__ = ["SQUEEZE", "STEPS", "Creases"]
