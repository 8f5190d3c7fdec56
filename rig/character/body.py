"""A smooth, closed body mesh generated around any skeleton, for clips that come without a character.

The body is the zero level set of an implicit field: a smooth union of simple solids placed along the
bones, polygonised with flying edges (VTK, through PyVista), smoothed with Taubin's lambda|mu filter
(which does not shrink) and put back onto the implicit surface. The result is one closed,
consistently wound, genus-0 surface (Z-up, metres, the skeleton's rest pose); see
:func:`generate_body` for the stages.

Solids. Every piece is an "elliptic round cone" (:class:`_Piece`): a segment whose elliptic
cross-section follows a smooth profile along it, closed by half-ellipsoid caps. With equal circular
ends it is a capsule; with a zero-length segment an ellipsoid. Distances use the ellipsoid estimate
``k0 (k0 - 1) / k1`` (exact for spheres, close near the surface otherwise), which is all the contour
needs. Pieces join by a quadratic smooth minimum whose radius is set per piece (wide at the armpit
and crotch, narrow at finger roots); distal parts are blended last, so that a wide blend never
reaches across to a hand.

Proportions come from the skeleton alone (joint tree, rest pose, bone lengths; no joint names),
using :func:`rig.motion.bone_roles.bone_roles` for the trunk, neck and head:

- stature ``H``: height of the shoulder line above the lowest joint or end site, divided by 0.82 (the
  shoulder's share of an adult's height); the extent of the rest pose when there are no arms or no
  trunk. Sizes that no bone gives (head, neck, hands, feet, minimum radii) are fractions of ``H``.
- trunk: one loft of elliptic sections along the spine's direction from below the hip joints (the
  crotch) to the shoulder line; half-widths from the hip joint spacing (plus the thigh) and the
  shoulder joint spacing, depths a fixed share of the widths. A sloping piece from the top of the
  trunk to each shoulder joint makes the shoulders.
- limbs: legs are limb chains leaving the pelvis (thigh, shin, then the foot), arms are limb chains
  leaving the chest (clavicle bones, then the upper arm, the longest of the first three bones, the
  forearm, then the hand). Radii are proportional to the bone's length with clamps, tapered, with a
  calf and a forearm bulge; a foot is a flat loft from the heel (sole to ankle) to the toes, at least
  0.105 H ahead of the ankle; a hand is a flat ellipsoid along the forearm, at least 0.1 H long.
- head: an ellipsoid above the top of the neck chain, reaching the head's end site when there is one.
- other bones (fingers, toes, tails): thin tapered cones proportional to their length.
- zero-length bones (CMU's joints sitting at their parent) are skipped; their joints share a place.

Facing. "Front" is found from the feet: the horizontal direction perpendicular to the hip axis, with
its sign from the vectors ankle -> farthest toe point (toes point forward in every rest pose we
know). Without feet it falls back to the project's convention: figures face -Y. Left is
``up x front``. The CMU skeleton, the demo skeleton, CesiumMan and humanoid_CMU all face -Y.

Topology. Limbs that hang close to the trunk (the demo's arms hang beside the hips) would touch it
and make a handle. Before polygonising, every pair of pieces that share no joint and of which one is a
distal limb part (forearm, hand, shin, foot and beyond) is kept apart by two voxels plus the later
piece's blend, shrinking both pieces near the contact (:func:`_keep_apart`); the demo's hips and
hands come out slimmer for it. After contouring only the largest connected component is kept.

Fat volumes (belly, chest, glutes, back of the upper arms) are ellipsoids placed on the trunk and arms
as they are after keeping the limbs apart, blended into the field, sized by :class:`BodyOptions` in
metres of extra thickness at their most prominent point, and returned as :class:`FatVolume` records
for the jiggle that later issues simulate on them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import PchipInterpolator
from scipy.sparse.csgraph import connected_components

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.capsules import segment_closest
from jiggle.rig.motion.bone_roles import bone_roles
from jiggle.rig.motion.clip import Clip

UP = np.array([0.0, 0.0, 1.0])
SHOULDER_SHARE = 0.82  # shoulder joint height / stature of an adult
ZERO_BONE = 1e-4       # metres: bones shorter than this are a joint sitting at its parent
TABLE = 49  # samples of a piece's cross-section along its axis
VOXEL_PER_STATURE = 0.9  # voxel ~ this * stature / sqrt(vertex count), for the gap estimate


# ----------------------------------------------------------------------------------------- API
@dataclass(frozen=True)
class BodyOptions:
    """How the body is generated. Lengths are metres.

    resolution : target vertex count of the mesh (10k to 40k is the useful range; the result lands
        within about 15% of it). The voxel size follows from a coarse trial contour.
    thickness : scale of every trunk, neck and limb radius (1 = an average adult build).
    head_size : scale of the head.
    belly : metres the belly fat pushes the front of the lower trunk out (0 = no belly volume).
    chest : metres the chest fat pushes each side of the front of the upper trunk out.
    glutes : metres the glute fat pushes each side of the back of the pelvis out.
    upper_arms : metres the fat on the back of each upper arm adds.
    blend : scale of every smooth-union radius (0 = hard union with creases at the joints).
    smoothing_iterations : Taubin passes (one lambda and one mu step each) after contouring.
    project : after smoothing, put the vertices back on the implicit surface (two Newton steps).
    arm_angle : degrees; an upper arm hanging closer than this to straight down is swung out to it
        in the plane of the body before building (the bind pose, ``Body.bind``), so the arm stands
        clear of the trunk and its weights do not reach into the side; 0 builds in the rest pose.
    """

    resolution: int = 20000
    thickness: float = 1.0
    head_size: float = 1.0
    belly: float = 0.015
    chest: float = 0.01
    glutes: float = 0.015
    upper_arms: float = 0.01
    blend: float = 1.0
    smoothing_iterations: int = 10
    project: bool = True
    arm_angle: float = 40.0


@dataclass(frozen=True)
class FatVolume:
    """A blob of fat blended into the body, for the fat jiggle simulated later.

    name : "belly", "chest_L", "chest_R", "glute_L", "glute_R", "upper_arm_L" or "upper_arm_R".
    joint : index of the clip joint whose frame it rides (the bone through it leaves that joint).
    center : (3,) float64, metres, rest-pose world position.
    radii : (3,) float64, metres, ellipsoid semi-axes.
    axes : (3, 3) float64, rows are the ellipsoid's unit axes in world (radii[i] along axes[i]).
    """

    name: str
    joint: int
    center: np.ndarray
    radii: np.ndarray
    axes: np.ndarray


@dataclass(frozen=True)
class Body:
    """A generated body. Arrays are read-only.

    vertices : (V, 3) float64, metres, Z-up, the skeleton's rest pose.
    faces : (F, 3) int32, counter-clockwise seen from outside (outward normals).
    fat : the fat volumes blended into it (those with a size above zero).
    joint_positions : (J, 3) float64, metres, the rest-pose world joint positions it was built on.
    front : (3,) unit vector, the direction the body faces (see the module docstring).
    stature : metres, the stature estimate all unspecified sizes are fractions of.
    voxel : metres, the grid spacing the surface was contoured at.
    timings : seconds per stage ("field", "contour", "cleanup", "smoothing", ...).
    bind : one-frame Clip of the pose the body was built in (the rest pose, with hanging arms swung
        out to ``BodyOptions.arm_angle``); skin it from this pose.
    """

    vertices: np.ndarray
    faces: np.ndarray
    fat: tuple[FatVolume, ...]
    joint_positions: np.ndarray
    front: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    stature: float = 0.0
    voxel: float = 0.0
    timings: dict = field(default_factory=dict)
    bind: Clip | None = None


def generate_body(clip: Clip, options: BodyOptions = BodyOptions()) -> Body:
    """A smooth, watertight, genus-0 body around the clip's rest-pose skeleton.

    Stages (seconds in ``body.timings``): layout of the solids, a coarse trial contour that sets the
    voxel size for the requested vertex count, the field on the grid, the contour, cleanup (largest
    component, outward faces), smoothing (Taubin, then a projection back onto the implicit surface).
    """
    t0 = time.perf_counter()
    clip = bind_pose(clip, options.arm_angle)
    pieces, sk = layout(clip, options)
    timings = {"layout": time.perf_counter() - t0}
    pieces, v, f, h = surface(pieces, sk.stature / 45.0, options, timings)
    timings["total"] = time.perf_counter() - t0
    return Body(vertices=frozen_array(v), faces=frozen_array(f, np.int32), fat=tuple(_fat_records(pieces)),
                joint_positions=frozen_array(sk.pos[:sk.J]), front=frozen_array(sk.front),
                stature=float(sk.stature), voxel=float(h), timings=timings, bind=clip)


def surface(pieces: list, h0: float, options: BodyOptions, timings: dict) -> tuple[list, np.ndarray, np.ndarray, float]:
    """The closed surface of `pieces`: (pieces at least a voxel thick, vertices (V, 3), faces (F, 3),
    voxel h metres). A coarse trial at voxel `h0` sets the voxel for options.resolution vertices
    (marching cubes gives vertices in proportion to area / voxel^2); then contour, keep the largest
    component facing out, smooth, and put back on the implicit surface. Stage seconds go to `timings`."""
    t = time.perf_counter()
    v0, _ = _polygonise(at_least_voxel(pieces, h0), h0)
    h = h0 * np.sqrt(len(v0) / max(int(options.resolution), 100))
    timings["trial"] = time.perf_counter() - t

    pieces = at_least_voxel(pieces, h)
    t = time.perf_counter()
    grid = grid_around(pieces, h)
    values = evaluate_field(pieces, grid)
    timings["field"] = time.perf_counter() - t
    t = time.perf_counter()
    v, f = contour(values, grid)
    timings["contour"] = time.perf_counter() - t
    t = time.perf_counter()
    v, f = largest_component(v, f)
    f = outward(v, f)
    timings["cleanup"] = time.perf_counter() - t
    t = time.perf_counter()
    v = taubin_smooth(v, f, options.smoothing_iterations)
    # Umbrella smoothing evens out the marching-cubes triangles but draws faint ripples where their
    # pattern is regular (slanted limbs); putting the vertices back on the smooth implicit surface
    # keeps the even triangles and drops the ripples.
    if options.project:
        v = project_to_surface(pieces, v, h)
    timings["smoothing"] = time.perf_counter() - t
    return pieces, v, f, h


def bind_pose(clip: Clip, arm_angle: float = 40.0) -> Clip:
    """A one-frame clip of the rest pose with every upper arm that hangs within `arm_angle` degrees
    of straight down swung out sideways (about the body's front axis) to that angle."""
    from jiggle.rig.motion import quat
    rest = replace(clip, rotations=clip.rest_rotations[None], translations=clip.offsets[None])
    if arm_angle <= 0:
        return rest
    sk = _analyse(rest)
    world_r, _ = rest.rest_world()
    local = rest.rest_rotations.copy()
    changed = False
    for ch in sk.chains:
        if ch.kind != "arm":
            continue
        u, tip = _upper_arm(sk, ch)
        d = sk.pos[tip] - sk.pos[u]
        d /= np.linalg.norm(d)
        hang = np.degrees(np.arccos(np.clip(-d @ UP, -1.0, 1.0)))
        if hang >= arm_angle:
            continue
        side = np.sign((sk.pos[u] - sk.pos[sk.spine[-1]]) @ sk.left) if sk.spine else 1.0
        turn = np.radians(arm_angle - hang)
        # the sign that moves the hand away from the body's mid-plane
        best = max((quat.from_axis_angle(sk.front, a) for a in (turn, -turn)),
                   key=lambda q: side * (quat.rotate(q, d) @ sk.left))
        new_world = quat.mul(best, world_r[u])
        p = clip.parents[u]
        local[u] = quat.mul(quat.conj(world_r[p]), new_world) if p >= 0 else new_world
        changed = True
    if not changed:
        return rest
    local = quat.canonical(local)
    return replace(rest, rest_rotations=local, rotations=local[None],
                   meta={**rest.meta, "bind_pose": f"arms swung out to {arm_angle:g} deg"})


def layout(clip: Clip, options: BodyOptions = BodyOptions()) -> tuple[list, "_Skeleton"]:
    """The solids of the body in blending order (see :func:`evaluate_field`), sized and kept apart,
    and the skeleton as read for them (positions, facing, stature)."""
    sk = _analyse(clip)
    # the gap kept between parts that must not touch: the smooth union's reach plus two voxels
    # (voxel estimate for the requested vertex count, calibrated on human proportions)
    h_est = VOXEL_PER_STATURE * sk.stature / np.sqrt(max(int(options.resolution), 100))
    pieces, trunk = _pieces(sk, options)
    pieces = _keep_apart(pieces, gap=2.0 * h_est)
    if trunk is not None:  # fat goes on the trunk as it is after keeping the arms clear
        trunk = replace(trunk, piece=pieces[0])
        fat = [_ellipsoid(c, axes, radii, 0.8 * min(radii) * options.blend, places, tag=(name, joint))
               for name, joint, c, radii, axes, places in _fat(sk, trunk, options)]
        pieces = _keep_apart(_blend_order(pieces + fat), gap=2.0 * h_est)
    return pieces, sk


# ------------------------------------------------------------------------------- the skeleton
@dataclass
class _Chain:
    """A limb chain leaving the trunk. bones: (joint, tip point) pairs of non-zero length along its
    main path, proximal first; kind "arm", "leg" or "other"."""

    kind: str
    bones: list[tuple[int, int]]


@dataclass
class _Skeleton:
    """The rest pose read for body building.

    pos : (J + E, 3) joint then end-site world positions. node : (J + E,) the point's place (the first
    joint of a chain of zero-length bones). bones : (joint, tip point, role) of non-zero length.
    """

    J: int
    pos: np.ndarray
    node: np.ndarray
    bones: list[tuple[int, int, str]]
    tips: list[list[int]]           # per point, the tip points of its non-zero bones
    spine: list[int]                # joints from the root to the chest (zero-length ones included)
    hips: list[int]                 # leg chain start joints
    chains: list[_Chain]
    neck: list[tuple[int, int]]     # neck bones (joint, tip)
    head: tuple[int, int] | None    # head bone (joint, tip point)
    front: np.ndarray
    left: np.ndarray
    stature: float
    children: list[list[int]]       # per point, every child point (zero-length bones included)

    def length(self, a: int, b: int) -> float:
        return float(np.linalg.norm(self.pos[b] - self.pos[a]))

    def subtree(self, p: int) -> list[int]:
        """Points below point p (p included), following non-zero and zero-length bones."""
        out, stack = [], [p]
        while stack:
            q = stack.pop()
            out.append(q)
            stack += self.children[q]
        return out


def _analyse(clip: Clip) -> _Skeleton:
    """Positions, places, roles, limb chains, facing and stature of the clip's rest skeleton."""
    J = clip.num_joints
    rot, jpos = clip.rest_world()
    epos = clip.end_world(rot[None], jpos[None])[0] if len(clip.end_parents) else np.zeros((0, 3))
    pos = np.concatenate([jpos, epos])
    parent = np.concatenate([clip.parents, clip.end_parents]).astype(int)
    roles = bone_roles(clip)
    extent = float(np.ptp(pos, axis=0).max()) or 1.0
    eps = max(ZERO_BONE, 1e-4 * extent)

    node = np.arange(len(pos))
    tips_all = [[] for _ in pos]
    for p in range(len(pos)):  # parents come before children; end sites after all joints
        if parent[p] >= 0:
            tips_all[parent[p]].append(p)
            if np.linalg.norm(pos[p] - pos[parent[p]]) < eps:
                node[p] = node[parent[p]]
    bones, tips = [], [[] for _ in pos]
    for j in range(J):
        kids = clip.children(j) + [J + e for e in np.nonzero(clip.end_parents == j)[0]]
        for k, c in enumerate(kids):
            if node[c] != node[j]:
                bones.append((j, c, roles[j][k]))
                tips[j].append(c)

    trunk = [(j, c) for j, c, r in bones if r == "trunk"]
    neck = [(j, c) for j, c, r in bones if r == "neck"]
    heads = [(j, c) for j, c, r in bones if r == "head"]
    head = heads[0] if heads else None
    chest = neck[0][0] if neck else (head[0] if head else None)
    spine = []
    if chest is not None and trunk:
        j = chest
        while j >= 0:
            spine.append(j)
            j = int(parent[j])
        spine = spine[::-1]
    on_spine = {node[j] for j in spine}
    hips = [c for j, c in trunk if node[c] not in on_spine]

    sk = _Skeleton(J=J, pos=pos, node=node, bones=bones, tips=tips, spine=spine, hips=hips,
                   chains=[], neck=neck, head=head, front=np.array([0.0, -1.0, 0.0]),
                   left=np.array([1.0, 0.0, 0.0]), stature=extent, children=tips_all)
    limb_roles = {(j, c) for j, c, r in bones if r == "limb"}
    chest_node = node[chest] if chest is not None else -1
    trunk_nodes = on_spine | {node[h] for h in hips}
    for j, c, r in bones:
        if r != "limb" or node[j] not in trunk_nodes:
            continue
        path = _main_path(sk, j, c, limb_roles)
        if node[j] == chest_node:
            kind = "arm"
        elif pos[path[-1][1], 2] < pos[j, 2] - 0.3 * sum(sk.length(a, b) for a, b in path):
            kind = "leg"
        else:
            kind = "other"
        sk.chains.append(_Chain(kind, path))
    _facing(sk)
    _stature(sk)
    return sk


def _main_path(sk: _Skeleton, j: int, c: int, limb: set) -> list[tuple[int, int]]:
    """Bones from (j, c) on, following at each joint the branch holding the most points."""
    path = [(j, c)]
    while sk.tips[c]:
        nxt = max(sk.tips[c], key=lambda t: len(sk.subtree(t)))
        if (c, nxt) not in limb:
            break
        path.append((c, nxt))
        c = nxt
    return path


def _facing(sk: _Skeleton) -> None:
    """Front and left directions (unit, horizontal): see the module docstring."""
    legs = [ch for ch in sk.chains if ch.kind == "leg"]
    arms = [ch for ch in sk.chains if ch.kind == "arm"]
    if len(legs) >= 2:
        across = sk.pos[legs[0].bones[0][0]] - sk.pos[legs[1].bones[0][0]]
    elif len(arms) >= 2:
        across = sk.pos[arms[0].bones[0][1]] - sk.pos[arms[1].bones[0][1]]
    else:
        return
    across = across - across @ UP * UP
    if np.linalg.norm(across) < 1e-9:
        return
    front = np.cross(across, UP)
    front /= np.linalg.norm(front)
    toes = np.zeros(3)
    for ch in legs:
        if len(ch.bones) >= 3:
            ankle = ch.bones[1][1]
            far = max(sk.subtree(ankle), key=lambda p: np.linalg.norm(sk.pos[p] - sk.pos[ankle]))
            toes += sk.pos[far] - sk.pos[ankle]
    if abs(toes @ front) < 1e-9:
        toes = np.array([0.0, -1.0, 0.0])  # no feet: the project's convention
    sk.front = front * np.sign(toes @ front)
    sk.left = np.cross(UP, sk.front)


def _stature(sk: _Skeleton) -> None:
    """Stature estimate from the shoulder line's height over the lowest point (module docstring)."""
    arms = [ch for ch in sk.chains if ch.kind == "arm"]
    floor = sk.pos[:, 2].min()
    if arms and sk.spine:
        shoulder = np.mean([sk.pos[_upper_arm(sk, ch)[0], 2] for ch in arms])
        if shoulder > floor:
            sk.stature = float((shoulder - floor) / SHOULDER_SHARE)
            return
    sk.stature = float(np.ptp(sk.pos, axis=0).max())


def _upper_arm(sk: _Skeleton, ch: _Chain) -> tuple[int, int]:
    """The upper arm bone: the longest of the first three bones of an arm chain."""
    return max(ch.bones[:3], key=lambda b: sk.length(*b))


def _wrist(sk: _Skeleton, ch: _Chain) -> int:
    """The wrist: the tip of the bone after the upper arm (the forearm), or of the upper arm."""
    u = ch.bones.index(_upper_arm(sk, ch))
    return ch.bones[min(u + 1, len(ch.bones) - 1)][1]


# ------------------------------------------------------------------------------------ pieces
@dataclass
class _Piece:
    """An elliptic round cone (see the module docstring). All lengths metres.

    a, b : (3,) segment ends (equal for an ellipsoid). frame : (3, 3) rows e0 (a -> b), e1, e2.
    ts : (n,) stations along a -> b, 0 to 1 (one station for an ellipsoid).
    semi : (n, 2) cross-section semi-axes along e1, e2 at each station; between stations a monotone
        cubic (PCHIP) when `smooth`, else straight lines.
    ca, cb : semi-axes of the end caps along e0.
    k : smooth-union radius with what is already there.
    places : skeleton places (nodes) it covers; pieces sharing one may touch.
    distal : a forearm, hand, shin, foot or beyond: kept apart from pieces it shares no place with.
    fixed : never shrunk by :func:`_keep_apart` (the head).
    slots : (n,) index of the size factor of each station (shared where pieces meet at a joint;
        -1: its own).
    tag : (name, joint) for a fat volume, else None.
    """

    a: np.ndarray
    b: np.ndarray
    frame: np.ndarray
    ts: np.ndarray
    semi: np.ndarray
    ca: float
    cb: float
    k: float
    places: frozenset
    distal: bool = False
    fixed: bool = False
    slots: tuple = ()
    smooth: bool = False
    tag: tuple | None = None
    table: np.ndarray = field(init=False, repr=False)  # (TABLE, 2) semi-axes at even parameters

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.b - self.a))

    def __post_init__(self):
        # semi-axes sampled at TABLE evenly spaced parameters, for fast interpolation
        tt = np.linspace(0.0, 1.0, TABLE)
        if len(self.ts) == 1:
            self.table = np.repeat(self.semi[:1], TABLE, axis=0)
        elif self.smooth and len(self.ts) > 2:
            self.table = PchipInterpolator(self.ts, self.semi, axis=0)(tt)
        else:
            self.table = np.stack([np.interp(tt, self.ts, self.semi[:, i]) for i in range(2)], axis=1)

    def sections(self, t):
        """Semi-axes (s1, s2) at parameters t (any shape, 0..1), metres."""
        return _lookup(self.table, t)


