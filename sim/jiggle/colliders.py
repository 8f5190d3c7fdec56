"""What the particles collide with: bone capsules and the floor, built once; their motion per run.

:class:`ColliderModel` (frozen, built once at bind by :func:`collider_model`): the character's bone
capsules (rig/character/capsules.py) shrunk inside the muscles over each bone, the floor height, the
friction, and for every muscle the capsules it collides with, as a CSR list:

- not the bones of its own chain: the joints its attachments ride and every joint on the skeleton's
  paths between them (a muscle does not collide with the bones it wraps), nor a bone ending at one
  of those joints (the neighbour it meets at the joint);
- not a capsule one of its particles already lies in (or within REST_CLEARANCE of) at bind: a
  constraint violated at rest would push the rest shape about.

Every muscle collides with the floor (a half-space z >= floor). A particle is held out of a capsule (or
above the floor) only as far as its goal is at that moment: the goal's penetration is the pair's
allowance, and the contact acts on the jiggle beyond it (sim/jiggle/contact_kernels.py says why).

:class:`Colliders` is a ColliderModel with the capsules' ends as a goal track on a run's knots (the
same knots as the particles' goals, so a capsule's position inside a step is the same Hermite
arithmetic as a goal's, and a chunked bake's resumed chunks see the same track). The solver takes it
in :meth:`sim.jiggle.solver.ParticleSolver.integrate`; the contact is a projection with friction
(sim/jiggle/contact_kernels.py says how and why).

:class:`SkinCheck` counts skin vertices of one body part (its dominant joint) inside another part's
capsule per frame: the check that the skin, not only the particles, respects the body.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.capsules import BoneCapsules, bone_capsules, segment_distance
from jiggle.sim.jiggle.goal_track import GoalControl, build_track
from jiggle.sim.jiggle.params import CVS

FRICTION = 0.5
"""Coulomb friction coefficient of a particle sliding on a capsule or the floor (skin on skin, ~0.5)."""
REST_CLEARANCE = 0.005
"""metres: a muscle whose particles come this close to a capsule at bind does not collide with it."""
SHRINK = 0.9
"""A capsule's radius is at most this fraction of the distance to the nearest CV of its own muscles."""
NO_FLOOR = -1.0e30
BROAD_BLOCK = 8
"""Knot intervals the host's broad phase boxes together (Colliders.active)."""


@dataclass(frozen=True, eq=False)
class ColliderModel:
    """The colliders of a particle model (read-only arrays; `wp_*` their device copies).

    capsules : rig.character.capsules.BoneCapsules (C capsules).
    floor : metres, world z of the floor plane (None: no floor).
    friction : Coulomb coefficient >= 0.
    pair_offsets : (M + 1,) int64; muscle m collides with capsules pair_capsule[pair_offsets[m]:pair_offsets[m + 1]].
    pair_capsule : (P,) int64.
    excluded_rest : (M, C) bool, pairs left out because they touch at bind.
    muscle_names : (M,).
    """

    capsules: BoneCapsules
    floor: float | None
    friction: float
    pair_offsets: np.ndarray
    pair_capsule: np.ndarray
    excluded_rest: np.ndarray
    muscle_names: tuple
    device: str
    wp_radius: wp.array
    wp_pair_offsets: wp.array
    wp_pair_capsule: wp.array

    @property
    def num_capsules(self) -> int:
        return self.capsules.count

    @property
    def names(self) -> tuple:
        """(C + 1,) names of what a particle may hit: the capsules, then "floor"."""
        return tuple(self.capsules.names) + ("floor",)

    @classmethod
    def from_pairs(cls, capsules: BoneCapsules, keep: np.ndarray, *, floor: float | None = None,
                   friction: float = FRICTION, muscle_names=None, device: str = "cpu",
                   excluded_rest: np.ndarray | None = None) -> "ColliderModel":
        """A model from capsules and which muscle collides with which: keep (M, C) bool."""
        if not (isinstance(friction, (int, float)) and math.isfinite(friction) and friction >= 0):
            raise InputError(f"collision friction must be a number >= 0, got {friction!r}", field="friction")
        if floor is not None and not math.isfinite(floor):
            raise InputError(f"the floor height must be a finite number of metres, got {floor!r}", field="floor")
        keep = np.asarray(keep, bool)
        if keep.ndim != 2 or keep.shape[1] != capsules.count:
            raise InputError(f"expected (muscles, {capsules.count}) collision pairs, got {keep.shape}", field="colliders")
        M = len(keep)
        offsets = np.concatenate([[0], np.cumsum(keep.sum(axis=1))]).astype(np.int64)
        pair = np.concatenate([np.flatnonzero(k) for k in keep]).astype(np.int64) if M else np.zeros(0, np.int64)

        def dev(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)
        return cls(capsules=capsules, floor=None if floor is None else float(floor), friction=float(friction),
                   pair_offsets=frozen_array(offsets, np.int64), pair_capsule=frozen_array(pair, np.int64),
                   excluded_rest=frozen_array(np.zeros_like(keep) if excluded_rest is None else excluded_rest, bool),
                   muscle_names=tuple(muscle_names or (f"group {m}" for m in range(M))), device=str(device),
                   wp_radius=dev(capsules.radius.astype(np.float32), wp.float32),
                   wp_pair_offsets=dev(offsets.astype(np.int32), wp.int32),
                   wp_pair_capsule=dev(pair.astype(np.int32), wp.int32))

    @cached_property
    def keep(self) -> np.ndarray:
        """(M, C) bool: which muscle collides with which capsule."""
        keep = np.zeros((len(self.pair_offsets) - 1, self.num_capsules), bool)
        for m in range(len(keep)):
            keep[m, self.pairs(m)] = True
        return keep

    @cached_property
    def margin(self) -> np.ndarray:
        """(M,) metres: the largest radius of each muscle's capsules (how far one push may move a particle)."""
        return np.array([self.capsules.radius[self.pairs(m)].max() if len(self.pairs(m)) else 0.0
                         for m in range(len(self.pair_offsets) - 1)])

    def pairs(self, m: int) -> np.ndarray:
        """Capsules muscle m collides with."""
        return self.pair_capsule[self.pair_offsets[m]:self.pair_offsets[m + 1]]

    def at(self, knots: np.ndarray, world: np.ndarray, cuts=None) -> "Colliders":
        """The colliders moving with joint world transforms world (S, J, 4, 4) at knots (S,) seconds;
        cuts (S - 1,) bool as the particles' goal track has them (None: none)."""
        knots = np.asarray(knots, dtype=np.float64)
        ends = self.capsules.ends(np.asarray(world, dtype=np.float64)).reshape(len(knots), -1, 3)
        return self.on_track(knots, ends, cuts)

    def on_track(self, knots: np.ndarray, ends: np.ndarray, cuts=None) -> "Colliders":
        """As :meth:`at` from the capsules' ends (S, 2C, 3) metres at knots (S,)."""
        ends = np.asarray(ends, dtype=np.float64).reshape(len(knots), 2 * self.num_capsules, 3)
        if self.num_capsules == 0:                 # a track needs points: one still point far away
            ends = np.full((len(knots), 2, 3), 1.0e6)
        cut = np.zeros(len(knots) - 1, bool) if cuts is None else np.asarray(cuts, bool)
        track = build_track(knots, ends, cuts=cut)
        return Colliders(self, track.to_device(self.device))


