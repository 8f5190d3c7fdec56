"""What the eye sees of a chain: how far its tip swung beyond plain skinning, and whether it passed into the body.

- swing: per chain, the tip's (the end of its last link's bone) distance from where the animation puts it, per
  frame; its largest over the chain's length is the chain's swing share.
- penetrations: link-frames where a link's capsule sinks into a body capsule (one the animated pose keeps apart
  from it) or the floor deeper than PENETRATION of the link's radius.

Capsules are segments with radii; `segment_distances` is the closest distance between two sets of segments.
"""
from __future__ import annotations

import numpy as np

PENETRATION = 0.25
"""A link sinking into a capsule or the floor deeper than this share of its radius is a penetration."""


def segment_distances(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """(...) the closest distance between segments p0-p1 and q0-q1 (..., 3), broadcast."""
    from jiggle.rig.character.capsules import segment_closest
    s, t = segment_closest(p0, p1, q0, q1)
    return np.linalg.norm(p0 + s[..., None] * (p1 - p0) - q0 - t[..., None] * (q1 - q0), axis=-1)


def link_segments(world: np.ndarray, links) -> tuple[np.ndarray, np.ndarray]:
    """(T, n, 3) twice: each link's bone ends in world, from joint world transforms (T, J, 4, 4)."""
    W = world[:, links.joints]
    a = W[..., :3, 3]
    b = np.einsum("tnij,nj->tni", W[..., :3, :3], links.tip) + a
    return a, b


def capsule_segments(world: np.ndarray, capsules) -> tuple[np.ndarray, np.ndarray]:
    """(T, C, 3) twice: each body capsule's axis ends in world."""
    W = world[:, capsules.joint]
    ends = np.einsum("tcij,cej->tcei", W[..., :3, :3], capsules.local) + W[..., None, :3, 3]
    return ends[:, :, 0], ends[:, :, 1]


def depths(world: np.ndarray, links, capsules) -> np.ndarray:
    """(T, n, C) metres: how deep each link's capsule sinks into each body capsule (<= 0: apart)."""
    a, b = link_segments(world, links)
    c0, c1 = capsule_segments(world, capsules)
    dist = segment_distances(a[:, :, None], b[:, :, None], c0[:, None], c1[:, None])
    return links.radius[None, :, None] + capsules.radius[None, None, :] - dist


def kept_apart(world: np.ndarray, links, capsules, own: set) -> np.ndarray:
    """(n, C) bool: the body capsules each link's capsule stays clear of in the animated pose (world (K, J, 4, 4),
    chains on their animated pose) at every frame given, and that are not the chains' own (`own`: joints)."""
    if capsules is None or not capsules.count:
        return np.zeros((links.count, 0), bool)
    apart = np.ones((links.count, capsules.count), bool)
    for k in range(0, len(world), 64):
        apart &= (depths(world[k:k + 64], links, capsules) <= 0.0).all(axis=0)
    apart &= ~np.isin(capsules.joint, list(own))[None]
    return apart


def measure(static: np.ndarray, final: np.ndarray, links, capsules, apart: np.ndarray | None, floor,
            names) -> dict:
    """The figures of a swung bake: static and final joint world transforms (T, J, 4, 4); `apart` (n, C) the
    pairs that count (kept_apart); floor metres or None; names the chains'. Per chain: its length, the tip's
    largest swing (metres and share of the length), penetrations (link-frames) and the deepest, and the tip's path
    (T, 3) metres static and final ("tip_static", "tip_final")."""
    a0, b0 = link_segments(static, links)
    a1, b1 = link_segments(final, links)
    out = {}
    pen = np.zeros((len(final), links.count), bool)
    worst = np.zeros(links.count)
    if capsules is not None and capsules.count and apart is not None and apart.any():
        for k in range(0, len(final), 64):
            d = depths(final[k:k + 64], links, capsules)
            d = np.where(apart[None], d, -np.inf)
            deep = d.max(axis=2)
            pen[k:k + 64] |= deep > PENETRATION * links.radius[None]
            worst = np.maximum(worst, deep.max(axis=0))
    if floor is not None:
        low = np.minimum(a1[..., 2], b1[..., 2]) - links.radius[None] - floor
        low0 = np.minimum(a0[..., 2], b0[..., 2]) - links.radius[None] - floor
        below = (-low > PENETRATION * links.radius[None]) & (low0 >= 0.0)
        pen |= below
    for ci, name in enumerate(names):
        idx = np.flatnonzero(links.chain == ci)
        tip = idx[np.argmax(links.arc[idx] + np.linalg.norm(links.tip[idx], axis=1))]
        d = np.linalg.norm(b1[:, tip] - b0[:, tip], axis=1)
        L = float(links.length[ci])
        out[name] = {"joints": int(len(idx)), "length_m": round(L, 5), "tip_peak_m": round(float(d.max()), 6),
                     "swing_share": round(float(d.max()) / max(L, 1e-12), 5),
                     "penetrations": int(pen[:, idx].sum()),
                     "deepest_m": round(float(max(worst[idx].max(), 0.0)), 6),
                     "tip_static": b0[:, tip], "tip_final": b1[:, tip]}
    return out
