"""Vertex normals of a triangle mesh, recomputed per frame from its faces.

A vertex normal is the normalised sum of the raw cross products ``(p1 - p0) x (p2 - p0)`` of the
faces around it: each face counts in proportion to its area (its cross product is twice the area).
The vertex-to-face incidence is a sparse (V, F) matrix built once per mesh, so each frame is two
vectorised NumPy steps and one sparse product.

A vertex with no usable normal (it touches no face, only degenerate faces, or faces whose normals
cancel exactly) gets ``FALLBACK`` = (0, 0, 1), the world up (Z-up): every returned normal is unit
length and finite, so shading and offsets along normals never see NaN.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse

from jiggle.rig.base.errors import InputError

FALLBACK = np.array([0.0, 0.0, 1.0])


class VertexNormals:
    """Area-weighted vertex normals of one triangle topology.

    Parameters
    ----------
    faces : (F, 3) int, vertex indices of each triangle; counter-clockwise seen from outside
        for outward normals.
    num_vertices : V, the number of vertices the faces index into.
    """

    def __init__(self, faces, num_vertices: int):
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or not (
                faces.size == 0 or np.issubdtype(faces.dtype, np.integer)):
            raise InputError(f"expected an (F, 3) int array, got shape {faces.shape} "
                             f"dtype {faces.dtype}", field="faces")
        if faces.size and (faces.min() < 0 or faces.max() >= num_vertices):
            raise InputError(f"indices must lie in [0, {num_vertices}), found "
                             f"[{faces.min()}, {faces.max()}]", field="faces")
        self.faces = faces.astype(np.int64)
        self.faces.setflags(write=False)
        self.num_vertices = int(num_vertices)
        F = faces.shape[0]
        self.incidence = scipy.sparse.csr_matrix(
            (np.ones(3 * F), (self.faces.ravel(), np.repeat(np.arange(F), 3))),
            shape=(self.num_vertices, F))

    def __call__(self, positions) -> np.ndarray:
        """Unit normals of positions (V, 3) or (N, V, 3), metres -> the same shape.

        Float32 positions give float32 normals, anything else float64; the sums run in float64.
        """
        p = np.asarray(positions)
        if p.shape[-2:] != (self.num_vertices, 3) or p.ndim not in (2, 3):
            raise InputError(f"expected shape (V, 3) or (N, V, 3) with V = {self.num_vertices}, "
                             f"got {p.shape}", field="positions")
        dtype = np.float32 if p.dtype == np.float32 else np.float64
        batch = p.reshape(-1, self.num_vertices, 3).astype(np.float64)
        N = batch.shape[0]
        tri = batch[:, self.faces]  # (N, F, 3 corners, 3)
        face_n = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
        # one sparse product for the whole batch: faces on rows, (frame, axis) on columns
        summed = self.incidence @ face_n.transpose(1, 0, 2).reshape(-1, 3 * N)
        n = summed.reshape(self.num_vertices, N, 3).transpose(1, 0, 2)
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        ok = (length > 0.0) & np.isfinite(length)
        n = np.where(ok, n / np.where(ok, length, 1.0), FALLBACK)
        return n.reshape(p.shape).astype(dtype)

    def batch(self, positions, device: str = "cpu") -> np.ndarray:
        """The same normals as a call, for positions (T, V, 3) float32 -> (T, V, 3) float32, by one
        Warp launch (rig/character/normals_kernels.py); what a bake's cache writer uses for every frame."""
        import warp as wp

        from jiggle.rig.character import normals_kernels as kernels
        p = np.ascontiguousarray(positions, dtype=np.float32)
        if p.ndim != 3 or p.shape[1:] != (self.num_vertices, 3):
            raise InputError(f"expected shape (T, {self.num_vertices}, 3), got {p.shape}", field="positions")
        if p.size == 0:
            return np.broadcast_to(FALLBACK.astype(np.float32), p.shape).copy()
        if not hasattr(self, "_device_lists"):
            inc = self.incidence
            self._device_lists = (wp.array(self.faces.astype(np.int32), dtype=wp.vec3i, device=device),
                                  wp.array(inc.indptr.astype(np.int32), dtype=wp.int32, device=device),
                                  wp.array(inc.indices.astype(np.int32), dtype=wp.int32, device=device))
        faces, offsets, face_of = self._device_lists
        pts = wp.array(p, dtype=wp.vec3, device=device)
        out = wp.empty(p.shape[:2], dtype=wp.vec3, device=device)
        wp.launch(kernels.gather_normals, dim=p.shape[:2], device=device,
                  inputs=[pts, faces, offsets, face_of, wp.vec3d(*FALLBACK)], outputs=[out])
        return out.numpy().copy()


def vertex_normals(positions, faces) -> np.ndarray:
    """Unit area-weighted normals of positions (V, 3) or (N, V, 3) for faces (F, 3); see the module."""
    p = np.asarray(positions)
    return VertexNormals(faces, p.shape[-2])(p)