@dataclass(frozen=True, eq=False)
class Colliders:
    """A ColliderModel and its capsules' ends as a goal track on a run's knots (control.track.pos: (S, 2C, 3))."""

    model: ColliderModel
    control: GoalControl

    def active(self, particles, track) -> tuple[np.ndarray, np.ndarray]:
        """The broad phase of a run (sim/jiggle/contact_kernels.py): for knot interval j and muscle m, what the
        muscle may touch there, ids[offsets[j M + m]:offsets[j M + m + 1]] (capsule c, or C for the floor).

        particles : the ParticleModel (its groups are the muscles; reach per particle). track : the particles'
        GoalTrack, on the same knots as this one. Returns (offsets ((S - 1) M + 1,), ids (A,)) int32.
        """
        cm = self.model
        offs = np.asarray(particles.group_offsets, dtype=np.int64)
        M, C = len(offs) - 1, cm.num_capsules
        # boxes per BROAD_BLOCK intervals: the kernel's per-step cull (sim/jiggle/contact_kernels.py) makes
        # them tight again, so a coarser host phase only costs a few more per-muscle box tests per step
        mlo, mhi = group_boxes(track, offs[:-1], BROAD_BLOCK)               # (B, M, 3)
        from jiggle.sim.jiggle.tissue_law import BROAD
        # the tissue law turns particles back before their reach; BROAD reaches cover the violent exceptions
        reach = BROAD * np.maximum.reduceat(np.where(particles.glued, 0.0, particles.reach), offs[:-1])
        grow = (reach + cm.margin + 1e-4)[None, :, None]                    # inf reach: always near
        mlo, mhi = mlo - grow, mhi + grow
        near = np.zeros((len(mlo), M, C + 1), bool)
        if C:
            starts = np.arange(0, 2 * C, 2)
            clo, chi = group_boxes(self.control.track, starts, BROAD_BLOCK)  # (B, C, 3): both ends
            clo = clo - cm.capsules.radius[None, :, None]
            chi = chi + cm.capsules.radius[None, :, None]
            # box overlap on every axis, for the pairs the muscle collides with
            overlap = ((clo[:, None] <= mhi[:, :, None]) & (chi[:, None] >= mlo[:, :, None])).all(axis=3)
            np.logical_and(overlap, cm.keep[None], out=near[..., :C])
        if cm.floor is not None:
            near[..., C] = mlo[..., 2] < cm.floor
        near = np.repeat(near, BROAD_BLOCK, axis=0)[:len(track.times) - 1]  # (S - 1, M, C + 1)
        counts = near.sum(axis=2).reshape(-1)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        ids = np.nonzero(near.reshape(-1, C + 1))[1].astype(np.int32)
        return offsets, ids


