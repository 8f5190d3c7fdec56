"""The edges of a triangle mesh as a graph: each edge once with its faces, and the vertex adjacency.

Shared by whatever walks a skin's surface: automatic weights smoothed over it (bone_heat), the skin's
quality measures (rig.skin.quality), its spread and Delta Mush (rig.skin.surface_smoothing,
rig.skin.delta_mush).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def mesh_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unique edges of a triangle mesh and their faces.

    faces : (F, 3) int vertex indices.
    Returns edges (E, 2) int32 (the smaller vertex index first) and edge_faces (E, 2) int32: the first
    two faces holding the edge, -1 in the second column for a boundary edge (a non-manifold edge with
    three or more faces is measured between its first two).
    """
    faces = np.asarray(faces, dtype=np.int64)
    F = len(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    f = np.tile(np.arange(F), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((f, key[:, 1], key[:, 0]))
    key, f = key[order], f[order]
    first = np.ones(len(key), bool)
    first[1:] = np.any(key[1:] != key[:-1], axis=1)
    start = np.nonzero(first)[0]
    count = np.diff(np.append(start, len(key)))
    second = np.where(count > 1, f[np.minimum(start + 1, len(key) - 1)], -1)
    return key[start].astype(np.int32), np.stack([f[start], second], axis=1).astype(np.int32)


def mesh_neighbours(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """(V, V) 0/1 adjacency of the mesh's edges, symmetric."""
    faces = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    ones = np.ones(2 * len(e), np.float32)
    return sp.coo_matrix((ones, (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                         shape=(num_vertices, num_vertices)).tocsr()