def _lookup(table: np.ndarray, t):
    """Linear interpolation in a (TABLE, 2) table sampled at evenly spaced parameters 0..1 at
    parameters t (any shape); returns the two columns, each shaped like t."""
    x = np.clip(np.asarray(t), 0.0, 1.0) * (TABLE - 1)
    i = np.minimum(x.astype(np.int64), TABLE - 2)
    w = (x - i)[..., None]
    v = table[i] * (1 - w) + table[i + 1] * w
    return v[..., 0], v[..., 1]


def _frame(axis: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """(3, 3) rows: unit axis, the unit part of `hint` across it, and their cross product."""
    e0 = axis / np.linalg.norm(axis)
    e1 = hint - hint @ e0 * e0
    if np.linalg.norm(e1) < 1e-3 * max(np.linalg.norm(hint), 1e-12):
        e1 = np.cross(e0, [1.0, 0.0, 0.0] if abs(e0[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 = e1 / np.linalg.norm(e1)
    return np.stack([e0, e1, np.cross(e0, e1)])


def _cone(a, b, radii, k, places, *, ts=None, hint=None, distal=False, slots=None, caps=None,
          smooth=True) -> _Piece:
    """A round cone from a to b. radii : (n,) radii or (n, 2) elliptic semi-axes along (hint,
    axis x hint) at stations ts (default evenly spread from a to b); caps default to the end radii."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    semi = np.asarray(radii, float)
    semi = np.repeat(semi[:, None], 2, axis=1) if semi.ndim == 1 else semi
    n = len(semi)
    ts = np.linspace(0.0, 1.0, n) if ts is None else np.asarray(ts, float)
    fr = _frame(b - a if np.linalg.norm(b - a) > 0 else UP, UP if hint is None else np.asarray(hint, float))
    ca, cb = (float(semi[0].min()), float(semi[-1].min())) if caps is None else caps
    return _Piece(a, b, fr, ts, semi, ca, cb, float(k), frozenset(places), distal, False,
                  tuple([-1] * n if slots is None else slots), smooth)


def _ellipsoid(center, axes, radii, k, places, fixed=False, tag=None) -> _Piece:
    """An ellipsoid: semi-axis radii[i] along the unit row axes[i]."""
    c = np.asarray(center, float)
    return _Piece(c, c.copy(), np.asarray(axes, float), np.zeros(1), np.array([radii[1:]], float),
                  float(radii[0]), float(radii[0]), float(k), frozenset(places), False, fixed, (-1,), tag=tag)


class _Slots:
    """Size-factor slots: one per skeleton place (shared by the pieces meeting there), or new ones."""

    def __init__(self, sk: _Skeleton):
        self.sk, self.count, self.by_node = sk, 0, {}

    def new(self) -> int:
        self.count += 1
        return self.count - 1

    def at(self, p: int) -> int:
        n = int(self.sk.node[p])
        if n not in self.by_node:
            self.by_node[n] = self.new()
        return self.by_node[n]


def _pieces(sk: _Skeleton, o: BodyOptions) -> tuple[list[_Piece], "_Trunk | None"]:
    """The solids of the body but the fat, in blending order (trunk first), and the trunk."""
    H, th = sk.stature, o.thickness
    slots = _Slots(sk)
    pieces: list[_Piece] = []
    covered = set()
    legs = [ch for ch in sk.chains if ch.kind == "leg"]
    arms = [ch for ch in sk.chains if ch.kind == "arm"]
    trunk = _trunk(sk, legs, arms, th, o.blend, slots) if sk.spine else None
    if trunk is not None:
        pieces.append(trunk.piece)
        covered.update((j, c) for j, c, r in sk.bones if r == "trunk")

    r_neck = 0.032 * H * th
    if sk.head is not None:
        head, base = _head(sk, o, r_neck)
        if sk.neck:
            j0 = sk.neck[0][0]
            pieces.append(_cone(sk.pos[j0], sk.pos[base], [r_neck, r_neck], 0.5 * r_neck * o.blend,
                                {sk.node[j] for j, _ in sk.neck} | {sk.node[base]},
                                slots=(slots.at(j0), slots.at(base))))
        pieces.append(head)
        covered.update(sk.neck + [sk.head])

    for ch in sk.chains:
        if ch.kind in ("leg", "arm"):
            if ch.kind == "leg":
                more, done = _leg(sk, ch, th, o.blend, slots)
            else:
                more, done = _arm(sk, ch, th, o.blend, slots, trunk)
            pieces += more
            covered.update(done)

    # everything else: fingers, toes, tails, bones beyond the head, skeletons without a trunk
    first = {ch.bones[0] for ch in sk.chains}
    hands = {p for ch in arms for p in sk.subtree(_wrist(sk, ch))}
    for j, c, r in sk.bones:
        if (j, c) in covered:
            continue
        L = sk.length(j, c)
        if j in hands:  # fingers and thumbs: thin, inside the hand's ellipsoid but for their tips
            ra = float(np.clip(0.15 * L, 0.005 * H, 0.009 * H)) * th
        else:
            ra = float(np.clip(0.18 * L, 0.006 * H, 0.04 * H)) * th
        distal = not (r == "trunk" or (j, c) in first)
        pieces.append(_cone(sk.pos[j], sk.pos[c], [ra, 0.8 * ra], 0.5 * 0.8 * ra * o.blend,
                            {sk.node[j], sk.node[c]}, distal=distal, slots=(slots.at(j), slots.at(c))))

    return _blend_order(pieces), trunk


def _blend_order(pieces: list[_Piece]) -> list[_Piece]:
    """Trunk first, then the other proximal pieces, fat, and distal parts last: a wide blend (thigh
    into the hips, fat) applied after a hand is in the field would reach across to the hand; the
    distal parts' own blends are narrow."""
    return sorted(pieces, key=lambda p: 2 if p.distal else (1 if p.tag else 0))


def _fat_records(pieces: list[_Piece]) -> list[FatVolume]:
    """FatVolume records of the fat pieces (after any shrinking)."""
    return [FatVolume(p.tag[0], int(p.tag[1]), frozen_array(p.a), frozen_array([p.ca, *p.semi[0]]),
                      frozen_array(p.frame)) for p in pieces if p.tag is not None]


@dataclass
class _Trunk:
    piece: _Piece
    hip: np.ndarray         # (3,) centre of the trunk at the hip line
    axis: np.ndarray        # (3,) unit, hip line towards shoulder line
    length: float           # hip line to shoulder line, metres
    heights: np.ndarray     # (n,) station heights above the hip line, metres

    def centre(self, height: float) -> np.ndarray:
        return self.hip + height * self.axis

    def section(self, height: float) -> tuple[float, float]:
        """(half-width, half-depth) at a height above the hip line."""
        lo, hi = self.heights[0], self.heights[-1]
        w, d = self.piece.sections(np.clip((height - lo) / (hi - lo), 0, 1))
        return float(w), float(d)


def _trunk(sk: _Skeleton, legs, arms, th: float, blend: float, slots: _Slots) -> _Trunk:
    """The trunk: one smooth elliptic loft along the spine, from below the hip joints to the shoulder
    line (see the module docstring)."""
    H = sk.stature
    spine = sk.pos[sk.spine]
    hip_pts = np.array([sk.pos[ch.bones[0][0]] for ch in legs]) if legs else spine[:1]
    sh_pts = np.array([sk.pos[_upper_arm(sk, ch)[0]] for ch in arms]) if arms else spine[-1:]
    hip, shoulder = hip_pts.mean(0), sh_pts.mean(0)
    a_h = 0.5 * np.ptp(hip_pts @ sk.left) if len(legs) >= 2 else 0.05 * H
    a_s = 0.5 * np.ptp(sh_pts @ sk.left) if len(arms) >= 2 else 2.0 * a_h
    r_thigh = np.mean([_thigh_radius(sk, ch) for ch in legs]) * th if legs else 0.05 * H * th

    # axis: the spine's direction (root to chest), through the mean of the hip, spine and shoulder
    # points; heights measured from the hip line
    axis = spine[-1] - spine[0] if np.linalg.norm(spine[-1] - spine[0]) > 0.05 * H else UP
    axis = axis / np.linalg.norm(axis)
    pts = np.concatenate([[hip], spine, [shoulder]])
    mid = pts.mean(0)
    hip_c = mid + ((hip - mid) @ axis) * axis
    T = max(float((shoulder - hip) @ axis), 0.15 * H)

    W_h = (a_h + 0.95 * r_thigh) if legs else 0.85 * a_s * th
    W_c = max(0.88 * a_s * th, 0.9 * W_h)
    # (height as a share of the hip-to-shoulder length, half-width, half-depth)
    sections = np.array([
        [-0.13, min(0.62 * W_h, 0.6 * a_h), 0.50 * W_h],  # the crotch, narrower than the thighs' gap
        [0.00, 1.00 * W_h, 0.63 * W_h],
        [0.38, 0.84 * W_h, 0.56 * W_h],
        [0.70, W_c, 0.68 * W_c],
        [0.86, 0.93 * W_c, 0.62 * W_c],
        [1.00, 0.60 * W_c, 0.45 * W_c],
    ])
    heights = sections[:, 0] * T
    a, b = hip_c + heights[0] * axis, hip_c + heights[-1] * axis
    ts = (heights - heights[0]) / (heights[-1] - heights[0])
    places = frozenset(sk.node[j] for j in sk.spine) | {sk.node[j] for j in sk.hips}
    places |= {sk.node[_upper_arm(sk, ch)[0]] for ch in arms}
    piece = _cone(a, b, sections[:, 1:], 0.0, places, ts=ts, hint=sk.left,
                  slots=[slots.new() for _ in sections], caps=(0.6 * sections[0, 2], 0.4 * sections[-1, 2]))
    return _Trunk(piece, hip_c, axis, T, heights)


def _thigh_radius(sk: _Skeleton, ch: _Chain) -> float:
    """Thigh radius at the hip, metres (before the thickness option): 0.2 of the thigh's length."""
    return float(np.clip(0.20 * sk.length(*ch.bones[0]), 0.012 * sk.stature, 0.07 * sk.stature))


def _leg(sk, ch: _Chain, th, blend, slots: _Slots) -> tuple[list[_Piece], set]:
    """Thigh, shin with a calf bulge, then the foot: a flat loft from the heel to the toes. Returns
    the pieces and the bones they stand for."""
    H = sk.stature
    (j0, c0) = ch.bones[0]
    L = sk.length(j0, c0)
    r_hip = _thigh_radius(sk, ch) * th
    r_mid = np.clip(0.16 * L, 0.011 * H, 0.06 * H) * th
    r_knee = np.clip(0.12 * L, 0.01 * H, 0.045 * H) * th
    out = [_cone(sk.pos[j0], sk.pos[c0], [r_hip, r_mid, r_knee], 0.5 * r_hip * blend, {sk.node[j0], sk.node[c0]},
                 ts=[0, 0.45, 1], slots=(slots.at(j0), slots.new(), slots.at(c0)))]
    if len(ch.bones) < 2:
        return out, {ch.bones[0]}
    j1, c1 = ch.bones[1]
    L = sk.length(j1, c1)
    r_knee2 = min(r_knee, np.clip(0.125 * L, 0.01 * H, 0.045 * H) * th)
    r_calf = np.clip(0.135 * L, 0.01 * H, 0.05 * H) * th
    r_ankle = np.clip(0.08 * L, 0.008 * H, 0.03 * H) * th
    out.append(_cone(sk.pos[j1], sk.pos[c1], [r_knee2, r_calf, r_ankle], 0.15 * r_knee2 * blend,
                     {sk.node[j1], sk.node[c1]}, ts=[0, 0.3, 1], distal=True,
                     slots=(slots.at(j1), slots.new(), slots.at(c1))))
    ankle = c1
    foot = _bones_below(sk, ankle)
    # foot: a flat loft from the heel (from the sole up to the ankle) to the toe tip, the toes
    # reaching at least 0.105 of the stature ahead of the ankle (CesiumMan's bones stop at the ball
    # of the foot); thin cones along the foot's bones keep its joints inside
    fw, fh = 0.026 * H * th, 0.012 * H * th
    A = sk.pos[ankle]
    pts = [ankle] + [c for _, c in foot]
    sole = min(A[2] - 1.3 * r_ankle, min(sk.pos[p, 2] for p in pts) - 0.8 * fh)
    tip = max(pts, key=lambda p: (sk.pos[p] - A) @ sk.front)
    reach = max((sk.pos[tip] - A) @ sk.front + 0.5 * fh, 0.105 * H)
    toe = sk.pos[tip] + (reach - (sk.pos[tip] - A) @ sk.front) * sk.front
    toe[2] = sole + 0.9 * fh
    half = 0.5 * (A[2] - sole)
    heel = A - 0.6 * half * sk.front
    heel[2] = sole + half
    out.append(_cone(heel, toe, [[0.7 * fw, half], [0.85 * fw, 0.8 * half], [fw, 1.3 * fh], [0.8 * fw, 0.9 * fh]],
                     0.5 * r_ankle * blend, {sk.node[p] for p in pts}, ts=[0, 0.3, 0.7, 1], hint=sk.left,
                     distal=True, slots=(slots.at(ankle), slots.new(), slots.new(), slots.new()),
                     caps=(max(0.7 * half, 0.5 * fw), 0.9 * fh)))
    for j, c in foot:
        out.append(_cone(sk.pos[j], sk.pos[c], [[0.7 * fw, fh], [0.6 * fw, 0.8 * fh]], 0.3 * fh * blend,
                         {sk.node[j], sk.node[c]}, hint=sk.left, distal=True, slots=(slots.at(j), slots.at(c))))
    return out, set(ch.bones[:2]) | set(foot)


def _bones_below(sk: _Skeleton, p: int) -> list[tuple[int, int]]:
    """Non-zero bones in the subtree of point p."""
    return [(j, c) for j in sk.subtree(p) for c in sk.tips[j]]


def _arm(sk, ch: _Chain, th, blend, slots: _Slots, trunk=None) -> tuple[list[_Piece], set]:
    """Clavicle bones, upper arm, forearm with a bulge near the elbow, and a flat hand. Returns the
    pieces and the bones they stand for (finger bones are left to thin cones)."""
    H = sk.stature
    out = []
    u = ch.bones.index(_upper_arm(sk, ch))
    ju, cu = ch.bones[u]
    L = sk.length(ju, cu)
    r_sh, r_mid, r_el = (np.clip(f * L, 0.01 * H, 0.045 * H) * th for f in (0.17, 0.16, 0.125))
    if u > 0 and trunk is not None:
        # the shoulder slope: from the top of the trunk's axis to the shoulder joint (the clavicle
        # bones may start low on the chest and would draw a ridge across it)
        top = trunk.centre(trunk.length - 0.2 * r_sh)
        out.append(_cone(top, sk.pos[ju], [0.7 * r_sh, 0.85 * r_sh], r_sh * blend,
                         {sk.node[j] for j, _ in ch.bones[:u + 1]}, slots=(slots.new(), slots.at(ju))))
    else:
        for j, c in ch.bones[:u]:
            r = 0.85 * r_sh
            out.append(_cone(sk.pos[j], sk.pos[c], [r, r], 0.6 * r * blend, {sk.node[j], sk.node[c]},
                             slots=(slots.at(j), slots.at(c))))
    out.append(_cone(sk.pos[ju], sk.pos[cu], [r_sh, r_mid, r_el], 0.6 * r_sh * blend, {sk.node[ju], sk.node[cu]},
                     ts=[0, 0.4, 1], slots=(slots.at(ju), slots.new(), slots.at(cu))))
    wrist, direction, r_wrist = cu, sk.pos[cu] - sk.pos[ju], r_el
    if u + 1 < len(ch.bones):
        jf, cf = ch.bones[u + 1]
        Lf = sk.length(jf, cf)
        r_el2 = min(r_el, np.clip(0.135 * Lf, 0.008 * H, 0.04 * H) * th)
        r_fmid = np.clip(0.15 * Lf, 0.008 * H, 0.04 * H) * th
        r_wrist = np.clip(0.10 * Lf, 0.006 * H, 0.025 * H) * th
        out.append(_cone(sk.pos[jf], sk.pos[cf], [r_el2, r_fmid, r_wrist], 0.15 * r_el2 * blend,
                         {sk.node[jf], sk.node[cf]}, ts=[0, 0.3, 1], distal=True,
                         slots=(slots.at(jf), slots.new(), slots.at(cf))))
        wrist, direction = cf, sk.pos[cf] - sk.pos[jf]
    out.append(_hand(sk, wrist, direction, r_wrist, blend))
    return out, set(ch.bones[:u + 2])


def _hand(sk, wrist: int, direction: np.ndarray, r_wrist: float, blend: float) -> _Piece:
    """A flat ellipsoid from the wrist along the forearm, the palm's width across the front direction
    (palms down in a T-pose, facing the thighs when the arms hang), as long as the hand's bones reach
    and at least 0.1 of the stature (CMU's hand bones stop short of the finger tips)."""
    H = sk.stature
    d = direction / np.linalg.norm(direction)
    reach = max((sk.pos[p] - sk.pos[wrist]) @ d for p in sk.subtree(wrist))
    length = max(reach + 0.01 * H, 0.1 * H)
    fr = _frame(d, sk.front if abs(sk.front @ d) < 0.9 else sk.left)
    radii = (0.5 * length, 0.22 * length, max(0.08 * length, 0.55 * r_wrist))
    p = _ellipsoid(sk.pos[wrist] + 0.45 * length * d, fr, radii, 0.6 * r_wrist * blend,
                   {sk.node[q] for q in sk.subtree(wrist)})
    return replace(p, distal=True)


def _head(sk: _Skeleton, o: BodyOptions, r_neck: float) -> tuple[_Piece, int]:
    """The head ellipsoid and the point at its base (the top of the neck). The head reaches from
    the base up by the head bone's length when it ends at an end site (clamped to 0.06..0.12 of the
    stature), else by 0.09 of the stature; it faces front."""
    H = sk.stature
    j, c = sk.head
    leaf = c < sk.J and not sk.tips[c]
    base = c if leaf else j
    span = 0.09 * H if leaf else float(np.clip(sk.length(j, c), 0.06 * H, 0.12 * H))
    top = sk.pos[base] + span * UP
    sh = float(np.clip(0.55 * span, 0.06 * H, 0.07 * H)) * o.head_size
    # half way towards the end site across (humanoid_CMU's points at the face), and the face forward
    across = 0.0 if leaf else 0.5 * ((sk.pos[c] - sk.pos[base]) - (sk.pos[c] - sk.pos[base]) @ UP * UP)
    centre = top - sh * UP + across + 0.08 * sh * sk.front
    axes = np.stack([UP, sk.left, sk.front])
    piece = _ellipsoid(centre, axes, (sh, 0.68 * sh, 0.85 * sh), 0.6 * r_neck * o.blend,
                       {sk.node[j], sk.node[c]}, fixed=True)
    return piece, base


def _fat(sk: _Skeleton, tr: _Trunk, o: BodyOptions) -> list[tuple]:
    """Fat ellipsoids (name, joint, centre, radii, axes, places), each pushing the surface out by its
    size at its most prominent point (its centre sits inside the body, its outer tip that far out)."""
    out = []
    fr, lf, T = sk.front, sk.left, tr.length
    axes = np.stack([lf, fr, np.cross(lf, fr)])
    places = tr.piece.places

    def spine_joint(height: float) -> int:
        """The spine joint whose bone passes through this height above the hip line."""
        below = [j for j in sk.spine if (sk.pos[j] - tr.hip) @ tr.axis <= height]
        return below[-1] if below else sk.spine[0]

    if o.belly > 0:
        h = 0.28 * T
        w, d = tr.section(h)
        rf = 0.5 * d + o.belly
        out.append(("belly", spine_joint(h), tr.centre(h) + (d + o.belly - rf) * fr,
                    [0.75 * w + 0.5 * o.belly, rf, 0.22 * T + 0.5 * o.belly], axes, places))
    if o.chest > 0:
        h = 0.68 * T
        w, d = tr.section(h)
        rf = 0.45 * d + o.chest
        front = d * np.sqrt(1 - 0.45 ** 2)
        for side, sign in (("L", 1), ("R", -1)):
            out.append((f"chest_{side}", spine_joint(h), tr.centre(h) + sign * 0.45 * w * lf + (front + o.chest - rf) * fr,
                        [0.35 * w + 0.5 * o.chest, rf, 0.16 * T + 0.5 * o.chest], axes, places))
    if o.glutes > 0:
        h = 0.0
        w, d = tr.section(h)
        rb = 0.5 * d + o.glutes
        back = d * np.sqrt(1 - 0.45 ** 2)
        for side, sign in (("L", 1), ("R", -1)):
            out.append((f"glute_{side}", sk.spine[0], tr.centre(h) + sign * 0.45 * w * lf - (back + o.glutes - rb) * fr,
                        [0.38 * w + 0.5 * o.glutes, rb, 0.14 * T + 0.5 * o.glutes], axes, places))
    if o.upper_arms > 0:
        for ch in (ch for ch in sk.chains if ch.kind == "arm"):
            j, c = _upper_arm(sk, ch)
            a, b = sk.pos[j], sk.pos[c]
            L = float(np.linalg.norm(b - a))
            r = np.clip(0.16 * L, 0.01 * sk.stature, 0.045 * sk.stature) * o.thickness
            arm_axes = _frame(b - a, -fr)  # rows: along the bone, back (away from the front), across
            rb = 0.5 * r + o.upper_arms
            centre = a + 0.45 * (b - a) + (r + o.upper_arms - rb) * arm_axes[1]
            side = "L" if (a - tr.hip) @ lf > 0 else "R"
            out.append((f"upper_arm_{side}", j, centre, [0.3 * L + 0.5 * o.upper_arms, rb, 0.7 * r + 0.5 * o.upper_arms],
                        arm_axes, frozenset({sk.node[j], sk.node[c]})))
    return out


# ------------------------------------------------------------------------- keeping parts apart
def _keep_apart(pieces: list[_Piece], gap: float, iterations: int = 15) -> list[_Piece]:
    """Shrink pieces so that no distal limb part comes within `gap` (metres) plus the blend of a
    piece it shares no skeleton place with: a touch there would close a handle through the body.

    The size factors of the stations nearest the contact are lowered (stations at a joint are
    shared by the pieces meeting there, so the surface stays continuous), both sides in proportion
    to their size, and the check repeated until every pair is clear.
    """
    n = len(pieces)
    count = max([s for p in pieces for s in p.slots] + [-1]) + 1
    own = []
    for p in pieces:  # stations without a shared slot get their own
        ids = []
        for s in p.slots:
            ids.append(s if s >= 0 else count)
            count += s < 0
        own.append(replace(p, slots=tuple(ids)))
    pieces = own
    scale = np.ones(count)
    I, Jp = np.triu_indices(n, 1)
    check = np.array([(pieces[i].distal or pieces[j].distal) and not (pieces[i].places & pieces[j].places)
                      and not (pieces[i].fixed and pieces[j].fixed) for i, j in zip(I, Jp)], bool)
    I, Jp = I[check], Jp[check]
    if len(I) == 0:
        return pieces
    A = np.array([p.a for p in pieces])
    B = np.array([p.b for p in pieces])
    k = np.array([p.k for p in pieces])
    fixed = np.array([p.fixed for p in pieces])
    s, t = _candidates(A[I], B[I], A[Jp], B[Jp])            # (M, C) parameters on both pieces
    pi, pj = A[I][:, None] + s[..., None] * (B - A)[I][:, None], A[Jp][:, None] + t[..., None] * (B - A)[Jp][:, None]
    v = pj - pi
    dist = np.linalg.norm(v, axis=2)
    u = v / np.maximum(dist, 1e-12)[..., None]
    u[dist < 1e-12] = UP
    need = 0.6 * k[Jp] + gap  # the later piece's blend is the one reaching across the gap
    for _ in range(iterations):
        cur = [_scaled(p, scale) for p in pieces]
        ri = _support(cur, I, s, u)
        rj = _support(cur, Jp, t, -u)
        margin = dist - ri - rj - need[:, None]
        worst = margin.argmin(axis=1)
        rows = np.arange(len(I))
        bad = np.nonzero(margin[rows, worst] < 0)[0]
        if len(bad) == 0:
            break
        base = scale.copy()  # each contact asks for a factor on the sizes at this pass; keep the least
        for m in bad:
            c = worst[m]
            i, j, room, a, b = I[m], Jp[m], max(dist[m, c] - need[m], 0.0), ri[m, c], rj[m, c]
            if fixed[i]:
                fi, fj = 1.0, max(room - a, 0.3 * b) / b
            elif fixed[j]:
                fi, fj = max(room - b, 0.3 * a) / a, 1.0
            else:
                fi = fj = max(room / (a + b), 0.3)
            for p, par, f in ((i, s[m, c], fi), (j, t[m, c], fj)):
                if f < 1.0:
                    ids = np.array(pieces[p].slots)
                    scale[ids] = np.minimum(scale[ids], base[ids] * f ** _station_weights(pieces[p].ts, par))
        scale = np.maximum(scale, 0.2)
    return [_scaled(p, scale) for p in pieces]


def _candidates(a1, b1, a2, b2, samples: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """(M, 1 + 2 samples) parameter pairs (s on segment 1, t on segment 2) where two pieces may come
    closest: the segments' closest points, and evenly spaced points on each with the closest point
    on the other (parallel limbs, like an arm hanging beside the trunk, are close all along, and
    their radii vary)."""
    s0, t0 = segment_closest(a1, b1, a2, b2)
    grid = np.linspace(0.0, 1.0, samples)
    on1 = a1[:, None] + grid[None, :, None] * (b1 - a1)[:, None]
    on2 = a2[:, None] + grid[None, :, None] * (b2 - a2)[:, None]
    t1 = _closest_param(on1, a2[:, None], b2[:, None])
    s2 = _closest_param(on2, a1[:, None], b1[:, None])
    s = np.concatenate([s0[:, None], np.broadcast_to(grid, t1.shape), s2], axis=1)
    t = np.concatenate([t0[:, None], t1, np.broadcast_to(grid, s2.shape)], axis=1)
    return s, t


def _closest_param(p, a, b):
    """Parameter (0..1) of the point of segment a-b closest to p, broadcasting over leading axes."""
    d = b - a
    dd = np.einsum("...i,...i->...", d, d)
    return np.clip(np.einsum("...i,...i->...", p - a, d) / np.maximum(dd, 1e-24), 0.0, 1.0) * (dd > 1e-24)


def _station_weights(ts: np.ndarray, t: float) -> np.ndarray:
    """(n,) share of a shrink at parameter t taken by each station: 1 at the nearer stations of the
    span holding t (both in its middle), falling to 0 at the far ones."""
    if len(ts) == 1:
        return np.ones(1)
    i = int(np.clip(np.searchsorted(ts, t) - 1, 0, len(ts) - 2))
    span = ts[i + 1] - ts[i]
    w = np.zeros(len(ts))
    w[i] = min(1.0, 2.0 * (ts[i + 1] - t) / span)
    w[i + 1] = min(1.0, 2.0 * (t - ts[i]) / span)
    return w


def _scaled(p: _Piece, scale: np.ndarray) -> _Piece:
    g = scale[list(p.slots)]
    return replace(p, semi=p.semi * g[:, None], ca=p.ca * g[0], cb=p.cb * g[-1], k=p.k * g.min())


def _support(pieces: list[_Piece], idx: np.ndarray, t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(M, C) extent of piece idx[m] from its axis point at parameter t[m, c] in the unit direction
    u[m, c]: the support function of the cross-section ellipse (and of the end cap at the ends)."""
    fr = np.array([p.frame for p in pieces])[idx]                # (M, 3, 3)
    tab = np.array([p.table for p in pieces])[idx]               # (M, TABLE, 2)
    caps = np.array([[p.ca, p.cb] for p in pieces])[idx]         # (M, 2)
    loc = np.einsum("mij,mcj->mci", fr, u)
    x = np.clip(t, 0, 1) * (TABLE - 1)
    i0 = np.minimum(x.astype(np.int64), TABLE - 2)
    w = (x - i0)[..., None]
    rows = np.arange(len(idx))[:, None]
    semi = tab[rows, i0] * (1 - w) + tab[rows, i0 + 1] * w     # (M, C, 2)
    cap = np.where(t <= 1e-9, caps[:, :1], np.where(t >= 1 - 1e-9, caps[:, 1:], 0.0))
    return np.sqrt((cap * loc[..., 0]) ** 2 + (semi[..., 0] * loc[..., 1]) ** 2 + (semi[..., 1] * loc[..., 2]) ** 2)


def at_least_voxel(pieces: list[_Piece], h: float) -> list[_Piece]:
    """The pieces with every semi-axis at least `h` metres (one voxel), so that thin fingers stay
    connected when contoured at that spacing."""
    return [replace(p, semi=np.maximum(p.semi, h), ca=max(p.ca, h), cb=max(p.cb, h)) for p in pieces]


# ------------------------------------------------------------------------------------- field
@dataclass(frozen=True)
class Grid:
    """A regular grid: origin (3,) metres of point [0, 0, 0], spacing metres, shape (nx, ny, nz)."""

    origin: np.ndarray
    spacing: float
    shape: tuple[int, int, int]

    def axes(self) -> list[np.ndarray]:
        """x, y, z coordinates (n,) float32 of the grid lines."""
        return [(self.origin[i] + self.spacing * np.arange(self.shape[i])).astype(np.float32) for i in range(3)]


def _bounds(p: _Piece, pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Corners (3,), (3,) metres of a box holding the piece's solid, padded by `pad` metres."""
    r = max(p.semi.max(), p.ca, p.cb) + pad
    return np.minimum(p.a, p.b) - r, np.maximum(p.a, p.b) + r


def grid_around(pieces: list[_Piece], h: float) -> Grid:
    """A grid of spacing `h` metres holding every piece with three voxels to spare."""
    lo = np.min([_bounds(p, 0)[0] for p in pieces], axis=0) - 3 * h
    hi = np.max([_bounds(p, 0)[1] for p in pieces], axis=0) + 3 * h
    shape = tuple(int(n) for n in np.ceil((hi - lo) / h).astype(int) + 1)
    return Grid(lo, float(h), shape)


def piece_distance(p: _Piece, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Approximate signed distance (metres, negative inside) of piece p at points broadcast from the
    coordinate arrays x, y, z (e.g. shapes (nx,1,1), (1,ny,1), (1,1,nz)), float32."""
    f32 = np.float32
    dx, dy, dz = x - f32(p.a[0]), y - f32(p.a[1]), z - f32(p.a[2])
    e = p.frame.astype(f32)
    q0 = dx * e[0, 0] + dy * e[0, 1] + dz * e[0, 2]
    q1 = dx * e[1, 0] + dy * e[1, 1] + dz * e[1, 2]
    q2 = dx * e[2, 0] + dy * e[2, 1] + dz * e[2, 2]
    L = p.length
    if L > 0:
        t = np.clip(q0 / f32(L), 0, 1)
        q0 = q0 - t * f32(L)
        s1, s2 = (s.astype(f32) for s in p.sections(t))
        c = np.where(q0 < 0, f32(p.ca), f32(p.cb))
    else:
        s1, s2, c = f32(p.semi[0, 0]), f32(p.semi[0, 1]), f32(p.ca)
    u0, u1, u2 = q0 / c, q1 / s1, q2 / s2
    k0 = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    k1 = np.sqrt((u0 / c) ** 2 + (u1 / s1) ** 2 + (u2 / s2) ** 2)
    inside = -np.minimum(np.minimum(s1, s2), c)
    return np.where(k1 > 1e-12, k0 * (k0 - 1) / np.maximum(k1, f32(1e-12)), inside)


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Quadratic smooth minimum: min(a, b) minus at most k/4 where a and b are within k (k=0: min)."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0) / k
    return np.minimum(a, b) - h * h * (0.25 * k)


def _reach(pieces: list[_Piece], pad: float) -> np.ndarray:
    """(P,) metres around each piece's solid within which it can change the field near zero: the
    widest blend of it or any piece after it (a later smooth union reaches back to every value within
    its radius), times 1.5, plus `pad`."""
    k = np.array([p.k for p in pieces] + [0.0])
    return 1.5 * np.maximum.accumulate(k[::-1])[::-1][:-1] + pad


def evaluate_field(pieces: list[_Piece], grid: Grid, cull: bool = True) -> np.ndarray:
    """(nx, ny, nz) float32 field, negative inside the body: the pieces smooth-unioned in order.

    cull : evaluate each piece only on the grid block around it (padded by :func:`_reach` with three
        voxels), where it can change the sign or the values near zero; False evaluates every piece
        on the whole grid (the reference).
    """
    h = grid.spacing
    field = np.full(grid.shape, np.float32(1e3 * h), np.float32)
    xs, ys, zs = grid.axes()
    for p, reach in zip(pieces, _reach(pieces, 3 * h)):
        if cull:
            lo, hi = _bounds(p, reach)
            i0 = np.clip(np.floor((lo - grid.origin) / h).astype(int), 0, np.array(grid.shape))
            i1 = np.clip(np.ceil((hi - grid.origin) / h).astype(int) + 1, 0, np.array(grid.shape))
        else:
            i0, i1 = np.zeros(3, int), np.array(grid.shape)
        if np.any(i1 <= i0):
            continue
        block = (slice(i0[0], i1[0]), slice(i0[1], i1[1]), slice(i0[2], i1[2]))
        d = piece_distance(p, xs[block[0], None, None], ys[None, block[1], None], zs[None, None, block[2]])
        field[block] = smooth_min(field[block], d, p.k)
    # a value exactly at the iso level would give coincident contour points; nudge it outside
    field[np.abs(field) < 1e-7] = 1e-7
    return field


def field_at(pieces: list[_Piece], points: np.ndarray, pad: float, offsets: np.ndarray | None = None) -> np.ndarray:
    """Field (float64) at points (N, 3) metres, as :func:`evaluate_field` on the grid: each piece is
    evaluated only at the points within :func:`_reach` (with `pad` metres; three voxels give the
    grid's values) of it. offsets : (S, 3) metres, shifts of every point (a difference stencil),
    giving (S, N) values; None gives (N,)."""
    pts = np.asarray(points, float)
    off = np.zeros((1, 3)) if offsets is None else np.asarray(offsets, float)
    out = np.full((len(off), len(pts)), 1e3, np.float32)
    for p, reach in zip(pieces, _reach(pieces, pad)):
        lo, hi = _bounds(p, reach)
        idx = np.nonzero(np.all((pts >= lo) & (pts <= hi), axis=1))[0]
        if len(idx):
            q = (pts[idx][None] + off[:, None]).astype(np.float32)
            out[:, idx] = smooth_min(out[:, idx], piece_distance(p, q[..., 0], q[..., 1], q[..., 2]), p.k)
    out = out.astype(float)
    return out[0] if offsets is None else out


def project_to_surface(pieces: list[_Piece], v: np.ndarray, voxel: float, iterations: int = 2) -> np.ndarray:
    """Vertices (V, 3) moved onto the zero level set by Newton steps along the field's gradient
    (central differences of a quarter voxel), each step at most a voxel."""
    v = np.array(v, float)
    step = 0.25 * voxel
    stencil = np.concatenate([np.zeros((1, 3)), np.eye(3) * step, -np.eye(3) * step])
    for _ in range(iterations):
        f = field_at(pieces, v, 3 * voxel + step, stencil)
        g = ((f[1:4] - f[4:7]) / (2 * step)).T
        move = (f[0] / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
        v -= np.clip(move, -voxel, voxel)  # a vertex with a poor gradient moves a little
    return v


# ----------------------------------------------------------------------------------- surface
def contour(values: np.ndarray, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Zero level set of the field by flying edges: vertices (V, 3) float64, faces (F, 3) int64."""
    import pyvista as pv
    img = pv.ImageData(dimensions=grid.shape, spacing=(grid.spacing,) * 3, origin=tuple(grid.origin))
    img.point_data["f"] = values.ravel(order="F")
    surf = img.contour([0.0], scalars="f", method="flying_edges", compute_scalars=False)
    if surf.n_cells == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    if not surf.is_all_triangles:
        surf = surf.triangulate()
    return np.asarray(surf.points, float), surf.faces.reshape(-1, 4)[:, 1:].astype(np.int64)


def _polygonise(pieces: list[_Piece], h: float) -> tuple[np.ndarray, np.ndarray]:
    grid = grid_around(pieces, h)
    return largest_component(*contour(evaluate_field(pieces, grid), grid))


def largest_component(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The connected piece of the mesh with the most faces, vertices renumbered (unused dropped)."""
    if len(f) == 0:
        return v, f
    n = len(v)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]]])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(g, directed=False)
    keep = np.bincount(label[f[:, 0]]).argmax()
    f = f[label[f[:, 0]] == keep]
    used = np.unique(f)
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Volume enclosed by a closed triangle mesh, m^3, positive when faces wind outward."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def outward(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Faces flipped if needed so that the enclosed volume is positive (normals point out)."""
    return f[:, ::-1].copy() if signed_volume(v, f) < 0 else f


def taubin_smooth(v: np.ndarray, f: np.ndarray, iterations: int, lam: float = 0.5, mu: float = -0.53) -> np.ndarray:
    """Taubin's lambda|mu smoothing with uniform (umbrella) weights: each pass shrinks by lam and
    inflates by mu, so that low frequencies (the shape) keep their size while voxel steps vanish.
    v : (V, 3) metres; returns the smoothed copy."""
    n = len(v)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A.data[:] = 1.0  # each edge appears in two faces: count it once
    deg = np.asarray(A.sum(axis=1)).ravel()
    W = sp.diags(1.0 / np.maximum(deg, 1)) @ A
    v = v.copy()
    for _ in range(iterations):
        v += lam * (W @ v - v)
        v += mu * (W @ v - v)
    return v