def group_boxes(track, starts: np.ndarray, block: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (B, G, 3) metres: per block of `block` knot intervals (B = ceil((S - 1) / block)), a box
    around the goal curves of each group of particles starts[g]:starts[g + 1] (the last to the end): the
    box of the group's knot positions in the block (both ends of every interval), grown per axis by the
    largest |velocity| x H / 3 of its particles there. Each cubic lies in the hull of its Bezier control
    points pa, pa + va H / 3, pb - vb H / 3, pb, which that box holds.

    The knots are reduced first, block by block (contiguous rows), then the particles, on the block's
    rows: a block of 8 intervals costs about an eighth of one box per interval."""
    S = len(track.times)
    first = np.arange(0, S - 1, block)                                      # (B,) each block's first interval
    H = np.maximum.reduceat(np.diff(track.times), first) / 3.0             # (B,) its longest interval / 3
    starts = np.asarray(starts, dtype=np.int64)

    def red(op, a, rows):
        # blocks of rows by `block` strided views (numpy's reduceat over rows is several times slower), then
        # groups of particles on the block rows
        out = a[0::block].copy()
        for k in range(1, block):
            part = a[k::block]
            op(out[:len(part)], part, out=out[:len(part)])
        return op.reduceat(out, starts, axis=1)
    # knots of block b: first[b] .. first[b] + block (its last interval's far end: the next block's first knot)
    pmin = red(np.minimum, track.pos[:-1], first)
    pmax = red(np.maximum, track.pos[:-1], first)
    last = np.minimum(first + block, S - 1)
    pmin = np.minimum(pmin, np.minimum.reduceat(track.pos[last], starts, axis=1))
    pmax = np.maximum(pmax, np.maximum.reduceat(track.pos[last], starts, axis=1))
    # |v| bounded by max(v, -min v): reductions only, no (S, N, 3) temporary (a fresh one page-faults)
    speed = np.maximum(red(np.maximum, track.vel_start, first), -red(np.minimum, track.vel_start, first))
    np.maximum(speed, red(np.maximum, track.vel_end, first), out=speed)
    np.maximum(speed, -red(np.minimum, track.vel_end, first), out=speed)
    speed *= H[:, None, None]
    return pmin - speed, pmax + speed


def muscle_chains(rig, parents: np.ndarray) -> list[set]:
    """Per muscle of `rig` (rig.muscle.model.MuscleRig): the joints it rides (rig.joints) and every joint
    on the skeleton paths between them (through their deepest common ancestor)."""
    parents = np.asarray(parents)

    def up(j):
        path = [int(j)]
        while parents[path[-1]] >= 0:
            path.append(int(parents[path[-1]]))
        return path
    out = []
    for joints in np.asarray(rig.joints):
        paths = [up(j) for j in set(int(j) for j in joints)]
        common = set(paths[0]).intersection(*map(set, paths[1:]))
        top = max(common, key=lambda j: len(up(j))) if common else None
        chain = set()
        for p in paths:
            for j in p:
                chain.add(j)
                if j == top:
                    break
        out.append(chain)
    return out


def collider_model(rig, character, *, capsules: BoneCapsules | None = None, floor: float | None = None,
                   friction: float = FRICTION, device: str = "cpu") -> ColliderModel:
    """The colliders of `rig`'s muscles (rig.muscle.model.MuscleRig) on `character` (its bone capsules,
    unless `capsules` are given, e.g. a MuJoCo model's geoms), with a floor at z = floor metres (None:
    none). See the module for which muscle collides with what."""
    if capsules is None:
        capsules = bone_capsules(character)
    parents = capsules.parents
    chains = muscle_chains(rig, parents)
    C, M = capsules.count, rig.M
    own = np.array([[capsules.joint[c] in ch or (capsules.child[c] >= 0 and capsules.child[c] in ch)
                     for c in range(C)] for ch in chains], bool).reshape(M, C)
    rest = np.asarray(rig.rest_cvs, dtype=np.float64).reshape(M, CVS, 3)
    bind = np.asarray(character.bind_world, dtype=np.float64)
    if C:
        owner = np.repeat(own, CVS, axis=0)                                 # (40 M, C): CVs over their own bones
        capsules = capsules.shrunk_inside(bind, rest.reshape(-1, 3), owner, SHRINK)
    ends = capsules.ends(bind)
    touch = np.zeros((M, C), bool)
    for c in range(C):
        a, b = ends[c]
        ab = b - a
        L2 = float(ab @ ab)
        t = np.clip((rest - a) @ ab / L2, 0, 1) if L2 > 0 else np.zeros(rest.shape[:2])
        d = np.linalg.norm(rest - (a + t[..., None] * ab), axis=2)
        touch[:, c] = (d < capsules.radius[c] + REST_CLEARANCE).any(axis=1)
    return ColliderModel.from_pairs(capsules, ~own & ~touch, floor=floor, friction=friction,
                                    muscle_names=rig.names, device=device, excluded_rest=touch & ~own)


def rest_floor(character, lowest_joint: float | None = None) -> float:
    """metres: the kinematic drive's floor, the lowest skin vertex at rest (the feet), lowered by as much as
    the motion's lowest joint (lowest_joint, metres) goes below the bind pose's lowest joint: a clip whose
    feet reach lower than the bind pose's stays above its floor."""
    skin = float(np.min(character.vertices[:, 2]))
    if lowest_joint is None:
        return skin
    return skin + min(0.0, float(lowest_joint) - float(np.min(np.asarray(character.bind_world)[:, 2, 3])))


