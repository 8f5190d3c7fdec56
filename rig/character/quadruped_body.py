"""A smooth, closed body generated around a four-legged skeleton (a dog-like build), the quadruped
counterpart of rig/character/body.py, built from the same machinery: elliptic round cones and
ellipsoids (``body._cone``, ``body._ellipsoid``) smooth-unioned into an implicit field, polygonised,
cleaned to its largest component, Taubin-smoothed and projected back onto the field.

Reading the skeleton. The roles come from the rest pose's geometry
(:func:`rig.motion.body_plan.quadruped_roles`: paws are the lowest tips, the girdles are where their
chains meet, the head the highest point off the legs, the tail a chain reaching back past the hips),
not from names. From them: the spine (hips to chest), the neck and head (chest to the head's
farthest tip), the tail (to its farthest tip) and each leg from its girdle joint (scapula or hip
joint) down to its lowest tip. ``L`` is the hips-to-chest distance; every size is a fraction of it.

Solids (world Z-up, metres, the rest pose; "front" is the horizontal direction hips -> chest):

- trunk: one loft from behind the hips (the rump) to in front of the chest (the breast), barrel
  shaped: deeper than wide, deepest at the chest, its back a few centimetres above the spine joints,
  its axis fitted through the sections' centres so the belly line rises towards the flank;
- neck: a cone from the chest to the head joint; head: a skull ellipsoid and a muzzle cone reaching
  the head's tip;
- legs: front: scapula, upper arm, forearm, pastern; hind: a thick thigh (the haunch), gaskin,
  metatarsus; each ends in a paw, a flat ellipsoid on the floor around the toe joint and its tip;
- tail: tapered cones along its chain;
- fat (:class:`rig.character.body.FatVolume`): "belly" under the trunk between the ribs and the
  flank (``BodyOptions.belly``), "chest" on the breast below the neck (``BodyOptions.chest``) and
  "haunch_L" / "haunch_R" on the back of each thigh (``BodyOptions.glutes``), each in metres of extra
  thickness at its most prominent point.

As in body.py, every distal part (forearm, pastern, gaskin, metatarsus, paw, tail beyond its base) is
kept apart from the pieces it shares no joint with (``body._keep_apart``), so an elbow that comes
near the chest cannot close a handle, and only the largest component is kept: the surface is one
closed, outward-wound genus-0 mesh.

Weights. Bone heat alone gives the underside of the deep chest to the nearest bones, the two front
legs' (it hangs between the elbows, far below the spine), and LBS then blends their opposite swings
into a crease. :func:`heat_bones` gives bone heat the trunk's own bones: a keel KEEL * L above the
barrel's underside, from below the spine joint to below the chest and on to the sternum between the
shoulder joints, owned by the spine joints (``load.body_character`` passes it to ``auto_weighted``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.body import (
    UP,
    Body,
    BodyOptions,
    _blend_order,
    _cone,
    _ellipsoid,
    _fat_records,
    _frame,
    _keep_apart,
    _Slots,
    surface,
)
from jiggle.rig.motion.body_plan import detect_body_plan, quadruped_roles
from jiggle.rig.motion.clip import Clip

VOXEL_PER_LENGTH = 0.5   # voxel ~ this * L / sqrt(vertex count), for the gap estimate (measured on the dog)
# trunk sections: (place along the spine as a share of L from the hips towards the chest, half-width,
# half-depth, both shares of L); the back stays BACK * L above the spine joints
TRUNK = np.array([
    [-0.30, 0.10, 0.10],    # rump, behind the hip joints (the buttocks)
    [0.00, 0.19, 0.18],     # hips
    [0.45, 0.165, 0.16],    # waist
    [0.82, 0.20, 0.18],     # chest
    [1.05, 0.18, 0.18],     # shoulders
    [1.25, 0.12, 0.15],     # breast, in front of the shoulder joints
])
BACK = 0.07
# bone heat: the trunk's keel runs this share of L above the barrel's underside (heat_bones)
KEEL = 0.1
# the rib cage, an ellipsoid below the front of the trunk that makes the chest deep: centre (share of
# L along the spine), semi-axes (front-back, half-width, half-depth) as shares of L
RIBS = (0.8, (0.40, 0.19, 0.27))


def is_quadruped(clip: Clip) -> bool:
    """True when the clip's rest skeleton reads as four-legged (rig.motion.body_plan)."""
    return detect_body_plan(clip).kind == "quadruped"


