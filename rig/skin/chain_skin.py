"""The skin follows the swung chains: what the chains' joints add to the smooth skin, vertex by vertex.

A chain joint's swing changes its skinning matrix S = W B^-1 (W its world transform, B its bind matrix) from the
animated one; every vertex it influences moves by its weight's share of that change:

    delta_v = sum over v's influences k on chain joints of  w_k (S_swung[j_k] - S_animated[j_k]) [x_v; 1]

That is linear skinning's own answer for the swung skeleton (the final skin is the static one plus it), exact where
the chain's skin has no muscle over it (the tissue templates leave chains none), and only the vertices a chain joint
influences are touched: nothing else of the skin can change.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class ChainSkin:
    """The vertices `joints` (the chain joints, (n,) character joint indices) influence on `character`, and how:
    built once. `vertices` (Vc,) their indices."""

    def __init__(self, character, joints):
        joints = np.asarray(joints, np.int64)
        J = character.num_joints
        slot = np.full(J, -1, np.int64)
        slot[joints] = np.arange(len(joints))
        jj = np.asarray(character.joints, np.int64)
        ww = np.asarray(character.weights, np.float64)
        hit = (slot[jj] >= 0) & (ww > 0)
        v, k = np.nonzero(hit)
        self.vertices = np.unique(v)
        row = np.searchsorted(self.vertices, v)
        n = len(joints)
        w = ww[v, k]
        # delta_v = sum_j sum_b (W_vj x_vb) D_jab: one sparse (Vc, 4 n) matrix of weight times rest point, applied
        # to every frame's joint changes at once
        rest = np.c_[np.asarray(character.vertices, np.float64)[v], np.ones(len(v))]      # (P, 4)
        cols = 4 * slot[jj[v, k]][:, None] + np.arange(4)[None]
        self.matrix = sp.csr_matrix(((w[:, None] * rest).ravel(), (np.repeat(row, 4), cols.ravel())),
                                    shape=(len(self.vertices), 4 * n))
        """(Vc, 4 n) sparse: row v, column 4 j + b holds v's weight on chain joint j times its rest point's
        coordinate b (x, y, z, 1)."""
        self.joints = joints
        self.weight = np.bincount(row, weights=w, minlength=len(self.vertices)).astype(np.float32)
        """(Vc,) each vertex's share of skin weight on chain joints: 1 on a chain, between 0 and 1 where it blends
        into the body (a chain's root)."""
        self.inv_bind = np.linalg.inv(np.asarray(character.bind_matrices, np.float64)[joints])   # (n, 4, 4)

    def delta(self, world_static: np.ndarray, world_final: np.ndarray) -> np.ndarray:
        """(T, Vc, 3) float32 metres: what the swing moves each of `vertices`, from the animated and swung joint
        world transforms (T, J, 4, 4)."""
        T = len(world_static)
        if not len(self.vertices):
            return np.zeros((T, 0, 3), np.float32)
        d = (np.asarray(world_final, np.float64)[:, self.joints] - np.asarray(world_static, np.float64)[:, self.joints])
        D = d[:, :, :3, :] @ self.inv_bind[None]                          # (T, n, 3, 4): the skinning matrices' change
        out = self.matrix @ D.transpose(1, 3, 0, 2).reshape(4 * len(self.joints), T * 3)     # (Vc, T * 3)
        return out.reshape(len(self.vertices), T, 3).transpose(1, 0, 2).astype(np.float32)