# ------------------------------------------------------------------------------ contact records
def muscle_contacts(records: np.ndarray, offsets: np.ndarray, mass: np.ndarray | None = None) -> dict:
    """Per frame and muscle, from the solver's particle contact records (T, N, 3) (depth m, impulse N s,
    hit id): {"depth": (T, M) metres, the largest penetration before correction; "hit": (T, M) int, what
    the deepest particle hit (a capsule, C for the floor, -1 nothing); "impulse": (T, M) N s, summed}."""
    records = np.asarray(records, dtype=np.float64)
    T = records.shape[0]
    M = len(offsets) - 1
    depth, hit, imp = np.zeros((T, M)), np.full((T, M), -1, np.int64), np.zeros((T, M))
    for m in range(M):
        r = records[:, offsets[m]:offsets[m + 1]]
        if r.shape[1] == 0:
            continue
        k = np.argmax(r[..., 0], axis=1)
        depth[:, m] = r[np.arange(T), k, 0]
        hit[:, m] = np.where(depth[:, m] > 0, r[np.arange(T), k, 2], -1).astype(np.int64)
        imp[:, m] = r[..., 1].sum(axis=1)
    return {"depth": depth, "hit": hit, "impulse": imp}


def contact_summary(depth: np.ndarray, hit: np.ndarray, impulse: np.ndarray, muscle_names, collider_names,
                    times: np.ndarray) -> dict:
    """bake.json's "contacts" from per-frame, per-muscle contacts (T, M) each: per frame the deepest
    penetration (mm, before correction), which muscle and what it hit; per (muscle, collider) pair the
    frames in contact, the deepest penetration and the summed impulse."""
    T = len(times)
    deepest = depth.max(axis=1) if depth.size else np.zeros(T)
    who = depth.argmax(axis=1) if depth.size else np.zeros(T, int)
    per_frame = {
        "time_s": [round(float(t), 6) for t in times],
        "max_penetration_mm": [round(1000.0 * float(d), 4) for d in deepest],
        "muscle": [muscle_names[int(m)] if d > 0 else None for m, d in zip(who, deepest)],
        "hit": [collider_names[int(hit[f, who[f]])] if deepest[f] > 0 else None for f in range(T)],
        "impulse_Ns": [round(float(i), 6) for i in (impulse.sum(axis=1) if impulse.size else np.zeros(T))],
    }
    pairs = []
    for m, c in sorted({(int(m), int(hit[f, m])) for f, m in zip(*np.nonzero(hit >= 0))}):
        sel = hit[:, m] == c
        pairs.append({"muscle": muscle_names[m], "hit": collider_names[c], "frames": int(sel.sum()),
                      "max_penetration_mm": round(1000.0 * float(depth[sel, m].max()), 4),
                      "impulse_Ns": round(float(impulse[sel, m].sum()), 6)})
    pairs.sort(key=lambda p: -p["max_penetration_mm"])
    return {"frames_in_contact": int((deepest > 0).sum()),
            "max_penetration_mm": round(1000.0 * float(deepest.max()), 4) if T else 0.0,
            "pairs": pairs, "per_frame": per_frame}


# ------------------------------------------------------------------------------ the skin's check
SKIN_ADJACENT = 1
"""A vertex is not checked against the capsule of a bone whose joints lie this many bones or fewer from its
own part (its own bone and the ones meeting it at a joint, where skins legitimately fold over each other)."""
SKIN_REST_SHARE = 0.02
"""Nor against a capsule holding more than this share of its part's vertices at rest."""