@dataclass
class _Quad:
    """The rest skeleton read for building. Points are joints then end sites.

    pos : (P, 3) metres. spine : points hips -> chest. neck : points chest -> head joint. head_tip :
    the head's farthest point. tail : points from the tail base to its tip. legs : {"left_front", ...:
    points from the girdle joint (scapula or hip joint) down to the lowest tip}. front, left : (3,)
    unit horizontal directions. L : hips-to-chest distance, metres. floor : z of the ground under the
    paws, metres. roles : {role: joint}.
    """

    pos: np.ndarray
    spine: list[int]
    neck: list[int]
    head_tip: int
    tail: list[int]
    legs: dict
    front: np.ndarray
    left: np.ndarray
    L: float
    floor: float
    roles: dict


def _read(clip: Clip) -> _Quad:
    roles = quadruped_roles(clip)
    rot, jpos = clip.rest_world()
    epos = clip.end_world(rot[None], jpos[None])[0] if len(clip.end_parents) else np.zeros((0, 3))
    pos = np.concatenate([jpos, epos])
    parent = np.concatenate([clip.parents, clip.end_parents]).astype(int)
    kids = [[] for _ in pos]
    for p, q in enumerate(parent):
        if q >= 0:
            kids[q].append(p)

    def below(p: int) -> list[int]:
        out, stack = [], [p]
        while stack:
            q = stack.pop()
            out.append(q)
            stack += kids[q]
        return out

    def up_to(p: int, top: int) -> list[int]:
        """Points from `top` down to `p` (p under top)."""
        out = [p]
        while out[-1] != top:
            out.append(int(parent[out[-1]]))
        return out[::-1]

    def farthest(p: int, key) -> int:
        return max(below(p), key=key)

    hips, chest = roles["hips"], roles["chest"]
    spine = up_to(chest, hips)
    head = roles["head"]
    neck = up_to(head, chest)
    head_tip = farthest(head, lambda q: np.linalg.norm(pos[q] - pos[head]))
    tail = []
    if "tail" in roles:
        t = roles["tail"]
        tail = up_to(farthest(t, lambda q: np.linalg.norm(pos[q] - pos[t])), t)
    legs = {}
    for s in ("left", "right"):
        for e in ("front", "hind"):
            top = roles.get(f"{s}_{e}_shoulder", roles[f"{s}_{e}_upper_leg"])
            legs[f"{s}_{e}"] = up_to(farthest(top, lambda q: -pos[q, 2]), top)
    f = pos[chest] - pos[hips]
    front = np.array([f[0], f[1], 0.0]) / np.linalg.norm(f[:2])
    tips = [ch[-1] for ch in legs.values()]
    L = float(np.linalg.norm(f))
    floor = float(pos[tips, 2].min()) - 0.015 * L
    return _Quad(pos, spine, neck, head_tip, tail, legs, front, np.cross(UP, front), L, floor, roles)


def generate_quadruped_body(clip: Clip, options: BodyOptions = BodyOptions()) -> Body:
    """A smooth, watertight, genus-0 body around a four-legged clip's rest-pose skeleton (see the
    module docstring); stages and timings as :func:`rig.character.body.generate_body`. Body.bind is
    the rest pose; Body.stature is the height of the back above the floor, metres."""
    t0 = time.perf_counter()
    rest = replace(clip, rotations=clip.rest_rotations[None], translations=clip.offsets[None])
    pieces, q = quadruped_layout(rest, options)
    timings = {"layout": time.perf_counter() - t0}
    pieces, v, f, h = surface(pieces, q.L / 40.0, options, timings)
    timings["total"] = time.perf_counter() - t0
    J = clip.num_joints
    withers = float(q.pos[q.spine, 2].max() + BACK * q.L - q.floor)
    return Body(vertices=frozen_array(v), faces=frozen_array(f, np.int32), fat=tuple(_fat_records(pieces)),
                joint_positions=frozen_array(q.pos[:J]), front=frozen_array(q.front), stature=withers,
                voxel=float(h), timings=timings,
                bind=replace(rest, meta={**rest.meta, "bind_pose": "rest (quadruped)"}))


