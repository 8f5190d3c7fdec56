"""Bone capsules: a capsule inside the body around every bone of a character, built once at bind.

A bone is the segment from a joint to one of its children (or to its end site, for a leaf, cut back to
where the joint's skin ends along it, less the radius: an end site may lie past a fingertip or the top
of the head), riding the joint (its world transform carries the segment). Its capsule's radius comes
from the skin around it: the distances from the segment of the skin vertices the bone's joint
dominates, measured along the middle of the bone (parameter t in [MID_LO, MID_HI], away from the
joints where the neighbours' skin folds in), their SKIN_PERCENTILE percentile (the thin side of the
limb, not the average), then shrunk by the local tissue thickness so that the capsule sits inside the
body, under the muscles and fat that jiggle over it:

    radius = max(MIN_FRACTION r_skin, r_skin - tissue),  tissue = TISSUE_FRACTION r_skin by default

and at most INSIDE_FRACTION of the distance from any point of its axis to the nearest skin vertex (the
skin may be thinner near a bone's ends than along its middle: a neck over the chest bone's end)

(sim/jiggle/colliders.py shrinks them further to the inner side of the bone's own muscles,
:meth:`BoneCapsules.shrunk_inside`). Bones shorter than MIN_LENGTH (CMU's zero-length hip and
clavicle roots) or with fewer than MIN_VERTICES skin vertices around them get no capsule.

Capsules are what the particles of the jiggle collide with (sim/jiggle/colliders.py) and what the
skin is checked against (skin vertices of one part inside another part's capsule).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from jiggle.rig.base.frozen import frozen_array

MID_LO, MID_HI = 0.15, 0.85
"""Skin vertices projecting on this part of a bone set its radius."""
SKIN_PERCENTILE = 20.0
"""Percentile of the skin's distances to the bone taken as the skin radius r_skin."""
TISSUE_FRACTION = 0.4
"""Default tissue thickness (muscle and fat over the bone) as a fraction of r_skin."""
MIN_FRACTION = 0.25
"""A capsule keeps at least this fraction of r_skin (a bone's core)."""
INNER_PERCENTILE = 10.0
"""Percentile of the distances of a bone's own muscles' CVs to it taken as the muscles' inner side (the
few CVs a fitted muscle puts nearer the axis, where it wraps a joint, do not set it)."""
MIN_LENGTH = 0.02
"""metres: shorter bones get no capsule."""
MIN_VERTICES = 8
"""Skin vertices a bone needs around it for a capsule."""
INSIDE_FRACTION = 0.9
"""A capsule's radius is at most this fraction of the distance from its axis to the nearest skin vertex."""
AXIS_SAMPLES = 17
"""Points along a capsule's axis where that distance is measured."""
MIN_MODEL_RADIUS = 0.005
"""metres: a model's geom whose radius would shrink below this to stay inside the skin is dropped."""
LEAF_PERCENTILE = 98.0
"""A leaf bone's capsule ends where this share of its skin vertices lies behind it along the bone."""