@dataclass(frozen=True, eq=False)
class SkinCheck:
    """Counts skin vertices inside another body part's capsule. part : (V,) int32 each vertex's joint
    (its strongest influence). part_offsets (J + 1,), part_capsule : the capsules each part is checked
    against (CSR). capsules : BoneCapsules. cluster : (V,) each vertex's cluster (a few centimetres of one
    part's skin, :func:`vertex_clusters`), None: one per part; cluster_centre : (K, 3) metres, each
    cluster's centre in its part's joint's bind frame, None: the world origin (a loose cull).

    :meth:`count` is cheap: per frame each cluster's reach from its centre (riding the joint), then the
    capsules of its part's list within reach (most clusters have none), then only those tested per vertex."""

    capsules: BoneCapsules
    part: np.ndarray
    part_offsets: np.ndarray
    part_capsule: np.ndarray
    cluster: np.ndarray | None = None
    cluster_centre: np.ndarray | None = None

    @cached_property
    def cluster_part(self) -> np.ndarray:
        """(K,) int64: each cluster's part (joint)."""
        if self.cluster is None:
            return np.arange(len(self.part_offsets) - 1)
        out = np.zeros(int(self.cluster.max()) + 1 if len(self.cluster) else 0, np.int64)
        out[self.cluster] = self.part
        return out

    @cached_property
    def _device_arrays(self) -> dict:
        return {}

    def _model(self, device: str):
        """The check's constant arrays on `device` (made once per device): cluster_offsets (K + 1,) and
        cluster_vertex (V,) (the vertices sorted by cluster, CSR), cluster_part (K,), part_offsets,
        part_capsule, radius."""
        got = self._device_arrays.get(device)
        if got is None:
            def dev(a, dtype):
                return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)
            cluster = np.asarray(self.part if self.cluster is None else self.cluster, np.int64)
            K = len(self.cluster_part)
            order = np.argsort(cluster, kind="stable")
            offsets = np.concatenate([[0], np.cumsum(np.bincount(cluster, minlength=K))])
            got = self._device_arrays[device] = (
                dev(offsets.astype(np.int32), wp.int32), dev(order.astype(np.int32), wp.int32),
                dev(self.cluster_part.astype(np.int32), wp.int32), dev(self.part_offsets.astype(np.int32), wp.int32),
                dev(self.part_capsule.astype(np.int32) if len(self.part_capsule) else np.zeros(1, np.int32), wp.int32),
                dev(self.capsules.radius.astype(np.float32), wp.float32))
        return got

    def inside(self, world: np.ndarray, skin: np.ndarray, device: str = "cpu") -> np.ndarray:
        """(T, V) bool: vertex v of frame t inside a capsule it is checked against; world (T, J, 4, 4),
        skin (T, V, 3) metres (one Warp launch)."""
        from jiggle.sim.jiggle import contact_kernels as ck
        skin = np.asarray(skin, dtype=np.float32)
        T, V = skin.shape[:2]
        if self.capsules.count == 0 or T == 0:
            return np.zeros((T, V), bool)
        ends = self.capsules.ends(world).reshape(T, -1, 3).astype(np.float32)
        out = wp.zeros((T, V), dtype=wp.int32, device=device)

        def dev(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)
        wp.launch(ck.skin_inside, dim=(T, V), device=device,
                  inputs=[dev(self.part.astype(np.int32), wp.int32), dev(self.part_offsets.astype(np.int32), wp.int32),
                          dev(self.part_capsule.astype(np.int32), wp.int32),
                          dev(self.capsules.radius.astype(np.float32), wp.float32), dev(ends, wp.vec3),
                          dev(skin, wp.vec3)],
                  outputs=[out])
        return out.numpy().astype(bool)

    def centres(self, world: np.ndarray) -> np.ndarray:
        """(T, K, 3) float32 metres: each cluster's centre under joint world transforms world (T, J, 4, 4)."""
        K = len(self.cluster_part)
        if self.cluster_centre is None:
            return np.zeros((len(world), K, 3), np.float32)
        w = np.asarray(world, dtype=np.float64)
        cp = self.cluster_part
        out = w[:, :, :3, 3][:, cp]                                         # (T, K, 3): R c + t, column by column
        for b in range(3):                                                  # (a batched 3x3 einsum is slower)
            out += w[:, :, :3, b][:, cp] * self.cluster_centre[None, :, None, b]
        return out.astype(np.float32)

    def count(self, world: np.ndarray, skin: np.ndarray, device: str = "cpu") -> np.ndarray:
        """(T,) int32: vertices inside another part's capsule per frame, world (T, J, 4, 4), skin (T, V, 3)
        metres; equal to inside(world, skin).sum(axis=1). :meth:`keep_out`'s launch with the skin as both the
        static and the final skin (nothing is then pulled back)."""
        skin = np.ascontiguousarray(skin, dtype=np.float32)
        return self.keep_out(world, skin, skin.copy(), device)["static"]

    def keep_out(self, world: np.ndarray, static: np.ndarray, final: np.ndarray,
                 device: str = "cpu", rigid=None) -> dict:
        """The final skin kept out of the capsules its static skin is not in: a final vertex (T, V, 3) float32
        metres, changed in place, that the jiggle took inside a capsule of its part's list is pulled back along
        final - static to just before the capsule (sim/jiggle/contact_kernels.py: skin_keep_out_clusters);
        skin the animation itself puts inside stays. Returns per frame (T,) "static" and "final" (the counts
        of :meth:`count`, taken after the pull-back: final <= static in every frame), "kept" (vertices pulled
        back) and "pulled_m" (the longest pull-back, metres). world (T, J, 4, 4). One launch.
        rigid : rig.character.gear.Ride (rows, piece) of the gear and hard shells, or None: a rigid piece is pulled
        back as a whole, by the largest share of its jiggle any of its vertices was (its jiggle is one translation,
        so it stays rigid: pulling back single vertices would stretch and tear its edges)."""
        from jiggle.sim.jiggle import contact_kernels as ck
        T = len(final)
        out = {"static": np.zeros(T, np.int32), "final": np.zeros(T, np.int32), "kept": np.zeros(T, np.int32),
               "pulled_m": np.zeros(T, np.float32)}
        if self.capsules.count == 0 or T == 0 or len(self.part_capsule) == 0:
            return out
        if not (isinstance(final, np.ndarray) and final.dtype == np.float32 and final.flags.c_contiguous):
            raise TypeError("keep_out changes the final skin in place: a C-contiguous float32 array")
        model = self._model(device)
        K = len(self.cluster_part)
        ends = wp.array(self.capsules.ends(world).reshape(T, -1, 3).astype(np.float32), dtype=wp.vec3, device=device)
        centres = wp.array(self.centres(world), dtype=wp.vec3, device=device)
        s = wp.array(np.ascontiguousarray(static, dtype=np.float32), dtype=wp.vec3, device=device, copy=False)
        f = wp.array(final, dtype=wp.vec3, device=device, copy=False)      # on the CPU: the caller's array
        cand = wp.empty((T, K, int(np.diff(self.part_offsets).max())), dtype=wp.int32, device=device)
        counts = [wp.zeros(T, dtype=wp.int32, device=device) for _ in range(3)]
        pulled = wp.zeros(T, dtype=float, device=device)
        rows = None if rigid is None or not len(getattr(rigid, "rows", ())) else np.asarray(rigid.rows)
        before = final[:, rows] if rows is not None else None
        wp.launch(ck.skin_keep_out_clusters, dim=(T, K), device=device, inputs=[*model, ends, centres, s, f, cand],
                  outputs=[*counts, pulled])
        if f.device.is_cuda or f.ptr != final.ctypes.data:
            final[...] = f.numpy()
        if rows is not None:
            _pull_whole(rows, np.asarray(rigid.piece), static, final, before)
        for key, a in zip(("static", "final", "kept"), counts):
            out[key] = a.numpy()
        out["pulled_m"] = pulled.numpy()
        return out