def quadruped_layout(clip: Clip, options: BodyOptions = BodyOptions()) -> tuple[list, _Quad]:
    """The solids in blending order, sized and kept apart, and the skeleton as read for them."""
    q = _read(clip)
    o = options
    gap = 2.0 * VOXEL_PER_LENGTH * q.L / np.sqrt(max(int(o.resolution), 100))
    slots = _Slots(SimpleNamespace(node=np.arange(len(q.pos))))
    pieces, trunk = _pieces(q, o, slots)
    pieces = _keep_apart(_blend_order(pieces), gap=gap)
    fat = [_ellipsoid(c, axes, radii, 0.8 * min(radii) * o.blend, places, tag=(name, joint))
           for name, joint, c, radii, axes, places in _fat(q, trunk, o)]
    pieces = _keep_apart(_blend_order(pieces + fat), gap=gap)
    return pieces, q


@dataclass
class _Trunk:
    """The trunk loft: axis from a (rump) to b (breast), stations ts (0..1), semi-axes (n, 2) metres
    (half-width, half-depth), and the places it covers."""

    a: np.ndarray
    b: np.ndarray
    ts: np.ndarray
    semi: np.ndarray
    places: frozenset
    ribs: np.ndarray = None      # the rib cage's centre, its front-back and vertical semi-axes (metres)
    ribs_length: float = 0.0
    ribs_depth: float = 0.0

    def centre(self, t: float) -> np.ndarray:
        return self.a + t * (self.b - self.a)

    def section(self, t: float) -> tuple[float, float]:
        return float(np.interp(t, self.ts, self.semi[:, 0])), float(np.interp(t, self.ts, self.semi[:, 1]))

    def underside(self, point: np.ndarray) -> float:
        """z (metres) of the trunk's underside (the loft's or the rib cage's, the lower) below a point."""
        t = self.at(point)
        bottom = self.centre(t)[2] - self.section(t)[1]
        front = self.b - self.a
        front[2] = 0.0
        s = (point - self.ribs) @ _unit(front) / self.ribs_length
        if abs(s) < 1.0:
            bottom = min(bottom, self.ribs[2] - self.ribs_depth * np.sqrt(1.0 - s * s))
        return float(bottom)

    def at(self, point: np.ndarray) -> float:
        """Parameter (0..1) of the trunk section through a point."""
        d = self.b - self.a
        return float(np.clip((point - self.a) @ d / (d @ d), 0, 1))


def _trunk(q: _Quad, o: BodyOptions, slots) -> tuple[list, _Trunk]:
    """The trunk loft and the rib cage (see TRUNK, RIBS)."""
    L, th = q.L, o.thickness
    hips = q.pos[q.spine[0]]
    sp = q.pos[q.spine]
    along = (sp - hips) @ q.front / L                      # spine joints' places, shares of L
    h = TRUNK[:, 0]
    top = np.interp(h, along, sp[:, 2]) + BACK * L         # the back line, flat beyond the spine's ends
    depth = TRUNK[:, 2] * L * th
    centre_z = top - depth
    # a straight axis through the sections' centres (least squares), the back line kept exact
    A = np.stack([h, np.ones_like(h)], axis=1)
    slope, icpt = np.linalg.lstsq(A, centre_z, rcond=None)[0]
    cz = slope * h + icpt
    semi = np.stack([TRUNK[:, 1] * L * th, top - cz], axis=1)
    mid_x = np.interp(h, along, sp @ q.left)
    pts = hips + np.outer(h * L, q.front)
    pts = pts - np.outer(pts @ q.left - mid_x, q.left)
    pts[:, 2] = cz
    a, b = pts[0], pts[-1]
    ts = (h - h[0]) / (h[-1] - h[0])
    girdles = [ch[0] for ch in q.legs.values()] + [ch[1] for ch in q.legs.values()]
    places = frozenset(q.spine) | frozenset(girdles) | frozenset(q.neck[:2]) | frozenset(q.tail[:1])
    piece = _cone(a, b, semi, 0.0, places, ts=ts, hint=q.left, slots=[slots.new() for _ in h],
                  caps=(0.9 * semi[0].mean(), 0.8 * semi[-1].mean()))
    piece = replace(piece, fixed=True)     # a leg near the trunk gives way, not the trunk
    # the rib cage: its top at the back line, reaching down to about the elbows
    h_r, (rl, rw, rd) = RIBS
    c = hips + h_r * L * q.front
    c = c - (c @ q.left - np.interp(h_r, along, sp @ q.left)) * q.left
    c[2] = np.interp(h_r, along, sp[:, 2]) + BACK * L - rd * L * th
    ribs = _ellipsoid(c, np.stack([q.front, q.left, UP]), (rl * L, rw * L * th, rd * L * th), 0.25 * L * o.blend,
                      places, fixed=True)
    return [piece, ribs], _Trunk(a, b, ts, semi, places, c, rl * L, rd * L * th)


