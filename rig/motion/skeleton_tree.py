"""A skeleton's rest pose as a tree of points (joints and end sites), with the walks that role and
body-plan detection share: common ancestors, paths, chains grouped by place, subtrees.

Points are every joint, then every end site, each with the joint that carries it (`owner`); only
the largest joint tree counts when a file holds several. Positions are the rest pose (Z-up, metres).
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.motion.clip import Clip

SAME_PLACE = 1e-3
"""Joints closer than this fraction of the skeleton's size sit at the same place (zero-length bones,
like CMU's LHipJoint at the Hips or LeftFingerBase at the LeftHand)."""


class SkeletonTree:
    """Tree helpers over one skeleton's rest pose.

    pos : (J, 3) rest joint positions; pts : (P, 3) points of the main tree (joints, then end sites);
    owner : (P,) joint of each point; is_end : (P,) bool; kids : children per joint; depth : (J,);
    size : largest extent of the points, metres; eps : SAME_PLACE of it.
    """

    def __init__(self, clip: Clip):
        self.clip = clip
        self.where = clip.source or None
        rot, pos = clip.rest_world()
        self.pos = pos
        J = clip.num_joints
        self.parents = np.asarray(clip.parents)
        self.kids = [[] for _ in range(J)]
        for j, p in enumerate(self.parents):
            if p >= 0:
                self.kids[p].append(j)
        self.depth = np.zeros(J, int)
        for j, p in enumerate(self.parents):
            self.depth[j] = self.depth[p] + 1 if p >= 0 else 0
        # the largest tree, when the file holds several
        tree = np.zeros(J, int)
        for j, p in enumerate(self.parents):
            tree[j] = tree[p] if p >= 0 else j
        main = np.bincount(tree).argmax()
        self.in_tree = tree == main
        ends = clip.end_world(rot[None], pos[None])[0] if len(clip.end_parents) else np.zeros((0, 3))
        self.pts = np.concatenate([pos, ends])
        self.owner = np.concatenate([np.arange(J), np.asarray(clip.end_parents, int)])
        self.has_end = np.zeros(J, bool)
        self.has_end[np.asarray(clip.end_parents, int)] = True
        self.is_end = np.arange(len(self.owner)) >= J
        live = self.in_tree[self.owner]
        self.pts, self.owner, self.is_end = self.pts[live], self.owner[live], self.is_end[live]
        self.size = float(np.ptp(self.pts, axis=0).max())
        self.eps = max(SAME_PLACE * self.size, 1e-9)

    @property
    def tips(self) -> np.ndarray:
        """(P,) bool: points that end a chain (end sites, and childless joints without an end site)."""
        return self.is_end | np.array([not self.kids[o] and not self.has_end[o] for o in self.owner])

    def lca(self, a: int, b: int) -> int:
        """The deepest joint that is an ancestor of (or equal to) both joints."""
        while a != b:
            if self.depth[a] >= self.depth[b]:
                a = self.parents[a]
            else:
                b = self.parents[b]
        return int(a)

    def path(self, top: int, bottom: int) -> list[int]:
        """Joints from `top` (excluded) down to `bottom` (included); `top` must be its ancestor."""
        out = []
        while bottom != top:
            out.append(int(bottom))
            bottom = self.parents[bottom]
        return out[::-1]

    def under(self, j: int, top: int) -> bool:
        """True when joint j is `top` or below it."""
        while j >= 0 and j != top:
            j = self.parents[j]
        return j == top

    def groups(self, chain: list[int]) -> list[list[int]]:
        """Consecutive joints of a chain at the same place merged, in order."""
        out: list[list[int]] = []
        for j in chain:
            if out and np.linalg.norm(self.pos[j] - self.pos[out[-1][-1]]) < self.eps:
                out[-1].append(j)
            else:
                out.append([j])
        return out

    def parts_from(self, first: int, trunk: int, share: float) -> np.ndarray:
        """(P,) bool: points whose chain parts from point `first`'s at least `share` of the way from it
        to joint `trunk` (where its limb leaves the trunk): the points of other limbs."""
        tip = self.pts[first]
        reach = np.linalg.norm(self.pos[trunk] - tip)
        owner = self.owner[first]
        return np.array([np.linalg.norm(self.pos[self.lca(int(o), owner)] - tip) > share * reach
                         for o in self.owner])

    def farthest_below(self, j: int) -> int:
        """Index into the points of the point in j's subtree (j excluded) farthest from joint j,
        or -1 when j has none."""
        best, far = -1, self.eps
        for i, o in enumerate(self.owner):
            if (o != j or self.is_end[i]) and self.under(int(o), j):
                d = np.linalg.norm(self.pts[i] - self.pos[j])
                if d > far:
                    best, far = i, d
        return best