def _pull_whole(rows: np.ndarray, piece: np.ndarray, static: np.ndarray, final: np.ndarray, before: np.ndarray) -> None:
    """SkinCheck.keep_out's rigid pieces: every vertex of a piece (rows (R,), piece (R,) in 0..K-1) pulled back by
    the largest share of its jiggle (before - static, (T, R, 3)) that keep_out pulled any of them back, in place
    in `final` (T, V, 3); pieces nothing pulled stay as they are, bit for bit."""
    after = final[:, rows]
    if np.array_equal(after, before):
        return
    jig = before.astype(np.float64) - static[:, rows]
    share = np.linalg.norm(before.astype(np.float64) - after, axis=2) / np.maximum(np.linalg.norm(jig, axis=2), 1e-12)
    T, K = len(final), int(piece.max()) + 1
    most = np.zeros((T, K))
    for t in np.nonzero((share > 0.0).any(axis=1))[0]:
        np.maximum.at(most[t], piece, np.minimum(share[t], 1.0))
    hit = most[:, piece] > 0.0                                                   # (T, R)
    moved = (before - most[:, piece][..., None] * jig).astype(final.dtype)
    final[:, rows] = np.where(hit[..., None], moved, after)


CLUSTER_SIZE = 0.06
"""metres: the skin check's clusters are a part's vertices in one cube of this size at rest."""