def heat_bones(clip: Clip, options: BodyOptions = BodyOptions()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trunk's own bones for bone heat: a keel along the underside of the barrel, KEEL * L above it.

    Returns parents (K,) int (the spine joint each hangs from), starts (K, 3) and ends (K, 3) metres,
    in the rest pose of `clip`; see ``load.auto_weighted(heat_bones=...)``.
    """
    rest = replace(clip, rotations=clip.rest_rotations[None], translations=clip.offsets[None])
    q = _read(rest)
    _, tr = _trunk(q, options, _Slots(SimpleNamespace(node=np.arange(len(q.pos)))))
    lift = KEEL * q.L * options.thickness

    def keel(p):
        c = np.array(p, float)
        mid = tr.centre(tr.at(c))
        c = c - ((c - mid) @ q.left) * q.left
        c[2] = tr.underside(c) + lift
        return c

    fronts = [ch[1] for name, ch in q.legs.items() if name.endswith("front")]
    sternum = keel(q.pos[fronts].mean(axis=0))
    points = [keel(q.pos[j]) for j in q.spine[1:]] + [sternum]
    return np.array(q.spine[1:]), np.array(points[:-1]), np.array(points[1:])


def _pieces(q: _Quad, o: BodyOptions, slots) -> tuple[list, _Trunk]:
    L, th, bl = q.L, o.thickness, o.blend
    P = q.pos
    out, trunk = _trunk(q, o, slots)

    # neck: from the chest to the head joint, deeper than wide, blended wide into the trunk
    c0, hd = q.neck[0], q.neck[-1]
    rn = 0.12 * L * th
    out.append(_cone(P[c0], P[hd], [[rn, 1.3 * rn], [0.75 * rn, 0.95 * rn]], 0.6 * rn * bl, set(q.neck),
                     hint=q.left, slots=(slots.at(c0), slots.at(hd))))
    # head: a skull around the head joint and a muzzle to the tip
    tip = P[q.head_tip]
    d = tip - P[hd]
    span = float(np.linalg.norm(d))
    u = d / span
    sk = 0.125 * L * o.head_size
    skull = _ellipsoid(P[hd] + 0.2 * d, _frame(u, UP)[[0, 2, 1]], (max(0.45 * span, sk), 0.75 * sk, 0.8 * sk),
                       0.5 * rn * bl, {hd, q.head_tip}, fixed=True)
    out.append(skull)
    rm = 0.6 * sk
    out.append(_cone(P[hd] + 0.35 * d, tip - 0.5 * rm * 0.55 * u, [[0.9 * rm, rm], [0.55 * rm, 0.5 * rm]],
                     0.4 * rm * bl, {hd, q.head_tip}, hint=q.left))

    # legs
    for name, ch in q.legs.items():
        front = name.endswith("front")
        bones = list(zip(ch[:-1], ch[1:]))
        if front:   # scapula, upper arm, forearm, pastern, paw bone
            radii = [(0.08, 0.07), (0.07, 0.055), (0.055, 0.034), (0.036, 0.032)]
        else:       # thigh (haunch), gaskin, metatarsus, paw bone
            radii = [(0.11, 0.06), (0.06, 0.032), (0.032, 0.028)]
        for i, (j, c) in enumerate(bones[:-1]):
            r0, r1 = (r * L * th for r in radii[min(i, len(radii) - 1)])
            proximal = i < (2 if front else 1)
            depth = 1.25 if (not front and i == 0) else 1.1     # thighs are deeper (fore-aft) than wide
            k = (0.5 * r0 if proximal else 0.3 * r1) * bl
            out.append(_cone(P[j], P[c], [[r0, depth * r0], [0.5 * (r0 + r1), 0.5 * depth * (r0 + r1)],
                                          [r1, 1.05 * r1]], k, {j, c}, hint=q.left, distal=not proximal,
                             slots=(slots.at(j), slots.new(), slots.at(c))))
        out.append(_paw(q, ch, L * th, bl, slots))

    # tail: tapered cones, the first blended into the rump
    n = len(q.tail) - 1
    for i, (j, c) in enumerate(zip(q.tail[:-1], q.tail[1:])):
        r0 = (0.055 - 0.035 * i / max(n, 1)) * L * th
        r1 = (0.055 - 0.035 * (i + 1) / max(n, 1)) * L * th
        out.append(_cone(P[j], P[c], [r0, r1], (0.6 * r0 if i == 0 else 0.3 * r1) * bl, {j, c}, distal=i > 0,
                         slots=(slots.at(j), slots.at(c))))
    return out, trunk


def _paw(q: _Quad, ch: list[int], s: float, blend: float, slots):
    """A flat ellipsoid around the paw: from behind the paw joint to its tip, resting on the floor."""
    P = q.pos
    toe, tip = ch[-2], ch[-1]
    d = P[tip] - P[toe]
    d[2] = 0.0
    if np.linalg.norm(d) < 1e-6:
        d = q.front.copy()
    length = max(float(np.linalg.norm(d)), 0.06 * s)
    u = d / np.linalg.norm(d)
    hz = max(P[toe, 2] - q.floor, 0.03 * s)
    centre = np.array([*(P[toe, :2] + 0.35 * length * u[:2]), q.floor + hz])
    radii = (0.75 * length + 0.02 * s, 0.055 * s, hz)
    p = _ellipsoid(centre, np.stack([u, np.cross(UP, u), UP]), radii, 0.3 * hz * blend, {ch[-3], toe, tip})
    return replace(p, distal=True, slots=(slots.at(toe),))


def _fat(q: _Quad, tr: _Trunk, o: BodyOptions) -> list[tuple]:
    """Fat ellipsoids (name, joint, centre, radii, axes, places), each pushing the surface out by its
    size at its most prominent point."""
    out = []
    L = q.L
    down = -UP
    axes = np.stack([q.left, q.front, UP])
    if o.belly > 0:   # under the trunk, between the ribs and the flank
        t = tr.at(q.pos[q.spine[0]] + 0.55 * L * q.front)
        w, d = tr.section(t)
        rf = 0.5 * d + o.belly
        joint = min(q.spine[1:-1] or q.spine[:1], key=lambda j: abs(tr.at(q.pos[j]) - t))
        out.append(("belly", joint, tr.centre(t) + (d + o.belly - rf) * down,
                    [0.7 * w + 0.5 * o.belly, 0.3 * L + 0.5 * o.belly, rf], axes, tr.places))
    if o.chest > 0:   # on the breast, below the neck
        t = tr.at(q.pos[q.spine[-1]] + 0.15 * L * q.front)
        w, d = tr.section(t)
        n = _unit(0.5 * q.front - 0.85 * UP)
        rf = 0.45 * d + o.chest
        out.append(("chest", q.spine[-1], tr.centre(t) + (d + o.chest - rf) * n,
                    [0.6 * w + 0.5 * o.chest, rf, 0.18 * L + 0.5 * o.chest], _frame(q.left, n), tr.places))
    if o.glutes > 0:  # on the back and outside of each thigh, below the rump
        for name, ch in q.legs.items():
            if not name.endswith("hind"):
                continue
            a, b = q.pos[ch[0]], q.pos[ch[1]]
            side = 1.0 if (a - q.pos[q.spine[0]]) @ q.left > 0 else -1.0
            n = _unit(0.6 * side * q.left - 0.8 * q.front)
            r = 0.15 * L * o.thickness
            rh = 0.5 * r + o.glutes
            centre = a + 0.3 * (b - a) + (r + o.glutes - rh) * n
            fr = _frame(n, b - a)
            out.append((f"haunch_{'L' if side > 0 else 'R'}", ch[0], centre,
                        [rh, 0.3 * np.linalg.norm(b - a) + 0.5 * o.glutes, 0.1 * L + 0.5 * o.glutes], fr,
                        frozenset({ch[0], ch[1]}) | tr.places))
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)