@dataclass(frozen=True, eq=False)
class BoneCapsules:
    """Capsules riding the joints of a character (arrays read-only).

    joint : (C,) int32 joint each capsule rides (its world transform carries the capsule).
    child : (C,) int32 joint at the segment's far end, -1 for an end site.
    local : (C, 2, 3) float64 metres, the segment's ends in the joint's bind frame
        (inv(bind_world[joint]) @ end).
    radius : (C,) float64 metres.
    names : (C,) "joint>child" labels.
    parents : (J,) int32 the skeleton's parents (for chains and adjacency).
    """

    joint: np.ndarray
    child: np.ndarray
    local: np.ndarray
    radius: np.ndarray
    names: tuple
    parents: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "joint", frozen_array(self.joint, np.int32))
        object.__setattr__(self, "child", frozen_array(self.child, np.int32))
        object.__setattr__(self, "local", frozen_array(np.asarray(self.local, np.float64).reshape(-1, 2, 3)))
        object.__setattr__(self, "radius", frozen_array(self.radius, np.float64))
        object.__setattr__(self, "parents", frozen_array(self.parents, np.int32))
        object.__setattr__(self, "names", tuple(self.names))

    @property
    def count(self) -> int:
        return len(self.joint)

    def ends(self, world: np.ndarray) -> np.ndarray:
        """(..., C, 2, 3) metres: the segments' ends under joint world transforms `world` (..., J, 4, 4)."""
        world = np.asarray(world, dtype=np.float64)
        w = world[..., self.joint, :, :]                                    # (..., C, 4, 4)
        return np.einsum("...cij,ckj->...cki", w[..., :3, :3], self.local) + w[..., None, :3, 3]

    def shrunk_inside(self, bind_world: np.ndarray, points: np.ndarray, owner: np.ndarray,
                      fraction: float = 0.9) -> "BoneCapsules":
        """The capsules with each radius at most `fraction` x the inner side of the tissue over it: the
        INNER_PERCENTILE percentile of the distances from its segment of `points` (P, 3) metres at bind
        that `owner` (P, C) bool marks as lying over it (e.g. the CVs of the muscles that wrap the
        bone), among those projecting on its middle; never below MIN_FRACTION of its skin radius share
        (the bone's core). The capsule then sits inside those muscles."""
        ends = self.ends(bind_world)
        r = self.radius.copy()
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        for c in range(self.count):
            sel = owner[:, c]
            if not sel.any():
                continue
            d, t = segment_distance(points[sel], ends[c, 0], ends[c, 1])
            mid = (t >= MID_LO) & (t <= MID_HI)
            if mid.any():
                core = MIN_FRACTION / (1.0 - TISSUE_FRACTION) * self.radius[c]      # MIN_FRACTION r_skin
                r[c] = max(min(r[c], fraction * float(np.percentile(d[mid], INNER_PERCENTILE))), min(core, r[c]))
        return replace(self, radius=np.maximum(r, 1e-4))


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances (n,) metres of points p (n, 3) from the segment a-b (3,), and the parameter t (n,)
    in [0, 1] of the nearest point a + t (b - a)."""
    ab = b - a
    L2 = float(ab @ ab)
    t = np.clip((p - a) @ ab / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(p))
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1), t


def segment_closest(p1, q1, p2, q2) -> tuple[np.ndarray, np.ndarray]:
    """Parameters s, t (...) in [0, 1] of the closest points p1 + s (q1 - p1) and p2 + t (q2 - p2) of two segments,
    their ends (..., 3), broadcast (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    tiny = 1e-12
    denom = a * e - b * b
    s = np.where(denom > tiny, np.clip((b * f - c * e) / np.maximum(denom, tiny), 0, 1), 0.0)
    s = np.where(a <= tiny, 0.0, s)
    t = np.where(e > tiny, (b * s + f) / np.maximum(e, tiny), 0.0)
    # t outside [0, 1]: clamp it, and s to the clamped t
    s = np.where(t < 0, np.where(a > tiny, np.clip(-c / np.maximum(a, tiny), 0, 1), 0.0), s)
    s = np.where(t > 1, np.where(a > tiny, np.clip((b - c) / np.maximum(a, tiny), 0, 1), 0.0), s)
    return s, np.clip(t, 0, 1)


def bone_capsules(character) -> BoneCapsules:
    """The capsules of a rig.character.Character (see the module)."""
    from jiggle.rig.character.character import end_sites
    bind = np.asarray(character.bind_world, dtype=np.float64)
    pos = bind[:, :3, 3]
    parents = np.asarray(character.parents)
    tips = end_sites(character.skeleton) if character.skeleton is not None else np.full_like(pos, np.nan)
    segs = [(int(p), j, pos[p], pos[j]) for j, p in enumerate(parents) if p >= 0]
    has_child = np.zeros(len(parents), bool)
    has_child[parents[parents >= 0]] = True
    segs += [(j, -1, pos[j], tips[j]) for j in range(len(parents)) if not has_child[j] and np.isfinite(tips[j]).all()]
    from scipy.spatial import cKDTree
    dominant = character.dominant_joint()
    verts = np.asarray(character.vertices, dtype=np.float64)
    tree = cKDTree(verts)
    joint, child, local, radius, names = [], [], [], [], []
    for p, c, a, b in segs:
        if np.linalg.norm(b - a) < MIN_LENGTH:
            continue
        own = verts[dominant == p]
        if len(own) < MIN_VERTICES:
            continue
        d, t = segment_distance(own, a, b)
        mid = (t >= MID_LO) & (t <= MID_HI)
        if mid.sum() < MIN_VERTICES:
            continue
        r_skin = float(np.percentile(d[mid], SKIN_PERCENTILE))
        r = max(MIN_FRACTION * r_skin, r_skin - TISSUE_FRACTION * r_skin)
        if c < 0:
            b = _leaf_end(own, a, b, r)
        # the skin may be thinner near the ends than along the middle (a neck over the chest's end): no
        # part of the capsule comes nearer the skin than (1 - INSIDE_FRACTION) r
        near, _ = tree.query(a + np.linspace(0.0, 1.0, AXIS_SAMPLES)[:, None] * (b - a))
        r = min(r, INSIDE_FRACTION * float(near.min()))
        inv = np.linalg.inv(bind[p])
        joint.append(p)
        child.append(c)
        local.append([(inv @ np.append(e, 1.0))[:3] for e in (a, b)])
        radius.append(r)
        names.append(f"{character.joint_names[p]}>{character.joint_names[c] if c >= 0 else 'end'}")
    return BoneCapsules(joint=np.array(joint, np.int32), child=np.array(child, np.int32),
                        local=np.array(local, np.float64).reshape(-1, 2, 3), radius=np.array(radius, np.float64),
                        names=tuple(names), parents=parents)


def _leaf_end(own: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """The far end of a leaf bone's capsule (metres): an end site may lie past the skin (a fingertip, the top
    of a head), so the axis stops where the skin the joint dominates ends along it (the LEAF_PERCENTILE
    percentile of the vertices' positions along the axis), less the radius, so the cap stays inside."""
    ab = b - a
    L = float(np.linalg.norm(ab))
    t = (own - a) @ ab / (L * L)
    reach = min(1.0, float(np.percentile(t, LEAF_PERCENTILE))) * L - r
    return a + ab * max(reach, 0.5 * MIN_LENGTH) / L


def capsules_from_geoms(joint, ends_local, radius, names, parents, child=None) -> BoneCapsules:
    """Capsules given as they are (e.g. a MuJoCo model's own capsule geoms): joint (C,), ends_local
    (C, 2, 3) metres in the joint's bind frame, radius (C,) metres, names (C,), the skeleton's parents (J,),
    child (C,) the joint at each segment's far end (None: -1, none)."""
    return BoneCapsules(joint=np.asarray(joint), child=np.full(len(joint), -1) if child is None else np.asarray(child),
                        local=ends_local, radius=np.asarray(radius), names=tuple(names), parents=parents)


def model_capsules(character, joint, local, radius, names,
                   fallback: BoneCapsules | None = None) -> tuple[BoneCapsules, int]:
    """A MuJoCo model's own capsule geoms (sim.drive.skeleton.capsule_geoms: joint (C,), local (C, 2, 3)
    metres in the joint's frame, radius (C,) metres, names) as the capsules of `character`, kept inside its
    skin: a geom is dropped when the middle of its axis lies outside the skin (the nearest rest vertex's
    normal points toward it) or its radius would shrink below MIN_MODEL_RADIUS; the others keep their axis
    and take at most INSIDE_FRACTION of the distance from the inside part of their axis to the skin (a
    model's capsules are sized for its own body, not this character's). A joint none of whose geoms is
    kept gets the capsules `fallback` (the character's bone capsules, :func:`bone_capsules`) has for it:
    the model's geoms where they exist. Each kept geom's far end is matched to the joint's child that lies
    along it (for the chain rules of sim/jiggle/colliders.py). Returns (capsules, kept): the kept geoms
    first, then the fallback's."""
    from scipy.spatial import cKDTree
    bind = np.asarray(character.bind_world, dtype=np.float64)
    parents = np.asarray(character.parents)
    verts = np.asarray(character.vertices, dtype=np.float64)
    normals = np.asarray(character.normals, dtype=np.float64)
    tree = cKDTree(verts)
    joint = np.asarray(joint, dtype=np.int64)
    local = np.asarray(local, dtype=np.float64).reshape(-1, 2, 3)
    out = {"joint": [], "child": [], "local": [], "radius": [], "names": []}
    for c in range(len(joint)):
        j = int(joint[c])
        ends = local[c] if np.linalg.norm(local[c, 0]) <= np.linalg.norm(local[c, 1]) else local[c, ::-1]
        a, b = (bind[j, :3, :3] @ ends.T).T + bind[j, :3, 3]            # a: the end nearer the joint
        pts = a + np.linspace(0.0, 1.0, AXIS_SAMPLES)[:, None] * (b - a)
        d, idx = tree.query(pts)
        outside = np.einsum("ij,ij->i", pts - verts[idx], normals[idx]) > 0.0
        if outside[AXIS_SAMPLES // 2] or outside.all():
            continue
        r = min(float(radius[c]), INSIDE_FRACTION * float(d[~outside].min()))
        if r < MIN_MODEL_RADIUS:
            continue
        kids = np.flatnonzero(parents == j)
        child = -1
        if len(kids) and np.linalg.norm(b - a) > 0:
            far = np.linalg.norm(bind[kids, :3, 3] - b, axis=1)
            k = int(np.argmin(far))
            if far[k] <= r + 0.5 * np.linalg.norm(bind[kids[k], :3, 3] - bind[j, :3, 3]):
                child = int(kids[k])
        for key, v in (("joint", j), ("child", child), ("local", ends), ("radius", r), ("names", names[c])):
            out[key].append(v)
    kept = len(out["joint"])
    if fallback is not None:
        have = set(out["joint"])
        for c in range(fallback.count):
            if int(fallback.joint[c]) not in have:
                for key, v in (("joint", fallback.joint[c]), ("child", fallback.child[c]), ("local", fallback.local[c]),
                               ("radius", fallback.radius[c]), ("names", fallback.names[c])):
                    out[key].append(v)
    return BoneCapsules(joint=np.array(out["joint"], np.int32), child=np.array(out["child"], np.int32),
                        local=np.array(out["local"], np.float64).reshape(-1, 2, 3),
                        radius=np.array(out["radius"], np.float64), names=tuple(out["names"]),
                        parents=parents), kept