def vertex_clusters(part: np.ndarray, rest: np.ndarray, bind_world: np.ndarray,
                    size: float = CLUSTER_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """(cluster (V,) int64, centre (K, 3) metres in the part's joint's bind frame): the vertices of each
    part (part (V,)) grouped by the cube of side `size` their rest position (V, 3) lies in, each cluster's
    centre the centroid of its rest vertices. Small clusters keep the skin check's cull tight: a cluster's
    reach from its centre stays about its own size while the body moves."""
    rest = np.asarray(rest, dtype=np.float64)
    cell = np.floor(rest / size).astype(np.int64)
    cell -= cell.min(axis=0) if len(cell) else 0
    span = cell.max(axis=0) + 1 if len(cell) else np.ones(3, np.int64)
    key = ((np.asarray(part, np.int64) * span[0] + cell[:, 0]) * span[1] + cell[:, 1]) * span[2] + cell[:, 2]
    _, cluster = np.unique(key, return_inverse=True)                    # one int64 key: a 1-d unique
    cluster = cluster.reshape(-1)
    K = int(cluster.max()) + 1 if len(cluster) else 0
    sums = np.zeros((K, 3))
    np.add.at(sums, cluster, rest)
    centre = sums / np.bincount(cluster, minlength=K)[:, None]
    joint = np.zeros(K, np.int64)
    joint[cluster] = part
    inv = np.linalg.inv(np.asarray(bind_world, dtype=np.float64))[joint]
    return cluster, np.einsum("kij,kj->ki", inv[:, :3, :3], centre) + inv[:, :3, 3]


def skin_check(character, capsules: BoneCapsules) -> SkinCheck:
    """The SkinCheck of `character` against `capsules` (see SKIN_ADJACENT, SKIN_REST_SHARE)."""
    parents = np.asarray(character.parents)
    J = len(parents)
    # tree distance between joints (bones), by BFS from every joint: J is small (tens)
    nbr = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            nbr[j].append(int(p))
            nbr[int(p)].append(j)
    dist = np.full((J, J), 10**6)
    for s in range(J):
        dist[s, s], front = 0, [s]
        while front:
            nxt = []
            for a in front:
                for b in nbr[a]:
                    if dist[s, b] > dist[s, a] + 1:
                        dist[s, b] = dist[s, a] + 1
                        nxt.append(b)
            front = nxt
    part = np.asarray(character.dominant_joint(), dtype=np.int64)
    rest = np.asarray(character.vertices, dtype=np.float64)
    C = capsules.count
    # (V, C) rest vertices inside each capsule, capsule by capsule ((V, 3) temporaries, not (V, C, 3))
    bind_ends = capsules.ends(character.bind_world)
    inside_rest = np.stack([segment_distance(rest, a, b)[0] < r for (a, b), r in zip(bind_ends, capsules.radius)],
                           axis=1) if C else None
    # (J, C) share of each part's rest vertices inside each capsule (bincounts, not a boolean mask per pair)
    n_part = np.bincount(part, minlength=J)
    share = np.stack([np.bincount(part, weights=inside_rest[:, c], minlength=J) for c in range(C)], axis=1) \
        / np.maximum(n_part, 1)[:, None] if C else np.zeros((J, 0))
    lists = []
    for j in range(J):
        ok = []
        for c in range(C):
            near = min(dist[j, capsules.joint[c]], dist[j, capsules.child[c]] if capsules.child[c] >= 0 else 10**6)
            if near <= SKIN_ADJACENT:
                continue
            if n_part[j] and share[j, c] > SKIN_REST_SHARE:
                continue
            ok.append(c)
        lists.append(ok)
    offsets = np.concatenate([[0], np.cumsum([len(x) for x in lists])]).astype(np.int64)
    flat = np.array([c for x in lists for c in x], np.int64)
    cluster, centre = vertex_clusters(part, rest, character.bind_world)
    return SkinCheck(capsules, frozen_array(part, np.int64), frozen_array(offsets, np.int64),
                     frozen_array(flat, np.int64), frozen_array(cluster, np.int64), frozen_array(centre, np.float64))


def skin_inside_numpy(ends: np.ndarray, radius: np.ndarray, skin: np.ndarray, part: np.ndarray | None = None,
                      part_offsets: np.ndarray | None = None, part_capsule=None, all_pairs: bool = False) -> np.ndarray:
    """NumPy reference of the skin_inside kernel: (T, V) bool from capsule ends (T, C, 2, 3), radius (C,),
    skin (T, V, 3); all_pairs gives (T, V, C) inside flags for every capsule instead."""
    ends = np.asarray(ends, dtype=np.float64).reshape(len(skin), -1, 2, 3)
    a, b = ends[:, None, :, 0], ends[:, None, :, 1]                      # (T, 1, C, 3)
    ab = b - a
    L2 = np.sum(ab * ab, axis=-1)
    x = np.asarray(skin, dtype=np.float64)[:, :, None]                    # (T, V, 1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(L2 > 0, np.clip(np.sum((x - a) * ab, axis=-1) / np.where(L2 > 0, L2, 1), 0, 1), 0.0)
    d2 = np.sum((x - (a + t[..., None] * ab)) ** 2, axis=-1)              # (T, V, C)
    inside = d2 < np.asarray(radius)[None, None] ** 2
    if all_pairs:
        return inside
    mask = np.zeros((len(part_offsets) - 1, inside.shape[2]), bool)
    for j in range(len(part_offsets) - 1):
        mask[j, part_capsule[part_offsets[j]:part_offsets[j + 1]]] = True
    return (inside & mask[part][None]).any(axis=2)


def keep_out_numpy(ends: np.ndarray, radius: np.ndarray, static: np.ndarray, final: np.ndarray, part: np.ndarray,
                   part_offsets: np.ndarray, part_capsule: np.ndarray, passes: int = 4) -> np.ndarray:
    """NumPy reference of SkinCheck.keep_out in float64: the final skin (T, V, 3) with each vertex inside a
    capsule of its part's list that its static vertex is not inside moved back along final - static onto
    that capsule's surface (the first one the segment enters; again for up to `passes` capsules, then the
    static vertex). ends (T, C, 2, 3), radius (C,)."""
    ends = np.asarray(ends, dtype=np.float64).reshape(len(final), -1, 2, 3)
    out = np.array(final, dtype=np.float64)
    static = np.asarray(static, dtype=np.float64)

    def dist(x, a, b):
        return segment_distance(x[None], a, b)[0][0]
    for t in range(len(out)):
        for v in range(out.shape[1]):
            p = part[v]
            caps = part_capsule[part_offsets[p]:part_offsets[p + 1]]
            s = static[t, v]
            f = out[t, v]
            for _ in range(passes + 1):
                bad = [c for c in caps if dist(f, *ends[t, c]) < radius[c] <= dist(s, *ends[t, c])]
                if not bad:
                    break
                if _ == passes:
                    f = s
                    break
                us = []
                for c in bad:      # the root of |x(u) - axis| = r on [0, 1]: distance falls then rises (convex)
                    lo, hi = 0.0, 1.0
                    for _i in range(60):
                        mid = 0.5 * (lo + hi)
                        lo, hi = (lo, mid) if dist(s + mid * (f - s), *ends[t, c]) < radius[c] else (mid, hi)
                    us.append(lo)
                f = s + min(us) * (f - s)
            out[t, v] = f
    return out


# ------------------------------------------------------------------------------ NumPy references
def axis_distance_numpy(x, a, b):
    """(t, q, distance) of x (3,) from the segment a-b: its closest point's parameter t in [0, 1] and the point."""
    ab = b - a
    L2 = ab @ ab
    t = float(np.clip((x - a) @ ab / L2, 0.0, 1.0)) if L2 > 0 else 0.0
    q = a + t * ab
    return t, q, float(np.linalg.norm(x - q))


def capsule_push_numpy(x, v, a, b, va, vb, r, friction, g=None):
    """The kernels' capsule_push in float64 for one particle: (x, v, depth). g : the particle's goal (3,)
    metres; the surface it is held outside of has radius min(r, |g - axis|) (None: r, no allowance)."""
    t, q, dist = axis_distance_numpy(x, a, b)
    rs = r if g is None else min(r, axis_distance_numpy(g, a, b)[2])
    if dist >= rs:
        return x, v, 0.0
    d = x - q
    n = d / dist if dist > 1e-9 else np.array([0.0, 0.0, 1.0])
    return q + n * rs, surface_velocity_numpy(v, va + t * (vb - va), n, friction), rs - dist


def surface_velocity_numpy(v, w, n, friction):
    vr = v - w
    vn = vr @ n
    if vn >= 0:
        return v
    vt = vr - vn * n
    st = np.linalg.norm(vt)
    keep = max(0.0, st + friction * vn) / st if st > 0 else 0.0
    return w + keep * vt


def contact_numpy(model: ColliderModel, muscle_offsets: np.ndarray, glued: np.ndarray, x: np.ndarray,
                  v: np.ndarray, ends: np.ndarray, ends_vel: np.ndarray,
                  goal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact pass in float64, every listed pair checked (no broad phase): x, v (N, 3) at a step's
    end, the capsules' ends (C, 2, 3) and their velocities, and the particles' goals (N, 3) then (the rest
    state that sets each pair's allowance, sim/jiggle/contact_kernels.py; None: no allowance) -> (x, v,
    depth (N,), beyond the allowance)."""
    x, v = np.array(x, dtype=np.float64), np.array(v, dtype=np.float64)
    depth = np.zeros(len(x))
    for m in range(len(muscle_offsets) - 1):
        for i in range(muscle_offsets[m], muscle_offsets[m + 1]):
            if glued[i]:
                continue
            g = None if goal is None else np.asarray(goal[i], dtype=np.float64)
            for c in model.pairs(m):
                x[i], v[i], d = capsule_push_numpy(x[i], v[i], ends[c, 0], ends[c, 1], ends_vel[c, 0], ends_vel[c, 1],
                                                   model.capsules.radius[c], model.friction, g)
                depth[i] = max(depth[i], d)
            floor = model.floor if model.floor is None or g is None else min(model.floor, g[2])
            if floor is not None and x[i, 2] < floor:
                depth[i] = max(depth[i], floor - x[i, 2])
                x[i, 2] = floor
                v[i] = surface_velocity_numpy(v[i], np.zeros(3), np.array([0.0, 0.0, 1.0]), model.friction)
    return x, v, depth


def integrate_contact_numpy(model, colliders: ColliderModel, flow, track, cap_track, x: np.ndarray, v: np.ndarray,
                            grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The NumPy reference of ParticleSolver.integrate with colliders, float64: (x, v) (N, 3) at grid[-1]
    and the largest contact depth (N,) metres over the run. cap_track : the capsules' ends' GoalTrack
    (S, 2C) on the goal track's knots; flow(h) -> (N, tissue_law.ROW) tissue flow rows."""
    from jiggle.sim.jiggle import tissue_law
    from jiggle.sim.jiggle.goal_track import hermite
    from jiggle.sim.jiggle.solver import _check_steps, kick_numpy
    grid = np.asarray(grid, dtype=np.float64)
    dts = np.diff(grid)
    steps = list(zip(*(a.tolist() for a in _check_steps(track, grid))))
    mu = model.drag[:, None]

    def goal(tr, j, s):
        return hermite(tr.pos[j], tr.pos[j + 1], tr.vel_start[j], tr.vel_end[j], tr.times[j + 1] - tr.times[j], s)

    j, s0, _ = steps[0]
    g, gv, _, _ = goal(track, j, s0)
    y, u = x - g, v - gv
    deepest = np.zeros(len(x))
    h_kick = 0.5 * dts[0]
    for k, ((j, s0, _), h) in enumerate(zip(steps, dts)):
        _, gv, gacc, gjerk = goal(track, j, s0)
        u = kick_numpy(model, y, u, h_kick)
        b0 = model.gravity_vector - gacc - mu * gv
        b1 = -gjerk - mu * gacc
        b2 = -0.5 * mu * gjerk
        y, u, _ = tissue_law.step_numpy(flow(h), y, u, b0, b1, b2, h, np.asarray(model.reach, dtype=np.float64))
        g1, gv1, _, _ = goal(track, j, s0 + h)
        ends, ends_v, _, _ = goal(cap_track, j, s0 + h)
        C = colliders.num_capsules
        xs, vs, d = contact_numpy(colliders, model.group_offsets, model.glued, g1 + y, gv1 + u,
                                  ends[:2 * C].reshape(C, 2, 3), ends_v[:2 * C].reshape(C, 2, 3), goal=g1)
        y, u = xs - g1, vs - gv1
        deepest = np.maximum(deepest, d)
        h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
    j, s0, _ = steps[-1]
    g1, gv1, _, _ = goal(track, j, s0 + dts[-1])
    u = kick_numpy(model, y, u, 0.5 * dts[-1])
    return g1 + y, gv1 + u, deepest
