"""Seams: a mesh split where its UVs or normals jump (glTF, OBJ and FBX all store a vertex per corner kind) has
several vertices at one rest place. Plain skinning moves them alike (they have the same weights); the muscles'
deformers need not (normals, regions and spreads are per vertex), which would open the surface along the seam.
The skin stage welds them: every vertex of a seam group gets the group's mean position, frame by frame.

A group is the vertices within `tol` of one another at rest that also share their skin weights (a split made on
purpose, with other weights, is left alone).
"""
from __future__ import annotations

import weakref

import numpy as np

_CACHE: dict = {}


def seam_groups(vertices: np.ndarray, joints: np.ndarray, weights: np.ndarray, tol: float = 1e-6):
    """(labels (V,) int64, the averaging matrix (G, V) scipy.sparse) of the seam groups, None when no two vertices
    share a rest place with the same weights. tol : metres."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    v = np.asarray(vertices, np.float64)
    pairs = cKDTree(v).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return None
    key = lambda i: (np.asarray(joints)[i], np.round(np.asarray(weights, np.float64)[i], 5))   # noqa: E731
    ja, wa = key(pairs[:, 0])
    jb, wb = key(pairs[:, 1])
    same = np.all(np.where(wa > 0, ja, -1) == np.where(wb > 0, jb, -1), axis=1) & np.all(wa == wb, axis=1)
    pairs = pairs[same]
    if len(pairs) == 0:
        return None
    V = len(v)
    graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(V, V))
    n, labels = connected_components(graph, directed=False)
    counts = np.bincount(labels, minlength=n).astype(np.float64)
    avg = csr_matrix((1.0 / counts[labels], (labels, np.arange(V))), shape=(n, V))
    return labels, avg


def for_character(character):
    """seam_groups of a character, computed once while it lives (characters are frozen; a Character's arrays make
    it unhashable, so the cache is keyed by identity and emptied when it goes)."""
    key = id(character)
    if key not in _CACHE:
        _CACHE[key] = seam_groups(character.vertices, character.joints, character.weights)
        weakref.finalize(character, _CACHE.pop, key, None)
    return _CACHE[key]


def weld(skins: np.ndarray, groups) -> np.ndarray:
    """skins (T, V, 3) with every seam group at its mean, frame by frame (same dtype; unchanged when groups is
    None)."""
    if groups is None:
        return skins
    labels, avg = groups
    T, V, _ = skins.shape
    flat = np.ascontiguousarray(np.transpose(skins, (1, 0, 2))).reshape(V, 3 * T).astype(np.float64)
    out = (avg @ flat)[labels].reshape(V, T, 3)
    return np.ascontiguousarray(np.transpose(out, (1, 0, 2))).astype(skins.dtype)
